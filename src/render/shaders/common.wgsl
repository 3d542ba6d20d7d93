// Shared by the sky, terrain and mesh passes: per-frame constants (group 0) and the shading.
// Layout mirrors `Globals` in src/render/draw.rs (192 bytes).

struct Globals {
    view_proj: mat4x4<f32>,
    // xyz: camera position; w: exposure s of the tone map 1 - exp(-L s)
    eye: vec4<f32>,
    // camera frame scaled so that forward + ndc.x * right + ndc.y * up is the pixel's ray
    cam_right: vec4<f32>,
    cam_up: vec4<f32>,
    // w: 1 where the sky is the cube texture `sky_cube`, 0 for the lat-long `sky_texture`
    cam_forward: vec4<f32>,
    // xyz: unit vector towards the sun
    sun_direction: vec4<f32>,
    sun_irradiance: vec4<f32>,
    // irradiance of a horizontal surface from the sky; w: 1 in the region pass (`region_pass`)
    ambient: vec4<f32>,
    // x, y: image width and height in pixels; z, w: weights of the direct and ambient terms
    viewport: vec4<f32>,
};

@group(0) @binding(0) var<uniform> globals: Globals;
// The sky, lat-long, linear RGB radiance, Rgba32Float read with textureLoad (not filterable on GL).
@group(0) @binding(1) var sky_texture: texture_2d<f32>;
// The sun's visibility per pixel from the line-space soft shadows (src/render/soft_shadow.rs),
// R32Float, used where sun_direction.w is 1 (`bake render --soft-shadows`); 1×1 otherwise.
@group(0) @binding(2) var soft_visibility: texture_2d<f32>;
// The sky stage's cube map, Rgba16Float, faces on world axes (src/cube.rs): sampled with the
// world direction, bilinear and seamless.
@group(0) @binding(3) var sky_cube: texture_cube<f32>;
@group(0) @binding(4) var sky_sampler: sampler;

const PI: f32 = 3.14159265358979;

// The region pass (`bake render --regions`, globals.ambient.w = 1): every fragment writes its
// region's indicator instead of radiance, so the resolved image holds each region's coverage.
const REGION_TERRAIN: vec3<f32> = vec3<f32>(1.0, 0.0, 0.0);
const REGION_OPAQUE: vec3<f32> = vec3<f32>(0.0, 1.0, 0.0);
const REGION_LEAVES: vec3<f32> = vec3<f32>(0.0, 0.0, 1.0);

fn region_pass() -> bool {
    return globals.ambient.w != 0.0;
}

// A model surface's region: leaves where `leaves` is set (an alpha-tested material).
fn model_region(leaves: bool) -> vec3<f32> {
    return select(REGION_OPAQUE, REGION_LEAVES, leaves);
}

// The soft-shadow visibility of the pixel that `world` projects to.
fn soft_visibility_at(world: vec3<f32>) -> f32 {
    let c = globals.view_proj * vec4<f32>(world, 1.0);
    let uv = vec2<f32>(c.x / c.w * 0.5 + 0.5, 0.5 - c.y / c.w * 0.5);
    let size = vec2<i32>(textureDimensions(soft_visibility));
    let px = clamp(vec2<i32>(floor(uv * vec2<f32>(size))), vec2<i32>(0), size - vec2<i32>(1));
    return textureLoad(soft_visibility, px, 0).r;
}

// The sky ambient of src/render/light.rs: albedo/π · E_sky · (1 + n_z)/2 (the CPU reference's
// `Reference::ambient_term`; the ambient term of the shading contract replaces it).
fn ambient_sky(albedo: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return albedo * globals.ambient.rgb * (0.5 + 0.5 * n.z) / PI;
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
