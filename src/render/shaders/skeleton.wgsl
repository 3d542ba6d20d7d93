// Skeletons (src/render/skeleton.rs): a model's own line and point arrays (TXF), drawn for the
// instances whose bounding sphere projects to at most `skeleton.pixels` pixels of radius
// (lod/select.rs). Group 1: the model's colour. Vertex buffer 0: model-space positions (two per
// segment in the line pass, one per point in the point pass), buffer 1: the instance records.
// Lit as a surface facing up (+Z): the sun by Lambert with the shadow-map lookup of the other
// passes, the sky SH irradiance at +Z as the ambient term (the impostors' fallback).

struct SkeletonParams {
    // rgb: the model's mean albedo (linear), a: 1 where the model has alpha-tested materials
    // (the region pass's leaves), else 0
    albedo: vec4<f32>,
};

@group(1) @binding(0) var<uniform> skeleton: SkeletonParams;

struct SkeletonIn {
    @location(0) position: vec3<f32>,
    @location(3) instance_position: vec3<f32>,
    @location(4) instance_scale: f32,
    @location(5) instance_rotation_deg: f32,
};

struct SkeletonOut {
    @builtin(position) position: vec4<f32>,
    @location(0) world: vec3<f32>,
};

@vertex
fn vs_main(v: SkeletonIn) -> SkeletonOut {
    let a = radians(v.instance_rotation_deg);
    let q = v.position * v.instance_scale;
    let world = vec3<f32>(cos(a) * q.x - sin(a) * q.y, sin(a) * q.x + cos(a) * q.y, q.z)
        + v.instance_position;
    var out: SkeletonOut;
    out.position = globals.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    return out;
}

@fragment
fn fs_main(in: SkeletonOut) -> @location(0) vec4<f32> {
    if (region_pass()) {
        return vec4<f32>(model_region(skeleton.albedo.a != 0.0), 1.0);
    }
    let n = vec3<f32>(0.0, 0.0, 1.0);
    let albedo = skeleton.albedo.rgb;
    let direct = direct_lambert(albedo, n, in.world);
    let amb = albedo * max(sky_irradiance(n), vec3<f32>(0.0)) / PI * ambient.scale.x;
    return vec4<f32>(direct * globals.viewport.z + amb * globals.viewport.w, 1.0);
}
