// PRT paths on the GPU (src/prt/gpu.rs): the estimator of src/prt/transfer.rs (`Ctx::side`,
// `Ctx::trace`) traced through the model's CWBVH as obvhs builds it (src/trace/bvh.rs,
// `GpuBvhData`), with the same alpha test, the same Sobol points and digital shifts and the
// same SplitMix64 bounce streams (64-bit arithmetic on u32 pairs). Only the float arithmetic
// differs (sin/cos/sqrt, fused multiply-adds), so a path may branch otherwise where a rounding
// decides, and the result is equal to the CPU's within the Monte-Carlo noise, not bit-equal.
//
// One invocation is one work item: `chunk_samples` consecutive paths of one vertex side. It
// writes its 2 sets × 16 coefficients × RGB sums and its ray count to its own record; the host
// adds the records of a side in order, so a device gives the same bytes on every run.

struct Params {
    // First work item of this dispatch, work items in it, invocations per grid row.
    first: u32,
    count: u32,
    stride: u32,
    // Work items per side, paths per side, paths per work item.
    chunks: u32,
    samples: u32,
    chunk_samples: u32,
    bounces: u32,
    // Ray offset along the normal (world units).
    eps: f32,
    // 0: the model has no BVH (every path escapes).
    has_bvh: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// 20 words per CwBvhNode (GpuBvhData::nodes).
@group(0) @binding(1) var<storage, read> nodes: array<u32>;
// 20 words per slot: v0, e1, e2, uv0, uv1 − uv0, uv2 − uv0, triangle, mask, material, 0, 0.
@group(0) @binding(2) var<storage, read> slots: array<u32>;
// 4 words per mask: width, height, first word of its bits, 0.
@group(0) @binding(3) var<storage, read> masks: array<u32>;
@group(0) @binding(4) var<storage, read> mask_bits: array<u32>;
// Per material: albedo RGB, translucence.
@group(0) @binding(5) var<storage, read> materials: array<vec4<f32>>;
// 12 words per vertex side: origin, normal, shift x, shift y, key hash (lo, hi), valid, 0.
@group(0) @binding(6) var<storage, read> starts: array<u32>;
// RECORD words per work item: 96 f32 sums ([set][coefficient][channel]), rays, 0.
@group(0) @binding(7) var<storage, read_write> records: array<u32>;

const RECORD: u32 = 98u;
const NODE_WORDS: u32 = 20u;
const SLOT_WORDS: u32 = 20u;
const NO_MASK: u32 = 0xffffffffu;
const TAU: f32 = 6.2831855;
// obvhs' lower bound on a child box's entry distance (cwbvh::node::EPSILON).
const BOX_EPSILON: f32 = 0.0001;
// Stands for +∞ (the CPU's ray has tmax = ∞); finite so that no fast-math assumption bites.
const FAR: f32 = 3.0e38;

// ---- 64-bit integers as (lo, hi) -------------------------------------------------------

fn mul32(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    return vec2<u32>((mid << 16u) | (p00 & 0xffffu), p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u));
}

fn mul64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let p = mul32(a.x, b.x);
    return vec2<u32>(p.x, p.y + a.x * b.y + a.y * b.x);
}

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

// a ^ (a >> s) for 0 < s < 32.
fn xor_shr(a: vec2<u32>, s: u32) -> vec2<u32> {
    return vec2<u32>(a.x ^ ((a.x >> s) | (a.y << (32u - s))), a.y ^ (a.y >> s));
}

const GAMMA: vec2<u32> = vec2<u32>(0x7f4a7c15u, 0x9e3779b9u);
const PATH_SEED_MUL: vec2<u32> = vec2<u32>(0xd192ed03u, 0xd1b54a32u);

// SplitMix64's finalizer (src/rng.rs `finalize`).
fn finalize(z0: vec2<u32>) -> vec2<u32> {
    var z = mul64(xor_shr(z0, 30u), vec2<u32>(0x1ce4e5b9u, 0xbf58476du));
    z = mul64(xor_shr(z, 27u), vec2<u32>(0x133111ebu, 0x94d049bbu));
    return xor_shr(z, 31u);
}

fn mix64(x: vec2<u32>) -> vec2<u32> {
    return finalize(add64(x, GAMMA));
}

// The bounce stream of the current path (src/rng.rs `Rng::hashed`, `Rng::f32`).
var<private> rng_state: vec2<u32>;

fn rng_seed(seed: vec2<u32>) {
    rng_state = add64(mix64(seed), GAMMA);
}

fn rng_f32() -> f32 {
    rng_state = add64(rng_state, GAMMA);
    let x = finalize(rng_state);
    return f32(x.y >> 8u) * (1.0 / 16777216.0);
}

// ---- sampling ----------------------------------------------------------------------------

// Point k of the 2-D Sobol (0,2)-sequence, XOR-scrambled (transfer.rs `sobol_scrambled`).
fn sobol(k: u32, sx: u32, sy: u32) -> vec2<f32> {
    var v = 0x80000000u;
    var y = 0u;
    var i = k;
    while i != 0u {
        if (i & 1u) != 0u {
            y ^= v;
        }
        i >>= 1u;
        v ^= v >> 1u;
    }
    let x = reverseBits(k);
    return vec2<f32>(f32((x ^ sx) >> 8u), f32((y ^ sy) >> 8u)) * (1.0 / 16777216.0);
}

fn sign_of(x: f32) -> f32 {
    return select(1.0, -1.0, (bitcast<u32>(x) & 0x80000000u) != 0u);
}

// Cosine-weighted direction around unit n (src/trace/mod.rs `cosine_hemisphere`, `frame`).
fn cosine_hemisphere(n: vec3<f32>, u1: f32, u2: f32) -> vec3<f32> {
    let r = sqrt(u1);
    let phi = TAU * u2;
    let s = sin(phi);
    let c = cos(phi);
    let z = sqrt(max(1.0 - u1, 0.0));
    let sg = sign_of(n.z);
    let a = -1.0 / (sg + n.z);
    let b = n.x * n.y * a;
    let t = vec3<f32>(1.0 + sg * n.x * n.x * a, sg * b, -sg * n.x);
    let bt = vec3<f32>(b, sg + n.y * n.y * a, -n.y);
    return t * (r * c) + bt * (r * s) + n * z;
}

// ---- the CWBVH ---------------------------------------------------------------------------

fn safe_inverse(x: f32) -> f32 {
    if abs(x) <= 1.1920929e-7 {
        return sign_of(x) / 1.1920929e-7;
    }
    return 1.0 / x;
}

// Byte i (0..8) of an 8-byte node array held as two words.
fn byte_of(w: vec2<u32>, i: u32) -> u32 {
    return (select(w.x, w.y, i >= 4u) >> ((i & 3u) * 8u)) & 0xffu;
}

// The hit mask of a node's children (obvhs `CwBvhNode::intersect_ray`): internal children
// in the high byte at their traversal priority, leaf children's primitives in the low 24 bits.
fn intersect_node(ni: u32, o: vec3<f32>, idir: vec3<f32>, neg: vec3<bool>, tmax: f32, oct_inv4: u32) -> u32 {
    let base = ni * NODE_WORDS;
    let p = vec3<f32>(bitcast<f32>(nodes[base]), bitcast<f32>(nodes[base + 1u]), bitcast<f32>(nodes[base + 2u]));
    let w3 = nodes[base + 3u];
    let ext = vec3<f32>(
        bitcast<f32>((w3 & 0xffu) << 23u),
        bitcast<f32>(((w3 >> 8u) & 0xffu) << 23u),
        bitcast<f32>(((w3 >> 16u) & 0xffu) << 23u),
    );
    let adj_idir = ext * idir;
    let adj_o = (p - o) * idir;
    // The child metadata and quantized planes, loaded once; the ray's octant picks which of
    // each axis' planes is the entry and which the exit.
    let metas = vec2<u32>(nodes[base + 6u], nodes[base + 7u]);
    let min_x = vec2<u32>(nodes[base + 8u], nodes[base + 9u]);
    let max_x = vec2<u32>(nodes[base + 10u], nodes[base + 11u]);
    let min_y = vec2<u32>(nodes[base + 12u], nodes[base + 13u]);
    let max_y = vec2<u32>(nodes[base + 14u], nodes[base + 15u]);
    let min_z = vec2<u32>(nodes[base + 16u], nodes[base + 17u]);
    let max_z = vec2<u32>(nodes[base + 18u], nodes[base + 19u]);
    let near_x = select(min_x, max_x, neg.x);
    let far_x = select(max_x, min_x, neg.x);
    let near_y = select(min_y, max_y, neg.y);
    let far_y = select(max_y, min_y, neg.y);
    let near_z = select(min_z, max_z, neg.z);
    let far_z = select(max_z, min_z, neg.z);
    var mask = 0u;
    for (var c = 0u; c < 8u; c++) {
        let cm = byte_of(metas, c);
        if cm == 0u {
            continue;
        }
        let qmin = vec3<f32>(f32(byte_of(near_x, c)), f32(byte_of(near_y, c)), f32(byte_of(near_z, c)));
        let qmax = vec3<f32>(f32(byte_of(far_x, c)), f32(byte_of(far_y, c)), f32(byte_of(far_z, c)));
        let t0 = qmin * adj_idir + adj_o;
        let t1 = qmax * adj_idir + adj_o;
        let tmin = max(max(max(t0.x, t0.y), t0.z), BOX_EPSILON);
        let tmx = min(min(min(t1.x, t1.y), t1.z), tmax);
        if tmin <= tmx {
            let inner = (cm & 0x18u) == 0x18u;
            let index = (cm ^ select(0u, oct_inv4 & 0xffu, inner)) & 0x1fu;
            mask |= ((cm >> 5u) & 7u) << index;
        }
    }
    return mask;
}

fn slot_vec(s: u32, at: u32) -> vec3<f32> {
    let b = s * SLOT_WORDS + at;
    return vec3<f32>(bitcast<f32>(slots[b]), bitcast<f32>(slots[b + 1u]), bitcast<f32>(slots[b + 2u]));
}

// Möller–Trumbore as src/trace/bvh.rs `intersect` writes it: (t, u, v, 1) or w = 0 for none.
fn intersect_slot(s: u32, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> vec4<f32> {
    let v0 = slot_vec(s, 0u);
    let e1 = slot_vec(s, 3u);
    let e2 = slot_vec(s, 6u);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det == 0.0 {
        return vec4<f32>(0.0);
    }
    let inv = 1.0 / det;
    let sv = o - v0;
    let u = dot(sv, p) * inv;
    if !(u >= 0.0 && u <= 1.0) {
        return vec4<f32>(0.0);
    }
    let q = cross(sv, e1);
    let v = dot(d, q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return vec4<f32>(0.0);
    }
    let t = dot(e2, q) * inv;
    if !(t >= 0.0 && t <= tmax) {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(t, u, v, 1.0);
}

// Texel index along one axis: floor(c · n) repeated into [0, n) (`AlphaMask::opaque_at`).
fn texel(c: f32, n: u32) -> u32 {
    let f = clamp(floor(c * f32(n)), -1073741824.0, 1073741824.0);
    var i = i32(f) % i32(n);
    if i < 0 {
        i += i32(n);
    }
    return u32(i);
}

// Whether a hit on slot s at barycentrics (u, v) is on an opaque texel.
fn opaque(s: u32, u: f32, v: f32) -> bool {
    let b = s * SLOT_WORDS;
    let m = slots[b + 16u];
    if m == NO_MASK {
        return true;
    }
    let t0 = vec2<f32>(bitcast<f32>(slots[b + 9u]), bitcast<f32>(slots[b + 10u]));
    let d1 = vec2<f32>(bitcast<f32>(slots[b + 11u]), bitcast<f32>(slots[b + 12u]));
    let d2 = vec2<f32>(bitcast<f32>(slots[b + 13u]), bitcast<f32>(slots[b + 14u]));
    let ss = t0.x + u * d1.x + v * d2.x;
    let tt = t0.y + u * d1.y + v * d2.y;
    let w = masks[m * 4u];
    let h = masks[m * 4u + 1u];
    let i = texel(tt, h) * w + texel(ss, w);
    return ((mask_bits[masks[m * 4u + 2u] + (i >> 5u)] >> (i & 31u)) & 1u) == 1u;
}

struct Hit {
    t: f32,
    u: f32,
    v: f32,
    slot: u32,
    found: bool,
}

// The closest opaque hit (`any`: the first one found) along o + t·d, t ≥ 0
// (`ModelBvh::closest_hit`, `ModelBvh::any_hit`: the obvhs traversal order and the skip of a
// triangle tested just before through a neighbouring box).
fn trace_ray(o: vec3<f32>, d: vec3<f32>, any: bool) -> Hit {
    var best = Hit(FAR, 0.0, 0.0, 0u, false);
    if params.has_bvh == 0u {
        return best;
    }
    let idir = vec3<f32>(safe_inverse(d.x), safe_inverse(d.y), safe_inverse(d.z));
    let neg = d < vec3<f32>(0.0);
    let oct_inv4 = select(0x04040404u, 0u, neg.x) | select(0x02020202u, 0u, neg.y) | select(0x01010101u, 0u, neg.z);
    var stack: array<vec2<u32>, 32>;
    var sp = 0u;
    var tmax = FAR;
    var current = vec2<u32>(0u, 0x80000000u);
    var prims = vec2<u32>(0u, 0u);
    var last = NO_MASK;
    loop {
        while prims.y != 0u {
            let local = firstLeadingBit(prims.y);
            prims.y &= ~(1u << local);
            let s = prims.x + local;
            let tri = slots[s * SLOT_WORDS + 15u];
            let same = tri == last;
            last = tri;
            if same {
                continue;
            }
            let h = intersect_slot(s, o, d, tmax);
            if h.w != 0.0 && h.x < tmax && opaque(s, h.y, h.z) {
                best = Hit(h.x, h.y, h.z, s, true);
                if any {
                    return best;
                }
                tmax = h.x;
            }
        }
        prims = vec2<u32>(0u, 0u);
        if (current.y & 0xff000000u) != 0u {
            let hits_imask = current.y;
            let offset = firstLeadingBit(hits_imask);
            current.y &= ~(1u << offset);
            if (current.y & 0xff000000u) != 0u && sp < 32u {
                stack[sp] = current;
                sp += 1u;
            }
            let slot_index = (offset - 24u) ^ (oct_inv4 & 0xffu);
            let relative = countOneBits(hits_imask & ~(0xffffffffu << slot_index));
            let ni = current.x + relative;
            let hitmask = intersect_node(ni, o, idir, neg, tmax, oct_inv4);
            let base = ni * NODE_WORDS;
            current = vec2<u32>(nodes[base + 4u], (hitmask & 0xff000000u) | (nodes[base + 3u] >> 24u));
            prims = vec2<u32>(nodes[base + 5u], hitmask & 0x00ffffffu);
        } else {
            current = vec2<u32>(0u, 0u);
        }
        if prims.y == 0u && (current.y & 0xff000000u) == 0u {
            if sp == 0u {
                break;
            }
            sp -= 1u;
            current = stack[sp];
        }
    }
    return best;
}

// ---- the estimator -----------------------------------------------------------------------

var<private> sums: array<f32, 96>;

// The order-4 SH basis (src/sh/basis.wgsl, prepended) times the throughput, added to the sets.
fn add_escape(d: vec3<f32>, beta: vec3<f32>, bounced: bool) {
    var b = sh_basis16(d);
    let sets = select(1u, 2u, bounced);
    for (var st = 0u; st < sets; st++) {
        for (var i = 0u; i < 16u; i++) {
            let at = st * 48u + i * 3u;
            sums[at] += beta.x * b[i];
            sums[at + 1u] += beta.y * b[i];
            sums[at + 2u] += beta.z * b[i];
        }
    }
}

// Follows one path (transfer.rs `Ctx::trace`); returns the rays traced.
fn trace_path(origin: vec3<f32>, d0: vec3<f32>) -> u32 {
    var o = origin;
    var d = d0;
    var beta = vec3<f32>(1.0);
    for (var bounce = 0u; ; bounce++) {
        if bounce == params.bounces {
            // The last ray only has to tell whether the path escapes.
            if !trace_ray(o, d, true).found {
                add_escape(d, beta, bounce > 0u);
            }
            return bounce + 1u;
        }
        let h = trace_ray(o, d, false);
        if !h.found {
            add_escape(d, beta, bounce > 0u);
            return bounce + 1u;
        }
        let v0 = slot_vec(h.slot, 0u);
        let e1 = slot_vec(h.slot, 3u);
        let e2 = slot_vec(h.slot, 6u);
        let position = v0 + e1 * h.u + e2 * h.v;
        let c = cross(e1, e2);
        let len = length(c);
        var ng = vec3<f32>(0.0);
        if len > 0.0 && len < FAR {
            ng = c * (1.0 / len);
        }
        let m = materials[slots[h.slot * SLOT_WORDS + 17u]];
        beta = beta * m.xyz;
        if all(beta == vec3<f32>(0.0)) || all(ng == vec3<f32>(0.0)) {
            return bounce + 1u;
        }
        // Russian roulette from the second hit on.
        let q = min(max(max(beta.x, beta.y), beta.z), 1.0);
        if q < 1.0 && bounce >= 1u {
            if rng_f32() >= q {
                return bounce + 1u;
            }
            beta = beta / q;
        }
        let facing = select(-ng, ng, dot(ng, d) < 0.0);
        let out = select(facing, -facing, rng_f32() < m.w);
        o = position + out * params.eps;
        let u1 = rng_f32();
        let u2 = rng_f32();
        d = cosine_hemisphere(out, u1, u2);
    }
    return 0u;
}

@compute @workgroup_size(64)
fn paths(@builtin(global_invocation_id) gid: vec3<u32>) {
    let local = gid.y * params.stride + gid.x;
    if local >= params.count {
        return;
    }
    let item = params.first + local;
    let side = item / params.chunks;
    let chunk = item % params.chunks;
    let sb = side * 12u;
    var rays = 0u;
    if starts[sb + 10u] != 0u {
        let origin = vec3<f32>(bitcast<f32>(starts[sb]), bitcast<f32>(starts[sb + 1u]), bitcast<f32>(starts[sb + 2u]));
        let n = vec3<f32>(bitcast<f32>(starts[sb + 3u]), bitcast<f32>(starts[sb + 4u]), bitcast<f32>(starts[sb + 5u]));
        let sx = starts[sb + 6u];
        let sy = starts[sb + 7u];
        let key = vec2<u32>(starts[sb + 8u], starts[sb + 9u]);
        let k0 = chunk * params.chunk_samples;
        let k1 = min(k0 + params.chunk_samples, params.samples);
        for (var k = k0; k < k1; k++) {
            let u = sobol(k, sx, sy);
            let d = cosine_hemisphere(n, u.x, u.y);
            let seed = mul64(vec2<u32>(k, 0u), PATH_SEED_MUL);
            rng_seed(vec2<u32>(key.x ^ seed.x, key.y ^ seed.y));
            rays += trace_path(origin, d);
        }
    }
    let rb = local * RECORD;
    for (var i = 0u; i < 96u; i++) {
        records[rb + i] = bitcast<u32>(sums[i]);
    }
    records[rb + 96u] = rays;
    records[rb + 97u] = 0u;
}

// Single rays for the tests (`prt::gpu::closest_hits`): `starts` holds 8 words per ray (origin,
// 0, direction, 0); `records` gets 4 per ray: the closest hit's t and mesh triangle
// (0xffffffff: none), and whether the any-hit query found a hit.
@compute @workgroup_size(64)
fn rays(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.stride + gid.x;
    if i >= params.count {
        return;
    }
    let b = i * 8u;
    let o = vec3<f32>(bitcast<f32>(starts[b]), bitcast<f32>(starts[b + 1u]), bitcast<f32>(starts[b + 2u]));
    let d = vec3<f32>(bitcast<f32>(starts[b + 4u]), bitcast<f32>(starts[b + 5u]), bitcast<f32>(starts[b + 6u]));
    let h = trace_ray(o, d, false);
    let a = trace_ray(o, d, true);
    records[i * 4u] = bitcast<u32>(h.t);
    records[i * 4u + 1u] = select(0xffffffffu, slots[h.slot * SLOT_WORDS + 15u], h.found);
    records[i * 4u + 2u] = select(0u, 1u, a.found);
    records[i * 4u + 3u] = 0u;
}
