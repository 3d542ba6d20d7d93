//! Light maps of meshes placed a few times (the 3DS objects of a scene): one atlas layout per
//! mesh ([`super::atlas`]), one tile of it per instance (tiles side by side in one texture, row
//! by row), every covered texel lit by the same estimator as the terrain
//! ([`super::texel_irradiance`]: sun disc with shadows from the whole scene, sky with visibility,
//! one bounce; or seed 001's thesis estimator), then the gutters dilated.
//!
//! A renderer finds the light map of vertex `v` of instance slot `s` at
//! `tiles[s].xy + lightmap_uv[v] · tiles[s].zw` (atlas UV, v = 0 at the top row) and samples it
//! bilinearly with clamp-to-edge; [`AtlasLightmap::sample`] is that lookup on the CPU. Where chart
//! borders split mesh vertices, [`AtlasLayout::split_mesh`] gives the mesh to draw (the renderer
//! does the same from the section's `vertex_source` and `indices`); otherwise
//! [`AtlasLayout::uv_per_mesh_vertex`] is the second UV set of the mesh section as it is.

use super::atlas::{AtlasLayout, build_atlas, dilate, rasterize};
use super::{BakeLight, LightmapOptions, texel_irradiance};
use crate::model::Mesh;
use crate::trace::SceneTracer;
use glam::Vec3A;
use rayon::prelude::*;

/// A mesh and the scene instances (indices into the scene BVH's instances) that place it.
#[derive(Debug, Clone, Copy)]
pub struct PlacedMesh<'a> {
    pub mesh: &'a Mesh,
    pub instances: &'a [u32],
}

/// The baked atlas of one placed mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct AtlasLightmap {
    pub layout: AtlasLayout,
    /// Scene instance of every tile slot.
    pub instances: Vec<u32>,
    /// Tiles per atlas row.
    pub columns: u32,
    pub width: u32,
    pub height: u32,
    /// Irradiance (linear RGB) per atlas texel, row-major, row 0 at v = 0.
    pub texels: Vec<[f32; 3]>,
    /// The same without the direct sun (sky and bounced light): a renderer that draws the sun
    /// itself adds this one.
    pub indirect: Vec<[f32; 3]>,
    /// Per texel: 0 empty, 1 covered by a triangle, 2 a gutter texel filled by dilation.
    pub coverage: Vec<u8>,
    /// Texels the triangles cover (over all tiles).
    pub covered: u64,
    /// Texels filled by dilation.
    pub gutter_texels: u64,
}

impl AtlasLightmap {
    /// Atlas-UV rectangle (u₀, v₀, width, height) of tile slot `s`.
    pub fn tile_rect(&self, s: usize) -> [f32; 4] {
        tile_rect(s, self.columns, self.layout.tile, self.width, self.height)
    }

    /// Bilinear, clamp-to-edge lookup at atlas UV (texel centres at (i + ½)/W), like a GPU.
    pub fn sample(&self, uv: [f32; 2]) -> [f32; 3] {
        let (w, h) = (self.width as i64, self.height as i64);
        let x = uv[0] * self.width as f32 - 0.5;
        let y = uv[1] * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: i64, j: i64| self.texels[(j.clamp(0, h - 1) * w + i.clamp(0, w - 1)) as usize];
        let (i, j) = (x0 as i64, y0 as i64);
        let mut out = [0.0; 3];
        for (di, dj, wgt) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let t = at(i + di, j + dj);
            for k in 0..3 {
                out[k] += wgt * t[k];
            }
        }
        out
    }

    /// Atlas UV of a point with barycentrics `l` in mesh triangle `t`, on tile slot `s`.
    pub fn triangle_uv(&self, s: usize, t: usize, l: [f32; 3]) -> [f32; 2] {
        let r = self.tile_rect(s);
        let uv = self.layout.indices[t]
            .iter()
            .zip(l)
            .fold([0.0; 2], |a, (&v, w)| {
                let p = self.layout.uv[v as usize];
                [a[0] + p[0] * w, a[1] + p[1] * w]
            });
        [r[0] + uv[0] * r[2], r[1] + uv[1] * r[3]]
    }
}

fn tile_rect(s: usize, columns: u32, tile: u32, width: u32, height: u32) -> [f32; 4] {
    let (col, row) = (s as u32 % columns, s as u32 / columns);
    [
        (col * tile) as f32 / width as f32,
        (row * tile) as f32 / height as f32,
        tile as f32 / width as f32,
        tile as f32 / height as f32,
    ]
}

/// Bakes the atlas light map of a placed mesh. `seed` separates the random streams of different
/// meshes; texels are independent, so the result does not depend on the thread count. An error
/// if the mesh's charts do not fit the largest tile.
pub fn bake_object_lightmap(
    bvh: &dyn SceneTracer,
    albedo: &[[f32; 3]],
    light: &BakeLight,
    placed: PlacedMesh,
    seed: u64,
    opts: &LightmapOptions,
) -> Result<AtlasLightmap, String> {
    let layout = build_atlas(placed.mesh, &opts.atlas)?;
    Ok(bake_with_layout(
        bvh, albedo, light, placed, layout, seed, opts,
    ))
}

/// [`bake_object_lightmap`] with a given layout.
fn bake_with_layout(
    bvh: &dyn SceneTracer,
    albedo: &[[f32; 3]],
    light: &BakeLight,
    placed: PlacedMesh,
    layout: AtlasLayout,
    seed: u64,
    opts: &LightmapOptions,
) -> AtlasLightmap {
    let g = rasterize(placed.mesh, &layout);
    let tile = layout.tile;
    let n = placed.instances.len().max(1) as u32;
    let columns = (n as f64).sqrt().ceil() as u32;
    let rows = n.div_ceil(columns);
    let (width, height) = (columns * tile, rows * tile);
    let sky_irr = light.sky.to_irradiance();
    let mut texels = vec![[0.0f32; 3]; (width * height) as usize];
    let mut indirect = vec![[0.0f32; 3]; (width * height) as usize];
    let mut coverage = vec![0u8; (width * height) as usize];
    let (mut covered, mut gutter_texels) = (0, 0);
    for (s, &inst) in placed.instances.iter().enumerate() {
        let tr = bvh.instances()[inst as usize];
        let slot_seed = crate::trace::mix64(seed ^ ((s as u64) << 32));
        let (mut tex, mut ind): (Vec<[f32; 3]>, Vec<[f32; 3]>) = g
            .par_iter()
            .enumerate()
            .map(|(k, t)| match t {
                None => ([0.0; 3], [0.0; 3]),
                Some(t) => {
                    let p = tr.point_to_world(t.position);
                    let nrm = tr.normal_to_world(t.normal).normalize_or(Vec3A::Z);
                    let texel = crate::trace::mix64(slot_seed ^ k as u64);
                    let e = texel_irradiance(bvh, albedo, light, &sky_irr, p, nrm, texel, opts);
                    let d = texel_direct_sun(bvh, light, p, nrm, texel, opts);
                    (e, [0, 1, 2].map(|c| (e[c] - d[c]).max(0.0)))
                }
            })
            .unzip();
        let mut filled: Vec<bool> = g.iter().map(Option::is_some).collect();
        covered += filled.iter().filter(|&&f| f).count() as u64;
        dilate(&mut ind, &mut filled.clone(), &layout, layout.gutter + 1);
        gutter_texels += dilate(&mut tex, &mut filled, &layout, layout.gutter + 1);
        let cov: Vec<u8> = g
            .iter()
            .zip(&filled)
            .map(|(t, &f)| if t.is_some() { 1 } else { 2 * f as u8 })
            .collect();
        let (x0, y0) = ((s as u32 % columns) * tile, (s as u32 / columns) * tile);
        for y in 0..tile {
            let row = ((y0 + y) * width + x0) as usize;
            let src = (y * tile) as usize..((y + 1) * tile) as usize;
            texels[row..row + tile as usize].copy_from_slice(&tex[src.clone()]);
            indirect[row..row + tile as usize].copy_from_slice(&ind[src.clone()]);
            coverage[row..row + tile as usize].copy_from_slice(&cov[src]);
        }
    }
    AtlasLightmap {
        layout,
        instances: placed.instances.to_vec(),
        columns,
        width,
        height,
        texels,
        indirect,
        coverage,
        covered,
        gutter_texels,
    }
}

/// The direct-sun part of [`texel_irradiance`] at the same point with the same per-texel seed
/// (so the same disc samples): `E_sun · max(0, n·s) · V`, V = 1 in thesis mode.
pub fn texel_direct_sun(
    bvh: &dyn SceneTracer,
    light: &BakeLight,
    p: Vec3A,
    n: Vec3A,
    texel: u64,
    opts: &LightmapOptions,
) -> [f32; 3] {
    let Some((s, irr)) = light.sun else {
        return [0.0; 3];
    };
    let s = Vec3A::from(s);
    let cos = n.dot(s);
    if cos <= 0.0 {
        return [0.0; 3];
    }
    let vis = match opts.mode {
        super::LightmapMode::Thesis => 1.0,
        super::LightmapMode::Physical => {
            super::sun_visibility(bvh, p + n * 1e-3, s, opts.sun_samples, texel)
        }
    };
    irr.map(|e| e * cos * vis)
}

/// The models that get an atlas: placed at least once and at most `max_instances` times.
/// Returns, per such model, its index and its instances in scene order.
pub fn placed_models(
    models: &[u32],
    model_count: usize,
    max_instances: u32,
) -> Vec<(u32, Vec<u32>)> {
    let mut of_model: Vec<Vec<u32>> = vec![Vec::new(); model_count];
    for (i, &m) in models.iter().enumerate() {
        if let Some(l) = of_model.get_mut(m as usize) {
            l.push(i as u32);
        }
    }
    of_model
        .into_iter()
        .enumerate()
        .filter(|(_, l)| !l.is_empty() && l.len() <= max_instances as usize)
        .map(|(m, l)| (m as u32, l))
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn placed_models_are_those_with_one_to_max_instances() {
        // Model 0 once, model 1 twice, model 2 twenty times, model 3 never, one bad index.
        let mut models = vec![1, 0, 1];
        models.extend([2; 20]);
        models.push(9);
        let p = super::placed_models(&models, 4, 16);
        assert_eq!(p, vec![(0, vec![1]), (1, vec![0, 2])]);
        assert_eq!(super::placed_models(&models, 4, 20).len(), 3);
    }
}
