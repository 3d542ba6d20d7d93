// One N-tree (the `linespace` section): its leaves hold its own triangles, in the world.

// `segments`: Seg per invocation; `shadow`: vec4 per receiver (w < 0.5: none, fully lit)
// followed by vec4 per light sample.
@group(0) @binding(8) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> results: array<atomic<u32>>;

fn leaf_hit_flat(s: Seg, tr: Tree, leaf: u32, at: Placement) -> bool {
    let end = tr.indices + leaf_tris[tr.leaves + leaf + 1u];
    for (var i = tr.indices + leaf_tris[tr.leaves + leaf]; i < end; i++) {
        let t = tr.tris + tri_indices[i];
        if (hits_triangle(s, tri_vertex(t, 0u), tri_vertex(t, 1u), tri_vertex(t, 2u))) {
            return true;
        }
    }
    return false;
}

fn occluded(s: Seg) -> bool {
    var tr: Tree;
    tr.origin = params.origin;
    tr.leaf_size = params.leaf_size;
    tr.depth = params.depth;
    tr.groups = 0u;
    tr.leaves = 0u;
    tr.indices = 0u;
    tr.tris = 0u;
    var at: Placement;
    return occluded_flat(s, tr, at, params.use_linespaces == 1u, params.refine);
}
