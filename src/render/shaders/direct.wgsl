// The direct sun of the shading contract: L_direct = E_sun · visibility · f(wi, wo) · |cos θi|.
// f is the two-layer Schlick BRDF, a line-by-line port of `SchlickMaterial::eval`
// (src/material/schlick.rs; keep the two in step), evaluated in the normal-mapped tangent frame;
// visibility comes from the sun's cascaded shadow maps (group 2, src/render/shadow.rs) with 3x3 PCF.
// Prepended (after common.wgsl) to the terrain and mesh shaders.

// Layout mirrors `ShadowParams` in src/render/shadow.rs (352 bytes).
struct ShadowParams {
    // world to each cascade's light clip space
    light_view_proj: array<mat4x4<f32>, 4>,
    // per cascade: x one texel in uv, y normal offset (m), z depth bias (depth units), w texel (m)
    cascade: array<vec4<f32>, 4>,
    // the far view depth of each cascade (m)
    splits: vec4<f32>,
    // xyz: the camera's forward direction; w: cascade count (0: no map)
    view: vec4<f32>,
};

@group(2) @binding(0) var<uniform> shadow: ShadowParams;
@group(2) @binding(1) var shadow_map: texture_depth_2d_array;
@group(2) @binding(2) var shadow_sampler: sampler_comparison;

struct SchlickLayer {
    roughness: f32,
    isotropy: f32,
    diffuse: f32,
    glossy: f32,
    specular: f32,
    color: vec3<f32>,
};

struct Schlick {
    top: SchlickLayer,
    bottom: SchlickLayer,
    translucence: f32,
};

// The 96-byte `MaterialRecord` of src/material/section.rs as six vec4s: (r, p, a, b) and
// (c, C) of the top layer, the same of the bottom layer, (bump, τ, opacity, flags), emission.
fn schlick_from_record(v: array<vec4<f32>, 6>) -> Schlick {
    let top = SchlickLayer(v[0].x, v[0].y, v[0].z, v[0].w, v[1].x, v[1].yzw);
    let bottom = SchlickLayer(v[2].x, v[2].y, v[2].z, v[2].w, v[3].x, v[3].yzw);
    return Schlick(top, bottom, v[4].y);
}

// src/material/schlick.rs `toksvig_roughness`: r' = 2/(f·s + 2), s = 2/r − 2,
// f = |n̄| / (|n̄| + s(1 − |n̄|)).
fn toksvig_roughness(r_in: f32, length: f32) -> f32 {
    let r = clamp(r_in, 1e-4, 1.0);
    let n = clamp(length, 1e-3, 1.0);
    let s = 2.0 / r - 2.0;
    let f = n / (n + s * (1.0 - n));
    return 2.0 / (f * s + 2.0);
}

// G(v): Smith masking of the GGX distribution Z/π.
fn schlick_shadowing(l: SchlickLayer, v: f32) -> f32 {
    let r = max(l.roughness, 1e-4);
    return 2.0 * v / (v + sqrt(r + (1.0 - r) * v * v));
}

// S(u) = C + (1 - C)(1 - u)^5; a layer of reflectivity C = 0 is no interface: S = 0
// (SchlickLayer::fresnel in src/material/schlick.rs).
fn schlick_fresnel(l: SchlickLayer, u: f32) -> vec3<f32> {
    if (all(l.color == vec3<f32>(0.0))) {
        return vec3<f32>(0.0);
    }
    let m = 1.0 - clamp(u, 0.0, 1.0);
    let m2 = m * m;
    return l.color + (vec3<f32>(1.0) - l.color) * (m2 * m2 * m);
}

// G·G'·Z·A / (4π v v').
fn schlick_glossy_lobe(l: SchlickLayer, wi: vec3<f32>, wo: vec3<f32>, h: vec3<f32>) -> f32 {
    let v = wo.z;
    let vp = wi.z;
    let r = max(l.roughness, 1e-4);
    let t = h.z;
    let d = 1.0 + r * t * t - t * t;
    let z = r / (d * d);
    let p = clamp(l.isotropy, 1e-4, 1.0);
    let hxy = sqrt(h.x * h.x + h.y * h.y);
    var w = 1.0;
    if (hxy > 1e-7) {
        w = h.x / hxy;
    }
    let a = sqrt(p / (p * p - p * p * w * w + w * w));
    return schlick_shadowing(l, v) * schlick_shadowing(l, vp) * z * a / (4.0 * PI * v * vp);
}

// Lambertian part C·a/π (no Fresnel factor), glossy lobe × S(u).
fn schlick_reflectance(l: SchlickLayer, wi: vec3<f32>, wo: vec3<f32>, h: vec3<f32>, u: f32) -> vec3<f32> {
    let g = l.glossy * schlick_glossy_lobe(l, wi, wo, h);
    return l.color * (l.diffuse / PI) + schlick_fresnel(l, u) * g;
}

// `SchlickMaterial::eval`: light from wi, seen from wo, tangent frame, two-sided, translucent.
fn schlick_eval(m: Schlick, wi_in: vec3<f32>, wo_in: vec3<f32>, map: vec3<f32>) -> vec3<f32> {
    if (wi_in.z == 0.0 || wo_in.z == 0.0) {
        return vec3<f32>(0.0);
    }
    let bottom_color = m.bottom.color * map;
    if ((wi_in.z > 0.0) != (wo_in.z > 0.0)) {
        return m.translucence * bottom_color / PI;
    }
    let wi = vec3<f32>(wi_in.xy, abs(wi_in.z));
    let wo = vec3<f32>(wo_in.xy, abs(wo_in.z));
    let h = normalize(wi + wo);
    let u = clamp(dot(wo, h), 0.0, 1.0);
    let rt = schlick_reflectance(m.top, wi, wo, h, u);
    var b = m.bottom;
    b.color = bottom_color;
    let rb = schlick_reflectance(b, wi, wo, h, u);
    let through = (vec3<f32>(1.0) - schlick_fresnel(m.top, wi.z)) * (vec3<f32>(1.0) - schlick_fresnel(m.top, wo.z));
    return (1.0 - m.translucence) * (rt + through * rb);
}

// Any unit vector orthogonal to unit n (Frisvad), as src/render/scene.rs `any_tangent`.
fn any_tangent(n: vec3<f32>) -> vec3<f32> {
    if (n.z < -0.999999) {
        return vec3<f32>(0.0, -1.0, 0.0);
    }
    let a = 1.0 / (1.0 + n.z);
    let b = -n.x * n.y * a;
    return vec3<f32>(1.0 - n.x * n.x * a, b, -n.x);
}

// Orthonormal (t, b, n) around unit n with t as close to `t_in` as possible.
fn shading_frame(n: vec3<f32>, t_in: vec3<f32>) -> mat3x3<f32> {
    var t = t_in - n * dot(n, t_in);
    if (dot(t, t) < 1e-12) {
        t = any_tangent(n);
    }
    t = normalize(t);
    return mat3x3<f32>(t, cross(n, t), n);
}

// The cascade of a receiver: the first whose far split lies beyond its view depth (the last
// one takes the rest); no blending between cascades.
fn shadow_cascade(world: vec3<f32>) -> i32 {
    let d = dot(world - globals.eye.xyz, shadow.view.xyz);
    let n = i32(shadow.view.w);
    var i = 0;
    loop {
        if (i >= n - 1 || d <= shadow.splits[i]) {
            break;
        }
        i = i + 1;
    }
    return i;
}

// The fraction of the sun seen at `world` (1 without a shadow map). The point is pushed half a
// texel along the normal towards the sun's side, and the 3×3 PCF's texels (each tap a bilinear
// 2×2, so 4×4 texels with the taps' weights summed) are compared one by one against the
// receiver's own plane at each texel's centre (receiver-plane depth, Isidoro 2006), less a
// depth bias of one texel of the receiver's cascade. A single reference depth for the whole
// filter needed a slope-scaled bias of 2 tan θ texels (up to 17) to keep a plane tilted by θ
// from the light out of its own shadow, and that bias let every occluder that near through:
// a trunk's sides, steep to the sun, were lit under the leaves just above them (the generated
// over view's trunks 1.09 of the path tracer's direct term), while a lit leaf's filter still
// reached neighbouring leaves beside it (docs/VALIDATION.md).
fn sun_visibility(world: vec3<f32>, n: vec3<f32>) -> f32 {
    // `--soft-shadows`: the line-space visibility replaces the shadow map.
    if (globals.sun_direction.w > 0.5) {
        return soft_visibility_at(world);
    }
    if (shadow.view.w == 0.0) {
        return 1.0;
    }
    let k = shadow_cascade(world);
    let cp = shadow.cascade[k];
    let m = shadow.light_view_proj[k];
    let cos_s = dot(n, normalize(globals.sun_direction.xyz));
    let side = select(-1.0, 1.0, cos_s >= 0.0);
    let p = world + n * (side * cp.y);
    let c = m * vec4<f32>(p, 1.0);
    let size = f32(textureDimensions(shadow_map).x);
    // The lookup point in texel units (texel centres at whole numbers).
    let f = vec2<f32>(c.x * 0.5 + 0.5, 0.5 - c.y * 0.5) * size - 0.5;
    let g = receiver_plane_gradient(m, n, size, cp.z);
    let base = floor(f);
    let fr = f - base;
    let wx = array<f32, 4>(1.0 - fr.x, 1.0, 1.0, fr.x);
    let wy = array<f32, 4>(1.0 - fr.y, 1.0, 1.0, fr.y);
    // Each texel's own comparison: the bilinear comparison at its centre (weight 1 there;
    // `textureLoad` of a depth texture has no GLSL form), clamped to the map's edge.
    var sum = 0.0;
    for (var j = 0; j < 4; j = j + 1) {
        for (var i = 0; i < 4; i = i + 1) {
            let t = base + vec2<f32>(f32(i - 1), f32(j - 1));
            let reference = c.z + dot(g, t - f) - cp.z;
            let lit = textureSampleCompareLevel(shadow_map, shadow_sampler, (t + 0.5) / size, k, reference);
            sum = sum + wx[i] * wy[j] * lit;
        }
    }
    return sum / 9.0;
}

// The light depth's change per shadow-map texel (x right, y down) across the plane of unit
// normal `n` under the light view `m`, at most 8 depth-bias units (`bias`: one texel's depth)
// per texel: a plane nearly along the light.
fn receiver_plane_gradient(m: mat4x4<f32>, n: vec3<f32>, size: f32, bias: f32) -> vec2<f32> {
    let t1 = any_tangent(n);
    let t2 = cross(n, t1);
    let a1 = (m * vec4<f32>(t1, 0.0)).xyz;
    let a2 = (m * vec4<f32>(t2, 0.0)).xyz;
    // Along t1 and t2: texels moved (x, y) and depth.
    let u1 = vec2<f32>(a1.x, -a1.y) * (0.5 * size);
    let u2 = vec2<f32>(a2.x, -a2.y) * (0.5 * size);
    let det = u1.x * u2.y - u2.x * u1.y;
    let cap = 8.0 * bias;
    if (abs(det) < 1e-12) {
        return vec2<f32>(0.0);
    }
    let g = vec2<f32>(a1.z * u2.y - a2.z * u1.y, a2.z * u1.x - a1.z * u2.x) / det;
    let l = length(g);
    if (l > cap) {
        return g * (cap / l);
    }
    return g;
}

// The sun's unit direction and irradiance; zero irradiance when there is no sun.
fn sun_light() -> vec4<f32> {
    let s = globals.sun_direction.xyz;
    if (dot(s, s) < 1e-12) {
        return vec4<f32>(0.0, 0.0, 1.0, 0.0);
    }
    return vec4<f32>(normalize(s), 1.0);
}

// Lambert under the sun: albedo/π · E · max(n·s, 0) · visibility (n faces the viewer).
fn direct_lambert(albedo: vec3<f32>, n: vec3<f32>, world: vec3<f32>) -> vec3<f32> {
    let sun = sun_light();
    let c = max(dot(n, sun.xyz), 0.0) * sun.w;
    if (c <= 0.0) {
        return vec3<f32>(0.0);
    }
    return albedo / PI * globals.sun_irradiance.rgb * c * sun_visibility(world, n);
}

// Two-layer Schlick under the sun in the frame of shading normal `ns` and tangent `t`; `n` is
// the interpolated (unmapped) normal used for the shadow lookup.
fn direct_schlick(m: Schlick, map: vec3<f32>, ns: vec3<f32>, t: vec3<f32>, n: vec3<f32>, world: vec3<f32>) -> vec3<f32> {
    let sun = sun_light();
    if (sun.w == 0.0) {
        return vec3<f32>(0.0);
    }
    let f = shading_frame(ns, t);
    let wo = normalize(globals.eye.xyz - world);
    let wi_l = vec3<f32>(dot(sun.xyz, f[0]), dot(sun.xyz, f[1]), dot(sun.xyz, f[2]));
    let wo_l = vec3<f32>(dot(wo, f[0]), dot(wo, f[1]), dot(wo, f[2]));
    let fr = schlick_eval(m, wi_l, wo_l, map) * abs(wi_l.z);
    if (max(fr.r, max(fr.g, fr.b)) <= 0.0) {
        return vec3<f32>(0.0);
    }
    return globals.sun_irradiance.rgb * fr * sun_visibility(world, n);
}
