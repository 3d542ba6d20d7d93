// Instanced models: vertex arrays straight from the mesh section (positions, normals, uvs in
// three buffers, tangents from the `tangents:<model>` section in a fourth), or a `lod` level's
// vertices with the same attributes gathered, and one 32-byte InstanceRecord per instance
// (position, scale, rotation about +Z in degrees, the instance's index in `reserved`). Alpha test at 0.5
// on the colour map times the material's opacity; the direct sun in direct.wgsl.

struct MaterialParams {
    // linear RGB diffuse colour, alpha 1
    base_color: vec4<f32>,
    // x: the colour map's mip levels, y: its level-0 coverage (src/render/coverage.rs)
    alpha: vec4<f32>,
};

@group(1) @binding(0) var<uniform> material: MaterialParams;
@group(1) @binding(1) var color_map: texture_2d<f32>;
@group(1) @binding(2) var color_sampler: sampler;

struct DirectMaterial {
    // the material section's 96-byte MaterialRecord; record[5].w (its spare float): 1 for an
    // alpha-tested material (the region pass's leaves)
    record: array<vec4<f32>, 6>,
    // x: 1 = two-layer Schlick, 0 = Lambert; y: 1 = has a normal map; z: opacity
    mode: vec4<f32>,
};

@group(1) @binding(3) var<uniform> direct_material: DirectMaterial;
@group(1) @binding(4) var normal_map: texture_2d<f32>;
// The colour map's mean-colour height in [0, 1] (R16Float mips), parallax mapping's input; a
// 1×1 0.5 where the material has none.
@group(1) @binding(5) var height_map: texture_2d<f32>;

struct MeshIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) instance_position: vec3<f32>,
    @location(4) instance_scale: f32,
    @location(5) instance_rotation_deg: f32,
    @location(6) tangent: vec4<f32>,
    // The instance's index among its model's instances (the record's `reserved` field, set by
    // the renderer's buckets): its maps and light-map UVs are read with it.
    @location(7) instance_ref: u32,
    @builtin(vertex_index) vertex_index: u32,
};

struct MeshOut {
    @builtin(position) position: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) tangent: vec4<f32>,
    // The clip-space position again, interpolated as the inputs are (`screen_point`).
    @location(4) clip: vec4<f32>,
    // The ambient term's per-vertex values (shaders/ambient.wgsl).
    @location(8) ambient_front: vec3<f32>,
    @location(9) ambient_back: vec3<f32>,
    @location(10) light_map_uv: vec2<f32>,
    // The environment's radiance in the view's mirror direction about the vertex normal
    // (the top layer's gloss, src/render/ambient/gloss.rs).
    @location(11) ambient_mirror: vec3<f32>,
};

// The scene pass: placement plus the ambient term's per-vertex PRT (eq. 4.8's two sides).
@vertex
fn vs_main(v: MeshIn) -> MeshOut {
    var out = mesh_vertex(v);
    let amb = ambient_vertex(v.vertex_index, v.instance_ref);
    out.ambient_front = amb.front;
    out.ambient_back = amb.back;
    out.light_map_uv = amb.uv;
    let n = facing_normal(out.normal, out.world);
    let wo = normalize(globals.eye.xyz - out.world);
    out.ambient_mirror = ambient_env_radiance(v.instance_ref, 2.0 * dot(n, wo) * n - wo, v.instance_rotation_deg);
    return out;
}

// The shadow pass: placement only (no ambient work, no group 3).
@vertex
fn vs_shadow(v: MeshIn) -> MeshOut {
    return mesh_vertex(v);
}

fn mesh_vertex(v: MeshIn) -> MeshOut {
    let a = radians(v.instance_rotation_deg);
    let c = cos(a);
    let s = sin(a);
    let p = v.position * v.instance_scale;
    let world = vec3<f32>(c * p.x - s * p.y, s * p.x + c * p.y, p.z) + v.instance_position;
    var out: MeshOut;
    out.position = globals.view_proj * vec4<f32>(world, 1.0);
    out.clip = out.position;
    out.world = world;
    // A uniform scale keeps normals; only the rotation applies.
    out.normal = vec3<f32>(c * v.normal.x - s * v.normal.y, s * v.normal.x + c * v.normal.y, v.normal.z);
    out.uv = v.uv;
    out.tangent = vec4<f32>(c * v.tangent.x - s * v.tangent.y, s * v.tangent.x + c * v.tangent.y, v.tangent.z, v.tangent.w);
    return out;
}

// The sun on a model: two-layer Schlick in the normal-mapped tangent frame, or Lambert on the
// side facing the viewer for models without a material section.
// `ts` is the normal map's tangent-space normal, `len` its filtered length |n̄| (Toksvig).
fn mesh_direct(in: MeshOut, texel: vec3<f32>, ts: vec3<f32>, len: f32) -> vec3<f32> {
    if (direct_material.mode.x == 0.0) {
        let n = facing_normal(in.normal, in.world);
        return direct_lambert(texel * material.base_color.rgb, n, in.world);
    }
    // Degenerate inputs: a zero normal faces the viewer, a zero tangent is any orthogonal one.
    let n = facing_normal_or_self(in.normal, in.world);
    let tl = dot(in.tangent.xyz, in.tangent.xyz);
    let t = select(any_tangent(n), in.tangent.xyz * inverseSqrt(tl), tl > 1e-12);
    var ns = n;
    if (direct_material.mode.y != 0.0) {
        let b = cross(n, t) * select(1.0, -1.0, in.tangent.w < 0.0);
        ns = normalize(t * ts.x + b * ts.y + n * ts.z);
    }
    var m = schlick_from_record(direct_material.record);
    // Toksvig (globals.cam_up.w = 1, src/material/schlick.rs `with_toksvig`): the roughness of
    // both layers from the filtered normal's length at the sampled levels.
    if (direct_material.mode.y != 0.0 && globals.cam_up.w != 0.0) {
        m.top.roughness = toksvig_roughness(m.top.roughness, len);
        m.bottom.roughness = toksvig_roughness(m.bottom.roughness, len);
    }
    return direct_schlick(m, texel, ns, t, n, in.world);
}

// The unit normal; a zero one becomes the view direction (like `facing_normal`, not flipped).
fn facing_normal_or_self(n: vec3<f32>, world: vec3<f32>) -> vec3<f32> {
    if (dot(n, n) < 1e-12) {
        return normalize(globals.eye.xyz - world);
    }
    return normalize(n);
}

// The ambient term (shaders/ambient.wgsl) with albedo = base colour × colour map: the diffuse
// albedo the PRT bake folds into the transfer (src/render/ambient.rs); a material section's top
// layer reflects the environment and takes its Fresnel share of the light that reaches the bottom
// layer (src/render/ambient/gloss.rs, `ambient_layers` and `reflect_ambient`; record roughness,
// no Toksvig).
fn mesh_ambient(in: MeshOut, texel: vec3<f32>) -> vec3<f32> {
    let albedo = texel * material.base_color.rgb;
    let n = facing_normal(in.normal, in.world);
    let seen_front = dot(in.normal, globals.eye.xyz - in.world) >= 0.0;
    // A model without a material section is Lambertian: no top layer (colour 0 is no
    // interface), opaque (PRT takes its translucence below), as `AmbientLayers::LAMBERT`.
    var m = schlick_from_record(direct_material.record);
    if (direct_material.mode.x == 0.0) {
        let none = SchlickLayer(1.0, 1.0, 0.0, 0.0, 0.0, vec3<f32>(0.0));
        m = Schlick(none, none, 0.0);
    }
    let v = dot(n, normalize(globals.eye.xyz - in.world));
    var e_seen = vec3<f32>(0.0);
    var e_other = vec3<f32>(0.0);
    var l_r = in.ambient_mirror;
    if (ambient.mode.x == AMBIENT_PRT) {
        m.translucence = ambient.albedo_scale_t.w;
        var seen = in.ambient_front;
        var other = in.ambient_back;
        if (!seen_front) {
            seen = in.ambient_back;
            other = in.ambient_front;
        }
        e_seen = seen * ambient.albedo_scale_t.xyz;
        e_other = other * ambient.albedo_scale_t.xyz;
    } else if (ambient.mode.x == AMBIENT_LIGHT_MAP) {
        let e = light_map_bilinear(in.light_map_uv);
        let open = sky_irradiance(n);
        let lo = dot(open, vec3<f32>(0.2126, 0.7152, 0.0722));
        var k = 1.0;
        if (lo > 0.0) {
            k = clamp(dot(e, vec3<f32>(0.2126, 0.7152, 0.0722)) / lo, 0.0, 1.0);
        }
        e_seen = max(e, vec3<f32>(0.0)) / PI;
        e_other = e_seen;
        l_r = l_r * k;
    } else {
        e_seen = max(sky_irradiance(n), vec3<f32>(0.0)) / PI;
        e_other = e_seen;
    }
    return ambient_layered(m, v, albedo, e_seen, e_other, l_r) * ambient.scale.x;
}

// Far leaf cards (src/render/coverage.rs): the weight of the per-sample test at mip level
// lambda of a chain of `levels` levels, 0 up to the 4×4 level, 1 from the 2×2 level on.
fn far_weight(levels: f32, lambda: f32) -> f32 {
    if (levels < 3.0) {
        return 0.0;
    }
    let top = levels - 1.0;
    return clamp(min(lambda, top) - (top - 2.0), 0.0, 1.0);
}

// The far test of the card's point under sample k (k = 4: the pixel's centre): 1 where the
// colour map's level-0 alpha (bilinear) times the opacity reaches ½ there, the uv carried from
// the fragment's by the screen derivatives (src/render/coverage.rs, "each sample's own test").
fn far_sample(uv: vec2<f32>, dux: vec2<f32>, duy: vec2<f32>, frag: vec2<f32>, at: vec2<f32>, k: u32) -> f32 {
    let o = sample_offset(frag, at, k);
    let a = textureSampleLevel(color_map, color_sampler, uv + dux * o.x + duy * o.y, 0.0).a;
    return select(0.0, 1.0, a * direct_material.mode.z >= 0.5);
}

// Parallax mapping with offset limiting (Welch 2004; seed 000 §4.7.3), where
// globals.cam_right.w is 1 (`bake render --parallax`) and the material has a height map: the
// surface stands d = (2h − 1) · bump metres off the triangle, and the texture is read at the
// point the view ray crosses that height, offset-limited: o = d · (V − n (n·V)) in the tangent
// plane (no division by n·V), carried into uv through the screen derivatives (o as a
// combination of ∂p/∂x and ∂p/∂y, the same combination of ∂uv/∂x and ∂uv/∂y). The CPU
// reference does it with the triangle's uv gradients (src/render/reference.rs `parallax_uv`).
fn parallax_uv(in: MeshOut, dux: vec2<f32>, duy: vec2<f32>) -> vec2<f32> {
    let dpx = dpdx(in.world);
    let dpy = dpdy(in.world);
    let h = textureSampleGrad(height_map, color_sampler, in.uv, dux, duy).r;
    let d = (2.0 * h - 1.0) * direct_material.record[4].x;
    if (dot(in.normal, in.normal) < 1e-12) {
        return in.uv;
    }
    let n = normalize(in.normal);
    let v = normalize(globals.eye.xyz - in.world);
    let o = d * (v - n * dot(n, v));
    let a11 = dot(dpx, dpx);
    let a12 = dot(dpx, dpy);
    let a22 = dot(dpy, dpy);
    let det = a11 * a22 - a12 * a12;
    if (det <= 1e-30) {
        return in.uv;
    }
    let b1 = dot(o, dpx);
    let b2 = dot(o, dpy);
    let x = (a22 * b1 - a12 * b2) / det;
    let y = (a11 * b2 - a12 * b1) / det;
    return in.uv + x * dux + y * duy;
}

@fragment
fn fs_main(in: MeshOut) -> MaskedFragment {
    let f = shade(in);
    return MaskedFragment(f.color, f.mask);
}

// The entry point where the backend cannot write the sample mask (GL: naga writes
// `gl_SampleMask` as a scalar, gfx-rs/wgpu#6085; src/render/pipelines.rs `mask_by_sample`): run
// per sample (reading `sample_index` makes the shader run once per sample), each invocation
// keeping its own sample where the mask has it: the same samples as `fs_main`, at four times the
// shading.
@fragment
fn fs_main_per_sample(in: MeshOut, @builtin(sample_index) k: u32) -> @location(0) vec4<f32> {
    let f = shade(in);
    if (((f.mask >> k) & 1u) == 0u) {
        discard;
    }
    return f.color;
}

fn shade(in: MeshOut) -> Shaded {
    // Every texture read and derivative before the discard (uniform control flow: the parallax
    // switch is a uniform).
    var texel: vec4<f32>;
    var nm: vec4<f32>;
    let dux = dpdx(in.uv);
    let duy = dpdy(in.uv);
    var uv = in.uv;
    if (globals.cam_right.w != 0.0 && direct_material.mode.w != 0.0) {
        uv = parallax_uv(in, dux, duy);
        texel = textureSampleGrad(color_map, color_sampler, uv, dux, duy);
        nm = textureSampleGrad(normal_map, color_sampler, uv, dux, duy);
    } else {
        texel = textureSample(color_map, color_sampler, in.uv);
        nm = textureSample(normal_map, color_sampler, in.uv);
    }
    let ts = nm.xyz * 2.0 - 1.0;
    let a = texel.a * direct_material.mode.z;
    let dax = dpdx(a);
    let day = dpdy(a);
    let w = abs(dax) + abs(day);
    // The mip level's λ from the level-0 footprint, as the CPU reference's `mip_lambda`.
    let dims = vec2<f32>(textureDimensions(color_map, 0));
    let rho = max(length(dux * dims), length(duy * dims));
    let lambda = log2(max(rho, 1e-30));
    let t = far_weight(material.alpha.x, lambda);
    let d = layer_dither(in.position.xy, in.world);
    let at = screen_point(in.clip);
    var mask = 0xffffffffu;
    if (SAMPLE_MASK) {
        // The near ramp across the alpha edge; far away each sample's own alpha test at the
        // card's point under it; each of the four samples against its own threshold.
        var near = vec4<f32>(0.0);
        var far = vec4<f32>(0.0);
        for (var k = 0u; k < 4u; k++) {
            let o = sample_offset(in.position.xy, at, k);
            near[k] = clamp((a + dax * o.x + day * o.y - 0.5) / max(w, 1e-4) + 0.5, 0.0, 1.0);
        }
        if (t > 0.0) {
            for (var k = 0u; k < 4u; k++) {
                far[k] = far_sample(uv, dux, duy, in.position.xy, at, k);
            }
        }
        mask = sample_mask_of(mix(near, far, t), d);
        if (mask == 0u) {
            discard;
        }
    } else {
        let hard = select(0.0, 1.0, a >= 0.5);
        var far = hard;
        if (t > 0.0) {
            far = far_sample(uv, dux, duy, in.position.xy, at, 4u);
        }
        if (mix(hard, far, t) < d) {
            discard;
        }
    }
    if (region_pass()) {
        return Shaded(vec4<f32>(model_region(direct_material.record[5].w != 0.0), 1.0), mask);
    }
    // Emission (the record's last vec4, zero without a material section): emitted radiance on
    // both faces, drawn in full renders only (weight kd · ka), in neither term alone.
    let emission = direct_material.record[5].xyz * (globals.viewport.z * globals.viewport.w);
    let l = mesh_direct(in, texel.rgb, ts, nm.a) * globals.viewport.z
        + mesh_ambient(in, texel.rgb) * globals.viewport.w + emission;
    return Shaded(vec4<f32>(l, 1.0), mask);
}

// The shadow pass: depth only, with the alpha test at level 0 at the texel's centre (one sample
// per shadow-map texel, as the CPU reference's shadow rays and each far sample of the camera
// pass test theirs). At the mip level of the map's footprint a small far card's coarse alpha
// (its 2×2 level is ½ everywhere) passed over the whole card: crowns cast solid shadows, and the
// generated close view's leaves read 0.925 of the path tracer's direct term (docs/VALIDATION.md).
@fragment
fn fs_shadow(in: MeshOut) {
    let texel = textureSampleLevel(color_map, color_sampler, in.uv, 0.0);
    if (texel.a * direct_material.mode.z < 0.5) {
        discard;
    }
}
