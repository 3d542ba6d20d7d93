// Shared by the sky, terrain and mesh passes: per-frame constants (group 0) and the shading.
// Layout mirrors `Globals` in src/render/draw.rs (192 bytes).

struct Globals {
    view_proj: mat4x4<f32>,
    // xyz: camera position; w: exposure s of the tone map 1 - exp(-L s)
    eye: vec4<f32>,
    // camera frame scaled so that forward + ndc.x * right + ndc.y * up is the pixel's ray
    cam_right: vec4<f32>,
    cam_up: vec4<f32>,
    cam_forward: vec4<f32>,
    // xyz: unit vector towards the sun
    sun_direction: vec4<f32>,
    sun_irradiance: vec4<f32>,
    // irradiance of a horizontal surface from the sky
    ambient: vec4<f32>,
    // x, y: image width and height in pixels
    viewport: vec4<f32>,
};

@group(0) @binding(0) var<uniform> globals: Globals;
// The sky, lat-long, linear RGB radiance, Rgba32Float read with textureLoad (not filterable on GL).
@group(0) @binding(1) var sky_texture: texture_2d<f32>;

// The sun's visibility per pixel, R32Float: 1×1 texel of 1 unless `--soft-shadows` (then the
// line-space soft shadows of src/render/soft_shadow.rs, one texel per pixel).
@group(0) @binding(2) var sun_visibility: texture_2d<f32>;

const PI: f32 = 3.14159265358979;

fn sun_visibility_at(frag: vec4<f32>) -> f32 {
    let last = vec2<i32>(textureDimensions(sun_visibility)) - vec2<i32>(1);
    return textureLoad(sun_visibility, min(vec2<i32>(frag.xy), last), 0).r;
}

// Lambert under the sun (times its visibility) plus the sky ambient, see src/render/light.rs.
fn shade_lambert(albedo: vec3<f32>, n: vec3<f32>, visibility: f32) -> vec3<f32> {
    let sun = globals.sun_irradiance.rgb * max(dot(n, globals.sun_direction.xyz), 0.0) * visibility;
    let sky = globals.ambient.rgb * (0.5 + 0.5 * n.z);
    return albedo * (sun + sky) / PI;
}

// Normal facing the viewer (plants are thin and lit from both sides); a degenerate normal
// becomes the view direction.
fn facing_normal(n_in: vec3<f32>, world: vec3<f32>) -> vec3<f32> {
    let v = normalize(globals.eye.xyz - world);
    if (dot(n_in, n_in) < 1e-12) {
        return v;
    }
    let n = normalize(n_in);
    if (dot(n, v) < 0.0) {
        return -n;
    }
    return n;
}
