//! Grouped soft-shadow queries (CPU only): the S² segments from one receiver p to the samples
//! of a quad light lie in the pyramid conv(p, light quad), and one traversal of the N-tree with
//! that pyramid answers them together when it can prove the pyramid (nearly) empty.
//!
//! The traversal enters every filled child the pyramid may overlap (box outside one of the
//! pyramid's planes: skipped). A child that holds neither p nor part of the light, and whose
//! planes are not within a margin of p (a segment lying in a node's face plane has no shaft), is
//! skipped when every line-space pair (entry patch, exit patch) the pyramid can touch reads empty:
//! entry faces are the faces p lies beyond, exit faces those some light point lies beyond, and
//! the patches of a face are those within a margin of the bounding rectangle of the pyramid's
//! cross-section with the face plane. Otherwise an inner child is descended; a deepest-level
//! child that is not empty aborts the grouped answer (the pyramid may be partly blocked there).
//! In the nodes that hold p or the light the traversal reaches the leaves: their triangles are
//! kept unless they lie outside a pyramid plane or their own plane separates them from the
//! truncated pyramid (the segments start `offset` away from p, so the receiver's own triangle
//! never blocks). The few that remain are tested exactly against every segment, with the
//! reference's ray/triangle test and t range.
//!
//! So an answer that is not aborted is exact: a triangle that blocks a segment lies in a filled
//! cell the pyramid overlaps, which no empty line-space pair can skip, so it is among the
//! tested triangles. Aborted receivers fall back to [`NTree::segment_occluded`] per segment.
//! Hence per segment: exact-lit ⊇ grouped-lit ⊇ per-segment-lit (tests in `tests.rs`).

use super::linespace::{FACES, face_axis, face_side};
use super::ntree::NTree;
use super::query::{AreaLight, QueryStats, Segment, to_bvh_triangle};

/// Most line-space pairs one node's check reads before it descends instead.
const MAX_PAIRS: usize = 256;

/// Most (leaf, triangle) entries gathered before the grouped answer gives up.
const MAX_GATHERED: usize = 512;
/// Most triangles tested exactly against every segment before the grouped answer gives up.
const MAX_EXACT: usize = 48;
/// Margin of the box and patch tests, in leaf cells (box tests) or child cells (patches).
const MARGIN: f64 = 1e-3;

/// Counters of grouped queries.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GroupStats {
    /// Receivers answered by one pyramid traversal.
    pub proven: u64,
    /// Receivers that fell back to per-segment queries.
    pub fallbacks: u64,
    /// Line-space pairs read by pyramid checks.
    pub pair_lookups: u64,
    /// Exact segment/triangle tests of proven receivers.
    pub exact_tests: u64,
    /// Per-segment counters of the fallbacks.
    pub per_segment: QueryStats,
}

/// The pyramid conv(apex, quad) in leaf-cell units (f64): its bounding box and its planes
/// (outward normal, offset), four sides and the light plane.
#[derive(Debug, Clone)]
struct Pyramid {
    apex: [f64; 3],
    corners: [[f64; 3]; 4],
    lo: [f64; 3],
    hi: [f64; 3],
    planes: Vec<([f64; 3], f64)>,
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl Pyramid {
    fn new(apex: [f64; 3], corners: [[f64; 3]; 4]) -> Pyramid {
        let mut lo = apex;
        let mut hi = apex;
        for c in &corners {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        let centroid = [0, 1, 2].map(|k| corners.iter().map(|c| c[k]).sum::<f64>() / 4.0);
        let mut planes = Vec::with_capacity(5);
        let mut add = |nrm: [f64; 3], at: [f64; 3]| {
            let len = dot(nrm, nrm).sqrt();
            if len > 0.0 {
                let nrm = nrm.map(|x| x / len);
                // Orient outward: the inner reference point lies on the negative side.
                let inner = [0, 1, 2].map(|k| 0.5 * (apex[k] + centroid[k]));
                let s = if dot(nrm, sub(inner, at)) > 0.0 {
                    -1.0
                } else {
                    1.0
                };
                let nrm = nrm.map(|x| x * s);
                planes.push((nrm, dot(nrm, at)));
            }
        };
        for i in 0..4 {
            let (a, b) = (corners[i], corners[(i + 1) % 4]);
            add(cross(sub(a, apex), sub(b, apex)), apex);
        }
        add(
            cross(sub(corners[1], corners[0]), sub(corners[3], corners[0])),
            corners[0],
        );
        Pyramid {
            apex,
            corners,
            lo,
            hi,
            planes,
        }
    }

    /// Whether the box may overlap the pyramid (false only when a plane separates them).
    fn may_overlap(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        if (0..3).any(|k| lo[k] > self.hi[k] + MARGIN || hi[k] < self.lo[k] - MARGIN) {
            return false;
        }
        self.planes.iter().all(|(nrm, d)| {
            let near = (0..3)
                .map(|k| nrm[k] * if nrm[k] > 0.0 { lo[k] } else { hi[k] })
                .sum::<f64>();
            near - d <= MARGIN
        })
    }

    /// The 8 edges: apex to each corner, then the quad's sides.
    fn edges(&self) -> [([f64; 3], [f64; 3]); 8] {
        let c = self.corners;
        [
            (self.apex, c[0]),
            (self.apex, c[1]),
            (self.apex, c[2]),
            (self.apex, c[3]),
            (c[0], c[1]),
            (c[1], c[2]),
            (c[2], c[3]),
            (c[3], c[0]),
        ]
    }

    /// Bounding rectangle, on axes (k+1) mod 3 and (k+2) mod 3, of the part of the pyramid in
    /// the slab c0 ≤ x_k ≤ c1: its sections with both planes and its vertices between them.
    fn slab(&self, k: usize, c0: f64, c1: f64) -> Option<[f64; 4]> {
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let mut r = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut grow = |q: [f64; 4]| {
            r = [
                r[0].min(q[0]),
                r[1].min(q[1]),
                r[2].max(q[2]),
                r[3].max(q[3]),
            ];
        };
        for c in [c0, c1] {
            if let Some(q) = self.section(k, c, a, b) {
                grow(q);
            }
        }
        for v in std::iter::once(&self.apex).chain(&self.corners) {
            if v[k] >= c0 && v[k] <= c1 {
                grow([v[a], v[b], v[a], v[b]]);
            }
        }
        (r[0] <= r[2]).then_some(r)
    }

    /// Bounding rectangle, on axes a and b, of the pyramid's cross-section with the plane
    /// x_k = c; None when the pyramid does not reach the plane.
    fn section(&self, k: usize, c: f64, a: usize, b: usize) -> Option<[f64; 4]> {
        let mut r = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut put = |p: [f64; 3]| {
            r = [
                r[0].min(p[a]),
                r[1].min(p[b]),
                r[2].max(p[a]),
                r[3].max(p[b]),
            ];
        };
        for (p, q) in self.edges() {
            let (dp, dq) = (p[k] - c, q[k] - c);
            if dp == 0.0 {
                put(p);
            }
            if dq == 0.0 {
                put(q);
            }
            if dp * dq < 0.0 {
                let s = dp / (dp - dq);
                put([0, 1, 2].map(|j| p[j] + s * (q[j] - p[j])));
            }
        }
        (r[0] <= r[2]).then_some(r)
    }
}

/// Per-receiver state of a pyramid traversal.
struct Walk<'a> {
    pyr: &'a Pyramid,
    /// Bounding box of the light quad (leaf cells).
    light_lo: [f64; 3],
    light_hi: [f64; 3],
    gathered: Vec<u32>,
    pair_lookups: u64,
    /// The axis along which the pyramid is longest (children are walked in layers across it).
    layer_axis: usize,
}

/// Outcome of one node: proven free so far, or give up.
type Flow = Result<(), ()>;

impl NTree {
    /// Whether each segment from `p` to the light's samples is blocked: one pyramid traversal
    /// when it proves the pyramid free but for a few exactly tested triangles, else the
    /// per-segment line-space answers. Segment i goes to `light.sample(i)`, as in
    /// [`NTree::shadow`].
    pub fn shadow_segments(
        &self,
        p: [f32; 3],
        light: &AreaLight,
        offset: f32,
        stats: &mut GroupStats,
    ) -> Vec<bool> {
        let k = light.samples.max(1).pow(2);
        let segs: Vec<Segment> = (0..k)
            .map(|i| Segment::between(p, light.sample(i), offset))
            .collect();
        // Probe: the segment to the sample nearest the light's centre, per segment. Blocked
        // means the pyramid is not empty: no traversal is spent on proving it.
        let s = light.samples.max(1);
        let probe = (s / 2 * s + s / 2) as usize;
        let probe_hit = self.segment_occluded(&segs[probe], &mut stats.per_segment);
        if !probe_hit {
            if let Some(hits) = self.shadow_pyramid(p, light, offset, &segs, stats) {
                stats.proven += 1;
                return hits;
            }
        }
        stats.fallbacks += 1;
        segs.iter()
            .enumerate()
            .map(|(i, seg)| {
                i == probe && probe_hit
                    || i != probe && self.segment_occluded(seg, &mut stats.per_segment)
            })
            .collect()
    }

    /// The grouped answer, or None where the pyramid is not proven (nearly) empty.
    fn shadow_pyramid(
        &self,
        p: [f32; 3],
        light: &AreaLight,
        offset: f32,
        segs: &[Segment],
        stats: &mut GroupStats,
    ) -> Option<Vec<bool>> {
        let grid = |w: [f32; 3]| {
            [0, 1, 2].map(|k| (w[k] as f64 - self.origin[k] as f64) / self.leaf_size[k] as f64)
        };
        let world = [0, 1, 2, 3].map(|i| corners_world(light, i));
        let corners = world.map(grid);
        let pyr = Pyramid::new(grid(p), corners);
        let mut light_lo = corners[0];
        let mut light_hi = corners[0];
        for q in &corners {
            for k in 0..3 {
                light_lo[k] = light_lo[k].min(q[k]);
                light_hi[k] = light_hi[k].max(q[k]);
            }
        }
        let mut walk = Walk {
            pyr: &pyr,
            light_lo,
            light_hi,
            gathered: Vec::new(),
            pair_lookups: 0,
            layer_axis: (0..3)
                .max_by(|&i, &j| (pyr.hi[i] - pyr.lo[i]).total_cmp(&(pyr.hi[j] - pyr.lo[j])))
                .unwrap_or(2),
        };
        let side = self.n.pow(self.depth) as f64;
        let flow = if pyr.may_overlap([0.0; 3], [side; 3]) {
            self.walk_node(&mut walk, 0, 0, [0.0; 3], side)
        } else {
            Ok(())
        };
        stats.pair_lookups += walk.pair_lookups;
        flow.ok()?;
        let mut tris = walk.gathered;
        tris.sort_unstable();
        tris.dedup();
        let ps = p.map(|x| x as f64);
        let world_corners = world.map(|q| q.map(|x| x as f64));
        tris.retain(|&t| {
            let tri = self.triangles[t as usize].map(|q| q.map(|x| x as f64));
            !separated(&tri, ps, &world_corners, offset as f64, &pyr, self)
        });
        if tris.len() > MAX_EXACT {
            return None;
        }
        stats.exact_tests += (tris.len() * segs.len()) as u64;
        Some(
            segs.iter()
                .map(|s| {
                    let ray = s.bvh_ray();
                    tris.iter().any(|&t| {
                        to_bvh_triangle(&self.triangles[t as usize]).intersect(&ray) <= ray.tmax
                    })
                })
                .collect(),
        )
    }

    /// Walks the children of inner node `g` (level `level`, minimum corner `base`, side in
    /// leaf cells) that the pyramid may overlap.
    fn walk_node(&self, w: &mut Walk, g: u32, level: u32, base: [f64; 3], side: f64) -> Flow {
        let n = self.n as i64;
        let cell = side / self.n as f64;
        let leaves = level + 1 == self.depth;
        // Layers across the pyramid's longest axis, each with the rectangle of the pyramid's
        // part in that layer (a wide pyramid's bounding box would hold most of the node).
        let k = w.layer_axis;
        let (a, b) = ((k + 1) % 3, (k + 2) % 3);
        let cells = |lo: f64, hi: f64, base: f64| {
            let i = ((lo - MARGIN - base) / cell).floor() as i64;
            let j = ((hi + MARGIN - base) / cell).floor() as i64;
            i.max(0)..=j.min(n - 1)
        };
        for i in cells(w.pyr.lo[k], w.pyr.hi[k], base[k]) {
            let c0 = base[k] + i as f64 * cell;
            let Some(r) = w.pyr.slab(k, c0 - MARGIN, c0 + cell + MARGIN) else {
                continue;
            };
            for j in cells(r[1], r[3], base[b]) {
                for l in cells(r[0], r[2], base[a]) {
                    let mut c = [0i64; 3];
                    c[k] = i;
                    c[a] = l;
                    c[b] = j;
                    let [x, y, z] = c;
                    let slot = (x + n * y + n * n * z) as usize;
                    if !self.filled(g, slot) {
                        continue;
                    }
                    let lo = [x, y, z].map(|c| c as f64);
                    let lo = [0, 1, 2].map(|k| base[k] + lo[k] * cell);
                    let hi = lo.map(|v| v + cell);
                    if !w.pyr.may_overlap(lo, hi) {
                        continue;
                    }
                    let e = self.nodes[1 + g as usize * self.n3() + slot];
                    if leaves {
                        w.gathered.extend_from_slice(self.leaf_triangles(&e));
                        if w.gathered.len() > MAX_GATHERED {
                            return Err(());
                        }
                        continue;
                    }
                    self.walk_child(w, e.group(), level + 1, lo, cell)?;
                }
            }
        }
        Ok(())
    }

    /// One inner child: skipped when its line space proves the pyramid's shafts empty,
    /// descended where it holds p or the light (or p lies near its planes), else descended
    /// above the deepest level and given up at it.
    fn walk_child(&self, w: &mut Walk, g: u32, level: u32, lo: [f64; 3], side: f64) -> Flow {
        let hi = lo.map(|v| v + side);
        let near = |x: f64, a: f64, b: f64| x > a - MARGIN && x < b + MARGIN;
        let apex = w.pyr.apex;
        let holds_light =
            (0..3).all(|k| w.light_lo[k] < hi[k] + MARGIN && w.light_hi[k] > lo[k] - MARGIN);
        let on_plane = (0..3).any(|k| near(apex[k], lo[k], lo[k]) || near(apex[k], hi[k], hi[k]));
        // Deepest-level nodes next to p are searched leaf by leaf: the surface p lies on
        // passes through them, so their shafts near p read full.
        let reach = if level + 1 == self.depth { side } else { 0.0 };
        let holds_apex = (0..3).all(|k| near(apex[k], lo[k] - reach, hi[k] + reach));
        if !holds_light && !on_plane && !holds_apex {
            let e = self.pyramid_shafts_empty(w, g, lo, side);
            if e == Some(true) {
                return Ok(());
            }
            if level + 1 == self.depth {
                return Err(());
            }
        }
        self.walk_node(w, g, level, lo, side)
    }

    /// Whether every (entry patch, exit patch) pair the pyramid can touch reads empty in the
    /// line space of group g (node at `lo`, side `side`); None when there are too many pairs.
    fn pyramid_shafts_empty(&self, w: &mut Walk, g: u32, lo: [f64; 3], side: f64) -> Option<bool> {
        let n = self.n;
        let cell = side / n as f64;
        let hi = lo.map(|v| v + side);
        let pyr = w.pyr;
        let mut entry: Vec<(usize, [u32; 4])> = Vec::with_capacity(3);
        let mut exit: Vec<(usize, [u32; 4])> = Vec::with_capacity(3);
        let qmin = [0, 1, 2].map(|k| {
            pyr.corners
                .iter()
                .map(|c| c[k])
                .fold(f64::INFINITY, f64::min)
        });
        let qmax = [0, 1, 2].map(|k| {
            pyr.corners
                .iter()
                .map(|c| c[k])
                .fold(f64::NEG_INFINITY, f64::max)
        });
        for f in 0..FACES {
            let k = face_axis(f);
            let max_side = face_side(f) == 1;
            let plane = if max_side { hi[k] } else { lo[k] };
            let is_entry = if max_side {
                pyr.apex[k] > plane
            } else {
                pyr.apex[k] < plane
            };
            let is_exit = if max_side {
                qmax[k] > plane
            } else {
                qmin[k] < plane
            };
            if !is_entry && !is_exit {
                continue;
            }
            let (a, b) = ((k + 1) % 3, (k + 2) % 3);
            let Some(r) = pyr.section(k, plane, a, b) else {
                continue;
            };
            let to_patch = |x: f64, base: f64| ((x - base) / cell).floor();
            let (ua, ub) = (
                to_patch(r[0] - MARGIN * cell, lo[a]),
                to_patch(r[2] + MARGIN * cell, lo[a]),
            );
            let (va, vb) = (
                to_patch(r[1] - MARGIN * cell, lo[b]),
                to_patch(r[3] + MARGIN * cell, lo[b]),
            );
            let nf = n as f64;
            if ub < 0.0 || vb < 0.0 || ua >= nf || va >= nf {
                continue;
            }
            let clamp = |x: f64| x.clamp(0.0, nf - 1.0) as u32;
            let rect = [clamp(ua), clamp(va), clamp(ub), clamp(vb)];
            if is_entry {
                entry.push((f, rect));
            }
            if is_exit {
                exit.push((f, rect));
            }
        }
        let layout = self.layout();
        let mut lookups = 0usize;
        for (fa, ra) in &entry {
            for pa in rect_patches(ra, n) {
                let quad = patch_corners(*fa, pa, n, lo, cell);
                let (plo, phi) = quad_box(&quad);
                if !pyr.may_overlap(plo, phi) {
                    continue;
                }
                for (fb, rb) in exit.iter().filter(|(fb, _)| fb != fa) {
                    let r =
                        project_patch(pyr.apex, &quad, *fb, lo, side, cell, n).map_or(*rb, |p| {
                            [
                                p[0].max(rb[0]),
                                p[1].max(rb[1]),
                                p[2].min(rb[2]),
                                p[3].min(rb[3]),
                            ]
                        });
                    if r[0] > r[2] || r[1] > r[3] {
                        continue;
                    }
                    lookups += ((r[2] - r[0] + 1) * (r[3] - r[1] + 1)) as usize;
                    if lookups > MAX_PAIRS {
                        w.pair_lookups += lookups as u64;
                        return None;
                    }
                    for pb in rect_patches(&r, n) {
                        if layout
                            .bit(*fa, pa, *fb, pb)
                            .is_some_and(|b| self.linespace_bit(g, b))
                        {
                            w.pair_lookups += lookups as u64;
                            return Some(false);
                        }
                    }
                }
            }
        }
        w.pair_lookups += lookups as u64;
        Some(true)
    }
}

/// The four corners (leaf cells) of patch `p` of face `f` of the node at `lo` with child cells
/// of `cell`.
fn patch_corners(f: usize, p: u32, n: u32, lo: [f64; 3], cell: f64) -> [[f64; 3]; 4] {
    let k = face_axis(f);
    let (a, b) = ((k + 1) % 3, (k + 2) % 3);
    let (u, v) = ((p % n) as f64, (p / n) as f64);
    let plane = lo[k] + face_side(f) as f64 * n as f64 * cell;
    [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)].map(|(du, dv)| {
        let mut c = [0.0; 3];
        c[k] = plane;
        c[a] = lo[a] + (u + du) * cell;
        c[b] = lo[b] + (v + dv) * cell;
        c
    })
}

fn quad_box(q: &[[f64; 3]; 4]) -> ([f64; 3], [f64; 3]) {
    let lo = [0, 1, 2].map(|k| q.iter().map(|c| c[k]).fold(f64::INFINITY, f64::min));
    let hi = [0, 1, 2].map(|k| q.iter().map(|c| c[k]).fold(f64::NEG_INFINITY, f64::max));
    (lo, hi)
}

/// Patch rectangle [u0, v0, u1, v1] of face `f` that the rays from `apex` through the patch
/// `quad` can reach (its central projection, widened by the margin); None when a corner's ray
/// does not reach the face plane (the projection is unbounded: every patch).
fn project_patch(
    apex: [f64; 3],
    quad: &[[f64; 3]; 4],
    f: usize,
    lo: [f64; 3],
    side: f64,
    cell: f64,
    n: u32,
) -> Option<[u32; 4]> {
    let k = face_axis(f);
    let (a, b) = ((k + 1) % 3, (k + 2) % 3);
    let plane = lo[k] + face_side(f) as f64 * side;
    let mut r = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for c in quad {
        let d = c[k] - apex[k];
        let s = (plane - apex[k]) / d;
        if d == 0.0 || !(s > 0.0) || !s.is_finite() {
            return None;
        }
        let (pu, pv) = (
            apex[a] + s * (c[a] - apex[a]),
            apex[b] + s * (c[b] - apex[b]),
        );
        r = [r[0].min(pu), r[1].min(pv), r[2].max(pu), r[3].max(pv)];
    }
    let nf = n as f64;
    let to = |x: f64, base: f64| (((x - base) / cell).floor()).clamp(-1.0, nf);
    let (u0, u1) = (
        to(r[0] - MARGIN * cell, lo[a]),
        to(r[2] + MARGIN * cell, lo[a]),
    );
    let (v0, v1) = (
        to(r[1] - MARGIN * cell, lo[b]),
        to(r[3] + MARGIN * cell, lo[b]),
    );
    if u1 < 0.0 || v1 < 0.0 || u0 >= nf || v0 >= nf {
        return Some([1, 1, 0, 0]);
    }
    let c = |x: f64| x.clamp(0.0, nf - 1.0) as u32;
    Some([c(u0), c(v0), c(u1), c(v1)])
}

/// Patch indices of a rectangle [u0, v0, u1, v1] (inclusive).
fn rect_patches(r: &[u32; 4], n: u32) -> impl Iterator<Item = u32> + '_ {
    (r[1]..=r[3]).flat_map(move |v| (r[0]..=r[2]).map(move |u| u + n * v))
}

/// Light corner i (0: corner, 1: +u, 2: +u+v, 3: +v), world space.
fn corners_world(l: &AreaLight, i: usize) -> [f32; 3] {
    let (su, sv) = ([0.0, 1.0, 1.0, 0.0][i], [0.0, 0.0, 1.0, 1.0][i]);
    [0, 1, 2].map(|k| l.corner[k] + su * l.edge_u[k] + sv * l.edge_v[k])
}

/// Whether a triangle (world, f64) cannot block any segment from `p` to the light quad that
/// starts `offset` from p: all its vertices beyond one pyramid plane (grid units), or its own
/// plane separating the light from the segments' starts.
fn separated(
    tri: &[[f64; 3]; 3],
    p: [f64; 3],
    light: &[[f64; 3]; 4],
    offset: f64,
    pyr: &Pyramid,
    t: &NTree,
) -> bool {
    let grid = |w: [f64; 3]| [0, 1, 2].map(|k| (w[k] - t.origin[k] as f64) / t.leaf_size[k] as f64);
    let g = tri.map(grid);
    let outside = pyr
        .planes
        .iter()
        .any(|(nrm, d)| g.iter().all(|v| dot(*nrm, *v) - d > MARGIN));
    if outside {
        return true;
    }
    let nrm = cross(sub(tri[1], tri[0]), sub(tri[2], tri[0]));
    let len = dot(nrm, nrm).sqrt();
    if len == 0.0 || offset <= 0.0 {
        return false;
    }
    let nrm = nrm.map(|x| x / len);
    let dp = dot(nrm, sub(p, tri[0]));
    let dq: Vec<f64> = light.iter().map(|q| dot(nrm, sub(*q, tri[0]))).collect();
    let max_len = light
        .iter()
        .map(|q| dot(sub(*q, p), sub(*q, p)).sqrt())
        .fold(0.0, f64::max);
    // Orient so that the light is on the positive side; then a segment point at parameter t
    // has signed distance (1 − t)·dp + t·dq ≥ dp + t·(dq_min − dp).
    let (dp, dq_min) = if dq.iter().all(|&d| d > 0.0) {
        (dp, dq.iter().cloned().fold(f64::INFINITY, f64::min))
    } else if dq.iter().all(|&d| d < 0.0) {
        (-dp, dq.iter().map(|d| -d).fold(f64::INFINITY, f64::min))
    } else {
        return false;
    };
    if dp >= 0.0 {
        return true;
    }
    // The segment crosses the plane at t* ≤ −dp / (dq_min − dp); segments start at
    // t_min = offset / |q − p| ≥ offset / max_len. Half of that as a safety margin.
    -dp / (dq_min - dp) < 0.5 * offset / max_len
}
