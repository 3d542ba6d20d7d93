// The two-level line spaces of a placed scene (the `linespace-scene` section,
// linespace::instanced::SceneLinespace::segment_occluded): the terrain's exact any-hit through
// its min/max quadtree (trace::heightfield::Heightfield::any_hit, the same cell triangles and
// the same Möller–Trumbore as trace::bvh::intersect), then the top tree over the instances'
// bounds (walk `_top`: refinement always exact, its leaves listing instances), each listed
// instance tested by its model's tree (walk `_model`) on the segment moved into the model's
// frame, whose leaves place the model's triangles into the world and test them against the
// world segment. The pools hold the top tree first, then every model tree (`scene`'s tree
// table gives their bases).

// `scene` (u32 words): the tree table (12 words per tree: origin, depth, leaf size, the bases
// of its groups, leaves, indices and triangles, one unused), the instances at
// `params.instances_at` (8 words each: position, scale, cos θ, sin θ, model, unused: InstanceRef),
// the quadtree's levels 1.. at `params.levels_at` (3 words per level: width, height, first
// node; the nodes [min, max] as f32 pairs after the table). Level 0 (one node per cell) is
// computed from `heights` as MinMaxQuadtree::build does.
@group(0) @binding(8) var<storage, read> scene: array<u32>;
// The terrain's heights, row-major (one f32 when there is no terrain).
@group(0) @binding(9) var<storage, read> heights: array<f32>;
@group(0) @binding(10) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> results: array<atomic<u32>>;

fn f32_at(w: u32) -> f32 {
    return bitcast<f32>(scene[w]);
}

fn tree_at(k: u32) -> Tree {
    let w = 12u * k;
    var t: Tree;
    t.origin = vec3<f32>(f32_at(w), f32_at(w + 1u), f32_at(w + 2u));
    t.depth = scene[w + 3u];
    t.leaf_size = vec3<f32>(f32_at(w + 4u), f32_at(w + 5u), f32_at(w + 6u));
    t.groups = scene[w + 7u];
    t.leaves = scene[w + 8u];
    t.indices = scene[w + 9u];
    t.tris = scene[w + 10u];
    return t;
}

// Instance i's placement (its model: inst_model) with the world segment.
fn inst_at(i: u32, s: Seg) -> Placement {
    let w = params.instances_at + 8u * i;
    return Placement(
        vec3<f32>(f32_at(w), f32_at(w + 1u), f32_at(w + 2u)),
        f32_at(w + 3u),
        f32_at(w + 4u),
        f32_at(w + 5u),
        s,
    );
}

fn inst_model(i: u32) -> u32 {
    return scene[params.instances_at + 8u * i + 6u];
}

// InstanceRef::dir_to_model.
fn dir_to_model(r: Placement, d: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(r.cos * d.x + r.sin * d.y, -r.sin * d.x + r.cos * d.y, d.z);
}

// InstanceRef::to_world.
fn to_world(r: Placement, p: vec3<f32>) -> vec3<f32> {
    let q = p * r.scale;
    let w = vec3<f32>(r.cos * q.x - r.sin * q.y, r.sin * q.x + r.cos * q.y, q.z);
    return w + r.position;
}

// SceneLinespace::segment_in: the same t, the origin and direction in the model's frame.
fn segment_in(r: Placement, s: Seg) -> Seg {
    let org = dir_to_model(r, s.org - r.position) / r.scale;
    return Seg(org, s.t_min, dir_to_model(r, s.dir) / r.scale, s.t_max);
}

// A model tree's leaf: its triangles placed by the current instance, against the world segment.
fn leaf_hit_model(s: Seg, tr: Tree, leaf: u32, at: Placement) -> bool {
    let end = tr.indices + leaf_tris[tr.leaves + leaf + 1u];
    for (var i = tr.indices + leaf_tris[tr.leaves + leaf]; i < end; i++) {
        let t = tr.tris + tri_indices[i];
        let a = to_world(at, tri_vertex(t, 0u));
        let b = to_world(at, tri_vertex(t, 1u));
        let c = to_world(at, tri_vertex(t, 2u));
        if (hits_triangle(at.world, a, b, c)) {
            return true;
        }
    }
    return false;
}

// Where the segment enters a tree's root box (NTree::root_span's t0), or t_max when it misses.
fn root_entry(s: Seg, tr: Tree) -> f32 {
    let iv = root_of(s, tr).iv;
    let t0 = max(iv.x, s.t_min);
    let t1 = min(iv.y, s.t_max);
    if (t0 > t1 || iv.x != iv.x || iv.y != iv.y) {
        return s.t_max;
    }
    return t0;
}

// SceneLinespace::instance_occluded: in `near` mode exact for an instance whose model box the
// segment enters within near_distance of its start.
fn instance_occluded(i: u32, s: Seg) -> bool {
    let r = inst_at(i, s);
    let tr = tree_at(inst_model(i) + 1u);
    let ms = segment_in(r, s);
    var refine = params.refine;
    if (refine == 3u) {
        let len = sqrt(s.dir.x * s.dir.x + s.dir.y * s.dir.y + s.dir.z * s.dir.z);
        if ((root_entry(ms, tr) - s.t_min) * len <= params.near_distance) {
            refine = 2u;
        }
    }
    return occluded_model(ms, tr, r, params.use_linespaces == 1u, refine);
}

// A top tree's leaf: every instance it lists (an instance listed by several leaves on the
// segment's way is tested again: the CPU skips it, the answer is the same).
fn leaf_hit_top(s: Seg, tr: Tree, leaf: u32, at: Placement) -> bool {
    let end = tr.indices + leaf_tris[tr.leaves + leaf + 1u];
    for (var e = tr.indices + leaf_tris[tr.leaves + leaf]; e < end; e++) {
        if (instance_occluded(tri_indices[e], s)) {
            return true;
        }
    }
    return false;
}

// --- The terrain (trace::heightfield) ---

const PAD_CELLS: f32 = 1e-3;
// 3 nodes per level pushed at most before the next pop, plus one (levels ≤ 21: gpu.rs checks).
const HF_STACK: u32 = 64u;

fn hf_height(i: u32, j: u32) -> f32 {
    return heights[j * (params.hf_cells.x + 1u) + i];
}

// Heightfield::position.
fn hf_position(i: u32, j: u32) -> vec3<f32> {
    return vec3<f32>(
        params.hf_origin.x + f32(i) * params.hf_step.x,
        params.hf_origin.y + f32(j) * params.hf_step.y,
        hf_height(i, j),
    );
}

// Level k's width, height and first node (level 0: the cells, computed from the heights).
fn hf_level(k: u32) -> vec3<u32> {
    if (k == 0u) {
        return vec3<u32>(params.hf_cells, 0u);
    }
    let w = params.levels_at + 3u * (k - 1u);
    return vec3<u32>(scene[w], scene[w + 1u], scene[w + 2u]);
}

// MinMaxQuadtree::node: [min, max] of node (x, y) of level k.
fn hf_node(k: u32, x: u32, y: u32) -> vec2<f32> {
    if (k == 0u) {
        let c0 = hf_height(x, y);
        let c1 = hf_height(x + 1u, y);
        let c2 = hf_height(x, y + 1u);
        let c3 = hf_height(x + 1u, y + 1u);
        return vec2<f32>(min(min(c0, c1), min(c2, c3)), max(max(c0, c1), max(c2, c3)));
    }
    let l = hf_level(k);
    let at = params.levels_at + 3u * (params.hf_levels - 1u) + 2u * (l.z + y * l.x + x);
    return vec2<f32>(f32_at(at), f32_at(at + 1u));
}

struct GridRay {
    o: vec3<f32>,
    d: vec3<f32>,
    inv: vec3<f32>,
}

// Heightfield::span: entry and exit of node (k, x, y)'s padded box within [tmin, tmax]
// (x > y: missed).
fn hf_span(g: GridRay, k: u32, x: u32, y: u32, tmin: f32, tmax: f32) -> vec2<f32> {
    let l0 = params.hf_cells;
    let x0 = f32(x << k);
    let y0 = f32(y << k);
    let x1 = f32(min((x + 1u) << k, l0.x));
    let y1 = f32(min((y + 1u) << k, l0.y));
    let z = hf_node(k, x, y);
    let lo = vec3<f32>(x0 - PAD_CELLS, y0 - PAD_CELLS, z.x - params.hf_pad_z);
    let hi = vec3<f32>(x1 + PAD_CELLS, y1 + PAD_CELLS, z.y + params.hf_pad_z);
    let t0 = (lo - g.o) * g.inv;
    let t1 = (hi - g.o) * g.inv;
    let a = min(t0, t1);
    let b = max(t0, t1);
    let near = max(max(max(a.x, a.y), a.z), tmin);
    let far = min(min(min(b.x, b.y), b.z), tmax);
    return vec2<f32>(near, far);
}

// trace::bvh::intersect on the triangle (v0, v0 + e1, v0 + e2): a hit with t in [tmin, tmax].
fn hf_triangle(v0: vec3<f32>, e1: vec3<f32>, e2: vec3<f32>, s: Seg) -> bool {
    let p = cross3(s.dir, e2);
    let det = dot3(e1, p);
    if (det == 0.0) {
        return false;
    }
    let inv = 1.0 / det;
    let q0 = s.org - v0;
    let u = dot3(q0, p) * inv;
    if (!(u >= 0.0 && u <= 1.0)) {
        return false;
    }
    let q = cross3(q0, e1);
    let v = dot3(s.dir, q) * inv;
    if (!(v >= 0.0 && u + v <= 1.0)) {
        return false;
    }
    let t = dot3(e2, q) * inv;
    return t >= s.t_min && t <= s.t_max;
}

// Heightfield::hit_cell (either of cell (i, j)'s two triangles).
fn hf_cell_hit(i: u32, j: u32, s: Seg) -> bool {
    let a = hf_position(i, j);
    let b = hf_position(i + 1u, j);
    let c = hf_position(i, j + 1u);
    let d = hf_position(i + 1u, j + 1u);
    return hf_triangle(a, b - a, d - a, s) || hf_triangle(a, d - a, c - a, s);
}

// Heightfield::any_hit: a stack descent from the smallest node covering the segment's footprint.
fn terrain_occluded(s: Seg) -> bool {
    var g: GridRay;
    g.o = vec3<f32>(
        (s.org.x - params.hf_origin.x) / params.hf_step.x,
        (s.org.y - params.hf_origin.y) / params.hf_step.y,
        s.org.z,
    );
    g.d = vec3<f32>(s.dir.x / params.hf_step.x, s.dir.y / params.hf_step.y, s.dir.z);
    g.inv = 1.0 / g.d;
    let top = params.hf_levels - 1u;
    let span = hf_span(g, top, 0u, 0u, s.t_min, s.t_max);
    if (!(span.x <= span.y)) {
        return false;
    }
    // Heightfield::root.
    var root = vec3<u32>(top, 0u, 0u);
    let a = g.o + g.d * span.x;
    let b = g.o + g.d * span.y;
    let big = 3.0e38;
    let finite = all(abs(a) <= vec3<f32>(big)) && all(abs(b) <= vec3<f32>(big));
    if (finite) {
        let l0 = params.hf_cells;
        let pad = 2.0 * PAD_CELLS;
        let x0 = u32(clamp(min(a.x, b.x) - pad, 0.0, f32(l0.x - 1u)));
        let x1 = u32(clamp(max(a.x, b.x) + pad, 0.0, f32(l0.x - 1u)));
        let y0 = u32(clamp(min(a.y, b.y) - pad, 0.0, f32(l0.y - 1u)));
        let y1 = u32(clamp(max(a.y, b.y) + pad, 0.0, f32(l0.y - 1u)));
        var k = 0u;
        while (k < top && ((x0 >> k) != (x1 >> k) || (y0 >> k) != (y1 >> k))) {
            k += 1u;
        }
        root = vec3<u32>(k, x0 >> k, y0 >> k);
    }
    var stack: array<vec3<u32>, HF_STACK>;
    stack[0] = root;
    var sp = 1u;
    while (sp > 0u) {
        sp -= 1u;
        let nd = stack[sp];
        if (nd.x == 0u) {
            if (hf_cell_hit(nd.y, nd.z, s)) {
                return true;
            }
            continue;
        }
        let k = nd.x - 1u;
        let l = hf_level(k);
        for (var c = 0u; c < 4u; c++) {
            let x = 2u * nd.y + (c & 1u);
            let y = 2u * nd.z + (c >> 1u);
            if (x < l.x && y < l.y && sp < HF_STACK) {
                let sp2 = hf_span(g, k, x, y, s.t_min, s.t_max);
                if (sp2.x <= sp2.y) {
                    stack[sp] = vec3<u32>(k, x, y);
                    sp += 1u;
                }
            }
        }
    }
    return false;
}

// SceneLinespace::segment_occluded (with `use_linespaces == 0`: every tree walked without line
// spaces, every leaf on the way tested exactly: the exact visibility of the placed scene).
fn occluded(s: Seg) -> bool {
    if (params.has_terrain == 1u && terrain_occluded(s)) {
        return true;
    }
    if (params.trees == 0u || params.instances == 0u) {
        return false;
    }
    var none: Placement;
    return occluded_top(s, tree_at(0u), none, params.use_linespaces == 1u, 2u);
}
