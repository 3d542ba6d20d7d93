//! Real spherical harmonics: basis evaluation, projection of cube maps and lat-long images with
//! exact solid angles, rotation, and the clamped-cosine convolution that turns radiance into
//! irradiance. Used by the sky, PRT and the per-instance environment maps.
//!
//! # Convention (seed 000, eqs. 2.18–2.23; docs/CONVENTIONS.md)
//!
//! Real, orthonormal (`∫_S y_i y_j dω = δ_ij`), with the Condon–Shortley phase inside the
//! associated Legendre polynomials:
//!
//! ```text
//! P_0^0 = 1,  P_m^m = (−1)^m (2m−1)!! (1−x²)^{m/2},  P_{m+1}^m = x (2m+1) P_m^m,
//! (l−m) P_l^m = x (2l−1) P_{l−1}^m − (l+m−1) P_{l−2}^m
//! y_l^m = √2 K_l^m cos(mφ) P_l^m(cos θ)     m > 0
//!       = √2 K_l^m sin(−mφ) P_l^{−m}(cos θ) m < 0
//!       = K_l^0 P_l^0(cos θ)                m = 0
//! K_l^m = sqrt((2l+1)(l−|m|)! / (4π (l+|m|)!))
//! ```
//!
//! with `d = (sin θ cos φ, sin θ sin φ, cos θ)` (Z up). Coefficient index `i = l(l+1) + m`
//! (0-based); "order n" means n bands, n² coefficients. So `y_1^1 = −√(3/4π)·x` (the phase makes
//! the odd-m functions negative towards +x / +y).
//!
//! Radiance and irradiance coefficients are different types ([`ShRadiance`], [`ShIrradiance`]):
//! the clamped-cosine convolution (Ramamoorthi & Hanrahan 2001) scales band l by `Â_l` (π, 2π/3,
//! π/4, 0, …) and the two must never be mixed.

use crate::cube::{self, CubeMap, Face};
use crate::model::FloatImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The project's order: 4 bands.
pub const ORDER: usize = 4;
/// Coefficients at [`ORDER`].
pub const COEFFS: usize = ORDER * ORDER;

/// Coefficient index of (l, m): `l(l+1) + m`.
pub const fn index(l: usize, m: i32) -> usize {
    ((l * (l + 1)) as isize + m as isize) as usize
}

/// Normalization `K_l^m` (eq. 2.23), for `m ≥ 0`.
fn k_lm(l: usize, m: usize) -> f64 {
    // (l−m)!/(l+m)! as a product, no factorial overflow for the orders used here.
    let ratio: f64 = ((l - m + 1)..=(l + m)).map(|k| 1.0 / k as f64).product();
    ((2 * l + 1) as f64 * ratio / (4.0 * PI)).sqrt()
}

/// Evaluates all `order²` basis functions at a unit direction into `out` (reference path, f64).
///
/// Uses `P_l^m(cos θ) = sin^m θ · Q_l^m(cos θ)` and `sin^m θ (cos mφ, sin mφ) = (x + iy)^m`, so it
/// needs no trigonometry and is exact at the poles.
pub fn eval_basis_into(order: usize, dir: [f64; 3], out: &mut [f64]) {
    assert!(out.len() >= order * order, "output holds order² values");
    let [x, y, z] = dir;
    let (mut cm, mut sm) = (1.0f64, 0.0f64); // Re, Im of (x + iy)^m
    let mut qmm = 1.0f64; // Q_m^m = (−1)^m (2m−1)!!
    for m in 0..order {
        if m > 0 {
            (cm, sm) = (cm * x - sm * y, cm * y + sm * x);
            qmm *= -((2 * m - 1) as f64);
        }
        let (mut q_prev, mut q) = (0.0, qmm); // Q_{l−1}^m, Q_l^m for l = m
        for l in m..order {
            if l == m + 1 {
                (q_prev, q) = (q, z * (2 * m + 1) as f64 * qmm);
            } else if l > m + 1 {
                let next =
                    (z * (2 * l - 1) as f64 * q - (l + m - 1) as f64 * q_prev) / (l - m) as f64;
                (q_prev, q) = (q, next);
            }
            let k = k_lm(l, m);
            if m == 0 {
                out[index(l, 0)] = k * q;
            } else {
                let s = std::f64::consts::SQRT_2 * k * q;
                out[index(l, m as i32)] = s * cm;
                out[index(l, -(m as i32))] = s * sm;
            }
        }
    }
}

/// All `order²` basis functions at a unit direction.
pub fn eval_basis(order: usize, dir: [f32; 3]) -> Vec<f32> {
    let mut out = vec![0.0f64; order * order];
    eval_basis_into(order, dir.map(f64::from), &mut out);
    out.into_iter().map(|v| v as f32).collect()
}

/// The 16 basis functions of order 4 at a unit direction (fast path, f32; the constants are the
/// K_l^m·P_l^m products of the reference path, which a test checks).
#[inline]
pub fn eval_basis16(d: [f32; 3]) -> [f32; 16] {
    let [x, y, z] = d;
    let (x2, y2, z2) = (x * x, y * y, z * z);
    [
        0.282_094_8,
        -0.488_602_5 * y,
        0.488_602_5 * z,
        -0.488_602_5 * x,
        1.092_548_4 * x * y,
        -1.092_548_4 * y * z,
        0.315_391_57 * (3.0 * z2 - 1.0),
        -1.092_548_4 * x * z,
        0.546_274_2 * (x2 - y2),
        -0.590_043_6 * y * (3.0 * x2 - y2),
        2.890_611_4 * x * y * z,
        -0.457_045_8 * y * (5.0 * z2 - 1.0),
        0.373_176_33 * z * (5.0 * z2 - 3.0),
        -0.457_045_8 * x * (5.0 * z2 - 1.0),
        1.445_305_7 * z * (x2 - y2),
        -0.590_043_6 * x * (x2 - 3.0 * y2),
    ]
}

/// Clamped-cosine convolution factor `Â_l`: the irradiance `E(n) = ∫ L(ω) max(0, n·ω) dω` has
/// coefficients `Â_l · L_lm` (Ramamoorthi & Hanrahan 2001, eq. 8): π, 2π/3, π/4, 0, −π/24, 0, …
pub fn clamped_cosine_factor(l: usize) -> f64 {
    match l {
        0 => PI,
        1 => 2.0 * PI / 3.0,
        _ if l % 2 == 1 => 0.0,
        _ => {
            let half = l / 2;
            let sign = if half % 2 == 1 { 1.0 } else { -1.0 }; // (−1)^{l/2 − 1}
            let fact = |n: usize| (1..=n).map(|k| k as f64).product::<f64>();
            2.0 * PI * sign / ((l + 2) as f64 * (l - 1) as f64) * fact(l)
                / (2f64.powi(l as i32) * fact(half).powi(2))
        }
    }
}

/// Band of coefficient index `i`.
pub fn band_of(i: usize) -> usize {
    (i as f64).sqrt() as usize
}

/// Order-4 RGB radiance coefficients `L_i = ∫ L(ω) y_i(ω) dω`; evaluates to radiance.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ShRadiance {
    pub coeffs: [[f32; 3]; COEFFS],
}

/// Order-4 RGB irradiance coefficients `E_i = Â_l L_i`; evaluates to the irradiance a surface
/// with normal n receives, `E(n) = ∫ L(ω) max(0, n·ω) dω` (W/m² for L in W/(m² sr)).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ShIrradiance {
    pub coeffs: [[f32; 3]; COEFFS],
}

fn eval_rgb(coeffs: &[[f32; 3]; COEFFS], d: [f32; 3]) -> [f32; 3] {
    let b = eval_basis16(d);
    let mut out = [0.0f32; 3];
    for (c, bi) in coeffs.iter().zip(b) {
        for k in 0..3 {
            out[k] += c[k] * bi;
        }
    }
    out
}

impl ShRadiance {
    /// Radiance in unit direction `d` (band-limited reconstruction, eq. 2.26).
    pub fn eval(&self, d: [f32; 3]) -> [f32; 3] {
        eval_rgb(&self.coeffs, d)
    }

    /// Irradiance coefficients by the clamped-cosine convolution.
    pub fn to_irradiance(&self) -> ShIrradiance {
        let mut coeffs = self.coeffs;
        for (i, c) in coeffs.iter_mut().enumerate() {
            let a = clamped_cosine_factor(band_of(i)) as f32;
            *c = c.map(|v| v * a);
        }
        ShIrradiance { coeffs }
    }

    /// The function rotated by `rot`: the result at `R·ω` equals `self` at ω.
    pub fn rotated(&self, rot: &ShRotation) -> ShRadiance {
        assert_eq!(rot.order, ORDER);
        let mut coeffs = [[0.0; 3]; COEFFS];
        rot.apply_rgb(&self.coeffs, &mut coeffs);
        ShRadiance { coeffs }
    }

    /// The function rotated about +Z by `angle` radians (closed form).
    pub fn rotated_z(&self, angle: f64) -> ShRadiance {
        let mut coeffs = self.coeffs;
        rotate_z_in_place(ORDER, &mut coeffs, angle);
        ShRadiance { coeffs }
    }
}

impl ShIrradiance {
    /// Irradiance on a surface with unit normal `n`.
    pub fn eval(&self, n: [f32; 3]) -> [f32; 3] {
        eval_rgb(&self.coeffs, n)
    }

    /// Rotated about +Z by `angle` radians (irradiance rotates like radiance).
    pub fn rotated_z(&self, angle: f64) -> ShIrradiance {
        let mut coeffs = self.coeffs;
        rotate_z_in_place(ORDER, &mut coeffs, angle);
        ShIrradiance { coeffs }
    }
}

/// Rotates coefficients of any element type about +Z by `angle` (g(ω) = f(R_z(−angle)·ω)):
/// per band, the (cos mφ, sin mφ) pair turns by mα.
pub fn rotate_z_in_place<T: ShValue>(order: usize, coeffs: &mut [T], angle: f64) {
    for l in 1..order {
        for m in 1..=l as i32 {
            let (s, c) = (m as f64 * angle).sin_cos();
            let (ip, im) = (index(l, m), index(l, -m));
            let (a, b) = (coeffs[ip], coeffs[im]);
            coeffs[ip] = a.scale(c as f32).add(b.scale(-s as f32));
            coeffs[im] = a.scale(s as f32).add(b.scale(c as f32));
        }
    }
}

/// What an SH coefficient can be: a float or an RGB triple.
pub trait ShValue: Copy {
    fn scale(self, s: f32) -> Self;
    fn add(self, o: Self) -> Self;
}

impl ShValue for f32 {
    fn scale(self, s: f32) -> Self {
        self * s
    }
    fn add(self, o: Self) -> Self {
        self + o
    }
}

impl ShValue for [f32; 3] {
    fn scale(self, s: f32) -> Self {
        self.map(|v| v * s)
    }
    fn add(self, o: Self) -> Self {
        [self[0] + o[0], self[1] + o[1], self[2] + o[2]]
    }
}

/// Gauss–Legendre nodes and weights on [−1, 1] (Newton iteration on P_n; exact for polynomials
/// of degree ≤ 2n − 1).
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    (p0, p1) = (
                        p1,
                        ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64,
                    );
                }
                let p = if n == 0 { 1.0 } else { p1 };
                let p_prev = if n == 1 { 1.0 } else { p0 };
                dp = n as f64 * (x * p - p_prev) / (x * x - 1.0);
                let dx = p / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// A product quadrature on the sphere (Gauss–Legendre in z, uniform in φ): unit directions and
/// weights, exact for spherical polynomials of degree ≤ min(2·n_z − 1, n_phi − 1).
pub fn sphere_quadrature(n_z: usize, n_phi: usize) -> Vec<([f64; 3], f64)> {
    let mut out = Vec::with_capacity(n_z * n_phi);
    for (z, w) in gauss_legendre(n_z) {
        let r = (1.0 - z * z).max(0.0).sqrt();
        for j in 0..n_phi {
            let phi = 2.0 * PI * (j as f64 + 0.5) / n_phi as f64;
            out.push((
                [r * phi.cos(), r * phi.sin(), z],
                w * 2.0 * PI / n_phi as f64,
            ));
        }
    }
    out
}

/// Projects a scalar function with an exact quadrature of `n_z × n_phi` points (exact when f is
/// band-limited to degree ≤ min(2·n_z − 1, n_phi − 1) − (order − 1)).
pub fn project_quadrature(
    order: usize,
    f: impl Fn([f64; 3]) -> f64,
    n_z: usize,
    n_phi: usize,
) -> Vec<f64> {
    let mut out = vec![0.0; order * order];
    let mut basis = vec![0.0; order * order];
    for (d, w) in sphere_quadrature(n_z, n_phi) {
        eval_basis_into(order, d, &mut basis);
        let fw = f(d) * w;
        for (o, b) in out.iter_mut().zip(&basis) {
            *o += fw * b;
        }
    }
    out
}

/// The SH rotation of order `order` for a rotation matrix `r` (row-major, `v' = r·v`): block-
/// diagonal per band. Built by projecting the rotated basis with a quadrature that is exact for
/// products of two band-l functions (degree 2l), so the matrix is exact to rounding.
#[derive(Debug, Clone, PartialEq)]
pub struct ShRotation {
    pub order: usize,
    /// Block l is (2l+1)², row-major: `g_{l,m} = Σ_{m'} M[m][m'] f_{l,m'}`.
    blocks: Vec<Vec<f64>>,
}

impl ShRotation {
    /// The rotation of functions by `r`: `g(ω) = f(rᵀ·ω)`, so `g(r·ω) = f(ω)`.
    pub fn new(order: usize, r: [[f64; 3]; 3]) -> Self {
        let n = order * order;
        let quad = sphere_quadrature(order.max(1), (2 * order).max(1));
        let mut blocks: Vec<Vec<f64>> = (0..order).map(|l| vec![0.0; (2 * l + 1).pow(2)]).collect();
        let (mut b, mut br) = (vec![0.0; n], vec![0.0; n]);
        for (d, w) in quad {
            // rᵀ·d: the point the rotated function reads.
            let dr = [0, 1, 2].map(|k| r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2]);
            eval_basis_into(order, d, &mut b);
            eval_basis_into(order, dr, &mut br);
            for (l, block) in blocks.iter_mut().enumerate() {
                let (base, w2) = (l * l, 2 * l + 1);
                for i in 0..w2 {
                    for j in 0..w2 {
                        block[i * w2 + j] += w * b[base + i] * br[base + j];
                    }
                }
            }
        }
        ShRotation { order, blocks }
    }

    /// Rotation about `axis` (unit) by `angle` radians (right-hand rule).
    pub fn from_axis_angle(order: usize, axis: [f64; 3], angle: f64) -> Self {
        Self::new(order, axis_angle_matrix(axis, angle))
    }

    /// Applies the rotation to coefficients (`src` and `dst` hold order² values).
    pub fn apply<T: ShValue + Default>(&self, src: &[T], dst: &mut [T]) {
        for (l, block) in self.blocks.iter().enumerate() {
            let (base, w2) = (l * l, 2 * l + 1);
            for i in 0..w2 {
                let mut acc = T::default();
                for j in 0..w2 {
                    acc = acc.add(src[base + j].scale(block[i * w2 + j] as f32));
                }
                dst[base + i] = acc;
            }
        }
    }

    /// Applies the rotation to RGB coefficients.
    pub fn apply_rgb(&self, src: &[[f32; 3]], dst: &mut [[f32; 3]]) {
        self.apply(src, dst)
    }
}

/// Row-major rotation matrix about a unit axis (Rodrigues).
pub fn axis_angle_matrix(a: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    let [x, y, z] = a;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

/// Sums per-row partial sums in row order (deterministic whatever the thread count).
fn sum_rows(rows: Vec<[[f64; 3]; COEFFS]>) -> ShRadiance {
    let mut acc = [[0.0f64; 3]; COEFFS];
    for r in rows {
        for (a, v) in acc.iter_mut().zip(r) {
            for k in 0..3 {
                a[k] += v[k];
            }
        }
    }
    ShRadiance {
        coeffs: acc.map(|c| c.map(|v| v as f32)),
    }
}

/// Adds `value · basis(d) · weight` to a row's sum.
#[inline]
fn accumulate(row: &mut [[f64; 3]; COEFFS], d: [f32; 3], value: [f32; 3], weight: f64) {
    let b = eval_basis16(d);
    let v = value.map(|c| c as f64 * weight);
    for (r, bi) in row.iter_mut().zip(b) {
        let bi = bi as f64;
        r[0] += v[0] * bi;
        r[1] += v[1] * bi;
        r[2] += v[2] * bi;
    }
}

/// Projects a cube map to order 4: `L_i = Σ_texels L · y_i(centre) · ω_texel` with the exact
/// texel solid angles (so a constant map gives exactly `L00 = 2√π·L`).
pub fn project_cube(cube: &CubeMap) -> ShRadiance {
    project_cube_with(cube, &cube::solid_angle_table(cube.size))
}

/// [`project_cube`] with the cube's [`cube::solid_angle_table`] computed already.
pub(crate) fn project_cube_with(cube: &CubeMap, omega: &[f64]) -> ShRadiance {
    let n = cube.size as usize;
    let rows: Vec<_> = (0..6 * n)
        .into_par_iter()
        .map(|fr| {
            let (face, row) = (Face::ALL[fr / n], fr % n);
            let mut acc = [[0.0f64; 3]; COEFFS];
            for col in 0..n {
                let d = cube::texel_direction(cube.size, face, col as u32, row as u32);
                let v = cube.texels[fr * n + col];
                accumulate(&mut acc, d.map(|c| c as f32), v, omega[row * n + col]);
            }
            acc
        })
        .collect();
    sum_rows(rows)
}

/// Projects a lat-long image (docs/CONVENTIONS.md mapping) to order 4 with exact pixel solid
/// angles `Δφ (cos θ0 − cos θ1)`: the midpoint rule per pixel, computed separably (fast path).
///
/// With `y_lm(θ, φ) = y_lm(θ, 0)·cos(mφ)` and `y_{l,−m}(θ, φ) = y_lm(θ, 0)·sin(mφ)` (m > 0), each
/// row only needs the sums `Σ_col L·cos(mφ)` and `Σ_col L·sin(mφ)` for m < 4: 7 products per
/// pixel instead of 16. [`project_latlong_reference`] is the same sum texel by texel.
pub fn project_latlong(img: &FloatImage) -> ShRadiance {
    let (w, h) = (img.width as usize, img.height as usize);
    // cos(mφ), sin(mφ) per column, m = 0..3 (sin(0) omitted): 7 entries.
    let trig: Vec<[f64; 7]> = (0..w)
        .map(|col| {
            let phi = (col as f64 + 0.5) / w as f64 * 2.0 * PI;
            let (s1, c1) = phi.sin_cos();
            let (s2, c2) = (2.0 * phi).sin_cos();
            let (s3, c3) = (3.0 * phi).sin_cos();
            [1.0, c1, s1, c2, s2, c3, s3]
        })
        .collect();
    let rows: Vec<_> = (0..h)
        .into_par_iter()
        .map(|row| {
            let omega = cube::latlong_row_solid_angle(row as u32, img.width, img.height);
            let theta = (row as f64 + 0.5) / h as f64 * PI;
            let mut b = [0.0f64; COEFFS];
            eval_basis_into(ORDER, [theta.sin(), 0.0, theta.cos()], &mut b);
            let mut sums = [[0.0f64; 3]; 7];
            for (p, t) in img.pixels[row * w..(row + 1) * w].iter().zip(&trig) {
                let v = p.map(f64::from);
                for (s, &tk) in sums.iter_mut().zip(t) {
                    s[0] += v[0] * tk;
                    s[1] += v[1] * tk;
                    s[2] += v[2] * tk;
                }
            }
            let mut acc = [[0.0f64; 3]; COEFFS];
            for l in 0..ORDER {
                for m in 0..=l {
                    let f = omega * b[index(l, m as i32)];
                    let (c, s) = if m == 0 { (0, 0) } else { (2 * m - 1, 2 * m) };
                    for k in 0..3 {
                        acc[index(l, m as i32)][k] += f * sums[c][k];
                        if m > 0 {
                            acc[index(l, -(m as i32))][k] += f * sums[s][k];
                        }
                    }
                }
            }
            acc
        })
        .collect();
    sum_rows(rows)
}

/// The same sum as [`project_latlong`], pixel by pixel (reference path).
pub fn project_latlong_reference(img: &FloatImage) -> ShRadiance {
    let (w, h) = (img.width as usize, img.height as usize);
    let rows: Vec<_> = (0..h)
        .into_par_iter()
        .map(|row| {
            let omega = cube::latlong_row_solid_angle(row as u32, img.width, img.height);
            let theta = (row as f64 + 0.5) / h as f64 * PI;
            let (st, ct) = theta.sin_cos();
            let mut acc = [[0.0f64; 3]; COEFFS];
            for col in 0..w {
                let phi = (col as f64 + 0.5) / w as f64 * 2.0 * PI;
                let (sp, cp) = phi.sin_cos();
                let d = [(st * cp) as f32, (st * sp) as f32, ct as f32];
                accumulate(&mut acc, d, img.pixels[row * w + col], omega);
            }
            acc
        })
        .collect();
    sum_rows(rows)
}

/// The exact projection of the image read as piecewise constant per pixel:
/// `Σ_p L_p ∫_pixel y_i dω`, each pixel integral by a 4 × 4 Gauss–Legendre rule in (θ, φ)
/// (error ~ Δ⁸: exact to rounding at any practical resolution). Slow; the benchmarks' oracle.
pub fn project_latlong_exact(img: &FloatImage) -> ShRadiance {
    let (w, h) = (img.width as usize, img.height as usize);
    let gl = gauss_legendre(4);
    let (dphi, dtheta) = (2.0 * PI / w as f64, PI / h as f64);
    let rows: Vec<_> = (0..h)
        .into_par_iter()
        .map(|row| {
            let mut acc = [[0.0f64; 3]; COEFFS];
            let mut b = [0.0f64; COEFFS];
            for col in 0..w {
                let mut integral = [0.0f64; COEFFS];
                for &(u, wu) in &gl {
                    let theta = (row as f64 + 0.5 + 0.5 * u) * dtheta;
                    let (st, ct) = theta.sin_cos();
                    for &(v, wv) in &gl {
                        let phi = (col as f64 + 0.5 + 0.5 * v) * dphi;
                        eval_basis_into(ORDER, [st * phi.cos(), st * phi.sin(), ct], &mut b);
                        let wt = wu * wv * 0.25 * dtheta * dphi * st;
                        for (i, bi) in b.iter().enumerate() {
                            integral[i] += wt * bi;
                        }
                    }
                }
                let p = img.pixels[row * w + col];
                for (a, y) in acc.iter_mut().zip(integral) {
                    for k in 0..3 {
                        a[k] += p[k] as f64 * y;
                    }
                }
            }
            acc
        })
        .collect();
    sum_rows(rows)
}

#[cfg(test)]
mod tests;
