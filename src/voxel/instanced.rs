//! The instanced (two-level) SVO of a placed scene: one octree per model, voxelized once in the
//! model's own frame by today's code ([`super::voxelize`], [`super::svo`]), instance references
//! with their transforms, a uniform top-level grid over the instances' bounds, and the terrain as
//! its own octree in the scene's grid. Memory grows with the models (and 32 B plus a few grid
//! references per instance), not with the placed triangles. Section: [`super::instanced_section`].
//!
//! Resolution (docs/CONVENTIONS.md, "Instanced SVO"): the scene gets the flattened SVO's grid,
//! `Grid::fit` of the placed scene's bounds at `resolution` voxels along the longest axis, voxel
//! side v. The terrain is voxelized in exactly that grid. Model m is voxelized in its own frame
//! with voxel side at most v / s_max (s_max the largest scale among its instances), so no
//! instance's voxel is wider than a scene voxel. Under an instance (p, s, θ) a model voxel is the
//! box {p + R_z(θ)·(s·x) : x in the voxel}: a cube of side s·v_m turned by θ about +Z; its normal
//! is turned by R_z(θ), its colour is the model's.
//!
//! Traversal ([`InstancedSvo::trace`]): a DDA over the top grid; each instance listed in a cell
//! is traced once (over the whole ray) by [`super::traverse::trace_svo`] on the ray moved into
//! its voxel units (same `t`); the terrain is traced once. The nearest hit wins, ties to the
//! lower instance number (the terrain is number `instances − 1`, last); the walk stops once the
//! best hit lies before the current cell's exit. The LOD walk ([`InstancedSvo::trace_lod`])
//! applies one rule from the top cells down: a top cell, a sub-cell, or inside an instance a
//! node of its model whose world side is at most `cone · t` where the ray enters it (and which
//! covers enough) answers with its filtered attributes.

use super::Grid;
use super::geometry::Geometry;
use super::lod_trace::can_stop;
use super::svo::{Svo, voxels_to_svo};
use super::traverse::{Dda, VoxelRay, box_interval, slot, trace_svo};
use super::voxelize::{VoxelizeOptions, Voxels, mesh_to_voxels_in};
use crate::error::{Error, Result};
use crate::model::{Instance, Terrain};
use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

/// One placed model (or the terrain): repr(C), Pod, 32 bytes, the `instances` array's element.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct InstanceRef {
    pub position: [f32; 3],
    pub scale: f32,
    /// cos θ and sin θ of the rotation about +Z (as `f32::sin_cos` of the radians gives them,
    /// the same values the flattened placement uses).
    pub cos: f32,
    pub sin: f32,
    /// Index into [`InstancedSvo::models`].
    pub model: u32,
    /// 0.
    pub reserved: u32,
}
const _: () = assert!(size_of::<InstanceRef>() == 32);

impl InstanceRef {
    /// The identity placement of `model` (the terrain's).
    pub fn identity(model: u32) -> InstanceRef {
        InstanceRef {
            position: [0.0; 3],
            scale: 1.0,
            cos: 1.0,
            sin: 0.0,
            model,
            reserved: 0,
        }
    }

    /// From a scene instance, for `model`.
    pub fn of(i: &Instance, model: u32) -> InstanceRef {
        let (sin, cos) = i.rotation_deg.to_radians().sin_cos();
        InstanceRef {
            position: i.position,
            scale: i.scale,
            cos,
            sin,
            model,
            reserved: 0,
        }
    }

    /// Model space to world: position + R_z(θ)·(scale·p), as `geometry::place_instance`.
    pub fn to_world(&self, p: [f32; 3]) -> [f32; 3] {
        let q = p.map(|x| x * self.scale);
        let r = [
            self.cos * q[0] - self.sin * q[1],
            self.sin * q[0] + self.cos * q[1],
            q[2],
        ];
        [0, 1, 2].map(|k| r[k] + self.position[k])
    }

    /// A world direction turned into the model's frame (R_z(−θ), not scaled).
    pub fn dir_to_model(&self, d: [f32; 3]) -> [f32; 3] {
        [
            self.cos * d[0] + self.sin * d[1],
            -self.sin * d[0] + self.cos * d[1],
            d[2],
        ]
    }

    /// A model direction (a normal) turned into the world.
    pub fn dir_to_world(&self, d: [f32; 3]) -> [f32; 3] {
        [
            self.cos * d[0] - self.sin * d[1],
            self.sin * d[0] + self.cos * d[1],
            d[2],
        ]
    }

    /// A world point in the model's frame.
    pub fn point_to_model(&self, p: [f32; 3]) -> [f32; 3] {
        let d = self.dir_to_model([0, 1, 2].map(|k| p[k] - self.position[k]));
        d.map(|x| x / self.scale)
    }
}

/// One model's octree, in its own frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSvo {
    /// The mesh section it was voxelized from (`terrain` for the terrain).
    pub mesh_section: String,
    pub svo: Svo,
}

/// The uniform top-level grid: cubic cells of side `cell` from `origin`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TopGrid {
    pub origin: [f32; 3],
    pub cell: f32,
    pub dims: [u32; 3],
}

impl TopGrid {
    pub fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    fn index(&self, c: [i64; 3]) -> usize {
        let d = self.dims.map(|d| d as usize);
        c[0] as usize + d[0] * (c[1] as usize + d[1] * c[2] as usize)
    }
}

/// The two-level SVO.
#[derive(Debug, Clone, PartialEq)]
pub struct InstancedSvo {
    /// The flattened SVO's grid (the scene's resolution; the terrain's octree uses it).
    pub scene_grid: Grid,
    pub models: Vec<ModelSvo>,
    /// The placed models; with a terrain, its identity placement is the last entry.
    pub instances: Vec<InstanceRef>,
    pub terrain: bool,
    pub top: TopGrid,
    /// Cell c lists `cell_instances[cell_start[c]..cell_start[c + 1]]` (x fastest, then y, z).
    pub cell_start: Vec<u32>,
    pub cell_instances: Vec<u32>,
    /// The top level's filtered attributes ([`TopAggregates`]).
    pub aggregates: TopAggregates,
}

/// Sub-cells per axis of a top cell (one 4³ node, a 64-bit mask in Morton slot order).
pub const SUB: u32 = 4;

/// Filtered attributes of the top grid (docs/CONVENTIONS.md, "Instanced SVO"): per top cell the
/// aggregate of the placed model voxels whose centres fall in it, and per occupied sub-cell of
/// its 4³ subdivision the same over the sub-cell. Premultiplied RGBA8 colours whose α is the
/// coverage min(1, Σ (s·v_m)³·α_voxel / volume), octahedral world normals (the coverage- and
/// volume-weighted sum of the voxels' turned normals). The terrain's voxels are aggregated as
/// an instance at the identity (the top grid spans its box), so a far view sees the ground.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopAggregates {
    /// Per top cell: (mask low, mask high, first sub-cell, 0); bit s of the mask: sub-cell at
    /// Morton slot s holds a voxel centre. Sub-cell s of cell c has attribute
    /// `cells + first + popcount(mask below s)`.
    pub nodes: Vec<[u32; 4]>,
    /// Per top cell, then per occupied sub-cell: RGBA8 linear premultiplied.
    pub colors: Vec<u32>,
    /// The same entries: octahedral world normal (0: none).
    pub normals: Vec<u32>,
}

impl TopAggregates {
    /// The 64-bit sub-cell mask of cell `c`.
    pub fn mask(&self, c: usize) -> u64 {
        let n = self.nodes[c];
        n[0] as u64 | (n[1] as u64) << 32
    }

    /// Attribute index of sub-cell `s` of cell `c` (its bit must be set).
    pub fn sub_attr(&self, c: usize, s: u32) -> usize {
        let below = self.mask(c) & ((1u64 << s) - 1);
        self.nodes.len() + self.nodes[c][2] as usize + below.count_ones() as usize
    }
}

/// A walk's stop on a top-level aggregate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AggregateHit {
    /// 0: a top cell, 1: a sub-cell.
    pub level: u32,
    /// Index into [`TopAggregates::colors`] / `normals`.
    pub attr: u32,
    /// World ray parameter where the walk enters the region.
    pub t: f32,
}

/// A walk's stop on an inner node (or brick) of an instance's model octree: its filtered
/// attributes, the model's `node_colors` / `node_normals`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeHit {
    /// Instance number (the terrain's is the last).
    pub instance: u32,
    /// Level in the model's octree (0 the root, below its `levels`: a voxel is a
    /// [`SceneHit::Voxel`]).
    pub level: u32,
    /// The cell's minimum corner in the model's voxels.
    pub cell: [u32; 3],
    /// Index into the model's `node_colors` / `node_normals`.
    pub attr: u32,
    /// World ray parameter where the walk enters the cell.
    pub t: f32,
}

/// What the LOD walk ([`InstancedSvo::trace_lod`]) ends on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SceneHit {
    Voxel(InstanceHit),
    /// A model's filtered node inside an instance (or the terrain).
    Node(NodeHit),
    Aggregate(AggregateHit),
}

impl SceneHit {
    pub fn t(&self) -> f32 {
        match self {
            SceneHit::Voxel(h) => h.t,
            SceneHit::Node(h) => h.t,
            SceneHit::Aggregate(a) => a.t,
        }
    }

    /// The instance of a voxel or node hit.
    pub fn instance(&self) -> Option<u32> {
        match self {
            SceneHit::Voxel(h) => Some(h.instance),
            SceneHit::Node(h) => Some(h.instance),
            SceneHit::Aggregate(_) => None,
        }
    }
}

/// The first voxel hit along a world ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceHit {
    /// Instance number (the terrain's is the last).
    pub instance: u32,
    /// The voxel in its model's grid.
    pub voxel: [u32; 3],
    /// World ray parameter of the voxel's entry.
    pub t: f32,
}

/// Corners of a grid's box in its own space.
fn grid_corners(g: &Grid) -> [[f32; 3]; 8] {
    let hi = g.to_world(g.dims.map(|d| d as f32));
    std::array::from_fn(|i| [0, 1, 2].map(|k| if i >> k & 1 == 0 { g.origin[k] } else { hi[k] }))
}

fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
    (
        [0, 1, 2].map(|k| a.0[k].min(b.0[k])),
        [0, 1, 2].map(|k| a.1[k].max(b.1[k])),
    )
}

/// Bounds of a model's vertices placed by `r` (as the flattened placement computes them).
fn placed_bounds(m: &Geometry, r: &InstanceRef) -> Option<([f32; 3], [f32; 3])> {
    let mut it = m.mesh.positions.iter().map(|&p| r.to_world(p));
    let first = it.next()?;
    Some(it.fold((first, first), |b, p| union(b, (p, p))))
}

/// Voxels along a model's longest axis so that `Grid::fit` gives a voxel side at most `size`.
fn model_resolution(lo: [f32; 3], hi: [f32; 3], size: f32) -> u32 {
    let longest = (0..3)
        .map(|k| hi[k] - lo[k])
        .fold(0.0f32, f32::max)
        .max(1e-6);
    let n = longest * 1.0002 / size;
    // A count within 10⁻⁴ of an integer is that integer (the flattened grid's own count).
    let r = n.round();
    let n = if (n - r).abs() <= 1e-4 * r.max(1.0) {
        r
    } else {
        n.ceil()
    };
    (n as u32).clamp(1, super::MAX_DIM)
}

/// Bytes the build holds at least besides its output: every placed model's mesh, the
/// terrain's heights and one tile of its mesh (32 B per vertex, 16 B per triangle, as
/// `PlacedSize::mesh_bytes`; tiles of [`TERRAIN_TILE_CELLS`] and their margins), the largest
/// per-triangle set-up of one voxelization (they run one at a time), and per instance its
/// reference, bounds and about eight grid references (88 B).
pub fn build_bytes(terrain: (u64, u64), models: &[(u64, u64)], instances: u64) -> u64 {
    let mesh = |(v, t): (u64, u64)| v.saturating_mul(32).saturating_add(t.saturating_mul(16));
    let setup = |(_, t): (u64, u64)| {
        t.saturating_mul(super::geometry::SceneStage::Svo.bytes_per_triangle())
    };
    let tile = (
        terrain.0.min(TERRAIN_TILE_CELLS * 3 / 2),
        terrain.1.min(TERRAIN_TILE_CELLS * 3),
    );
    let meshes = models.iter().fold(
        mesh(tile).saturating_add(terrain.0.saturating_mul(4)),
        |a, &m| a.saturating_add(mesh(m)),
    );
    let peak = models
        .iter()
        .map(|&m| setup(m))
        .max()
        .unwrap_or(0)
        .max(setup(tile));
    meshes
        .saturating_add(peak)
        .saturating_add(instances.saturating_mul(88))
}

impl InstancedSvo {
    /// Builds the two-level SVO: `models[i]` is the geometry of model i of the instances (None:
    /// no mesh, its instances are not placed, as the flattened scene skips them).
    pub fn build(
        terrain: Option<&Terrain>,
        models: &[Option<(String, Geometry)>],
        instances: &[Instance],
        opts: &VoxelizeOptions,
    ) -> Result<InstancedSvo> {
        // The placed scene's bounds, exactly as the flattened mesh has them.
        let placed: Vec<(usize, InstanceRef)> = instances
            .iter()
            .filter(|i| matches!(models.get(i.model as usize), Some(Some(_))))
            .map(|i| (i.model as usize, InstanceRef::of(i, i.model)))
            .collect();
        let per_instance: Vec<Option<([f32; 3], [f32; 3])>> = placed
            .par_iter()
            .map(|(m, r)| placed_bounds(&models[*m].as_ref().expect("filtered").1, r))
            .collect();
        let mut bounds = terrain.and_then(terrain_bounds);
        for b in per_instance.into_iter().flatten() {
            bounds = Some(bounds.map_or(b, |a| union(a, b)));
        }
        let (lo, hi) =
            bounds.ok_or_else(|| Error::Runtime("the scene has no vertices to voxelize".into()))?;
        let scene_grid = Grid::fit(lo, hi, opts.resolution);
        let v = scene_grid.voxel_size[0];

        // Per model, once: voxelized in its own frame.
        let mut out_models = Vec::new();
        let mut model_map = vec![u32::MAX; models.len()];
        for (m, geo) in models.iter().enumerate() {
            let Some((name, geo)) = geo else { continue };
            let s_max = placed
                .iter()
                .filter(|(pm, _)| *pm == m)
                .map(|(_, r)| r.scale.abs())
                .fold(0.0f32, f32::max);
            if s_max <= 0.0 || !s_max.is_finite() {
                continue;
            }
            let Some((mlo, mhi)) = geo.mesh.bounds() else {
                continue;
            };
            let grid = Grid::fit(mlo, mhi, model_resolution(mlo, mhi, v / s_max));
            let vox = mesh_to_voxels_in(&geo.mesh, &geo.textures, &grid, opts)?;
            if vox.bricks.is_empty() {
                continue;
            }
            model_map[m] = out_models.len() as u32;
            out_models.push(ModelSvo {
                mesh_section: name.clone(),
                svo: voxels_to_svo(&vox),
            });
        }
        let mut refs: Vec<InstanceRef> = placed
            .iter()
            .filter(|(m, _)| model_map[*m] != u32::MAX)
            .map(|(m, r)| InstanceRef {
                model: model_map[*m],
                ..*r
            })
            .collect();
        let grid_instances = refs.len();
        let mut has_terrain = false;
        if let Some(t) = terrain {
            let vox = terrain_voxels(t, &scene_grid, opts, TERRAIN_TILE_CELLS)?;
            if !vox.bricks.is_empty() {
                refs.push(InstanceRef::identity(out_models.len() as u32));
                out_models.push(ModelSvo {
                    mesh_section: "terrain".into(),
                    svo: voxels_to_svo(&vox),
                });
                has_terrain = true;
            }
        }
        let boxes: Vec<([f32; 3], [f32; 3])> = refs[..grid_instances]
            .iter()
            .map(|r| instance_box(r, &out_models[r.model as usize].svo.grid))
            .collect();
        // The top grid covers the terrain too: its voxels are in the aggregates.
        let terrain_box = has_terrain.then(|| {
            let r = &refs[grid_instances];
            instance_box(r, &out_models[r.model as usize].svo.grid)
        });
        let (top, cell_start, cell_instances) = top_grid(&boxes, terrain_box);
        let mut s = InstancedSvo {
            scene_grid,
            models: out_models,
            instances: refs,
            terrain: has_terrain,
            top,
            cell_start,
            cell_instances,
            aggregates: TopAggregates::default(),
        };
        s.aggregates = top_aggregates(&s);
        Ok(s)
    }

    /// Instances in the top grid (all but the terrain).
    pub fn grid_instances(&self) -> usize {
        self.instances.len() - self.terrain as usize
    }

    /// A world ray in instance `i`'s voxel units (the same `t`).
    pub fn ray_in(&self, i: usize, origin: [f32; 3], dir: [f32; 3], t: [f32; 2]) -> VoxelRay {
        let r = &self.instances[i];
        let g = &self.models[r.model as usize].svo.grid;
        let o = g.to_grid(r.point_to_model(origin));
        let d = r.dir_to_model(dir);
        VoxelRay {
            origin: o,
            dir: [0, 1, 2].map(|k| d[k] / (r.scale * g.voxel_size[k])),
            t_min: t[0],
            t_max: t[1],
        }
    }

    /// The first voxel of instance `i` along the world ray.
    pub fn trace_instance(
        &self,
        i: usize,
        origin: [f32; 3],
        dir: [f32; 3],
        t: [f32; 2],
    ) -> Option<InstanceHit> {
        let r = self.ray_in(i, origin, dir, t);
        let svo = &self.models[self.instances[i].model as usize].svo;
        trace_svo(svo, &r).map(|h| InstanceHit {
            instance: i as u32,
            voxel: h.voxel,
            t: h.t,
        })
    }

    /// World side of one voxel of instance `i` (|scale| × its model's voxel side): the `unit`
    /// of its octree's LOD rule.
    pub fn voxel_side(&self, i: usize) -> f32 {
        let r = &self.instances[i];
        r.scale.abs() * self.models[r.model as usize].svo.grid.voxel_size[0]
    }

    /// The LOD walk of instance `i`'s model ([`super::lod_trace::trace_lod_scaled`]) on the
    /// world ray: a node whose world side (its side × [`Self::voxel_side`]) is at most
    /// `cone · t` where the ray enters it, and whose coverage can stop, ends the walk on its
    /// filtered attributes; else the first voxel. Cone 0: [`Self::trace_instance`].
    pub fn trace_instance_lod(
        &self,
        i: usize,
        origin: [f32; 3],
        dir: [f32; 3],
        t: [f32; 2],
        cone: f32,
    ) -> Option<SceneHit> {
        let r = self.ray_in(i, origin, dir, t);
        let svo = &self.models[self.instances[i].model as usize].svo;
        let h = super::lod_trace::trace_lod_scaled(svo, &r, cone, self.voxel_side(i))?;
        let instance = i as u32;
        Some(if h.level >= svo.levels {
            SceneHit::Voxel(InstanceHit {
                instance,
                voxel: h.cell,
                t: h.t,
            })
        } else {
            SceneHit::Node(NodeHit {
                instance,
                level: h.level,
                cell: h.cell,
                attr: h.attr,
                t: h.t,
            })
        })
    }

    /// The first voxel along a world ray `origin + t·dir`, t in `t` (both levels): the LOD
    /// walk with cone 0, which never stops on an aggregate.
    pub fn trace(&self, origin: [f32; 3], dir: [f32; 3], t: [f32; 2]) -> Option<InstanceHit> {
        match self.trace_lod(origin, dir, t, 0.0) {
            Some(SceneHit::Voxel(h)) => Some(h),
            _ => None,
        }
    }

    /// The world ray in top-grid units (the same `t`).
    fn top_ray(&self, origin: [f32; 3], dir: [f32; 3], t: [f32; 2]) -> VoxelRay {
        let top = &self.top;
        VoxelRay {
            origin: [0, 1, 2].map(|k| (origin[k] - top.origin[k]) / top.cell),
            dir: dir.map(|d| d / top.cell),
            t_min: t[0],
            t_max: t[1],
        }
    }

    /// The first top-level region along the ray, in cell `c` (at `cc`, entered at `tc`, left
    /// at `exit`), that stops the walk by the LOD rule: the cell itself when its side is at most
    /// `cone · tc` and its coverage [`can_stop`]; else its first occupied sub-cell, front to
    /// back, entered at `ts ≤ t1` with side/4 ≤ `cone · ts` that can stop.
    #[allow(clippy::too_many_arguments)]
    fn region_stop(
        &self,
        r: &VoxelRay,
        c: usize,
        cc: [f32; 3],
        tc: f32,
        exit: f32,
        t0: f32,
        t1: f32,
        cone: f32,
    ) -> Option<AggregateHit> {
        let a = &self.aggregates;
        let side = self.top.cell;
        if side <= cone * tc && can_stop(a.colors[c]) {
            return Some(AggregateHit {
                level: 0,
                attr: c as u32,
                t: tc,
            });
        }
        let mask = a.mask(c);
        let sub = side / SUB as f32;
        if mask == 0 || sub > cone * exit.min(t1) {
            return None;
        }
        let q = 1.0 / SUB as f32;
        let mut d = Dda::new(r, cc, q, [SUB as i64; 3], tc);
        loop {
            let s = slot(d.c);
            if mask >> s & 1 == 1 {
                let lo = [0, 1, 2].map(|k| cc[k] + d.c[k] as f32 * q);
                let ts = box_interval(r, lo, lo.map(|x| x + q)).0.max(t0);
                let attr = a.sub_attr(c, s);
                if ts <= t1 && sub <= cone * ts && can_stop(a.colors[attr]) {
                    return Some(AggregateHit {
                        level: 1,
                        attr: attr as u32,
                        t: ts,
                    });
                }
            }
            if d.exit() > t1 || !d.advance(SUB as i64) {
                return None;
            }
        }
    }

    /// The LOD walk (docs/CONVENTIONS.md, "Instanced SVO"): the terrain's voxels, then the top
    /// grid front to back; a cell or sub-cell whose side is at most `cone · t` where the walk
    /// enters it (t the later of its slab entry and the grid's) and whose aggregate covers at
    /// least [`super::lod_trace::MIN_STOP_ALPHA`]/255 ends the walk at that t, unless a voxel
    /// hit (terrain or an instance listed in a cell visited so far) lies at or before it; other
    /// cells trace their instances as [`InstancedSvo::trace`]. `dir` should be a unit vector:
    /// the footprint at t is `cone · t` world units. Cone 0 is the voxel walk exactly.
    pub fn trace_lod(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        t: [f32; 2],
        cone: f32,
    ) -> Option<SceneHit> {
        let mut best: Option<SceneHit> = None;
        let better = |h: &SceneHit, b: &Option<SceneHit>| match b {
            None => true,
            Some(b) => h.t() < b.t() || (h.t() == b.t() && h.instance() < b.instance()),
        };
        if self.terrain {
            best = self.trace_instance_lod(self.instances.len() - 1, origin, dir, t, cone);
        }
        let top = &self.top;
        let r = self.top_ray(origin, dir, t);
        let dims = top.dims.map(|d| d as f32);
        let (t0, t1) = box_interval(&r, [0.0; 3], dims);
        let (t0, t1) = (t0.max(t[0]), t1.min(t[1]));
        // Without instances only the aggregates (the terrain's) can stop a walk with a cone.
        if t0 > t1 || (self.cell_instances.is_empty() && cone <= 0.0) {
            return best;
        }
        let n = top.dims.map(|d| d as i64);
        let mut dda = Dda::new(&r, [0.0; 3], 1.0, n, t0);
        let mut tested: Vec<u32> = Vec::new();
        loop {
            let c = top.index(dda.c);
            let exit = dda.exit();
            let stop = if cone > 0.0 {
                let cc = dda.c.map(|x| x as f32);
                let tc = box_interval(&r, cc, cc.map(|x| x + 1.0)).0.max(t0);
                self.region_stop(&r, c, cc, tc, exit, t0, t1, cone)
            } else {
                None
            };
            let list =
                &self.cell_instances[self.cell_start[c] as usize..self.cell_start[c + 1] as usize];
            for &i in list {
                if tested.contains(&i) {
                    continue;
                }
                tested.push(i);
                let cap = best.map_or(t[1], |b| b.t());
                let cap = stop.map_or(cap, |s| cap.min(s.t));
                if let Some(h) = self.trace_instance_lod(i as usize, origin, dir, [t[0], cap], cone)
                    && better(&h, &best)
                {
                    best = Some(h);
                }
            }
            if let Some(s) = stop {
                return Some(match best {
                    Some(b) if b.t() <= s.t => b,
                    _ => SceneHit::Aggregate(s),
                });
            }
            if best.is_some_and(|b| b.t() < exit) || exit > t1 {
                return best;
            }
            let k = n.iter().copied().max().unwrap_or(1);
            if !dda.advance(k) || (0..3).any(|a| dda.c[a] >= n[a]) {
                return best;
            }
        }
    }

    /// Colour (linear RGBA, straight alpha: rgb/α, the coverage) and world normal (turned by
    /// the instance's rotation) of a model node.
    pub fn node_attributes(&self, h: &NodeHit) -> Option<([f32; 4], [f32; 3])> {
        let r = &self.instances[h.instance as usize];
        let svo = &self.models[r.model as usize].svo;
        let i = h.attr as usize;
        let c = super::svo::unpack_rgba8(*svo.node_colors.get(i)?);
        let n = r.dir_to_world(super::svo::unpack_normal(*svo.node_normals.get(i)?));
        Some((super::lod_trace::straight(c), n))
    }

    /// Colour (linear RGBA, straight alpha: rgb/α, the coverage) and world normal of an
    /// aggregate.
    pub fn aggregate_attributes(&self, a: &AggregateHit) -> ([f32; 4], [f32; 3]) {
        let i = a.attr as usize;
        (
            super::lod_trace::straight(super::svo::unpack_rgba8(self.aggregates.colors[i])),
            super::svo::unpack_normal(self.aggregates.normals[i]),
        )
    }

    /// Colour (linear RGBA, straight alpha) and world normal of a hit voxel.
    pub fn hit_attributes(&self, h: &InstanceHit) -> Option<([f32; 4], [f32; 3])> {
        let r = &self.instances[h.instance as usize];
        let svo = &self.models[r.model as usize].svo;
        let i = svo.voxel_index(h.voxel)?;
        let c = super::svo::unpack_rgba8(svo.voxel_colors[i]);
        let c = if c[3] > 0.0 {
            [c[0] / c[3], c[1] / c[3], c[2] / c[3], c[3]]
        } else {
            c
        };
        let n = r.dir_to_world(super::svo::unpack_normal(svo.voxel_normals[i]));
        Some((c, n))
    }

    /// Voxels of all models (each counted once), and bytes as stored.
    pub fn stats(&self) -> (u64, u64) {
        let mut voxels = 0;
        let mut bytes = 0;
        for m in &self.models {
            let s = m.svo.stats();
            voxels += s.voxels;
            bytes += s.topology_bytes + s.attribute_bytes;
        }
        bytes += 32 * self.instances.len() as u64
            + 4 * (self.cell_start.len() + self.cell_instances.len()) as u64
            + 16 * self.aggregates.nodes.len() as u64
            + 8 * self.aggregates.colors.len() as u64;
        (voxels, bytes)
    }
}

/// Bounds of the terrain's samples (those of `terrain_mesh`'s vertices, without building it).
pub fn terrain_bounds(t: &Terrain) -> Option<([f32; 3], [f32; 3])> {
    let (w, h) = (t.width.max(1), t.height.max(1));
    (0..h)
        .into_par_iter()
        .map(|j| {
            let first = t.position(0, j);
            (1..w).fold((first, first), |b, i| {
                let p = t.position(i, j);
                union(b, (p, p))
            })
        })
        .reduce_with(union)
}

/// A brick a terrain tile owns, with its voxels' colours and normals.
type TileBrick = (super::voxelize::Brick, Vec<[f32; 4]>, Vec<[f32; 3]>);

/// Terrain cells voxelized at once (about 2·10⁶ triangles, ≈ 0.5 GB of mesh and set-up).
pub const TERRAIN_TILE_CELLS: u64 = 1 << 20;

/// The terrain voxelized in `grid`, in tiles of about `tile_cells` cells: the same voxels and
/// attributes, bit for bit, as `mesh_to_voxels_in(terrain_mesh(t))` (a voxel's bits depend only
/// on the triangles that touch it, in index order; each tile owns whole columns of bricks and
/// takes every cell near them, in the mesh's order), with memory bounded by the tile.
pub fn terrain_voxels(
    t: &Terrain,
    grid: &Grid,
    opts: &VoxelizeOptions,
    tile_cells: u64,
) -> Result<Voxels> {
    let (w, h) = (t.width.max(1), t.height.max(1));
    let textures = if t.color.is_some() {
        vec![t.color.clone()]
    } else {
        Vec::new()
    };
    let cells = (w as u64 - 1) * (h as u64 - 1);
    if opts.solid || cells <= tile_cells || w < 2 || h < 2 {
        let g = super::geometry::terrain_mesh(t);
        return mesh_to_voxels_in(&g.mesh, &textures, grid, opts);
    }
    let dx = [t.extent[0] / (w - 1) as f32, t.extent[1] / (h - 1) as f32];
    let side_m = (tile_cells as f32).sqrt() * dx[0].min(dx[1]);
    let tile = (((side_m / grid.voxel_size[0]) as u32) / 4 * 4).max(4);
    let mut parts: Vec<TileBrick> = Vec::new();
    let mut skipped = 0;
    for vy0 in (0..grid.dims[1]).step_by(tile as usize) {
        for vx0 in (0..grid.dims[0]).step_by(tile as usize) {
            let own = [[vx0, vx0 + tile], [vy0, vy0 + tile]];
            let range = |k: usize, n: u32| {
                let lo = grid.origin[k] + own[k][0] as f32 * grid.voxel_size[k];
                let hi = grid.origin[k] + own[k][1] as f32 * grid.voxel_size[k];
                let c0 = ((lo - t.origin[k]) / dx[k]).floor() as i64 - 2;
                let c1 = ((hi - t.origin[k]) / dx[k]).ceil() as i64 + 2;
                (
                    c0.clamp(0, n as i64 - 2) as u32,
                    c1.clamp(0, n as i64 - 2) as u32,
                )
            };
            let (i0, i1) = range(0, w);
            let (j0, j1) = range(1, h);
            let mesh = super::geometry::terrain_tile_mesh(t, [i0, i1 + 1], [j0, j1 + 1]);
            let v = mesh_to_voxels_in(&mesh, &textures, grid, opts)?;
            skipped += v.skipped_triangles;
            let mut at = 0usize;
            for b in &v.bricks {
                let n = b.mask.count_ones() as usize;
                let c = super::morton_decode(b.key).map(|x| x * 4);
                if (0..2).all(|k| c[k] >= own[k][0] && c[k] < own[k][1]) {
                    parts.push((
                        *b,
                        v.colors[at..at + n].to_vec(),
                        v.normals[at..at + n].to_vec(),
                    ));
                }
                at += n;
            }
        }
    }
    parts.sort_by_key(|p| p.0.key);
    let mut out = Voxels {
        grid: *grid,
        bricks: Vec::with_capacity(parts.len()),
        colors: Vec::new(),
        normals: Vec::new(),
        skipped_triangles: skipped,
        open_columns: 0,
    };
    for (b, c, n) in parts {
        out.bricks.push(b);
        out.colors.extend(c);
        out.normals.extend(n);
    }
    Ok(out)
}

/// One model voxel as the aggregates read it: its centre in the model's frame, its stored
/// premultiplied colour and its stored normal (model frame), both decoded.
struct ModelVoxel {
    centre: [f32; 3],
    color: [f32; 4],
    normal: [f32; 3],
}

fn model_voxels(svo: &Svo) -> Vec<ModelVoxel> {
    let mut out = Vec::with_capacity(svo.voxel_colors.len());
    brick_voxels(svo, &svo.leaf_bricks(), 0, &mut out);
    out
}

/// The voxels of `bricks` (consecutive leaf bricks of `svo` in Morton order, the first voxel's
/// attribute index `first`), appended to `out`.
fn brick_voxels(
    svo: &Svo,
    bricks: &[super::voxelize::Brick],
    first: usize,
    out: &mut Vec<ModelVoxel>,
) {
    let mut i = first;
    for b in bricks {
        let mut m = b.mask;
        while m != 0 {
            let s = m.trailing_zeros() as u64;
            let v = super::morton_decode(b.key << 6 | s);
            out.push(ModelVoxel {
                centre: svo.grid.to_world(v.map(|x| x as f32 + 0.5)),
                color: super::svo::unpack_rgba8(svo.voxel_colors[i]),
                normal: super::svo::unpack_normal(svo.voxel_normals[i]),
            });
            i += 1;
            m &= m - 1;
        }
    }
}

/// The top cell and sub-cell slot holding world point `p` (clamped into the grid).
pub fn region_of(top: &TopGrid, p: [f32; 3]) -> (usize, u32) {
    let u = [0, 1, 2].map(|k| (p[k] - top.origin[k]) / top.cell);
    let c = [0, 1, 2].map(|k| (u[k].floor() as i64).clamp(0, top.dims[k] as i64 - 1));
    let sub = [0, 1, 2]
        .map(|k| (((u[k] - c[k] as f32) * SUB as f32).floor() as i64).clamp(0, SUB as i64 - 1));
    (top.index(c), slot(sub))
}

/// Sums of one region: Σ w·α, Σ w·rgb (premultiplied), Σ w·α·n (world), w the voxel's volume.
type Sums = [f64; 7];

fn add(a: &mut Sums, b: &Sums) {
    for k in 0..7 {
        a[k] += b[k];
    }
}

/// The stored colour and normal of a region of volume `vol` from its sums (see
/// [`TopAggregates`]).
pub fn aggregate_of(a: &[f64; 7], vol: f64) -> (u32, u32) {
    let l = (a[4] * a[4] + a[5] * a[5] + a[6] * a[6]).sqrt();
    let normal = if l > 0.0 {
        super::svo::pack_normal([a[4] / l, a[5] / l, a[6] / l].map(|x| x as f32))
    } else {
        0
    };
    if a[0] <= 0.0 {
        return (0, normal);
    }
    let alpha = (a[0] / vol).min(1.0);
    let k = alpha / a[0];
    let c = [a[1] * k, a[2] * k, a[3] * k, alpha].map(|x| x as f32);
    (super::svo::pack_rgba8(c), normal)
}

/// Instances summed per task: the sums' grouping, so the bytes do not depend on the threads.
const AGGREGATE_CHUNK: usize = 256;

/// Terrain bricks summed per task (the same reason).
const TERRAIN_AGGREGATE_BRICKS: usize = 1 << 14;

/// Appends the (region key, sums) of the voxels `voxels` of a model placed by `r`, whose voxels
/// are cubes of side `side` (the model's voxel side).
fn bin_voxels(
    s: &InstancedSvo,
    r: &InstanceRef,
    side: f32,
    voxels: &[ModelVoxel],
    raw: &mut Vec<(u64, Sums)>,
) {
    let w = (r.scale.abs() as f64 * side as f64).powi(3);
    for v in voxels {
        let (c, sl) = region_of(&s.top, r.to_world(v.centre));
        let n = r.dir_to_world(v.normal);
        let wa = w * v.color[3] as f64;
        raw.push((
            (c as u64) << 6 | sl as u64,
            [
                wa,
                w * v.color[0] as f64,
                w * v.color[1] as f64,
                w * v.color[2] as f64,
                wa * n[0] as f64,
                wa * n[1] as f64,
                wa * n[2] as f64,
            ],
        ));
    }
}

/// The top level's filtered attributes of a built scene (see [`TopAggregates`]). Every gridded
/// instance's voxels are placed (centre p + R_z(θ)·(s·x)) and the terrain's voxels taken as they
/// are (its identity placement), binned by centre, summed in f64 in a fixed order (instances in
/// chunks of [`AGGREGATE_CHUNK`], each in instance and Morton order, then the terrain's bricks
/// in chunks of [`TERRAIN_AGGREGATE_BRICKS`] in Morton order; the chunks' sums added in chunk
/// order), then quantized.
pub fn top_aggregates(s: &InstancedSvo) -> TopAggregates {
    let gridded = &s.instances[..s.grid_instances()];
    let terrain_model = s
        .terrain
        .then(|| s.instances[s.grid_instances()].model as usize);
    let voxels: Vec<Vec<ModelVoxel>> = s
        .models
        .iter()
        .enumerate()
        .map(|(m, model)| {
            if Some(m) == terrain_model {
                Vec::new()
            } else {
                model_voxels(&model.svo)
            }
        })
        .collect();
    let mut chunks: Vec<Vec<(u64, Sums)>> = gridded
        .par_chunks(AGGREGATE_CHUNK)
        .map(|chunk| {
            let mut raw: Vec<(u64, Sums)> = Vec::new();
            for r in chunk {
                let side = s.models[r.model as usize].svo.grid.voxel_size[0];
                bin_voxels(s, r, side, &voxels[r.model as usize], &mut raw);
            }
            collapse(raw)
        })
        .collect();
    if let Some(m) = terrain_model {
        let svo = &s.models[m].svo;
        let r = s.instances[s.grid_instances()];
        let bricks = svo.leaf_bricks();
        // The attribute index of each chunk's first voxel.
        let firsts: Vec<usize> = bricks
            .chunks(TERRAIN_AGGREGATE_BRICKS)
            .scan(0usize, |at, c| {
                let first = *at;
                *at += c
                    .iter()
                    .map(|b| b.mask.count_ones() as usize)
                    .sum::<usize>();
                Some(first)
            })
            .collect();
        let terrain: Vec<Vec<(u64, Sums)>> = bricks
            .par_chunks(TERRAIN_AGGREGATE_BRICKS)
            .zip(firsts)
            .map(|(c, first)| {
                let mut v = Vec::new();
                brick_voxels(svo, c, first, &mut v);
                let mut raw = Vec::with_capacity(v.len());
                bin_voxels(s, &r, svo.grid.voxel_size[0], &v, &mut raw);
                collapse(raw)
            })
            .collect();
        chunks.extend(terrain);
    }
    let merged = collapse(chunks.into_iter().flatten().collect());
    let cells = s.top.cells();
    let mut nodes = vec![[0u32; 4]; cells];
    let (mut colors, mut normals) = (vec![0u32; cells], vec![0u32; cells]);
    let (mut sub_colors, mut sub_normals) = (Vec::new(), Vec::new());
    let side = s.top.cell as f64;
    let (cell_vol, sub_vol) = (side.powi(3), (side / SUB as f64).powi(3));
    let mut i = 0;
    while i < merged.len() {
        let c = (merged[i].0 >> 6) as usize;
        let mut mask = 0u64;
        let mut sum = [0.0f64; 7];
        nodes[c][2] = sub_colors.len() as u32;
        while i < merged.len() && (merged[i].0 >> 6) as usize == c {
            let (key, sums) = &merged[i];
            mask |= 1 << (key & 63);
            add(&mut sum, sums);
            let (col, nor) = aggregate_of(sums, sub_vol);
            sub_colors.push(col);
            sub_normals.push(nor);
            i += 1;
        }
        nodes[c][0] = mask as u32;
        nodes[c][1] = (mask >> 32) as u32;
        (colors[c], normals[c]) = aggregate_of(&sum, cell_vol);
    }
    // Cells without sub-cells start where the next occupied one does (ascending firsts).
    let mut next = sub_colors.len() as u32;
    for n in nodes.iter_mut().rev() {
        if n[0] | n[1] == 0 {
            n[2] = next;
        } else {
            next = n[2];
        }
    }
    colors.extend(sub_colors);
    normals.extend(sub_normals);
    TopAggregates {
        nodes,
        colors,
        normals,
    }
}

/// Sorts (key, sums) pairs by key (stable) and adds equal keys' sums in their order.
fn collapse(mut v: Vec<(u64, Sums)>) -> Vec<(u64, Sums)> {
    v.sort_by_key(|e| e.0);
    let mut out: Vec<(u64, Sums)> = Vec::new();
    for (k, s) in v {
        match out.last_mut() {
            Some(last) if last.0 == k => add(&mut last.1, &s),
            _ => out.push((k, s)),
        }
    }
    out
}

/// World bounds of an instance's voxel grid box (its 8 corners placed).
pub fn instance_box(r: &InstanceRef, g: &Grid) -> ([f32; 3], [f32; 3]) {
    let c = grid_corners(g).map(|p| r.to_world(p));
    let b = c[1..].iter().fold((c[0], c[0]), |b, &p| union(b, (p, p)));
    // Grown by a millionth of the extent against rounding in the placement.
    let pad = (0..3).map(|k| b.1[k] - b.0[k]).fold(0.0f32, f32::max) * 1e-6 + 1e-6;
    (b.0.map(|x| x - pad), b.1.map(|x| x + pad))
}

/// The top grid over instance boxes: about two instances per cell over the union of the boxes
/// and `also` (the terrain's box), cubic cells, at most 256 per axis; CSR lists in instance
/// order.
pub fn top_grid(
    boxes: &[([f32; 3], [f32; 3])],
    also: Option<([f32; 3], [f32; 3])>,
) -> (TopGrid, Vec<u32>, Vec<u32>) {
    let Some(first) = also.as_ref().or(boxes.first()) else {
        let top = TopGrid {
            origin: [0.0; 3],
            cell: 1.0,
            dims: [1; 3],
        };
        return (top, vec![0, 0], Vec::new());
    };
    let (lo, hi) = boxes.iter().fold(*first, |a, &b| union(a, b));
    let ext = [0, 1, 2].map(|k| (hi[k] - lo[k]).max(1e-6));
    let longest = ext.iter().cloned().fold(0.0f32, f32::max);
    // Cells of a side that gives about n/2 cells over the boxes' union (volume / side³).
    let target = (boxes.len() as f64 / 2.0).max(1.0);
    let vol = ext.iter().map(|&e| e as f64).product::<f64>();
    let side = ((vol / target).cbrt() as f32).max(longest / 256.0);
    let dims = ext.map(|e| ((e / side).ceil() as u32).clamp(1, 256));
    let top = TopGrid {
        origin: lo,
        cell: side,
        dims,
    };
    let cell_range = |b: &([f32; 3], [f32; 3])| {
        let c =
            |x: f32, k: usize| (((x - lo[k]) / side).floor() as i64).clamp(0, dims[k] as i64 - 1);
        (
            [0, 1, 2].map(|k| c(b.0[k], k)),
            [0, 1, 2].map(|k| c(b.1[k], k)),
        )
    };
    let mut counts = vec![0u32; top.cells() + 1];
    for b in boxes {
        let (a, z) = cell_range(b);
        for cz in a[2]..=z[2] {
            for cy in a[1]..=z[1] {
                for cx in a[0]..=z[0] {
                    counts[top.index([cx, cy, cz]) + 1] += 1;
                }
            }
        }
    }
    for i in 1..counts.len() {
        counts[i] += counts[i - 1];
    }
    let mut fill = counts.clone();
    let mut list = vec![0u32; *counts.last().unwrap_or(&0) as usize];
    for (i, b) in boxes.iter().enumerate() {
        let (a, z) = cell_range(b);
        for cz in a[2]..=z[2] {
            for cy in a[1]..=z[1] {
                for cx in a[0]..=z[0] {
                    let c = top.index([cx, cy, cz]);
                    list[fill[c] as usize] = i as u32;
                    fill[c] += 1;
                }
            }
        }
    }
    (top, counts, list)
}

#[cfg(test)]
#[path = "instanced_tests.rs"]
pub(crate) mod tests;
