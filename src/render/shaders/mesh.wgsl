// Instanced models: vertex arrays straight from the mesh section (positions, normals, uvs in
// three buffers) and one 32-byte InstanceRecord per instance (position, scale, rotation about +Z
// in degrees). Alpha test at 0.5 on the colour map.

struct MaterialParams {
    // linear RGB diffuse colour, alpha 1
    base_color: vec4<f32>,
};

@group(1) @binding(0) var<uniform> material: MaterialParams;
@group(1) @binding(1) var color_map: texture_2d<f32>;
@group(1) @binding(2) var color_sampler: sampler;

struct MeshIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) instance_position: vec3<f32>,
    @location(4) instance_scale: f32,
    @location(5) instance_rotation_deg: f32,
};

struct MeshOut {
    @builtin(position) position: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
};

@vertex
fn vs_main(v: MeshIn) -> MeshOut {
    let a = radians(v.instance_rotation_deg);
    let c = cos(a);
    let s = sin(a);
    let p = v.position * v.instance_scale;
    let world = vec3<f32>(c * p.x - s * p.y, s * p.x + c * p.y, p.z) + v.instance_position;
    var out: MeshOut;
    out.position = globals.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    // A uniform scale keeps normals; only the rotation applies.
    out.normal = vec3<f32>(c * v.normal.x - s * v.normal.y, s * v.normal.x + c * v.normal.y, v.normal.z);
    out.uv = v.uv;
    return out;
}

@fragment
fn fs_main(in: MeshOut) -> @location(0) vec4<f32> {
    let texel = textureSample(color_map, color_sampler, in.uv);
    if (texel.a < 0.5) {
        discard;
    }
    let n = facing_normal(in.normal, in.world);
    return vec4<f32>(shade_lambert(texel.rgb * material.base_color.rgb, n, sun_visibility_at(in.position)), 1.0);
}
