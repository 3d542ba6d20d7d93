// The octree walk of one packed SVO, written once for the flattened `svo` section
// (svo_trace.wgsl: its only tree, first node and first leaf byte 0) and for each model of the
// two-level `svo-scene` section (svo_scene.wgsl: the model's own ranges of the shared arrays):
// traverse::trace_svo, a hierarchical DDA over the 4³ cells of each node with an explicit stack
// in place of traverse::trace_node's recursion. Rays are in the tree's voxel units. Answers
// (i, j, k, bits of t) of the first occupied voxel, or MISS.
// Prepended: dda.wgsl and svo_common.wgsl. The including shader declares `GpuRay` and the
// `nodes` (u32×4 per inner node: mask low, mask high, first_child, first_voxel; on the last
// inner level first_child is a byte offset into `leaves`) and `leaves` bindings.

const MAX_INNER: u32 = 10u;
const MISS: vec4<u32> = vec4<u32>(0xffffffffu);

// traverse::trace_brick: the voxels of one brick, inside `dims`.
fn walk_brick(r: GpuRay, mask: vec2<u32>, base: vec3<f32>, t0: f32, t1: f32, dims: vec3<u32>) -> vec4<u32> {
    var dda = dda_new(r.origin, r.dir, base, 1.0, vec3<i32>(4), t0);
    loop {
        if (mask_bit(mask, slot_of(dda.c))) {
            let vi = vec3<i32>(base) + dda.c;
            let v = vec3<u32>(vi);
            if (all(v < dims)) {
                return vec4<u32>(v, bitcast<u32>(voxel_entry_t(r.origin, r.dir, r.t_min, v)));
            }
        }
        if (dda_exit(dda) > t1 || !dda_advance(&dda, 4)) {
            return MISS;
        }
    }
    return MISS;
}

// traverse::trace_svo on the tree of grid `dims`, root side `side` (4^levels voxels),
// `inner_levels` (levels − 1) inner levels, whose nodes start at nodes[first_node] and whose
// bricks at byte first_leaf of `leaves`: one frame per inner level (node, corner, cell size,
// span, DDA).
fn svo_walk(r: GpuRay, dims: vec3<u32>, side: f32, inner_levels: u32, first_node: u32, first_leaf: u32) -> vec4<u32> {
    let iv = box_interval(r.origin, r.dir, vec3<f32>(0.0), vec3<f32>(dims));
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
    cell[0] = side / 4.0;
    t[0] = t0;
    t_end[0] = t1;
    dda[0] = dda_new(r.origin, r.dir, base[0], cell[0], vec3<i32>(4), t0);
    loop {
        // Visit the current cell of level lv.
        let nd = nodes[first_node + node[lv]];
        let s = slot_of(dda[lv].c);
        let exit = min(dda_exit(dda[lv]), t_end[lv]);
        if (mask_bit(nd.xy, s)) {
            let below = count_below(nd.xy, s);
            let child = nd.z + below;
            let cbase = base[lv] + vec3<f32>(dda[lv].c) * cell[lv];
            if (lv + 1u == inner_levels) {
                let h = walk_brick(r, brick_mask(first_leaf + nd.z, below), cbase, t[lv], exit, dims);
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
