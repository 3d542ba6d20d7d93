// Entry points over `occluded(s)` (ls_flat.wgsl or ls_scene.wgsl): `segments` (one segment per
// invocation, output 1 = occluded, 0 = clear) and `shadow` (one receiver per invocation against
// every light sample; output the number of lit samples, or with FLAG_FRACTION the f32 bits of
// lit / samples). Bindings `queries` and `results` are declared by the variant (after its pools).

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
