// HDR to display: L_s = 1 - exp(-L s) (seed 000, 4.7.4); the Rgba8UnormSrgb target applies the
// sRGB encoding when it stores the value, or (--gamma) the thesis' L_g = L_s^γ is written as is.

struct ToneParams {
    // x: exposure s; y: 0 sRGB encoding, 1 the thesis' L_g = L_s^γ (eq. 4.10) with γ in z
    exposure: vec4<f32>,
};

// The linear value whose sRGB encoding (applied by the target on store) is `v`.
fn srgb_decode(v: vec3<f32>) -> vec3<f32> {
    let lo = v / 12.92;
    let hi = pow((v + 0.055) / 1.055, vec3<f32>(2.4));
    return select(hi, lo, v <= vec3<f32>(0.04045));
}

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
    let ls = 1.0 - exp(-max(l, vec3<f32>(0.0)) * tone.exposure.x);
    if (tone.exposure.y > 0.5) {
        // The target encodes to sRGB on store: hand it the value whose encoding is L_g.
        return vec4<f32>(srgb_decode(pow(ls, vec3<f32>(tone.exposure.z))), 1.0);
    }
    return vec4<f32>(ls, 1.0);
}
