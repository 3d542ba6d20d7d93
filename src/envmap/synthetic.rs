//! Synthetic per-instance environment maps for benchmarks and tests: a smooth field from terrain
//! occlusion plus independent per-instance noise of a chosen level.
//!
//! The noise-free part is a cheap physical model of what `bake envmaps` computes, in the world
//! frame: from a probe 1 m above the terrain, the horizon of the heightfield in 16 azimuths
//! (marched out to ~170 m) hides the sky below it (a soft edge of ~11°, so that the maps vary
//! continuously with position); where the horizon hides the sky the probe sees the terrain, lit by
//! the sky (C_H) and by the sun (C_S, cosine with the local terrain normal). The maps are projected
//! on SH order 4 with a fixed set of 128 spherical Fibonacci directions. On top of it every
//! coefficient gets Gaussian noise with standard deviation `noise` × (RMS of all noise-free
//! coefficients), seeded per instance: a stand-in for the Monte-Carlo noise of traced maps and for
//! what the smooth model lacks (occlusion by neighbouring plants).

use super::section::{COEFFS, DIM};
use crate::rng::Rng;
use rayon::prelude::*;

/// Directions of the projection.
const DIRECTIONS: u32 = 128;
/// Horizon azimuths.
const AZIMUTHS: usize = 16;
/// Probe height above the terrain, metres.
const PROBE: f32 = 1.0;
/// Width of the soft horizon edge, radians.
const EDGE: f32 = 0.2;

/// The benchmark terrain's height at (x, y) (metres; the same hills as the traced bench scene).
pub fn bench_terrain_height(x: f32, y: f32) -> f32 {
    20.0 * (x * 0.01).sin() * (y * 0.013).cos() + 3.0 * (x * 0.07 + y * 0.05).sin()
}

/// Noise-free and noisy maps (`DIM` floats per instance, C_H then C_S, `[coefficient][rgb]`).
pub struct SyntheticMaps {
    pub truth: Vec<f32>,
    pub noisy: Vec<f32>,
}

/// Maps for instances at `positions` (x, y on the terrain `height`), noise level `noise`.
pub fn synthetic_envmaps(
    positions: &[[f32; 3]],
    height: &(dyn Fn(f32, f32) -> f32 + Sync),
    noise: f32,
    seed: u64,
) -> SyntheticMaps {
    let dirs: Vec<([f32; 3], [f32; 16])> = (0..DIRECTIONS)
        .map(|k| {
            let d = super::bake::fibonacci_direction(k, DIRECTIONS).to_array();
            (d, crate::sh::eval_basis16(d))
        })
        .collect();
    let truth: Vec<f32> = positions
        .par_iter()
        .flat_map_iter(|p| terrain_maps(*p, height, &dirs))
        .collect();
    let rms = super::cluster::rms_of(&truth);
    let sigma = noise * rms;
    let noisy = truth
        .par_chunks(DIM)
        .enumerate()
        .flat_map_iter(|(i, m)| {
            let mut rng = Rng::new(crate::trace::mix64(
                seed ^ (i as u64).wrapping_mul(0x9E37_79B9),
            ));
            m.iter()
                .map(|v| v + sigma * gauss(&mut rng))
                .collect::<Vec<f32>>()
        })
        .collect();
    SyntheticMaps { truth, noisy }
}

/// A standard normal deviate (Box–Muller).
fn gauss(rng: &mut Rng) -> f32 {
    let u1 = (rng.f32() as f64).max(1e-12);
    let u2 = rng.f32() as f64;
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// The noise-free maps of one probe.
fn terrain_maps(
    p: [f32; 3],
    height: &(dyn Fn(f32, f32) -> f32 + Sync),
    dirs: &[([f32; 3], [f32; 16])],
) -> [f32; DIM] {
    let horizon = horizon_angles(p[0], p[1], height);
    let (hx, hy) = (
        height(p[0] + 0.5, p[1]) - height(p[0] - 0.5, p[1]),
        height(p[0], p[1] + 0.5) - height(p[0], p[1] - 0.5),
    );
    let nl = (hx * hx + hy * hy + 1.0).sqrt();
    let normal = [-hx / nl, -hy / nl, 1.0 / nl];
    let sun = {
        let s = [0.4f32, 0.3, 0.85];
        let l = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
        s.map(|v| v / l)
    };
    let rho = [0.2f32, 0.25, 0.15];
    let sky = [0.25f32, 0.35, 0.6];
    // Ground radiance: Lambertian, lit by the sky (≈ π·mean sky radiance on the upper half of
    // its normal) and by the sun.
    let cos_sun = (normal[0] * sun[0] + normal[1] * sun[1] + normal[2] * sun[2]).max(0.0);
    let ground_h = [0, 1, 2].map(|c| rho[c] * sky[c] * (0.5 + 0.5 * normal[2]));
    let ground_s = [0, 1, 2].map(|c| rho[c] / std::f32::consts::PI * [3.0, 2.8, 2.5][c] * cos_sun);
    let w = 4.0 * std::f32::consts::PI / dirs.len() as f32;
    let mut out = [0.0f32; DIM];
    for (d, y) in dirs {
        let elev = d[2].clamp(-1.0, 1.0).asin();
        let az = d[1].atan2(d[0]).rem_euclid(std::f32::consts::TAU);
        let s = az / std::f32::consts::TAU * AZIMUTHS as f32;
        let (a0, f) = (s.floor() as usize % AZIMUTHS, s.fract());
        let h = horizon[a0] * (1.0 - f) + horizon[(a0 + 1) % AZIMUTHS] * f;
        let t = ((elev - h) / EDGE + 0.5).clamp(0.0, 1.0);
        let vis = t * t * (3.0 - 2.0 * t);
        let sky_l = 0.6 + 0.8 * d[2].max(0.0);
        for c in 0..3 {
            let lh = vis * sky[c] * sky_l + (1.0 - vis) * ground_h[c];
            let ls = (1.0 - vis) * ground_s[c];
            for (k, yk) in y.iter().enumerate() {
                out[k * 3 + c] += w * yk * lh;
                out[(COEFFS + k) * 3 + c] += w * yk * ls;
            }
        }
    }
    out
}

/// Elevation angle of the terrain's horizon seen from the probe above (x, y), per azimuth.
fn horizon_angles(x: f32, y: f32, height: &(dyn Fn(f32, f32) -> f32 + Sync)) -> [f32; AZIMUTHS] {
    let z0 = height(x, y) + PROBE;
    std::array::from_fn(|a| {
        let phi = a as f32 / AZIMUTHS as f32 * std::f32::consts::TAU;
        let (ux, uy) = (phi.cos(), phi.sin());
        let mut best = f32::NEG_INFINITY;
        let mut d = 1.5f32;
        for _ in 0..15 {
            best = best.max((height(x + d * ux, y + d * uy) - z0) / d);
            d *= 1.4;
        }
        best.atan()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_open_terrain_gives_the_projected_sky_and_noise_has_its_level() {
        let pos: Vec<[f32; 3]> = (0..400)
            .map(|i| [(i % 20) as f32 * 3.0, (i / 20) as f32 * 3.0, 0.0])
            .collect();
        let flat = |_: f32, _: f32| 0.0;
        let m = synthetic_envmaps(&pos, &flat, 0.02, 7);
        // On flat ground the horizon is at 0: band 0 of C_H is the sky's upper hemisphere plus the
        // ground's lower one, Y00 ∫ L dω; compare with an independent fine quadrature.
        let mut expect = [0.0f64; 3];
        let n = 2000;
        for i in 0..n {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let t = ((z.asin() as f32 / EDGE + 0.5).clamp(0.0, 1.0)) as f64;
            let vis = t * t * (3.0 - 2.0 * t);
            for c in 0..3 {
                let sky = [0.25, 0.35, 0.6][c] * (0.6 + 0.8 * z.max(0.0));
                let ground = [0.2, 0.25, 0.15][c] * [0.25, 0.35, 0.6][c];
                expect[c] +=
                    0.282_094_8 * (vis * sky + (1.0 - vis) * ground) * 4.0 * std::f64::consts::PI
                        / n as f64;
            }
        }
        for (c, e) in expect.iter().enumerate() {
            let got = m.truth[c] as f64;
            assert!((got - e).abs() < 0.02 * e, "{c}: {got} {e}");
        }
        // Every instance on flat ground sees the same maps.
        assert!(m.truth.chunks(DIM).all(|c| c == &m.truth[..DIM]));
        let rms = (m.truth.iter().map(|v| v * v).sum::<f32>() / m.truth.len() as f32).sqrt();
        let diff = (m
            .noisy
            .iter()
            .zip(&m.truth)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f32>()
            / m.truth.len() as f32)
            .sqrt();
        assert!((diff / rms / 0.02 - 1.0).abs() < 0.05, "{}", diff / rms);
    }

    #[test]
    fn a_valley_sees_less_sky_than_a_ridge() {
        let hills = |x: f32, _: f32| 20.0 * (x * 0.03).cos();
        let (ridge, valley) = (
            [0.0, 50.0, 20.0],
            [std::f32::consts::PI / 0.03, 50.0, -20.0],
        );
        let m = synthetic_envmaps(&[valley, ridge], &hills, 0.0, 1);
        // Band 0 blue of C_H (sky-dominated), and the sun's bounce C_S band 0 the other way.
        assert!(
            m.truth[2] < 0.9 * m.truth[DIM + 2],
            "{} {}",
            m.truth[2],
            m.truth[DIM + 2]
        );
        assert!(m.truth[COEFFS * 3] > m.truth[DIM + COEFFS * 3]);
        assert_eq!(m.truth, m.noisy);
    }
}
