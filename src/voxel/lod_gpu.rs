//! The level-of-detail traversal ([`super::lod_trace`]) on the GPU: `shaders/svo_lod.wgsl`, with
//! the `svo` section's `nodes` and `leaves` bound as [`super::gpu`] binds them, the filtered and
//! voxel attributes as (colour, normal) pairs, and per last-level inner node the index of its
//! first brick (the packed nodes point at bytes of `leaves`, the filtered values are indexed by
//! brick). [`compare_lod_hits`] measures its agreement with the CPU on the same rays.

use super::compute::{self, Kernel};
use super::gpu::{DDA_WGSL, GpuRay, SVO_COMMON_WGSL, SVO_WALK_WGSL, t_off};
use super::lod_trace::LodHit;
use super::svo::Svo;
use super::traverse::VoxelRay;
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use bytemuck::{Pod, Zeroable};

const LOD_WGSL: &str = include_str!("shaders/svo_lod.wgsl");

/// The shader's `Params` (48 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    dims: [u32; 3],
    inner_levels: u32,
    side: f32,
    count: u32,
    stride: u32,
    node_count: u32,
    cone: f32,
    levels: u32,
    pad: [u32; 2],
}
const _: () = assert!(size_of::<Params>() == 48);

/// An octree with its attributes resident on the GPU, with the LOD kernel.
pub struct SvoLodGpu<'g> {
    gpu: &'g Gpu,
    kernel: Kernel,
    buffers: [wgpu::Buffer; 5],
    dims: [u32; 3],
    levels: u32,
    node_count: u32,
}

/// Per inner node of `svo`: on the last inner level the index of its first brick (the packed
/// node holds a byte offset into `leaves` instead), elsewhere 0.
pub(crate) fn brick_first(svo: &Svo) -> Vec<u32> {
    let last = svo.inner_levels().saturating_sub(1);
    (0..svo.nodes.len())
        .map(|i| {
            let on_last = svo.level_start.get(last).is_some_and(|&s| i as u32 >= s);
            if on_last { svo.nodes[i].first_child } else { 0 }
        })
        .collect()
}

/// (colour, normal) pairs of two parallel arrays.
fn interleave(colors: &[u32], normals: &[u32]) -> Vec<[u32; 2]> {
    colors.iter().zip(normals).map(|(&c, &n)| [c, n]).collect()
}

impl<'g> SvoLodGpu<'g> {
    pub fn new(gpu: &'g Gpu, svo: &Svo) -> Result<Self> {
        if !(2..=11).contains(&svo.levels) {
            return Err(Error::runtime(format!(
                "svo: {} levels (the GPU kernel handles 2..=11)",
                svo.levels
            )));
        }
        let (nodes, leaves) = super::packed::pack_leaves(svo);
        let brick_first = brick_first(svo);
        let node_attrs = interleave(&svo.node_colors, &svo.node_normals);
        let voxel_attrs = interleave(&svo.voxel_colors, &svo.voxel_normals);
        let buffers = [
            compute::storage(gpu, "svo nodes", bytemuck::cast_slice(&nodes))?,
            compute::storage(gpu, "svo leaves", &leaves)?,
            compute::storage(gpu, "svo brick index", bytemuck::cast_slice(&brick_first))?,
            compute::storage(
                gpu,
                "svo node attributes",
                bytemuck::cast_slice(&node_attrs),
            )?,
            compute::storage(
                gpu,
                "svo voxel attributes",
                bytemuck::cast_slice(&voxel_attrs),
            )?,
        ];
        let parts = [DDA_WGSL, SVO_COMMON_WGSL, SVO_WALK_WGSL, LOD_WGSL];
        Ok(SvoLodGpu {
            gpu,
            kernel: Kernel::new(gpu, "svo lod trace", &parts, "main", 6)?,
            buffers,
            dims: svo.grid.dims,
            levels: svo.levels,
            node_count: svo.nodes.len() as u32,
        })
    }

    /// The stopping cell of each ray (voxel units) at footprint `cone · t`, as
    /// [`super::lod_trace::trace_lod`] finds it.
    pub fn trace(&self, rays: &[VoxelRay], cone: f32) -> Result<Vec<Option<LodHit>>> {
        let count = u32::try_from(rays.len())
            .map_err(|_| Error::runtime("svo lod trace: more than 2³² rays"))?;
        let (grid, stride) = compute::grid_for(count);
        let params = Params {
            dims: self.dims,
            inner_levels: self.levels - 1,
            side: 4f32.powi(self.levels as i32),
            count,
            stride,
            node_count: self.node_count,
            cone,
            levels: self.levels,
            pad: [0; 2],
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
        let uniform = compute::uniform(g, "svo lod params", bytemuck::bytes_of(&params));
        let input = compute::storage(g, "svo lod rays", bytemuck::cast_slice(&gpu_rays))?;
        let bytes = 32 * rays.len() as u64;
        let out = compute::output(g, "svo lod hits", bytes);
        let [a, b, c, d, e] = &self.buffers;
        let raw = self
            .kernel
            .run(g, &uniform, &[a, b, c, d, e, &input], &out, grid, bytes)?;
        let words: &[[u32; 8]] = bytemuck::cast_slice(&raw);
        Ok(words
            .iter()
            .map(|w| {
                (w[0] != u32::MAX).then(|| LodHit {
                    level: w[0],
                    t: f32::from_bits(w[1]),
                    color: w[2],
                    normal: w[3],
                    cell: [w[4], w[5], w[6]],
                    attr: w[7],
                })
            })
            .collect())
    }
}

/// The rays with unit directions (t_max scaled to match), so that t is a distance in voxels and
/// a cone means the same on every ray.
pub fn unit_rays(rays: &[VoxelRay]) -> Vec<VoxelRay> {
    rays.iter()
        .map(|r| {
            let l = r.dir.iter().map(|d| d * d).sum::<f32>().sqrt();
            VoxelRay {
                dir: r.dir.map(|d| d / l),
                t_max: r.t_max * l,
                ..*r
            }
        })
        .collect()
}

/// Cones that spread random rays through a grid of largest side `d` over the levels: at t = d/2
/// a footprint of 0 (voxels), 4 (bricks), 16 and 64 voxels.
pub fn validation_cones(d: u32) -> [f32; 4] {
    [0.0, 8.0, 32.0, 128.0].map(|k| k / d.max(1) as f32)
}

/// The largest fraction of rays whose LOD answers may disagree before `bake validate` fails:
/// a level choice `s ≤ cone · t` flips where t lands on the boundary and the GPU rounds a
/// division differently (t within [`super::gpu::T_TOLERANCE`]); lavapipe measures 0.
pub const LOD_MISMATCH_FRACTION: f64 = 1e-3;

/// Agreement of GPU and CPU LOD traversal on the same rays.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LodAgreement {
    pub rays: usize,
    /// Rays both hit in the same cell at the same level.
    pub hits: usize,
    /// Rays where one side hits and the other misses.
    pub hit_mismatches: usize,
    /// Rays both hit but at another level or in another cell (a cell-edge or level-boundary
    /// tie: the DDA's entry t rounded differently).
    pub cell_mismatches: usize,
    /// Same cell, but the colour, normal or attribute index differ (none are expected: both
    /// read the same words).
    pub attribute_mismatches: usize,
    /// Same cell with |t_gpu − t_cpu| > T_TOLERANCE·max(1, |t|).
    pub t_mismatches: usize,
    pub max_t_error: f32,
    /// Up to 5 disagreeing ray indices.
    pub examples: Vec<usize>,
}

impl LodAgreement {
    /// Rays that disagree in any way.
    pub fn mismatches(&self) -> usize {
        self.hit_mismatches + self.cell_mismatches + self.attribute_mismatches + self.t_mismatches
    }

    /// At most [`LOD_MISMATCH_FRACTION`] of the rays disagree.
    pub fn agrees(&self) -> bool {
        self.mismatches() as f64 <= LOD_MISMATCH_FRACTION * self.rays as f64
    }
}

/// Compares GPU answers with the CPU's.
pub fn compare_lod_hits(gpu: &[Option<LodHit>], cpu: &[Option<LodHit>]) -> LodAgreement {
    let mut a = LodAgreement {
        rays: cpu.len(),
        hit_mismatches: gpu.len().abs_diff(cpu.len()),
        ..Default::default()
    };
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        let bad = match (g, c) {
            (None, None) => false,
            (Some(g), Some(c)) if (g.level, g.cell) == (c.level, c.cell) => {
                a.hits += 1;
                a.max_t_error = a.max_t_error.max((g.t - c.t).abs());
                let t_bad = t_off(g.t, c.t);
                let attr_off = (g.color, g.normal, g.attr) != (c.color, c.normal, c.attr);
                a.t_mismatches += usize::from(t_bad);
                a.attribute_mismatches += usize::from(attr_off);
                t_bad || attr_off
            }
            (Some(_), Some(_)) => {
                a.cell_mismatches += 1;
                true
            }
            _ => {
                a.hit_mismatches += 1;
                true
            }
        };
        if bad && a.examples.len() < 5 {
            a.examples.push(i);
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{BackendChoice, init_gpu};
    use crate::voxel::gpu::random_rays;
    use crate::voxel::lod_trace::trace_lod;
    use crate::voxel::svo::voxels_to_svo;
    use crate::voxel::tests::{Rng, random_voxels};

    #[test]
    fn gpu_lod_traversal_equals_cpu_at_every_level() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let mut rng = Rng::new(17);
        // 2 to 5 levels, non-cubic grids that are not multiples of 4.
        for dims in [[4, 4, 4], [37, 20, 45], [130, 17, 9], [300, 41, 22]] {
            let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
            let dev = SvoLodGpu::new(&gpu, &svo).unwrap();
            let rays = unit_rays(&random_rays(dims, 20_000, dims[2] as u64));
            let mut levels = vec![0usize; svo.levels as usize + 1];
            for cone in [0.0f32, 0.03, 0.15, 0.6, 3.0, 1e30] {
                let on_gpu = dev.trace(&rays, cone).unwrap();
                let on_cpu: Vec<_> = rays.iter().map(|r| trace_lod(&svo, r, cone)).collect();
                let a = compare_lod_hits(&on_gpu, &on_cpu);
                // lavapipe rounds as the CPU does: every ray agrees (a real GPU may round a
                // division differently and move a tie; the CLI reports the count).
                assert_eq!(a.mismatches(), 0, "dims {dims:?}, cone {cone}: {a:?}");
                assert!(a.hits > 2_000, "dims {dims:?}, cone {cone}: {a:?}");
                for h in on_cpu.iter().flatten() {
                    levels[h.level as usize] += 1;
                }
            }
            // Voxels and bricks answer some rays (coarser cells of the sparse shell are mostly
            // below the coverage floor).
            let l = svo.levels as usize;
            assert!(
                levels[l] > 0 && levels[l - 1] > 0,
                "dims {dims:?}: {levels:?}"
            );
        }
    }

    #[test]
    fn the_shader_has_the_cpu_coverage_floor() {
        let line = format!(
            "const MIN_STOP_ALPHA: u32 = {}u;",
            crate::voxel::lod_trace::MIN_STOP_ALPHA
        );
        assert!(
            SVO_WALK_WGSL.contains(&line),
            "svo_walk.wgsl lacks {line:?}"
        );
    }

    #[test]
    fn compare_lod_hits_counts_each_kind_of_disagreement() {
        let h = |level: u32, x: u32, t: f32, color: u32| {
            Some(LodHit {
                level,
                cell: [x, 0, 0],
                t,
                color,
                normal: 0,
                attr: 0,
            })
        };
        let cpu = [
            h(2, 4, 1.0, 7),
            h(2, 4, 1.0, 7),
            None,
            h(3, 1, 50.0, 7),
            h(3, 1, 2.0, 7),
        ];
        let gpu = [
            h(2, 4, 1.0, 7),
            h(1, 0, 1.0, 7),
            h(3, 1, 1.0, 7),
            h(3, 1, 50.1, 7),
            h(3, 1, 2.0, 8),
        ];
        let a = compare_lod_hits(&gpu, &cpu);
        assert_eq!(
            (
                a.hit_mismatches,
                a.cell_mismatches,
                a.t_mismatches,
                a.attribute_mismatches
            ),
            (1, 1, 1, 1)
        );
        assert_eq!(a.examples, vec![1, 2, 3, 4]);
        assert_eq!(a.mismatches(), 4);
    }
}
