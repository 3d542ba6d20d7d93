//! The impostor atlas: `grid × grid` hemi-octahedral views of a model (src/lod/octa.rs), each
//! `tile²` texels of albedo with alpha-tested coverage, model-space normal and depth, made by
//! casting one orthographic ray per texel into the model's BVH (crate::trace, alpha test at 0.5
//! on the colour maps, as the PRT and the CPU reference renderer see the model).
//!
//! Why the CPU ray caster and not a wgpu pass: it is exact per texel centre, deterministic
//! whatever the thread count, and needs no adapter in the stage (a stage is a pure function);
//! `bake lod` on the 30 generated trees casts 30 × 262,144 rays (docs/PERFORMANCE.md).
//!
//! Colour: the colour map's texel (nearest, sRGB-decoded) times the material's diffuse colour
//! (display values decoded from sRGB), re-encoded to sRGB; alpha 255 where a ray hits, else 0
//! (RGB 0). Normal: the interpolated shading normal turned towards the eye (leaves are two-sided),
//! with the surface's material index in alpha (255 for 255 and above).

use super::octa;
use super::section::{HEMI_OCTAHEDRAL, ImpostorAtlas, ImpostorMeta};
use crate::color::{linear_to_srgb, srgb_to_linear};
use crate::error::Result;
use crate::model::{Mesh, Rgba8Image};
use crate::trace::{AlphaMask, BuildPreset, ModelBvh, Ray};
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// One atlas texel: colour, normal, depth code.
type Texel = ([u8; 4], [u8; 4], u8);

/// Bakes the atlas of `mesh` around the sphere (`centre`, `radius`).
#[allow(clippy::too_many_arguments)]
pub fn bake_impostor(
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    masks: &[Option<AlphaMask>],
    centre: [f32; 3],
    radius: f32,
    grid: u32,
    tile: u32,
    error: f32,
) -> Result<(ImpostorMeta, ImpostorAtlas)> {
    let bvh = ModelBvh::build(mesh, masks, BuildPreset::default())?;
    let radius = if radius > 0.0 { radius } else { 1.0 };
    let side = (grid * tile) as usize;
    let centre_v = Vec3A::from(centre);
    // One row of tiles per task: texels are independent, so the bytes do not depend on threads.
    let rows: Vec<Vec<Texel>> = (0..side)
        .into_par_iter()
        .map(|y| {
            (0..side)
                .map(|x| texel(&bvh, mesh, textures, centre_v, radius, grid, tile, x, y))
                .collect()
        })
        .collect();
    let mut atlas = ImpostorAtlas {
        color: Vec::with_capacity(side * side),
        normal: Vec::with_capacity(side * side),
        depth: Vec::with_capacity(side * side),
    };
    for (c, n, d) in rows.into_iter().flatten() {
        atlas.color.push(c);
        atlas.normal.push(n);
        atlas.depth.push(d);
    }
    let meta = ImpostorMeta {
        layout: HEMI_OCTAHEDRAL.into(),
        grid,
        tile,
        centre,
        radius,
        error,
    };
    Ok((meta, atlas))
}

/// The ray of atlas texel (x, y): origin outside the sphere on the eye's side, direction −ω.
pub fn texel_ray(
    centre: Vec3A,
    radius: f32,
    grid: u32,
    tile: u32,
    x: usize,
    y: usize,
) -> (Ray, Vec3A) {
    let (i, j) = (x as u32 / tile, y as u32 / tile);
    let (c, r) = (x as u32 % tile, y as u32 % tile);
    let w = octa::tile_direction(i, j, grid);
    let (right, up) = octa::view_axes(w);
    let s = 2.0 * (c as f32 + 0.5) / tile as f32 - 1.0;
    let t = 1.0 - 2.0 * (r as f32 + 0.5) / tile as f32;
    let w = Vec3A::from(w);
    let o = centre + (Vec3A::from(right) * s + Vec3A::from(up) * t) * radius + w * (2.0 * radius);
    // obvhs' slab test divides by the direction: an exactly zero component (the diagonal
    // tiles have ω_y = 0) gives 0·∞ = NaN on a box face through the origin and a missed box.
    let d = (-w).to_array().map(|c| {
        if c.abs() < 1e-7 {
            1e-7f32.copysign(c)
        } else {
            c
        }
    });
    (Ray::new(o, Vec3A::from(d), 0.0), w)
}

#[allow(clippy::too_many_arguments)]
fn texel(
    bvh: &ModelBvh,
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    centre: Vec3A,
    radius: f32,
    grid: u32,
    tile: u32,
    x: usize,
    y: usize,
) -> Texel {
    let (ray, w) = texel_ray(centre, radius, grid, tile, x, y);
    let Some(hit) = bvh.closest_hit(&ray) else {
        return ([0; 4], [0; 4], 255);
    };
    let s = bvh.surface(&hit);
    let mut n = s.shading_normal;
    if n.dot(w) < 0.0 {
        n = -n;
    }
    let enc = |v: f32| ((v * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
    // A: the surface's material index (255 for 255 and above), so the renderer can light the
    // texel with its material (src/render/impostor.rs).
    let normal = [enc(n.x), enc(n.y), enc(n.z), s.material.min(255) as u8];
    let delta = (centre - s.position).dot(w);
    let depth = octa::depth_code(delta, radius);
    (albedo(mesh, textures, s.material, s.uv), normal, depth)
}

/// sRGB albedo of a material at `uv` (alpha 255).
fn albedo(mesh: &Mesh, textures: &[Option<Rgba8Image>], material: u32, uv: [f32; 2]) -> [u8; 4] {
    let (lin, _) = linear_albedo(mesh, textures, material, uv);
    let e = |v: f32| (linear_to_srgb(v) * 255.0).round().clamp(0.0, 255.0) as u8;
    [e(lin[0]), e(lin[1]), e(lin[2]), 255]
}

/// The model's mean albedo, sRGB with A = 255 (the skeleton's colour): the linear albedo
/// averaged over the surface by area, each triangle sampled at three interior points
/// (barycentric (4, 1, 1)/6 and its rotations), texels whose alpha is below 0.5 (cut out by the
/// alpha test) left out. Mid grey for a mesh without visible area.
pub fn mean_albedo(mesh: &Mesh, textures: &[Option<Rgba8Image>]) -> [u8; 4] {
    let (mut sum, mut weight) = ([0.0f64; 3], 0.0f64);
    for (t, tri) in mesh.indices.iter().enumerate() {
        let p = tri.map(|v| glam::Vec3::from(mesh.positions[v as usize]));
        let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length() as f64;
        if area.is_nan() || area <= 0.0 {
            continue;
        }
        let uv = tri.map(|v| mesh.uvs[v as usize]);
        for r in 0..3 {
            let b = [0, 1, 2].map(|k| if k == r { 4.0 / 6.0 } else { 1.0 / 6.0 });
            let at = [0, 1].map(|c| b[0] * uv[0][c] + b[1] * uv[1][c] + b[2] * uv[2][c]);
            let (lin, alpha) = linear_albedo(mesh, textures, mesh.triangle_materials[t], at);
            if alpha < 0.5 {
                continue;
            }
            for k in 0..3 {
                sum[k] += area * lin[k] as f64;
            }
            weight += area;
        }
    }
    if weight <= 0.0 {
        return [128, 128, 128, 255];
    }
    let e = |v: f64| {
        (linear_to_srgb((v / weight) as f32) * 255.0)
            .round()
            .clamp(0.0, 255.0) as u8
    };
    [e(sum[0]), e(sum[1]), e(sum[2]), 255]
}

/// Linear albedo of a material at `uv` and the colour map's alpha there (1 without one).
fn linear_albedo(
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    material: u32,
    uv: [f32; 2],
) -> ([f32; 3], f32) {
    let Some(m) = mesh.materials.get(material as usize) else {
        return ([1.0, 0.0, 1.0], 1.0);
    };
    let mut alpha = 1.0;
    let mut lin = crate::material::convert::diffuse_albedo(m);
    if let Some(img) = m
        .color_map
        .and_then(|i| textures.get(i as usize))
        .and_then(|t| t.as_ref())
    {
        let (w, h) = (img.width.max(1) as i64, img.height.max(1) as i64);
        let px = ((uv[0] * w as f32).floor() as i64).rem_euclid(w);
        let py = ((uv[1] * h as f32).floor() as i64).rem_euclid(h);
        if let Some(t) = img.pixels.get((py * w + px) as usize) {
            for k in 0..3 {
                lin[k] *= srgb_to_linear(t[k] as f32 / 255.0);
            }
            alpha = t[3] as f32 / 255.0;
        }
    }
    (lin, alpha)
}

/// The direction towards the eye of atlas tile (i, j) as a `Vec3` (re-exported for readers).
pub fn tile_direction(i: u32, j: u32, grid: u32) -> Vec3 {
    octa::tile_direction(i, j, grid)
}
