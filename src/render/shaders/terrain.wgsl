// The terrain, drawn without vertex buffers: vertex k of quad q is a corner of grid cell q, its
// height read from the R32Float height texture (the pack's heights array, uploaded as is).
// Grid: corner-aligned samples, row 0 south; colour map row 0 north (v = 1 - j/(H-1)).

struct TerrainParams {
    // xy: origin, zw: extent (metres)
    origin_extent: vec4<f32>,
    // x, y: samples per row and number of rows
    size: vec4<u32>,
};

@group(1) @binding(0) var<uniform> terrain: TerrainParams;
@group(1) @binding(1) var heights: texture_2d<f32>;
@group(1) @binding(2) var color_map: texture_2d<f32>;
@group(1) @binding(3) var color_sampler: sampler;
// World-space normals, one texel per grid sample, row 0 south (the terrain section's `normals`).
@group(1) @binding(4) var terrain_normals: texture_2d<f32>;

struct TerrainOut {
    @builtin(position) position: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
};

fn height_at(i: i32, j: i32) -> f32 {
    let w = i32(terrain.size.x);
    let h = i32(terrain.size.y);
    return textureLoad(heights, vec2<i32>(clamp(i, 0, w - 1), clamp(j, 0, h - 1)), 0).r;
}

@vertex
fn vs_main(@builtin(vertex_index) vid: u32) -> TerrainOut {
    let w = i32(terrain.size.x);
    let h = i32(terrain.size.y);
    let quad = i32(vid / 6u);
    // Two counter-clockwise triangles (seen from above): (0,0) (1,0) (1,1) and (0,0) (1,1) (0,1).
    var dx = array<i32, 6>(0, 1, 1, 0, 1, 0);
    var dy = array<i32, 6>(0, 0, 1, 0, 1, 1);
    let corner = vid % 6u;
    let i = quad % (w - 1) + dx[corner];
    let j = quad / (w - 1) + dy[corner];
    return grid_vertex(i, j);
}

// Grid sample (i, j) as a terrain vertex.
fn grid_vertex(i: i32, j: i32) -> TerrainOut {
    let w = i32(terrain.size.x);
    let h = i32(terrain.size.y);
    let step = terrain.origin_extent.zw / vec2<f32>(f32(w - 1), f32(h - 1));
    let xy = terrain.origin_extent.xy + vec2<f32>(f32(i), f32(j)) * step;
    let world = vec3<f32>(xy, height_at(i, j));
    // Central differences (one-sided at the edges).
    let span_x = f32(min(i + 1, w - 1) - max(i - 1, 0)) * step.x;
    let span_y = f32(min(j + 1, h - 1) - max(j - 1, 0)) * step.y;
    let dzdx = (height_at(i + 1, j) - height_at(i - 1, j)) / span_x;
    let dzdy = (height_at(i, j + 1) - height_at(i, j - 1)) / span_y;
    var out: TerrainOut;
    out.position = globals.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.normal = vec3<f32>(-dzdx, -dzdy, 1.0);
    out.uv = vec2<f32>(f32(i) / f32(w - 1), 1.0 - f32(j) / f32(h - 1));
    return out;
}

// The chunked LOD grid (src/render/terrain_lod.rs): one instance per chunk, drawn at a step of
// 2^step_log2 cells. Vertex k: quads first (n² of them, n = CHUNK / step, row-major), then the
// skirts of the four edges (south, north, west, east; n segments each), six vertices per quad.
// Sample coordinates past the grid are clamped (such quads have zero area); a skirt on the
// terrain's border has zero depth.
const CHUNK: u32 = 64u;

struct ChunkIn {
    @builtin(vertex_index) vid: u32,
    @location(0) cell: vec2<u32>,
    @location(1) step_log2: u32,
    @location(2) skirt_bottom: f32,
};

@vertex
fn vs_chunk(c: ChunkIn) -> TerrainOut {
    let w = i32(terrain.size.x);
    let h = i32(terrain.size.y);
    let step = i32(1u << c.step_log2);
    let n = CHUNK >> c.step_log2;
    let q = c.vid / 6u;
    let corner = c.vid % 6u;
    var dx = array<i32, 6>(0, 1, 1, 0, 1, 0);
    var dy = array<i32, 6>(0, 0, 1, 0, 1, 1);
    let x0 = i32(c.cell.x);
    let y0 = i32(c.cell.y);
    var i: i32;
    var j: i32;
    var down = 0.0;
    if (q < n * n) {
        i = x0 + (i32(q % n) + dx[corner]) * step;
        j = y0 + (i32(q / n) + dy[corner]) * step;
    } else {
        let s = q - n * n;
        let edge = s / n;
        let along = (i32(s % n) + dx[corner]) * step;
        let side = i32(CHUNK);
        if (edge == 0u) {
            i = x0 + along;
            j = y0;
        } else if (edge == 1u) {
            i = x0 + along;
            j = y0 + side;
        } else if (edge == 2u) {
            i = x0;
            j = y0 + along;
        } else {
            i = x0 + side;
            j = y0 + along;
        }
        down = f32(dy[corner]);
        let ci = clamp(i, 0, w - 1);
        let cj = clamp(j, 0, h - 1);
        let border = (edge < 2u && (cj == 0 || cj == h - 1)) || (edge >= 2u && (ci == 0 || ci == w - 1));
        if (border) {
            down = 0.0;
        }
    }
    i = clamp(i, 0, w - 1);
    j = clamp(j, 0, h - 1);
    var out = grid_vertex(i, j);
    if (down > 0.0) {
        out.world.z = min(out.world.z, c.skirt_bottom);
        out.position = globals.view_proj * vec4<f32>(out.world, 1.0);
    }
    return out;
}

// The normal map at a world point: texel centres sit on the grid samples, so the bilinear
// lookup interpolates the sample normals.
fn terrain_normal(world: vec3<f32>) -> vec3<f32> {
    let size = vec2<f32>(f32(terrain.size.x), f32(terrain.size.y));
    let g = (world.xy - terrain.origin_extent.xy) / terrain.origin_extent.zw * (size - 1.0);
    let c = textureSample(terrain_normals, color_sampler, (g + 0.5) / size).xyz * 2.0 - 1.0;
    return normalize(c);
}

@fragment
fn fs_main(in: TerrainOut) -> @location(0) vec4<f32> {
    let albedo = textureSample(color_map, color_sampler, in.uv).rgb;
    let n = terrain_normal(in.world);
    if (region_pass()) {
        return vec4<f32>(REGION_TERRAIN, 1.0);
    }
    let l = direct_lambert(albedo, n, in.world) * globals.viewport.z
        + ambient_terrain(in.uv, albedo, n) * globals.viewport.w;
    return vec4<f32>(l, 1.0);
}
