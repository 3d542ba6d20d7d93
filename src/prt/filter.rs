//! Spatial filtering of a transfer (a denoiser, biased): each vertex takes the weighted mean
//! of the transfers of the vertices within `radius` of it whose normal is within the angle
//! `acos(min_cos)` of its own and whose material is its own (weight 1 − (d/r)²). The four
//! corners of a flat leaf quad see almost the same occluders, so their independent
//! Monte-Carlo noise averages out while the transfer hardly changes: `bake bench prt-error`
//! measures both effects together (the filtered error includes the bias).

use super::transfer::{PER_VERTEX, Transfer};
use crate::model::Mesh;
use glam::Vec3A;
use rayon::prelude::*;
use std::collections::HashMap;

/// Options of [`Neighbourhoods`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterOptions {
    /// Radius in model units.
    pub radius: f32,
    /// Least cosine between two vertices' normals.
    pub min_cos: f32,
}

/// The vertices of a mesh in a grid of cells `radius` wide, for neighbour queries.
pub struct Neighbourhoods<'a> {
    mesh: &'a Mesh,
    opts: FilterOptions,
    cells: HashMap<[i32; 3], Vec<u32>>,
    material: Vec<u32>,
}

impl<'a> Neighbourhoods<'a> {
    pub fn new(mesh: &'a Mesh, opts: FilterOptions) -> Self {
        let mut material = vec![u32::MAX; mesh.positions.len()];
        for (t, tri) in mesh.indices.iter().enumerate() {
            for &i in tri {
                if let Some(m) = material.get_mut(i as usize)
                    && *m == u32::MAX
                {
                    *m = mesh.triangle_materials.get(t).copied().unwrap_or(u32::MAX);
                }
            }
        }
        let mut cells: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (v, p) in mesh.positions.iter().enumerate() {
            if material[v] != u32::MAX && Vec3A::from(*p).is_finite() {
                cells
                    .entry(cell(*p, opts.radius))
                    .or_default()
                    .push(v as u32);
            }
        }
        Neighbourhoods {
            mesh,
            opts,
            cells,
            material,
        }
    }

    /// The neighbours of `v` (itself included, first) and their weights, in a fixed order.
    pub fn of(&self, v: u32) -> Vec<(u32, f32)> {
        let m = self.mesh;
        let p = Vec3A::from(m.positions[v as usize]);
        let n = Vec3A::from(m.normals[v as usize]).normalize_or_zero();
        let mut out = vec![(v, 1.0)];
        if n == Vec3A::ZERO || self.material[v as usize] == u32::MAX || !p.is_finite() {
            return out;
        }
        let c = cell(m.positions[v as usize], self.opts.radius);
        let r2 = self.opts.radius * self.opts.radius;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(list) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                        continue;
                    };
                    for &u in list {
                        if u == v || self.material[u as usize] != self.material[v as usize] {
                            continue;
                        }
                        let d2 = (Vec3A::from(m.positions[u as usize]) - p).length_squared();
                        let nu = Vec3A::from(m.normals[u as usize]).normalize_or_zero();
                        if d2 < r2 && nu.dot(n) >= self.opts.min_cos {
                            out.push((u, 1.0 - d2 / r2));
                        }
                    }
                }
            }
        }
        out[1..].sort_by_key(|&(u, _)| u);
        out
    }
}

fn cell(p: [f32; 3], r: f32) -> [i32; 3] {
    p.map(|x| (x / r).floor() as i32)
}

/// The filtered transfer of `targets`, reading each neighbour's transfer through `row` (its
/// index in `t`, `None` where it was not baked: left out).
pub fn filter_vertices(
    hoods: &Neighbourhoods,
    t: &Transfer,
    targets: &[u32],
    row: &(dyn Fn(u32) -> Option<usize> + Sync),
) -> Transfer {
    let coeffs: Vec<[f32; 3]> = targets
        .par_iter()
        .flat_map_iter(|&v| {
            let mut acc = [[0.0f64; 3]; PER_VERTEX];
            let mut wsum = 0.0f64;
            for (u, w) in hoods.of(v) {
                let Some(i) = row(u) else { continue };
                for (a, c) in acc
                    .iter_mut()
                    .zip(&t.coeffs[i * PER_VERTEX..(i + 1) * PER_VERTEX])
                {
                    for k in 0..3 {
                        a[k] += w as f64 * c[k] as f64;
                    }
                }
                wsum += w as f64;
            }
            let s = if wsum > 0.0 { 1.0 / wsum } else { 0.0 };
            acc.into_iter().map(move |a| a.map(|x| (x * s) as f32))
        })
        .collect();
    Transfer {
        vertices: targets.len() as u32,
        coeffs,
        ..t.clone()
    }
}

/// The filtered transfer of every vertex of `mesh` (`t` indexed by vertex).
pub fn filter_transfer(mesh: &Mesh, t: &Transfer, opts: FilterOptions) -> Transfer {
    let hoods = Neighbourhoods::new(mesh, opts);
    let all: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    filter_vertices(&hoods, t, &all, &|u| Some(u as usize))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Material;

    /// Three vertices at the origin's neighbourhood: one like vertex 0, one turned away, one
    /// of another material; and one far away.
    fn mesh() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [0.05, 0.0, 0.0],
                [0.0, 0.05, 0.0],
                [0.0, 0.0, 0.05],
                [5.0, 0.0, 0.0],
            ],
            normals: vec![
                [0.0, 0.0, 1.0],
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, 0.0, 1.0],
            ],
            uvs: vec![[0.0; 2]; 5],
            indices: vec![[0, 1, 2], [3, 4, 0]],
            triangle_materials: vec![0, 1],
            materials: vec![Material::default(), Material::default()],
            ..Mesh::default()
        }
    }

    #[test]
    fn neighbours_share_normal_material_and_place() {
        let m = mesh();
        let opts = FilterOptions {
            radius: 0.1,
            min_cos: 0.9,
        };
        let hoods = Neighbourhoods::new(&m, opts);
        let n: Vec<u32> = hoods.of(0).iter().map(|x| x.0).collect();
        // 2 is turned away, 3 has material 1 (its first triangle), 4 is far.
        assert_eq!(n, [0, 1]);
        let w = hoods.of(0)[1].1;
        assert!((w - (1.0 - 0.25)).abs() < 1e-6, "{w}");
        assert_eq!(hoods.of(4).len(), 1);
    }

    #[test]
    fn filtering_keeps_a_constant_transfer() {
        let m = mesh();
        let t = Transfer {
            vertices: 5,
            samples: 1,
            bounces: 0,
            coeffs: vec![[0.25, 0.5, 1.0]; 5 * PER_VERTEX],
            rays: 0,
            skipped_vertices: 0,
        };
        let f = filter_transfer(
            &m,
            &t,
            FilterOptions {
                radius: 0.1,
                min_cos: 0.9,
            },
        );
        assert_eq!(f.coeffs, t.coeffs);
    }
}
