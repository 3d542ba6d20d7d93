// World-position pass of the soft shadows (src/render/soft_shadow.rs), terrain: the receiver,
// lifted off the surface along its normal by 10⁻³ of its distance to the eye. Appended to
// common.wgsl + terrain.wgsl (vs_main, TerrainOut).

@fragment
fn fs_world(in: TerrainOut) -> @location(0) vec4<u32> {
    let n = normalize(in.normal);
    let bias = 1e-3 * distance(globals.eye.xyz, in.world);
    // The bits of the f32s: the target is Rgba32Uint (soft_shadow.rs, WORLD_FORMAT).
    return bitcast<vec4<u32>>(vec4<f32>(in.world + n * bias, 1.0));
}
