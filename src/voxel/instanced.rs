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
//! best hit lies before the current cell's exit.

use super::Grid;
use super::geometry::Geometry;
use super::svo::{Svo, voxels_to_svo};
use super::traverse::{Dda, VoxelRay, box_interval, trace_svo};
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
        let (top, cell_start, cell_instances) = top_grid(&boxes);
        Ok(InstancedSvo {
            scene_grid,
            models: out_models,
            instances: refs,
            terrain: has_terrain,
            top,
            cell_start,
            cell_instances,
        })
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

    /// The first voxel along a world ray `origin + t·dir`, t in `t` (both levels).
    pub fn trace(&self, origin: [f32; 3], dir: [f32; 3], t: [f32; 2]) -> Option<InstanceHit> {
        let mut best: Option<InstanceHit> = None;
        let better = |h: InstanceHit, b: &Option<InstanceHit>| match b {
            None => true,
            Some(b) => h.t < b.t || (h.t == b.t && h.instance < b.instance),
        };
        if self.terrain {
            best = self.trace_instance(self.instances.len() - 1, origin, dir, t);
        }
        let top = &self.top;
        let r = VoxelRay {
            origin: [0, 1, 2].map(|k| (origin[k] - top.origin[k]) / top.cell),
            dir: dir.map(|d| d / top.cell),
            t_min: t[0],
            t_max: t[1],
        };
        let dims = top.dims.map(|d| d as f32);
        let (t0, t1) = box_interval(&r, [0.0; 3], dims);
        let (t0, t1) = (t0.max(t[0]), t1.min(t[1]));
        if t0 > t1 || self.cell_instances.is_empty() {
            return best;
        }
        let n = top.dims.map(|d| d as i64);
        let mut dda = Dda::new(&r, [0.0; 3], 1.0, n, t0);
        let mut tested: Vec<u32> = Vec::new();
        loop {
            let c = top.index(dda.c);
            let list =
                &self.cell_instances[self.cell_start[c] as usize..self.cell_start[c + 1] as usize];
            for &i in list {
                if tested.contains(&i) {
                    continue;
                }
                tested.push(i);
                let cap = best.map_or(t[1], |b| b.t);
                if let Some(h) = self.trace_instance(i as usize, origin, dir, [t[0], cap])
                    && better(h, &best)
                {
                    best = Some(h);
                }
            }
            let exit = dda.exit();
            if best.is_some_and(|b| b.t < exit) || exit > t1 {
                return best;
            }
            let k = n.iter().copied().max().unwrap_or(1);
            if !dda.advance(k) || (0..3).any(|a| dda.c[a] >= n[a]) {
                return best;
            }
        }
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
            + 4 * (self.cell_start.len() + self.cell_instances.len()) as u64;
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

/// World bounds of an instance's voxel grid box (its 8 corners placed).
pub fn instance_box(r: &InstanceRef, g: &Grid) -> ([f32; 3], [f32; 3]) {
    let c = grid_corners(g).map(|p| r.to_world(p));
    let b = c[1..].iter().fold((c[0], c[0]), |b, &p| union(b, (p, p)));
    // Grown by a millionth of the extent against rounding in the placement.
    let pad = (0..3).map(|k| b.1[k] - b.0[k]).fold(0.0f32, f32::max) * 1e-6 + 1e-6;
    (b.0.map(|x| x - pad), b.1.map(|x| x + pad))
}

/// The top grid over instance boxes: about two instances per cell over the boxes' union,
/// cubic cells, at most 256 per axis; CSR lists in instance order.
pub fn top_grid(boxes: &[([f32; 3], [f32; 3])]) -> (TopGrid, Vec<u32>, Vec<u32>) {
    let Some(first) = boxes.first() else {
        let top = TopGrid {
            origin: [0.0; 3],
            cell: 1.0,
            dims: [1; 3],
        };
        return (top, vec![0, 0], Vec::new());
    };
    let (lo, hi) = boxes[1..].iter().fold(*first, |a, &b| union(a, b));
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
