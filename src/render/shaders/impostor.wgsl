// Impostors (src/render/impostor.rs): one quad per instance (6 vertices, no vertex arrays; the
// InstanceRecord in slot 0): the image plane of the hemi-octahedral view of the model's atlas
// nearest the eye, turned to face the eye, textured with that view (src/lod/octa.rs; `nearest_tile` in impostor.rs is the CPU twin of `tile_of`
// below: keep the two in step) through its depth atlas: the texel the eye's ray meets there
// (parallax, `march`). Alpha test at 0.5 like mesh.wgsl, the atlas normal rotated to the
// world lit by the sun (Lambert on the atlas albedo) with the shadow-map lookup of direct.wgsl at
// the surface point the depth atlas gives, and the ambient of the instance's environment maps
// (group 3: the model's first ambient group; the sky's where the model has no PRT).

struct ImpostorParams {
    // xyz: centre of every view (model units), w: radius
    centre_radius: vec4<f32>,
    // x: grid N, y: texels per tile side, z: atlas side N·tile, w: 1 where the model has
    // alpha-tested materials (the region pass's leaves where a texel names no material)
    grid_tile: vec4<u32>,
};

@group(1) @binding(0) var<uniform> impostor: ImpostorParams;
@group(1) @binding(1) var atlas_color: texture_2d<f32>;
@group(1) @binding(2) var atlas_normal: texture_2d<f32>;
@group(1) @binding(3) var atlas_depth: texture_2d<f32>;

// The model's materials as mesh.wgsl's DirectMaterial (record, mode: x 1 = Schlick), the first
// 16; the atlas normal's alpha names a texel's (src/lod/impostor.rs).
struct ImpostorMaterial {
    record: array<vec4<f32>, 6>,
    mode: vec4<f32>,
};

struct ImpostorMaterials {
    // x: how many of `m` are set
    count: vec4<u32>,
    m: array<ImpostorMaterial, 16>,
};

@group(1) @binding(4) var<uniform> impostor_materials: ImpostorMaterials;

struct ImpostorIn {
    @location(3) instance_position: vec3<f32>,
    @location(4) instance_scale: f32,
    @location(5) instance_rotation_deg: f32,
    @location(7) instance_ref: u32,
    @builtin(vertex_index) vertex_index: u32,
};

struct ImpostorOut {
    @builtin(position) position: vec4<f32>,
    @location(0) world: vec3<f32>,
    // the quad's (s, t) in [-1, 1]², s along `right`, t along `up`
    @location(1) st: vec2<f32>,
    @location(2) @interpolate(flat) tile: vec2<u32>,
    // the instance's rotation (cos, sin), the tile's direction in the world (its depths are
    // measured along it) and the radius
    @location(3) @interpolate(flat) rot: vec2<f32>,
    @location(4) @interpolate(flat) view_dir: vec3<f32>,
    @location(5) @interpolate(flat) radius: f32,
    // the instance's index among its model's (its ambient maps) and rotation in degrees
    // The environment's radiance SH, bands 0–2 (RGB of coefficient i at component i·3 + c of
    // env0..env6): the instance's maps C_H + C_S (model frame, env6.w = 1) where the model has
    // PRT, else the sky's (world frame, env6.w = 0). The vertex stage reads them, as the mesh
    // path reads the maps per vertex (storage buffers are vertex-only on downlevel devices).
    @location(6) @interpolate(flat) env0: vec4<f32>,
    @location(7) @interpolate(flat) env1: vec4<f32>,
    @location(8) @interpolate(flat) env2: vec4<f32>,
    @location(9) @interpolate(flat) env3: vec4<f32>,
    @location(10) @interpolate(flat) env4: vec4<f32>,
    @location(11) @interpolate(flat) env5: vec4<f32>,
    @location(12) @interpolate(flat) env6: vec4<f32>,
    // the impostor's centre in the world (its depths are measured from it)
    @location(13) @interpolate(flat) centre: vec3<f32>,
    // The clip-space position again, interpolated as the inputs are (`screen_point`).
    @location(14) clip: vec4<f32>,
};

// The tile of unit direction w (z < 0 clamped to the horizon), as octa.rs `tile_of`.
fn octa_cell(w: vec3<f32>, n: u32) -> vec2<u32> {
    let v = vec3<f32>(w.x, w.y, max(w.z, 0.0));
    let l1 = abs(v.x) + abs(v.y) + v.z;
    var uv = vec2<f32>(0.5, 0.5);
    if (l1 > 0.0) {
        let a = v.x / l1;
        let b = v.y / l1;
        uv = vec2<f32>(0.5 * (a + b + 1.0), 0.5 * (a - b + 1.0));
    }
    let c = clamp(floor(uv * f32(n)), vec2<f32>(0.0), vec2<f32>(f32(n - 1u)));
    return vec2<u32>(c);
}

// octa.rs `tile_direction`.
fn octa_tile_direction(i: u32, j: u32, n: u32) -> vec3<f32> {
    let x = 2.0 * (f32(i) + 0.5) / f32(n) - 1.0;
    let y = 2.0 * (f32(j) + 0.5) / f32(n) - 1.0;
    let a = 0.5 * (x + y);
    let b = 0.5 * (x - y);
    return normalize(vec3<f32>(a, b, 1.0 - abs(a) - abs(b)));
}

// The tile whose centre direction is nearest to w: the best of the cell holding w and its eight
// neighbours (impostor.rs `nearest_tile`).
fn nearest_tile(w_in: vec3<f32>, n: u32) -> vec2<u32> {
    var w = vec3<f32>(w_in.xy, max(w_in.z, 0.0));
    if (dot(w, w) < 1e-24) {
        w = vec3<f32>(0.0, 0.0, 1.0);
    }
    w = normalize(w);
    let c = vec2<i32>(octa_cell(w, n));
    var best = vec2<u32>(c);
    var best_dot = -2.0;
    for (var dj = -1; dj <= 1; dj = dj + 1) {
        for (var di = -1; di <= 1; di = di + 1) {
            let i = c.x + di;
            let j = c.y + dj;
            if (i < 0 || j < 0 || i >= i32(n) || j >= i32(n)) {
                continue;
            }
            let d = dot(octa_tile_direction(u32(i), u32(j), n), w);
            if (d > best_dot) {
                best_dot = d;
                best = vec2<u32>(u32(i), u32(j));
            }
        }
    }
    return best;
}

// octa.rs `view_axes` (right, up) for the direction towards the eye w.
fn view_right(w: vec3<f32>) -> vec3<f32> {
    let c = cross(vec3<f32>(0.0, 0.0, 1.0), w);
    if (length(c) > 1e-6) {
        return normalize(c);
    }
    return vec3<f32>(1.0, 0.0, 0.0);
}

// A world direction in the model frame (undo the rotation (cos, sin) about +Z).
fn model_dir(w: vec3<f32>, rot: vec2<f32>) -> vec3<f32> {
    return vec3<f32>(rot.x * w.x + rot.y * w.y, -rot.y * w.x + rot.x * w.y, w.z);
}

// sin of the angle between world direction w and the centre direction of `tile`.
fn impostor_tile_error(tile: vec2<u32>, w: vec3<f32>, rot: vec2<f32>) -> f32 {
    let c = octa_tile_direction(tile.x, tile.y, impostor.grid_tile.x);
    let d = normalize(model_dir(w, rot));
    let k = clamp(dot(c, d), -1.0, 1.0);
    return sqrt(max(1.0 - k * k, 0.0));
}

// The instance's impostor centre in the world.
fn impostor_centre(v: ImpostorIn) -> vec3<f32> {
    let a = radians(v.instance_rotation_deg);
    let q = impostor.centre_radius.xyz * v.instance_scale;
    return vec3<f32>(cos(a) * q.x - sin(a) * q.y, sin(a) * q.x + cos(a) * q.y, q.z) + v.instance_position;
}

// The camera pass: the quad faces the eye.
@vertex
fn vs_main(v: ImpostorIn) -> ImpostorOut {
    var to_eye = globals.eye.xyz - impostor_centre(v);
    if (dot(to_eye, to_eye) < 1e-20) {
        to_eye = vec3<f32>(0.0, 0.0, 1.0);
    }
    var out = impostor_vertex(v, normalize(to_eye));
    var c: array<f32, 28>;
    c[27] = 0.0;
    if (ambient.mode.x == AMBIENT_PRT) {
        let m = v.instance_ref * 96u;
        for (var i = 0u; i < 27u; i++) {
            c[i] = instance_maps[m + i];
        }
        c[27] = 1.0;
    } else {
        for (var i = 0u; i < 9u; i++) {
            c[3u * i] = ambient.sky_radiance[i].r;
            c[3u * i + 1u] = ambient.sky_radiance[i].g;
            c[3u * i + 2u] = ambient.sky_radiance[i].b;
        }
    }
    out.env0 = vec4<f32>(c[0], c[1], c[2], c[3]);
    out.env1 = vec4<f32>(c[4], c[5], c[6], c[7]);
    out.env2 = vec4<f32>(c[8], c[9], c[10], c[11]);
    out.env3 = vec4<f32>(c[12], c[13], c[14], c[15]);
    out.env4 = vec4<f32>(c[16], c[17], c[18], c[19]);
    out.env5 = vec4<f32>(c[20], c[21], c[22], c[23]);
    out.env6 = vec4<f32>(c[24], c[25], c[26], c[27]);
    return out;
}

// The environment's radiance (weights 1) or irradiance (the cosine lobe's A_l = π, 2π/3, π/4)
// towards unit world direction d, from the fragment's band-0–2 SH.
fn impostor_env(in: ImpostorOut, d_world: vec3<f32>, irradiance: bool) -> vec3<f32> {
    var d = d_world;
    if (in.env6.w != 0.0) {
        d = model_dir(d_world, in.rot);
    }
    let y = sh_basis16(d);
    let f = array<vec4<f32>, 7>(in.env0, in.env1, in.env2, in.env3, in.env4, in.env5, in.env6);
    var e = vec3<f32>(0.0);
    for (var i = 0u; i < 9u; i++) {
        var k = 1.0;
        if (irradiance) {
            k = PI / 4.0;
            if (i == 0u) {
                k = PI;
            } else if (i < 4u) {
                k = 2.0 * PI / 3.0;
            }
        }
        var rgb: vec3<f32>;
        for (var ch = 0u; ch < 3u; ch++) {
            let j = 3u * i + ch;
            rgb[ch] = f[j / 4u][j % 4u];
        }
        e += rgb * (k * y[i]);
    }
    // The sky's band 3 (its radiance only: the cosine lobe has none) from the uniform; the
    // instance maps' band 3 is not passed (docs/MATERIALS.md).
    if (!irradiance && in.env6.w == 0.0) {
        for (var i = 9u; i < 16u; i++) {
            e += ambient.sky_radiance[i].rgb * y[i];
        }
    }
    return e;
}

// The shadow pass (globals.view_proj is the sun's view): the quad faces the sun and shows the
// view nearest the sun's direction.
@vertex
fn vs_shadow(v: ImpostorIn) -> ImpostorOut {
    return impostor_vertex(v, sun_light().xyz);
}

// The quad of an instance seen from unit world direction w_world (towards the viewer).
fn impostor_vertex(v: ImpostorIn, w_world: vec3<f32>) -> ImpostorOut {
    let a = radians(v.instance_rotation_deg);
    let c = cos(a);
    let s = sin(a);
    let centre = impostor_centre(v);
    let radius = impostor.centre_radius.w * abs(v.instance_scale);
    // Into the model frame: undo the rotation about +Z.
    let w_model = vec3<f32>(c * w_world.x + s * w_world.y, -s * w_world.x + c * w_world.y, w_world.z);
    let tile = nearest_tile(w_model, impostor.grid_tile.x);
    // The quad is the tile's own image plane: perpendicular to the tile's centre direction, with
    // the axes its texels were cast along (lod/impostor.rs `texel_ray`), turned into the world.
    // (Facing the eye with axes from the eye's direction turned the image by the azimuth between
    // the two directions, up to tens of degrees near the zenith, and moved its parts: the
    // fixture's far benches were drawn rotated and a metre off, docs/VALIDATION.md.)
    let w_tile = octa_tile_direction(tile.x, tile.y, impostor.grid_tile.x);
    let right_m = view_right(w_tile);
    let up_m = cross(w_tile, right_m);
    let w_t = vec3<f32>(c * w_tile.x - s * w_tile.y, s * w_tile.x + c * w_tile.y, w_tile.z);
    let right = vec3<f32>(c * right_m.x - s * right_m.y, s * right_m.x + c * right_m.y, right_m.z);
    let up = vec3<f32>(c * up_m.x - s * up_m.y, s * up_m.x + c * up_m.y, up_m.z);
    // Two triangles: corners (-1,-1) (1,-1) (1,1), (-1,-1) (1,1) (-1,1).
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0),
    );
    let st = corners[v.vertex_index % 6u];
    // `world`: the point of the tile's image plane at (s, t), where the atlas' texel rays start
    // (the fragment's surface point is it moved by the depth along the tile's direction).
    let world = centre + (right * st.x + up * st.y) * radius;
    // Drawn facing the viewer: the tile's plane turned by the smallest rotation that takes the
    // tile's direction w_t to w_world (about w_t × w_world, no twist about the view axis), so
    // the picture keeps its size and orientation. Drawn in the tile's plane itself, it was
    // foreshortened by cos e (e the angle between the two, up to about 15° between tiles): a
    // round model's silhouette lost that share of its pixels to the ground behind it (spec0's
    // far houses: 768 of the meshes' 783 pixels at 160×90, docs/VALIDATION.md).
    let drawn = centre + turn_towards(w_t, w_world, world - centre);
    var out: ImpostorOut;
    out.position = globals.view_proj * vec4<f32>(drawn, 1.0);
    out.clip = out.position;
    out.world = world;
    out.st = st;
    out.tile = tile;
    out.rot = vec2<f32>(c, s);
    out.view_dir = w_t;
    out.radius = radius;
    out.centre = centre;
    return out;
}

// x turned by the smallest rotation that takes unit vector a to unit vector b (Rodrigues, about
// a × b); x itself where the two are (nearly) opposite.
fn turn_towards(a: vec3<f32>, b: vec3<f32>, x: vec3<f32>) -> vec3<f32> {
    let k = cross(a, b);
    let c = dot(a, b);
    if (c <= -0.999) {
        return x;
    }
    return x * c + cross(k, x) + k * (dot(k, x) / (1.0 + c));
}

// The atlas texel of the quad's point `st` in the fragment's tile: texel (c, r) of the tile, as
// lod/impostor.rs `texel_ray` (s = 2(c + ½)/tile − 1, t = 1 − 2(r + ½)/tile), nearest.
fn atlas_texel_at(in: ImpostorOut, st: vec2<f32>) -> vec2<i32> {
    let tile = impostor.grid_tile.y;
    let fc = clamp(floor((st.x * 0.5 + 0.5) * f32(tile)), 0.0, f32(tile - 1u));
    let fr = clamp(floor((0.5 - st.y * 0.5) * f32(tile)), 0.0, f32(tile - 1u));
    return vec2<i32>(in.tile * tile + vec2<u32>(u32(fc), u32(fr)));
}

// The atlas level of the fragment's footprint (src/render/coverage.rs, impostors): log₂ of its
// larger side in level-0 texels, rounded, within the chains (src/render/impostor.rs
// `atlas_chains`: a level-L texel is the 2^L-wide block below it, its alpha the block's
// coverage). `dx`, `dy`: the derivatives of `st`.
fn atlas_level(dx: vec2<f32>, dy: vec2<f32>) -> i32 {
    let rho = max(length(dx), length(dy)) * 0.5 * f32(impostor.grid_tile.y);
    let top = f32(textureNumLevels(atlas_color) - 1u);
    return i32(clamp(round(log2(max(rho, 1e-8))), 0.0, top));
}

// The depth atlas' offset δ = (centre − x)·w of texel `px` of level `level`.
fn atlas_delta_at(in: ImpostorOut, px: vec2<i32>, level: i32) -> f32 {
    return (textureLoad(atlas_depth, px, level).r * 2.0 - 1.0) * in.radius;
}

// The shadow pass: the sun tile's picture (no parallax: each texel at its own point of the
// tile's frame, so the map's surface lies within r·sin e_sun of the model's along the sun, the
// tolerance of the camera pass's lookup), alpha-tested at level 0, the depth of the surface
// point the depth atlas gives. Marching the sun's ray through the sun tile's depth atlas as the
// camera pass marches the eye's was measured and not kept (docs/VALIDATION.md, twelfth session).
@fragment
fn fs_shadow(in: ImpostorOut) -> @builtin(frag_depth) f32 {
    let px = atlas_texel_at(in, in.st);
    if (textureLoad(atlas_color, px, 0).a < 0.5) {
        discard;
    }
    let p = globals.view_proj * vec4<f32>(in.world - in.view_dir * atlas_delta_at(in, px, 0), 1.0);
    return clamp(p.z / p.w, 0.0, 1.0);
}

// The viewer's ray through a fragment in the frame of the fragment's tile: at the depth offset
// δ = (centre − x)·w of the depth atlas it crosses the tile's image plane's coordinates
// st0 + k·δ, and it lies in the tile's box (|s|, |t| ≤ 1, |δ| ≤ radius) for δ in [lo, hi]
// (none where lo > hi).
struct TileRay {
    st0: vec2<f32>,
    k: vec2<f32>,
    lo: f32,
    hi: f32,
};

// The eye's ray through the drawn quad's point of tile coordinates `st`, the quad turned towards
// unit direction `toward` (`impostor_vertex`).
fn tile_ray(in: ImpostorOut, st: vec2<f32>, toward: vec3<f32>) -> TileRay {
    let axes = tile_axes(in.tile, in.rot);
    let right = axes[0];
    let up = axes[1];
    let w = axes[2];
    // The drawn point relative to the centre: the tile plane's point turned to face `toward`.
    let q = turn_towards(w, toward, (right * st.x + up * st.y) * in.radius);
    var d = -toward;
    let e = in.centre + q - globals.eye.xyz;
    if (dot(e, e) > 1e-20) {
        d = normalize(e);
    }
    // Depth grows along the ray at g = −d·w per unit length (the eye's tile is within about
    // 15° of the eye's direction; below the horizon the clamped tile may lie farther off).
    let g = max(-dot(d, w), 1e-3);
    let k = vec2<f32>(dot(d, right), dot(d, up)) / (in.radius * g);
    let st0 = vec2<f32>(dot(q, right), dot(q, up)) / in.radius + k * dot(q, w);
    var lo = -in.radius;
    var hi = in.radius;
    for (var c = 0; c < 2; c++) {
        if (abs(k[c]) > 1e-12) {
            let a = (-1.0 - st0[c]) / k[c];
            let b = (1.0 - st0[c]) / k[c];
            lo = max(lo, min(a, b));
            hi = min(hi, max(a, b));
        } else if (abs(st0[c]) > 1.0) {
            hi = lo - 1.0;
        }
    }
    return TileRay(st0, k, lo, hi);
}

// The surface offset δ of the tile's texel under `st` at atlas level `level` (the block's
// nearest, `atlas_chains`), or 3·radius where the texel holds no surface (depth code 255, the
// empty texels' code at every level).
fn atlas_height(in: ImpostorOut, st: vec2<f32>, level: i32) -> f32 {
    let px = atlas_texel_at(in, st) >> vec2<u32>(u32(level));
    let code = textureLoad(atlas_depth, px, level).r;
    if (code > 254.5 / 255.0) {
        return 3.0 * in.radius;
    }
    return (code * 2.0 - 1.0) * in.radius;
}

// Where a ray meets the tile's depth atlas: its tile coordinates, its depth offset δ and
// whether it met a surface.
struct TileHit {
    st: vec2<f32>,
    delta: f32,
    hit: bool,
};

// Whether a ray point at depth offset `t` lies in the texel column of surface offset `h`: at or
// behind the surface, and no deeper than `shell` behind it.
fn in_column(t: f32, h: f32, shell: f32) -> bool {
    return t >= h && t <= h + shell;
}

// How deep behind its surface a texel's column reaches, in texels of the ray's sideways travel
// (`march`): a model with alpha-tested materials (a crown: the atlas knows its nearest leaves,
// not what lies behind them) and a solid one.
const LEAF_SHELL: f32 = 1.0;
const SOLID_SHELL: f32 = 4.0;

// Parallax through the tile's depth atlas at level `level`: the first point of the ray in a
// texel's column, the texel's surface and what lies behind it, `shell_texels` of the ray's
// sideways travel deep (at least two depth codes). Columns through the whole box closed the
// holes between a crown's leaves for every ray that passed behind one and drew a bench's slats
// and legs as long as the box is deep (docs/VALIDATION.md, twelfth session). Steps of at most half
// a texel of that level along the ray's way across the tile (at most 64), then 6 halvings of the
// step that met a column; the point is the ray's at the texel's own depth where that lies in the
// last step (else the step's end: the ray met the column's side). Seen along the tile's own
// direction (k = 0) it is the texel under `st` at its depth: the tile's picture, as drawn before
// parallax.
fn march(in: ImpostorOut, ray: TileRay, level: i32, shell_texels: f32) -> TileHit {
    var out = TileHit(ray.st0, 0.0, false);
    if (ray.lo > ray.hi) {
        return out;
    }
    let texels = f32(impostor.grid_tile.y >> u32(level));
    let travel = length(ray.k) * (ray.hi - ray.lo) * 0.5 * texels;
    let shell = max(shell_texels * 2.0 / (texels * max(length(ray.k), 1e-12)), 4.0 * in.radius / 255.0);
    let n = u32(clamp(ceil(2.0 * travel), 1.0, 64.0));
    var a = ray.lo;
    var b = ray.lo;
    var found = false;
    for (var i = 0u; i <= n; i++) {
        let t = mix(ray.lo, ray.hi, f32(i) / f32(n));
        if (in_column(t, atlas_height(in, ray.st0 + ray.k * t, level), shell)) {
            b = t;
            found = true;
            break;
        }
        a = t;
    }
    if (!found) {
        return out;
    }
    if (b > a) {
        for (var j = 0; j < 6; j++) {
            let m = 0.5 * (a + b);
            if (in_column(m, atlas_height(in, ray.st0 + ray.k * m, level), shell)) {
                b = m;
            } else {
                a = m;
            }
        }
    }
    out.st = ray.st0 + ray.k * b;
    out.delta = clamp(atlas_height(in, out.st, level), a, b);
    out.hit = true;
    return out;
}

// The world point of a hit: the tile plane's point at its (s, t) moved by −δ along the tile's
// direction.
fn hit_surface(in: ImpostorOut, hit: TileHit) -> vec3<f32> {
    let axes = tile_axes(in.tile, in.rot);
    return in.centre + (axes[0] * hit.st.x + axes[1] * hit.st.y) * in.radius - axes[2] * hit.delta;
}

// The unit direction from the impostor's centre towards the eye (`vs_main`'s).
fn towards_eye(in: ImpostorOut) -> vec3<f32> {
    let e = globals.eye.xyz - in.centre;
    if (dot(e, e) < 1e-20) {
        return vec3<f32>(0.0, 0.0, 1.0);
    }
    return normalize(e);
}

// The image axes (right, up) and the direction w of tile `tile` in the world, for an instance
// turned by `rot` (cos, sin) about +Z, as `impostor_vertex` places the tile's quad.
fn tile_axes(tile: vec2<u32>, rot: vec2<f32>) -> mat3x3<f32> {
    let w_m = octa_tile_direction(tile.x, tile.y, impostor.grid_tile.x);
    let right_m = view_right(w_m);
    let up_m = cross(w_m, right_m);
    let c = rot.x;
    let s = rot.y;
    return mat3x3<f32>(
        vec3<f32>(c * right_m.x - s * right_m.y, s * right_m.x + c * right_m.y, right_m.z),
        vec3<f32>(c * up_m.x - s * up_m.y, s * up_m.x + c * up_m.y, up_m.z),
        vec3<f32>(c * w_m.x - s * w_m.y, s * w_m.x + c * w_m.y, w_m.z),
    );
}

// Whether the model itself lets the sun reach `surface` (world), from the atlas' view nearest
// the sun: the surface point projected into that tile's image, and its depth along the tile's
// direction against the first surface the tile saw there, with the tolerance `tol` (metres) of
// the two tiles' angular error. The shadow map's lookup moves past the impostor's own shadow
// (by the same tolerance), which loses the crown's shadow on its trunk and inner leaves; this
// puts it back.
fn impostor_self_visibility(in: ImpostorOut, surface: vec3<f32>, sun_tile: vec2<u32>, tol: f32) -> f32 {
    let axes = tile_axes(sun_tile, in.rot);
    let right = axes[0];
    let up = axes[1];
    let w = axes[2];
    let q = surface - in.centre;
    let st = vec2<f32>(dot(q, right), dot(q, up)) / in.radius;
    if (abs(st.x) >= 1.0 || abs(st.y) >= 1.0) {
        return 1.0;
    }
    let tile = impostor.grid_tile.y;
    let fc = clamp(floor((st.x * 0.5 + 0.5) * f32(tile)), 0.0, f32(tile - 1u));
    let fr = clamp(floor((0.5 - st.y * 0.5) * f32(tile)), 0.0, f32(tile - 1u));
    let px = vec2<i32>(sun_tile * tile + vec2<u32>(u32(fc), u32(fr)));
    if (textureLoad(atlas_color, px, 0).a < 0.5) {
        return 1.0;
    }
    let first = (textureLoad(atlas_depth, px, 0).r * 2.0 - 1.0) * in.radius;
    let mine = dot(-q, w);
    return select(1.0, 0.0, mine > first + tol);
}

// The atlas' own shadow over the block of level `level` at `px` (`surface`: the block's nearest
// surface point): the mean of `impostor_self_visibility` over up to 4×4 of its level-0 texels
// that hold a surface (evenly spaced), each at its own surface point from its level-0 depth.
// The block's nearest surface alone is the crown's outermost leaf, lit more often than the
// leaves it stands for: the generated over view's leaves read 1.07 of the path tracer's direct
// term that way (docs/VALIDATION.md), 1.01 with the mean.
fn block_self_visibility(in: ImpostorOut, px: vec2<i32>, level: i32, surface: vec3<f32>, sun_tile: vec2<u32>, step: f32) -> f32 {
    if (level <= 0) {
        return impostor_self_visibility(in, surface, sun_tile, step);
    }
    let axes = tile_axes(in.tile, in.rot);
    let right = axes[0];
    let up = axes[1];
    let tile = f32(impostor.grid_tile.y);
    let side = 1u << u32(level);
    let n = min(side, 4u);
    let stride = side / n;
    let base = vec2<u32>(px) << vec2<u32>(u32(level));
    let origin = in.tile * impostor.grid_tile.y;
    var sum = 0.0;
    var count = 0.0;
    for (var j = 0u; j < n; j++) {
        for (var i = 0u; i < n; i++) {
            let t = base + vec2<u32>(i * stride + stride / 2u, j * stride + stride / 2u);
            if (textureLoad(atlas_color, vec2<i32>(t), 0).a < 0.5) {
                continue;
            }
            let l = vec2<f32>(t - origin) + 0.5;
            let st = vec2<f32>(2.0 * l.x / tile - 1.0, 1.0 - 2.0 * l.y / tile);
            let q = in.centre + (right * st.x + up * st.y) * in.radius;
            let p = q - in.view_dir * atlas_delta_at(in, vec2<i32>(t), 0);
            sum += impostor_self_visibility(in, p, sun_tile, step);
            count += 1.0;
        }
    }
    if (count == 0.0) {
        return impostor_self_visibility(in, surface, sun_tile, step);
    }
    return sum / count;
}

// The irradiance of a block of the atlas whose mean normal is `n` times `spread` (its length,
// 1 for a texel of level 0): the mean of E over the block's normals, E being linear in the
// normal but for band 2, is E's even part plus `spread` times its odd part along n (the mean
// normal renormalized would light a block whose normals spread as if they all faced n).
fn block_irradiance(in: ImpostorOut, n: vec3<f32>, spread: f32) -> vec3<f32> {
    let e = impostor_env(in, n, true);
    let back = impostor_env(in, -n, true);
    return mix(0.5 * (e + back), e, spread);
}

// The camera pass' fragment: colour, the samples kept, and the depth of the surface point the
// depth atlas gives (not the quad's plane through the centre: a house's front and base lie
// in front of it, and there the quad's point is below the ground beside the house, which hid
// the impostor's lower edge: docs/VALIDATION.md).
struct ImpostorFragment {
    @location(0) color: vec4<f32>,
    @builtin(sample_mask) mask: u32,
    @builtin(frag_depth) depth: f32,
};

struct ImpostorFragmentPerSample {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

// A shaded impostor fragment and its depth.
struct ImpostorShaded {
    color: vec4<f32>,
    mask: u32,
    depth: f32,
};

@fragment
fn fs_main(in: ImpostorOut) -> ImpostorFragment {
    let f = shade(in);
    return ImpostorFragment(f.color, f.mask, f.depth);
}

// Where the backend cannot write the sample mask (GL; mesh.wgsl `fs_main_per_sample`).
@fragment
fn fs_main_per_sample(in: ImpostorOut, @builtin(sample_index) k: u32) -> ImpostorFragmentPerSample {
    let f = shade(in);
    if (((f.mask >> k) & 1u) == 0u) {
        discard;
    }
    return ImpostorFragmentPerSample(f.color, f.depth);
}

// The window depth of world point `x` in the camera pass.
fn impostor_depth(x: vec3<f32>) -> f32 {
    let p = globals.view_proj * vec4<f32>(x, 1.0);
    return clamp(p.z / p.w, 0.0, 1.0);
}

fn shade(in: ImpostorOut) -> ImpostorShaded {
    // A model with alpha-tested materials: the atlas at the footprint's level, its texel's
    // coverage against the samples' thresholds (as far leaf cards: the view's coverage over the
    // pixel rather than the one texel at its centre), its mean colour, normal and depth for
    // the light. A solid model: each sample's own level-0 texel (below). Either way the texel
    // is the one the eye's ray meets in the depth atlas (parallax, `march`), not the one under
    // the quad's point: a picture from one tile put each texel where the tile's plane through
    // the centre has it, δ·sin e off for a surface δ in front of or behind that plane, e the
    // angle between the eye and the tile (up to about 15°).
    let dsx = dpdx(in.st);
    let dsy = dpdy(in.st);
    var level = atlas_level(dsx, dsy);
    let toward = towards_eye(in);
    let d = layer_dither(in.position.xy, in.world);
    var mask = 0xffffffffu;
    var hit: TileHit;
    if (impostor.grid_tile.w == 0u) {
        // A model without alpha-tested materials (a solid silhouette) is drawn as MSAA draws its
        // mesh: each sample keeps the model where its ray meets a surface in the level-0 depth
        // atlas, and the pixel is shaded once, with the level-0 texel the ray through its centre
        // meets (or the one its first kept sample's meets where the centre's misses, as
        // centroid sampling would). The block's coverage at the footprint's level against the
        // samples' thresholds spread a thin post's or a wall's edge over samples wherever it
        // lay in the pixel and let the ground through the pixels the model covers (spec0's far
        // houses and posts: 0.857 of the path tracer's ambient term; docs/VALIDATION.md).
        // Shading with the block instead of the texel:
        // tests/render_lod.rs `a_small_far_impostor_covers_the_pixels_its_mesh_covers`.
        let at = screen_point(in.clip);
        let o = sample_offset(in.position.xy, at, 4u);
        hit = march(in, tile_ray(in, in.st + dsx * o.x + dsy * o.y, toward), 0, SOLID_SHELL);
        var c = vec4<f32>(0.0);
        if (SAMPLE_MASK) {
            for (var k = 0u; k < 4u; k++) {
                let ok = sample_offset(in.position.xy, at, k);
                let h = march(in, tile_ray(in, in.st + dsx * ok.x + dsy * ok.y, toward), 0, SOLID_SHELL);
                if (h.hit) {
                    c[k] = 1.0;
                    if (!hit.hit) {
                        hit = h;
                    }
                }
            }
            mask = sample_mask_of(c, d);
        }
        if (!hit.hit) {
            discard;
        }
        level = 0;
    } else {
        hit = march(in, tile_ray(in, in.st, toward), level, LEAF_SHELL);
        if (!hit.hit) {
            discard;
        }
    }
    let px = atlas_texel_at(in, hit.st) >> vec2<u32>(u32(level));
    let texel = textureLoad(atlas_color, px, level);
    if (impostor.grid_tile.w != 0u) {
        if (SAMPLE_MASK) {
            mask = sample_mask_of(vec4<f32>(texel.a), d);
            if (mask == 0u || texel.a <= 0.0) {
                discard;
            }
        } else if (texel.a < d || texel.a <= 0.0) {
            discard;
        }
    }
    let nt = textureLoad(atlas_normal, px, level);
    let k = u32(round(nt.a * 255.0));
    // The surface point: where the ray met the depth atlas.
    let surface = hit_surface(in, hit);
    let depth = impostor_depth(surface);
    if (region_pass()) {
        // The texel's material names its region (a trunk is opaque, its crown leaves), as the
        // meshes' pass counts them; the model's flag where the atlas names no material.
        var leaves = impostor.grid_tile.w != 0u;
        if (k < impostor_materials.count.x) {
            leaves = impostor_materials.m[k].record[5].w != 0.0;
        }
        return ImpostorShaded(vec4<f32>(model_region(leaves), 1.0), mask, depth);
    }
    let nm = nt.xyz * 2.0 - 1.0;
    // Past level 0 the normal is the block's mean, shorter where its normals spread.
    let spread = select(1.0, clamp(length(nm), 0.0, 1.0), level > 0);
    let c = in.rot.x;
    let s = in.rot.y;
    let n_world = vec3<f32>(c * nm.x - s * nm.y, s * nm.x + c * nm.y, nm.z);
    let n = facing_normal(n_world, surface);
    let albedo = texel.rgb;
    // The shadow map holds the impostor itself, drawn in the tile nearest the sun; this
    // fragment's surface is a point of the model (the eye tile's ray met it, to a texel and the
    // depth code's step). The sun tile's depths are exact along its own centre direction, so
    // the shadow map's surface there differs along the sun by up to r·sin e_sun (e_sun: the
    // angle between the sun and its tile's centre) plus the depth code's step 2r/255 and a
    // texel: the lookup moves that far towards the sun, so an impostor does not shadow itself
    // through the map (tests/render_lod.rs: a bench 0.60 of full detail before); casters farther
    // away still shadow it, and its own shadow comes from the atlas (`impostor_self_visibility`).
    // (The eye tile's error was in this distance too, until the self-shadow test: 1.04 → 1.02
    // for the bench, 1.085 → 1.075 for the plant's direct term.)
    let sun_dir = sun_light().xyz;
    let sun_tile = nearest_tile(model_dir(sun_dir, in.rot), impostor.grid_tile.x);
    let e_sun = impostor_tile_error(sun_tile, sun_dir, in.rot);
    let tol = in.radius * (e_sun + 2.0 / 255.0 + 2.0 / f32(impostor.grid_tile.y));
    let lit_at = surface + sun_dir * tol;
    // The surface point is a point of the model (the eye tile's ray met it) up to the depth
    // code's step; tested along the sun tile's own direction, the tolerance is that step and
    // a texel's width (a sloped surface's depth across the texel it projects to).
    let step = in.radius * (4.0 / 255.0 + 2.0 / f32(impostor.grid_tile.y));
    let self_vis = block_self_visibility(in, px, level, surface, sun_tile, step);
    if (k < impostor_materials.count.x && impostor_materials.m[k].mode.x != 0.0) {
        // The texel's material: its two layers under the sun and under the sky, with the atlas
        // albedo as the bottom layer's colour × colour map (record roughness, no normal map).
        var m = schlick_from_record(impostor_materials.m[k].record);
        m.bottom.color = vec3<f32>(1.0);
        let wo = normalize(globals.eye.xyz - surface);
        let direct = direct_schlick(m, albedo, n, any_tangent(n), n, lit_at) * self_vis;
        let e_seen = max(block_irradiance(in, n, spread), vec3<f32>(0.0)) / PI;
        let e_other = max(block_irradiance(in, -n, spread), vec3<f32>(0.0)) / PI;
        let l_r = impostor_env(in, 2.0 * dot(n, wo) * n - wo, false);
        let amb = ambient_layered(m, dot(n, wo), albedo, e_seen, e_other, l_r) * ambient.scale.x;
        return ImpostorShaded(vec4<f32>(direct * globals.viewport.z + amb * globals.viewport.w, 1.0), mask, depth);
    }
    let direct = direct_lambert(albedo, n, lit_at) * self_vis;
    let amb = albedo * max(block_irradiance(in, n, spread), vec3<f32>(0.0)) / PI * ambient.scale.x;
    return ImpostorShaded(vec4<f32>(direct * globals.viewport.z + amb * globals.viewport.w, 1.0), mask, depth);
}
