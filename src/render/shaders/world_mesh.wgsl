// World-position pass of the soft shadows (src/render/soft_shadow.rs), instanced meshes: the
// same alpha test as fs_main, and the receiver lifted along the viewer-facing normal by 10⁻³ of
// its distance to the eye. Appended to common.wgsl + mesh.wgsl (vs_main, MeshOut).

@fragment
fn fs_world(in: MeshOut) -> @location(0) vec4<u32> {
    let texel = textureSample(color_map, color_sampler, in.uv);
    if (texel.a * direct_material.mode.z < 0.5) {
        discard;
    }
    let n = facing_normal(in.normal, in.world);
    let bias = 1e-3 * distance(globals.eye.xyz, in.world);
    // The bits of the f32s: the target is Rgba32Uint (soft_shadow.rs, WORLD_FORMAT).
    return bitcast<vec4<u32>>(vec4<f32>(in.world + n * bias, 1.0));
}
