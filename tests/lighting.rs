//! Light maps and environment maps against analytic answers.

use bake::envmap::bake::{EnvmapOptions, EnvmapScene, bake_envmaps};
use bake::lightmap::{BakeLight, LightmapMode, LightmapOptions, SUN_RADIUS, texel_irradiance};
use bake::model::{Material, Mesh, Terrain};
use bake::sh::ShRadiance;
use bake::trace::{InstanceTransform, SceneBvh};
use glam::Vec3A;
use std::f32::consts::PI;

mod common;
use common::{lens_area, linear_sky, place, scene_bvh};

fn mesh(positions: Vec<[f32; 3]>, indices: Vec<[u32; 3]>) -> Mesh {
    let n = positions.len();
    Mesh {
        normals: vec![[0.0, 0.0, 1.0]; n],
        uvs: vec![[0.0, 0.0]; n],
        triangle_materials: vec![0; indices.len()],
        materials: vec![Material::default()],
        positions,
        indices,
        ..Default::default()
    }
}

/// A disc of radius r in the plane z = 0 (a fan of many thin triangles).
fn disc(r: f32, segments: u32) -> Mesh {
    let mut p = vec![[0.0, 0.0, 0.0]];
    for k in 0..segments {
        let a = k as f32 / segments as f32 * 2.0 * PI;
        p.push([r * a.cos(), r * a.sin(), 0.0]);
    }
    let idx = (0..segments)
        .map(|k| [0, 1 + k, 1 + (k + 1) % segments])
        .collect();
    mesh(p, idx)
}

fn scene(models: Vec<Mesh>, inst: Vec<InstanceTransform>) -> SceneBvh {
    scene_bvh(&models.iter().collect::<Vec<_>>(), inst)
}

fn at(model: u32, t: [f32; 3]) -> InstanceTransform {
    place(model, t, 0.0)
}

#[test]
fn open_sky_plane_gets_the_analytic_irradiance() {
    // Nothing above the plane: E = ∫ (a + b cos θ) cos θ dω + E_sun cos θ_s = πa + 2πb/3 + E_s cos θ_s.
    let far = scene(vec![disc(1.0, 16)], vec![at(0, [0.0, 0.0, -50.0])]);
    let (a, b) = (0.7, 0.4);
    let s = Vec3A::new(0.3, 0.2, 0.9).normalize();
    let light = BakeLight {
        sky: linear_sky(a, b),
        sun: Some((s.to_array(), [100.0, 90.0, 80.0])),
    };
    let expect = |k: usize| PI * a + 2.0 * PI * b / 3.0 + [100.0, 90.0, 80.0][k] * s.z;
    for mode in [LightmapMode::Physical, LightmapMode::Thesis] {
        let opts = LightmapOptions {
            samples: 1024,
            sun_samples: 16,
            mode,
            ..Default::default()
        };
        for texel in 0..4 {
            let e = texel_irradiance(
                &far,
                &[[0.5; 3]],
                &light,
                &light.sky.to_irradiance(),
                Vec3A::ZERO,
                Vec3A::Z,
                texel,
                &opts,
            );
            for k in 0..3 {
                assert!(
                    (e[k] - expect(k)).abs() < 0.01 * expect(k),
                    "{mode:?} texel {texel}: {e:?} vs {}",
                    expect(k)
                );
            }
        }
    }
}

#[test]
fn opaque_disc_casts_the_analytic_umbra_and_penumbra_of_the_real_sun() {
    // A black disc of radius D at height h, the sun at the zenith, no sky: the visible fraction of
    // the sun at horizontal distance ρ from the axis is 1 − lens(ρ, h·tan r, D) / (π (h·tan r)²).
    let (radius, h) = (2.0f32, 1.0f32);
    let bvh = scene(vec![disc(radius, 4096)], vec![at(0, [0.0, 0.0, h])]);
    let light = BakeLight {
        sky: ShRadiance::default(),
        sun: Some(([0.0, 0.0, 1.0], [1000.0; 3])),
    };
    let opts = LightmapOptions {
        samples: 1,
        sun_samples: 1024,
        mode: LightmapMode::Physical,
        ..Default::default()
    };
    let a = (h * SUN_RADIUS.tan()) as f64;
    for t in [-3.0, -1.0, -0.5, 0.0, 0.4, 0.8, 1.5] {
        let rho = radius as f64 + t * a;
        let expected = 1.0 - lens_area(rho, a, radius as f64) / (std::f64::consts::PI * a * a);
        let p = Vec3A::new(rho as f32, 0.0, 0.0);
        let e = texel_irradiance(
            &bvh,
            &[[0.0; 3]],
            &light,
            &light.sky.to_irradiance(),
            p,
            Vec3A::Z,
            7,
            &opts,
        );
        let vis = e[0] as f64 / 1000.0;
        assert!(
            (vis - expected).abs() < 0.03,
            "ρ = D {t:+} a: visible {vis:.3}, analytic {expected:.3}"
        );
    }
    // Thesis mode has no visibility: the umbra is lit.
    let thesis = LightmapOptions {
        mode: LightmapMode::Thesis,
        ..opts
    };
    let e = texel_irradiance(
        &bvh,
        &[[0.0; 3]],
        &light,
        &light.sky.to_irradiance(),
        Vec3A::ZERO,
        Vec3A::Z,
        0,
        &thesis,
    );
    assert!((e[0] - 1000.0).abs() < 1e-3);
}

fn flat_terrain(extent: f32) -> Mesh {
    let t = Terrain {
        width: 3,
        height: 3,
        heights: vec![0.0; 9],
        origin: [-extent / 2.0; 2],
        extent: [extent; 2],
        color: None,
    };
    bake::trace::pack_scene::terrain_mesh(&t)
}

#[test]
fn envmap_of_an_instance_on_a_flat_ground_matches_the_analytic_projection() {
    // Constant sky L, ground of albedo ρ: the instance sees L above and ρ·L below the horizon.
    // f = (1+ρ)L/2 + (1−ρ)L/2·sign(z): band 0 √(4π)/2·L(1 + ρ); odd zonal terms from the step,
    // 4π K_l ∫₀¹ P_l(z) dz · (1−ρ)L/2: l = 1 gives √(3/4π)·πL(1 − ρ), l = 3 gives −√(7/4π)·(π/4)L(1 − ρ).
    let (l, rho) = (1.5f32, 0.4f32);
    let bvh = scene(
        vec![disc(0.3, 16), flat_terrain(20_000.0)],
        vec![at(0, [0.0, 0.0, 0.0]), at(1, [0.0, 0.0, 0.0])],
    );
    let sky = linear_sky(l, 0.0);
    let scene = EnvmapScene {
        bvh: &bvh,
        count: 1,
        probe_height: vec![0.5],
        albedo: vec![[0.9; 3], [rho; 3]],
        sky,
        sun: None,
    };
    let maps = bake_envmaps(
        &scene,
        &EnvmapOptions {
            samples: 4096,
            seed: 1,
            ..EnvmapOptions::DEFAULT
        },
    );
    let (ch, cs) = maps[0];
    let c00 = (4.0 * PI).sqrt() / 2.0 * l * (1.0 + rho);
    let c10 = (3.0 / (4.0 * PI)).sqrt() * PI * l * (1.0 - rho);
    assert!((ch[0][0] - c00).abs() < 0.01 * c00, "{} vs {c00}", ch[0][0]);
    assert!((ch[2][0] - c10).abs() < 0.02 * c10, "{} vs {c10}", ch[2][0]);
    let c30 = -(7.0 / (4.0 * PI)).sqrt() * PI / 4.0 * l * (1.0 - rho);
    assert!(
        (ch[12][0] - c30).abs() < 0.03 * c30.abs(),
        "{} vs {c30}",
        ch[12][0]
    );
    for (i, c) in ch.iter().enumerate().skip(1) {
        if i != 2 && i != 12 {
            assert!(c[0].abs() < 0.02 * c00, "coefficient {i}: {}", c[0]);
        }
    }
    assert!(cs.iter().all(|c| c[0] == 0.0), "no sun, no C_S");
}

#[test]
fn envmaps_converge_to_a_brute_force_reference() {
    // A cluttered scene: boxes around the instance, a sun. Error against 32k samples shrinks with N.
    let boxes = disc(1.0, 32);
    let mut inst = vec![at(0, [0.0, 0.0, 0.0])];
    for k in 0..12 {
        let a = k as f32 * 0.5;
        inst.push(at(0, [3.0 * a.cos(), 3.0 * a.sin(), 0.5 + 0.2 * k as f32]));
    }
    inst.push(at(1, [0.0, 0.0, 0.0]));
    let n = inst.len();
    let bvh = scene(vec![boxes, flat_terrain(200.0)], inst);
    let s = Vec3A::new(0.5, 0.3, 0.8).normalize();
    let sc = EnvmapScene {
        bvh: &bvh,
        count: 1,
        probe_height: vec![0.5],
        albedo: vec![[0.6; 3]; n],
        sky: linear_sky(1.0, 0.5),
        sun: Some(bake::envmap::bake::SunLight {
            direction: s.to_array(),
            irradiance: [50.0; 3],
        }),
    };
    let reference = bake_envmaps(
        &sc,
        &EnvmapOptions {
            samples: 32768,
            seed: 99,
            ..EnvmapOptions::DEFAULT
        },
    )[0];
    let err = |samples| {
        let m = bake_envmaps(
            &sc,
            &EnvmapOptions {
                samples,
                seed: 7,
                ..EnvmapOptions::DEFAULT
            },
        )[0];
        let d: f32 =
            m.0.iter()
                .chain(m.1.iter())
                .zip(reference.0.iter().chain(reference.1.iter()))
                .map(|(a, b)| (a[0] - b[0]).powi(2))
                .sum();
        d.sqrt()
    };
    let (e64, e512, e4096) = (err(64), err(512), err(4096));
    eprintln!("envmap error vs 32k-sample reference: N=64 {e64}, N=512 {e512}, N=4096 {e4096}");
    // Monte-Carlo error falls about as 1/√N (a factor √8 ≈ 2.8 per step); ask for a factor 2.
    assert!(
        e512 < e64 / 2.0 && e4096 < e512 / 2.0,
        "{e64} {e512} {e4096}"
    );
    let norm: f32 = reference.0.iter().map(|c| c[0] * c[0]).sum::<f32>().sqrt();
    assert!(e4096 < 0.05 * norm, "{e4096} vs |C| {norm}");
}

#[test]
fn envmaps_are_rotated_into_the_instance_frame_and_deterministic() {
    let bvh0 = scene(
        vec![disc(0.3, 8), flat_terrain(100.0)],
        vec![at(0, [0.0; 3]), at(0, [2.0, 0.0, 1.0]), at(1, [0.0; 3])],
    );
    let mut rotated = vec![at(0, [0.0; 3]), at(0, [2.0, 0.0, 1.0]), at(1, [0.0; 3])];
    rotated[0].rotation_deg = 90.0;
    let bvh90 = scene(vec![disc(0.3, 8), flat_terrain(100.0)], rotated);
    let mk = |bvh| EnvmapScene {
        bvh,
        count: 1,
        probe_height: vec![0.2],
        albedo: vec![[0.5; 3]; 3],
        sky: linear_sky(1.0, 0.3),
        sun: None,
    };
    let opts = EnvmapOptions {
        samples: 8192,
        seed: 3,
        ..EnvmapOptions::DEFAULT
    };
    let m0 = bake_envmaps(&mk(&bvh0), &opts)[0].0;
    let m90 = bake_envmaps(&mk(&bvh90), &opts)[0].0;
    // The world maps agree; in the rotated instance's frame the neighbour at world +x is at local −y.
    let back = ShRadiance { coeffs: m90 }.rotated_z((90.0f64).to_radians());
    for (a, b) in back.coeffs.iter().zip(m0.iter()) {
        assert!((a[0] - b[0]).abs() < 0.05, "{a:?} {b:?}");
    }
    let run = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| {
                bake_envmaps(
                    &mk(&bvh0),
                    &EnvmapOptions {
                        samples: 256,
                        seed: 5,
                        ..EnvmapOptions::DEFAULT
                    },
                )
            })
    };
    assert_eq!(run(1), run(2));
}
