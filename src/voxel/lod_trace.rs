//! Level-of-detail ray traversal of the sparse voxel octree: the hierarchical DDA of
//! [`super::traverse`], stopping at the first occupied cell that is no larger than the ray's
//! cone, and answering with that cell's filtered colour and normal (the `node_colors` and
//! `node_normals` of [`super::svo`]) instead of descending to its voxels.
//!
//! Levels: level 0 is the root (side 4^L voxels, L = [`Svo::levels`]), level l an inner node of
//! side 4^(L−l), level L−1 a brick (side 4), level L a single voxel (side 1).
//!
//! The rule: a ray carries a cone, its footprint at parameter t being `cone · t` voxels (with a
//! unit direction in voxel units, `cone` is the pixel's angle times the LOD scale, see
//! [`crate::render::svo_view`]). The traversal visits the occupied cells front to back as
//! [`super::traverse::trace_svo`] does; an occupied cell of side s that the DDA enters at t
//! stops the descent when `s ≤ cone · t` and its stored coverage α is at least
//! [`MIN_STOP_ALPHA`]/255 (or when it is a voxel). So the answer is the coarsest level whose
//! cells are no wider than the footprint where the ray enters them, and cone 0 gives the voxel
//! traversal exactly (same voxel, bit-equal t). The coverage floor is there because the stored
//! colours are RGBA8 premultiplied: a cell covered to α = a/255 holds its colour in steps of
//! 1/a, and a sparse coarse cell (a plane fills 1/64 of a 64³ node: a = 4; the root of a
//! landscape often rounds to a = 0) has none worth showing; such cells are descended.
//!
//! The t of the rule, and the hit's t, is where the ray enters the cell: the later of the cell's
//! own slab entry ([`box_interval`] of its box) and of the grid's entry clamped to `t_min` (for
//! a voxel, [`voxel_entry_t`] as in `trace_svo`). The descent itself follows the DDA as
//! `trace_svo` does, so cone 0 visits exactly its cells.
//!
//! Under a scale ([`trace_lod_scaled`], the instanced SVO's models): `unit` is the world side of
//! one voxel (the instance's |scale| × the model's voxel side) and t a world distance; a cell
//! stops the walk when `side · unit ≤ cone · t`, one rule for the flattened SVO (unit 1, t and
//! the cone in voxels) and the instances' octrees (t and the cone in metres).
//!
//! Alpha: a stopping cell is opaque. Its stored alpha is its coverage (the fraction of its
//! volume occupied), but the ray ends there whatever the coverage, and [`LodHit::straight_color`]
//! shows it un-premultiplied (rgb / α: the coverage-weighted mean colour of the voxels below).
//! Front-to-back accumulation would let light through sparse parents, but the coverage of a
//! surface is small at every coarse level (a plane fills 1/4 of its bricks), so coarse levels
//! would read as fog; opaque cells keep the surface's look and make the level visible as
//! blockiness. The stored values are RGBA8, so a parent's un-premultiplied colour has steps of
//! 1/(255 α), at most 1/16 with the coverage floor.

use super::svo::{Node, Svo, unpack_normal, unpack_rgba8};
use super::traverse::{Dda, VoxelRay, box_interval, slot, voxel_entry_t};

/// The stopping cell along a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LodHit {
    /// 0 (root) to L (voxel).
    pub level: u32,
    /// The cell's minimum corner in voxels.
    pub cell: [u32; 3],
    pub t: f32,
    /// The stored colour: RGBA8, linear, premultiplied (the voxel's, or the cell's filtered mean).
    pub color: u32,
    /// The stored octahedral normal.
    pub normal: u32,
    /// Where they are stored: an index into `node_colors` (level < L: the inner nodes, then the
    /// bricks) or, for a voxel (level L), into `voxel_colors`.
    pub attr: u32,
}

impl LodHit {
    /// The colour un-premultiplied (rgb / α; black where α is 0), and the coverage α.
    pub fn straight_color(&self) -> [f32; 4] {
        straight(unpack_rgba8(self.color))
    }

    /// The unit normal (zero where none is stored).
    pub fn normal(&self) -> [f32; 3] {
        unpack_normal(self.normal)
    }
}

/// rgb / α of a premultiplied colour (black where α is 0), α kept.
pub fn straight(c: [f32; 4]) -> [f32; 4] {
    if c[3] <= 0.0 {
        return [0.0; 4];
    }
    [c[0] / c[3], c[1] / c[3], c[2] / c[3], c[3]]
}

/// The least stored alpha (8-bit coverage) with which a coarse cell may end the walk; sparser
/// cells are descended whatever the cone (see the module documentation).
pub const MIN_STOP_ALPHA: u32 = 16;

/// Whether a cell with stored colour `color` (RGBA8 premultiplied) covers enough to stop on.
pub fn can_stop(color: u32) -> bool {
    color >> 24 >= MIN_STOP_ALPHA
}

/// Side in voxels of a cell of `level` in an octree of `levels` levels.
pub fn cell_side(levels: u32, level: u32) -> f32 {
    4f32.powi(levels as i32 - level as i32)
}

/// The first occupied cell along `r` at the level the cone picks (see the module documentation).
pub fn trace_lod(svo: &Svo, r: &VoxelRay, cone: f32) -> Option<LodHit> {
    trace_lod_scaled(svo, r, cone, 1.0)
}

/// [`trace_lod`] where a cell of side s voxels is `s · unit` wide for the rule `s · unit ≤ cone
/// · t` (see the module documentation): an instance's octree walked with world t and cone.
pub fn trace_lod_scaled(svo: &Svo, r: &VoxelRay, cone: f32, unit: f32) -> Option<LodHit> {
    if svo.nodes.is_empty() {
        return None;
    }
    let side = cell_side(svo.levels, 0);
    let (t0, t1) = box_interval(r, [0.0; 3], svo.grid.dims.map(|d| d as f32));
    let (t0, t1) = (t0.max(r.t_min), t1.min(r.t_max));
    if t0 > t1 {
        return None;
    }
    if side * unit <= cone * t0 && can_stop(svo.node_colors[0]) {
        return Some(cell_hit(svo, 0, 0, [0.0; 3], t0));
    }
    let walk = Walk {
        svo,
        r,
        cone,
        unit,
        t0,
    };
    walk.node(0, 0, [0.0; 3], side, t0, t1)
}

/// A hit on the filtered value `attr` (node index, or `nodes.len()` + brick index).
fn cell_hit(svo: &Svo, level: u32, attr: usize, base: [f32; 3], t: f32) -> LodHit {
    LodHit {
        level,
        cell: base.map(|b| b as u32),
        t,
        color: svo.node_colors[attr],
        normal: svo.node_normals[attr],
        attr: attr as u32,
    }
}

struct Walk<'a> {
    svo: &'a Svo,
    r: &'a VoxelRay,
    cone: f32,
    /// World side of one voxel (1 for the flattened SVO).
    unit: f32,
    /// The grid's entry, clamped to `t_min`.
    t0: f32,
}

impl Walk<'_> {
    /// DDA over the 4³ cells of inner node `node` (level `level`), as `traverse::trace_node`.
    fn node(
        &self,
        level: u32,
        node: usize,
        base: [f32; 3],
        side: f32,
        t0: f32,
        t1: f32,
    ) -> Option<LodHit> {
        let svo = self.svo;
        let n = svo.nodes[node];
        let mask = n.mask();
        let cell = side / 4.0;
        let last = level as usize + 1 == svo.inner_levels();
        let mut dda = Dda::new(self.r, base, cell, [4; 3], t0);
        let mut t = t0;
        loop {
            let s = slot(dda.c);
            let exit = dda.exit().min(t1);
            if mask >> s & 1 == 1 {
                let child = svo.child(&n, s) as usize;
                let cbase = [0, 1, 2].map(|k| base[k] + dda.c[k] as f32 * cell);
                let attr = if last { svo.nodes.len() + child } else { child };
                let stop = (self.cone > 0.0).then(|| {
                    let hi = cbase.map(|b| b + cell);
                    box_interval(self.r, cbase, hi).0.max(self.t0)
                });
                let hit = if let Some(tc) = stop
                    && cell * self.unit <= self.cone * tc
                    && can_stop(svo.node_colors[attr])
                {
                    Some(cell_hit(svo, level + 1, attr, cbase, tc))
                } else if last {
                    self.brick(&n, child, cbase, t, exit)
                } else {
                    self.node(level + 1, child, cbase, cell, t, exit)
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

    /// The voxels of brick `brick` (a child of `parent`), as `traverse::trace_brick`.
    fn brick(
        &self,
        parent: &Node,
        brick: usize,
        base: [f32; 3],
        t0: f32,
        t1: f32,
    ) -> Option<LodHit> {
        let svo = self.svo;
        let mask = svo.bricks[brick];
        // Attribute index of the brick's first voxel: the parent's, plus its earlier bricks'.
        let first = parent.first_voxel
            + svo.bricks[parent.first_child as usize..brick]
                .iter()
                .map(|b| b.count_ones())
                .sum::<u32>();
        let mut dda = Dda::new(self.r, base, 1.0, [4; 3], t0);
        loop {
            let s = slot(dda.c);
            if mask >> s & 1 == 1 {
                let v = [0, 1, 2].map(|k| (base[k] as i64 + dda.c[k]) as u32);
                if (0..3).all(|k| v[k] < svo.grid.dims[k]) {
                    let i = (first + (mask & ((1u64 << s) - 1)).count_ones()) as usize;
                    return Some(LodHit {
                        level: svo.levels,
                        cell: v,
                        t: voxel_entry_t(self.r, v),
                        color: svo.voxel_colors[i],
                        normal: svo.voxel_normals[i],
                        attr: i as u32,
                    });
                }
            }
            if dda.exit() > t1 || !dda.advance(4) {
                return None;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxel::gpu::random_rays;
    use crate::voxel::svo::voxels_to_svo;
    use crate::voxel::tests::{Rng, random_voxels};
    use crate::voxel::traverse::trace_svo;
    use crate::voxel::voxelize::{Brick, Voxels, bricks_of_keys};
    use crate::voxel::{Grid, morton_decode, morton_encode};
    use std::collections::HashMap;

    /// Random voxels with random unit normals (the shared generator's are all +Z).
    fn voxels_with_normals(rng: &mut Rng, dims: [u32; 3]) -> Voxels {
        let mut v = random_voxels(rng, dims);
        for n in &mut v.normals {
            let d = [
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            ];
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3);
            *n = d.map(|x| x / l);
        }
        v
    }

    /// [`random_rays`] with unit directions, so that t is a distance in voxels.
    fn unit_rays(dims: [u32; 3], count: usize, seed: u64) -> Vec<VoxelRay> {
        crate::voxel::lod_gpu::unit_rays(&random_rays(dims, count, seed))
    }

    /// Every voxel's straight colour and normal, by coordinate (from the voxel set, not the tree).
    fn voxel_table(v: &Voxels) -> HashMap<[u32; 3], ([f32; 4], [f32; 3])> {
        v.keys()
            .iter()
            .enumerate()
            .map(|(i, &k)| (morton_decode(k), (v.colors[i], v.normals[i])))
            .collect()
    }

    /// The brute-force filtered value of the cube `[cell, cell + side)³`: the premultiplied mean
    /// over all side³ voxels (empty ones transparent black) and the coverage-weighted normal.
    fn region_mean(
        table: &HashMap<[u32; 3], ([f32; 4], [f32; 3])>,
        cell: [u32; 3],
        side: u32,
    ) -> ([f64; 4], [f64; 3], usize) {
        let (mut c, mut n, mut count) = ([0.0f64; 4], [0.0f64; 3], 0);
        for (p, (col, nor)) in table {
            if (0..3).all(|k| p[k] >= cell[k] && p[k] < cell[k] + side) {
                count += 1;
                let a = col[3] as f64;
                for k in 0..3 {
                    c[k] += col[k] as f64 * a;
                    n[k] += nor[k] as f64 * a;
                }
                c[3] += a;
            }
        }
        let vol = (side as f64).powi(3);
        (c.map(|x| x / vol), n, count)
    }

    #[test]
    fn at_cone_zero_the_lod_trace_is_the_voxel_trace() {
        let mut rng = Rng::new(3);
        for dims in [[4, 4, 4], [37, 20, 45], [130, 17, 9]] {
            let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
            let mut hits = 0;
            for r in random_rays(dims, 4000, dims[1] as u64) {
                for cone in [0.0, 1e-9] {
                    let a = trace_lod(&svo, &r, cone);
                    let b = trace_svo(&svo, &r);
                    assert_eq!(
                        a.map(|h| (h.cell, h.t.to_bits())),
                        b.map(|h| (h.voxel, h.t.to_bits()))
                    );
                    if let Some(h) = a {
                        assert_eq!(h.level, svo.levels);
                        let i = svo.voxel_index(h.cell).unwrap();
                        assert_eq!(
                            (h.color, h.normal),
                            (svo.voxel_colors[i], svo.voxel_normals[i])
                        );
                        hits += 1;
                    }
                }
            }
            assert!(hits > 1000, "dims {dims:?}: {hits} hits");
        }
    }

    #[test]
    fn a_stopping_cell_holds_the_brute_force_mean_of_its_region() {
        let mut rng = Rng::new(8);
        let dims = [70, 40, 52];
        let v = voxels_with_normals(&mut rng, dims);
        let table = voxel_table(&v);
        let svo = voxels_to_svo(&v);
        let mut per_level = vec![0usize; svo.levels as usize + 1];
        for (i, r) in unit_rays(dims, 2000, 4).iter().enumerate() {
            let cone = [0.02f32, 0.1, 0.5, 2.0][i % 4];
            let Some(h) = trace_lod(&svo, r, cone) else {
                continue;
            };
            per_level[h.level as usize] += 1;
            let side = cell_side(svo.levels, h.level) as u32;
            assert!(h.cell.iter().all(|c| c % side == 0), "{h:?}");
            let (c, n, count) = region_mean(&table, h.cell, side);
            assert!(count > 0, "{h:?}: an empty region");
            let got = unpack_rgba8(h.color);
            for k in 0..4 {
                assert!(
                    (got[k] as f64 - c[k]).abs() <= 0.5 / 255.0 + 1e-5,
                    "{h:?}: {got:?} vs {c:?}"
                );
            }
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l > 1e-3 {
                let g = h.normal();
                let dot: f64 = (0..3).map(|k| g[k] as f64 * n[k] / l).sum();
                assert!(dot > 0.9999, "{h:?}: normal {g:?} vs {n:?}");
            }
        }
        // Every level from the 16³ nodes to the voxels answered some rays (the root and the
        // 64³ nodes of the sparse shell are below the coverage floor).
        assert!(per_level[2..].iter().all(|&n| n > 10), "{per_level:?}");
    }

    /// Index into `node_colors` of the occupied cell of `level` holding voxel `cell`.
    fn attr_of(svo: &Svo, cell: [u32; 3], level: u32) -> usize {
        let key = morton_encode(cell);
        let mut node = 0usize;
        for l in 0..level as usize {
            let slot = ((key >> (6 * (svo.levels as usize - 1 - l))) & 63) as u32;
            let child = svo.child(&svo.nodes[node], slot) as usize;
            if l + 1 == svo.inner_levels() {
                return svo.nodes.len() + child;
            }
            node = child;
        }
        node
    }

    #[test]
    fn the_level_follows_the_cone_and_coarser_cells_are_hit_no_later() {
        let mut rng = Rng::new(12);
        let dims = [64, 64, 64];
        let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
        let rays = unit_rays(dims, 3000, 9);
        for cone in [0.01f32, 0.05, 0.2, 1.0] {
            let (mut coarse, mut violations) = (0, 0);
            for r in &rays {
                let fine = trace_svo(&svo, r);
                let Some(h) = trace_lod(&svo, r, cone) else {
                    // A coarse cell holds all the voxels below it: no hit means no voxel hit.
                    assert!(fine.is_none(), "{r:?}");
                    continue;
                };
                if let Some(f) = fine {
                    assert!(h.t <= f.t * (1.0 + 1e-5) + 1e-5, "{r:?}: {h:?} after {f:?}");
                }
                let side = cell_side(svo.levels, h.level);
                // The stopping rule, recomputed from the cell's box: s ≤ cone·t, and the parent
                // (4s) was wider than the footprint where the ray entered it.
                let entry = |s: f32| {
                    let lo = h.cell.map(|c| (c as f32 / s).floor() * s);
                    let grid = box_interval(r, [0.0; 3], dims.map(|d| d as f32)).0;
                    box_interval(r, lo, lo.map(|x| x + s))
                        .0
                        .max(grid)
                        .max(r.t_min)
                };
                if h.level < svo.levels {
                    coarse += 1;
                    violations += usize::from(side > cone * entry(side) * (1.0 + 1e-5));
                    assert!(can_stop(h.color), "{h:?}: below the coverage floor");
                }
                // The parent was descended: too wide for the footprint, or too sparse.
                if h.level > 0 {
                    let parent = svo.node_colors[attr_of(&svo, h.cell, h.level - 1)];
                    violations += usize::from(
                        4.0 * side <= cone * entry(4.0 * side) * (1.0 - 1e-5) && can_stop(parent),
                    );
                }
            }
            assert_eq!(violations, 0, "cone {cone}");
            if cone >= 0.2 {
                assert!(coarse > 300, "cone {cone}: only {coarse} coarse hits");
            }
        }
    }

    /// Every voxel of `dims` below height `top`, colour `color` (a dense block).
    fn block_voxels(dims: [u32; 3], top: u32, color: [f32; 4]) -> Voxels {
        let mut keys = Vec::new();
        for z in 0..top {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    keys.push(morton_encode([x, y, z]));
                }
            }
        }
        keys.sort_unstable();
        let bricks = bricks_of_keys(keys.iter().copied());
        Voxels {
            grid: Grid {
                origin: [0.0; 3],
                voxel_size: [1.0; 3],
                dims,
            },
            bricks,
            colors: vec![color; keys.len()],
            normals: vec![[0.0, 0.0, 1.0]; keys.len()],
            skipped_triangles: 0,
            open_columns: 0,
        }
    }

    #[test]
    fn a_huge_cone_answers_with_the_root_wherever_the_ray_meets_the_grid() {
        // A block filling the lower 40 % of a 16³ root: coverage 0.4, above the floor.
        let dims = [16, 16, 16];
        let svo = voxels_to_svo(&block_voxels(dims, 7, [0.9, 0.5, 0.1, 1.0]));
        assert!(can_stop(svo.node_colors[0]));
        let mut roots = 0;
        for r in unit_rays(dims, 2000, 1) {
            let (t0, t1) = box_interval(&r, [0.0; 3], dims.map(|d| d as f32));
            let meets = t0.max(r.t_min) <= t1.min(r.t_max);
            let h = trace_lod(&svo, &r, 1e30);
            // A ray starting inside the grid has a zero footprint there and sees voxels.
            if t0 <= r.t_min {
                continue;
            }
            assert_eq!(h.is_some(), meets, "{r:?}");
            if let Some(h) = h {
                assert_eq!((h.level, h.cell, h.color), (0, [0; 3], svo.node_colors[0]));
                assert_eq!(h.t, t0.max(r.t_min));
                let c = h.straight_color();
                assert!(
                    (c[0] - 0.9).abs() < 0.01 && (c[2] - 0.1).abs() < 0.01,
                    "{c:?}"
                );
                roots += 1;
            }
        }
        assert!(roots > 400, "{roots} root hits");
    }

    #[test]
    fn a_huge_cone_stops_at_the_first_cell_dense_enough_and_never_below_the_floor() {
        let mut rng = Rng::new(6);
        let dims = [37, 20, 45];
        let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
        // The sparse shell's root is below the coverage floor, so it is never the answer.
        assert!(!can_stop(svo.node_colors[0]));
        let (mut coarse, mut hits) = (0, 0);
        for r in unit_rays(dims, 2000, 1) {
            let fine = trace_svo(&svo, &r);
            let Some(h) = trace_lod(&svo, &r, 1e30) else {
                assert!(fine.is_none(), "{r:?}");
                continue;
            };
            hits += 1;
            assert!(h.level > 0, "{h:?}");
            if h.level < svo.levels {
                coarse += 1;
                assert!(can_stop(h.color), "{h:?}");
            }
        }
        assert!(coarse > hits / 2, "{coarse} of {hits} hits coarse");
    }

    /// One brick of a 16³ grid (two levels) holding a 4 × 4 layer of half-transparent voxels.
    fn layer_brick(z: u32, color: [f32; 4]) -> Voxels {
        let mut mask = 0u64;
        for y in 4..8 {
            for x in 4..8 {
                mask |= 1 << (morton_encode([x, y, z]) & 63);
            }
        }
        Voxels {
            grid: Grid {
                origin: [0.0; 3],
                voxel_size: [1.0; 3],
                dims: [16; 3],
            },
            bricks: vec![Brick {
                key: morton_encode([4, 4, z]) >> 6,
                mask,
            }],
            colors: vec![color; 16],
            normals: vec![[0.0, 0.0, -1.0]; 16],
            skipped_triangles: 0,
            open_columns: 0,
        }
    }

    #[test]
    fn a_partly_covered_cell_is_an_opaque_hit_at_its_entry_with_its_straight_colour() {
        let color = [0.8, 0.4, 0.2, 0.5];
        let svo = voxels_to_svo(&layer_brick(6, color));
        assert_eq!(svo.levels, 2);
        let r = VoxelRay {
            origin: [6.5, 5.5, -10.0],
            dir: [0.0, 0.0, 1.0],
            t_min: 0.0,
            t_max: f32::INFINITY,
        };
        // Root (16) > 0.5·10 at the grid's entry; the brick (4) ≤ 0.5·14 at its own (z = 4).
        let h = trace_lod(&svo, &r, 0.5).unwrap();
        assert_eq!((h.level, h.cell, h.t), (1, [4, 4, 4], 14.0));
        let c = h.straight_color();
        // Coverage 16/64 of α 0.5: stored alpha 0.125; rgb un-premultiplied within 0.5/(255 α).
        assert!((c[3] - 0.125).abs() <= 0.5 / 255.0, "{c:?}");
        for k in 0..3 {
            assert!(
                (c[k] - color[k]).abs() <= 0.5 / 255.0 / c[3] + 1e-6,
                "{c:?}"
            );
        }
        assert_eq!(h.normal(), [0.0, 0.0, -1.0]);
        // A finer cone reaches the voxel layer itself at z = 6. A coarser one would take the
        // root at z = 0, but its coverage (8/4096) is below the floor: the brick again.
        let v = trace_lod(&svo, &r, 0.1).unwrap();
        assert_eq!((v.level, v.cell, v.t), (2, [6, 5, 6], 16.0));
        assert!(!can_stop(svo.node_colors[0]));
        let coarse = trace_lod(&svo, &r, 2.0).unwrap();
        assert_eq!((coarse.level, coarse.t), (1, 14.0));
        // A ray through the brick's empty lower half meets no voxel, but stops on the brick.
        let under = VoxelRay {
            origin: [-10.0, 5.5, 4.5],
            dir: [1.0, 0.0, 0.0],
            ..r
        };
        assert!(trace_svo(&svo, &under).is_none());
        let h = trace_lod(&svo, &under, 0.5).unwrap();
        assert_eq!((h.level, h.cell, h.t), (1, [4, 4, 4], 14.0));
    }
}
