// The sky background: a full-screen triangle at infinite depth; each pixel looks up the sky
// along its ray: the sky stage's cube texture (bilinear, seamless), or the lat-long image,
// bilinear with wrap in u and clamp in v (done by hand because Rgba32Float is not filterable
// everywhere).

struct SkyOut {
    @builtin(position) position: vec4<f32>,
};

@vertex
fn vs_main(@builtin(vertex_index) vid: u32) -> SkyOut {
    let x = f32(vid & 1u) * 4.0 - 1.0;
    let y = f32(vid >> 1u) * 4.0 - 1.0;
    var out: SkyOut;
    // Reversed Z: depth 0 is infinitely far.
    out.position = vec4<f32>(x, y, 0.0, 1.0);
    return out;
}

fn sky_radiance(d: vec3<f32>) -> vec3<f32> {
    if (globals.cam_forward.w > 0.5) {
        return textureSampleLevel(sky_cube, sky_sampler, d, 0.0).rgb;
    }
    let size = vec2<i32>(textureDimensions(sky_texture));
    let theta = acos(clamp(d.z, -1.0, 1.0));
    var phi = atan2(d.y, d.x);
    if (phi < 0.0) {
        phi = phi + 2.0 * PI;
    }
    let x = phi / (2.0 * PI) * f32(size.x) - 0.5;
    let y = theta / PI * f32(size.y) - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let i0 = ((i32(x0) % size.x) + size.x) % size.x;
    let i1 = (i0 + 1) % size.x;
    let j0 = clamp(i32(y0), 0, size.y - 1);
    let j1 = clamp(i32(y0) + 1, 0, size.y - 1);
    let a = mix(textureLoad(sky_texture, vec2<i32>(i0, j0), 0).rgb,
                textureLoad(sky_texture, vec2<i32>(i1, j0), 0).rgb, fx);
    let b = mix(textureLoad(sky_texture, vec2<i32>(i0, j1), 0).rgb,
                textureLoad(sky_texture, vec2<i32>(i1, j1), 0).rgb, fx);
    return mix(a, b, fy);
}

// The sun's disc (sun_irradiance.w: its solid angle Ω, 0 for none): a cap of cos ρ = 1 − Ω/2π
// around the sun's direction with radiance E/Ω, what the sky stage took out of the cube.
fn sun_disc(d: vec3<f32>) -> vec3<f32> {
    let omega = globals.sun_irradiance.w;
    if (omega <= 0.0 || dot(d, globals.sun_direction.xyz) < 1.0 - omega / (2.0 * PI)) {
        return vec3<f32>(0.0);
    }
    return globals.sun_irradiance.xyz / omega;
}

@fragment
fn fs_main(in: SkyOut) -> @location(0) vec4<f32> {
    let ndc = vec2<f32>(in.position.x / globals.viewport.x * 2.0 - 1.0,
                        1.0 - in.position.y / globals.viewport.y * 2.0);
    let d = normalize(globals.cam_forward.xyz + ndc.x * globals.cam_right.xyz + ndc.y * globals.cam_up.xyz);
    if (region_pass()) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    return vec4<f32>(sky_radiance(d) + sun_disc(d), 1.0);
}
