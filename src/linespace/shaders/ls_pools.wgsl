// The N-tree's pools as the `linespace` section packs them (layout in src/linespace/ntree.rs and
// docs/FORMAT.md), one or more trees concatenated (a `Tree` names a tree's bases), and what a
// traversal needs besides its leaves: children found by rank over the occupancy bits,
// line-space bits as occupancy & shaft cells (shaft_full), exact Möller–Trumbore tests written
// like obvhs' Triangle::intersect (the CPU's exact test). The walk itself is ls_walk.wgsl,
// instantiated per kind of leaf; the entry points are ls_entries.wgsl over an `occluded(s)` that
// ls_flat.wgsl (one tree, its own triangles) or ls_scene.wgsl (two levels over instances and the
// terrain) defines. Prepended: dda.wgsl.

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
    reserved: u32,
    // query::Refine at the deepest level: 0 shaft, 1 cells, 2 exact, 3 near.
    refine: u32,
    // ls_scene.wgsl: trees in `scene` (the top tree first), instances, whether a terrain is bound.
    trees: u32,
    instances: u32,
    has_terrain: u32,
    // The terrain (trace::heightfield): origin and sample step (x, y), cells per row and column,
    // quadtree levels, the boxes' height margin.
    hf_origin: vec2<f32>,
    hf_step: vec2<f32>,
    hf_cells: vec2<u32>,
    hf_levels: u32,
    hf_pad_z: f32,
    // SceneLinespace::near_distance; where the instances and the quadtree's levels start in
    // `scene` (u32 words).
    near_distance: f32,
    instances_at: u32,
    levels_at: u32,
    pad0: u32,
}

struct Seg {
    org: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

// One tree in the pools: its grid and where its groups, leaves, indices and triangles start.
struct Tree {
    origin: vec3<f32>,
    depth: u32,
    leaf_size: vec3<f32>,
    groups: u32,
    leaves: u32,
    indices: u32,
    tris: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// `occupancy`: u64 per 64 child slots read as u32 pairs (low word first): occ_words per group.
@group(0) @binding(1) var<storage, read> occupancy: array<u32>;
// `first_child`: per group, the number of its first filled child (group or leaf).
@group(0) @binding(2) var<storage, read> first_child: array<u32>;
// `leaf_tris`: per leaf, its first entry in tri_indices; plus the end.
@group(0) @binding(3) var<storage, read> leaf_tris: array<u32>;
@group(0) @binding(4) var<storage, read> tri_indices: array<u32>;
// `triangles`: f32×9 (a flattened tree's in the world, a model tree's in its model's frame).
@group(0) @binding(5) var<storage, read> triangles: array<f32>;
// `shaft_cells`: per stored shaft (9n⁴: shaft::ShaftTable), occ_words u32 of the child cells
// it meets.
@group(0) @binding(6) var<storage, read> shaft_cells: array<u32>;
// The occupancy with each group's slots reversed (bit s = slot n³ − 1 − s), for the 6 face
// pairs stored as point reflections.
@group(0) @binding(7) var<storage, read> occupancy_rev: array<u32>;
const MAX_DEPTH: u32 = 12u;
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
fn hits_triangle(s: Seg, v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>) -> bool {
    let e1 = v0 - v1;
    let e2 = v2 - v0;
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

fn filled(tr: Tree, group: u32, slot: u32) -> bool {
    let w = occupancy[(tr.groups + group) * params.occ_words + (slot >> 5u)];
    return ((w >> (slot & 31u)) & 1u) == 1u;
}

// NTree::child: first_child + the filled slots below `slot` (a popcount per word).
fn child(tr: Tree, group: u32, slot: u32) -> u32 {
    let at = (tr.groups + group) * params.occ_words;
    var rank = 0u;
    for (var i = 0u; i < (slot >> 5u); i++) {
        rank += countOneBits(occupancy[at + i]);
    }
    let below = (1u << (slot & 31u)) - 1u;
    rank += countOneBits(occupancy[at + (slot >> 5u)] & below);
    return first_child[tr.groups + group] + rank;
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
fn ls_bit(tr: Tree, group: u32, fa: u32, pa: u32, fb: u32, pb: u32) -> bool {
    let pp = params.n * params.n;
    let r = pair_row(pair_index(fa, fb));
    let block = r & 15u;
    var row = block * pp * pp + pa * pp + pb;
    if ((r & 16u) != 0u) {
        row = block * pp * pp + (pp - 1u - pa) * pp + (pp - 1u - pb);
    }
    let at = (tr.groups + group) * params.occ_words;
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
fn shaft_full(tr: Tree, o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> u32 {
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
                        full = ls_bit(tr, group, fa, pa, fb, pb);
                    } else {
                        full = ls_bit(tr, group, fb, pb, fa, pa);
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

// query::NTree::cells_crossed: whether the segment crosses a leaf of the node with geometry.
fn cells_crossed(tr: Tree, o: vec3<f32>, d: vec3<f32>, group: u32, base: vec3<f32>, side: f32, t0: f32, t1: f32) -> bool {
    let n = i32(params.n);
    var dda = dda_new(o, d, base, side / f32(params.n), vec3<i32>(n), t0);
    loop {
        let c = dda.c;
        if (filled(tr, group, u32(c.x + n * c.y + n * n * c.z))) {
            return true;
        }
        if (dda_exit(dda) >= t1 || !dda_advance(&dda, n)) {
            return false;
        }
    }
    return false;
}

// What a model tree's leaves need besides their triangles: the instance placing them
// (InstanceRef's position, scale, cos θ, sin θ) and the segment in the world (ls_scene.wgsl;
// unused by the other leaves). Passed by value: per-invocation `var<private>` state written in
// divergent code gave wrong answers on lavapipe.
struct Placement {
    position: vec3<f32>,
    scale: f32,
    cos: f32,
    sin: f32,
    world: Seg,
}

// A node on the walk's stack (ls_walk.wgsl).
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

// The segment in a tree's leaf-cell units and where it lies in the root box (NTree::grid_ray,
// root_span): `iv` the box's entry and exit t, `side` the root's side in leaf cells.
struct Root {
    o: vec3<f32>,
    side: f32,
    d: vec3<f32>,
    iv: vec2<f32>,
}

fn root_of(s: Seg, tr: Tree) -> Root {
    var r: Root;
    r.o = (s.org - tr.origin) / tr.leaf_size;
    r.d = s.dir / tr.leaf_size;
    r.side = 1.0;
    for (var l = 0u; l < tr.depth; l++) {
        r.side *= f32(params.n);
    }
    r.iv = box_interval(r.o, r.d, vec3<f32>(0.0), vec3<f32>(r.side));
    return r;
}
