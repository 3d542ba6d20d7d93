// First hit of a batch of rays in the packed SVO (src/voxel/svo.rs and src/voxel/packed.rs, the
// `svo` section's arrays bound as they are): a hierarchical DDA over the 4³ cells of each node with an explicit
// stack in place of traverse::trace_node's recursion. Rays are in voxel units. Output per ray:
// (i, j, k, bits of t) of the first occupied voxel, or all ones on a miss.
// Prepended: dda.wgsl.

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

// Morton slot of a 2-bit cell coordinate inside a 4³ node.
fn slot_of(c: vec3<i32>) -> u32 {
    let u = vec3<u32>(c);
    return (u.x & 1u) | ((u.y & 1u) << 1u) | ((u.z & 1u) << 2u)
        | ((u.x & 2u) << 2u) | ((u.y & 2u) << 3u) | ((u.z & 2u) << 4u);
}

fn mask_bit(m: vec2<u32>, s: u32) -> bool {
    let w = select(m.x, m.y, s >= 32u);
    return ((w >> (s & 31u)) & 1u) == 1u;
}

// popcount(mask & ((1 << s) − 1)).
fn count_below(m: vec2<u32>, s: u32) -> u32 {
    if (s < 32u) {
        return countOneBits(m.x & ((1u << s) - 1u));
    }
    return countOneBits(m.x) + countOneBits(m.y & ((1u << (s - 32u)) - 1u));
}

fn leaf_byte(b: u32) -> u32 {
    return (leaves[b >> 2u] >> ((b & 3u) * 8u)) & 0xffu;
}

// The 64-bit mask (low, high) of brick `index` among the bricks starting at byte `first`.
fn brick_mask(first: u32, index: u32) -> vec2<u32> {
    var at = first;
    for (var i = 0u; i < index; i++) {
        at += 1u + countOneBits(leaf_byte(at));
    }
    let octants = leaf_byte(at);
    var m = vec2<u32>(0u);
    var k = at + 1u;
    for (var o = 0u; o < 8u; o++) {
        if (((octants >> o) & 1u) == 1u) {
            let b = leaf_byte(k);
            k += 1u;
            if (o < 4u) {
                m.x |= b << (8u * o);
            } else {
                m.y |= b << (8u * (o - 4u));
            }
        }
    }
    return m;
}

fn voxel_entry_t(o: vec3<f32>, d: vec3<f32>, t_min: f32, v: vec3<u32>) -> f32 {
    let lo = vec3<f32>(v);
    return max(box_interval(o, d, lo, lo + vec3<f32>(1.0)).x, t_min);
}

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
