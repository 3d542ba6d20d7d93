// First hit of a batch of rays in the packed SVO (src/voxel/svo.rs and src/voxel/packed.rs, the
// `svo` section's arrays bound as they are), by the walk of svo_walk.wgsl. Rays are in voxel
// units. Output per ray: (i, j, k, bits of t) of the first occupied voxel, or all ones on a miss.
// Prepended: dda.wgsl, svo_common.wgsl and svo_walk.wgsl.

struct Params {
    dims: vec3<u32>,
    inner_levels: u32,
    // 4^levels, the root's side in voxels.
    side: f32,
    count: u32,
    stride: u32,
    node_count: u32,
}

struct GpuRay {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
// `nodes`: u32×4 per inner node (mask low, mask high, first_child, first_voxel); on the last
// inner level first_child is a byte offset into `leaves`.
@group(0) @binding(1) var<storage, read> nodes: array<vec4<u32>>;
// `leaves`: bytes (little endian in u32 words), per brick an octant byte and one 8-bit mask per
// non-empty octant.
@group(0) @binding(2) var<storage, read> leaves: array<u32>;
@group(0) @binding(3) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(4) var<storage, read_write> hits: array<vec4<u32>>;

// traverse::trace_svo on the section's one tree (svo_walk.wgsl).
fn trace(r: GpuRay) -> vec4<u32> {
    if (params.node_count == 0u) {
        return MISS;
    }
    return svo_walk(r, params.dims, params.side, params.inner_levels, 0u, 0u);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    hits[i] = trace(rays[i]);
}
