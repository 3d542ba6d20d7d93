// The octree walk of one packed SVO, written once for the flattened `svo` section (svo_trace.wgsl
// and svo_lod.wgsl: its only tree, first node, leaf byte and attribute 0) and for each model of
// the two-level `svo-scene` section (svo_scene.wgsl: the model's own ranges of the shared
// arrays): lod_trace::trace_lod_scaled, operation for operation, a hierarchical DDA over the 4³
// cells of each node with an explicit stack in place of the CPU's recursion. Rays are in the
// tree's voxel units. An occupied cell of side s (voxels) whose slab entry t (the later of its
// box's entry and the grid's, clamped to t_min) has s · unit ≤ cone · t and whose filtered
// coverage is at least MIN_STOP_ALPHA/255 ends the walk on its filtered attributes; cone 0 never
// stops on a cell (traverse::trace_svo exactly).
// Prepended: dda.wgsl and svo_common.wgsl. The including shader declares `GpuRay`, the `nodes`
// (u32×4 per inner node: mask low, mask high, first_child, first_voxel; on the last inner level
// first_child is a byte offset into `leaves`) and `leaves` bindings, and two accessors that
// svo_trace.wgsl (cone 0) never calls: `walk_node_color(i)`, the stored colour of global
// filtered attribute i, and `walk_brick_first(n)`, the index of the first brick (local to its
// tree) of global node n of a last inner level.

const MAX_INNER: u32 = 10u;
const MISS: vec4<u32> = vec4<u32>(0xffffffffu);
// lod_trace::MIN_STOP_ALPHA: the least stored alpha byte a coarse cell may stop the walk with.
const MIN_STOP_ALPHA: u32 = 16u;

fn can_stop(color: u32) -> bool {
    return (color >> 24u) >= MIN_STOP_ALPHA;
}

// One tree: its grid, root side 4^levels, inner levels (levels − 1), and where its nodes, leaf
// bytes and filtered attributes start in the shared arrays; `nodes` its inner node count (its
// bricks' filtered attributes follow its nodes').
struct WalkTree {
    dims: vec3<u32>,
    side: f32,
    inner_levels: u32,
    first_node: u32,
    first_leaf: u32,
    first_attr: u32,
    nodes: u32,
}

// The stopping cell: its level (0 the root, inner_levels + 1 a voxel; all ones on a miss), its
// minimum corner in voxels, t, and its attribute index local to the tree (into the filtered
// attributes for a cell, into the voxel attributes for a voxel: computed only with
// `voxel_attr`, else 0).
struct WalkHit {
    level: u32,
    cell: vec3<u32>,
    t: f32,
    attr: u32,
}

fn walk_miss() -> WalkHit {
    return WalkHit(0xffffffffu, vec3<u32>(0u), 0.0, 0u);
}

// lod_trace::Walk::brick: the voxels of one brick, inside `dims`; `first` is the attribute index
// of the brick's first voxel (when asked for).
fn walk_brick(r: GpuRay, mask: vec2<u32>, first: u32, base: vec3<f32>, t0: f32, t1: f32, tree: WalkTree) -> WalkHit {
    var dda = dda_new(r.origin, r.dir, base, 1.0, vec3<i32>(4), t0);
    loop {
        let s = slot_of(dda.c);
        if (mask_bit(mask, s)) {
            let v = vec3<u32>(vec3<i32>(base) + dda.c);
            if (all(v < tree.dims)) {
                let t = voxel_entry_t(r.origin, r.dir, r.t_min, v);
                return WalkHit(tree.inner_levels + 1u, v, t, first + count_below(mask, s));
            }
        }
        if (dda_exit(dda) > t1 || !dda_advance(&dda, 4)) {
            return walk_miss();
        }
    }
    return walk_miss();
}

// lod_trace::trace_lod_scaled on `tree`: one frame per inner level (node, corner, cell size, t,
// span, DDA).
fn svo_walk(r: GpuRay, tree: WalkTree, cone: f32, unit: f32, voxel_attr: bool) -> WalkHit {
    let iv = box_interval(r.origin, r.dir, vec3<f32>(0.0), vec3<f32>(tree.dims));
    let t0 = max(iv.x, r.t_min);
    let t1 = min(iv.y, r.t_max);
    if (t0 > t1) {
        return walk_miss();
    }
    if (tree.side * unit <= cone * t0 && can_stop(walk_node_color(tree.first_attr))) {
        return WalkHit(0u, vec3<u32>(0u), t0, 0u);
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
    cell[0] = tree.side / 4.0;
    t[0] = t0;
    t_end[0] = t1;
    dda[0] = dda_new(r.origin, r.dir, base[0], cell[0], vec3<i32>(4), t0);
    loop {
        // Visit the current cell of level lv (a child at level lv + 1).
        let nd = nodes[tree.first_node + node[lv]];
        let s = slot_of(dda[lv].c);
        let exit = min(dda_exit(dda[lv]), t_end[lv]);
        if (mask_bit(nd.xy, s)) {
            let below = count_below(nd.xy, s);
            let cbase = base[lv] + vec3<f32>(dda[lv].c) * cell[lv];
            let last = lv + 1u == tree.inner_levels;
            if (cone > 0.0) {
                var attr = nd.z + below;
                if (last) {
                    attr = tree.nodes + walk_brick_first(tree.first_node + node[lv]) + below;
                }
                let tc = max(box_interval(r.origin, r.dir, cbase, cbase + vec3<f32>(cell[lv])).x, t0);
                if (cell[lv] * unit <= cone * tc && can_stop(walk_node_color(tree.first_attr + attr))) {
                    return WalkHit(lv + 1u, vec3<u32>(cbase), tc, attr);
                }
            }
            if (last) {
                var first = 0u;
                if (voxel_attr) {
                    first = nd.w + voxels_before(tree.first_leaf + nd.z, below);
                }
                let mask = brick_mask(tree.first_leaf + nd.z, below);
                let h = walk_brick(r, mask, first, cbase, t[lv], exit, tree);
                if (h.level != 0xffffffffu) {
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
                    return walk_miss();
                }
                lv -= 1u;
                continue;
            }
            dda[lv] = d;
            t[lv] = ex;
            break;
        }
    }
    return walk_miss();
}
