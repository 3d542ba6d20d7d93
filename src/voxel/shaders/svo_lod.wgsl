// Level-of-detail traversal of the packed SVO (src/voxel/lod_trace.rs, operation for operation):
// svo_trace.wgsl's stack DDA, stopping at the first occupied cell whose side is at most
// params.cone · t where the DDA enters it and whose coverage is at least MIN_STOP_ALPHA (or at a
// voxel) and answering with that cell's filtered
// attributes. Rays are in voxel units. Output per ray, two vec4<u32>: (level, bits of t, colour,
// normal) and (cell corner x, y, z, 0); level all ones on a miss.
// Prepended: dda.wgsl and svo_common.wgsl.

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

struct LodHit {
    a: vec4<u32>,
    b: vec4<u32>,
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

const MAX_INNER: u32 = 10u;
// lod_trace::MIN_STOP_ALPHA: the least stored alpha byte a coarse cell may stop the walk with.
const MIN_STOP_ALPHA: u32 = 16u;

fn can_stop(color: u32) -> bool {
    return (color >> 24u) >= MIN_STOP_ALPHA;
}

fn miss() -> LodHit {
    return LodHit(vec4<u32>(0xffffffffu), vec4<u32>(0u));
}

fn cell_hit(level: u32, attr: vec2<u32>, base: vec3<f32>, t: f32) -> LodHit {
    return LodHit(vec4<u32>(level, bitcast<u32>(t), attr.x, attr.y), vec4<u32>(vec3<u32>(base), 0u));
}

// lod_trace::Walk::brick: `first` is the attribute index of the brick's first voxel.
fn lod_brick(r: GpuRay, mask: vec2<u32>, first: u32, base: vec3<f32>, t0: f32, t1: f32) -> LodHit {
    var dda = dda_new(r.origin, r.dir, base, 1.0, vec3<i32>(4), t0);
    loop {
        let s = slot_of(dda.c);
        if (mask_bit(mask, s)) {
            let v = vec3<u32>(vec3<i32>(base) + dda.c);
            if (all(v < params.dims)) {
                let a = voxel_attrs[first + count_below(mask, s)];
                let t = voxel_entry_t(r.origin, r.dir, r.t_min, v);
                return LodHit(vec4<u32>(params.levels, bitcast<u32>(t), a.x, a.y), vec4<u32>(v, 0u));
            }
        }
        if (dda_exit(dda) > t1 || !dda_advance(&dda, 4)) {
            return miss();
        }
    }
    return miss();
}

// lod_trace::trace_lod: one frame per inner level, as svo_trace.wgsl's trace.
fn trace(r: GpuRay) -> LodHit {
    if (params.node_count == 0u) {
        return miss();
    }
    let iv = box_interval(r.origin, r.dir, vec3<f32>(0.0), vec3<f32>(params.dims));
    let t0 = max(iv.x, r.t_min);
    let t1 = min(iv.y, r.t_max);
    if (t0 > t1) {
        return miss();
    }
    if (params.side <= params.cone * t0 && can_stop(node_attrs[0].x)) {
        return cell_hit(0u, node_attrs[0], vec3<f32>(0.0), t0);
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
        // Visit the current cell of level lv (a child at level lv + 1).
        let nd = nodes[node[lv]];
        let s = slot_of(dda[lv].c);
        let exit = min(dda_exit(dda[lv]), t_end[lv]);
        if (mask_bit(nd.xy, s)) {
            let below = count_below(nd.xy, s);
            let cbase = base[lv] + vec3<f32>(dda[lv].c) * cell[lv];
            let last = lv + 1u == params.inner_levels;
            var attr = nd.z + below;
            if (last) {
                attr = params.node_count + brick_first[node[lv]] + below;
            }
            if (cell[lv] <= params.cone * t[lv] && can_stop(node_attrs[attr].x)) {
                return cell_hit(lv + 1u, node_attrs[attr], cbase, t[lv]);
            }
            if (last) {
                let first = nd.w + voxels_before(nd.z, below);
                let h = lod_brick(r, brick_mask(nd.z, below), first, cbase, t[lv], exit);
                if (h.a.x != 0xffffffffu) {
                    return h;
                }
            } else {
                let c = cell[lv] / 4.0;
                node[lv + 1u] = nd.z + below;
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
                    return miss();
                }
                lv -= 1u;
                continue;
            }
            dda[lv] = d;
            t[lv] = ex;
            break;
        }
    }
    return miss();
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let h = trace(rays[i]);
    hits[2u * i] = h.a;
    hits[2u * i + 1u] = h.b;
}
