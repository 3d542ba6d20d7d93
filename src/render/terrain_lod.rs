//! The terrain as a chunked LOD grid (seed 000 §4.7.2's camera-dependent grid, done as chunks),
//! built from the terrain section's min/max quadtree.
//!
//! The cell grid is cut into chunks of [`CHUNK`]×[`CHUNK`] cells (clipped at the far edges).
//! A chunk is drawn with a step of 2^s cells (s = 0..=log2 CHUNK): its quads join every
//! 2^s-th sample, so each quad spans exactly one node of quadtree level s. Within such a node the
//! drawn surface (between its corner samples) and the full-resolution surface both lie in the
//! node's [min, max], so the node's `max − min` bounds the vertical error; a chunk's error at
//! step s is the largest over its level-s nodes ([`ChunkGrid::errors`], 0 at s = 0).
//!
//! Per frame ([`ChunkGrid::select`]): a chunk whose box (its cells' x, y and the quadtree's
//! [min, max]) lies outside the view is culled; the others take the coarsest step whose projected
//! error `error·k/d ≤ τ` (k pixels per metre at distance 1, d the distance from the eye to the
//! box, τ the render's LOD threshold; τ = 0 gives full resolution). The rule is the mesh LOD's
//! with the instance scale 1.
//!
//! Cracks: neighbouring chunks may take different steps, so their shared edge is drawn as two
//! different polylines through the same edge samples. Each chunk hangs a skirt below its inner
//! edges (not the terrain's border): vertical quads from the edge down to its box's minimum
//! less [`SKIRT_MARGIN`] of its height range. Both polylines interpolate samples of the shared
//! edge, which lie in both chunks' [min, max], so the higher one's skirt closes the gap.

use crate::terrain::quadtree::MinMaxQuadtree;
use glam::Vec3;

/// Cells per chunk side (a power of two).
pub const CHUNK: u32 = 64;
/// Steps 2^0 ..= 2^MAX_STEP_LOG2 cells.
pub const MAX_STEP_LOG2: u32 = CHUNK.trailing_zeros();
/// Extra depth of a skirt below its chunk's minimum, as a fraction of the chunk's height range
/// (plus 1 cm).
pub const SKIRT_MARGIN: f32 = 0.05;

/// One chunk as the terrain vertex shader reads it (instance buffer, 32 bytes):
/// first cell (x, y), step log2, then the skirt's bottom height.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ChunkRecord {
    pub cell: [u32; 2],
    pub step_log2: u32,
    pub skirt_bottom: f32,
}
const _: () = assert!(size_of::<ChunkRecord>() == 16);

/// The chunks of a terrain and their errors.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkGrid {
    /// Chunks per row and per column.
    pub chunks: [u32; 2],
    /// Cells per row and per column.
    pub cells: [u32; 2],
    pub origin: [f32; 2],
    /// Metres per cell in x and y.
    pub cell_size: [f32; 2],
    /// `[min, max]` height per chunk, row-major.
    pub bounds: Vec<[f32; 2]>,
    /// Vertical error bound per chunk and step (`MAX_STEP_LOG2 + 1` per chunk).
    pub errors: Vec<f32>,
}

/// What [`ChunkGrid::select`] chose.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Selection {
    /// Chunks drawn at each step, grouped by step (`by_step[s]` the records of step 2^s).
    pub by_step: Vec<Vec<ChunkRecord>>,
    pub culled: u32,
}

impl Selection {
    /// Triangles drawn (surface and skirts).
    pub fn triangles(&self) -> u64 {
        self.by_step
            .iter()
            .enumerate()
            .map(|(s, c)| c.len() as u64 * vertices_per_chunk(s as u32) as u64 / 3)
            .sum()
    }
}

/// Vertices of one chunk drawn at step 2^s: n² quads and 4n skirt quads, n = CHUNK / 2^s, six
/// vertices each (the shader clips quads past the grid to zero area).
pub fn vertices_per_chunk(step_log2: u32) -> u32 {
    let n = CHUNK >> step_log2;
    6 * (n * n + 4 * n)
}

impl ChunkGrid {
    /// The chunks of a `width × height` sample grid over `origin`, `extent` with its quadtree.
    pub fn new(
        tree: &MinMaxQuadtree,
        (width, height): (u32, u32),
        origin: [f32; 2],
        extent: [f32; 2],
    ) -> ChunkGrid {
        let cells = [width.max(2) - 1, height.max(2) - 1];
        let chunks = [cells[0].div_ceil(CHUNK), cells[1].div_ceil(CHUNK)];
        let steps = MAX_STEP_LOG2 as usize + 1;
        let n = chunks[0] as usize * chunks[1] as usize;
        let mut bounds = vec![[f32::INFINITY, f32::NEG_INFINITY]; n];
        let mut errors = vec![0.0f32; n * steps];
        for s in 0..steps.min(tree.levels()) {
            let l = tree.level(s);
            // Level-s nodes per chunk side: CHUNK >> s.
            let per = (CHUNK >> s) as usize;
            let nodes = &tree.nodes()[l.first as usize..];
            for y in 0..l.height as usize {
                let cy = y / per;
                for x in 0..l.width as usize {
                    let [lo, hi] = nodes[y * l.width as usize + x];
                    let c = cy * chunks[0] as usize + x / per;
                    if s == 0 {
                        let b = &mut bounds[c];
                        *b = [b[0].min(lo), b[1].max(hi)];
                    } else {
                        let e = &mut errors[c * steps + s];
                        *e = e.max(hi - lo);
                    }
                }
            }
        }
        // Steps past the tree's root (grids smaller than a chunk): the whole range.
        for s in tree.levels()..steps {
            for c in 0..n {
                errors[c * steps + s] = bounds[c][1] - bounds[c][0];
            }
        }
        ChunkGrid {
            chunks,
            cells,
            origin,
            cell_size: [extent[0] / cells[0] as f32, extent[1] / cells[1] as f32],
            bounds,
            errors,
        }
    }

    /// The error bound of chunk `c` at step 2^s.
    pub fn error(&self, c: usize, s: u32) -> f32 {
        self.errors[c * (MAX_STEP_LOG2 as usize + 1) + s as usize]
    }

    /// World box of chunk (cx, cy).
    pub fn chunk_box(&self, cx: u32, cy: u32) -> (Vec3, Vec3) {
        let b = self.bounds[(cy * self.chunks[0] + cx) as usize];
        let x0 = cx * CHUNK;
        let y0 = cy * CHUNK;
        let x1 = (x0 + CHUNK).min(self.cells[0]);
        let y1 = (y0 + CHUNK).min(self.cells[1]);
        let p = |x: u32, y: u32| {
            [
                self.origin[0] + x as f32 * self.cell_size[0],
                self.origin[1] + y as f32 * self.cell_size[1],
            ]
        };
        let (a, c) = (p(x0, y0), p(x1, y1));
        (Vec3::new(a[0], a[1], b[0]), Vec3::new(c[0], c[1], b[1]))
    }

    /// The chunks to draw from `eye` within `frustum` and their steps (see the module doc).
    pub fn select(&self, frustum: &super::cull::Frustum, eye: Vec3, k: f32, tau: f32) -> Selection {
        let mut sel = Selection {
            by_step: vec![Vec::new(); MAX_STEP_LOG2 as usize + 1],
            culled: 0,
        };
        for cy in 0..self.chunks[1] {
            for cx in 0..self.chunks[0] {
                let c = (cy * self.chunks[0] + cx) as usize;
                let (lo, hi) = self.chunk_box(cx, cy);
                if !frustum.meets_box(lo, hi) {
                    sel.culled += 1;
                    continue;
                }
                let d = (eye.clamp(lo, hi) - eye).length();
                let s = (0..=MAX_STEP_LOG2)
                    .rev()
                    .find(|&s| self.error(c, s) * k <= tau * d)
                    .unwrap_or(0);
                let range = hi.z - lo.z;
                sel.by_step[s as usize].push(ChunkRecord {
                    cell: [cx * CHUNK, cy * CHUNK],
                    step_log2: s,
                    skirt_bottom: lo.z - SKIRT_MARGIN * range - 0.01,
                });
            }
        }
        sel
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: u32, h: u32, f: impl Fn(f32, f32) -> f32) -> Vec<f32> {
        (0..h)
            .flat_map(|j| (0..w).map(move |i| (i, j)))
            .map(|(i, j)| f(i as f32, j as f32))
            .collect()
    }

    /// Brute-force oracle of the error bound: the largest vertical distance between the full
    /// grid's surface and the coarse grid's, sampled at every full-resolution sample (where the
    /// full surface has its vertices), must not exceed the chunk's bound at that step.
    #[test]
    fn the_quadtree_error_bounds_the_coarse_surface_at_every_sample() {
        let (w, h) = (150u32, 97u32);
        let heights = grid(w, h, |x, y| {
            3.0 * (x * 0.21).sin() + 2.0 * (y * 0.13).cos() + 0.01 * x * y
        });
        let tree = MinMaxQuadtree::build(&heights, w, h);
        let g = ChunkGrid::new(&tree, (w, h), [0.0, 0.0], [(w - 1) as f32, (h - 1) as f32]);
        let at = |i: u32, j: u32| heights[(j.min(h - 1) * w + i.min(w - 1)) as usize];
        for cy in 0..g.chunks[1] {
            for cx in 0..g.chunks[0] {
                let c = (cy * g.chunks[0] + cx) as usize;
                for s in 0..=MAX_STEP_LOG2 {
                    let st = 1u32 << s;
                    let mut worst = 0.0f32;
                    for j in cy * CHUNK..((cy + 1) * CHUNK).min(h - 1) + 1 {
                        for i in cx * CHUNK..((cx + 1) * CHUNK).min(w - 1) + 1 {
                            // The coarse quad holding sample (i, j), clipped to the grid, split
                            // along its (0,0)–(1,1) diagonal like the full grid.
                            let i0 = (i / st * st).min(w - 1);
                            let j0 = (j / st * st).min(h - 1);
                            let i1 = (i0 + st).min(w - 1);
                            let j1 = (j0 + st).min(h - 1);
                            let u = if i1 > i0 {
                                (i - i0) as f32 / (i1 - i0) as f32
                            } else {
                                0.0
                            };
                            let v = if j1 > j0 {
                                (j - j0) as f32 / (j1 - j0) as f32
                            } else {
                                0.0
                            };
                            let (h00, h10, h01, h11) =
                                (at(i0, j0), at(i1, j0), at(i0, j1), at(i1, j1));
                            let z = if u >= v {
                                h00 + (h10 - h00) * u + (h11 - h10) * v
                            } else {
                                h00 + (h01 - h00) * v + (h11 - h01) * u
                            };
                            worst = worst.max((z - at(i, j)).abs());
                        }
                    }
                    assert!(
                        worst <= g.error(c, s) + 1e-4,
                        "chunk {cx},{cy} step {st}: {worst} > {}",
                        g.error(c, s)
                    );
                }
                assert_eq!(g.error(c, 0), 0.0);
            }
        }
    }

    #[test]
    fn near_chunks_are_fine_far_chunks_coarse_and_hidden_ones_culled() {
        let (w, h) = (513u32, 513u32);
        let heights = grid(w, h, |x, y| 4.0 * (x * 0.05).sin() * (y * 0.07).cos());
        let tree = MinMaxQuadtree::build(&heights, w, h);
        let g = ChunkGrid::new(&tree, (w, h), [0.0, 0.0], [512.0, 512.0]);
        let cam = super::super::camera::Camera::look_at(
            Vec3::new(256.0, -10.0, 20.0),
            Vec3::new(256.0, 200.0, 0.0),
            45.0,
            16.0 / 9.0,
        );
        let f = super::super::cull::Frustum::from_view_proj(cam.view_proj(), false);
        let k = 720.0 / (2.0 * (22.5f32).to_radians().tan());
        let sel = g.select(&f, cam.eye, k, 1.0);
        let drawn: usize = sel.by_step.iter().map(Vec::len).sum();
        assert_eq!(drawn as u32 + sel.culled, g.chunks[0] * g.chunks[1]);
        assert!(
            sel.culled > 0,
            "a 45° view from the south edge misses some chunks"
        );
        // Every drawn chunk meets the rule, and the next coarser step would not.
        for (s, chunks) in sel.by_step.iter().enumerate() {
            for r in chunks {
                let (cx, cy) = (r.cell[0] / CHUNK, r.cell[1] / CHUNK);
                let c = (cy * g.chunks[0] + cx) as usize;
                let (lo, hi) = g.chunk_box(cx, cy);
                let d = (cam.eye.clamp(lo, hi) - cam.eye).length();
                assert!(g.error(c, s as u32) * k <= d + 1e-3);
                if s < MAX_STEP_LOG2 as usize {
                    assert!(g.error(c, s as u32 + 1) * k > d);
                }
                assert!(r.skirt_bottom < lo.z);
            }
        }
        // τ = 0: full resolution everywhere.
        let full = g.select(&f, cam.eye, k, 0.0);
        assert_eq!(full.by_step[0].len(), drawn);
        assert!(full.triangles() > sel.triangles());
    }
}
