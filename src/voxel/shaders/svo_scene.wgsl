// First hit of a batch of world rays in the two-level SVO (the `svo-scene` section's arrays bound
// as they are; src/voxel/instanced.rs): the terrain's octree, then a DDA over the top grid whose
// cells list instances; each instance's octree is walked on the ray moved into its voxel units,
// operation for operation as InstancedSvo::trace_lod (an instance listed in several cells is
// traced again, with the same answer, where the CPU remembers it). One LOD rule from the top
// cells down: with a cone > 0 a top cell or sub-cell no wider than cone·t where the walk enters
// it, whose aggregate covers enough, ends the walk (InstancedSvo::region_stop); inside an
// instance (and the terrain) svo_walk.wgsl stops on the model's node whose side × |scale| ×
// the model's voxel side is at most cone·t. Output per ray: two vec4<u32>: (instance, cell x,
// y, z) and (bits of t, level in the model's octree, attribute index local to the model, 0);
// instance all ones on a miss; on an aggregate (AGG, attribute, level, 0) and (bits of t, 0, 0,
// 0). Prepended: dda.wgsl, svo_common.wgsl and svo_walk.wgsl.

struct Params {
    top_origin: vec3<f32>,
    top_cell: f32,
    top_dims: vec3<u32>,
    count: u32,
    stride: u32,
    instances: u32,
    terrain: u32,
    // Index of cell_instances' first element in `cells` (cell count + 1).
    list_base: u32,
    // Footprint per unit t (world units); 0: never stop on an aggregate.
    cone: f32,
    // Index in `cells` of top_nodes (4 words per cell) and of top_colors.
    node_base: u32,
    color_base: u32,
    // Index in `cells` of the models' brick_first (per global node) and of their filtered
    // colours (per global attribute).
    brick_base: u32,
    attr_base: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

struct Model {
    origin: vec3<f32>,
    inner_levels: u32,
    voxel_size: vec3<f32>,
    side: f32,
    dims: vec3<u32>,
    first_node: u32,
    first_leaf: u32,
    first_attr: u32,
    node_count: u32,
    pad: u32,
}

struct Inst {
    position: vec3<f32>,
    scale: f32,
    cs: vec2<f32>,
    model: u32,
    reserved: u32,
}

struct GpuRay {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> nodes: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> leaves: array<u32>;
@group(0) @binding(3) var<storage, read> models: array<Model>;
@group(0) @binding(4) var<storage, read> insts: array<Inst>;
// cell_start (cells + 1), cell_instances, top_nodes (4 per cell), top_colors, the models'
// brick_first, the models' filtered colours (node_colors).
@group(0) @binding(5) var<storage, read> cells: array<u32>;
@group(0) @binding(6) var<storage, read> rays: array<GpuRay>;
@group(0) @binding(7) var<storage, read_write> hits: array<vec4<u32>>;

const AGG: u32 = 0xfffffffeu;

fn walk_node_color(i: u32) -> u32 {
    return cells[params.attr_base + i];
}

fn walk_brick_first(n: u32) -> u32 {
    return cells[params.brick_base + n];
}

// InstancedSvo::region_stop: (attribute, level, bits of t, 1) of the region of top cell `c`
// (corner cc, entered at tc, left at exit) that ends the walk, or w = 0.
fn region_stop(o: vec3<f32>, d: vec3<f32>, c: u32, cc: vec3<f32>, tc: f32, exit: f32, t0: f32, t1: f32, cone: f32) -> vec4<u32> {
    let side = params.top_cell;
    if (side <= cone * tc && can_stop(cells[params.color_base + c])) {
        return vec4<u32>(c, 0u, bitcast<u32>(tc), 1u);
    }
    let nb = params.node_base + 4u * c;
    let mask = vec2<u32>(cells[nb], cells[nb + 1u]);
    let sub = side / 4.0;
    if ((mask.x | mask.y) == 0u || sub > cone * min(exit, t1)) {
        return vec4<u32>(0u);
    }
    let q = 0.25;
    let top_cells = params.top_dims.x * params.top_dims.y * params.top_dims.z;
    var dd = dda_new(o, d, cc, q, vec3<i32>(4), tc);
    loop {
        let s = slot_of(dd.c);
        if (mask_bit(mask, s)) {
            let lo = cc + vec3<f32>(dd.c) * q;
            let ts = max(box_interval(o, d, lo, lo + vec3<f32>(q)).x, t0);
            let attr = top_cells + cells[nb + 2u] + count_below(mask, s);
            if (ts <= t1 && sub <= cone * ts && can_stop(cells[params.color_base + attr])) {
                return vec4<u32>(attr, 1u, bitcast<u32>(ts), 1u);
            }
        }
        if (dda_exit(dd) > t1 || !dda_advance(&dd, 4)) {
            return vec4<u32>(0u);
        }
    }
    return vec4<u32>(0u);
}

// InstancedSvo::ray_in + trace_instance_lod: the walk of instance i's model on the ray in its
// voxel units, a voxel measuring |scale| × the model's voxel side.
fn trace_instance(i: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32) -> WalkHit {
    let inst = insts[i];
    let m = models[inst.model];
    let c = inst.cs.x;
    let s = inst.cs.y;
    let q = o - inst.position;
    let pm = vec3<f32>(c * q.x + s * q.y, -s * q.x + c * q.y, q.z) / inst.scale;
    let dm = vec3<f32>(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
    var r: GpuRay;
    r.origin = (pm - m.origin) / m.voxel_size;
    r.dir = dm / (inst.scale * m.voxel_size);
    r.t_min = t0;
    r.t_max = t1;
    let tree = WalkTree(m.dims, m.side, m.inner_levels, m.first_node, m.first_leaf, m.first_attr, m.node_count);
    return svo_walk(r, tree, params.cone, abs(inst.scale) * m.voxel_size.x, false);
}

fn trace_scene(w: GpuRay) -> array<vec4<u32>, 2> {
    var best_i = 0xffffffffu;
    var best = walk_miss();
    if (params.terrain == 1u) {
        let h = trace_instance(params.instances - 1u, w.origin, w.dir, w.t_min, w.t_max);
        if (h.level != 0xffffffffu) {
            best = h;
            best_i = params.instances - 1u;
        }
    }
    let cell = params.top_cell;
    let o = (w.origin - params.top_origin) / cell;
    let d = w.dir / cell;
    let n = vec3<i32>(params.top_dims);
    let iv = box_interval(o, d, vec3<f32>(0.0), vec3<f32>(params.top_dims));
    let t0 = max(iv.x, w.t_min);
    let t1 = min(iv.y, w.t_max);
    if (t0 <= t1 && (cells[params.list_base - 1u] > 0u || params.cone > 0.0)) {
        var dda = dda_new(o, d, vec3<f32>(0.0), 1.0, n, t0);
        let k = max(max(n.x, n.y), n.z);
        loop {
            let ci = u32(dda.c.x) + params.top_dims.x * (u32(dda.c.y) + params.top_dims.y * u32(dda.c.z));
            let exit0 = dda_exit(dda);
            var stop = vec4<u32>(0u);
            if (params.cone > 0.0) {
                let cc = vec3<f32>(dda.c);
                let tc = max(box_interval(o, d, cc, cc + vec3<f32>(1.0)).x, t0);
                stop = region_stop(o, d, ci, cc, tc, exit0, t0, t1, params.cone);
            }
            for (var e = cells[ci]; e < cells[ci + 1u]; e++) {
                let i = cells[params.list_base + e];
                var cap = w.t_max;
                if (best_i != 0xffffffffu) {
                    cap = best.t;
                }
                if (stop.w == 1u) {
                    cap = min(cap, bitcast<f32>(stop.z));
                }
                let h = trace_instance(i, w.origin, w.dir, w.t_min, cap);
                if (h.level != 0xffffffffu) {
                    if (best_i == 0xffffffffu || h.t < best.t || (h.t == best.t && i < best_i)) {
                        best = h;
                        best_i = i;
                    }
                }
            }
            if (stop.w == 1u) {
                if (best_i == 0xffffffffu || best.t > bitcast<f32>(stop.z)) {
                    var agg: array<vec4<u32>, 2>;
                    agg[0] = vec4<u32>(AGG, stop.x, stop.y, 0u);
                    agg[1] = vec4<u32>(stop.z, 0u, 0u, 0u);
                    return agg;
                }
                break;
            }
            let exit = dda_exit(dda);
            if ((best_i != 0xffffffffu && best.t < exit) || exit > t1) {
                break;
            }
            if (!dda_advance(&dda, k) || dda.c.x >= n.x || dda.c.y >= n.y || dda.c.z >= n.z) {
                break;
            }
        }
    }
    var out: array<vec4<u32>, 2>;
    out[0] = vec4<u32>(best_i, best.cell);
    out[1] = vec4<u32>(bitcast<u32>(best.t), best.level, best.attr, 0u);
    if (best_i == 0xffffffffu) {
        out[0] = vec4<u32>(0xffffffffu);
        out[1] = vec4<u32>(0u);
    }
    return out;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let h = trace_scene(rays[i]);
    hits[2u * i] = h[0];
    hits[2u * i + 1u] = h[1];
}
