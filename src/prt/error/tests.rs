//! The error metric against an analytic oracle: a grid of unoccluded horizontal quads, whose
//! exact transfer is the SH projection of ρ·max(0, cos θ)/π (mirrored on the back side).

use super::*;
use crate::model::{Material, Mesh};
use crate::prt::transfer::{
    Adaptive, COEFFS, PER_VERTEX, PrtMaterial, PrtOptions, bake_prt, bake_prt_adaptive,
};
use crate::trace::ModelBvh;

const ALBEDO: [f32; 3] = [0.2, 0.5, 0.8];

/// `side`² unit quads on the plane z = 0, 2 m apart, normal +Z: none occludes another.
fn quad_grid(side: u32) -> Mesh {
    let mut mesh = Mesh {
        materials: vec![Material::default()],
        ..Mesh::default()
    };
    for i in 0..side * side {
        let (x, y) = ((i % side) as f32 * 2.0, (i / side) as f32 * 2.0);
        let base = mesh.positions.len() as u32;
        for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            mesh.positions.push([x + dx, y + dy, 0.0]);
            mesh.normals.push([0.0, 0.0, 1.0]);
            mesh.uvs.push([dx, dy]);
        }
        mesh.indices.push([base, base + 1, base + 2]);
        mesh.indices.push([base, base + 2, base + 3]);
        mesh.triangle_materials.extend([0, 0]);
    }
    mesh
}

/// The exact transfer of every vertex of [`quad_grid`]: K_0, (2/3)K_1, K_2/4 on the zonal
/// coefficients 0, 2, 6 (band 3's integral vanishes), odd bands negated on the back side, no
/// bounced light.
fn exact(vertices: usize) -> Transfer {
    let k = |l: f64| ((2.0 * l + 1.0) / (4.0 * std::f64::consts::PI)).sqrt();
    let mut zonal = [0.0f64; COEFFS];
    zonal[0] = k(0.0);
    zonal[2] = 2.0 * k(1.0) / 3.0;
    zonal[6] = k(2.0) / 4.0;
    let mut coeffs = vec![[0.0f32; 3]; vertices * PER_VERTEX];
    for v in 0..vertices {
        for side in 0..2 {
            let at = (v * 2 + side) * 2 * COEFFS;
            for (i, z) in zonal.iter().enumerate() {
                let sign = if side == 1 && i == 2 { -1.0 } else { 1.0 };
                coeffs[at + i] = ALBEDO.map(|a| (sign * z * a as f64) as f32);
            }
        }
    }
    Transfer {
        vertices: vertices as u32,
        samples: 0,
        bounces: 0,
        coeffs,
        rays: 0,
        skipped_vertices: 0,
    }
}

fn bake(mesh: &Mesh, samples: u32, seed: u64) -> Transfer {
    let m = [PrtMaterial {
        albedo: ALBEDO,
        translucence: 0.0,
    }];
    let o = PrtOptions {
        samples,
        bounces: 2,
        seed,
        ..PrtOptions::default()
    };
    bake_prt(mesh, &m, &[], &o).unwrap()
}

/// The true relative RMS error of `t`, against the exact transfer.
fn true_error(t: &Transfer) -> f64 {
    let e = exact(t.vertices as usize);
    mean_square_difference(t, &e).sqrt() / rms(&e)
}

#[test]
fn a_transfer_has_no_error_against_itself() {
    let mesh = quad_grid(2);
    let t = bake(&mesh, 16, 0);
    let e = transfer_error(&t, &t, &t);
    assert_eq!(e.rms_error, 0.0);
    assert_eq!(e.rms_difference, 0.0);
    assert_eq!(e.reference_noise, 0.0);
}

#[test]
fn corrected_error_matches_the_exact_error_of_an_unoccluded_grid() {
    let mesh = quad_grid(12);
    let a = bake(&mesh, 8, 0);
    // A reference no better than the estimate: uncorrected, its noise inflates the error by
    // about √(1 + 1/2); the correction removes it.
    let (r1, r2) = (bake(&mesh, 8, 101), bake(&mesh, 8, 202));
    let e = transfer_error(&a, &r1, &r2);
    let truth = true_error(&a);
    assert!(truth > 1e-3, "the oracle must see noise: {truth}");
    assert!(
        (e.rms_error / truth - 1.0).abs() < 0.15,
        "corrected {} vs exact {truth}",
        e.rms_error
    );
    assert!(e.rms_difference > 1.1 * truth, "{e:?} vs {truth}");
    // The reference's noise estimate against its exact value: (R₁ + R₂)/2 has half the
    // variance of one half.
    let noise = (true_error(&r1).powi(2) + true_error(&r2).powi(2)).sqrt() / 2.0;
    assert!(
        (e.reference_noise / noise - 1.0).abs() < 0.15,
        "{e:?} vs {noise}"
    );
}

#[test]
fn error_falls_with_the_sample_count() {
    let mesh = quad_grid(6);
    let (r1, r2) = (bake(&mesh, 1024, 101), bake(&mesh, 1024, 202));
    let errors: Vec<f64> = [4u32, 16, 64]
        .iter()
        .map(|&n| transfer_error(&bake(&mesh, n, 0), &r1, &r2).rms_error)
        .collect();
    // Monte Carlo alone would halve the error per 4× samples; stratified Sobol does better.
    assert!(errors[1] < errors[0] / 2.0, "{errors:?}");
    assert!(errors[2] < errors[1] / 2.0, "{errors:?}");
}

fn adaptive(
    mesh: &Mesh,
    m: &[PrtMaterial],
    o: &PrtOptions,
    masks: &[Option<crate::trace::AlphaMask>],
) -> Transfer {
    let bvh = ModelBvh::build_split(mesh, masks, o.preset, o.alpha_split).unwrap();
    let all: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    bake_prt_adaptive(&bvh, mesh, m, o, &all, Adaptive::for_samples(o.samples))
}

#[test]
fn adaptive_sampling_keeps_the_mean_count_and_converges() {
    let mesh = quad_grid(6);
    let m = [PrtMaterial {
        albedo: ALBEDO,
        translucence: 0.0,
    }];
    let o = PrtOptions {
        samples: 64,
        ..PrtOptions::default()
    };
    let fixed = bake_prt(&mesh, &m, &[], &o).unwrap();
    let a = adaptive(&mesh, &m, &o, &[]);
    // Unoccluded paths take one ray each: rays count the paths.
    let ratio = a.rays as f64 / fixed.rays as f64;
    assert!((ratio - 1.0).abs() < 0.02, "mean count kept: {ratio}");
    assert!(true_error(&a) < 2.0 * true_error(&fixed) + 1e-3);
}

#[test]
fn adaptive_sampling_does_not_depend_on_thread_count() {
    let (mesh, tex) = crate::prt::plant::procedural_plant(600, 3);
    let textures = [Some(tex)];
    let m = crate::prt::transfer::prt_materials(&mesh, &textures, 0.3);
    let masks = crate::prt::transfer::alpha_masks(&mesh, &textures);
    let o = PrtOptions {
        samples: 32,
        ..PrtOptions::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| adaptive(&mesh, &m, &o, &masks))
    };
    let (a, b) = (run(1), run(2));
    let bits =
        |t: &Transfer| -> Vec<u32> { t.coeffs.iter().flatten().map(|f| f.to_bits()).collect() };
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.rays, b.rays);
}

/// A transfer of `n` vertices with every component `v`.
fn filled(n: usize, v: f32) -> Transfer {
    Transfer {
        vertices: n as u32,
        samples: 1,
        bounces: 1,
        coeffs: vec![[v; 3]; n * PER_VERTEX],
        rays: 0,
        skipped_vertices: 0,
    }
}

#[test]
fn error_shares_find_the_part_that_differs_and_discount_the_reference_noise() {
    use crate::prt::transfer::{SETS, SIDES};
    // Reference halves that differ (noise) everywhere by ±0.1; the estimate is off the mean by
    // exactly that noise (so the corrected error is 0) except one coefficient of band 2 (i = 6),
    // back side, bounced set, of vertex 3.
    let (n, at) = (10, |v: usize, side: usize, set: usize, i: usize| {
        ((v * SIDES + side) * SETS + set) * COEFFS + i
    });
    let r1 = filled(n, 1.1);
    let r2 = filled(n, 0.9);
    let mut a = filled(n, 1.1);
    a.coeffs[at(3, 1, 1, 6)] = [1.5; 3];
    let e = error_shares(&a, &r1, &r2);
    let close = |got: &[f64], want: &[f64]| {
        assert!(
            got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-6),
            "{got:?} against {want:?}"
        )
    };
    close(&e.side, &[0.0, 1.0]);
    close(&e.set, &[0.0, 1.0]);
    close(&e.band, &[0.0, 0.0, 1.0, 0.0]);
    // Uncorrected, the noise (0.01 per component) would spread the shares: 0.16 against 0.01 ×
    // 1,279 other components. The signal shares of a constant transfer follow the component
    // counts: bands 1 : 3 : 5 : 7 of 16, sides and sets even.
    let s = signal_shares(&r1, &r2);
    close(&s.side, &[0.5, 0.5]);
    close(&s.set, &[0.5, 0.5]);
    close(&s.band, &[1.0 / 16.0, 3.0 / 16.0, 5.0 / 16.0, 7.0 / 16.0]);
}

#[test]
fn front_only_error_against_a_front_only_reference_is_the_front_sides_exact_error() {
    use crate::prt::transfer::PrtSides;
    let mesh = quad_grid(12);
    let m = [PrtMaterial {
        albedo: ALBEDO,
        translucence: 0.0,
    }];
    let bake_sides = |samples, seed, sides| {
        let o = PrtOptions {
            samples,
            bounces: 2,
            seed,
            sides,
            ..PrtOptions::default()
        };
        bake_prt(&mesh, &m, &[], &o).unwrap()
    };
    let front = |samples, seed| bake_sides(samples, seed, PrtSides::Front);
    let a = front(8, 0);
    let (r1, r2) = (front(8, 101), front(8, 202));
    // The exact front-only transfer: the oracle's back sides zeroed.
    let mut e = exact(a.vertices as usize);
    for v in 0..a.vertices as usize {
        let at = (v * 2 + 1) * 2 * COEFFS;
        e.coeffs[at..at + 2 * COEFFS].fill([0.0; 3]);
    }
    let truth = mean_square_difference(&a, &e).sqrt() / rms(&e);
    let err = transfer_error(&a, &r1, &r2);
    assert!(truth > 1e-3, "{truth}");
    assert!(
        (err.rms_error / truth - 1.0).abs() < 0.15,
        "corrected {} vs exact {truth}",
        err.rms_error
    );
    let shares = error_shares(&a, &r1, &r2);
    assert_eq!(shares.side[1], 0.0, "{shares:?}");
    assert!((shares.side[0] - 1.0).abs() < 1e-12, "{shares:?}");
    // The front side is the same bytes as under `both` at the same seed, so only the back
    // differs; on this mirror-symmetric grid the relative error is the same as with both sides.
    let both = bake_sides(8, 0, PrtSides::Both);
    for v in 0..a.vertices as usize {
        for set in 0..2 {
            assert_eq!(a.get(v, 0, set), both.get(v, 0, set));
        }
    }
    let both_truth = true_error(&both);
    assert!(
        (truth / both_truth - 1.0).abs() < 0.15,
        "{truth} vs {both_truth}"
    );
}
