// Entry points over `occluded(s)` (ls_flat.wgsl or ls_scene.wgsl): `segments` (one segment per
// invocation, output 1 = occluded, 0 = clear), `shadow` (one invocation per receiver and light
// sample, adding 1 to the receiver's count of lit samples; the output starts at 0) and
// `fractions` (per receiver, the count replaced by the f32 bits of lit / samples). Bindings
// `queries` and `results` (atomic u32) are declared by the variant, after its pools.
// One invocation per receiver looping over the samples gave wrong counts on lavapipe (Mesa
// 22.3) for the two-level query at scale, though every segment alone was right.

@compute @workgroup_size(64)
fn segments(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let a = queries[2u * i];
    let b = queries[2u * i + 1u];
    atomicStore(&results[i], select(0u, 1u, occluded(Seg(a.xyz, a.w, b.xyz, b.w))));
}

// Segment::between(p, sample, offset).
fn segment_between(p: vec3<f32>, q: vec3<f32>) -> Seg {
    let dir = q - p;
    let len = max(sqrt(dir.x * dir.x + dir.y * dir.y + dir.z * dir.z), 1e-30);
    return Seg(p, min(params.offset / len, 1.0), dir, params.seg_t_max);
}

// `queries`: vec4 per receiver (w < 0.5: none, every sample counts as lit), then vec4 per light
// sample; invocation j is receiver j / samples, sample j % samples.
@compute @workgroup_size(64)
fn shadow(@builtin(global_invocation_id) gid: vec3<u32>) {
    let j = flat_index(gid, params.stride);
    if (params.samples == 0u || j / params.samples >= params.count) {
        return;
    }
    let i = j / params.samples;
    let p = queries[i];
    if (p.w < 0.5 || !occluded(segment_between(p.xyz, queries[params.count + j % params.samples].xyz))) {
        atomicAdd(&results[i], 1u);
    }
}

@compute @workgroup_size(64)
fn fractions(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid, params.stride);
    if (i >= params.count) {
        return;
    }
    let lit = atomicLoad(&results[i]);
    atomicStore(&results[i], bitcast<u32>(f32(lit) / f32(max(params.samples, 1u))));
}
