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
