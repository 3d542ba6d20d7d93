//! Terrain preparation (seed 000 3.3.2): heights in metres as f32, the four-tap texture, a normal
//! map from the heights, and the min/max quadtree.
//!
//! Four-tap texel (i, j) = `(h[i, j], h[i+1, j], h[i, j+1], h[i+1, j+1])` in the grid's storage
//! order (row j + 1 is the next row: north of row j, since row 0 is the southern edge), clamped
//! at the last column and row: one fetch gives the four corners of a bilinear cell.
//! Normals are world-space (x east, y north, z up; the terrain's tangent frame is the world's),
//! from central differences in metres (one-sided at the edges), encoded `(n + 1)/2` in RGB, 255
//! in alpha.

use super::quadtree::MinMaxQuadtree;
use crate::model::Terrain;
use crate::texture::normalmap::{encode_normal, normalize};
use rayon::prelude::*;

/// Everything the renderer and the ray tracer need beyond the heights.
#[derive(Debug, Clone, PartialEq)]
pub struct PreparedTerrain {
    pub four_tap: Vec<[f32; 4]>,
    pub normals: Vec<[u8; 4]>,
    pub quadtree: MinMaxQuadtree,
}

/// Grid spacing in metres along x and y (1 where the grid has a single sample).
pub fn spacing(t: &Terrain) -> [f32; 2] {
    let s = |e: f32, n: u32| if n > 1 { e / (n - 1) as f32 } else { 1.0 };
    [s(t.extent[0], t.width), s(t.extent[1], t.height)]
}

/// The four-tap texture (see the module documentation).
pub fn four_tap(heights: &[f32], width: u32, height: u32) -> Vec<[f32; 4]> {
    let (w, h) = (width as usize, height as usize);
    let mut out = vec![[0.0f32; 4]; w * h];
    // Rows in parallel into a preallocated buffer: the 4096² case is memory-bound.
    out.par_chunks_mut(w).enumerate().for_each(|(j, dst)| {
        let row = &heights[j * w..][..w];
        let next = &heights[(j + 1).min(h - 1) * w..][..w];
        for (i, t) in dst.iter_mut().enumerate() {
            let i1 = (i + 1).min(w - 1);
            *t = [row[i], row[i1], next[i], next[i1]];
        }
    });
    out
}

/// The unit normal at sample (i, j) of a `w × h` grid with spacing `[sx, sy]`.
fn normal_at(hs: &[f32], w: usize, h: usize, [sx, sy]: [f32; 2], i: usize, j: usize) -> [f32; 3] {
    let (i0, i1) = (i.saturating_sub(1), (i + 1).min(w - 1));
    let (j0, j1) = (j.saturating_sub(1), (j + 1).min(h - 1));
    let dx = if i1 > i0 {
        (hs[j * w + i1] - hs[j * w + i0]) / ((i1 - i0) as f32 * sx)
    } else {
        0.0
    };
    let dy = if j1 > j0 {
        (hs[j1 * w + i] - hs[j0 * w + i]) / ((j1 - j0) as f32 * sy)
    } else {
        0.0
    };
    normalize([-dx, -dy, 1.0])
}

/// World-space unit normals of the height field.
pub fn terrain_normals(t: &Terrain) -> Vec<[f32; 3]> {
    let (w, h) = (t.width as usize, t.height as usize);
    let s = spacing(t);
    let mut out = vec![[0.0f32; 3]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, dst)| {
        for (i, n) in dst.iter_mut().enumerate() {
            *n = normal_at(&t.heights, w, h, s, i, j);
        }
    });
    out
}

/// The normal map, encoded (`(n + 1)/2`, alpha 255) without an intermediate float array.
pub fn terrain_normal_map(t: &Terrain) -> Vec<[u8; 4]> {
    let (w, h) = (t.width as usize, t.height as usize);
    let s = spacing(t);
    let mut out = vec![[0u8; 4]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(j, dst)| {
        for (i, n) in dst.iter_mut().enumerate() {
            *n = encode_normal(normal_at(&t.heights, w, h, s, i, j), 1.0);
        }
    });
    out
}

/// Prepares a terrain (a stage: pure). Fails on an empty grid or one whose heights do not
/// match its size.
pub fn prepare_terrain(t: &Terrain) -> Result<PreparedTerrain, String> {
    if t.width == 0 || t.height == 0 || t.heights.len() as u64 != t.width as u64 * t.height as u64 {
        return Err(format!(
            "{} heights for a {}×{} grid",
            t.heights.len(),
            t.width,
            t.height
        ));
    }
    if let Some(k) = t.heights.iter().position(|h| !h.is_finite()) {
        return Err(format!("height {k} is not finite"));
    }
    let ((four_tap, normals), quadtree) = rayon::join(
        || {
            rayon::join(
                || four_tap(&t.heights, t.width, t.height),
                || {
                    terrain_normals(t)
                        .par_iter()
                        .map(|&n| encode_normal(n, 1.0))
                        .collect()
                },
            )
        },
        || MinMaxQuadtree::build(&t.heights, t.width, t.height),
    );
    Ok(PreparedTerrain {
        four_tap,
        normals,
        quadtree,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn terrain(w: u32, h: u32, f: impl Fn(f32, f32) -> f32, extent: [f32; 2]) -> Terrain {
        let mut t = Terrain {
            width: w,
            height: h,
            heights: Vec::new(),
            origin: [10.0, 20.0],
            extent,
            color: None,
        };
        t.heights = (0..w * h)
            .map(|k| {
                let p = t.position_unchecked(k % w, k / w);
                f(p[0], p[1])
            })
            .collect();
        t
    }

    trait Pos {
        fn position_unchecked(&self, i: u32, j: u32) -> [f32; 2];
    }
    impl Pos for Terrain {
        fn position_unchecked(&self, i: u32, j: u32) -> [f32; 2] {
            let [sx, sy] = spacing(self);
            [
                self.origin[0] + i as f32 * sx,
                self.origin[1] + j as f32 * sy,
            ]
        }
    }

    #[test]
    fn four_tap_texel_holds_the_four_heights() {
        let t = terrain(7, 5, |x, y| x * 3.0 + y * y * 0.1, [12.0, 8.0]);
        let p = prepare_terrain(&t).unwrap();
        for j in 0..5u32 {
            for i in 0..7u32 {
                let texel = p.four_tap[(j * 7 + i) as usize];
                let (i1, j1) = ((i + 1).min(6), (j + 1).min(4));
                assert_eq!(
                    texel,
                    [
                        t.sample(i, j),
                        t.sample(i1, j),
                        t.sample(i, j1),
                        t.sample(i1, j1)
                    ]
                );
            }
        }
        // Bilinear from one texel equals the model's own bilinear lookup.
        let texel = p.four_tap[(2 * 7 + 3) as usize];
        let (fx, fy) = (0.25f32, 0.75f32);
        let bil = (texel[0] * (1.0 - fx) + texel[1] * fx) * (1.0 - fy)
            + (texel[2] * (1.0 - fx) + texel[3] * fx) * fy;
        let [sx, sy] = spacing(&t);
        let want = t.height_at(10.0 + (3.0 + fx) * sx, 20.0 + (2.0 + fy) * sy);
        assert!((bil - want).abs() < 1e-4);
    }

    #[test]
    fn plane_normals_are_analytic() {
        // z = 0.5x − 0.25y: n ∝ (−0.5, 0.25, 1) everywhere, including the edges.
        let t = terrain(9, 6, |x, y| 0.5 * x - 0.25 * y, [16.0, 10.0]);
        let want = normalize([-0.5, 0.25, 1.0]);
        for n in terrain_normals(&t) {
            for k in 0..3 {
                assert!((n[k] - want[k]).abs() < 1e-5, "{n:?}");
            }
        }
        let p = prepare_terrain(&t).unwrap();
        assert_eq!(p.normals[0], encode_normal(want, 1.0));
        assert_eq!(
            p.quadtree.node(p.quadtree.levels() - 1, 0, 0),
            [t.height_range().0, t.height_range().1]
        );
    }

    #[test]
    fn bad_grids_are_rejected() {
        let mut t = terrain(3, 3, |_, _| 0.0, [2.0, 2.0]);
        t.heights.pop();
        assert!(prepare_terrain(&t).is_err());
        let mut t = terrain(3, 3, |_, _| 0.0, [2.0, 2.0]);
        t.heights[4] = f32::NAN;
        assert!(prepare_terrain(&t).unwrap_err().contains("height 4"));
    }
}
