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

// Alpha coverage as samples (src/render/coverage.rs; the mesh and impostor passes).

// Coverage by sample mask (set by the pipeline under 4× MSAA, src/render/pipelines.rs), in the
// mesh and impostor passes: the mesh's alpha test at 0.5 becomes a ramp one pixel wide across the alpha edge, blended towards the
// level-0 coverage far away, and each sample is kept where that coverage reaches the sample's
// threshold (`sample_threshold`); the shader writes the mask. Without it the test is a hard
// discard against the pixel's threshold.
override SAMPLE_MASK: bool = false;

// The threshold of sample k of 4 in a pixel of dither threshold d: d + k/4 modulo 1
// (src/render/coverage.rs `sample_threshold`; multiples of 1/32, exact).
fn sample_threshold(d: f32, k: u32) -> f32 {
    let x = d + f32(k) * 0.25;
    return select(x, x - 1.0, x >= 1.0);
}

// A shaded fragment: its colour and the samples it keeps.
struct Shaded {
    color: vec4<f32>,
    mask: u32,
};

// The scene pass' fragment where the backend writes the sample mask.
struct MaskedFragment {
    @location(0) color: vec4<f32>,
    @builtin(sample_mask) mask: u32,
};

// The samples of 4 a fragment keeps in a pixel of dither threshold d, c[k] the coverage at
// sample k.
fn sample_mask_of(c: vec4<f32>, d: f32) -> u32 {
    var mask = 0u;
    for (var k = 0u; k < 4u; k++) {
        if (c[k] >= sample_threshold(d, k)) {
            mask = mask | (1u << k);
        }
    }
    return mask;
}

// The standard 4× sample positions in the pixel (Vulkan's, D3D's; the CPU reference's
// `STANDARD_4X`).
fn sample_position(k: u32) -> vec2<f32> {
    let p = array<vec2<f32>, 4>(
        vec2<f32>(0.375, 0.125),
        vec2<f32>(0.875, 0.375),
        vec2<f32>(0.125, 0.625),
        vec2<f32>(0.625, 0.875),
    );
    return p[k];
}

// The screen point (pixels, y down) of a clip-space position interpolated as the fragment's
// other inputs are: where the device evaluated them (the pixel's centre under per-pixel shading;
// per-sample shading, GL's path, keeps them there too on llvmpipe and lavapipe while the
// fragment's position moves to the sample, so it is measured rather than assumed).
fn screen_point(clip: vec4<f32>) -> vec2<f32> {
    let n = clip.xy / clip.w;
    return vec2<f32>((n.x * 0.5 + 0.5) * globals.viewport.x, (0.5 - n.y * 0.5) * globals.viewport.y);
}

// The screen offset from `at`, the point a fragment's inputs were interpolated at, to sample k
// of the pixel `frag` lies in (k = 4: the pixel's centre).
fn sample_offset(frag: vec2<f32>, at: vec2<f32>, k: u32) -> vec2<f32> {
    var s = vec2<f32>(0.5);
    if (k < 4u) {
        s = sample_position(k);
    }
    return floor(frag) + s - at;
}

// The 4×4 ordered-dither threshold of a pixel, (index + 0.5)/16.
fn bayer4(p: vec2<f32>) -> f32 {
    let m = array<u32, 16>(0u, 8u, 2u, 10u, 12u, 4u, 14u, 6u, 3u, 11u, 1u, 9u, 15u, 7u, 13u, 5u);
    let x = u32(p.x) & 3u;
    let y = u32(p.y) & 3u;
    return (f32(m[y * 4u + x]) + 0.5) / 16.0;
}

// Wellons' lowbias32 integer hash (src/render/coverage.rs `lowbias32`).
fn lowbias32(v: u32) -> u32 {
    var x = v;
    x = x ^ (x >> 16u);
    x = x * 0x7feb352du;
    x = x ^ (x >> 15u);
    x = x * 0x846ca68bu;
    return x ^ (x >> 16u);
}

// The dither threshold of the fragment at `world`: the pixel's, shifted by k/16 (modulo 1) with
// k hashed from its 2 cm slab of distance to the eye, so far cards behind each other pass
// independent shares of the pixels (src/render/coverage.rs `layer_dither`).
fn layer_dither(p: vec2<f32>, world: vec3<f32>) -> f32 {
    let slab = u32(floor(max(distance(globals.eye.xyz, world), 0.0) * 50.0));
    let k = lowbias32(slab) >> 28u;
    let x = bayer4(p) + f32(k) / 16.0;
    return select(x, x - 1.0, x >= 1.0);
}
