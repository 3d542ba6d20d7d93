//! A min/max quadtree over a height grid (seed 000 4.5.5): every node stores the lowest and
//! highest height of the terrain it covers, so a ray tracer can skip whole regions whose
//! bounding box the ray misses.
//!
//! Level 0 has one node per grid *cell* (the bilinear patch between samples (i, j) and
//! (i + 1, j + 1); a bilinear patch lies between its corners' extremes, so the node bounds it).
//! A W×H grid has (W − 1)×(H − 1) cells (at least 1×1). Level k + 1 halves each side rounding
//! up, node (x, y) covering nodes (2x..2x+1, 2y..2y+1) of level k; the last level is 1×1.
//! Node (x, y) of level k thus covers cells [x·2^k, (x+1)·2^k) × [y·2^k, (y+1)·2^k), clipped.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Size of one level and where its nodes start in the flat node array.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct QuadLevel {
    pub width: u32,
    pub height: u32,
    pub first: u64,
}

/// The min/max quadtree: levels finest first, nodes `[min, max]` row-major per level.
#[derive(Debug, Clone, PartialEq)]
pub struct MinMaxQuadtree {
    levels: Vec<QuadLevel>,
    nodes: Vec<[f32; 2]>,
}

impl MinMaxQuadtree {
    /// Builds the tree over `heights` (row-major, `width × height` samples).
    pub fn build(heights: &[f32], width: u32, height: u32) -> Self {
        assert_eq!(
            heights.len() as u64,
            width as u64 * height as u64,
            "grid size"
        );
        let (cw, ch) = ((width.max(2) - 1), (height.max(2) - 1));
        let (w, h) = (width as usize, height as usize);
        let at = |i: usize, j: usize| heights[j.min(h - 1) * w + i.min(w - 1)];
        let mut cells = vec![[0.0f32; 2]; cw as usize * ch as usize];
        cells
            .par_chunks_mut(cw as usize)
            .enumerate()
            .for_each(|(j, dst)| {
                for (i, m) in dst.iter_mut().enumerate() {
                    let c = [at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1)];
                    *m = [
                        c[0].min(c[1]).min(c[2].min(c[3])),
                        c[0].max(c[1]).max(c[2].max(c[3])),
                    ];
                }
            });
        let mut levels = vec![QuadLevel {
            width: cw,
            height: ch,
            first: 0,
        }];
        let mut nodes = cells;
        while let Some(&l) = levels.last() {
            if l.width == 1 && l.height == 1 {
                break;
            }
            let next = QuadLevel {
                width: l.width.div_ceil(2),
                height: l.height.div_ceil(2),
                first: nodes.len() as u64,
            };
            let parent = reduce_level(&nodes[l.first as usize..], l, next);
            nodes.extend(parent);
            levels.push(next);
        }
        MinMaxQuadtree { levels, nodes }
    }

    /// Rebuilds from stored parts, checking that they describe a tree.
    pub fn from_parts(levels: Vec<QuadLevel>, nodes: Vec<[f32; 2]>) -> Result<Self, String> {
        let mut first = 0u64;
        for (k, l) in levels.iter().enumerate() {
            let ok_size = match k.checked_sub(1).map(|p| levels[p]) {
                None => l.width >= 1 && l.height >= 1,
                Some(p) => l.width == p.width.div_ceil(2) && l.height == p.height.div_ceil(2),
            };
            if !ok_size || l.first != first {
                return Err(format!("quadtree level {k} does not follow its parent"));
            }
            first += l.width as u64 * l.height as u64;
        }
        let top_ok = levels.last().is_some_and(|l| l.width == 1 && l.height == 1);
        if !top_ok || first != nodes.len() as u64 {
            return Err(format!(
                "quadtree levels cover {first} nodes, the array has {}",
                nodes.len()
            ));
        }
        Ok(MinMaxQuadtree { levels, nodes })
    }

    /// Number of levels (finest = 0, root = `levels() − 1`).
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// Size and offset of level `k`.
    pub fn level(&self, k: usize) -> QuadLevel {
        self.levels[k]
    }

    /// All level descriptors.
    pub fn level_table(&self) -> &[QuadLevel] {
        &self.levels
    }

    /// Every node, all levels concatenated.
    pub fn nodes(&self) -> &[[f32; 2]] {
        &self.nodes
    }

    /// `[min, max]` of node (x, y) of level k.
    pub fn node(&self, k: usize, x: u32, y: u32) -> [f32; 2] {
        let l = self.levels[k];
        self.nodes[(l.first + y as u64 * l.width as u64 + x as u64) as usize]
    }

    /// `[min, max]` over the cells `[x0, x1) × [y0, y1)` (clipped to the grid), i.e. over the
    /// samples `[x0, x1] × [y0, y1]`. An empty window gives `[+∞, −∞]`.
    pub fn query(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> [f32; 2] {
        let l0 = self.levels[0];
        let (x1, y1) = (x1.min(l0.width), y1.min(l0.height));
        let mut acc = [f32::INFINITY, f32::NEG_INFINITY];
        if x0 < x1 && y0 < y1 {
            let root = self.levels.len() - 1;
            self.query_node(root, 0, 0, [x0, y0, x1, y1], &mut acc);
        }
        acc
    }

    fn query_node(&self, k: usize, x: u32, y: u32, win: [u32; 4], acc: &mut [f32; 2]) {
        let l = self.levels[k];
        if x >= l.width || y >= l.height {
            return;
        }
        let span = 1u32 << k;
        let (cx0, cy0) = (x * span, y * span);
        let (cx1, cy1) = (cx0.saturating_add(span), cy0.saturating_add(span));
        if cx1 <= win[0] || cy1 <= win[1] || cx0 >= win[2] || cy0 >= win[3] {
            return;
        }
        let l0 = self.levels[0];
        let inside = cx0 >= win[0]
            && cy0 >= win[1]
            && cx1.min(l0.width) <= win[2]
            && cy1.min(l0.height) <= win[3];
        if inside || k == 0 {
            let [lo, hi] = self.node(k, x, y);
            acc[0] = acc[0].min(lo);
            acc[1] = acc[1].max(hi);
            return;
        }
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            self.query_node(k - 1, 2 * x + dx, 2 * y + dy, win, acc);
        }
    }
}

fn reduce_level(child: &[[f32; 2]], c: QuadLevel, p: QuadLevel) -> Vec<[f32; 2]> {
    let (cw, chh) = (c.width as usize, c.height as usize);
    let mut out = vec![[0.0f32; 2]; p.width as usize * p.height as usize];
    out.par_chunks_mut(p.width as usize)
        .enumerate()
        .for_each(|(y, dst)| {
            for (x, m) in dst.iter_mut().enumerate() {
                *m = [f32::INFINITY, f32::NEG_INFINITY];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (cx, cy) = (2 * x + dx, 2 * y + dy);
                    if cx < cw && cy < chh {
                        let n = child[cy * cw + cx];
                        *m = [m[0].min(n[0]), m[1].max(n[1])];
                    }
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::rng::Rng;

    fn brute(h: &[f32], w: u32, x0: u32, y0: u32, x1: u32, y1: u32) -> [f32; 2] {
        let mut m = [f32::INFINITY, f32::NEG_INFINITY];
        for j in y0..=y1 {
            for i in x0..=x1 {
                let v = h[(j * w + i) as usize];
                m = [m[0].min(v), m[1].max(v)];
            }
        }
        m
    }

    #[test]
    fn queries_equal_brute_force_on_random_windows() {
        let mut rng = Rng::new(7);
        for &(w, h) in &[(2u32, 2u32), (17, 9), (64, 64), (33, 100)] {
            let heights: Vec<f32> = (0..w * h)
                .map(|_| rng.below(10_000) as f32 * 0.01 - 20.0)
                .collect();
            let t = MinMaxQuadtree::build(&heights, w, h);
            assert_eq!(t.level(t.levels() - 1).width, 1);
            // The root bounds everything.
            assert_eq!(
                t.node(t.levels() - 1, 0, 0),
                brute(&heights, w, 0, 0, w - 1, h - 1)
            );
            for _ in 0..300 {
                let (a, b) = (rng.below(w - 1), rng.below(w - 1));
                let (c, d) = (rng.below(h - 1), rng.below(h - 1));
                let (x0, x1) = (a.min(b), a.max(b) + 1);
                let (y0, y1) = (c.min(d), c.max(d) + 1);
                assert_eq!(
                    t.query(x0, y0, x1, y1),
                    brute(&heights, w, x0, y0, x1, y1),
                    "{w}×{h} window {x0},{y0}..{x1},{y1}"
                );
            }
            // Every node of every level against brute force over its cells.
            for k in 0..t.levels() {
                let l = t.level(k);
                for y in 0..l.height {
                    for x in 0..l.width {
                        let s = 1u32 << k;
                        let (x1, y1) = (((x + 1) * s).min(w - 1), ((y + 1) * s).min(h - 1));
                        assert_eq!(t.node(k, x, y), brute(&heights, w, x * s, y * s, x1, y1));
                    }
                }
            }
            let back =
                MinMaxQuadtree::from_parts(t.level_table().to_vec(), t.nodes().to_vec()).unwrap();
            assert_eq!(back, t);
        }
    }

    #[test]
    fn empty_window_and_bad_parts() {
        let t = MinMaxQuadtree::build(&[1.0, 2.0, 3.0, 4.0], 2, 2);
        assert_eq!(t.levels(), 1);
        assert_eq!(t.query(1, 0, 1, 1), [f32::INFINITY, f32::NEG_INFINITY]);
        assert!(MinMaxQuadtree::from_parts(t.level_table().to_vec(), vec![]).is_err());
    }
}
