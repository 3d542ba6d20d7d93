//! Tests of the SH module against analytic values, exact quadrature and a second algorithm.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use super::*;
use crate::cube::CubeMap;

/// A small deterministic generator (SplitMix64) for test inputs.
/// The crate's generator ([`crate::rng::Rng`], seeded with `Rng::new`) with the uniform
/// directions these tests draw.
struct Rng(crate::rng::Rng);
impl Rng {
    fn new(seed: u64) -> Self {
        Rng(crate::rng::Rng::new(seed))
    }
    fn next(&mut self) -> f64 {
        self.0.f64()
    }
    fn dir(&mut self) -> [f64; 3] {
        let z = 2.0 * self.next() - 1.0;
        let phi = 2.0 * PI * self.next();
        let r = (1.0 - z * z).sqrt();
        [r * phi.cos(), r * phi.sin(), z]
    }
}

fn f32v(d: [f64; 3]) -> [f32; 3] {
    d.map(|c| c as f32)
}

fn mat_vec(r: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

#[test]
fn fast_path_matches_the_legendre_recursion() {
    let mut rng = Rng::new(1);
    for _ in 0..200 {
        let d = rng.dir();
        let mut reference = [0.0; 16];
        eval_basis_into(4, d, &mut reference);
        let fast = eval_basis16(f32v(d));
        for i in 0..16 {
            assert!(
                (fast[i] as f64 - reference[i]).abs() < 2e-6,
                "{i}: {fast:?}"
            );
        }
    }
}

#[test]
fn low_bands_match_the_textbook_formulas_with_condon_shortley_phase() {
    // Independent closed forms (K and P written out by hand, CS phase included).
    let mut rng = Rng::new(2);
    let c1 = (3.0 / (4.0 * PI)).sqrt();
    for _ in 0..20 {
        let [x, y, z] = rng.dir();
        let mut b = [0.0; 9];
        eval_basis_into(3, [x, y, z], &mut b);
        let expect = [
            0.5 / PI.sqrt(),
            -c1 * y,
            c1 * z,
            -c1 * x,
            0.5 * (15.0 / PI).sqrt() * x * y,
            -0.5 * (15.0 / PI).sqrt() * y * z,
            0.25 * (5.0 / PI).sqrt() * (3.0 * z * z - 1.0),
            -0.5 * (15.0 / PI).sqrt() * x * z,
            0.25 * (15.0 / PI).sqrt() * (x * x - y * y),
        ];
        for i in 0..9 {
            assert!((b[i] - expect[i]).abs() < 1e-12, "{i}");
        }
    }
}

#[test]
fn basis_is_orthonormal_by_exact_quadrature() {
    // Order 6: products have degree ≤ 10; 6 Gauss points in z and 12 in φ integrate them exactly.
    let order = 6;
    let n = order * order;
    let mut gram = vec![0.0; n * n];
    let mut b = vec![0.0; n];
    for (d, w) in sphere_quadrature(6, 12) {
        eval_basis_into(order, d, &mut b);
        for i in 0..n {
            for j in 0..n {
                gram[i * n + j] += w * b[i] * b[j];
            }
        }
    }
    for i in 0..n {
        for j in 0..n {
            let e = if i == j { 1.0 } else { 0.0 };
            assert!(
                (gram[i * n + j] - e).abs() < 1e-12,
                "({i},{j}) {}",
                gram[i * n + j]
            );
        }
    }
}

#[test]
fn basis_is_orthonormal_on_a_cube_map() {
    // A second, independent quadrature (cube texels with exact solid angles): O(h²) accurate.
    let size = 64;
    for j in [0usize, 3, 6, 10, 15] {
        let cube = CubeMap::from_fn(size, |d| {
            let v = eval_basis16(f32v(d))[j];
            [v, 0.0, 0.0]
        });
        let sh = project_cube(&cube);
        for i in 0..16 {
            let e = if i == j { 1.0 } else { 0.0 };
            assert!(
                (sh.coeffs[i][0] - e).abs() < 2e-3,
                "({i},{j}) {}",
                sh.coeffs[i][0]
            );
        }
    }
}

#[test]
fn white_furnace() {
    // A constant sky L: L00 = 2√π·L exactly (the solid angles sum to 4π), the rest vanish, and
    // the irradiance on any surface is π·L.
    let l = [1.0f32, 2.5, 0.25];
    for size in [1, 8, 33] {
        let sh = project_cube(&CubeMap::filled(size, l));
        for k in 0..3 {
            let expect = 2.0 * PI.sqrt() * l[k] as f64;
            assert!(
                (sh.coeffs[0][k] as f64 - expect).abs() < 1e-5 * expect,
                "{size}"
            );
        }
        for c in &sh.coeffs[1..] {
            assert!(c.iter().all(|v| v.abs() < 1e-5), "{size}: {c:?}");
        }
        let e = sh.to_irradiance();
        let mut rng = Rng::new(3);
        for _ in 0..10 {
            let got = e.eval(f32v(rng.dir()));
            for k in 0..3 {
                assert!((got[k] as f64 - PI * l[k] as f64).abs() < 1e-4, "{got:?}");
            }
        }
    }
}

#[test]
fn clamped_cosine_lobe_projects_to_its_analytic_coefficients() {
    // f(ω) = max(0, n·ω): by Funk–Hecke its coefficients are Â_l · y_lm(n).
    let mut rng = Rng::new(4);
    for n in [[0.0, 0.0, 1.0], rng.dir(), rng.dir()] {
        let cube = CubeMap::from_fn(128, |d| {
            let c = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]).max(0.0) as f32;
            [c, c, c]
        });
        let sh = project_cube(&cube);
        let mut yn = [0.0; 16];
        eval_basis_into(4, n, &mut yn);
        for i in 0..16 {
            let expect = clamped_cosine_factor(band_of(i)) * yn[i];
            assert!(
                (sh.coeffs[i][1] as f64 - expect).abs() < 1e-3,
                "{i}: {} vs {expect}",
                sh.coeffs[i][1]
            );
        }
    }
    assert!((clamped_cosine_factor(2) - PI / 4.0).abs() < 1e-15);
    assert!((clamped_cosine_factor(4) + PI / 24.0).abs() < 1e-15);
    assert_eq!(clamped_cosine_factor(3), 0.0);
}

#[test]
fn irradiance_of_a_band_limited_sky_matches_direct_integration() {
    // E(n) from the convolution against a brute-force ∫ L max(0, n·ω) dω over a fine cube.
    let sky = |d: [f64; 3]| (1.0 + 0.8 * d[2] + 0.3 * d[0] * d[1]) as f32;
    let size = 96;
    let cube = CubeMap::from_fn(size, |d| [sky(d); 3]);
    let e = project_cube(&cube).to_irradiance();
    let omega = cube::solid_angle_table(size);
    let n2 = (size * size) as usize;
    for n in [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0]] {
        let mut direct = 0.0;
        for (i, t) in cube.texels.iter().enumerate() {
            let (face, rc) = (Face::ALL[i / n2], i % n2);
            let d = cube::texel_direction(
                size,
                face,
                (rc % size as usize) as u32,
                (rc / size as usize) as u32,
            );
            let c = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]).max(0.0);
            direct += t[0] as f64 * c * omega[rc];
        }
        let got = e.eval(f32v(n))[0] as f64;
        // The clamped cosine truncated at order 4 keeps > 99% of the energy of a smooth sky.
        assert!(
            (got - direct).abs() < 0.01 * direct,
            "{n:?}: {got} vs {direct}"
        );
    }
}

fn random_sh(rng: &mut Rng) -> ShRadiance {
    let mut s = ShRadiance::default();
    for c in s.coeffs.iter_mut() {
        *c = [0, 1, 2].map(|_| (2.0 * rng.next() - 1.0) as f32);
    }
    s
}

#[test]
fn rotation_is_equivariant() {
    let mut rng = Rng::new(5);
    for _ in 0..10 {
        let f = random_sh(&mut rng);
        let axis = rng.dir();
        let angle = 2.0 * PI * rng.next();
        let r = axis_angle_matrix(axis, angle);
        let g = f.rotated(&ShRotation::new(4, r));
        for _ in 0..20 {
            let w = rng.dir();
            let a = g.eval(f32v(mat_vec(&r, w)));
            let b = f.eval(f32v(w));
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() < 1e-4, "{a:?} vs {b:?}");
            }
        }
    }
}

#[test]
fn rotation_about_z_closed_form_matches_the_general_rotation() {
    let mut rng = Rng::new(6);
    let f = random_sh(&mut rng);
    for angle in [0.3, -1.2, PI, 5.0] {
        let general = f.rotated(&ShRotation::from_axis_angle(4, [0.0, 0.0, 1.0], angle));
        let closed = f.rotated_z(angle);
        for i in 0..16 {
            for k in 0..3 {
                assert!((general.coeffs[i][k] - closed.coeffs[i][k]).abs() < 1e-5);
            }
        }
        // Rotating about Z moves φ by the angle: compare with evaluation at the turned direction.
        let w = rng.dir();
        let (s, c) = angle.sin_cos();
        let rw = [c * w[0] - s * w[1], s * w[0] + c * w[1], w[2]];
        let (a, b) = (closed.eval(f32v(rw)), f.eval(f32v(w)));
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-4));
    }
}

#[test]
fn rotation_preserves_band_energy_and_composes() {
    let mut rng = Rng::new(7);
    let f = random_sh(&mut rng);
    let r1 = axis_angle_matrix(rng.dir(), 0.7);
    let r2 = axis_angle_matrix(rng.dir(), -2.1);
    let mut r12 = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r12[i][j] = (0..3).map(|k| r2[i][k] * r1[k][j]).sum();
        }
    }
    let two_steps = f
        .rotated(&ShRotation::new(4, r1))
        .rotated(&ShRotation::new(4, r2));
    let one_step = f.rotated(&ShRotation::new(4, r12));
    for l in 0..4 {
        let energy = |s: &ShRadiance| -> f32 {
            (l * l..(l + 1) * (l + 1))
                .map(|i| s.coeffs[i][0].powi(2))
                .sum()
        };
        assert!((energy(&f) - energy(&one_step)).abs() < 1e-4);
    }
    for i in 0..16 {
        for k in 0..3 {
            assert!((two_steps.coeffs[i][k] - one_step.coeffs[i][k]).abs() < 1e-5);
        }
    }
}

#[test]
fn latlong_and_cube_projections_agree() {
    let sky = |d: [f64; 3]| {
        let v = (1.0 + d[2]).powi(2) as f32 + 0.2 * d[0] as f32;
        [v, 0.5 * v, 2.0]
    };
    let cube = CubeMap::from_fn(64, sky);
    let (w, h) = (256, 128);
    let pixels = (0..w * h)
        .map(|i| {
            sky(cube::latlong_direction(
                (i % w) as f64 + 0.5,
                (i / w) as f64 + 0.5,
                w as u32,
                h as u32,
            ))
        })
        .collect();
    let img = FloatImage {
        width: w as u32,
        height: h as u32,
        pixels,
    };
    let (a, b) = (project_cube(&cube), project_latlong(&img));
    for i in 0..16 {
        for k in 0..3 {
            assert!((a.coeffs[i][k] - b.coeffs[i][k]).abs() < 2e-3, "{i} {k}");
        }
    }
}

#[test]
fn projection_is_deterministic_across_thread_counts() {
    let cube = CubeMap::from_fn(48, |d| [(d[0] * 3.0).sin() as f32, d[2] as f32, 1.0]);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| project_cube(&cube))
    };
    let (a, b) = (run(1), run(4));
    let bits = |s: &ShRadiance| {
        s.coeffs
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a), bits(&b));
}

#[test]
fn gauss_legendre_integrates_polynomials_exactly() {
    let q = gauss_legendre(5);
    // ∫_{-1}^{1} x^8 dx = 2/9 (degree 8 ≤ 2·5 − 1).
    let got: f64 = q.iter().map(|(x, w)| w * x.powi(8)).sum();
    assert!((got - 2.0 / 9.0).abs() < 1e-14);
    let total: f64 = q.iter().map(|(_, w)| w).sum();
    assert!((total - 2.0).abs() < 1e-14);
}

#[test]
fn separable_latlong_projection_matches_the_per_pixel_sum_and_the_exact_integral() {
    let (w, h) = (128u32, 64u32);
    let mut rng = Rng::new(9);
    let pixels = (0..w * h)
        .map(|_| [rng.next() as f32, rng.next() as f32 * 3.0, 1.0])
        .collect();
    let img = FloatImage {
        width: w,
        height: h,
        pixels,
    };
    let (fast, slow) = (project_latlong(&img), project_latlong_reference(&img));
    let exact = project_latlong_exact(&img);
    for i in 0..16 {
        for k in 0..3 {
            assert!(
                (fast.coeffs[i][k] - slow.coeffs[i][k]).abs() < 1e-4,
                "{i} {k}"
            );
            // Midpoint vs exact pixel integrals: O(Δ²) apart on noise.
            assert!(
                (fast.coeffs[i][k] - exact.coeffs[i][k]).abs() < 5e-3,
                "{i} {k}"
            );
        }
    }
    // A constant image: the exact projection gives 2√π·L to rounding.
    let ones = FloatImage {
        width: 16,
        height: 8,
        pixels: vec![[1.0; 3]; 128],
    };
    let e = project_latlong_exact(&ones);
    assert!((e.coeffs[0][0] as f64 - 2.0 * PI.sqrt()).abs() < 1e-6);
    assert!(e.coeffs[1..].iter().flatten().all(|v| v.abs() < 1e-6));
}
