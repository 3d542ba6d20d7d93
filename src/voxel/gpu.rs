//! GPU ray traversal of the sparse voxel octree: the `svo` section's `nodes` and `leaves` arrays
//! bound as storage buffers exactly as packed ([`super::packed`]: bricks as 2³ sub-masks, read
//! byte by byte from u32 words; 64-bit masks as (low, high) u32 pairs), traversed by `shaders/svo_trace.wgsl`, which follows [`super::traverse`]
//! operation for operation. [`validate_svo`] compares it with the CPU on random rays.

use super::compute::{self, Kernel};
use super::svo::Svo;
use super::traverse::{Hit, VoxelRay, trace_svo};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::rng::Rng;
use bytemuck::{Pod, Zeroable};

pub(crate) const DDA_WGSL: &str = include_str!("shaders/dda.wgsl");
pub(crate) const SVO_COMMON_WGSL: &str = include_str!("shaders/svo_common.wgsl");
/// The octree walk shared by `svo_trace.wgsl` and `svo_scene.wgsl`.
pub(crate) const SVO_WALK_WGSL: &str = include_str!("shaders/svo_walk.wgsl");
const SVO_WGSL: &str = include_str!("shaders/svo_trace.wgsl");

/// Tolerance of the hit `t` between GPU and CPU, relative to max(1, |t|): the slab divisions
/// may be rounded differently by a GPU (Vulkan allows 2.5 ulp for a division).
pub const T_TOLERANCE: f32 = 1e-5;

/// The shader's `Params` (32 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    dims: [u32; 3],
    inner_levels: u32,
    side: f32,
    count: u32,
    stride: u32,
    node_count: u32,
}

/// The shaders' `GpuRay` (32 bytes; svo_trace, svo_lod and svo_scene read the same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuRay {
    pub(super) origin: [f32; 3],
    pub(super) t_min: f32,
    pub(super) dir: [f32; 3],
    pub(super) t_max: f32,
}
const _: () = assert!(size_of::<GpuRay>() == 32);

/// Whether a GPU hit's t is off the CPU's by more than [`T_TOLERANCE`]·max(1, |t|) (NaN is off).
pub(super) fn t_off(gpu_t: f32, cpu_t: f32) -> bool {
    let err = (gpu_t - cpu_t).abs();
    err > T_TOLERANCE * cpu_t.abs().max(1.0) || err.is_nan()
}

/// An octree resident on the GPU, with its traversal kernel.
pub struct SvoGpu<'g> {
    gpu: &'g Gpu,
    kernel: Kernel,
    nodes: wgpu::Buffer,
    leaves: wgpu::Buffer,
    dims: [u32; 3],
    levels: u32,
    node_count: u32,
}

impl<'g> SvoGpu<'g> {
    /// Uploads the octree's topology in its stored form (the bytes the `svo` section's `nodes`
    /// and `leaves` arrays hold).
    pub fn new(gpu: &'g Gpu, svo: &Svo) -> Result<Self> {
        let (nodes, leaves) = super::packed::pack_leaves(svo);
        Self::from_arrays(
            gpu,
            svo.grid.dims,
            svo.levels,
            bytemuck::cast_slice(&nodes),
            &leaves,
        )
    }

    /// From the raw section arrays (`nodes`: u32×4 per node, `leaves`: bytes), e.g. the slices
    /// of a [`crate::pack::section::SectionView`]; the caller has validated them.
    pub fn from_arrays(
        gpu: &'g Gpu,
        dims: [u32; 3],
        levels: u32,
        nodes: &[u8],
        leaves: &[u8],
    ) -> Result<Self> {
        if !(2..=11).contains(&levels) {
            return Err(Error::runtime(format!(
                "svo: {levels} levels (the GPU kernel handles 2..=11)"
            )));
        }
        Ok(SvoGpu {
            gpu,
            kernel: Kernel::new(
                gpu,
                "svo trace",
                &[DDA_WGSL, SVO_COMMON_WGSL, SVO_WALK_WGSL, SVO_WGSL],
                "main",
                3,
            )?,
            nodes: compute::storage(gpu, "svo nodes", nodes)?,
            leaves: compute::storage(gpu, "svo leaves", leaves)?,
            dims,
            levels,
            node_count: (nodes.len() / 16) as u32,
        })
    }

    /// First hit of each ray (voxel units), as [`trace_svo`] computes it.
    pub fn trace(&self, rays: &[VoxelRay]) -> Result<Vec<Option<Hit>>> {
        let count = u32::try_from(rays.len())
            .map_err(|_| Error::runtime("svo trace: more than 2³² rays"))?;
        let (grid, stride) = compute::grid_for(count);
        let params = Params {
            dims: self.dims,
            inner_levels: self.levels - 1,
            side: 4f32.powi(self.levels as i32),
            count,
            stride,
            node_count: self.node_count,
        };
        let gpu_rays: Vec<GpuRay> = rays
            .iter()
            .map(|r| GpuRay {
                origin: r.origin,
                t_min: r.t_min,
                dir: r.dir,
                t_max: r.t_max,
            })
            .collect();
        let g = self.gpu;
        let uniform = compute::uniform(g, "svo params", bytemuck::bytes_of(&params));
        let input = compute::storage(g, "svo rays", bytemuck::cast_slice(&gpu_rays))?;
        let bytes = 16 * rays.len() as u64;
        let out = compute::output(g, "svo hits", bytes);
        let raw = self.kernel.run(
            g,
            &uniform,
            &[&self.nodes, &self.leaves, &input],
            &out,
            grid,
            bytes,
        )?;
        let words: &[[u32; 4]] = bytemuck::cast_slice(&raw);
        Ok(words
            .iter()
            .map(|w| {
                (w[0] != u32::MAX).then(|| Hit {
                    voxel: [w[0], w[1], w[2]],
                    t: f32::from_bits(w[3]),
                })
            })
            .collect())
    }
}

/// Traversal on the CPU that tolerates an empty octree (no root node).
pub fn trace_svo_cpu(svo: &Svo, r: &VoxelRay) -> Option<Hit> {
    if svo.nodes.is_empty() {
        None
    } else {
        trace_svo(svo, r)
    }
}

/// Random rays in voxel units: half start inside the grid, half outside looking at it, with
/// random directions and some t ranges cut short.
pub fn random_rays(dims: [u32; 3], count: usize, seed: u64) -> Vec<VoxelRay> {
    let mut rng = Rng::new(seed);
    let d = dims.map(|x| x as f32);
    (0..count)
        .map(|i| {
            let origin = if i % 2 == 0 {
                [0, 1, 2].map(|k| rng.range(0.0, d[k]))
            } else {
                [0, 1, 2].map(|k| rng.range(-0.5 * d[k], 1.5 * d[k]))
            };
            let target = [0, 1, 2].map(|k| rng.range(0.0, d[k]));
            let mut dir = [0, 1, 2].map(|k| target[k] - origin[k] + rng.range(-1.0, 1.0));
            // Some rays parallel to an axis or a plane.
            if i % 10 == 3 {
                dir[(rng.next_u64() % 3) as usize] = 0.0;
            }
            if dir == [0.0; 3] {
                dir = [1.0, 0.5, 0.25];
            }
            let t_max = if i % 5 == 0 {
                rng.range(0.1, 1.0)
            } else {
                f32::INFINITY
            };
            VoxelRay {
                origin,
                dir,
                t_min: 0.0,
                t_max,
            }
        })
        .collect()
}

/// Agreement of GPU and CPU traversal on a batch of rays.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SvoAgreement {
    pub rays: usize,
    pub hits: usize,
    /// Rays where the GPU and the CPU hit different voxels (or only one hits).
    pub voxel_mismatches: usize,
    /// Rays with the same voxel but |t_gpu − t_cpu| > T_TOLERANCE·max(1, |t|).
    pub t_mismatches: usize,
    pub max_t_error: f32,
    pub t_tolerance: f32,
    /// Up to 5 disagreeing ray indices.
    pub examples: Vec<usize>,
    /// Wall time of the GPU batch (upload, dispatch, read-back) and of the CPU traversal.
    pub gpu_seconds: f64,
    pub cpu_seconds: f64,
}

impl SvoAgreement {
    pub fn agrees(&self) -> bool {
        self.voxel_mismatches == 0 && self.t_mismatches == 0
    }
}

/// Compares GPU answers with the CPU's.
pub fn compare_hits(gpu: &[Option<Hit>], cpu: &[Option<Hit>]) -> SvoAgreement {
    let mut a = SvoAgreement {
        rays: cpu.len(),
        t_tolerance: T_TOLERANCE,
        ..Default::default()
    };
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let bad = match (g, c) {
            (None, None) => false,
            (Some(g), Some(c)) if g.voxel == c.voxel => {
                a.hits += 1;
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
    a.voxel_mismatches += gpu.len().abs_diff(cpu.len());
    a
}

/// Traces `rays` random rays on the GPU and the CPU and compares them.
pub fn validate_svo(gpu: &Gpu, svo: &Svo, rays: usize, seed: u64) -> Result<SvoAgreement> {
    let batch = random_rays(svo.grid.dims, rays, seed);
    let dev = SvoGpu::new(gpu, svo)?;
    let t0 = std::time::Instant::now();
    let on_gpu = dev.trace(&batch)?;
    let t1 = std::time::Instant::now();
    let on_cpu: Vec<Option<Hit>> = batch.iter().map(|r| trace_svo_cpu(svo, r)).collect();
    let t2 = std::time::Instant::now();
    Ok(SvoAgreement {
        gpu_seconds: (t1 - t0).as_secs_f64(),
        cpu_seconds: (t2 - t1).as_secs_f64(),
        ..compare_hits(&on_gpu, &on_cpu)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{BackendChoice, init_gpu};
    use crate::voxel::svo::voxels_to_svo;
    use crate::voxel::tests::{Rng, random_voxels};

    #[test]
    fn gpu_traversal_equals_cpu_on_every_ray() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let mut rng = Rng::new(5);
        // 2 to 5 levels, non-cubic grids that are not multiples of 4.
        for dims in [[4, 4, 4], [37, 20, 45], [130, 17, 9], [300, 41, 22]] {
            let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
            let a = validate_svo(&gpu, &svo, 20_000, dims[0] as u64).unwrap();
            assert!(a.agrees(), "dims {dims:?}: {a:?}");
            assert_eq!(a.rays, 20_000);
            assert!(a.hits > 2_000, "dims {dims:?}: only {} hits", a.hits);
        }
    }

    #[test]
    fn an_empty_octree_misses_everything_on_the_gpu() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let mut v = random_voxels(&mut Rng::new(1), [8, 8, 8]);
        v.bricks.clear();
        v.colors.clear();
        v.normals.clear();
        let svo = voxels_to_svo(&v);
        assert!(svo.nodes.is_empty());
        let rays = random_rays([8, 8, 8], 100, 3);
        let hits = SvoGpu::new(&gpu, &svo).unwrap().trace(&rays).unwrap();
        assert!(hits.iter().all(|h| h.is_none()));
    }

    #[test]
    fn compare_hits_counts_each_kind_of_disagreement() {
        let h = |x: u32, t: f32| {
            Some(Hit {
                voxel: [x, 0, 0],
                t,
            })
        };
        let cpu = [h(1, 2.0), h(1, 2.0), None, h(3, 100.0)];
        let gpu = [h(1, 2.0), h(2, 2.0), h(1, 1.0), h(3, 100.01)];
        let a = compare_hits(&gpu, &cpu);
        assert_eq!((a.voxel_mismatches, a.t_mismatches), (2, 1));
        assert_eq!(a.examples, vec![1, 2, 3]);
        assert!(!a.agrees());
    }
}
