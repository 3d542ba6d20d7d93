// The ambient term L_ambient (sky light and the sun's indirect light; never the direct sun), the
// GPU side of src/render/ambient.rs, which documents the formulas and evaluates the same ones for
// the CPU reference. Group 3 of the terrain and mesh passes (one layout for both; the terrain
// binds placeholders for what only meshes read):
//   0 AmbientParams (uniform), 1 light map (Rgba16Float, textureLoad + manual bilinear, the same
//   arithmetic as LightTexture::sample), 2 PRT per vertex (f32, full or packed layout),
//   3 per-instance maps C_H, C_S (96 f32 each, instance frame), 4 light-map UVs per vertex.

struct AmbientParams {
    // SH irradiance of the sun-free sky (world frame), rgb per coefficient
    sky_irradiance: array<vec4<f32>, 16>,
    // xyz: 1 / folded albedo of the material (PRT), w: translucence t
    albedo_scale_t: vec4<f32>,
    // x: mode (0 PRT, 1 light map, 2 sky irradiance), y: PRT layout (0 full, 1 packed),
    // z: vertices per instance of the light-map UVs (0: shared by all instances),
    // w: 1 when the terrain has a light map
    mode: vec4<u32>,
    // x: weight of the ambient term (0 or 1, `terms`)
    scale: vec4<f32>,
    // radiance SH of the sun-free sky (world frame), rgb per coefficient
    sky_radiance: array<vec4<f32>, 16>,
    // the top layer's glossy directional albedo (X, Y) over view cosine × roughness, two
    // entries per vec4 (src/render/ambient/gloss.rs `GlossLut`)
    gloss_lut: array<vec4<f32>, 256>,
};

@group(3) @binding(0) var<uniform> ambient: AmbientParams;
@group(3) @binding(1) var light_map: texture_2d<f32>;
@group(3) @binding(2) var<storage, read> prt: array<f32>;
@group(3) @binding(3) var<storage, read> instance_maps: array<f32>;
@group(3) @binding(4) var<storage, read> light_map_uvs: array<vec2<f32>>;

const AMBIENT_PRT: u32 = 0u;
const AMBIENT_LIGHT_MAP: u32 = 1u;

// sh_basis16: src/sh/basis.wgsl, prepended.

// Irradiance of the sun-free sky on a surface with unit normal n.
fn sky_irradiance(n: vec3<f32>) -> vec3<f32> {
    let y = sh_basis16(n);
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < 16u; i++) {
        e += ambient.sky_irradiance[i].rgb * y[i];
    }
    return e;
}

// The environment's radiance towards unit direction d: the instance's maps C_H + C_S (the
// first 48 floats of its 96, instance frame; d is turned by −rotation) for PRT, else the sky's
// SH (world frame). src/render/ambient/mod.rs `mesh_radiance`.
fn ambient_env_radiance(instance: u32, d: vec3<f32>, rotation_deg: f32) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    if (ambient.mode.x == AMBIENT_PRT) {
        let a = -radians(rotation_deg);
        let c = cos(a);
        let s = sin(a);
        let y = sh_basis16(vec3<f32>(c * d.x - s * d.y, s * d.x + c * d.y, d.z));
        let m = instance * 96u;
        for (var i = 0u; i < 16u; i++) {
            e += vec3<f32>(instance_maps[m + 3u * i], instance_maps[m + 3u * i + 1u], instance_maps[m + 3u * i + 2u]) * y[i];
        }
    } else {
        e = sky_radiance(d);
    }
    return e;
}

const GLOSS_LUT_V: u32 = 32u;
const GLOSS_LUT_R: u32 = 16u;

fn gloss_entry(i: u32) -> vec2<f32> {
    let q = ambient.gloss_lut[i / 2u];
    return select(q.xy, q.zw, (i & 1u) == 1u);
}

// (X, Y) at view cosine v and roughness r, bilinear in (v, r^(1/4)) (`GlossLut::lookup`).
fn gloss_lookup(v: f32, r: f32) -> vec2<f32> {
    let fv = clamp(v, 0.0, 1.0) * f32(GLOSS_LUT_V - 1u);
    let fr = sqrt(sqrt(clamp(r, 0.0, 1.0))) * f32(GLOSS_LUT_R - 1u);
    let iv = min(u32(fv), GLOSS_LUT_V - 2u);
    let ir = min(u32(fr), GLOSS_LUT_R - 2u);
    let av = fv - f32(iv);
    let ar = fr - f32(ir);
    let row0 = ir * GLOSS_LUT_V + iv;
    let row1 = row0 + GLOSS_LUT_V;
    let a = gloss_entry(row0) + (gloss_entry(row0 + 1u) - gloss_entry(row0)) * av;
    let b = gloss_entry(row1) + (gloss_entry(row1 + 1u) - gloss_entry(row1)) * av;
    return a + (b - a) * ar;
}

// A two-layer material's reflected ambient light on its seen side, at view cosine v
// (src/render/ambient/gloss.rs `ambient_layers` and `reflect_ambient`): e_seen and e_other are
// E/π of the two sides (albedo-free), l_r the environment's radiance in the view's mirror
// direction, albedo the bottom layer's colour (× colour map). Needs direct.wgsl (Schlick).
fn ambient_layered(m: Schlick, v_in: f32, albedo: vec3<f32>, e_seen: vec3<f32>, e_other: vec3<f32>, l_r: vec3<f32>) -> vec3<f32> {
    let top = m.top;
    let v = clamp(v_in, 0.0, 1.0);
    let has_top = any(top.color != vec3<f32>(0.0));
    var xy = vec2<f32>(0.0);
    var mean = vec3<f32>(0.0);
    if (has_top) {
        xy = gloss_lookup(v, top.roughness);
        mean = top.color + (vec3<f32>(1.0) - top.color) / 21.0;
    }
    let s_v = schlick_fresnel(top, v);
    let diffuse = (vec3<f32>(1.0) - s_v) * (vec3<f32>(1.0) - mean);
    let top_diffuse = top.color * top.diffuse;
    var gloss = vec3<f32>(0.0);
    if (has_top) {
        gloss = top.glossy * (top.color * xy.x + (vec3<f32>(1.0) - top.color) * xy.y) + top.specular * s_v;
    }
    let t = m.translucence;
    let d = (1.0 - t) * e_seen * (diffuse * albedo + top_diffuse) + t * e_other * albedo;
    return max(d, vec3<f32>(0.0)) + (1.0 - t) * gloss * max(l_r, vec3<f32>(0.0));
}

// The sky's radiance towards unit world direction d (its SH, world frame).
fn sky_radiance(d: vec3<f32>) -> vec3<f32> {
    let y = sh_basis16(d);
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < 16u; i++) {
        e += ambient.sky_radiance[i].rgb * y[i];
    }
    return e;
}

// Bilinear light-map lookup at (u, v), v = 0 at row 0, clamped to the edge.
fn light_map_bilinear(uv: vec2<f32>) -> vec3<f32> {
    let size = vec2<i32>(textureDimensions(light_map));
    let f = uv * vec2<f32>(size) - 0.5;
    let f0 = floor(f);
    let a = f - f0;
    let i0 = vec2<i32>(f0);
    let hi = size - vec2<i32>(1);
    let t00 = textureLoad(light_map, clamp(i0, vec2<i32>(0), hi), 0).rgb;
    let t10 = textureLoad(light_map, clamp(i0 + vec2<i32>(1, 0), vec2<i32>(0), hi), 0).rgb;
    let t01 = textureLoad(light_map, clamp(i0 + vec2<i32>(0, 1), vec2<i32>(0), hi), 0).rgb;
    let t11 = textureLoad(light_map, clamp(i0 + vec2<i32>(1, 1), vec2<i32>(0), hi), 0).rgb;
    let top = t00 + (t10 - t00) * a.x;
    let bottom = t01 + (t11 - t01) * a.x;
    return top + (bottom - top) * a.y;
}

// P·C over 16 RGB coefficients: transfer at prt[p + 3i + c], map at instance_maps[m + 3i + c].
fn prt_dot_full(p: u32, m: u32) -> vec3<f32> {
    var out = vec3<f32>(0.0);
    for (var i = 0u; i < 16u; i++) {
        let t = vec3<f32>(prt[p + 3u * i], prt[p + 3u * i + 1u], prt[p + 3u * i + 2u]);
        let c = vec3<f32>(
            instance_maps[m + 3u * i],
            instance_maps[m + 3u * i + 1u],
            instance_maps[m + 3u * i + 2u],
        );
        out += t * c;
    }
    return out;
}

// The packed side at prt[p..p + 20] against the map at instance_maps[m]: band 0 in RGB, bands
// 1–3 luminance with band 0's chromaticity (src/render/ambient.rs `decode_packed`).
fn prt_dot_packed(p: u32, m: u32) -> vec3<f32> {
    let b0 = vec3<f32>(prt[p], prt[p + 1u], prt[p + 2u]);
    let l0 = dot(b0, vec3<f32>(0.2126, 0.7152, 0.0722));
    var chroma = vec3<f32>(1.0);
    if (l0 > 0.0) {
        chroma = b0 / l0;
    }
    var out = b0 * vec3<f32>(instance_maps[m], instance_maps[m + 1u], instance_maps[m + 2u]);
    for (var i = 1u; i < 16u; i++) {
        let c = vec3<f32>(
            instance_maps[m + 3u * i],
            instance_maps[m + 3u * i + 1u],
            instance_maps[m + 3u * i + 2u],
        );
        out += chroma * prt[p + 3u + i] * c;
    }
    return out;
}

// Per vertex and side (0 front, 1 back): P_s0·C_H + P_s1·C_S (eq. 4.8 before the mix).
fn prt_side(vertex: u32, instance: u32, side: u32) -> vec3<f32> {
    let m = instance * 96u;
    if (ambient.mode.y == 0u) {
        let base = vertex * 192u + side * 96u;
        return prt_dot_full(base, m) + prt_dot_full(base + 48u, m + 48u);
    }
    let p = vertex * 40u + side * 20u;
    return prt_dot_packed(p, m) + prt[p + 3u] * prt_dot_packed(p, m + 48u);
}

// What the mesh vertex shader hands to the fragment: both sides' PRT radiance and the light-map UV.
struct AmbientVarying {
    front: vec3<f32>,
    back: vec3<f32>,
    uv: vec2<f32>,
};

fn ambient_vertex(vertex: u32, instance: u32) -> AmbientVarying {
    var out: AmbientVarying;
    out.front = vec3<f32>(0.0);
    out.back = vec3<f32>(0.0);
    out.uv = vec2<f32>(0.0);
    if (ambient.mode.x == AMBIENT_PRT) {
        out.front = prt_side(vertex, instance, 0u);
        out.back = prt_side(vertex, instance, 1u);
    } else if (ambient.mode.x == AMBIENT_LIGHT_MAP) {
        out.uv = light_map_uvs[instance * ambient.mode.z + vertex];
    }
    return out;
}

// L_ambient of the terrain at colour-map coordinates uv (row 0 north) with facing normal n.
fn ambient_terrain(uv: vec2<f32>, albedo: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    var e = vec3<f32>(0.0);
    if (ambient.mode.w == 1u) {
        e = light_map_bilinear(uv);
    } else {
        e = sky_irradiance(n);
    }
    return albedo * max(e, vec3<f32>(0.0)) / PI * ambient.scale.x;
}
