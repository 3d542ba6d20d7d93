//! The PRT estimator on the GPU (`prt.tracer = "gpu"`): a wgpu compute shader
//! (`shaders/prt.wgsl`) that follows the paths of [`super::transfer`] through the model's CWBVH
//! as obvhs built it ([`ModelBvh::gpu_data`]: nodes, slots in leaf order with their texture
//! coordinates, the alpha masks as bits), with the same alpha test, the same scrambled Sobol
//! first directions and the same SplitMix64 bounce streams ([`super::transfer::path_starts`]).
//!
//! What differs is only floating-point arithmetic (the GPU's sin, cos and sqrt, fused
//! multiply-adds): a path may turn otherwise where a rounding decides a branch (a ray grazing
//! an edge, a roulette draw against a throughput). The transfer is therefore equal to the CPU's
//! within the Monte-Carlo tolerance but not bit-equal, and it may differ between devices and
//! drivers; on one device it is deterministic, because each work item (16 paths of one vertex
//! side) sums its paths in order into its own record and the host adds a side's records in
//! order (in f64, as the CPU does). Welding is the CPU's ([`super::transfer::bake_welded`]).
//!
//! Dispatches hold at most [`BATCH`] work items (≤ 2^19 paths), laid out on a 2-D grid under
//! the 65,535-workgroup limit, with one output buffer of fixed size reused between them.

use super::transfer::{
    self as prt, COEFFS, PER_VERTEX, PrtMaterial, PrtOptions, SETS, SIDES, Transfer, VertexResult,
    collect_transfer,
};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::model::Mesh;
use crate::trace::ModelBvh;
use crate::voxel::compute::{self, Kernel};
use bytemuck::{Pod, Zeroable};

/// Entries of the shader's traversal stack (`trace_ray`'s `array<vec2<u32>, 32>`).
const STACK_ENTRIES: u32 = 32;

/// A BVH deeper than the shader's stack would lose subtrees silently: refused instead.
fn check_depth(data: Option<&crate::trace::bvh::GpuBvhData>) -> Result<()> {
    match data {
        Some(d) if d.depth > STACK_ENTRIES => Err(Error::runtime(format!(
            "the model's BVH is {} levels deep; the GPU tracer's traversal stack holds {} \
             (use prt.tracer = \"cpu\")",
            d.depth, STACK_ENTRIES
        ))),
        _ => Ok(()),
    }
}

/// The BVH's storage buffers (nodes, slots, masks, mask bits) after the depth check, and
/// whether there is a BVH at all (an empty model has none).
fn bvh_buffers(g: &Gpu, bvh: &ModelBvh) -> Result<([wgpu::Buffer; 4], bool)> {
    let data = bvh.gpu_data();
    check_depth(data.as_ref())?;
    let words = |v: Option<&Vec<u32>>| -> Vec<u8> {
        v.map_or_else(Vec::new, |w| bytemuck::cast_slice(w).to_vec())
    };
    let buffers = [
        compute::storage(g, "prt nodes", &words(data.as_ref().map(|d| &d.nodes)))?,
        compute::storage(g, "prt slots", &words(data.as_ref().map(|d| &d.slots)))?,
        compute::storage(g, "prt masks", &words(data.as_ref().map(|d| &d.masks)))?,
        compute::storage(
            g,
            "prt mask bits",
            &words(data.as_ref().map(|d| &d.mask_bits)),
        )?,
    ];
    Ok((buffers, data.is_some()))
}

const PRT_WGSL: &str = concat!(
    include_str!("../sh/basis.wgsl"),
    include_str!("shaders/prt.wgsl")
);

/// u32 words per work item's record: 2 sets × 16 coefficients × RGB, rays, padding.
const RECORD: usize = 98;
const SUMS: usize = SETS * COEFFS * 3;
/// u32 words per vertex side in the starts buffer.
const START_WORDS: usize = 12;
/// Paths per work item.
pub const CHUNK_SAMPLES: u32 = 16;
/// Work items per dispatch.
pub const BATCH: u32 = 1 << 15;

/// The shader's `Params` (48 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    first: u32,
    count: u32,
    stride: u32,
    chunks: u32,
    samples: u32,
    chunk_samples: u32,
    bounces: u32,
    eps: f32,
    has_bvh: u32,
    pad: [u32; 3],
}
const _: () = assert!(size_of::<Params>() == 48);

/// [`prt::bake_prt_with`] on the GPU: welds, traces the representatives with
/// [`bake_prt_gpu_subset`], copies to the welded vertices.
pub fn bake_prt_gpu(
    gpu: &Gpu,
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Transfer> {
    prt::bake_welded(bvh, mesh, materials, opts, progress, |unique| {
        bake_prt_gpu_subset(gpu, bvh, mesh, materials, opts, unique, progress)
    })
}

/// [`prt::bake_prt_subset`] on the GPU: the transfer of the listed vertices, in order.
pub(crate) fn bake_prt_gpu_subset(
    gpu: &Gpu,
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    vertices: &[u32],
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Transfer> {
    let starts = prt::path_starts(bvh, mesh, materials, opts, vertices);
    let sides = vertices.len() as u64 * SIDES as u64;
    let chunks = opts.samples.div_ceil(CHUNK_SAMPLES).max(1);
    let items = u32::try_from(sides * chunks as u64).map_err(|_| {
        Error::runtime(format!(
            "GPU PRT: {} vertices × {} paths are more than 2³² work items",
            vertices.len(),
            opts.samples
        ))
    })?;
    if items == 0 || opts.samples == 0 {
        return Ok(collect_transfer(
            starts
                .vertices
                .iter()
                .map(|v| v.as_ref().map(|_| (Box::new([[0.0f32; 3]; PER_VERTEX]), 0)))
                .collect(),
            opts,
        ));
    }

    let mats: Vec<[f32; 4]> = starts
        .materials
        .iter()
        .map(|m| [m.albedo[0], m.albedo[1], m.albedo[2], m.translucence])
        .collect();
    let mut start_words = Vec::with_capacity(sides as usize * START_WORDS);
    for v in &starts.vertices {
        for side in 0..SIDES {
            // A side not traced (`prt.sides`) is written as skipped: the shader sums nothing.
            match v.as_ref().and_then(|(_, s)| s[side].as_ref()) {
                Some(s) => {
                    start_words.extend(s.origin.to_array().map(f32::to_bits));
                    start_words.extend(s.normal.to_array().map(f32::to_bits));
                    start_words.extend([
                        s.shift.0,
                        s.shift.1,
                        s.key_hash as u32,
                        (s.key_hash >> 32) as u32,
                        1,
                        0,
                    ]);
                }
                None => start_words.extend([0; START_WORDS]),
            }
        }
    }
    let g = gpu;
    let ([nodes, slots, masks, mask_bits], has_bvh) = bvh_buffers(g, bvh)?;
    let inputs = [
        nodes,
        slots,
        masks,
        mask_bits,
        compute::storage(g, "prt materials", bytemuck::cast_slice(&mats))?,
        compute::storage(g, "prt starts", bytemuck::cast_slice(&start_words))?,
    ];
    let inputs: Vec<&wgpu::Buffer> = inputs.iter().collect();
    let kernel = Kernel::new(g, "prt paths", &[PRT_WGSL], "paths", inputs.len() as u32)?;
    let record_bytes = (RECORD * 4) as u64;
    let output = compute::output(g, "prt records", BATCH.min(items) as u64 * record_bytes);

    // Running sums of the side being added up (f64, in record order), then per vertex.
    let mut per_vertex: Vec<VertexResult> = Vec::with_capacity(vertices.len());
    let mut side_sum = [0.0f64; SUMS];
    let mut vertex_out = Box::new([[0.0f32; 3]; PER_VERTEX]);
    let mut vertex_rays = 0u64;
    let scale = 1.0 / opts.samples as f64;
    let mut first = 0u32;
    while first < items {
        let count = BATCH.min(items - first);
        let (grid, stride) = compute::grid_for(count);
        let params = Params {
            first,
            count,
            stride,
            chunks,
            samples: opts.samples,
            chunk_samples: CHUNK_SAMPLES,
            bounces: opts.bounces,
            eps: starts.eps,
            has_bvh: has_bvh as u32,
            pad: [0; 3],
        };
        let uniform = compute::uniform(g, "prt params", bytemuck::bytes_of(&params));
        let raw = kernel.run(
            g,
            &uniform,
            &inputs,
            &output,
            grid,
            count as u64 * record_bytes,
        )?;
        let records: &[u32] = bytemuck::cast_slice(&raw);
        let before = per_vertex.len();
        for (i, r) in records.chunks_exact(RECORD).enumerate() {
            let item = first + i as u32;
            let (side_index, chunk) = (item / chunks, item % chunks);
            for (a, &w) in side_sum.iter_mut().zip(&r[..SUMS]) {
                *a += f32::from_bits(w) as f64;
            }
            vertex_rays += r[SUMS] as u64;
            if chunk + 1 < chunks {
                continue;
            }
            // The side is complete: normalize as the CPU does.
            let (v, side) = (side_index as usize / SIDES, side_index as usize % SIDES);
            if let Some((albedo, _)) = &starts.vertices[v] {
                let dst = &mut vertex_out[side * SETS * COEFFS..(side + 1) * SETS * COEFFS];
                for (o, a) in dst.iter_mut().zip(side_sum.chunks_exact(3)) {
                    *o = std::array::from_fn(|k| (a[k] * scale * albedo[k] as f64) as f32);
                }
            }
            side_sum = [0.0; SUMS];
            if side + 1 == SIDES {
                let out = std::mem::replace(&mut vertex_out, Box::new([[0.0; 3]; PER_VERTEX]));
                let rays = std::mem::take(&mut vertex_rays);
                per_vertex.push(starts.vertices[v].map(|_| (out, rays)));
            }
        }
        progress((per_vertex.len() - before) as u64);
        first += count;
    }
    g.check()?;
    Ok(collect_transfer(per_vertex, opts))
}

/// A single ray's answers: its closest hit (distance, mesh triangle), and whether the any-hit
/// query found one.
pub type RayAnswer = (Option<(f32, u32)>, bool);

/// Closest hits (distance, mesh triangle) and any-hit answers of single rays (t ≥ 0, no
/// upper bound) traced by the shader's traversal: the check of the GPU walk against
/// [`ModelBvh::closest_hit`] and its brute force.
pub fn closest_hits(
    gpu: &Gpu,
    bvh: &ModelBvh,
    rays: &[crate::trace::Ray],
) -> Result<Vec<RayAnswer>> {
    let count =
        u32::try_from(rays.len()).map_err(|_| Error::runtime("GPU rays: more than 2³² rays"))?;
    let ray_words: Vec<u32> = rays
        .iter()
        .flat_map(|r| {
            let (o, d) = (r.origin.to_array(), r.dir.to_array());
            [o[0], o[1], o[2], 0.0, d[0], d[1], d[2], 0.0].map(f32::to_bits)
        })
        .collect();
    let g = gpu;
    let ([nodes, slots, masks, mask_bits], has_bvh) = bvh_buffers(g, bvh)?;
    let inputs = [
        nodes,
        slots,
        masks,
        mask_bits,
        compute::storage(g, "prt materials", &[0; 16])?,
        compute::storage(g, "prt rays", bytemuck::cast_slice(&ray_words))?,
    ];
    let inputs: Vec<&wgpu::Buffer> = inputs.iter().collect();
    let kernel = Kernel::new(g, "prt rays", &[PRT_WGSL], "rays", inputs.len() as u32)?;
    let (grid, stride) = compute::grid_for(count);
    let params = Params {
        first: 0,
        count,
        stride,
        chunks: 1,
        samples: 0,
        chunk_samples: 0,
        bounces: 0,
        eps: 0.0,
        has_bvh: has_bvh as u32,
        pad: [0; 3],
    };
    let uniform = compute::uniform(g, "prt params", bytemuck::bytes_of(&params));
    let bytes = 16 * count as u64;
    let output = compute::output(g, "prt ray results", bytes);
    let raw = kernel.run(g, &uniform, &inputs, &output, grid, bytes)?;
    let words: &[u32] = bytemuck::cast_slice(&raw);
    Ok(words
        .chunks_exact(4)
        .map(|w| {
            let hit = (w[1] != u32::MAX).then(|| (f32::from_bits(w[0]), w[1]));
            (hit, w[2] == 1)
        })
        .collect())
}

#[cfg(test)]
mod tests;
