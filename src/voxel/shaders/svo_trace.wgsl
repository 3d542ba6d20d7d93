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

// No filtered attributes are bound: the walk with cone 0 never reads them.
fn walk_node_color(i: u32) -> u32 {
    return 0u;
}

fn walk_brick_first(n: u32) -> u32 {
    return 0u;
}

// traverse::trace_svo on the section's one tree (svo_walk.wgsl with cone 0).
fn trace(r: GpuRay) -> vec4<u32> {
    if (params.node_count == 0u) {
        return MISS;
    }
    let tree = WalkTree(params.dims, params.side, params.inner_levels, 0u, 0u, 0u, params.node_count);
    let h = svo_walk(r, tree, 0.0, 1.0, false);
    if (h.level == 0xffffffffu) {
        return MISS;
    }
    return vec4<u32>(h.cell, bitcast<u32>(h.t));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    hits[i] = trace(rays[i]);
}
