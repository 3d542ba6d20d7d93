//! GPU soft-shadow queries through the N-tree with line spaces: the `linespace` section's
//! arrays (`occupancy`, `first_child`, `leaf_tris`, `tri_indices`, `triangles`, `shaft_cells`)
//! bound as storage buffers exactly as packed, traversed by `shaders/ls_walk.wgsl` (over the
//! pools of `ls_pools.wgsl`, the tree's own triangles as leaves: `ls_flat.wgsl`), which follows
//! [`super::query`] operation for operation (DDA, rank-compacted children, line-space
//! bits as occupancy & shaft cells, the deepest level's refinement, exact Möller–Trumbore tests
//! as obvhs writes them). [`validate_linespace`] compares it with the CPU on random segments and
//! shadow queries.

use super::ntree::NTree;
use super::query::{AreaLight, QueryStats, Segment};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::rng::Rng;
use crate::voxel::compute::{self, Kernel};
use bytemuck::{Pod, Zeroable};

const DDA_WGSL: &str = include_str!("../voxel/shaders/dda.wgsl");
const POOLS_WGSL: &str = include_str!("shaders/ls_pools.wgsl");
const WALK_WGSL: &str = include_str!("shaders/ls_walk.wgsl");
const FLAT_WGSL: &str = include_str!("shaders/ls_flat.wgsl");
const ENTRIES_WGSL: &str = include_str!("shaders/ls_entries.wgsl");

/// The walk of `ls_walk.wgsl` for leaves decided by `leaf_hit{suffix}`.
pub(super) fn walk_wgsl(suffix: &str) -> String {
    WALK_WGSL.replace("__X", suffix)
}

/// The shader sources of a query kernel: the pools, the walk per kind of leaf, the variant
/// (which defines `occluded`), the entry points.
pub(super) fn kernel_parts(walks: &[&str], variant: &'static str) -> Vec<String> {
    let mut parts = vec![DDA_WGSL.to_string(), POOLS_WGSL.to_string()];
    parts.extend(walks.iter().map(|w| walk_wgsl(w)));
    parts.push(variant.to_string());
    parts.push(ENTRIES_WGSL.to_string());
    parts
}

/// The shader's `Params` (128 bytes; the fields from `trees` on are the two-level query's).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct Params {
    pub(super) origin: [f32; 3],
    pub(super) n: u32,
    pub(super) leaf_size: [f32; 3],
    pub(super) depth: u32,
    pub(super) count: u32,
    pub(super) stride: u32,
    /// u32 words of a group's occupancy and of a shaft's cells.
    pub(super) occ_words: u32,
    pub(super) use_linespaces: u32,
    pub(super) offset: f32,
    pub(super) seg_t_max: f32,
    pub(super) samples: u32,
    /// 0 (unused).
    pub(super) reserved: u32,
    /// [`super::ntree::Refine::code`].
    pub(super) refine: u32,
    pub(super) trees: u32,
    pub(super) instances: u32,
    pub(super) has_terrain: u32,
    pub(super) hf_origin: [f32; 2],
    pub(super) hf_step: [f32; 2],
    pub(super) hf_cells: [u32; 2],
    pub(super) hf_levels: u32,
    pub(super) hf_pad_z: f32,
    pub(super) near_distance: f32,
    pub(super) instances_at: u32,
    pub(super) levels_at: u32,
    pub(super) pad: u32,
}
const _: () = assert!(size_of::<Params>() == 128);

/// Receivers of a shadow query: a world position, or none (answered fully lit).
pub type Receiver = Option<[f32; 3]>;

/// An N-tree resident on the GPU (or the two-level trees of a scene:
/// [`super::instanced_gpu`]), with its two kernels.
pub struct NTreeGpu<'g> {
    pub(super) gpu: &'g Gpu,
    pub(super) segments: Kernel,
    pub(super) shadow: Kernel,
    pub(super) fractions: Kernel,
    /// occupancy, first_child, leaf_tris, tri_indices, triangles, shaft_cells (the section's
    /// arrays), then the reversed occupancy derived from it (binding order); the two-level
    /// query's scene table and heights after them.
    pub(super) pools: Vec<wgpu::Buffer>,
    pub(super) base: Params,
}

impl<'g> NTreeGpu<'g> {
    /// Uploads the tree's arrays as they are (the bytes of the `linespace` section) and the
    /// reversed occupancy, one storage binding each; a pool larger than the device binds fails
    /// with its name and size.
    pub fn new(gpu: &'g Gpu, t: &NTree) -> Result<Self> {
        if t.depth as usize > 12 {
            return Err(Error::runtime("linespace: depth > 12"));
        }
        let parts = kernel_parts(&["_flat"], FLAT_WGSL);
        let parts: Vec<&str> = parts.iter().map(String::as_str).collect();
        let arrays: [(&str, &[u8]); 7] = [
            ("linespace occupancy", bytemuck::cast_slice(&t.occupancy)),
            (
                "linespace first_child",
                bytemuck::cast_slice(&t.first_child),
            ),
            ("linespace leaf_tris", bytemuck::cast_slice(&t.leaf_tris)),
            (
                "linespace tri_indices",
                bytemuck::cast_slice(&t.tri_indices),
            ),
            ("linespace triangles", bytemuck::cast_slice(&t.triangles)),
            (
                "linespace shaft_cells",
                bytemuck::cast_slice(&t.shafts.cells),
            ),
            (
                "linespace occupancy reversed",
                bytemuck::cast_slice(&t.occupancy_rev),
            ),
        ];
        let pools = arrays
            .iter()
            .map(|(label, bytes)| compute::storage(gpu, label, bytes))
            .collect::<Result<Vec<_>>>()?;
        let inputs = pools.len() as u32 + 1;
        Ok(NTreeGpu {
            gpu,
            segments: Kernel::new(gpu, "ntree segments", &parts, "segments", inputs)?,
            shadow: Kernel::new(gpu, "ntree shadow", &parts, "shadow", inputs)?,
            fractions: Kernel::new(gpu, "ntree fractions", &parts, "fractions", inputs)?,
            pools,
            base: Params {
                origin: t.origin,
                n: t.n,
                leaf_size: t.leaf_size,
                depth: t.depth,
                count: 0,
                stride: 0,
                occ_words: 2 * t.occupancy_words() as u32,
                use_linespaces: 1,
                offset: 0.0,
                seg_t_max: 1.0,
                samples: 0,
                refine: t.refine.code(),
                ..Params::zeroed()
            },
        })
    }

    /// Bytes uploaded (the pools as bound).
    pub fn pool_bytes(&self) -> u64 {
        self.pools.iter().map(|b| b.size()).sum()
    }

    /// The pools and then `extra` as the kernel's inputs.
    fn inputs<'a>(&'a self, extra: &'a wgpu::Buffer) -> Vec<&'a wgpu::Buffer> {
        self.pools.iter().chain([extra]).collect()
    }

    fn run(&self, kernel: &Kernel, params: Params, queries: &[[f32; 4]]) -> Result<Vec<u32>> {
        let (grid, stride) = compute::grid_for(params.count);
        let params = Params { stride, ..params };
        let g = self.gpu;
        let uniform = compute::uniform(g, "ntree params", bytemuck::bytes_of(&params));
        let input = compute::storage(g, "ntree queries", bytemuck::cast_slice(queries))?;
        let bytes = 4 * params.count as u64;
        let out = compute::output(g, "ntree results", bytes);
        let raw = kernel.run(g, &uniform, &self.inputs(&input), &out, grid, bytes)?;
        Ok(bytemuck::cast_slice(&raw).to_vec())
    }

    /// Records the `shadow` dispatch (one invocation per receiver and light sample, counting
    /// the lit ones into `out`, cleared first) and with `fractions` the `fractions` dispatch
    /// after it (counts → f32 fractions).
    fn record_shadow(
        &self,
        enc: &mut wgpu::CommandEncoder,
        params: Params,
        queries: &wgpu::Buffer,
        out: &wgpu::Buffer,
        fractions: bool,
    ) -> Result<()> {
        let g = self.gpu;
        let total = params
            .count
            .checked_mul(params.samples)
            .ok_or_else(|| Error::runtime("linespace: more than 2³² shadow segments"))?;
        enc.clear_buffer(out, 0, None);
        let (grid, stride) = compute::grid_for(total);
        let uniform = compute::uniform(
            g,
            "ntree params",
            bytemuck::bytes_of(&Params { stride, ..params }),
        );
        self.shadow
            .record(g, enc, &uniform, &self.inputs(queries), out, grid)?;
        if fractions {
            let (grid, stride) = compute::grid_for(params.count);
            let uniform = compute::uniform(
                g,
                "ntree params",
                bytemuck::bytes_of(&Params { stride, ..params }),
            );
            self.fractions
                .record(g, enc, &uniform, &self.inputs(queries), out, grid)?;
        }
        Ok(())
    }

    /// The shadow dispatches over `queries` (receivers, then light samples), read back.
    fn run_shadow(
        &self,
        params: Params,
        queries: &[[f32; 4]],
        fractions: bool,
    ) -> Result<Vec<u32>> {
        let g = self.gpu;
        let input = compute::storage(g, "ntree queries", bytemuck::cast_slice(queries))?;
        let bytes = 4 * params.count as u64;
        let out = compute::output(g, "ntree results", bytes);
        let mut enc = g.device.create_command_encoder(&Default::default());
        self.record_shadow(&mut enc, params, &input, &out, fractions)?;
        g.queue.submit([enc.finish()]);
        let raw = compute::read_back(g, &out, bytes)?;
        Ok(bytemuck::cast_slice(&raw).to_vec())
    }

    /// Whether each segment may be blocked ([`NTree::segment_occluded`], or with
    /// `linespaces == false` [`NTree::segment_occluded_exact`]).
    pub fn segments_occluded(&self, segs: &[Segment], linespaces: bool) -> Result<Vec<bool>> {
        let count = u32::try_from(segs.len())
            .map_err(|_| Error::runtime("linespace: more than 2³² segments"))?;
        let queries: Vec<[f32; 4]> = segs
            .iter()
            .flat_map(|s| {
                [
                    [s.from[0], s.from[1], s.from[2], s.t_min],
                    [s.dir[0], s.dir[1], s.dir[2], s.t_max],
                ]
            })
            .collect();
        let params = Params {
            count,
            use_linespaces: linespaces as u32,
            ..self.base
        };
        Ok(self
            .run(&self.segments, params, &queries)?
            .iter()
            .map(|&r| r == 1)
            .collect())
    }

    /// Lit light samples per receiver ([`NTree::shadow`] × samples²; `None` receivers count all
    /// samples as lit).
    pub fn shadow_counts(
        &self,
        receivers: &[Receiver],
        light: &AreaLight,
        offset: f32,
    ) -> Result<Vec<u32>> {
        let (queries, params) = self.shadow_setup(receivers, light, offset)?;
        self.run_shadow(params, &queries, false)
    }

    /// Lit fraction per receiver, computed on the GPU (lit / samples²).
    pub fn shadow_fractions(
        &self,
        receivers: &[Receiver],
        light: &AreaLight,
        offset: f32,
    ) -> Result<Vec<f32>> {
        self.shadow_fractions_with(receivers, light, offset, true)
    }

    /// [`Self::shadow_fractions`], or with `linespaces == false` the exact N-tree traversal
    /// (every filled leaf on the way tested exactly: ray-traced visibility, same segments).
    pub(crate) fn shadow_fractions_with(
        &self,
        receivers: &[Receiver],
        light: &AreaLight,
        offset: f32,
        linespaces: bool,
    ) -> Result<Vec<f32>> {
        let (queries, params) = self.shadow_setup(receivers, light, offset)?;
        let params = Params {
            use_linespaces: linespaces as u32,
            ..params
        };
        let raw = self.run_shadow(params, &queries, true)?;
        Ok(raw.iter().map(|&b| f32::from_bits(b)).collect())
    }

    /// Records the shadow kernels (f32 fractions into `out`) over `count` receivers that
    /// `queries` already holds as vec4 (w = 1: a receiver, w = 0: none), e.g. a world-position
    /// texture copied in; the light samples are written behind them.
    pub fn record_shadow_fractions(
        &self,
        enc: &mut wgpu::CommandEncoder,
        queries: &wgpu::Buffer,
        count: u32,
        light: &AreaLight,
        offset: f32,
        out: &wgpu::Buffer,
    ) -> Result<()> {
        let (q, params) = self.shadow_setup(&[], light, offset)?;
        let params = Params { count, ..params };
        let need = 16 * (count as u64 + q.len() as u64);
        if queries.size() < need || out.size() < 4 * count as u64 {
            return Err(Error::runtime("shadow kernel: buffers too small"));
        }
        self.gpu
            .queue
            .write_buffer(queries, 16 * count as u64, bytemuck::cast_slice(&q));
        self.record_shadow(enc, params, queries, out, true)
    }

    /// Receivers then light samples (computed on the CPU, so both sides use the same points).
    fn shadow_setup(
        &self,
        receivers: &[Receiver],
        light: &AreaLight,
        offset: f32,
    ) -> Result<(Vec<[f32; 4]>, Params)> {
        let count = u32::try_from(receivers.len())
            .map_err(|_| Error::runtime("linespace: more than 2³² receivers"))?;
        let k = light.samples.max(1).pow(2);
        let mut q: Vec<[f32; 4]> = receivers
            .iter()
            .map(|r| r.map_or([0.0; 4], |p| [p[0], p[1], p[2], 1.0]))
            .collect();
        q.extend((0..k).map(|i| {
            let s = light.sample(i);
            [s[0], s[1], s[2], 1.0]
        }));
        let params = Params {
            count,
            offset,
            seg_t_max: Segment::between([0.0; 3], [1.0; 3], 0.0).t_max,
            samples: k,
            ..self.base
        };
        Ok((q, params))
    }
}

/// Lit samples per receiver on the CPU ([`NTree::shadow`] without the division).
pub fn shadow_counts_cpu(
    t: &NTree,
    receivers: &[Receiver],
    light: &AreaLight,
    offset: f32,
) -> Vec<u32> {
    let k = light.samples.max(1).pow(2);
    let mut stats = QueryStats::default();
    receivers
        .iter()
        .map(|r| match r {
            None => k,
            Some(p) => (0..k)
                .filter(|&i| {
                    let s = Segment::between(*p, light.sample(i), offset);
                    !t.segment_occluded(&s, &mut stats)
                })
                .count() as u32,
        })
        .collect()
}

/// The root box of the tree: minimum corner and size.
pub fn root_box(t: &NTree) -> ([f32; 3], [f32; 3]) {
    let side = t.n.pow(t.depth) as f32;
    (t.origin, t.leaf_size.map(|s| s * side))
}

/// A quad light above the tree's box (as `bake bench linespace` places it).
pub fn light_above(t: &NTree, samples: u32) -> AreaLight {
    let (lo, size) = root_box(t);
    AreaLight {
        corner: [
            lo[0] + 0.3 * size[0],
            lo[1] + 0.3 * size[1],
            lo[2] + 2.0 * size[2],
        ],
        edge_u: [0.4 * size[0], 0.0, 0.0],
        edge_v: [0.0, 0.4 * size[1], 0.0],
        samples,
    }
}

/// Random receivers: points on random triangles (where shadows and self-occlusion matter)
/// and points anywhere in the box.
pub fn random_receivers(t: &NTree, count: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::new(seed);
    let (lo, size) = root_box(t);
    (0..count)
        .map(|i| {
            if i % 2 == 0 && !t.triangles.is_empty() {
                let tri = t.triangles[(rng.next_u64() % t.triangles.len() as u64) as usize];
                let (mut a, mut b) = (rng.f32(), rng.f32());
                if a + b > 1.0 {
                    (a, b) = (1.0 - a, 1.0 - b);
                }
                [0, 1, 2]
                    .map(|k| tri[0][k] + a * (tri[1][k] - tri[0][k]) + b * (tri[2][k] - tri[0][k]))
            } else {
                [0, 1, 2].map(|k| lo[k] + rng.f32() * size[k])
            }
        })
        .collect()
}

/// Agreement of GPU and CPU line-space queries.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LinespaceAgreement {
    pub segments: usize,
    pub occluded: usize,
    /// Segments where the GPU and the CPU line-space answers differ.
    pub segment_mismatches: usize,
    /// The same without line spaces (exact N-tree traversal on both sides).
    pub exact_mismatches: usize,
    pub receivers: usize,
    pub samples: u32,
    /// Receivers whose lit fraction differs.
    pub fraction_mismatches: usize,
    /// Of the mismatches above, those on segments that pass a placed triangle's edge within
    /// the rounding of world coordinates (two-level structures only: the GPU places a model's
    /// triangles into the world with other rounding than the CPU; [`ExactInstances::near_edge`])
    /// and the receivers with such a segment; not counted against agreement.
    ///
    /// [`ExactInstances::near_edge`]: super::instanced::ExactInstances::near_edge
    pub edge_segment_mismatches: usize,
    pub edge_exact_mismatches: usize,
    pub edge_fraction_mismatches: usize,
    /// Receivers strictly between 0 and 1 (penumbra).
    pub penumbra: usize,
    /// Up to 5 disagreeing segment indices.
    pub examples: Vec<usize>,
    /// Bytes of the pools bound on the GPU (the section's arrays plus the reversed occupancy).
    pub gpu_pool_bytes: u64,
    /// What the query did in a deepest-level node with a full shaft (both sides).
    pub refine: super::ntree::Refine,
    /// Wall time of the line-space segments on the GPU (upload, dispatch, read-back) and on
    /// the CPU (one thread).
    pub gpu_seconds: f64,
    pub cpu_seconds: f64,
}

impl LinespaceAgreement {
    /// Every answer the same, but for segments at a placed triangle's edge.
    pub fn agrees(&self) -> bool {
        self.segment_mismatches == self.edge_segment_mismatches
            && self.exact_mismatches == self.edge_exact_mismatches
            && self.fraction_mismatches == self.edge_fraction_mismatches
    }
}

/// Runs `receivers` random receivers against a `samples × samples` light above the tree: every
/// segment on both sides (with and without line spaces), and the shadow kernel's counts.
pub fn validate_linespace(
    gpu: &Gpu,
    t: &NTree,
    receivers: usize,
    samples: u32,
    seed: u64,
) -> Result<LinespaceAgreement> {
    let light = light_above(t, samples.max(1));
    let (_, size) = root_box(t);
    let offset = 1e-4 * size.iter().cloned().fold(0.0, f32::max);
    let points = random_receivers(t, receivers, seed);
    let dev = NTreeGpu::new(gpu, t)?;
    let cpu = CpuSide {
        occluded: &|s| t.segment_occluded(s, &mut QueryStats::default()),
        exact: &|s| t.segment_occluded_exact(s, &mut QueryStats::default()),
        at_edge: &|_| false,
    };
    compare_on(&dev, &points, &light, offset, &cpu, t.refine)
}

/// The CPU's answers that [`compare_on`] holds the GPU to.
pub(super) struct CpuSide<'a> {
    /// With line spaces (the structure's own query).
    pub occluded: &'a dyn Fn(&Segment) -> bool,
    /// Exact visibility (what the GPU answers without line spaces).
    pub exact: &'a dyn Fn(&Segment) -> bool,
    /// Whether rounding may decide the segment (a mismatch there is reported apart).
    pub at_edge: &'a dyn Fn(&Segment) -> bool,
}

/// The GPU against the CPU: every segment from `points` to the light's samples with and
/// without line spaces, and the shadow kernel's counts against the CPU's answers on the same
/// segments (receiver i's at i·samples..(i + 1)·samples).
pub(super) fn compare_on(
    dev: &NTreeGpu,
    points: &[[f32; 3]],
    light: &AreaLight,
    offset: f32,
    cpu_side: &CpuSide,
    refine: super::ntree::Refine,
) -> Result<LinespaceAgreement> {
    let k = light.samples.max(1).pow(2);
    let segs: Vec<Segment> = points
        .iter()
        .flat_map(|&p| (0..k).map(move |i| Segment::between(p, light.sample(i), offset)))
        .collect();
    let t0 = std::time::Instant::now();
    let cpu: Vec<bool> = segs.iter().map(cpu_side.occluded).collect();
    let t1 = std::time::Instant::now();
    let cpu_exact: Vec<bool> = segs.iter().map(cpu_side.exact).collect();
    let t2 = std::time::Instant::now();
    let gpu = dev.segments_occluded(&segs, true)?;
    let t3 = std::time::Instant::now();
    let gpu_exact = dev.segments_occluded(&segs, false)?;
    let recv: Vec<Receiver> = points.iter().map(|&p| Some(p)).collect();
    let counts_gpu = dev.shadow_counts(&recv, light, offset)?;
    let counts_cpu: Vec<u32> = cpu
        .chunks(k as usize)
        .map(|c| c.iter().filter(|&&o| !o).count() as u32)
        .collect();
    let mut r = LinespaceAgreement {
        segments: segs.len(),
        occluded: cpu.iter().filter(|&&o| o).count(),
        receivers: points.len(),
        samples: k,
        gpu_pool_bytes: dev.pool_bytes(),
        refine,
        cpu_seconds: (t1 - t0).as_secs_f64(),
        gpu_seconds: (t3 - t2).as_secs_f64(),
        ..Default::default()
    };
    let mut edge_receiver = vec![false; points.len()];
    for (i, s) in segs.iter().enumerate() {
        let bad = cpu[i] != gpu[i];
        let bad_exact = cpu_exact[i] != gpu_exact[i];
        r.segment_mismatches += bad as usize;
        r.exact_mismatches += bad_exact as usize;
        if (bad || bad_exact) && (cpu_side.at_edge)(s) {
            r.edge_segment_mismatches += bad as usize;
            r.edge_exact_mismatches += bad_exact as usize;
            edge_receiver[i / k as usize] = true;
        }
        if (bad || bad_exact) && r.examples.len() < 5 {
            r.examples.push(i);
        }
    }
    for (i, (g, c)) in counts_gpu.iter().zip(&counts_cpu).enumerate() {
        if g != c {
            r.fraction_mismatches += 1;
            r.edge_fraction_mismatches += edge_receiver[i] as usize;
        }
    }
    r.penumbra = counts_cpu.iter().filter(|&&c| c > 0 && c < k).count();
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{BackendChoice, init_gpu};
    use crate::linespace::dense::build_dense;
    use crate::linespace::ntree::{NTreeOptions, Refine, build_ntree};
    use crate::linespace::shaft::{ChildMasks, ShaftTable};
    use std::sync::Arc;

    /// Small random triangles in [0, 10]³ over a ground quad at z = −0.5.
    fn scene(seed: u64, count: usize) -> Vec<[[f32; 3]; 3]> {
        let mut rng = Rng::new(seed);
        let mut tris: Vec<[[f32; 3]; 3]> = (0..count)
            .map(|_| {
                let c = [0, 1, 2].map(|_| rng.range(0.0, 10.0));
                std::array::from_fn(|_| [0, 1, 2].map(|k| c[k] + rng.range(-0.8, 0.8)))
            })
            .collect();
        tris.push([[-2.0, -2.0, -0.5], [12.0, -2.0, -0.5], [12.0, 12.0, -0.5]]);
        tris.push([[-2.0, -2.0, -0.5], [12.0, 12.0, -0.5], [-2.0, 12.0, -0.5]]);
        tris
    }

    #[test]
    fn gpu_shadow_queries_equal_cpu_on_every_segment() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        for (n, depth, seed) in [(4, 2, 1), (3, 3, 2), (10, 2, 3), (2, 5, 4)] {
            let tris = scene(seed, 200);
            let shafts = Arc::new(ShaftTable::build(n));
            let mut t = build_ntree(
                &tris,
                &NTreeOptions {
                    n,
                    depth,
                    cubic_cells: true,
                },
                &shafts,
            )
            .unwrap();
            t.refine = Refine::Shaft;
            let a = validate_linespace(&gpu, &t, 400, 4, seed).unwrap();
            assert!(a.agrees(), "n {n} depth {depth}: {a:?}");
            assert_eq!(a.segments, 400 * 16);
            assert!(
                a.occluded > 400 && a.occluded < 6000,
                "n {n} depth {depth}: {a:?}"
            );
            assert!(a.penumbra > 10, "n {n} depth {depth}: {a:?}");
        }
    }

    #[test]
    fn gpu_compact_pools_equal_the_cpu_on_the_dense_reference_in_every_refine_mode() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let tris = scene(5, 300);
        let opts = NTreeOptions {
            n: 4,
            depth: 3,
            cubic_cells: true,
        };
        let mut t = build_ntree(&tris, &opts, &Arc::new(ShaftTable::build(4))).unwrap();
        // The CPU reads its line-space bits from the thesis' dense pool, built independently.
        let dense = build_dense(&tris, &opts, &ChildMasks::build(4)).unwrap();
        let light = light_above(&t, 4);
        let segs: Vec<Segment> = random_receivers(&t, 300, 2)
            .iter()
            .flat_map(|&p| (0..16).map(move |i| Segment::between(p, light.sample(i), 1e-3)))
            .collect();
        let mut blocked = Vec::new();
        for refine in [Refine::Shaft, Refine::Cells, Refine::Exact, Refine::Near] {
            t.refine = refine;
            let dev = NTreeGpu::new(&gpu, &t).unwrap();
            let mut reference = t.clone();
            reference.dense_linespaces = Some(Arc::new(dense.linespaces.clone()));
            for linespaces in [true, false] {
                let cpu: Vec<bool> = segs
                    .iter()
                    .map(|s| {
                        let mut st = QueryStats::default();
                        if linespaces {
                            reference.segment_occluded(s, &mut st)
                        } else {
                            reference.segment_occluded_exact(s, &mut st)
                        }
                    })
                    .collect();
                assert_eq!(dev.segments_occluded(&segs, linespaces).unwrap(), cpu);
                if linespaces {
                    blocked.push(cpu.iter().filter(|&&b| b).count());
                }
            }
        }
        // Each finer refinement blocks no more segments, and some blocked ones remain.
        assert!(
            blocked[0] >= blocked[1] && blocked[1] >= blocked[2],
            "{blocked:?}"
        );
        assert!(
            blocked[2] > 100 && blocked[0] < segs.len() - 100,
            "{blocked:?}"
        );
    }

    #[test]
    fn none_receivers_are_fully_lit_and_fractions_are_counts_over_samples() {
        let gpu = init_gpu(BackendChoice::Auto).expect("a wgpu adapter (lavapipe in CI)");
        let tris = scene(9, 100);
        let t = build_ntree(
            &tris,
            &NTreeOptions {
                n: 4,
                depth: 2,
                cubic_cells: true,
            },
            &Arc::new(ShaftTable::build(4)),
        )
        .unwrap();
        let light = light_above(&t, 3);
        let mut recv: Vec<Receiver> = random_receivers(&t, 50, 1).into_iter().map(Some).collect();
        recv[7] = None;
        let dev = NTreeGpu::new(&gpu, &t).unwrap();
        let counts = dev.shadow_counts(&recv, &light, 1e-3).unwrap();
        let fractions = dev.shadow_fractions(&recv, &light, 1e-3).unwrap();
        assert_eq!(counts, shadow_counts_cpu(&t, &recv, &light, 1e-3));
        assert_eq!(counts[7], 9);
        for (c, f) in counts.iter().zip(&fractions) {
            assert!((f - *c as f32 / 9.0).abs() <= 1e-6, "{f} vs {c}/9");
        }
    }
}
