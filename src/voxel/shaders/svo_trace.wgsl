// First hit of a batch of rays in the packed SVO (src/voxel/svo.rs and src/voxel/packed.rs, the
// `svo` section's arrays bound as they are): a hierarchical DDA over the 4³ cells of each node with an explicit
// stack in place of traverse::trace_node's recursion. Rays are in voxel units. Output per ray:
// (i, j, k, bits of t) of the first occupied voxel, or all ones on a miss.
// Prepended: dda.wgsl and svo_common.wgsl.

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

const MAX_INNER: u32 = 10u;
const MISS: vec4<u32> = vec4<u32>(0xffffffffu);

// traverse::trace_brick.
fn trace_brick(r: GpuRay, mask: vec2<u32>, base: vec3<f32>, t0: f32, t1: f32) -> vec4<u32> {
    var dda = dda_new(r.origin, r.dir, base, 1.0, vec3<i32>(4), t0);
    loop {
        if (mask_bit(mask, slot_of(dda.c))) {
            let vi = vec3<i32>(base) + dda.c;
            let v = vec3<u32>(vi);
            if (all(v < params.dims)) {
                return vec4<u32>(v, bitcast<u32>(voxel_entry_t(r.origin, r.dir, r.t_min, v)));
            }
        }
        if (dda_exit(dda) > t1 || !dda_advance(&dda, 4)) {
            return MISS;
        }
    }
    return MISS;
}

// traverse::trace_svo: one frame per inner level (node, corner, cell size, span, DDA).
fn trace(r: GpuRay) -> vec4<u32> {
    if (params.node_count == 0u) {
        return MISS;
    }
    let iv = box_interval(r.origin, r.dir, vec3<f32>(0.0), vec3<f32>(params.dims));
    let t0 = max(iv.x, r.t_min);
    let t1 = min(iv.y, r.t_max);
    if (t0 > t1) {
        return MISS;
    }
    var node: array<u32, MAX_INNER>;
    var base: array<vec3<f32>, MAX_INNER>;
    var cell: array<f32, MAX_INNER>;
    var t: array<f32, MAX_INNER>;
    var t_end: array<f32, MAX_INNER>;
    var dda: array<Dda, MAX_INNER>;
    var lv = 0u;
    node[0] = 0u;
    base[0] = vec3<f32>(0.0);
    cell[0] = params.side / 4.0;
    t[0] = t0;
    t_end[0] = t1;
    dda[0] = dda_new(r.origin, r.dir, base[0], cell[0], vec3<i32>(4), t0);
    loop {
        // Visit the current cell of level lv.
        let nd = nodes[node[lv]];
        let s = slot_of(dda[lv].c);
        let exit = min(dda_exit(dda[lv]), t_end[lv]);
        if (mask_bit(nd.xy, s)) {
            let below = count_below(nd.xy, s);
            let child = nd.z + below;
            let cbase = base[lv] + vec3<f32>(dda[lv].c) * cell[lv];
            if (lv + 1u == params.inner_levels) {
                let h = trace_brick(r, brick_mask(nd.z, below), cbase, t[lv], exit);
                if (h.x != 0xffffffffu) {
                    return h;
                }
            } else {
                let c = cell[lv] / 4.0;
                node[lv + 1u] = child;
                base[lv + 1u] = cbase;
                cell[lv + 1u] = c;
                t[lv + 1u] = t[lv];
                t_end[lv + 1u] = exit;
                dda[lv + 1u] = dda_new(r.origin, r.dir, cbase, c, vec3<i32>(4), t[lv]);
                lv += 1u;
                continue;
            }
        }
        // Advance level lv, popping finished levels.
        loop {
            var d = dda[lv];
            let e = dda_exit(d);
            let ex = min(e, t_end[lv]);
            if (e > t_end[lv] || !dda_advance(&d, 4)) {
                if (lv == 0u) {
                    return MISS;
                }
                lv -= 1u;
                continue;
            }
            dda[lv] = d;
            t[lv] = ex;
            break;
        }
    }
    return MISS;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    hits[i] = trace(rays[i]);
}
