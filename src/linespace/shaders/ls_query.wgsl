// Shadow segments through the packed N-tree in its compact form (the `linespace` section's
// arrays bound as they are, layout in src/linespace/ntree.rs and docs/FORMAT.md):
// query::NTree::occluded_in with an explicit stack, children found by rank over the occupancy
// bits, line-space bits as occupancy & shaft cells (shaft_full), the deepest level's refinement
// (query::Refine), and exact Möller–Trumbore tests in deepest-level nodes written like obvhs'
// Triangle::intersect (the CPU's exact test).
// Entry points: `segments` (one segment per invocation, output 1 = occluded, 0 = clear) and
// `shadow` (one receiver per invocation against every light sample; output the number of lit
// samples, or with FLAG_FRACTION the f32 bits of lit / samples).
// Prepended: dda.wgsl.

struct Params {
    origin: vec3<f32>,
    n: u32,
    leaf_size: vec3<f32>,
    depth: u32,
    count: u32,
    stride: u32,
    // u32 words of one group's occupancy (and of one shaft's cells): 2·⌈n³/64⌉.
    occ_words: u32,
    // 0: no line spaces (exact N-tree traversal), 1: line-space termination.
    use_linespaces: u32,
    // Segment::between: offset at the receiver, and the end t.
    offset: f32,
    seg_t_max: f32,
    samples: u32,
    flags: u32,
    // query::Refine at the deepest level: 0 shaft, 1 cells, 2 exact, 3 near.
    refine: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

struct Seg {
    org: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
// `occupancy`: u64 per 64 child slots read as u32 pairs (low word first): occ_words per group.
@group(0) @binding(1) var<storage, read> occupancy: array<u32>;
// `first_child`: per group, the number of its first filled child (group or leaf).
@group(0) @binding(2) var<storage, read> first_child: array<u32>;
// `leaf_tris`: per leaf, its first entry in tri_indices; plus the end.
@group(0) @binding(3) var<storage, read> leaf_tris: array<u32>;
@group(0) @binding(4) var<storage, read> tri_indices: array<u32>;
// `triangles`: f32×9, world space.
@group(0) @binding(5) var<storage, read> triangles: array<f32>;
// `shaft_cells`: per stored shaft (9n⁴: shaft::ShaftTable), occ_words u32 of the child cells
// it meets.
@group(0) @binding(6) var<storage, read> shaft_cells: array<u32>;
// The occupancy with each group's slots reversed (bit s = slot n³ − 1 − s), for the 6 face
// pairs stored as point reflections.
@group(0) @binding(7) var<storage, read> occupancy_rev: array<u32>;
// `segments`: Seg per invocation; `shadow`: vec4 per receiver (w < 0.5: none, fully lit)
// followed by vec4 per light sample.
@group(0) @binding(8) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> results: array<u32>;

const MAX_DEPTH: u32 = 12u;
const FLAG_FRACTION: u32 = 1u;
const PATCH_MARGIN: f32 = 1e-3;

fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn cross3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

fn tri_vertex(t: u32, v: u32) -> vec3<f32> {
    let i = 9u * t + 3u * v;
    return vec3<f32>(triangles[i], triangles[i + 1u], triangles[i + 2u]);
}

// obvhs Triangle::intersect: a hit with t in [t_min, t_max] (a zero determinant never hits:
// on the CPU it gives t = ±∞ or NaN).
fn hits_triangle(s: Seg, t: u32) -> bool {
    let v0 = tri_vertex(t, 0u);
    let e1 = v0 - tri_vertex(t, 1u);
    let e2 = tri_vertex(t, 2u) - v0;
    let n = cross3(e1, e2);
    let c = v0 - s.org;
    let r = cross3(s.dir, c);
    let det = dot3(n, s.dir);
    if (abs(det) < 3e-39) {
        return false;
    }
    let inv_det = 1.0 / det;
    let u = dot3(r, e2) * inv_det;
    let v = dot3(r, e1) * inv_det;
    let w = 1.0 - u - v;
    // Sign bits, as obvhs: −0.0 counts as outside.
    let signs = bitcast<u32>(u) | bitcast<u32>(v) | bitcast<u32>(w);
    if ((signs & 0x80000000u) != 0u) {
        return false;
    }
    let th = dot3(n, c) * inv_det;
    return th >= s.t_min && th <= s.t_max;
}

fn filled(group: u32, slot: u32) -> bool {
    let w = occupancy[group * params.occ_words + (slot >> 5u)];
    return ((w >> (slot & 31u)) & 1u) == 1u;
}

// NTree::child: first_child + the filled slots below `slot` (a popcount per word).
fn child(group: u32, slot: u32) -> u32 {
    let at = group * params.occ_words;
    var rank = 0u;
    for (var i = 0u; i < (slot >> 5u); i++) {
        rank += countOneBits(occupancy[at + i]);
    }
    let below = (1u << (slot & 31u)) - 1u;
    rank += countOneBits(occupancy[at + (slot >> 5u)] & below);
    return first_child[group] + rank;
}

// shaft::PAIR_ROWS: the stored block of face pair p (pair_index order) | 16 if it is read as
// the point reflection of that block.
fn pair_row(p: u32) -> u32 {
    switch (p) {
        case 0u: { return 0u; }
        case 1u: { return 1u; }
        case 2u: { return 2u; }
        case 3u: { return 3u; }
        case 4u: { return 4u; }
        case 5u: { return 2u | 16u; }
        case 6u: { return 1u | 16u; }
        case 7u: { return 4u | 16u; }
        case 8u: { return 3u | 16u; }
        case 9u: { return 5u; }
        case 10u: { return 6u; }
        case 11u: { return 7u; }
        case 12u: { return 7u | 16u; }
        case 13u: { return 6u | 16u; }
        default: { return 8u; }
    }
}

// Line-space bit of the shaft between patch pa of face fa and patch pb of face fb (fa < fb): the
// group's occupancy meets the shaft's cells (ShaftTable::meets).
fn ls_bit(group: u32, fa: u32, pa: u32, fb: u32, pb: u32) -> bool {
    let pp = params.n * params.n;
    let r = pair_row(pair_index(fa, fb));
    let block = r & 15u;
    var row = block * pp * pp + pa * pp + pb;
    if ((r & 16u) != 0u) {
        row = block * pp * pp + (pp - 1u - pa) * pp + (pp - 1u - pb);
    }
    let at = group * params.occ_words;
    let cb = row * params.occ_words;
    if ((r & 16u) != 0u) {
        for (var i = 0u; i < params.occ_words; i++) {
            if ((occupancy_rev[at + i] & shaft_cells[cb + i]) != 0u) {
                return true;
            }
        }
        return false;
    }
    for (var i = 0u; i < params.occ_words; i++) {
        if ((occupancy[at + i] & shaft_cells[cb + i]) != 0u) {
            return true;
        }
    }
    return false;
}

fn pair_index(a: u32, b: u32) -> u32 {
    return a * (11u - a) / 2u + (b - a - 1u);
}

// Face and patch coordinates of the boundary point at t (query::face_patches); face 6 = none.
fn face_patches(o: vec3<f32>, d: vec3<f32>, base: vec3<f32>, cell: f32, t: f32, entry: bool) -> vec3<f32> {
    let nf = f32(params.n);
    let side = cell * nf;
    var best_f = 6;
    var best_t = 0.0;
    for (var k = 0; k < 3; k++) {
        if (d[k] == 0.0) {
            continue;
        }
        let toward_max = (d[k] > 0.0) != entry;
        var plane = base[k];
        if (toward_max) {
            plane = base[k] + side;
        }
        let tk = (plane - o[k]) / d[k];
        if (best_f == 6 || (entry && tk > best_t) || (!entry && tk < best_t)) {
            best_f = 2 * k + select(0, 1, toward_max);
            best_t = tk;
        }
    }
    if (best_f == 6) {
        return vec3<f32>(6.0, 0.0, 0.0);
    }
    let k = best_f / 2;
    let a = (k + 1) % 3;
    let b = (k + 2) % 3;
    let u = (o[a] + d[a] * t - base[a]) / cell;
    let v = (o[b] + d[b] * t - base[b]) / cell;
    if (!(u >= PATCH_MARGIN && u <= nf - PATCH_MARGIN && v >= PATCH_MARGIN && v <= nf - PATCH_MARGIN)) {
        return vec3<f32>(6.0, 0.0, 0.0);
    }
    return vec3<f32>(f32(best_f), u, v);
}

// Patch index range [lo, hi] within the margin of x (query::patch_range).
fn patch_lo_hi(x: f32) -> vec2<u32> {
    let top = f32(params.n - 1u);
    return vec2<u32>(
        u32(clamp(floor(x - PATCH_MARGIN), 0.0, top)),
        u32(clamp(floor(x + PATCH_MARGIN), 0.0, top)),
    );
}

// query::shaft_full: 0 = every possible shaft empty, 1 = one is full, 2 = no line space applies.
fn shaft_full(o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> u32 {
    let cell = side / f32(params.n);
    let a = face_patches(o, d, base, cell, t0, true);
    if (a.x == 6.0) {
        return 2u;
    }
    let b = face_patches(o, d, base, cell, t1, false);
    if (b.x == 6.0 || a.x == b.x) {
        return 2u;
    }
    let fa = u32(a.x);
    let fb = u32(b.x);
    let n = params.n;
    let ua = patch_lo_hi(a.y);
    let va = patch_lo_hi(a.z);
    let ub = patch_lo_hi(b.y);
    let vb = patch_lo_hi(b.z);
    for (var av = va.x; av <= va.y; av++) {
        for (var au = ua.x; au <= ua.y; au++) {
            let pa = au + n * av;
            for (var bv = vb.x; bv <= vb.y; bv++) {
                for (var bu = ub.x; bu <= ub.y; bu++) {
                    let pb = bu + n * bv;
                    var full: bool;
                    if (fa < fb) {
                        full = ls_bit(group, fa, pa, fb, pb);
                    } else {
                        full = ls_bit(group, fb, pb, fa, pa);
                    }
                    if (full) {
                        return 1u;
                    }
                }
            }
        }
    }
    return 0u;
}

// query::exact_occluded: a DDA over the node's leaves, testing the triangles of filled ones.
fn exact_occluded(s: Seg, o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> bool {
    let n = i32(params.n);
    let cell = side / f32(params.n);
    var dda = dda_new(o, d, base, cell, vec3<i32>(n), t0);
    loop {
        let c = dda.c;
        let slot = u32(c.x + n * c.y + n * n * c.z);
        if (filled(group, slot)) {
            let leaf = child(group, slot);
            let end = leaf_tris[leaf + 1u];
            for (var i = leaf_tris[leaf]; i < end; i++) {
                if (hits_triangle(s, tri_indices[i])) {
                    return true;
                }
            }
        }
        if (dda_exit(dda) >= t1 || !dda_advance(&dda, n)) {
            return false;
        }
    }
    return false;
}

// query::NTree::cells_crossed: whether the segment crosses a leaf of the node with geometry.
fn cells_crossed(o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> bool {
    let n = i32(params.n);
    var dda = dda_new(o, d, base, side / f32(params.n), vec3<i32>(n), t0);
    loop {
        let c = dda.c;
        if (filled(group, u32(c.x + n * c.y + n * n * c.z))) {
            return true;
        }
        if (dda_exit(dda) >= t1 || !dda_advance(&dda, n)) {
            return false;
        }
    }
    return false;
}

struct Frame {
    group: u32,
    // bit 0: the segment starts inside, bit 1: it ends inside.
    inside: u32,
    base: vec3<f32>,
    side: f32,
    t0: f32,
    t1: f32,
    t: f32,
    dda: Dda,
}

// query::NTree::segment_occluded_with.
fn occluded(s: Seg) -> bool {
    let o = (s.org - params.origin) / params.leaf_size;
    let d = s.dir / params.leaf_size;
    let n = i32(params.n);
    var side = 1.0;
    for (var l = 0u; l < params.depth; l++) {
        side *= f32(params.n);
    }
    let iv = box_interval(o, d, vec3<f32>(0.0), vec3<f32>(side));
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
            let deepest = lv + 1u == params.depth;
            mode = 1u;
            if (params.use_linespaces == 1u && f.inside == 0u) {
                let full = shaft_full(o, d, f.group, f.base, f.side, f.t0, f.t1);
                if (full == 0u) {
                    mode = 3u;
                } else if (full == 1u && deepest) {
                    // Refine::Near: the thesis' hit unless the node is entered within one
                    // deepest-node side of the segment's start (query::near_start).
                    let len = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
                    let near = (f.t0 - s.t_min) * len < f.side;
                    if (params.refine == 0u || (params.refine == 3u && !near)) {
                        return true;
                    }
                    var hit = false;
                    if (params.refine == 1u) {
                        hit = cells_crossed(o, d, f.group, f.base, f.side, f.t0, f.t1);
                    } else {
                        hit = exact_occluded(s, o, d, f.group, f.base, f.side, f.t0, f.t1);
                    }
                    if (hit) {
                        return true;
                    }
                    mode = 3u;
                }
            }
            if (mode == 1u && deepest) {
                if (exact_occluded(s, o, d, f.group, f.base, f.side, f.t0, f.t1)) {
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
            if (filled(f.group, slot)) {
                let cell = f.side / f32(params.n);
                var inside = 0u;
                if ((f.inside & 1u) != 0u && f.t == f.t0) {
                    inside |= 1u;
                }
                if ((f.inside & 2u) != 0u && e >= f.t1) {
                    inside |= 2u;
                }
                st[lv + 1u].group = child(f.group, slot);
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

@compute @workgroup_size(64)
fn segments(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let a = queries[2u * i];
    let b = queries[2u * i + 1u];
    results[i] = select(0u, 1u, occluded(Seg(a.xyz, a.w, b.xyz, b.w)));
}

// Segment::between(p, sample, offset).
fn segment_between(p: vec3<f32>, q: vec3<f32>) -> Seg {
    let dir = q - p;
    let len = max(sqrt(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z), 1e-30);
    return Seg(p, min(params.offset / len, 1.0), dir, params.seg_t_max);
}

@compute @workgroup_size(64)
fn shadow(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let p = queries[i];
    var lit = 0u;
    if (p.w < 0.5) {
        lit = params.samples;
    } else {
        for (var k = 0u; k < params.samples; k++) {
            let q = queries[params.count + k].xyz;
            if (!occluded(segment_between(p.xyz, q))) {
                lit += 1u;
            }
        }
    }
    if ((params.flags & FLAG_FRACTION) != 0u) {
        results[i] = bitcast<u32>(f32(lit) / f32(max(params.samples, 1u)));
    } else {
        results[i] = lit;
    }
}
