//! Voxel attributes and the solid fill: colour from the material diffuse times the colour map at
//! the point of the triangle nearest to the voxel centre, the interpolated normal, the alpha
//! test; and the interior of closed meshes by even–odd crossings along +Z.

use super::voxelize::{Voxels, keys_of_bricks};
use super::{Grid, morton_encode};
use crate::error::Result;
use crate::model::{Mesh, Rgba8Image};
use rayon::prelude::*;

pub use crate::color::srgb_to_linear;

/// Unit vector, or zero for a zero vector.
pub fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 { v.map(|x| x / l) } else { [0.0; 3] }
}

struct MaterialShade {
    color: [f32; 3],
    alpha: f32,
    texture: Option<usize>,
    /// The colour map has texels with alpha below 255: test alpha per voxel.
    texture_alpha: bool,
}

struct TriShade {
    a: [f32; 3],
    e0: [f32; 3],
    e1: [f32; 3],
    d00: f32,
    d01: f32,
    d11: f32,
    inv_denom: f32,
    material: u32,
    /// Unit vertex normals (zero where the mesh has none) and the unit face normal.
    normals: [[f32; 3]; 3],
    face_normal: [f32; 3],
}

/// Everything needed to shade a triangle's voxels.
pub struct Shader<'a> {
    mesh: &'a Mesh,
    textures: &'a [Option<Rgba8Image>],
    lut: [f32; 256],
    materials: Vec<MaterialShade>,
    tris: Vec<TriShade>,
    cutoff: f32,
}

impl<'a> Shader<'a> {
    pub fn new(
        mesh: &'a Mesh,
        textures: &'a [Option<Rgba8Image>],
        grid: &Grid,
        cutoff: f32,
    ) -> Self {
        let lut = std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0));
        let materials = mesh
            .materials
            .iter()
            .map(|m| {
                let texture = m
                    .color_map
                    .map(|i| i as usize)
                    .filter(|&i| textures.get(i).is_some_and(|t| t.is_some()));
                let texture_alpha = texture.is_some_and(|i| {
                    textures[i]
                        .as_ref()
                        .is_some_and(|t| t.pixels.iter().any(|p| p[3] < 255))
                });
                MaterialShade {
                    color: crate::material::convert::diffuse_albedo(m),
                    alpha: m.diffuse[3].clamp(0.0, 1.0) * (1.0 - m.transparency.clamp(0.0, 1.0)),
                    texture,
                    texture_alpha,
                }
            })
            .collect();
        let tris = mesh
            .indices
            .par_iter()
            .zip(&mesh.triangle_materials)
            .map(|(t, &material)| {
                tri_shade(
                    t.map(|i| grid.to_grid(mesh.positions[i as usize])),
                    t.map(|i| normalize(mesh.normals[i as usize])),
                    material,
                )
            })
            .collect();
        Shader {
            mesh,
            textures,
            lut,
            materials,
            tris,
            cutoff,
        }
    }

    /// Whether any part of triangle `t` can pass the alpha test.
    pub fn triangle_visible(&self, t: usize) -> bool {
        let m = &self.materials[self.tris[t].material as usize];
        m.texture_alpha || m.alpha >= self.cutoff
    }

    /// Barycentric coordinates of the point of triangle `t` nearest (approximately: the plane
    /// projection clamped to the triangle) to `p` (voxel units).
    fn barycentric(&self, t: usize, p: [f32; 3]) -> [f32; 3] {
        let s = &self.tris[t];
        let v2 = [p[0] - s.a[0], p[1] - s.a[1], p[2] - s.a[2]];
        let d20 = v2[0] * s.e0[0] + v2[1] * s.e0[1] + v2[2] * s.e0[2];
        let d21 = v2[0] * s.e1[0] + v2[1] * s.e1[1] + v2[2] * s.e1[2];
        let v = ((s.d11 * d20 - s.d01 * d21) * s.inv_denom).max(0.0);
        let w = ((s.d00 * d21 - s.d01 * d20) * s.inv_denom).max(0.0);
        let u = (1.0 - v - w).max(0.0);
        let sum = u + v + w;
        if sum > 0.0 && sum.is_finite() {
            [u / sum, v / sum, w / sum]
        } else {
            [1.0 / 3.0; 3]
        }
    }

    fn texel(&self, tex: usize, uv: [f32; 2]) -> [f32; 4] {
        let Some(img) = self.textures[tex].as_ref() else {
            return [1.0; 4];
        };
        if img.width == 0 || img.height == 0 {
            return [1.0; 4];
        }
        let x = (uv[0] - uv[0].floor()) * img.width as f32;
        let y = (uv[1] - uv[1].floor()) * img.height as f32;
        let x = (x as u32).min(img.width - 1);
        let y = (y as u32).min(img.height - 1);
        let p = img.pixels[(y * img.width + x) as usize];
        [
            self.lut[p[0] as usize],
            self.lut[p[1] as usize],
            self.lut[p[2] as usize],
            p[3] as f32 / 255.0,
        ]
    }

    fn uv(&self, t: usize, b: [f32; 3]) -> [f32; 2] {
        let idx = self.mesh.indices[t];
        let mut uv = [0.0; 2];
        for (k, &i) in idx.iter().enumerate() {
            let u = self.mesh.uvs[i as usize];
            uv[0] += b[k] * u[0];
            uv[1] += b[k] * u[1];
        }
        uv
    }

    /// The alpha test for triangle `t` at the centre of voxel `p`.
    pub fn alpha_passes(&self, t: usize, p: [i64; 3]) -> bool {
        let m = &self.materials[self.tris[t].material as usize];
        if !m.texture_alpha {
            return m.alpha >= self.cutoff;
        }
        let c = p.map(|x| x as f32 + 0.5);
        let uv = self.uv(t, self.barycentric(t, c));
        m.alpha * self.texel(m.texture.unwrap_or(0), uv)[3] >= self.cutoff
    }

    /// Colour (linear, straight alpha) and normal of triangle `t` at voxel `p`, or None where the
    /// alpha test removes it (always agrees with [`Self::alpha_passes`]).
    pub fn sample(&self, t: usize, p: [i64; 3]) -> Option<([f32; 4], [f32; 3])> {
        self.sample_at(t, p.map(|x| x as f32 + 0.5))
    }

    /// As [`Self::sample`] at a point in voxel units.
    pub fn sample_at(&self, t: usize, c: [f32; 3]) -> Option<([f32; 4], [f32; 3])> {
        let m = &self.materials[self.tris[t].material as usize];
        let b = self.barycentric(t, c);
        let texel = match m.texture {
            Some(tex) => self.texel(tex, self.uv(t, b)),
            None => [1.0; 4],
        };
        let alpha = if m.texture_alpha {
            m.alpha * texel[3]
        } else {
            m.alpha
        };
        if alpha < self.cutoff {
            return None;
        }
        // The interpolated normal, not normalized: callers average several and normalize the
        // sum (one square root per voxel instead of one per triangle).
        let s = &self.tris[t];
        let mut n = [0.0; 3];
        for (bk, vn) in b.iter().zip(&s.normals) {
            for (nj, v) in n.iter_mut().zip(vn) {
                *nj += bk * v;
            }
        }
        if n == [0.0; 3] {
            n = s.face_normal;
        }
        let color = [
            m.color[0] * texel[0],
            m.color[1] * texel[1],
            m.color[2] * texel[2],
            alpha,
        ];
        Some((color, n))
    }
}

fn tri_shade(v: [[f32; 3]; 3], normals: [[f32; 3]; 3], material: u32) -> TriShade {
    let e0 = [v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]];
    let e1 = [v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]];
    let d = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (d00, d01, d11) = (d(e0, e0), d(e0, e1), d(e1, e1));
    let denom = d00 * d11 - d01 * d01;
    TriShade {
        a: v[0],
        e0,
        e1,
        d00,
        d01,
        d11,
        inv_denom: if denom != 0.0 { 1.0 / denom } else { 0.0 },
        material,
        normals,
        face_normal: normalize(super::voxelize::cross(e0, e1)),
    }
}

/// One crossing of a voxel-centre column (x + ½, y + ½) with a triangle.
#[derive(Clone, Copy)]
struct Crossing {
    column: u64,
    z: f32,
    tri: u32,
}

/// 2D edge function in f64 (exact for f32 inputs of moderate size, so shared edges agree).
fn edge(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
}

/// Top-left rule for a counter-clockwise triangle: an edge owns its points when it is a left
/// edge (going down) or a top edge (horizontal, going left), so shared edges count once.
fn owns(a: [f64; 2], b: [f64; 2]) -> bool {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    dy < 0.0 || (dy == 0.0 && dx < 0.0)
}

fn crossings_of(grid: &Grid, t: u32, v: [[f32; 3]; 3]) -> Vec<Crossing> {
    let mut p = v.map(|q| [q[0] as f64, q[1] as f64]);
    let mut z = v.map(|q| q[2] as f64);
    let area = edge(p[0], p[1], p[2]);
    if area == 0.0 {
        return Vec::new();
    }
    if area < 0.0 {
        p.swap(1, 2);
        z.swap(1, 2);
    }
    let area = area.abs();
    let lo = [0, 1].map(|k| (p[0][k].min(p[1][k]).min(p[2][k]) - 0.5).ceil().max(0.0) as i64);
    let hi = [0, 1].map(|k| {
        let m = (p[0][k].max(p[1][k]).max(p[2][k]) - 0.5).floor();
        m.min(grid.dims[k] as f64 - 1.0) as i64
    });
    let mut out = Vec::new();
    for y in lo[1]..=hi[1] {
        for x in lo[0]..=hi[0] {
            let c = [x as f64 + 0.5, y as f64 + 0.5];
            let w = [0, 1, 2].map(|i| edge(p[(i + 1) % 3], p[(i + 2) % 3], c));
            let inside =
                (0..3).all(|i| w[i] > 0.0 || (w[i] == 0.0 && owns(p[(i + 1) % 3], p[(i + 2) % 3])));
            if inside {
                let zc = (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / area;
                out.push(Crossing {
                    column: y as u64 * grid.dims[0] as u64 + x as u64,
                    z: zc as f32,
                    tri: t,
                });
            }
        }
    }
    out
}

/// Adds the voxels whose centres lie inside the mesh (even–odd rule along +Z); interior voxels
/// take the colour of the surface where their run enters and a zero normal.
pub fn fill_interior(v: &mut Voxels, mesh: &Mesh, shade: &Shader) -> Result<()> {
    let grid = v.grid;
    let mut xs: Vec<Crossing> = mesh
        .indices
        .par_iter()
        .enumerate()
        .flat_map_iter(|(t, tri)| {
            crossings_of(
                &grid,
                t as u32,
                tri.map(|i| grid.to_grid(mesh.positions[i as usize])),
            )
        })
        .collect();
    xs.par_sort_unstable_by(|a, b| {
        (a.column, a.z, a.tri)
            .partial_cmp(&(b.column, b.z, b.tri))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut interior: Vec<(u64, [f32; 4])> = Vec::new();
    let mut start = 0;
    while start < xs.len() {
        let mut end = start;
        while end < xs.len() && xs[end].column == xs[start].column {
            end += 1;
        }
        let run = &xs[start..end];
        if run.len() % 2 == 1 {
            v.open_columns += 1;
        }
        let col = run[0].column;
        let (x, y) = (
            (col % grid.dims[0] as u64) as u32,
            (col / grid.dims[0] as u64) as u32,
        );
        for pair in run.chunks_exact(2) {
            let k0 = ((pair[0].z - 0.5).ceil().max(0.0)) as i64;
            let k1 = ((pair[1].z - 0.5).floor() as i64).min(grid.dims[2] as i64 - 1);
            let at = [x as f32 + 0.5, y as f32 + 0.5, pair[0].z];
            let color = shade
                .sample_at(pair[0].tri as usize, at)
                .map_or([0.0; 4], |(c, _)| c);
            for k in k0..=k1 {
                interior.push((morton_encode([x, y, k as u32]), color));
            }
        }
        start = end;
    }
    interior.par_sort_unstable_by_key(|e| e.0);
    merge_interior(v, &interior);
    Ok(())
}

/// Merges interior voxels (sorted keys) into the surface voxels; surface attributes win.
fn merge_interior(v: &mut Voxels, interior: &[(u64, [f32; 4])]) {
    let surface = keys_of_bricks(&v.bricks);
    let (mut i, mut j) = (0, 0);
    let mut keys = Vec::with_capacity(surface.len() + interior.len());
    let mut colors = Vec::with_capacity(keys.capacity());
    let mut normals = Vec::with_capacity(keys.capacity());
    while i < surface.len() || j < interior.len() {
        let take_surface =
            j == interior.len() || (i < surface.len() && surface[i] <= interior[j].0);
        if take_surface {
            if j < interior.len() && surface[i] == interior[j].0 {
                j += 1;
            }
            keys.push(surface[i]);
            colors.push(v.colors[i]);
            normals.push(v.normals[i]);
            i += 1;
        } else {
            keys.push(interior[j].0);
            colors.push(interior[j].1);
            normals.push([0.0; 3]);
            j += 1;
        }
    }
    v.bricks = super::voxelize::bricks_of_keys(keys);
    v.colors = colors;
    v.normals = normals;
}
