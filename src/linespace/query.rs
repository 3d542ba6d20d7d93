//! Soft-shadow queries: shadow segments from a point to samples of a quad area light, answered
//! by a DDA through the N-tree that uses each node's line space to skip it (empty shaft) or, at
//! the deepest line-space level, to call it a hit (full shaft).
//!
//! Two cases the thesis leaves open are handled exactly: a segment that starts or ends inside a
//! node cannot use that node's line space (a shaft joins two boundary patches), so the DDA
//! descends; at the deepest line-space level it tests the node's triangles exactly (this is
//! where self-occlusion near the receiver is decided, with the same ray/triangle test and the
//! same t range as the exact reference). Segments entering and leaving through the same face, or
//! through a node edge or corner, descend the same way. With leaf cells marked conservatively
//! (see [`super::ntree`]) the answer errs only towards occlusion.
//!
//! Fixes of the thesis' listings: the shaft's end is the light sample (the thesis derives
//! `shaft.dest` from the light direction), end patches come from the exit point (its Algorithm 3
//! derives `endVec` from the end point), a node is skipped when the line-space test is *false*
//! (Algorithm 1 skips on true), and bits are read with a right shift.

use super::ntree::{NTree, Refine};
use crate::voxel::traverse::{Dda, VoxelRay, box_interval};
use obvhs::ray::Ray as BvhRay;
use obvhs::triangle::Triangle;

/// A quad area light: `corner + s·edge_u + t·edge_v`, s, t ∈ [0, 1], sampled on a
/// `samples × samples` grid of cell centres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AreaLight {
    pub corner: [f32; 3],
    pub edge_u: [f32; 3],
    pub edge_v: [f32; 3],
    pub samples: u32,
}

impl AreaLight {
    /// Fraction of the light's k² samples whose segment from `p` (moved `offset` off it)
    /// `occluded` lets through (1 = fully lit).
    pub fn lit_fraction(
        &self,
        p: [f32; 3],
        offset: f32,
        mut occluded: impl FnMut(&Segment) -> bool,
    ) -> f32 {
        let k = self.samples.max(1).pow(2);
        let lit = (0..k)
            .filter(|&i| !occluded(&Segment::between(p, self.sample(i), offset)))
            .count();
        lit as f32 / k as f32
    }

    /// Sample point i (row-major over the sample grid).
    pub fn sample(&self, i: u32) -> [f32; 3] {
        let k = self.samples.max(1);
        let s = ((i % k) as f32 + 0.5) / k as f32;
        let t = ((i / k) as f32 + 0.5) / k as f32;
        [0, 1, 2].map(|j| self.corner[j] + s * self.edge_u[j] + t * self.edge_v[j])
    }
}

/// A shadow segment `from + t·(to − from)`, t ∈ [t_min, t_max], in world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub from: [f32; 3],
    pub dir: [f32; 3],
    pub t_min: f32,
    pub t_max: f32,
}

impl Segment {
    /// From a receiver to a light sample, skipping `offset` metres at the receiver (against
    /// self-intersection) and stopping just before the light.
    pub fn between(from: [f32; 3], to: [f32; 3], offset: f32) -> Segment {
        let dir = [0, 1, 2].map(|k| to[k] - from[k]);
        let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2])
            .sqrt()
            .max(1e-30);
        Segment {
            from,
            dir,
            t_min: (offset / len).min(1.0),
            t_max: 1.0 - 1e-6,
        }
    }

    /// The same segment as an obvhs ray (what the exact reference and the exact tests use).
    pub fn bvh_ray(&self) -> BvhRay {
        BvhRay::new(self.from.into(), self.dir.into(), self.t_min, self.t_max)
    }
}

/// Counters of one or more queries.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct QueryStats {
    pub linespace_lookups: u64,
    pub exact_triangle_tests: u64,
    pub dda_steps: u64,
    pub nodes_visited: u64,
}

impl std::iter::Sum for QueryStats {
    /// The counters of several queries added up.
    fn sum<I: Iterator<Item = QueryStats>>(iter: I) -> QueryStats {
        iter.fold(QueryStats::default(), |a, b| QueryStats {
            linespace_lookups: a.linespace_lookups + b.linespace_lookups,
            exact_triangle_tests: a.exact_triangle_tests + b.exact_triangle_tests,
            dda_steps: a.dda_steps + b.dda_steps,
            nodes_visited: a.nodes_visited + b.nodes_visited,
        })
    }
}

/// Converts a triangle for obvhs.
pub fn to_bvh_triangle(t: &[[f32; 3]; 3]) -> Triangle {
    Triangle {
        v0: t[0].into(),
        v1: t[1].into(),
        v2: t[2].into(),
    }
}

impl NTree {
    /// The segment in leaf-cell units.
    pub(super) fn grid_ray(&self, s: &Segment) -> VoxelRay {
        VoxelRay {
            origin: [0, 1, 2].map(|k| (s.from[k] - self.origin[k]) / self.leaf_size[k]),
            dir: [0, 1, 2].map(|k| s.dir[k] / self.leaf_size[k]),
            t_min: s.t_min,
            t_max: s.t_max,
        }
    }

    /// Whether the segment may be blocked (never false when a triangle blocks it).
    pub fn segment_occluded(&self, s: &Segment, stats: &mut QueryStats) -> bool {
        self.segment_occluded_with(s, true, stats)
    }

    /// The same traversal without line spaces: every node on the way is descended and every
    /// filled leaf tested exactly (the thesis' "triangle tests" baseline; exact, no over-occlusion).
    pub fn segment_occluded_exact(&self, s: &Segment, stats: &mut QueryStats) -> bool {
        self.segment_occluded_with(s, false, stats)
    }

    fn segment_occluded_with(&self, s: &Segment, linespaces: bool, stats: &mut QueryStats) -> bool {
        let mut own = OwnTriangles { ray: s.bvh_ray() };
        self.occluded_by(s, linespaces, &mut own, stats)
    }

    /// The traversal with `leaves` deciding the leaves it refines into (the tree's own
    /// triangles, a model's triangles placed by an instance, or a top-level tree's instances).
    pub(crate) fn occluded_by<L: LeafTest>(
        &self,
        s: &Segment,
        linespaces: bool,
        leaves: &mut L,
        stats: &mut QueryStats,
    ) -> bool {
        self.occluded_by_refine(s, linespaces, self.refine, leaves, stats)
    }

    /// [`Self::occluded_by`] under the refinement mode `refine` instead of the tree's.
    pub(crate) fn occluded_by_refine<L: LeafTest>(
        &self,
        s: &Segment,
        linespaces: bool,
        refine: Refine,
        leaves: &mut L,
        stats: &mut QueryStats,
    ) -> bool {
        let r = self.grid_ray(s);
        match self.root_span(&r) {
            Some(span) => {
                self.occluded_in(&r, self.root_at(linespaces), span, refine, leaves, stats)
            }
            None => false,
        }
    }

    /// Only the exact test in the deepest-level node that holds the segment's start: the part
    /// of every query here that decides self-occlusion near the receiver, for the benchmark's
    /// lower bound (not an answer: blockers further away are ignored).
    pub fn start_node_occluded(&self, s: &Segment, stats: &mut QueryStats) -> bool {
        let r = self.grid_ray(s);
        let Some(mut span) = self.root_span(&r) else {
            return false;
        };
        if !span.start_inside {
            return false;
        }
        let n = self.n as i64;
        let mut at = self.root_at(false);
        while at.level + 1 < self.depth {
            let cell = at.side / self.n as f32;
            let dda = Dda::new(&r, at.base, cell, [n; 3], span.t0);
            let c = dda.c;
            let slot = (c[0] + n * c[1] + n * n * c[2]) as usize;
            if !self.filled(at.group, slot) {
                return false;
            }
            span.t1 = span.t1.min(dda.exit());
            at = At {
                group: self.child(at.group, slot),
                level: at.level + 1,
                base: [0, 1, 2].map(|k| at.base[k] + c[k] as f32 * cell),
                side: cell,
                linespaces: false,
            };
        }
        let mut own = OwnTriangles { ray: s.bvh_ray() };
        self.exact_occluded(&r, at.group, at.base, at.side, span, &mut own, stats)
    }

    /// The root node as a traversal position.
    pub(super) fn root_at(&self, linespaces: bool) -> At {
        At {
            group: 0,
            level: 0,
            base: [0.0; 3],
            side: self.n.pow(self.depth) as f32,
            linespaces,
        }
    }

    /// Where a grid-space segment lies in the root box; None when it misses it.
    pub(super) fn root_span(&self, r: &VoxelRay) -> Option<Span> {
        let side = self.n.pow(self.depth) as f32;
        let (te, tx) = box_interval(r, [0.0; 3], [side; 3]);
        let (t0, t1) = (te.max(r.t_min), tx.min(r.t_max));
        if t0 > t1 || te.is_nan() || tx.is_nan() {
            return None;
        }
        Some(Span {
            t0,
            t1,
            start_inside: te <= r.t_min,
            end_inside: tx >= r.t_max,
        })
    }

    /// Fraction of the light's samples that reach `p` (1 = fully lit).
    pub fn shadow(
        &self,
        p: [f32; 3],
        light: &AreaLight,
        offset: f32,
        stats: &mut QueryStats,
    ) -> f32 {
        light.lit_fraction(p, offset, |s| self.segment_occluded(s, stats))
    }

    fn occluded_in<L: LeafTest>(
        &self,
        r: &VoxelRay,
        at: At,
        span: Span,
        refine: Refine,
        leaves: &mut L,
        stats: &mut QueryStats,
    ) -> bool {
        let At {
            group,
            level,
            base,
            side,
            linespaces,
        } = at;
        let deepest = level + 1 == self.depth;
        stats.nodes_visited += 1;
        if linespaces && !span.start_inside && !span.end_inside {
            stats.linespace_lookups += 1;
            match self.shaft_full(r, group, base, side, span) {
                Some(false) => return false,
                Some(true) if deepest => {
                    return match refine {
                        Refine::Near if near_start(r, span.t0, side) => {
                            self.exact_occluded(r, group, base, side, span, leaves, stats)
                        }
                        Refine::Shaft | Refine::Near => true,
                        Refine::Cells => self.cells_crossed(r, group, base, side, span, stats),
                        Refine::Exact => {
                            self.exact_occluded(r, group, base, side, span, leaves, stats)
                        }
                    };
                }
                _ => {}
            }
        }
        if deepest {
            return self.exact_occluded(r, group, base, side, span, leaves, stats);
        }
        let n = self.n as i64;
        let cell = side / self.n as f32;
        let mut dda = Dda::new(r, base, cell, [n; 3], span.t0);
        let mut t = span.t0;
        loop {
            stats.dda_steps += 1;
            let exit = dda.exit().min(span.t1);
            let c = dda.c;
            let slot = (c[0] + n * c[1] + n * n * c[2]) as usize;
            // The group's occupancy bits (in cache) before the 8-byte entry (often not).
            // Above the deepest inner level every filled child is an inner node.
            if self.filled(group, slot) {
                let child = Span {
                    t0: t,
                    t1: exit,
                    start_inside: span.start_inside && t == span.t0,
                    end_inside: span.end_inside && dda.exit() >= span.t1,
                };
                let cb = [0, 1, 2].map(|k| base[k] + c[k] as f32 * cell);
                let at = At {
                    group: self.child(group, slot),
                    level: level + 1,
                    base: cb,
                    side: cell,
                    linespaces,
                };
                if self.occluded_in(r, at, child, refine, leaves, stats) {
                    return true;
                }
            }
            if dda.exit() >= span.t1 || !dda.advance(n) {
                return false;
            }
            t = exit;
        }
    }

    /// Whether any shaft the segment can lie in (entry and exit patches, widened by a margin
    /// near patch borders) is full; None where no line space applies (same face, node edges).
    pub(super) fn shaft_full(
        &self,
        r: &VoxelRay,
        group: u32,
        base: [f32; 3],
        side: f32,
        span: Span,
    ) -> Option<bool> {
        let cell = side / self.n as f32;
        let (fa, ua) = face_patches(r, base, cell, self.n, span.t0, true)?;
        let (fb, ub) = face_patches(r, base, cell, self.n, span.t1, false)?;
        if fa == fb {
            return None;
        }
        let layout = self.layout();
        for pa in patch_range(ua, self.n) {
            for pb in patch_range(ub, self.n) {
                if layout
                    .bit(fa, pa, fb, pb)
                    .is_some_and(|b| self.linespace_bit(group, b))
                {
                    return Some(true);
                }
            }
        }
        Some(false)
    }

    /// Exact test inside a deepest-level node: a DDA over its leaves, testing the triangles of
    /// each filled leaf the segment crosses (by `leaves`).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn exact_occluded<L: LeafTest>(
        &self,
        r: &VoxelRay,
        group: u32,
        base: [f32; 3],
        side: f32,
        span: Span,
        leaves: &mut L,
        stats: &mut QueryStats,
    ) -> bool {
        let n = self.n as i64;
        let cell = side / self.n as f32;
        let mut dda = Dda::new(r, base, cell, [n; 3], span.t0);
        loop {
            let c = dda.c;
            let slot = (c[0] + n * c[1] + n * n * c[2]) as usize;
            if self.filled(group, slot) && leaves.leaf_hit(self, self.child(group, slot), stats) {
                return true;
            }
            if dda.exit() >= span.t1 || !dda.advance(n) {
                return false;
            }
        }
    }
}

impl NTree {
    /// [`Refine::Cells`] inside a deepest-level node: whether the segment crosses a leaf that
    /// holds geometry (a DDA over the node's leaves, occupancy bits only).
    pub(super) fn cells_crossed(
        &self,
        r: &VoxelRay,
        group: u32,
        base: [f32; 3],
        side: f32,
        span: Span,
        stats: &mut QueryStats,
    ) -> bool {
        let n = self.n as i64;
        let mut dda = Dda::new(r, base, side / self.n as f32, [n; 3], span.t0);
        loop {
            stats.dda_steps += 1;
            let c = dda.c;
            if self.filled(group, (c[0] + n * c[1] + n * n * c[2]) as usize) {
                return true;
            }
            if dda.exit() >= span.t1 || !dda.advance(n) {
                return false;
            }
        }
    }
}

/// What a traversal tests in a leaf it refines into.
pub(crate) trait LeafTest {
    /// Whether the items of leaf `leaf` of `tree` block the segment.
    fn leaf_hit(&mut self, tree: &NTree, leaf: u32, stats: &mut QueryStats) -> bool;
}

/// The tree's own triangles against the segment, as obvhs tests them.
pub(crate) struct OwnTriangles {
    pub(crate) ray: BvhRay,
}

impl LeafTest for OwnTriangles {
    #[inline]
    fn leaf_hit(&mut self, tree: &NTree, leaf: u32, stats: &mut QueryStats) -> bool {
        let tris = tree.leaf_triangles(leaf);
        stats.exact_triangle_tests += tris.len() as u64;
        tris.iter().any(|&t| {
            to_bvh_triangle(&tree.triangles[t as usize]).intersect(&self.ray) <= self.ray.tmax
        })
    }
}

/// Whether the point at `t` lies within `side` (grid units) of the segment's start.
fn near_start(r: &VoxelRay, t: f32, side: f32) -> bool {
    let len = (r.dir[0] * r.dir[0] + r.dir[1] * r.dir[1] + r.dir[2] * r.dir[2]).sqrt();
    (t - r.t_min) * len < side
}

/// A node being traversed: its group, level, minimum corner and side (leaf units).
#[derive(Debug, Clone, Copy)]
pub(super) struct At {
    pub(super) group: u32,
    pub(super) level: u32,
    pub(super) base: [f32; 3],
    pub(super) side: f32,
    pub(super) linespaces: bool,
}

/// Where a segment is within a node.
#[derive(Debug, Clone, Copy)]
pub(super) struct Span {
    pub(super) t0: f32,
    pub(super) t1: f32,
    pub(super) start_inside: bool,
    pub(super) end_inside: bool,
}

/// Margin, in child cells, around patch borders and node edges.
const PATCH_MARGIN: f32 = 1e-3;

/// Face and patch coordinates (u, v in child-cell units) of the point at `t` on the node's
/// boundary: the entry face (`entry`) or the exit face. None near a node edge, where the point
/// may belong to two faces.
#[allow(clippy::needless_range_loop)]
fn face_patches(
    r: &VoxelRay,
    base: [f32; 3],
    cell: f32,
    n: u32,
    t: f32,
    entry: bool,
) -> Option<(usize, [f32; 2])> {
    let side = cell * n as f32;
    let mut best: Option<(usize, f32)> = None;
    for k in 0..3 {
        if r.dir[k] == 0.0 {
            continue;
        }
        let toward_max = (r.dir[k] > 0.0) != entry;
        let plane = base[k] + if toward_max { side } else { 0.0 };
        let tk = (plane - r.origin[k]) / r.dir[k];
        let better = match best {
            None => true,
            Some((_, tb)) => (entry && tk > tb) || (!entry && tk < tb),
        };
        if better {
            best = Some((2 * k + toward_max as usize, tk));
        }
    }
    let (f, _) = best?;
    let k = f / 2;
    let (a, b) = ((k + 1) % 3, (k + 2) % 3);
    let local = |j: usize| (r.origin[j] + r.dir[j] * t - base[j]) / cell;
    let (u, v) = (local(a), local(b));
    let nf = n as f32;
    let near_edge = |x: f32| !(PATCH_MARGIN..=nf - PATCH_MARGIN).contains(&x);
    if near_edge(u) || near_edge(v) {
        return None;
    }
    Some((f, [u, v]))
}

/// Patch indices within the margin of (u, v).
fn patch_range(uv: [f32; 2], n: u32) -> impl Iterator<Item = u32> {
    let r = |x: f32| {
        let lo = ((x - PATCH_MARGIN).floor() as i64).clamp(0, n as i64 - 1) as u32;
        let hi = ((x + PATCH_MARGIN).floor() as i64).clamp(0, n as i64 - 1) as u32;
        lo..=hi
    };
    let (ru, rv) = (r(uv[0]), r(uv[1]));
    rv.flat_map(move |v| ru.clone().map(move |u| u + n * v))
}

/// Exact shadow rays with an obvhs CWBVH (the reference and the benchmark's baseline).
pub struct ExactShadow {
    bvh: obvhs::cwbvh::CwBvh,
    tris: Vec<Triangle>,
}

impl ExactShadow {
    pub fn new(tris: &[[[f32; 3]; 3]]) -> Self {
        let tris: Vec<Triangle> = tris.iter().map(to_bvh_triangle).collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &tris,
            obvhs::BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        Self { bvh, tris }
    }

    /// Whether any triangle blocks the segment.
    pub fn occluded(&self, s: &Segment) -> bool {
        let ray = s.bvh_ray();
        !self.bvh.ray_traverse_miss(ray, |ray, id| {
            self.tris[self.bvh.primitive_indices[id] as usize].intersect(ray)
        })
    }

    /// Whether any triangle blocks the segment, testing every triangle (no BVH).
    pub fn occluded_brute_force(&self, s: &Segment) -> bool {
        let ray = s.bvh_ray();
        self.tris.iter().any(|t| t.intersect(&ray) <= ray.tmax)
    }
}
