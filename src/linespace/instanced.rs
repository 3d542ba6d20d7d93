//! Line spaces over instances (issue 39, item 2): one N-tree per model, built once in the
//! model's own frame, instance references with their transforms ([`InstanceRef`], as the
//! two-level SVO), a top-level N-tree over the instances' world bounds whose leaves list
//! instances (its line spaces are the shaft table against the occupancy of those bounds), and
//! the terrain as a height field (its min/max quadtree, [`Heightfield`]). Memory grows with the
//! models, the terrain's samples and the instances, not with the placed triangles. Section:
//! [`super::instanced_section`] (`linespace-scene`).
//!
//! Query ([`SceneLinespace::segment_occluded`]): the terrain first (an exact any-hit through
//! its quadtree, the triangles of `terrain_mesh`); then the top tree's DDA, an empty shaft
//! skipping a node. The top level never calls a full shaft a hit (instance bounds are mostly
//! empty space): in a deepest top-level node the leaves the segment crosses are refined into
//! their instances, each tested once per segment by walking its model's tree on the segment
//! moved into the model's frame (`R_z(−θ)·(p − position)/scale`, the same `t`), where the
//! refinement mode (`shaft`, `cells`, `exact`, `near`) applies as in the flattened tree (`near`:
//! `exact` for the instances the segment enters within one top-level deepest-node side of its
//! start, [`SceneLinespace::near_distance`], the model tree's own `near` rule beyond). Exact
//! tests place the model's triangles into the world as the flattened scene does
//! ([`InstanceRef::to_world`], the same operations as `geometry::place_instance`) and test them
//! against the world segment: in `exact` mode an answer is the flattened scene's exact answer.
//! Rounding of the segment's move into the model frame is covered by growing every model
//! triangle's cells by [`SceneLinespace::frame_margin`] (a bound on that rounding at the
//! scene's coordinates), so a triangle the world segment hits is always reached.
//!
//! Transforms: uniform scale (any finite non-zero value; zero-scale instances are degenerate
//! and skipped, as their flattened triangles block nothing), rotation about +Z, translation:
//! the scene format has no other. A non-finite transform is refused, naming the instance.

use super::ntree::{NTree, NTreeOptions, Refine, build_ntree_padded, check_options, path_key};
use super::query::{LeafTest, QueryStats, Segment, to_bvh_triangle};
use super::shaft::ShaftTable;
use crate::error::{Error, Result};
use crate::model::{Instance, Terrain};
use crate::trace::heightfield::Heightfield;
use crate::voxel::instanced::InstanceRef;
use obvhs::ray::Ray as BvhRay;
use rayon::prelude::*;
use std::sync::Arc;

/// A model's mesh section name and its triangles in its own frame (None: no mesh).
pub type ModelTriangles = Option<(String, Vec<[[f32; 3]; 3]>)>;

/// One model's N-tree, in its own frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelTree {
    /// The mesh section it was built from.
    pub mesh_section: String,
    pub tree: NTree,
}

/// The terrain as a height field (heights kept for the section; its colour is not read).
#[derive(Debug, Clone)]
pub struct SceneTerrain {
    pub terrain: Terrain,
    pub field: Heightfield,
}

impl SceneTerrain {
    pub fn new(t: &Terrain) -> Result<SceneTerrain> {
        let terrain = Terrain {
            color: None,
            ..t.clone()
        };
        let field = Heightfield::new(&terrain)?;
        Ok(SceneTerrain { terrain, field })
    }
}

impl PartialEq for SceneTerrain {
    fn eq(&self, o: &Self) -> bool {
        self.terrain == o.terrain
    }
}

/// The two-level line-space structure of a placed scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneLinespace {
    /// The models' options (n, depth, cubic cells); the top tree shares n (and the shaft table).
    pub opts: NTreeOptions,
    pub models: Vec<ModelTree>,
    /// The placed models (`model` indexes [`Self::models`]).
    pub instances: Vec<InstanceRef>,
    /// Over the instances' world bounds, its leaves listing instance numbers; None without
    /// instances.
    pub top: Option<NTree>,
    pub terrain: Option<SceneTerrain>,
    /// World units every model triangle's cells were grown by (before dividing by the scale).
    pub frame_margin: f32,
}

/// Relative bound of the rounding when a world segment is moved into a model's frame and a
/// model triangle placed into the world, against the scene's largest coordinate L (2⁻¹⁹: the
/// placed vertices round by up to 2⁻²² L, the segment's origin and direction moved into the
/// frame by up to 2⁻²¹ L each for a receiver within 2L of the instance, the tree's grid mapping
/// below that; 7.8 mm at 4 km, 0.2 mm at 100 m).
const FRAME_ROUNDING: f32 = 1.0 / 524_288.0;

/// Most (leaf, triangle) pairs per triangle, on average, a model tree's depth allows (counted
/// by the triangles' grown bounding boxes, an upper bound of the cells they touch).
pub const MODEL_PAIRS_PER_TRIANGLE: u64 = 64;

/// The deepest depth ≤ `opts.depth` at which the triangles' bounding boxes, grown by `margin`,
/// cover at most [`MODEL_PAIRS_PER_TRIANGLE`] leaf cells per triangle on average (at least 1):
/// a model's cells are not finer than its triangles warrant (a 16,000-triangle tree of 10 m at
/// n = 10, depth 3 would list each leaf card in hundreds of 1 cm cells).
pub fn model_depth(tris: &[[[f32; 3]; 3]], opts: &NTreeOptions, margin: f32) -> u32 {
    let Some((lo, hi)) = bounds(tris.iter().flatten().copied()) else {
        return 1;
    };
    let (origin, size) = super::ntree::root_box_of(
        lo.map(|x| x - margin),
        hi.map(|x| x + margin),
        opts.cubic_cells,
    );
    let budget = MODEL_PAIRS_PER_TRIANGLE.saturating_mul(tris.len() as u64);
    (1..=opts.depth)
        .rev()
        .find(|&d| {
            let res = opts.n.pow(d);
            let leaf = size.map(|s| s / res as f32);
            let cells: u64 = tris
                .par_iter()
                .map(|t| {
                    let (a, b) = bounds(t.iter().copied()).expect("3 corners");
                    (0..3)
                        .map(|k| {
                            let c = |x: f32| ((x - origin[k]) / leaf[k]).floor() as i64;
                            (c(b[k] + margin) - c(a[k] - margin) + 1).max(1) as u64
                        })
                        .product::<u64>()
                })
                .sum();
            d == 1 || cells <= budget
        })
        .unwrap_or(1)
}

/// Bounds of points.
fn bounds(pts: impl Iterator<Item = [f32; 3]>) -> Option<([f32; 3], [f32; 3])> {
    pts.fold(None, |b, p| {
        Some(match b {
            None => (p, p),
            Some((lo, hi)) => (
                [0, 1, 2].map(|k| lo[k].min(p[k])),
                [0, 1, 2].map(|k| hi[k].max(p[k])),
            ),
        })
    })
}

fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
    (
        [0, 1, 2].map(|k| a.0[k].min(b.0[k])),
        [0, 1, 2].map(|k| a.1[k].max(b.1[k])),
    )
}

/// World bounds of a model box placed by `r` (its 8 corners), grown by `pad`.
fn placed_box(r: &InstanceRef, (lo, hi): ([f32; 3], [f32; 3]), pad: f32) -> ([f32; 3], [f32; 3]) {
    let corners =
        (0..8).map(|i| r.to_world([0, 1, 2].map(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] })));
    let (a, b) = bounds(corners).expect("8 corners");
    (a.map(|x| x - pad), b.map(|x| x + pad))
}

/// Bytes the build holds at least: every placed model's mesh and its tree's triangles and
/// about four (leaf, triangle) pairs per triangle (while sorting, 16 B each, plus the kept 4 B
/// index), the terrain's heights three times (the source, the height field's copy, its
/// min/max quadtree), per instance its reference, bounds and about 27 top-level pairs
/// (32 + 24 + 27·20 B). Like the flattened estimate, without the shaft table (19.2 MB at
/// n = 10, shared).
pub use crate::voxel::geometry::linespace_scene_bytes as build_bytes;

impl SceneLinespace {
    /// Builds the structure: `models[i]` is model i's triangles in its own frame with its mesh
    /// section's name (None: no mesh, its instances are not placed, as the flattened scene
    /// skips them); `opts` is every model tree's configuration.
    pub fn build(
        terrain: Option<&Terrain>,
        models: &[ModelTriangles],
        instances: &[Instance],
        opts: &NTreeOptions,
        shafts: &Arc<ShaftTable>,
    ) -> Result<SceneLinespace> {
        check_options(opts)?;
        if shafts.layout.n != opts.n {
            return Err(Error::Runtime("shaft table built for another n".into()));
        }
        for (k, i) in instances.iter().enumerate() {
            let finite = i.position.iter().all(|x| x.is_finite())
                && i.scale.is_finite()
                && i.rotation_deg.is_finite();
            if !finite {
                return Err(Error::runtime(format!(
                    "instance {k} (model {}): its transform (position {:?}, scale {}, \
                     rotation {}°) is not finite; the line-space stage cannot place it",
                    i.model, i.position, i.scale, i.rotation_deg
                )));
            }
        }
        let model_bounds: Vec<Option<([f32; 3], [f32; 3])>> = models
            .iter()
            .map(|m| {
                m.as_ref()
                    .and_then(|(_, t)| bounds(t.iter().flatten().copied()))
            })
            .collect();
        // Placed instances: a model with triangles, a non-zero scale.
        let placed: Vec<(usize, InstanceRef)> = instances
            .iter()
            .filter(|i| i.scale != 0.0)
            .filter(|i| matches!(model_bounds.get(i.model as usize), Some(Some(_))))
            .map(|i| (i.model as usize, InstanceRef::of(i, i.model)))
            .collect();
        // A terrain of one row or column of samples has no cell, so no triangle to block.
        let terrain = terrain
            .filter(|t| t.width >= 2 && t.height >= 2)
            .map(SceneTerrain::new)
            .transpose()?;
        // The scene's largest coordinate: every placed model box and the terrain.
        let raw_boxes: Vec<([f32; 3], [f32; 3])> = placed
            .par_iter()
            .map(|(m, r)| placed_box(r, model_bounds[*m].expect("filtered"), 0.0))
            .collect();
        let mut scene = raw_boxes.iter().copied().reduce(union);
        if let Some(t) = &terrain {
            let (lo, hi) = t.field.bounds();
            scene =
                Some(scene.map_or((lo.into(), hi.into()), |s| union(s, (lo.into(), hi.into()))));
        }
        let largest = scene.map_or(1.0, |(lo, hi)| {
            lo.iter()
                .chain(hi.iter())
                .map(|x| x.abs())
                .fold(1.0f32, f32::max)
        });
        let frame_margin = largest * FRAME_ROUNDING;

        // Per model, once, in its own frame; its cells grown by the frame margin over the
        // smallest |scale| of its instances.
        let mut out_models = Vec::new();
        let mut model_map = vec![u32::MAX; models.len()];
        for (m, geo) in models.iter().enumerate() {
            let Some((name, tris)) = geo else { continue };
            let s_min = placed
                .iter()
                .filter(|(pm, _)| *pm == m)
                .map(|(_, r)| r.scale.abs())
                .fold(f32::INFINITY, f32::min);
            if !s_min.is_finite() || tris.is_empty() {
                continue;
            }
            let margin = frame_margin / s_min;
            let depth = model_depth(tris, opts, margin);
            let tree = build_ntree_padded(tris, &NTreeOptions { depth, ..*opts }, shafts, margin)?;
            model_map[m] = out_models.len() as u32;
            out_models.push(ModelTree {
                mesh_section: name.clone(),
                tree,
            });
        }
        let mut refs = Vec::new();
        let mut boxes = Vec::new();
        for ((m, r), b) in placed.iter().zip(&raw_boxes) {
            if model_map[*m] == u32::MAX {
                continue;
            }
            refs.push(InstanceRef {
                model: model_map[*m],
                ..*r
            });
            boxes.push((
                b.0.map(|x| x - 2.0 * frame_margin),
                b.1.map(|x| x + 2.0 * frame_margin),
            ));
        }
        let top = if boxes.is_empty() {
            None
        } else {
            Some(box_tree(&boxes, opts, shafts))
        };
        Ok(SceneLinespace {
            opts: *opts,
            models: out_models,
            instances: refs,
            top,
            terrain,
            frame_margin,
        })
    }

    /// Sets the refinement mode of every model tree (the top tree always refines into its
    /// instances).
    pub fn set_refine(&mut self, refine: Refine) {
        for m in &mut self.models {
            m.tree.refine = refine;
        }
    }

    /// The refinement mode of the model trees.
    pub fn refine(&self) -> Refine {
        self.models
            .first()
            .map_or(Refine::default(), |m| m.tree.refine)
    }

    /// The segment moved into instance `i`'s model frame (the same `t`).
    pub fn segment_in(&self, i: usize, s: &Segment) -> Segment {
        let r = &self.instances[i];
        let d = r.dir_to_model(s.dir);
        Segment {
            from: r.point_to_model(s.from),
            dir: d.map(|x| x / r.scale),
            t_min: s.t_min,
            t_max: s.t_max,
        }
    }

    /// Whether instance `i` may block the segment (its model's tree, its refinement mode; in
    /// `near` mode `exact` for an instance whose model box the segment enters within
    /// [`Self::near_distance`] of its start).
    pub fn instance_occluded(&self, i: usize, s: &Segment, stats: &mut QueryStats) -> bool {
        let r = &self.instances[i];
        let tree = &self.models[r.model as usize].tree;
        let mut placed = PlacedTriangles {
            ray: s.bvh_ray(),
            place: *r,
        };
        let ms = self.segment_in(i, s);
        let refine = match tree.refine {
            Refine::Near => {
                let entry = tree
                    .root_span(&tree.grid_ray(&ms))
                    .map_or(s.t_max, |sp| sp.t0);
                let len = s.dir.iter().map(|d| d * d).sum::<f32>().sqrt();
                if (entry - s.t_min) * len <= self.near_distance() {
                    Refine::Exact
                } else {
                    Refine::Near
                }
            }
            other => other,
        };
        tree.occluded_by_refine(&ms, true, refine, &mut placed, stats)
    }

    /// The `near` mode's exact zone at the instance level (world units): one deepest-node side
    /// of the top tree (what `near` means in a flattened tree of the scene's extent at the top
    /// tree's depth; 41 m at 4 km, depth 3, n = 10). 0 without a top tree.
    pub fn near_distance(&self) -> f32 {
        self.top.as_ref().map_or(0.0, |t| {
            t.leaf_size.iter().cloned().fold(0.0f32, f32::max) * t.n as f32
        })
    }

    /// Whether the terrain blocks the segment (exact).
    pub fn terrain_occluded(&self, s: &Segment) -> bool {
        self.terrain.as_ref().is_some_and(|t| {
            t.field.any_hit(&crate::trace::Ray {
                origin: s.from.into(),
                dir: s.dir.into(),
                tmin: s.t_min,
                tmax: s.t_max,
            })
        })
    }

    /// Whether the segment may be blocked (never false when a triangle of the placed scene
    /// blocks it; in `exact` mode exactly when one does).
    pub fn segment_occluded(&self, s: &Segment, stats: &mut QueryStats) -> bool {
        if self.terrain_occluded(s) {
            return true;
        }
        let Some(top) = &self.top else {
            return false;
        };
        let mut leaves = InstanceLeaves {
            scene: self,
            segment: s,
            tested: Vec::new(),
        };
        top.occluded_by(s, true, &mut leaves, stats)
    }

    /// Fraction of the light's samples that reach `p` (1 = fully lit).
    pub fn shadow(
        &self,
        p: [f32; 3],
        light: &super::query::AreaLight,
        offset: f32,
        stats: &mut QueryStats,
    ) -> f32 {
        light.lit_fraction(p, offset, |s| self.segment_occluded(s, stats))
    }

    /// Placed triangles (Σ over instances of their model's triangles).
    pub fn placed_triangles(&self) -> u64 {
        self.instances
            .iter()
            .map(|r| self.models[r.model as usize].tree.triangles.len() as u64)
            .sum()
    }

    /// Bytes of the arrays as stored (the trees, the instances, the heights; the shaft table
    /// once).
    pub fn bytes(&self) -> u64 {
        let tree = |t: &NTree| (t.bytes() - t.shafts.bytes()) as u64;
        let mut b: u64 = self.models.iter().map(|m| tree(&m.tree)).sum();
        if let Some(t) = &self.top {
            b += tree(t);
        }
        b += 32 * self.instances.len() as u64;
        if let Some(t) = &self.terrain {
            b += 4 * t.terrain.heights.len() as u64;
        }
        b + self
            .models
            .first()
            .map_or(0, |m| m.tree.shafts.bytes() as u64)
    }
}

/// Most top-level (leaf, instance) pairs per instance the top tree's depth allows.
const TOP_PAIRS_PER_INSTANCE: u64 = 64;

/// Leaf-cell range (inclusive) of a world box in a grid of `res` cells per axis.
fn cell_range(
    b: &([f32; 3], [f32; 3]),
    origin: [f32; 3],
    leaf: [f32; 3],
    res: u32,
) -> ([u32; 3], [u32; 3]) {
    let c = |x: f32, k: usize, m: f32| {
        (((x - origin[k]) / leaf[k] + m).floor() as i64).clamp(0, res as i64 - 1) as u32
    };
    (
        [0, 1, 2].map(|k| c(b.0[k], k, -super::ntree::CELL_MARGIN)),
        [0, 1, 2].map(|k| c(b.1[k], k, super::ntree::CELL_MARGIN)),
    )
}

/// The top-level tree over instance boxes: n as `opts`, the root box as a triangle tree's over
/// the boxes, and the deepest depth ≤ `opts.depth` at which the boxes cover at most
/// [`TOP_PAIRS_PER_INSTANCE`] leaf cells each on average (at least 1). Leaf cells list every
/// instance whose box overlaps the cell (margin 10⁻³ cell), in instance order.
pub fn box_tree(
    boxes: &[([f32; 3], [f32; 3])],
    opts: &NTreeOptions,
    shafts: &Arc<ShaftTable>,
) -> NTree {
    let (lo, hi) = boxes
        .iter()
        .copied()
        .reduce(union)
        .unwrap_or(([0.0; 3], [1.0; 3]));
    let (origin, size) = super::ntree::root_box_of(lo, hi, opts.cubic_cells);
    let n = opts.n;
    let pairs_at = |depth: u32| -> u64 {
        let res = n.pow(depth);
        let leaf = size.map(|s| s / res as f32);
        boxes
            .par_iter()
            .map(|b| {
                let (a, z) = cell_range(b, origin, leaf, res);
                (0..3).map(|k| (z[k] - a[k] + 1) as u64).product::<u64>()
            })
            .sum()
    };
    let budget = TOP_PAIRS_PER_INSTANCE * boxes.len() as u64;
    let depth = (1..=opts.depth)
        .rev()
        .find(|&d| d == 1 || pairs_at(d) <= budget)
        .unwrap_or(1);
    let res = n.pow(depth);
    let leaf_size = size.map(|s| s / res as f32);
    let mut pairs: Vec<(u64, u32)> = boxes
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, b)| {
            let (a, z) = cell_range(b, origin, leaf_size, res);
            let mut out = Vec::new();
            for cz in a[2]..=z[2] {
                for cy in a[1]..=z[1] {
                    for cx in a[0]..=z[0] {
                        out.push((path_key([cx, cy, cz], depth, n), i as u32));
                    }
                }
            }
            out
        })
        .collect();
    pairs.par_sort_unstable();
    let mut tree = NTree::from_cells(
        &NTreeOptions { depth, ..*opts },
        origin,
        leaf_size,
        &pairs,
        Vec::new(),
        shafts,
    );
    tree.refine = Refine::Exact;
    tree
}

/// A model's triangles placed by an instance, tested against the world segment.
struct PlacedTriangles {
    ray: BvhRay,
    place: InstanceRef,
}

impl LeafTest for PlacedTriangles {
    #[inline]
    fn leaf_hit(&mut self, tree: &NTree, leaf: u32, stats: &mut QueryStats) -> bool {
        let tris = tree.leaf_triangles(leaf);
        stats.exact_triangle_tests += tris.len() as u64;
        tris.iter().any(|&t| {
            let w = tree.triangles[t as usize].map(|p| self.place.to_world(p));
            to_bvh_triangle(&w).intersect(&self.ray) <= self.ray.tmax
        })
    }
}

/// The top tree's leaves: each listed instance tested once per segment.
struct InstanceLeaves<'a> {
    scene: &'a SceneLinespace,
    segment: &'a Segment,
    tested: Vec<u32>,
}

impl LeafTest for InstanceLeaves<'_> {
    fn leaf_hit(&mut self, tree: &NTree, leaf: u32, stats: &mut QueryStats) -> bool {
        for &i in tree.leaf_triangles(leaf) {
            if self.tested.contains(&i) {
                continue;
            }
            self.tested.push(i);
            if self
                .scene
                .instance_occluded(i as usize, self.segment, stats)
            {
                return true;
            }
        }
        false
    }
}

/// Exact visibility over instances without any tree (the tests' and the benchmark's oracle):
/// the terrain's exact any-hit, then every instance whose placed bounds the segment meets,
/// brute force over its model's triangles placed into the world (the flattened scene's
/// triangles, bit for bit).
pub struct ExactInstances<'a> {
    scene: &'a SceneLinespace,
    boxes: Vec<([f32; 3], [f32; 3])>,
}

impl<'a> ExactInstances<'a> {
    pub fn new(scene: &'a SceneLinespace) -> Self {
        let boxes = scene
            .instances
            .iter()
            .map(|r| {
                let t = &scene.models[r.model as usize].tree.triangles;
                let b = bounds(t.iter().flatten().copied()).expect("a model has triangles");
                placed_box(r, b, scene.frame_margin)
            })
            .collect();
        ExactInstances { scene, boxes }
    }

    /// Whether any placed triangle (or the terrain) blocks the segment.
    pub fn occluded(&self, s: &Segment) -> bool {
        if self.scene.terrain_occluded(s) {
            return true;
        }
        let ray = s.bvh_ray();
        self.crossed(s, 0.0).any(|(r, tris)| {
            tris.iter()
                .any(|t| to_bvh_triangle(&t.map(|p| r.to_world(p))).intersect(&ray) <= ray.tmax)
        })
    }

    /// The instances whose placed box, grown by `grow`, the segment meets, with their model's
    /// triangles (in the model's frame).
    fn crossed<'s>(
        &'s self,
        s: &'s Segment,
        grow: f32,
    ) -> impl Iterator<Item = (&'s InstanceRef, &'s [[[f32; 3]; 3]])> + 's {
        self.boxes
            .iter()
            .enumerate()
            .filter_map(move |(i, (lo, hi))| {
                let b = (lo.map(|x| x - grow), hi.map(|x| x + grow));
                let (t0, t1) = slab(s, &b);
                let r = &self.scene.instances[i];
                (t0 <= t1).then(|| (r, &self.scene.models[r.model as usize].tree.triangles[..]))
            })
    }
}

impl ExactInstances<'_> {
    /// Whether the segment passes within `delta` (world units) of an edge of a placed triangle,
    /// or meets one within `delta` of its ends: where rounding of the placement or of the
    /// triangle test can decide a hit (the line meets the triangle's plane, in f64, at a point
    /// that close to the triangle's boundary).
    pub fn near_edge(&self, s: &Segment, delta: f32) -> bool {
        let (o, d) = (s.from.map(f64::from), s.dir.map(f64::from));
        let delta = delta as f64;
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        self.crossed(s, delta as f32).any(|(r, tris)| {
            tris.iter().any(|t| {
                let w = t.map(|p| r.to_world(p).map(f64::from));
                let Some(tt) = plane_t(o, d, &w) else {
                    return false;
                };
                let near_end = ((tt - s.t_min as f64) * len).abs() <= delta
                    || ((tt - s.t_max as f64) * len).abs() <= delta;
                if tt * len < s.t_min as f64 * len - delta
                    || tt * len > s.t_max as f64 * len + delta
                {
                    return false;
                }
                let p = [0, 1, 2].map(|k| o[k] + d[k] * tt);
                let inside = point_in_triangle(p, &w);
                let edge = (0..3).any(|k| point_segment_distance(p, w[k], w[(k + 1) % 3]) <= delta);
                edge || (near_end && inside)
            })
        })
    }
}

/// Where the line o + t·d meets the triangle's plane (f64; None when parallel or degenerate).
fn plane_t(o: [f64; 3], d: [f64; 3], w: &[[f64; 3]; 3]) -> Option<f64> {
    let n = cross(sub(w[1], w[0]), sub(w[2], w[0]));
    let den = dot(n, d);
    if den.abs() < 1e-300 {
        return None;
    }
    Some(dot(n, sub(w[0], o)) / den)
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

/// Whether p (in the triangle's plane) lies inside it.
fn point_in_triangle(p: [f64; 3], w: &[[f64; 3]; 3]) -> bool {
    let n = cross(sub(w[1], w[0]), sub(w[2], w[0]));
    (0..3).all(|k| dot(cross(sub(w[(k + 1) % 3], w[k]), sub(p, w[k])), n) >= 0.0)
}

/// Distance from p to the segment a–b.
fn point_segment_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = sub(b, a);
    let l2 = dot(ab, ab);
    let t = if l2 > 0.0 {
        (dot(sub(p, a), ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let q = [0, 1, 2].map(|k| a[k] + t * ab[k] - p[k]);
    dot(q, q).sqrt()
}

/// The segment's parameter interval inside a box (empty: t0 > t1).
fn slab(s: &Segment, (lo, hi): &([f32; 3], [f32; 3])) -> (f32, f32) {
    let (mut t0, mut t1) = (s.t_min, s.t_max);
    for k in 0..3 {
        if s.dir[k] == 0.0 {
            if s.from[k] < lo[k] || s.from[k] > hi[k] {
                return (1.0, 0.0);
            }
            continue;
        }
        let inv = 1.0 / s.dir[k];
        let (a, b) = ((lo[k] - s.from[k]) * inv, (hi[k] - s.from[k]) * inv);
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        // Widened by a relative 10⁻⁵ against rounding (the oracle must not miss a box).
        let w = 1e-5 * (a.abs().max(b.abs()) + 1e-3);
        t0 = t0.max(a - w);
        t1 = t1.min(b + w);
    }
    (t0, t1)
}

#[cfg(test)]
#[path = "instanced_tests.rs"]
mod tests;
