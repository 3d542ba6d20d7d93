// HDR to display: L_s = 1 - exp(-L s) (seed 000, 4.7.4); the Rgba8UnormSrgb target applies the
// sRGB encoding when it stores the value.

struct ToneParams {
    // x: exposure s
    exposure: vec4<f32>,
};

@group(0) @binding(0) var hdr: texture_2d<f32>;
@group(0) @binding(1) var<uniform> tone: ToneParams;

@vertex
fn vs_main(@builtin(vertex_index) vid: u32) -> @builtin(position) vec4<f32> {
    let x = f32(vid & 1u) * 4.0 - 1.0;
    let y = f32(vid >> 1u) * 4.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) position: vec4<f32>) -> @location(0) vec4<f32> {
    let l = textureLoad(hdr, vec2<i32>(position.xy), 0).rgb;
    return vec4<f32>(1.0 - exp(-max(l, vec3<f32>(0.0)) * tone.exposure.x), 1.0);
}
