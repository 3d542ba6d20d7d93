// Level-of-detail traversal of the packed SVO (src/voxel/lod_trace.rs): the walk of
// svo_walk.wgsl with the ray's cone and unit 1 (cells measured in voxels), answering with the
// stopping cell's filtered attributes (a voxel's own). Rays are in voxel units. Output per ray,
// two vec4<u32>: (level, bits of t, colour, normal) and (cell corner x, y, z, attribute index);
// level all ones on a miss.
// Prepended: dda.wgsl, svo_common.wgsl and svo_walk.wgsl.

struct Params {
    dims: vec3<u32>,
    inner_levels: u32,
    // 4^levels, the root's side in voxels.
    side: f32,
    count: u32,
    stride: u32,
    node_count: u32,
    // Footprint of a ray at t: cone · t voxels.
    cone: f32,
    levels: u32,
    pad0: u32,
    pad1: u32,
}

struct GpuRay {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
// The `svo` section's `nodes` and `leaves` as svo_trace.wgsl reads them.
@group(0) @binding(1) var<storage, read> nodes: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> leaves: array<u32>;
// Per inner node of the last inner level: the index of its first brick (0 elsewhere).
@group(0) @binding(3) var<storage, read> brick_first: array<u32>;
// (colour, normal) per inner node, then per brick (`node_colors`, `node_normals`).
@group(0) @binding(4) var<storage, read> node_attrs: array<vec2<u32>>;
// (colour, normal) per voxel (`voxel_colors`, `voxel_normals`).
@group(0) @binding(5) var<storage, read> voxel_attrs: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(7) var<storage, read_write> hits: array<vec4<u32>>;

fn walk_node_color(i: u32) -> u32 {
    return node_attrs[i].x;
}

fn walk_brick_first(n: u32) -> u32 {
    return brick_first[n];
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    var a = vec4<u32>(0xffffffffu);
    var b = vec4<u32>(0u);
    if (params.node_count > 0u) {
        let tree = WalkTree(params.dims, params.side, params.inner_levels, 0u, 0u, 0u, params.node_count);
        let h = svo_walk(rays[i], tree, params.cone, 1.0, true);
        if (h.level != 0xffffffffu) {
            var attr = node_attrs[h.attr];
            if (h.level == params.levels) {
                attr = voxel_attrs[h.attr];
            }
            a = vec4<u32>(h.level, bitcast<u32>(h.t), attr.x, attr.y);
            b = vec4<u32>(h.cell, h.attr);
        }
    }
    hits[2u * i] = a;
    hits[2u * i + 1u] = b;
}
