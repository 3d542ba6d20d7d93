//! GPU traversal of the two-level SVO (`shaders/svo_scene.wgsl`): the `svo-scene` section's
//! arrays bound as stored (the models' `nodes` and `leaves` one after another, the `instances`
//! records, `cell_start` followed by `cell_instances` in one buffer) plus a table of the models'
//! grids, following [`InstancedSvo::trace`] operation for operation. [`validate_instanced`]
//! compares it with the CPU on random world rays.

use super::compute::{self, Kernel};
use super::gpu::{DDA_WGSL, GpuRay, SVO_COMMON_WGSL, SVO_WALK_WGSL, t_off};
use super::instanced::{AggregateHit, InstanceHit, InstancedSvo, NodeHit, SceneHit};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::rng::Rng;
use bytemuck::{Pod, Zeroable};

const SCENE_WGSL: &str = include_str!("shaders/svo_scene.wgsl");

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    top_origin: [f32; 3],
    top_cell: f32,
    top_dims: [u32; 3],
    count: u32,
    stride: u32,
    instances: u32,
    terrain: u32,
    list_base: u32,
    cone: f32,
    node_base: u32,
    color_base: u32,
    brick_base: u32,
    attr_base: u32,
    pad: [u32; 3],
}
const _: () = assert!(size_of::<Params>() == 80);

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuModel {
    origin: [f32; 3],
    inner_levels: u32,
    voxel_size: [f32; 3],
    side: f32,
    dims: [u32; 3],
    first_node: u32,
    first_leaf: u32,
    first_attr: u32,
    node_count: u32,
    pad: u32,
}
const _: () = assert!(size_of::<GpuModel>() == 64);

/// A world ray: origin, direction, [t_min, t_max].
pub type WorldRay = ([f32; 3], [f32; 3], [f32; 2]);

/// Marks an aggregate in the shader's output.
const AGG: u32 = u32::MAX - 1;

/// First hits of world rays on the GPU, as [`InstancedSvo::trace_lod`] computes them with
/// `cone` (0: the voxels, as [`InstancedSvo::trace`]).
pub fn trace_gpu(
    gpu: &Gpu,
    s: &InstancedSvo,
    rays: &[WorldRay],
    cone: f32,
) -> Result<Vec<Option<SceneHit>>> {
    if s.models.is_empty() || s.instances.is_empty() {
        return Ok(vec![None; rays.len()]);
    }
    if s.models.iter().any(|m| !(2..=11).contains(&m.svo.levels)) {
        return Err(Error::runtime("svo-scene: a model of more than 11 levels"));
    }
    let mut nodes = Vec::new();
    let mut leaves = Vec::new();
    let mut models = Vec::new();
    // Per global node: its first brick (local to its model) on a last inner level, else 0;
    // per global filtered attribute: its colour.
    let (mut brick_first, mut node_colors) = (Vec::new(), Vec::new());
    for m in &s.models {
        let (n, l) = super::packed::pack_leaves(&m.svo);
        let g = m.svo.grid;
        models.push(GpuModel {
            origin: g.origin,
            inner_levels: m.svo.levels - 1,
            voxel_size: g.voxel_size,
            side: 4f32.powi(m.svo.levels as i32),
            dims: g.dims,
            first_node: nodes.len() as u32,
            first_leaf: leaves.len() as u32,
            first_attr: node_colors.len() as u32,
            node_count: m.svo.nodes.len() as u32,
            pad: 0,
        });
        nodes.extend(n);
        leaves.extend(l);
        brick_first.extend(super::lod_gpu::brick_first(&m.svo));
        node_colors.extend(&m.svo.node_colors);
    }
    // The shader reads bytes from u32 words.
    while leaves.len() % 4 != 0 {
        leaves.push(0);
    }
    let mut cells = s.cell_start.clone();
    cells.extend(&s.cell_instances);
    let node_base = cells.len() as u32;
    cells.extend(s.aggregates.nodes.iter().flatten());
    let color_base = cells.len() as u32;
    cells.extend(&s.aggregates.colors);
    let brick_base = cells.len() as u32;
    cells.extend(&brick_first);
    let attr_base = cells.len() as u32;
    cells.extend(&node_colors);
    let count =
        u32::try_from(rays.len()).map_err(|_| Error::runtime("svo-scene trace: too many rays"))?;
    let (grid, stride) = compute::grid_for(count);
    let params = Params {
        top_origin: s.top.origin,
        top_cell: s.top.cell,
        top_dims: s.top.dims,
        count,
        stride,
        instances: s.instances.len() as u32,
        terrain: s.terrain as u32,
        list_base: s.cell_start.len() as u32,
        cone,
        node_base,
        color_base,
        brick_base,
        attr_base,
        pad: [0; 3],
    };
    let big = |t: f32| {
        if t.is_finite() {
            t
        } else {
            3.0e38f32.copysign(t)
        }
    };
    let gpu_rays: Vec<GpuRay> = rays
        .iter()
        .map(|(o, d, t)| GpuRay {
            origin: *o,
            t_min: big(t[0]),
            dir: *d,
            t_max: big(t[1]),
        })
        .collect();
    let kernel = Kernel::new(
        gpu,
        "svo-scene trace",
        &[DDA_WGSL, SVO_COMMON_WGSL, SVO_WALK_WGSL, SCENE_WGSL],
        "main",
        6,
    )?;
    let g = gpu;
    let buffers = [
        compute::storage(g, "svo-scene nodes", bytemuck::cast_slice(&nodes))?,
        compute::storage(g, "svo-scene leaves", &leaves)?,
        compute::storage(g, "svo-scene models", bytemuck::cast_slice(&models))?,
        compute::storage(g, "svo-scene instances", bytemuck::cast_slice(&s.instances))?,
        compute::storage(g, "svo-scene cells", bytemuck::cast_slice(&cells))?,
        compute::storage(g, "svo-scene rays", bytemuck::cast_slice(&gpu_rays))?,
    ];
    let uniform = compute::uniform(g, "svo-scene params", bytemuck::bytes_of(&params));
    let bytes = 32 * rays.len() as u64;
    let out = compute::output(g, "svo-scene hits", bytes);
    let inputs: Vec<&wgpu::Buffer> = buffers.iter().collect();
    let raw = kernel.run(g, &uniform, &inputs, &out, grid, bytes)?;
    let words: &[[u32; 8]] = bytemuck::cast_slice(&raw);
    Ok(words
        .iter()
        .map(|w| match w[0] {
            u32::MAX => None,
            AGG => Some(SceneHit::Aggregate(AggregateHit {
                level: w[2],
                attr: w[1],
                t: f32::from_bits(w[4]),
            })),
            i => {
                let levels = s.models[s.instances[i as usize].model as usize].svo.levels;
                Some(if w[5] >= levels {
                    SceneHit::Voxel(InstanceHit {
                        instance: i,
                        voxel: [w[1], w[2], w[3]],
                        t: f32::from_bits(w[4]),
                    })
                } else {
                    SceneHit::Node(NodeHit {
                        instance: i,
                        level: w[5],
                        cell: [w[1], w[2], w[3]],
                        attr: w[6],
                        t: f32::from_bits(w[4]),
                    })
                })
            }
        })
        .collect())
}

/// Random world rays around and through the scene grid's box: half from inside, half from
/// outside towards a point inside; some with a short `t_max`.
pub fn random_world_rays(s: &InstancedSvo, count: usize, seed: u64) -> Vec<WorldRay> {
    let g = &s.scene_grid;
    let lo = g.origin;
    let hi = g.to_world(g.dims.map(|d| d as f32));
    let mut rng = Rng::new(seed);
    (0..count)
        .map(|i| {
            let inside = [0, 1, 2].map(|k| rng.range(lo[k], hi[k]));
            let ext = [0, 1, 2].map(|k| hi[k] - lo[k]);
            let origin = if i % 2 == 0 {
                inside
            } else {
                [0, 1, 2].map(|k| rng.range(lo[k] - 0.5 * ext[k], hi[k] + 0.5 * ext[k]))
            };
            let target = [0, 1, 2].map(|k| rng.range(lo[k], hi[k]));
            let mut d = [0, 1, 2].map(|k| target[k] - origin[k]);
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
            d = d.map(|x| x / l);
            let t_max = if i % 5 == 0 {
                rng.range(0.0, l)
            } else {
                f32::INFINITY
            };
            (origin, d, [0.0, t_max])
        })
        .collect()
}

/// Agreement of the GPU and CPU traversals of the two-level SVO.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct InstancedAgreement {
    pub rays: usize,
    pub hits: usize,
    /// Of the agreeing hits, those on instances (not the terrain).
    pub instance_hits: usize,
    /// Rays where the two hit different (instance, voxel) pairs, or only one hits.
    pub voxel_mismatches: usize,
    /// Same (instance, voxel) with |t_gpu − t_cpu| > T_TOLERANCE·max(1, |t|).
    pub t_mismatches: usize,
    pub max_t_error: f32,
    pub examples: Vec<usize>,
    pub gpu_seconds: f64,
    pub cpu_seconds: f64,
    /// The same rays walked with [`lod_cone`] (the top level's aggregates on).
    pub lod: LodSceneAgreement,
}

/// Agreement of the LOD walks ([`InstancedSvo::trace_lod`] and the shader) on the same rays.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LodSceneAgreement {
    pub cone: f32,
    pub rays: usize,
    pub hits: usize,
    /// Of the agreeing hits, those on aggregates (top cells and sub-cells).
    pub aggregate_hits: usize,
    /// Of the agreeing hits, those on the models' filtered nodes inside instances (or the
    /// terrain).
    pub node_hits: usize,
    /// Rays whose answers differ (another voxel or region, only one hits, or t off).
    pub mismatches: usize,
    pub examples: Vec<usize>,
}

impl InstancedAgreement {
    /// The voxel walk agrees on every ray; the LOD walk on all but at most
    /// [`super::lod_gpu::LOD_MISMATCH_FRACTION`] of them (a level choice `s ≤ cone·t` flips
    /// where t lands on the boundary and the GPU rounds a division differently).
    pub fn agrees(&self) -> bool {
        self.voxel_mismatches == 0
            && self.t_mismatches == 0
            && self.lod.mismatches as f64
                <= super::lod_gpu::LOD_MISMATCH_FRACTION * self.lod.rays as f64
    }
}

/// The cone of the validation's LOD batch: a top cell stops the walk from one scene diagonal
/// away, a sub-cell from a quarter of it.
pub fn lod_cone(s: &InstancedSvo) -> f32 {
    let g = &s.scene_grid;
    let ext = [0, 1, 2].map(|k| g.dims[k] as f32 * g.voxel_size[k]);
    let diag = (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]).sqrt();
    s.top.cell / diag.max(1e-6)
}

/// Whether two answers of the LOD walk agree (same voxel or region, t within tolerance).
pub fn same_scene_hit(g: &Option<SceneHit>, c: &Option<SceneHit>) -> bool {
    match (g, c) {
        (None, None) => true,
        (Some(SceneHit::Voxel(g)), Some(SceneHit::Voxel(c))) => {
            g.instance == c.instance && g.voxel == c.voxel && !t_off(g.t, c.t)
        }
        (Some(SceneHit::Node(g)), Some(SceneHit::Node(c))) => {
            (g.instance, g.level, g.cell, g.attr) == (c.instance, c.level, c.cell, c.attr)
                && !t_off(g.t, c.t)
        }
        (Some(SceneHit::Aggregate(g)), Some(SceneHit::Aggregate(c))) => {
            g.attr == c.attr && g.level == c.level && !t_off(g.t, c.t)
        }
        _ => false,
    }
}

/// Traces `rays` random world rays on both and compares them: the voxel walk (cone 0), then
/// the LOD walk with [`lod_cone`].
pub fn validate_instanced(
    gpu: &Gpu,
    s: &InstancedSvo,
    rays: usize,
    seed: u64,
) -> Result<InstancedAgreement> {
    let batch = random_world_rays(s, rays, seed);
    let t0 = std::time::Instant::now();
    let on_gpu = trace_gpu(gpu, s, &batch, 0.0)?;
    let t1 = std::time::Instant::now();
    let on_cpu: Vec<Option<InstanceHit>> =
        batch.iter().map(|(o, d, t)| s.trace(*o, *d, *t)).collect();
    let t2 = std::time::Instant::now();
    let mut a = InstancedAgreement {
        rays,
        gpu_seconds: (t1 - t0).as_secs_f64(),
        cpu_seconds: (t2 - t1).as_secs_f64(),
        ..Default::default()
    };
    for (i, (g, c)) in on_gpu.iter().zip(&on_cpu).enumerate() {
        let g = match g {
            Some(SceneHit::Voxel(h)) => Some(*h),
            Some(SceneHit::Aggregate(_) | SceneHit::Node(_)) => {
                return Err(Error::runtime(
                    "svo-scene: an aggregate or model node hit with cone 0",
                ));
            }
            None => None,
        };
        let bad = match (g, c) {
            (None, None) => false,
            (Some(g), Some(c)) if g.instance == c.instance && g.voxel == c.voxel => {
                a.hits += 1;
                a.instance_hits += ((c.instance as usize) < s.grid_instances()) as usize;
                a.max_t_error = a.max_t_error.max((g.t - c.t).abs());
                let off = t_off(g.t, c.t);
                a.t_mismatches += off as usize;
                off
            }
            _ => {
                a.voxel_mismatches += 1;
                true
            }
        };
        if bad && a.examples.len() < 5 {
            a.examples.push(i);
        }
    }
    let cone = lod_cone(s);
    let on_gpu = trace_gpu(gpu, s, &batch, cone)?;
    let on_cpu: Vec<Option<SceneHit>> = batch
        .iter()
        .map(|(o, d, t)| s.trace_lod(*o, *d, *t, cone))
        .collect();
    a.lod = LodSceneAgreement {
        cone,
        rays,
        ..Default::default()
    };
    for (i, (g, c)) in on_gpu.iter().zip(&on_cpu).enumerate() {
        if !same_scene_hit(g, c) {
            a.lod.mismatches += 1;
            if a.lod.examples.len() < 5 {
                a.lod.examples.push(i);
            }
        } else if let Some(h) = c {
            a.lod.hits += 1;
            a.lod.aggregate_hits += matches!(h, SceneHit::Aggregate(_)) as usize;
            a.lod.node_hits += matches!(h, SceneHit::Node(_)) as usize;
        }
    }
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{BackendChoice, init_gpu};

    #[test]
    fn gpu_two_level_traversal_equals_cpu() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let s = super::super::instanced::tests::test_scene(64);
        let a = validate_instanced(&gpu, &s, 4000, 17).unwrap();
        assert!(a.hits > 1000 && a.instance_hits > 200, "{a:?}");
        assert!(a.agrees(), "{a:?}");
        // The LOD batch stops on aggregates of both levels and on the models' nodes inside
        // instances, and agrees on every ray here.
        assert!(a.lod.aggregate_hits > 200, "{:?}", a.lod);
        assert!(a.lod.node_hits > 100, "{:?}", a.lod);
        assert_eq!(a.lod.mismatches, 0, "{:?}", a.lod);
    }
}
