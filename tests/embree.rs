//! Embree (feature `embree`, Debian's libembree-dev) against the obvhs tracer on the same rays:
//! the procedural alpha-tested plant, rays from outside towards its crown and from its vertices
//! into the hemispheres (the PRT's first rays). Both must agree on hit or miss, on the triangle
//! and on the distance; the alpha test must change the answer for many rays on both sides.
//!
//! Then the PRT on Embree (`tracer = "embree"`) against the PRT on obvhs (`tracer = "cpu"`, the
//! independent oracle): the same sampler, so the transfers agree far below the Monte-Carlo
//! error, while another seed differs by about that error; and the Embree bake is byte-identical
//! across runs and thread counts.
#![cfg(feature = "embree")]

mod common;

use bake::trace::embree::EmbreeScene;
use bake::trace::{BuildPreset, ModelBvh, Ray, Rng};
use glam::Vec3A;

fn rays(mesh: &bake::model::Mesh) -> Vec<Ray> {
    let (lo, hi) = mesh.bounds().unwrap();
    let (lo, hi) = (Vec3A::from(lo), Vec3A::from(hi));
    let centre = (lo + hi) * 0.5;
    let r = (hi - lo).length();
    let mut rng = Rng::hashed(7);
    let mut out = Vec::new();
    // From a sphere around the plant towards a random point inside its bounds.
    for _ in 0..4000 {
        let d =
            Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5).normalize_or(Vec3A::Z);
        let target = lo + (hi - lo) * Vec3A::new(rng.f32(), rng.f32(), rng.f32());
        let origin = centre + d * r;
        out.push(Ray::new(origin, (target - origin).normalize(), 0.0));
    }
    // From vertices, offset along the normal, in random directions of its hemisphere.
    for v in (0..mesh.positions.len()).step_by(7).take(2000) {
        let n = Vec3A::from(mesh.normals[v]).normalize_or(Vec3A::Z);
        let p = Vec3A::from(mesh.positions[v]) + n * (1e-4 * r);
        let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5).normalize_or(n);
        let d = if d.dot(n) < 0.0 { -d } else { d };
        out.push(Ray::new(p, d, 0.0));
    }
    out
}

/// (rays where hit/miss differ, rays where both hit different triangles at different
/// distances, hits) of Embree against obvhs.
fn compare(e: &EmbreeScene, b: &ModelBvh, rays: &[Ray]) -> (usize, usize, usize) {
    let (mut differ, mut far, mut hits) = (0, 0, 0);
    for r in rays {
        match (e.closest_hit(r), b.closest_hit(r)) {
            (Some(x), Some(y)) => {
                hits += 1;
                if x.triangle != y.triangle && (x.t - y.t).abs() > 1e-4 * x.t.max(y.t) {
                    far += 1;
                }
            }
            (None, None) => {}
            _ => differ += 1,
        }
    }
    (differ, far, hits)
}

#[test]
fn embree_and_obvhs_agree_on_the_alpha_tested_plant() {
    let (mesh, tex) = bake::prt::plant::procedural_plant(5000, 1);
    let masks = bake::trace::materials::alpha_masks(&mesh, &[Some(tex)]);
    assert!(
        masks.iter().any(|m| m.is_some()),
        "the plant has alpha-tested leaves"
    );
    let rays = rays(&mesh);
    let embree = EmbreeScene::build(&mesh, &masks).unwrap();
    let obvhs = ModelBvh::build(&mesh, &masks, BuildPreset::default()).unwrap();
    let (differ, far, hits) = compare(&embree, &obvhs, &rays);
    eprintln!(
        "{} rays: {hits} hits, {differ} hit/miss differ, {far} other hits",
        rays.len()
    );
    assert!(hits > rays.len() / 5, "too few hits to compare: {hits}");
    assert!(
        differ * 1000 <= rays.len(),
        "{differ} of {} rays differ",
        rays.len()
    );
    assert!(far * 1000 <= hits, "{far} of {hits} hits are elsewhere");

    // Without the alpha test both see the opaque cards: many rays change on both sides alike.
    let opaque_e = EmbreeScene::build(&mesh, &[]).unwrap();
    let opaque_b = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
    let (d0, f0, _) = compare(&opaque_e, &opaque_b, &rays);
    assert!(
        d0 * 1000 <= rays.len() && f0 * 1000 <= rays.len(),
        "{d0} {f0}"
    );
    let changed = rays
        .iter()
        .filter(|r| {
            embree.closest_hit(r).map(|h| h.triangle) != opaque_e.closest_hit(r).map(|h| h.triangle)
        })
        .count();
    assert!(
        changed * 20 > rays.len(),
        "the alpha test changes only {changed} rays"
    );
}

mod prt {
    use bake::model::Mesh;
    use bake::prt::error::{mean_square_difference, rms};
    use bake::prt::transfer::{PrtMaterial, PrtOptions, PrtScene, PrtTracer, Transfer, bake_prt};
    use bake::trace::AlphaMask;
    use bake::trace::materials::{alpha_masks, prt_materials};
    use std::process::Command;

    /// The small procedural plant (a few hundred vertices), its materials and alpha masks.
    fn plant() -> (Mesh, Vec<PrtMaterial>, Vec<Option<AlphaMask>>) {
        let (mesh, tex) = bake::prt::plant::procedural_plant(300, 3);
        let textures = [Some(tex)];
        let mats = prt_materials(&mesh, &textures, 0.3);
        let masks = alpha_masks(&mesh, &textures);
        (mesh, mats, masks)
    }

    fn opts(tracer: PrtTracer, seed: u64) -> PrtOptions {
        PrtOptions {
            samples: 64,
            bounces: 3,
            seed,
            tracer,
            ..PrtOptions::default()
        }
    }

    /// RMS of a − b relative to the RMS of b.
    fn relative(a: &Transfer, b: &Transfer) -> f64 {
        mean_square_difference(a, b).sqrt() / rms(b)
    }

    #[test]
    fn embree_prt_agrees_with_the_cpu_prt() {
        let (mesh, mats, masks) = plant();
        assert!(mesh.positions.len() >= 300, "{}", mesh.positions.len());
        // The option really selects Embree.
        let scene = PrtScene::build(&mesh, &masks, &opts(PrtTracer::Embree, 0)).unwrap();
        assert!(matches!(scene, PrtScene::Embree(_)));
        let cpu = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Cpu, 0)).unwrap();
        let embree = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Embree, 0)).unwrap();
        // Negative control: the CPU PRT with another seed differs by the Monte-Carlo error
        // (about √2 times the error of one bake at 64 paths per side).
        let other = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Cpu, 1)).unwrap();
        let same_vertices = (0..cpu.vertices as usize)
            .filter(|&v| {
                let at = v * bake::prt::transfer::PER_VERTEX;
                let n = bake::prt::transfer::PER_VERTEX;
                cpu.coeffs[at..at + n] == embree.coeffs[at..at + n]
            })
            .count();
        let d_backend = relative(&embree, &cpu);
        let d_seed = relative(&other, &cpu);
        eprintln!(
            "{} vertices: Embree vs CPU {:.5} (bit-identical vertices {same_vertices}), \
             other seed {:.4}; rays {} vs {}",
            cpu.vertices, d_backend, d_seed, embree.rays, cpu.rays
        );
        assert!(rms(&cpu) > 0.0);
        assert_eq!(cpu.skipped_vertices, embree.skipped_vertices);
        assert!(d_seed > 0.02, "the control is too quiet: {d_seed}");
        assert!(
            d_backend < 0.05 * d_seed,
            "Embree vs CPU {d_backend}, other seed {d_seed}"
        );
        // The same paths: the ray counts match but for rare float-level hit differences.
        let rays = (embree.rays as f64 - cpu.rays as f64).abs() / cpu.rays as f64;
        assert!(rays < 1e-3, "{} vs {}", embree.rays, cpu.rays);
    }

    #[test]
    fn embree_prt_skips_the_back_of_one_sided_materials_as_the_cpu_does() {
        let (mut mesh, mats, masks) = plant();
        mesh.materials[0].double_sided = false;
        let cpu = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Cpu, 0)).unwrap();
        let embree = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Embree, 0)).unwrap();
        let both = PrtOptions {
            sides: bake::prt::transfer::PrtSides::Both,
            ..opts(PrtTracer::Embree, 0)
        };
        let embree_both = bake_prt(&mesh, &mats, &masks, &both).unwrap();
        let zero = |t: &Transfer, v: usize| {
            (0..2).all(|set| t.get(v, 1, set).iter().all(|c| *c == [0.0; 3]))
        };
        let mut skipped = 0;
        for v in 0..cpu.vertices as usize {
            assert_eq!(zero(&cpu, v), zero(&embree, v), "vertex {v}");
            skipped += (zero(&embree, v) && !zero(&embree_both, v)) as usize;
        }
        assert!(skipped > 0);
        assert!(embree.rays < embree_both.rays);
        let other = bake_prt(&mesh, &mats, &masks, &opts(PrtTracer::Cpu, 1)).unwrap();
        assert!(relative(&embree, &cpu) < 0.05 * relative(&other, &cpu));
    }

    #[test]
    fn embree_prt_is_deterministic_across_runs_and_threads() {
        let (mesh, mats, masks) = plant();
        let o = opts(PrtTracer::Embree, 0);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| bake_prt(&mesh, &mats, &masks, &o).unwrap())
        };
        let bits =
            |t: &Transfer| -> Vec<u32> { t.coeffs.iter().flatten().map(|x| x.to_bits()).collect() };
        let one = run(1);
        let two = run(2);
        let again = run(2);
        assert_eq!(bits(&one), bits(&two));
        assert_eq!(bits(&two), bits(&again));
        assert_eq!((one.rays, two.rays), (again.rays, again.rays));
    }

    /// `bake prt --tracer embree` writes the same bytes on 1 and 2 threads and again.
    #[test]
    fn embree_prt_cli_output_is_byte_identical() {
        let dir = tempfile::tempdir().unwrap();
        let run = |threads: &str, name: &str| {
            let out = dir.path().join(name);
            let o = Command::new(env!("CARGO_BIN_EXE_bake"))
                .args(["-q", "prt", "fixtures/scene/plant.txf", "--samples", "16"])
                .args(["--tracer", "embree", "-o"])
                .arg(&out)
                .env("RAYON_NUM_THREADS", threads)
                .env("NODEVICE_SELECT", "1")
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            std::fs::read(out).unwrap()
        };
        let one = run("1", "one.bake");
        let two = run("2", "two.bake");
        let again = run("2", "again.bake");
        assert!(one == two && two == again, "the Embree PRT bytes differ");
    }
}

/// The two-level scene of the light-map and environment-map stages on Embree
/// (`trace::EmbreeSceneBvh`: Embree instances of one Embree scene per model, the heightfield as
/// user geometry) against `trace::SceneBvh` (obvhs, the oracle) on a small generated scene: a
/// few alpha-leaved trees instanced on a terrain. Ray by ray (the ignored instance, terrain hits
/// bit-identical, hits on alpha-tested leaves), then the env maps, the terrain light map and the
/// object (atlas) light maps of `tracer = "embree"` against `"cpu"`: equal far below the
/// Monte-Carlo noise (negative controls: another seed, other per-texel streams), and the Embree
/// bakes byte-identical on 1 and 2 threads.
mod scene {
    use bake::envmap::bake::EnvmapOptions;
    use bake::lightmap::{BakeLight, LightmapOptions};
    use bake::trace::pack_scene::TraceScene;
    use bake::trace::{Ray, Rng, SceneTracer, Tracer};
    use glam::Vec3A;
    use std::sync::OnceLock;

    /// The generated scene (60 instances of 3 trees on a 65² terrain), built once: sources,
    /// terrain and sky only.
    /// The scene, its light and the pack's bytes, built once.
    #[allow(clippy::type_complexity)]
    static SCENE: OnceLock<((TraceScene, BakeLight), Vec<u8>)> = OnceLock::new();

    fn scene() -> &'static (TraceScene, BakeLight) {
        &SCENE.get_or_init(build_scene).0
    }

    fn pack_bytes() -> &'static [u8] {
        &SCENE.get_or_init(build_scene).1
    }

    /// The generated scene (60 instances of 3 trees on a 65² terrain): sources, terrain and sky
    /// only.
    fn build_scene() -> ((TraceScene, BakeLight), Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let p = bake::fixtures::large::LargeScene {
            instances: 60,
            models: 3,
            terrain: 65,
        };
        for (name, bytes) in bake::fixtures::large::large_files(&p) {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let mut opts = bake::graph::BuildOptions {
            scenes: vec![dir.path().join("scene.eco")],
            output: Some(dir.path().join("scene.bake")),
            sky: Some(dir.path().join("sky.hdr")),
            cache: bake::graph::CacheMode::Off,
            ..Default::default()
        }
        .preview();
        let s = &mut opts.pipeline.stages;
        (s.prt, s.lod, s.lightmap, s.atlas, s.envmaps, s.cluster) =
            (false, false, false, false, false, false);
        (s.bittree, s.svo, s.linespace) = (false, false, false);
        bake::graph::build(&opts, &bake::graph::progress::Silent).unwrap();
        let bytes = std::fs::read(dir.path().join("scene.bake")).unwrap();
        let pack = bake::pack::Pack::from_bytes(&bytes, "scene.bake").unwrap();
        let ts = bake::trace::pack_scene::trace_scene(&pack).unwrap();
        let light = bake::lightmap::scene_lighting(&pack).unwrap();
        ((ts, light), bytes)
    }

    /// Object (atlas) light maps of every tree (placed 20 times each) on Embree against cpu.
    #[test]
    fn embree_object_light_maps_equal_cpu() {
        let (ts, light) = scene();
        let pack = bake::pack::Pack::from_bytes(pack_bytes(), "scene.bake").unwrap();
        let o = |tracer| LightmapOptions {
            samples: 8,
            sun_samples: 2,
            max_instances: 100,
            tracer,
            ..Default::default()
        };
        let floats = |tracer| -> Vec<f32> {
            let s = bake::lightmap::object_sections(&pack, ts, light, &o(tracer)).unwrap();
            assert!(!s.is_empty());
            s.iter()
                .flat_map(|s| {
                    let v = bake::pack::section::SectionView::parse(&s.payload, 0).unwrap();
                    let (_, m) = bake::lightmap::atlas_section::from_section(&v).unwrap();
                    m.texels.into_iter().flatten()
                })
                .collect()
        };
        let (cpu, emb) = (floats(Tracer::Cpu), floats(Tracer::Embree));
        let d = rel_rms(&emb, &cpu);
        eprintln!(
            "object light maps: {} floats, embree vs cpu {d:.3e}",
            cpu.len()
        );
        assert!(d < 1e-3, "{d}");
    }

    /// ‖a − b‖ / ‖b‖ over every float.
    fn rel_rms(a: &[f32], b: &[f32]) -> f64 {
        assert_eq!(a.len(), b.len());
        let (mut d, mut n) = (0.0f64, 0.0f64);
        for (x, y) in a.iter().zip(b) {
            d += ((x - y) as f64).powi(2);
            n += (*y as f64).powi(2);
        }
        (d / n.max(1e-30)).sqrt()
    }

    #[test]
    fn embree_scene_hits_equal_the_obvhs_scene() {
        let (ts, _) = scene();
        compare_hits(ts, 20000);
    }

    /// [`compare_hits`] on a pack of one's own (a measurement, not a test):
    /// `BAKE_EMBREE_PACK=scene.bake cargo test --release --features embree --test embree -- --ignored`.
    #[test]
    #[ignore]
    fn embree_scene_hits_on_a_given_pack() {
        let Some(path) = std::env::var_os("BAKE_EMBREE_PACK") else {
            return;
        };
        let pack = bake::pack::Pack::open(std::path::Path::new(&path)).unwrap();
        let ts = bake::trace::pack_scene::trace_scene(&pack).unwrap();
        compare_hits(&ts, 200000);
    }

    fn compare_hits(ts: &TraceScene, rays: usize) {
        let cpu: &dyn SceneTracer = ts.tracer(Tracer::Cpu).unwrap();
        let emb = ts.tracer(Tracer::Embree).unwrap();
        let terrain = ts.instance_count as u32;
        assert_eq!(cpu.instances(), emb.instances());
        let t = ts.terrain.as_ref().unwrap();
        let (lo, hi) = (
            Vec3A::new(t.origin[0], t.origin[1], 0.0),
            Vec3A::new(t.origin[0] + t.extent[0], t.origin[1] + t.extent[1], 12.0),
        );
        let mut rng = Rng::hashed(11);
        let (mut n, mut hits, mut differ, mut terrain_hits, mut instance_hits) = (0, 0, 0, 0, 0);
        let (mut any_differ, mut beyond, mut max_dt, mut alpha_hits) = (0, 0, 0.0f32, 0);
        // Per model and material: alpha-tested?
        let masked: Vec<Vec<Option<bake::trace::AlphaMask>>> =
            ts.bvh.models().iter().map(|m| m.source().1).collect();
        for k in 0..rays {
            // From instance probes (one instance skipped, or two: the env maps skip the
            // instances that enclose the probe too) and from random points above the ground.
            let (o, skip) = if k % 2 == 0 {
                let i = rng.below(ts.instance_count as u32);
                let tr = ts.bvh.instances()[i as usize];
                let o = Vec3A::from(tr.translation) + Vec3A::Z * (1.0 + 3.0 * rng.f32());
                let skip = match k % 4 {
                    0 => vec![i],
                    _ => vec![rng.below(ts.instance_count as u32 + 1), i],
                };
                (o, skip)
            } else {
                let o = lo + (hi - lo) * Vec3A::new(rng.f32(), rng.f32(), rng.f32());
                (o, Vec::new())
            };
            let o = Vec3A::new(o.x, o.y, o.z.max(t.height_at(o.x, o.y) + 0.05));
            let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5)
                .normalize_or(Vec3A::Z);
            let r = Ray::new(o, d, 1e-4);
            n += 1;
            let (a, b) = (
                cpu.closest_hit_excluding(&r, &skip),
                emb.closest_hit_excluding(&r, &skip),
            );
            match (a, b) {
                (Some(a), Some(b)) => {
                    hits += 1;
                    assert!(
                        !skip.contains(&b.instance),
                        "the skipped instances are ignored"
                    );
                    assert!(
                        !skip.contains(&a.instance),
                        "the skipped instances are ignored"
                    );
                    if a.instance == terrain && b.instance == terrain {
                        // The same intersector on the same world ray: the same hit.
                        assert_eq!(a.hit, b.hit);
                        terrain_hits += 1;
                    } else if a.instance == b.instance && a.hit.triangle == b.hit.triangle {
                        // Both map the world ray into the instance in f32 (Embree through its
                        // inverse matrix): the rounding scales with the coordinates' size.
                        let tol = 1e-4 * a.hit.t.max(1.0) + 2e-6 * o.length();
                        let (sa, sb) = (cpu.surface(&a), emb.surface(&b));
                        let dt = (a.hit.t - b.hit.t).abs();
                        max_dt = max_dt.max(dt);
                        if dt > tol || (sa.position - sb.position).length() > 10.0 * tol {
                            beyond += 1;
                        }
                        if (sa.shading_normal - sb.shading_normal).length() > 1e-2 {
                            eprintln!(
                                "normal: {r:?} skip {skip:?} cpu {a:?} {sa:?} embree {b:?} {sb:?}"
                            );
                            beyond += 1;
                        }
                        instance_hits += 1;
                        let model = ts.bvh.instances()[a.instance as usize].model as usize;
                        if masked[model]
                            .get(sa.material as usize)
                            .is_some_and(|m| m.is_some())
                        {
                            alpha_hits += 1;
                        }
                    } else if (a.hit.t - b.hit.t).abs()
                        > 1e-4 * a.hit.t.max(1.0) + 2e-6 * o.length()
                    {
                        differ += 1;
                        if differ <= 5 {
                            eprintln!(
                                "elsewhere: {r:?} skip {skip:?} cpu {a:?} embree {b:?} brute {:?}",
                                ts.bvh.brute_force_closest_hit(&r)
                            );
                        }
                    }
                }
                (None, None) => {}
                (a, b) => {
                    differ += 1;
                    if differ <= 5 {
                        eprintln!("hit/miss: {r:?} cpu {a:?} embree {b:?}");
                    }
                }
            }
            if cpu.any_hit(&r) != emb.any_hit(&r) {
                any_differ += 1;
            }
        }
        eprintln!(
            "{n} rays: {hits} hits ({terrain_hits} terrain, {instance_hits} same triangle), \
             {differ} differ, any-hit differs on {any_differ}; same triangle: largest |Δt| \
             {max_dt:.2e}, {beyond} beyond the tolerance; {alpha_hits} on alpha-tested leaves"
        );
        assert!(alpha_hits > 0, "no hit on an alpha-tested leaf");
        assert!(
            beyond * 1000 <= n,
            "{beyond} of {n} hits beyond the tolerance"
        );
        assert!(
            terrain_hits > n / 10 && instance_hits > n / 20,
            "too few hits"
        );
        assert!(differ * 1000 <= n, "{differ} of {n} rays differ");
        assert!(
            any_differ * 1000 <= n,
            "{any_differ} of {n} any-hits differ"
        );
    }

    fn envmaps(tracer: Tracer, seed: u64) -> Vec<f32> {
        let (ts, light) = scene();
        let o = EnvmapOptions {
            samples: 64,
            seed,
            tracer,
            ..EnvmapOptions::DEFAULT
        };
        let maps = bake::envmap::instance_maps(ts, light, &o, 0..ts.instance_count).unwrap();
        maps.iter()
            .flat_map(|(h, s)| h.iter().chain(s.iter()).flatten().copied())
            .collect()
    }

    fn lightmap(tracer: Tracer) -> Vec<f32> {
        let (ts, light) = scene();
        let o = LightmapOptions {
            resolution: Some(48),
            samples: 16,
            sun_samples: 4,
            tracer,
            ..Default::default()
        };
        let (texels, _) = bake::lightmap::bake_terrain_lightmap_rows(ts, light, &o, 0..48)
            .unwrap()
            .unwrap();
        texels.iter().flatten().copied().collect()
    }

    #[test]
    fn embree_env_maps_equal_cpu_far_below_the_noise() {
        let cpu = envmaps(Tracer::Cpu, 0);
        let emb = envmaps(Tracer::Embree, 0);
        let other = envmaps(Tracer::Cpu, 1);
        let (d, noise) = (rel_rms(&emb, &cpu), rel_rms(&other, &cpu));
        eprintln!("env maps: embree vs cpu {d:.3e}, cpu seed 1 vs seed 0 {noise:.3e}");
        assert!(noise > 1e-3, "the negative control differs: {noise}");
        assert!(d < 0.05 * noise, "embree {d} against the noise {noise}");
    }

    #[test]
    fn embree_terrain_light_map_equals_cpu_far_below_the_noise() {
        let cpu = lightmap(Tracer::Cpu);
        let emb = lightmap(Tracer::Embree);
        let (ts, light) = scene();
        // Negative control: the same map with other sample streams (other seeds per texel).
        let o = LightmapOptions {
            resolution: Some(48),
            samples: 16,
            sun_samples: 4,
            ..Default::default()
        };
        let t = ts.terrain.as_ref().unwrap();
        let sky_irr = light.sky.to_irradiance();
        let mut other = Vec::new();
        for k in 0..48u32 * 48 {
            let (i, j) = (k % 48, k / 48);
            let x = t.origin[0] + (i as f32 + 0.5) / 48.0 * t.extent[0];
            let y = t.origin[1] + (1.0 - (j as f32 + 0.5) / 48.0) * t.extent[1];
            let p = Vec3A::new(x, y, t.height_at(x, y));
            let n = Vec3A::from(bake::lightmap::height_normal(t, x, y));
            let e = bake::lightmap::texel_irradiance(
                &ts.bvh,
                &ts.albedo,
                light,
                &sky_irr,
                p,
                n,
                k as u64 + (1 << 32),
                &o,
            );
            other.extend(e);
        }
        let (d, noise) = (rel_rms(&emb, &cpu), rel_rms(&other, &cpu));
        eprintln!("terrain light map: embree vs cpu {d:.3e}, other streams vs cpu {noise:.3e}");
        assert!(noise > 1e-3, "the negative control differs: {noise}");
        assert!(d < 0.05 * noise, "embree {d} against the noise {noise}");
    }

    #[test]
    fn embree_lighting_is_byte_identical_across_threads() {
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| (envmaps(Tracer::Embree, 0), lightmap(Tracer::Embree)))
        };
        let (a, b) = (run(1), run(2));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.0), bits(&b.0), "env maps");
        assert_eq!(bits(&a.1), bits(&b.1), "light map");
    }

    /// A post inside a closed house (its probe enclosed) and one beside it, on a ground plate:
    /// Embree skips the enclosing house as the CPU tracer does (the rule is decided on the CPU
    /// scene), so the env maps agree far below the noise, and post 0's Embree maps equal the
    /// CPU maps of the scene without the house.
    #[test]
    fn embree_env_maps_skip_the_enclosing_instance_as_the_cpu_does() {
        use bake::envmap::bake::{EnvmapScene, bake_envmaps};
        use bake::trace::EmbreeSceneBvh;
        let models = [
            super::common::closed_box([-0.15, -0.15, 0.0], [0.15, 0.15, 3.0]),
            super::common::closed_box([-1.5, -1.0, 0.0], [1.5, 1.0, 2.5]),
            super::common::closed_box([-200.0, -200.0, -1.0], [200.0, 200.0, 0.0]),
        ];
        let place = |m, t, r| super::common::place(m, t, r);
        let build = |house: bool| {
            let mut inst = vec![place(0, [0.0; 3], 0.0), place(0, [2.5, 0.0, 0.0], 0.0)];
            if house {
                inst.push(place(1, [0.3, 0.2, 0.0], 10.0));
            }
            inst.push(place(2, [0.0; 3], 0.0));
            super::common::scene_bvh(&models.iter().collect::<Vec<_>>(), inst)
        };
        let (cpu, bare) = (build(true), build(false));
        let emb = EmbreeSceneBvh::build(&cpu).unwrap();
        let p = Vec3A::new(0.0, 0.0, 1.5);
        assert_eq!(cpu.enclosing(p, 0), vec![2]);
        assert_eq!(SceneTracer::enclosing(&emb, p, 0), vec![2]);
        let o = EnvmapOptions {
            samples: 1024,
            seed: 3,
            ..EnvmapOptions::DEFAULT
        };
        let maps = |bvh: &dyn SceneTracer, albedo: Vec<[f32; 3]>| {
            let sc = EnvmapScene {
                bvh,
                count: 2,
                probe_height: vec![1.5; 2],
                albedo,
                sky: super::common::linear_sky(1.0, 0.5),
                sun: Some(bake::envmap::bake::SunLight {
                    direction: Vec3A::new(0.5, 0.3, 0.8).normalize().to_array(),
                    irradiance: [50.0; 3],
                }),
            };
            bake_envmaps(&sc, &o)
                .iter()
                .map(|(h, s)| h.iter().chain(s.iter()).flatten().copied().collect())
                .collect::<Vec<Vec<f32>>>()
        };
        let with = vec![[0.5; 3], [0.5; 3], [0.1; 3], [0.3; 3]];
        let (c, e) = (maps(&cpu, with.clone()), maps(&emb, with));
        let b = maps(&bare, vec![[0.5; 3], [0.5; 3], [0.3; 3]]);
        for k in 0..2 {
            let d = rel_rms(&e[k], &c[k]);
            eprintln!("post {k}: embree vs cpu {d:.3e}");
            assert!(d < 1e-4, "post {k}: {d}");
        }
        let d = rel_rms(&e[0], &b[0]);
        assert!(
            d < 1e-4,
            "post 0 on embree against the scene without the house: {d}"
        );
        assert!(
            rel_rms(&e[1], &b[1]) > 1e-2,
            "post 1 beside the house keeps it"
        );
    }
}
