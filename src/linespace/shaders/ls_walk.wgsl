// The N-tree walk (query::NTree::occluded_by_refine) over one tree of the pools, written once
// and instantiated per kind of leaf: `__X` is replaced by the instance's suffix (gpu.rs), and
// `leaf_hit__X(s, tr, leaf, at)` decides whether a filled leaf blocks the segment (its own
// triangles, a model's triangles placed by the instance `at`, or a top tree's instances). WGSL has
// no recursion or function parameters, so the two-level query needs two copies of the walk.

// query::exact_occluded: a DDA over the node's leaves, asking leaf_hit__X about filled ones.
fn exact_occluded__X(s: Seg, tr: Tree, at: Placement, o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> bool {
    let n = i32(params.n);
    let cell = side / f32(params.n);
    var dda = dda_new(o, d, base, cell, vec3<i32>(n), t0);
    loop {
        let c = dda.c;
        let slot = u32(c.x + n * c.y + n * n * c.z);
        if (filled(tr, group, slot)) {
            if (leaf_hit__X(s, tr, child(tr, group, slot), at)) {
                return true;
            }
        }
        if (dda_exit(dda) >= t1 || !dda_advance(&dda, n)) {
            return false;
        }
    }
    return false;
}

// query::NTree::occluded_by_refine.
fn occluded__X(s: Seg, tr: Tree, at: Placement, linespaces: bool, refine: u32) -> bool {
    let root = root_of(s, tr);
    let o = root.o;
    let d = root.d;
    let n = i32(params.n);
    let side = root.side;
    let iv = root.iv;
    let t0 = max(iv.x, s.t_min);
    let t1 = min(iv.y, s.t_max);
    if (t0 > t1) {
        return false;
    }
    var st: array<Frame, MAX_DEPTH>;
    var lv = 0u;
    st[0].group = 0u;
    st[0].inside = select(0u, 1u, iv.x <= s.t_min) | select(0u, 2u, iv.y >= s.t_max);
    st[0].base = vec3<f32>(0.0);
    st[0].side = side;
    st[0].t0 = t0;
    st[0].t1 = t1;
    // 0: enter the node at lv, 1: visit its current cell, 2: advance its DDA, 3: it is clear.
    var mode = 0u;
    loop {
        if (mode == 0u) {
            let f = st[lv];
            let deepest = lv + 1u == tr.depth;
            mode = 1u;
            if (linespaces && f.inside == 0u) {
                let full = shaft_full(tr, o, d, f.group, f.base, f.side, f.t0, f.t1);
                if (full == 0u) {
                    mode = 3u;
                } else if (full == 1u && deepest) {
                    // Refine::Near: the thesis' hit unless the node is entered within one
                    // deepest-node side of the segment's start (query::near_start).
                    let len = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
                    let near = (f.t0 - s.t_min) * len < f.side;
                    if (refine == 0u || (refine == 3u && !near)) {
                        return true;
                    }
                    var hit = false;
                    if (refine == 1u) {
                        hit = cells_crossed(tr, o, d, f.group, f.base, f.side, f.t0, f.t1);
                    } else {
                        hit = exact_occluded__X(s, tr, at, o, d, f.group, f.base, f.side, f.t0, f.t1);
                    }
                    if (hit) {
                        return true;
                    }
                    mode = 3u;
                }
            }
            if (mode == 1u && deepest) {
                if (exact_occluded__X(s, tr, at, o, d, f.group, f.base, f.side, f.t0, f.t1)) {
                    return true;
                }
                mode = 3u;
            }
            if (mode == 1u) {
                st[lv].dda = dda_new(o, d, f.base, f.side / f32(params.n), vec3<i32>(n), f.t0);
                st[lv].t = f.t0;
            }
        }
        if (mode == 3u) {
            if (lv == 0u) {
                return false;
            }
            lv -= 1u;
            mode = 2u;
        }
        if (mode == 1u) {
            let f = st[lv];
            let e = dda_exit(f.dda);
            let exit = min(e, f.t1);
            let c = f.dda.c;
            let slot = u32(c.x + n * c.y + n * n * c.z);
            mode = 2u;
            // Above the deepest inner level every filled child is an inner node.
            if (filled(tr, f.group, slot)) {
                let cell = f.side / f32(params.n);
                var inside = 0u;
                if ((f.inside & 1u) != 0u && f.t == f.t0) {
                    inside |= 1u;
                }
                if ((f.inside & 2u) != 0u && e >= f.t1) {
                    inside |= 2u;
                }
                st[lv + 1u].group = child(tr, f.group, slot);
                st[lv + 1u].inside = inside;
                st[lv + 1u].base = f.base + vec3<f32>(c) * cell;
                st[lv + 1u].side = cell;
                st[lv + 1u].t0 = f.t;
                st[lv + 1u].t1 = exit;
                lv += 1u;
                mode = 0u;
                continue;
            }
        }
        if (mode == 2u) {
            var dd = st[lv].dda;
            let e = dda_exit(dd);
            let exit = min(e, st[lv].t1);
            if (e >= st[lv].t1 || !dda_advance(&dd, n)) {
                mode = 3u;
            } else {
                st[lv].dda = dd;
                st[lv].t = exit;
                mode = 1u;
            }
        }
    }
    return false;
}

