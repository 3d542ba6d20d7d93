//! A steep surface keeps the shadow of an occluder just above it (issue 35: the generated over
//! view's trunks read 1.089 of the path tracer's direct term; docs/VALIDATION.md). A wall 8 m
//! wide and 4 m high with an awning 0.5 m deep along its top stands on a terrain 200 m wide,
//! under one shadow map over the whole scene (texels of 6 cm), the sun 80° off the wall's
//! normal and 44° high: the awning's shadow covers the wall's upper half, its occluding edge 0
//! to 2.9 m from the wall along the sun. The view sees only the wall. The oracle is the CPU
//! reference renderer's exact shadow rays over the same pixels (the negative control: the same
//! image without shadows).
//!
//! Before the fix the PCF compared every tap against the lookup point's depth less a
//! slope-scaled bias of (1 + 2 tan θ) texels, 12.3 texels (0.74 m) here, so the awning's shadow
//! was lost where the awning lay within that reach: the wall's top 0.5 m, in full shadow, read
//! 0.42 of its unshadowed radiance, and the whole wall 1.189 of the reference's (lavapipe).
//! Each texel is now compared against the receiver's own plane at the texel's centre
//! (receiver-plane depth) with a bias of one texel: 0.018 and 1.074 (the rest is the PCF's
//! penumbra, stretched 5.8× on the grazing wall), the same on lavapipe and GL.

mod common;

use bake::model::{Material, Mesh};
use bake::pack::Pack;

/// The wall (x ∈ [−4, 4], y = 0, z ∈ [0, 4], facing −y) and the awning along its top
/// (x ∈ [−4, 8], y ∈ [−0.5, 0], z = 4, facing up).
fn wall_and_awning() -> Mesh {
    let quad = |p: [[f32; 3]; 4], n: [f32; 3]| (p, n);
    let parts = [
        quad(
            [
                [-4.0, 0.0, 0.0],
                [4.0, 0.0, 0.0],
                [4.0, 0.0, 4.0],
                [-4.0, 0.0, 4.0],
            ],
            [0.0, -1.0, 0.0],
        ),
        quad(
            [
                [-4.0, -0.5, 4.0],
                [8.0, -0.5, 4.0],
                [8.0, 0.0, 4.0],
                [-4.0, 0.0, 4.0],
            ],
            [0.0, 0.0, 1.0],
        ),
    ];
    let mut m = Mesh {
        materials: vec![Material {
            diffuse: [0.8, 0.8, 0.8, 1.0],
            ..Material::default()
        }],
        ..Mesh::default()
    };
    for (p, n) in parts {
        let b = m.positions.len() as u32;
        m.positions.extend(p);
        m.normals.extend([n; 4]);
        m.uvs
            .extend([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]);
        m.indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
        m.triangle_materials.extend([0, 0]);
    }
    m
}

fn pack() -> Pack {
    let w = common::one_model_on_flat_terrain(
        "wall",
        &wall_and_awning(),
        [0.0; 3],
        [-100.0, -100.0],
        200.0,
    );
    Pack::from_bytes(&w.to_bytes().unwrap(), "steep.bake").unwrap()
}

#[test]
fn a_steep_wall_keeps_the_shadow_of_the_awning_just_above_it() {
    let pack = pack();
    // 80° off the wall's normal (0, −1, 0), 44° high, along +x.
    let sun = glam::Vec3::new(0.69, -0.174, 0.70).normalize();
    let opts = common::sun_only_view([0.0, -12.0, 2.0], [0.0, 0.0, 2.0], 16.0, sun.to_array());
    let shots = common::against_exact_shadows(&pack, &opts);
    let texel = shots.texel_m;
    assert!(texel > 0.05, "the map's texel {texel} m");
    let mean = common::mean_green;
    let (g, cpu, lit) = (
        mean(&shots.gpu),
        mean(&shots.exact),
        mean(&shots.unshadowed),
    );
    // The rows of the wall's top 0.5 m (the image spans 3.4 m of it in 72 rows), where the
    // awning lies within 0.7 m of the wall along the sun: in full shadow.
    let top = 10 * opts.width as usize;
    let (g_top, cpu_top) = (mean(&shots.gpu[..top]), mean(&shots.exact[..top]));
    eprintln!(
        "wall: GPU {g:.5}, CPU reference {cpu:.5}, unshadowed {lit:.5}; its top 0.5 m: GPU \
         {g_top:.5}, CPU {cpu_top:.5}; texel {texel} m"
    );
    // The awning shades about the wall's upper half (z from 2 to 4 of the 0.3–3.7 m seen).
    assert!(
        cpu < 0.7 * lit && cpu > 0.3 * lit,
        "the reference's wall is {cpu} of {lit} unshadowed"
    );
    assert!(
        cpu_top <= 1e-3 * lit && g_top <= 0.05 * lit,
        "the wall's top under the awning: GPU {g_top}, CPU {cpu_top} (unshadowed {lit})"
    );
    // The rest is the 3×3 PCF's penumbra, stretched 5.8× on a wall 80° off the light.
    assert!(
        (g / cpu - 1.0).abs() <= 0.10,
        "the GPU's wall {g} against the exact shadows' {cpu} ({:.3})",
        g / cpu
    );
}
