//! Ray traversal of the sparse voxel octree: a hierarchical Amanatides–Woo DDA over the 4³ cells
//! of each node (descending into occupied cells, skipping empty ones), and the reference: a flat
//! DDA over every voxel of the grid against the leaf set.
//!
//! Rays are in voxel units (see [`super::Grid::to_grid`]). Both traversals report the first
//! occupied voxel and `t` where the ray enters it, computed by the same slab formula
//! ([`voxel_entry_t`]), so equal voxels give bit-equal `t`.

use super::svo::Svo;

/// A ray in voxel units, `p(t) = origin + t·dir` for t in [t_min, t_max].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelRay {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub t_min: f32,
    pub t_max: f32,
}

/// The first occupied voxel along a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub voxel: [u32; 3],
    pub t: f32,
}

/// Entry and exit `t` of the box [lo, hi] (slab test), unclamped.
pub fn box_interval(r: &VoxelRay, lo: [f32; 3], hi: [f32; 3]) -> (f32, f32) {
    let mut t0 = f32::NEG_INFINITY;
    let mut t1 = f32::INFINITY;
    for k in 0..3 {
        let inv = 1.0 / r.dir[k];
        let (a, b) = ((lo[k] - r.origin[k]) * inv, (hi[k] - r.origin[k]) * inv);
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        // NaN (origin on a slab plane of a parallel ray) leaves the interval unchanged.
        if a > t0 {
            t0 = a;
        }
        if b < t1 {
            t1 = b;
        }
    }
    (t0, t1)
}

/// `t` at which the ray enters voxel `v` (at least `t_min`).
pub fn voxel_entry_t(r: &VoxelRay, v: [u32; 3]) -> f32 {
    let lo = v.map(|x| x as f32);
    let hi = v.map(|x| x as f32 + 1.0);
    box_interval(r, lo, hi).0.max(r.t_min)
}

/// Per-axis DDA state over cells of size `cell` starting at `base`.
pub(crate) struct Dda {
    pub(crate) c: [i64; 3],
    step: [i64; 3],
    t_max: [f32; 3],
    t_delta: [f32; 3],
}

impl Dda {
    /// Starts in the cell holding the point at `t`, clamped into `0..n[k]` cells.
    pub(crate) fn new(r: &VoxelRay, base: [f32; 3], cell: f32, n: [i64; 3], t: f32) -> Dda {
        let mut d = Dda {
            c: [0; 3],
            step: [0; 3],
            t_max: [f32::INFINITY; 3],
            t_delta: [f32::INFINITY; 3],
        };
        for k in 0..3 {
            let p = r.origin[k] + r.dir[k] * t;
            d.c[k] = (((p - base[k]) / cell).floor() as i64).clamp(0, n[k] - 1);
            if r.dir[k] > 0.0 {
                d.step[k] = 1;
                let edge = base[k] + (d.c[k] + 1) as f32 * cell;
                d.t_max[k] = (edge - r.origin[k]) / r.dir[k];
                d.t_delta[k] = cell / r.dir[k];
            } else if r.dir[k] < 0.0 {
                d.step[k] = -1;
                let edge = base[k] + d.c[k] as f32 * cell;
                d.t_max[k] = (edge - r.origin[k]) / r.dir[k];
                d.t_delta[k] = -cell / r.dir[k];
            }
        }
        d
    }

    /// Exit `t` of the current cell.
    pub(crate) fn exit(&self) -> f32 {
        self.t_max[0].min(self.t_max[1]).min(self.t_max[2])
    }

    /// Steps to the next cell; false when it leaves `0..n`.
    pub(crate) fn advance(&mut self, n: i64) -> bool {
        let k = if self.t_max[0] <= self.t_max[1] && self.t_max[0] <= self.t_max[2] {
            0
        } else if self.t_max[1] <= self.t_max[2] {
            1
        } else {
            2
        };
        self.c[k] += self.step[k];
        self.t_max[k] += self.t_delta[k];
        (0..n).contains(&self.c[k])
    }
}

/// Morton slot of a 2-bit cell coordinate inside a 4³ node.
pub(crate) fn slot(c: [i64; 3]) -> u32 {
    let b = |v: i64, i: u32| (v as u32 >> i) & 1;
    b(c[0], 0)
        | b(c[1], 0) << 1
        | b(c[2], 0) << 2
        | b(c[0], 1) << 3
        | b(c[1], 1) << 4
        | b(c[2], 1) << 5
}

/// First occupied voxel along the ray through the octree.
pub fn trace_svo(svo: &Svo, r: &VoxelRay) -> Option<Hit> {
    let side = 4f32.powi(svo.levels as i32);
    let dims = svo.grid.dims.map(|d| d as f32);
    let (t0, t1) = box_interval(r, [0.0; 3], dims);
    let (t0, t1) = (t0.max(r.t_min), t1.min(r.t_max));
    if t0 > t1 {
        return None;
    }
    trace_node(svo, r, 0, 0, [0.0; 3], side, t0, t1)
}

/// DDA over the 4³ cells of inner node `node` (level `level`) covering `side` voxels.
#[allow(clippy::too_many_arguments)]
fn trace_node(
    svo: &Svo,
    r: &VoxelRay,
    level: usize,
    node: usize,
    base: [f32; 3],
    side: f32,
    t0: f32,
    t1: f32,
) -> Option<Hit> {
    let n = svo.nodes[node];
    let mask = n.mask();
    let cell = side / 4.0;
    let mut dda = Dda::new(r, base, cell, [4; 3], t0);
    let mut t = t0;
    loop {
        let s = slot(dda.c);
        let exit = dda.exit().min(t1);
        if mask >> s & 1 == 1 {
            let child = svo.child(&n, s) as usize;
            let cbase = [0, 1, 2].map(|k| base[k] + dda.c[k] as f32 * cell);
            let hit = if level + 1 == svo.inner_levels() {
                trace_brick(svo, r, svo.bricks[child], cbase, t, exit)
            } else {
                trace_node(svo, r, level + 1, child, cbase, cell, t, exit)
            };
            if hit.is_some() {
                return hit;
            }
        }
        if dda.exit() > t1 || !dda.advance(4) {
            return None;
        }
        t = exit;
    }
}

fn trace_brick(
    svo: &Svo,
    r: &VoxelRay,
    mask: u64,
    base: [f32; 3],
    t0: f32,
    t1: f32,
) -> Option<Hit> {
    let mut dda = Dda::new(r, base, 1.0, [4; 3], t0);
    loop {
        if mask >> slot(dda.c) & 1 == 1 {
            let v = [0, 1, 2].map(|k| (base[k] as i64 + dda.c[k]) as u32);
            if (0..3).all(|k| v[k] < svo.grid.dims[k]) {
                return Some(Hit {
                    voxel: v,
                    t: voxel_entry_t(r, v),
                });
            }
        }
        if dda.exit() > t1 || !dda.advance(4) {
            return None;
        }
    }
}

/// The reference: a flat DDA over the whole grid, testing every voxel against `occupied`.
pub fn trace_dda(dims: [u32; 3], occupied: impl Fn([u32; 3]) -> bool, r: &VoxelRay) -> Option<Hit> {
    let (t0, t1) = box_interval(r, [0.0; 3], dims.map(|d| d as f32));
    let (t0, t1) = (t0.max(r.t_min), t1.min(r.t_max));
    if t0 > t1 {
        return None;
    }
    let n = *dims.iter().max().unwrap_or(&1) as i64;
    let mut dda = Dda::new(r, [0.0; 3], 1.0, dims.map(|d| d as i64), t0);
    loop {
        let v = dda.c.map(|x| x as u32);
        if (0..3).all(|k| v[k] < dims[k]) && occupied(v) {
            return Some(Hit {
                voxel: v,
                t: voxel_entry_t(r, v),
            });
        }
        if dda.exit() > t1 || !dda.advance(n) {
            return None;
        }
    }
}
