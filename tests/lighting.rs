//! Light maps and environment maps against analytic answers.

use bake::envmap::bake::{EnvmapOptions, EnvmapScene, SunLight, bake_envmaps, trace_envmaps_range};
use bake::lightmap::{BakeLight, LightmapMode, LightmapOptions, SUN_RADIUS, texel_irradiance};
use bake::model::{Material, Mesh, Terrain};
use bake::sh::ShRadiance;
use bake::trace::{InstanceTransform, SceneBvh};
use glam::Vec3A;
use std::f32::consts::PI;

mod common;
use common::{closed_box, lens_area, linear_sky, place, scene_bvh};

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
    let (bvh, n) = cluttered();
    let sc = cluttered_probe(&bvh, n);
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

/// The cluttered scene of `envmaps_converge_to_a_brute_force_reference`: 12 discs around the
/// instance at the origin, a flat ground, sky gradient and sun.
/// One probe 0.5 m above the instance of [`cluttered`], albedo 0.6, a linear sky and the sun.
fn cluttered_probe(bvh: &SceneBvh, n: usize) -> EnvmapScene<'_> {
    EnvmapScene {
        bvh,
        count: 1,
        probe_height: vec![0.5],
        albedo: vec![[0.6; 3]; n],
        sky: linear_sky(1.0, 0.5),
        sun: sun(),
    }
}

fn cluttered() -> (SceneBvh, usize) {
    let boxes = disc(1.0, 32);
    let mut inst = vec![at(0, [0.0, 0.0, 0.0])];
    for k in 0..12 {
        let a = k as f32 * 0.5;
        inst.push(at(0, [3.0 * a.cos(), 3.0 * a.sin(), 0.5 + 0.2 * k as f32]));
    }
    inst.push(at(1, [0.0, 0.0, 0.0]));
    let n = inst.len();
    (scene(vec![boxes, flat_terrain(200.0)], inst), n)
}

fn sun() -> Option<bake::envmap::bake::SunLight> {
    Some(bake::envmap::bake::SunLight {
        direction: Vec3A::new(0.5, 0.3, 0.8).normalize().to_array(),
        irradiance: [50.0; 3],
    })
}

#[test]
fn the_tracers_noise_covariance_matches_the_variance_across_independent_seeds() {
    // The noise estimate from one trace's two halves, Σ D Dᵀ / 4, against the covariance of the
    // maps over 2,000 independent seeds (the maps' true noise): trace, C_H and C_S parts, SH
    // bands and the whole matrix agree within the sampling error of 2,000 draws (≤ 5 % for a
    // trace; tolerance 15 %, Frobenius 20 %).
    let (bvh, n) = cluttered();
    let sc = cluttered_probe(&bvh, n);
    let seeds = 2000u64;
    let (mut maps, mut diffs) = (Vec::new(), Vec::new());
    for s in 0..seeds {
        let opts = EnvmapOptions {
            samples: 64,
            seed: 1000 + s,
            ..EnvmapOptions::DEFAULT
        };
        let t = trace_envmaps_range(&sc, &opts, 0..1);
        // The instance is not rotated: its frame is the world frame of the differences.
        maps.push(bake::envmap::section::flatten(
            &[t.maps[0].0],
            &[t.maps[0].1],
        ));
        diffs.push(t.diffs[0]);
    }
    const D: usize = 96;
    let mean: Vec<f64> = (0..D)
        .map(|c| maps.iter().map(|m| m[c] as f64).sum::<f64>() / seeds as f64)
        .collect();
    let mut emp = vec![0.0f64; D * D];
    for m in &maps {
        for a in 0..D {
            for b in 0..D {
                emp[a * D + b] += (m[a] as f64 - mean[a]) * (m[b] as f64 - mean[b]);
            }
        }
    }
    for v in &mut emp {
        *v /= (seeds - 1) as f64;
    }
    let est = bake::envmap::section::noise_from_differences(&diffs).covariance;
    let part = |m: &[f64], f: &dyn Fn(usize) -> bool| -> f64 {
        (0..D).filter(|&c| f(c)).map(|c| m[c * D + c]).sum()
    };
    let band = |c: usize| ((c % 48) / 3) as f64;
    type Part = Box<dyn Fn(usize) -> bool>;
    let checks: [(&str, Part); 7] = [
        ("trace", Box::new(|_| true)),
        ("C_H", Box::new(|c| c < 48)),
        ("C_S", Box::new(|c| c >= 48)),
        ("band 0", Box::new(move |c| band(c) < 1.0)),
        ("band 1", Box::new(move |c| (1.0..4.0).contains(&band(c)))),
        ("band 2", Box::new(move |c| (4.0..9.0).contains(&band(c)))),
        ("band 3", Box::new(move |c| band(c) >= 9.0)),
    ];
    for (name, f) in &checks {
        let (e, t) = (part(&est, f.as_ref()), part(&emp, f.as_ref()));
        eprintln!("{name}: estimated {e:.5e}, across seeds {t:.5e}");
        assert!(t > 0.0, "{name}: no noise across seeds");
        assert!((e / t - 1.0).abs() < 0.15, "{name}: estimated {e} vs {t}");
    }
    let frob = |m: &[f64]| m.iter().map(|x| x * x).sum::<f64>().sqrt();
    let diff: Vec<f64> = est.iter().zip(&emp).map(|(a, b)| a - b).collect();
    let rel = frob(&diff) / frob(&emp);
    eprintln!("covariance: relative Frobenius difference {rel:.3}");
    assert!(rel < 0.2, "{rel}");
    // Each single trace's own estimate (|D|²/4) averages to the same trace.
    let per = bake::envmap::section::noise_from_differences(&diffs).variance;
    let avg = per.iter().map(|&v| v as f64).sum::<f64>() / per.len() as f64;
    assert!((avg / part(&emp, &|_| true) - 1.0).abs() < 0.15);
}

#[test]
fn the_envmaps_section_with_its_noise_estimate_is_the_same_for_any_thread_count_and_shards() {
    // 2,100 instances (more than one 1,024-instance block of the covariance sum): one thread,
    // two threads, and two shards joined give byte-identical sections.
    let mut inst = Vec::new();
    for k in 0..2100u32 {
        let (x, y) = ((k % 50) as f32 * 2.0 - 50.0, (k / 50) as f32 * 2.0 - 42.0);
        let mut t = at(0, [x, y, 0.3 + 0.1 * (k % 7) as f32]);
        t.rotation_deg = (k * 37 % 360) as f32;
        inst.push(t);
    }
    inst.push(at(1, [0.0; 3]));
    let n = inst.len();
    let bvh = scene(vec![disc(0.6, 12), flat_terrain(400.0)], inst);
    let sc = EnvmapScene {
        bvh: &bvh,
        count: n - 1,
        probe_height: vec![0.5; n - 1],
        albedo: vec![[0.6; 3]; n],
        sky: linear_sky(1.0, 0.5),
        sun: sun(),
    };
    let opts = EnvmapOptions {
        samples: 16,
        seed: 4,
        ..EnvmapOptions::DEFAULT
    };
    let run = |t: usize, cuts: &[usize]| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| {
                // Shards between consecutive cuts.
                let mut all = bake::envmap::bake::Traced::default();
                for w in cuts.windows(2) {
                    all.extend(trace_envmaps_range(&sc, &opts, w[0]..w[1]));
                }
                bake::envmap::envmaps_section(&all, &opts)
            })
    };
    let one = run(1, &[0, 2100]);
    let v = bake::pack::section::SectionView::parse(&one.payload, 0).unwrap();
    let m = bake::envmap::section::EnvmapsMeta::decode(&v).unwrap();
    assert_eq!(m.noise_pairs, 2100);
    assert!(
        bake::envmap::section::envmaps_noise_from_section(&v, &m)
            .unwrap()
            .is_some()
    );
    assert!(one == run(2, &[0, 2100]), "thread count changed the bytes");
    assert!(one == run(2, &[0, 700, 2100]), "shards changed the bytes");
    // Without the noise estimate: no noise arrays.
    let plain = EnvmapOptions {
        noise_estimate: false,
        ..opts
    };
    let t = trace_envmaps_range(&sc, &plain, 0..10);
    assert!(t.diffs.is_empty());
    let s = bake::envmap::envmaps_section(&t, &plain);
    let v = bake::pack::section::SectionView::parse(&s.payload, 0).unwrap();
    assert_eq!(
        bake::envmap::section::EnvmapsMeta::decode(&v)
            .unwrap()
            .noise_pairs,
        0
    );
    assert!(v.info("noise_covariance").is_none());
}

#[test]
fn the_sky_control_variate_is_unbiased_and_lowers_the_variance() {
    // The cluttered scene (boxes around the probe, a ground plane, a sun): C_H by the control
    // variate (exact sky SH + traced difference where blocked) and by summing every ray's
    // radiance, each over 400 independent seeds of 64 rays. Unbiased: every coefficient's
    // mean agrees within 4 standard errors of the difference. Variance: the summed per-
    // coefficient variance of C_H is lower (measured 1.06×: the spherical Fibonacci set already
    // integrates the unblocked sky almost exactly; the noise is at the visibility edges, which
    // the correction keeps).
    let (bvh, n) = cluttered();
    let sc = cluttered_probe(&bvh, n);
    let seeds = 400;
    let draws = |cv: bool| -> Vec<Vec<f64>> {
        (0..seeds)
            .map(|s| {
                let o = EnvmapOptions {
                    samples: 64,
                    seed: 1000 + s,
                    sky_control_variate: cv,
                    ..EnvmapOptions::DEFAULT
                };
                let (ch, _) = bake_envmaps(&sc, &o)[0];
                ch.iter().flatten().map(|&v| v as f64).collect()
            })
            .collect()
    };
    let stats = |d: &[Vec<f64>]| {
        let k = d[0].len();
        let m: Vec<f64> = (0..k)
            .map(|i| d.iter().map(|x| x[i]).sum::<f64>() / d.len() as f64)
            .collect();
        let v: Vec<f64> = (0..k)
            .map(|i| d.iter().map(|x| (x[i] - m[i]).powi(2)).sum::<f64>() / (d.len() - 1) as f64)
            .collect();
        (m, v)
    };
    let (m_cv, v_cv) = stats(&draws(true));
    let (m_pl, v_pl) = stats(&draws(false));
    for i in 0..m_cv.len() {
        let se = ((v_cv[i] + v_pl[i]) / seeds as f64).sqrt();
        assert!(
            (m_cv[i] - m_pl[i]).abs() <= 4.0 * se + 1e-6,
            "coefficient {i}: control variate {} vs plain {} (standard error {se})",
            m_cv[i],
            m_pl[i]
        );
    }
    let ratio = v_pl.iter().sum::<f64>() / v_cv.iter().sum::<f64>();
    eprintln!("variance plain / control variate: {ratio:.2}");
    assert!(ratio > 1.0, "variance ratio {ratio}");
}

/// The two scenes of `a_probe_inside_another_instance_sees_the_scene_without_it`: two 3 m posts
/// (instances 0 and 1) on a flat ground, and with `house` a dark closed 3 × 2 × 2.5 m box around the
/// first post (its probe, 1.5 m up, inside) and 0.7 m from the second (its probe outside).
fn posts_and_house(house: bool) -> (SceneBvh, Vec<[f32; 3]>) {
    let post = closed_box([-0.15, -0.15, 0.0], [0.15, 0.15, 3.0]);
    let hut = closed_box([-1.5, -1.0, 0.0], [1.5, 1.0, 2.5]);
    let mut inst = vec![at(0, [0.0, 0.0, 0.0]), at(0, [2.5, 0.0, 0.0])];
    let mut albedo = vec![[0.5, 0.4, 0.3]; 2];
    if house {
        inst.push(place(1, [0.3, 0.2, 0.0], 10.0));
        albedo.push([0.1, 0.08, 0.06]);
    }
    inst.push(at(2, [0.0, 0.0, 0.0]));
    albedo.push([0.3; 3]);
    (scene(vec![post, hut, flat_terrain(400.0)], inst), albedo)
}

#[test]
fn a_probe_inside_another_instance_sees_the_scene_without_it() {
    // Oracle: the same scene without the enclosing house. The probe's rays ignore the house
    // that encloses it (trace::SceneBvh::enclosing), and so do its hit points' sun rays, so
    // post 0's maps must be those traced without the house (the same rays: the seeds follow
    // the instance number). Post 1 stands beside the house: its maps keep the house.
    let opts = EnvmapOptions {
        samples: 1024,
        seed: 11,
        ..EnvmapOptions::DEFAULT
    };
    let maps = |house| {
        let (bvh, albedo) = posts_and_house(house);
        let sc = EnvmapScene {
            bvh: &bvh,
            count: 2,
            probe_height: vec![1.5; 2],
            albedo,
            sky: linear_sky(1.0, 0.5),
            sun: sun(),
        };
        assert_eq!(
            bvh.enclosing(Vec3A::new(0.0, 0.0, 1.5), 0),
            if house { vec![2] } else { vec![] }
        );
        assert!(bvh.enclosing(Vec3A::new(2.5, 0.0, 1.5), 1).is_empty());
        bake_envmaps(&sc, &opts)
    };
    let (with, without) = (maps(true), maps(false));
    let flat = |m: &([[f32; 3]; 16], [[f32; 3]; 16])| -> Vec<f32> {
        m.0.iter().chain(m.1.iter()).flatten().copied().collect()
    };
    let diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let (a0, b0) = (flat(&with[0]), flat(&without[0]));
    let scale = b0.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(
        diff(&a0, &b0) <= 1e-5 * scale,
        "post 0 inside the house: {} of {scale}\n{a0:?}\n{b0:?}",
        diff(&a0, &b0)
    );
    // The sun's bounce off the ground reaches the probe: C_S is not empty.
    assert!(without[0].1[0][0] > 0.05 * without[0].0[0][0]);
    // Beside the house the house still occludes: its sky light C_H (band 0) falls by more than
    // a tenth, far beyond the noise (the same rays traced with and without it).
    let (h_with, h_without) = (with[1].0[0][0], without[1].0[0][0]);
    assert!(
        h_with < 0.9 * h_without,
        "post 1 beside the house: {h_with} vs {h_without}"
    );
}

#[test]
fn a_probe_ignores_the_instances_standing_inside_its_own_instance() {
    // The other way round: a house's probe (1.25 m up, inside the house) ignores the post that
    // stands inside the house (the post's probe is enclosed by the house): the house's maps
    // must be those traced in the scene without the post. Oracle: that scene (the house is
    // instance 0 in both, so the same rays). A post standing beside the house still counts.
    let post = closed_box([-0.15, -0.15, 0.0], [0.15, 0.15, 3.0]);
    let hut = closed_box([-1.5, -1.0, 0.0], [1.5, 1.0, 2.5]);
    let opts = EnvmapOptions {
        samples: 1024,
        seed: 12,
        ..EnvmapOptions::DEFAULT
    };
    let maps = |posts: &[[f32; 3]]| {
        let mut inst = vec![place(1, [0.0; 3], 20.0)];
        inst.extend(posts.iter().map(|&t| at(0, t)));
        inst.push(at(2, [0.0; 3]));
        let n = inst.len() - 1;
        let mut albedo = vec![[0.1, 0.08, 0.06]; n];
        albedo[0] = [0.6, 0.5, 0.4];
        albedo.push([0.3; 3]);
        let bvh = scene(vec![post.clone(), hut.clone(), flat_terrain(400.0)], inst);
        let sc = EnvmapScene {
            bvh: &bvh,
            count: n,
            probe_height: vec![1.25; n],
            albedo,
            sky: linear_sky(1.0, 0.5),
            sun: sun(),
        };
        bake_envmaps(&sc, &opts)[0]
    };
    let flat = |m: ([[f32; 3]; 16], [[f32; 3]; 16])| -> Vec<f32> {
        m.0.iter().chain(m.1.iter()).flatten().copied().collect()
    };
    let bare = flat(maps(&[]));
    let inside = flat(maps(&[[0.8, 0.3, 0.0]]));
    let beside = flat(maps(&[[2.3, 0.0, 0.0]]));
    let diff = |a: &[f32]| {
        a.iter()
            .zip(&bare)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let scale = bare.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(
        diff(&inside) <= 1e-5 * scale,
        "a post inside the house: {} of {scale}",
        diff(&inside)
    );
    assert!(
        diff(&beside) > 0.02 * scale,
        "a post beside the house: {} of {scale}",
        diff(&beside)
    );
}

/// The irradiance the first instance's maps (C_H + C_S, 4,096 rays, `seed`) give a normal.
fn probe_irradiance(sc: &EnvmapScene, seed: u64) -> bake::sh::ShIrradiance {
    let opts = EnvmapOptions {
        samples: 4096,
        seed,
        ..EnvmapOptions::DEFAULT
    };
    let (ch, cs) = bake_envmaps(sc, &opts)[0];
    let mut sum = ShRadiance::default();
    for c in 0..16 {
        for k in 0..3 {
            sum.coeffs[c][k] = ch[c][k] + cs[c][k];
        }
    }
    sum.to_irradiance()
}

/// Irradiance at `x` (normal `n`) by brute force: `n_rays` cosine-distributed rays through the
/// whole scene, each bringing the sun-free sky where it escapes and, where it hits, the one
/// bounce the environment maps model (ρ/π times the sky's unoccluded irradiance plus the sun
/// where it reaches the hit): the light an instance's surface point receives in the maps' own
/// model of transport, without the probe.
fn wall_irradiance(sc: &EnvmapScene, bvh: &SceneBvh, x: Vec3A, n: Vec3A, n_rays: u32) -> f32 {
    use bake::trace::Ray;
    let sky_irr = sc.sky.to_irradiance();
    let (t, b) = bake::trace::frame(n);
    let side = (n_rays as f32).sqrt() as u32;
    let mut sum = 0.0f64;
    for i in 0..side {
        for j in 0..side {
            let (u1, u2) = (
                (i as f32 + 0.5) / side as f32,
                (j as f32 + 0.5) / side as f32,
            );
            let (r, phi) = (u1.sqrt(), 2.0 * PI * u2);
            let d = (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).sqrt()).normalize();
            let l = match bvh.closest_hit(&Ray::new(x, d, 1e-4)) {
                None => sc.sky.eval(d.to_array())[0].max(0.0),
                Some(h) => {
                    let s = bvh.surface(&h);
                    let mut nh = s.shading_normal;
                    if nh.dot(d) > 0.0 {
                        nh = -nh;
                    }
                    let rho = sc.albedo[h.instance as usize][0];
                    let mut e = sky_irr.eval(nh.to_array())[0].max(0.0);
                    if let Some(sun) = &sc.sun {
                        let sd = Vec3A::from(sun.direction);
                        let cos = nh.dot(sd);
                        if cos > 0.0 && !bvh.any_hit(&Ray::new(s.position + nh * 1e-3, sd, 1e-4)) {
                            e += sun.irradiance[0] * cos;
                        }
                    }
                    rho / PI * e
                }
            };
            sum += l as f64;
        }
    }
    (PI as f64 * sum / (side * side) as f64) as f32
}

/// `model` alone on a flat ground (400 m across), both placed at the origin.
fn on_flat_ground(model: Mesh) -> SceneBvh {
    scene(
        vec![model, flat_terrain(400.0)],
        vec![at(0, [0.0; 3]), at(1, [0.0; 3])],
    )
}

/// The probe `height` above the model of [`on_flat_ground`]: albedo 0.5 (the model) and 0.4
/// (the ground), a linear sky and `sun`.
fn lone_probe(bvh: &SceneBvh, height: f32, sun: Option<SunLight>) -> EnvmapScene<'_> {
    EnvmapScene {
        bvh,
        count: 1,
        probe_height: vec![height],
        albedo: vec![[0.5; 3], [0.4; 3]],
        sky: linear_sky(1.0, 0.5),
        sun,
    }
}

#[test]
fn a_house_probe_lights_its_walls_like_the_ground_in_front_of_them() {
    // A closed house on a flat ground under the sun: its probe (1.25 m up) lies inside it. The
    // maps stand in for the light at the house's outer surfaces; the oracle is that light at the
    // middle of each wall, by brute force in the maps' own transport model (`wall_irradiance`).
    // The ground inside the house's box is seen by no wall: lit by the probe's maps as in the
    // house's shadow, the walls' bounce from the ground was lost; it is now lit as if the house
    // were absent (docs/CONVENTIONS.md, "Environment-map probes"). Measured (4,096 rays,
    // 2026-12-07): the walls' mean irradiance from the maps 0.828 of the oracle's with the
    // footprint in the house's shadow (per wall 0.81–0.85), 0.992 lit (0.96–1.04).
    let bvh = on_flat_ground(closed_box([-1.5, -1.0, 0.0], [1.5, 1.0, 2.5]));
    let sc = lone_probe(&bvh, 1.25, sun());
    assert!(bvh.instance_encloses(0, Vec3A::new(0.0, 0.0, 1.25)));
    let e_map = probe_irradiance(&sc, 5);
    let walls = [
        (Vec3A::new(1.5, 0.0, 1.25), Vec3A::X),
        (Vec3A::new(-1.5, 0.0, 1.25), -Vec3A::X),
        (Vec3A::new(0.0, 1.0, 1.25), Vec3A::Y),
        (Vec3A::new(0.0, -1.0, 1.25), -Vec3A::Y),
    ];
    let (mut m, mut o) = (0.0, 0.0);
    for (x, n) in walls {
        let oracle = wall_irradiance(&sc, &bvh, x + n * 1e-3, n, 16_384);
        let got = e_map.eval(n.to_array())[0];
        eprintln!(
            "wall {n}: maps {got:.4}, brute force {oracle:.4}, ratio {:.3}",
            got / oracle
        );
        assert!(
            (0.92..1.08).contains(&(got / oracle)),
            "wall facing {n}: {got} vs {oracle}"
        );
        m += got;
        o += oracle;
    }
    eprintln!("walls: maps / brute force {:.3}", m / o);
    assert!(
        (m / o - 1.0).abs() < 0.04,
        "walls' mean: {} vs {}",
        m / 4.0,
        o / 4.0
    );
}

#[test]
fn a_parasol_probe_keeps_the_shadow_under_its_roof() {
    // The other side of the house's rule: a post under a wide opaque roof (a parasol, a tree's
    // trunk and crown) has its probe inside the post, but its footprint is not enclosed, so the
    // ground under the roof keeps the roof's shadow in its maps. Oracle: the irradiance at the
    // post's sides by brute force (`wall_irradiance`); lit as if the parasol were absent, the
    // maps would see sunlit ground under the roof and read far above it. Measured (2026-12-07):
    // 1.014 of brute force; 1.291 with the house's rule applied to the parasol too.
    let mut parasol = closed_box([-0.15, -0.15, 0.0], [0.15, 0.15, 3.0]);
    let mut roof = disc(2.0, 32);
    for p in &mut roof.positions {
        p[2] += 3.0;
    }
    parasol.append(roof);
    let bvh = on_flat_ground(parasol);
    // The sun high, so the roof's shadow lies around the post.
    let high_sun = SunLight {
        direction: Vec3A::new(0.1, 0.05, 1.0).normalize().to_array(),
        irradiance: [50.0; 3],
    };
    let sc = lone_probe(&bvh, 1.5, Some(high_sun));
    assert!(
        bvh.instance_encloses(0, Vec3A::new(0.0, 0.0, 1.5)),
        "the probe is in the post"
    );
    let e_map = probe_irradiance(&sc, 6);
    let (mut m, mut o) = (0.0, 0.0);
    for n in [Vec3A::X, -Vec3A::X, Vec3A::Y, -Vec3A::Y] {
        let x = Vec3A::new(0.0, 0.0, 1.5) + n * (0.15 + 1e-3);
        m += e_map.eval(n.to_array())[0];
        o += wall_irradiance(&sc, &bvh, x, n, 16_384);
    }
    eprintln!("post sides: maps / brute force {:.3}", m / o);
    assert!(
        (m / o - 1.0).abs() < 0.1,
        "post sides: {} vs {}",
        m / 4.0,
        o / 4.0
    );
}
