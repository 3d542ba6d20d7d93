//! Sun extraction against injected suns of known direction and irradiance.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use super::*;
use std::f64::consts::PI;

fn smooth_sky(d: [f64; 3]) -> [f32; 3] {
    let v = 0.5 + 0.3 * d[2] + 0.1 * d[0];
    [v as f32, (0.8 * v) as f32, (1.2 * v) as f32]
}

fn angle(a: [f64; 3], b: [f32; 3]) -> f64 {
    let dot = a[0] * b[0] as f64 + a[1] * b[1] as f64 + a[2] * b[2] as f64;
    dot.clamp(-1.0, 1.0).acos()
}

/// Angular size of the texel the direction falls on: √ω.
fn texel_angle_at(size: u32, d: [f64; 3]) -> f64 {
    let (face, s, t) = cube::face_coords(d);
    let _ = face;
    let n = size as f64;
    let col = (((s + 1.0) * 0.5 * n).floor()).clamp(0.0, n - 1.0) as u32;
    let row = (((t + 1.0) * 0.5 * n).floor()).clamp(0.0, n - 1.0) as u32;
    cube::texel_solid_angle(size, col, row).sqrt()
}

#[test]
fn injected_sun_is_recovered_in_direction_and_irradiance() {
    let size = 256;
    let r = SUN_ANGULAR_RADIUS;
    let u = 0.6;
    let e_sun = 3.0; // irradiance at normal incidence (sky's horizontal irradiance is ≈ 2.2)
    // Disc with linear limb darkening: E = L0 · π r² (1 − u/3) (small-angle disc).
    let l0 = (e_sun / (PI * r * r * (1.0 - u / 3.0))) as f32;
    let positions = [
        ("face centre", [0.0, 0.0, 1.0]),
        ("generic", [0.3, -0.5, 0.6]),
        ("low", [0.9, 0.3, 0.08]),
        ("edge +X/+Z", [1.0, 0.2, 1.0]),
        ("edge +Y/-X", [-1.0, 1.0, 0.3]),
        ("corner +X+Y+Z", [1.0, 1.0, 1.0]),
        ("near corner", [1.0, 0.999, 1.001]),
    ];
    for (name, d) in positions {
        let dir = cube::normalize(d);
        let mut c = CubeMap::from_fn(size, smooth_sky);
        let added = add_sun_disc(&mut c, dir, r, [l0, 0.5 * l0, 0.25 * l0], u, 48);
        // The injection itself against the analytic disc irradiance.
        assert!(
            (added[0] - e_sun).abs() < 0.005 * e_sun,
            "{name}: injected {added:?}"
        );
        let (_, sun) = extract_sun(&c, &SunOptions::default());
        let tol = 0.5 * texel_angle_at(size, dir);
        let err = angle(dir, sun.direction);
        assert!(
            err < tol,
            "{name}: direction off by {err} rad (half a texel {tol})"
        );
        for (k, &add) in added.iter().enumerate() {
            let rel = (sun.irradiance[k] as f64 - add).abs() / add;
            assert!(
                rel < 0.01,
                "{name}: channel {k}: {} vs {}",
                sun.irradiance[k],
                added[k]
            );
        }
        assert!(!sun.clipped, "{name}: a limb-darkened disc is not clipped");
    }
}

#[test]
fn thesis_sun_undercounts_by_about_the_enlargement() {
    let size = 256;
    let dir = cube::normalize([0.2, 0.1, 1.0]);
    let mut c = CubeMap::from_fn(size, smooth_sky);
    let l0 = 1.0e5f32;
    add_sun_disc(&mut c, dir, SUN_ANGULAR_RADIUS, [l0; 3], 0.0, 32);
    let (_, sun) = extract_sun(&c, &SunOptions::default());
    // I_S(thesis) = mean excess · a, I_S = Σ excess ω ≈ mean excess · n·ω̄ = mean excess · 4a.
    let ratio = sun.irradiance[0] / sun.irradiance_thesis[0];
    let expect = (sun.solid_angle / (PI * SUN_ANGULAR_RADIUS.powi(2))) as f32;
    assert!(
        (ratio - expect).abs() < 0.05 * expect,
        "{ratio} vs {expect}"
    );
    assert!((4.0..4.5).contains(&expect), "{expect}");
}

#[test]
fn extraction_conserves_energy_and_leaves_a_continuous_sky() {
    let size = 128;
    let dir = cube::normalize([-0.4, 0.7, 0.5]);
    let mut c = CubeMap::from_fn(size, smooth_sky);
    add_sun_disc(&mut c, dir, SUN_ANGULAR_RADIUS, [2.0e5; 3], 0.5, 32);
    let (free, sun) = extract_sun(&c, &SunOptions::default());
    let omega = cube::solid_angle_table(size);
    let total = |m: &CubeMap| -> f64 {
        m.texels
            .iter()
            .enumerate()
            .map(|(i, t)| t[0] as f64 * omega[i % omega.len()])
            .sum()
    };
    let (before, after) = (total(&c), total(&free));
    assert!((before - after - sun.irradiance[0] as f64).abs() < 1e-5 * before);
    // No texel of the sun-free sky stands out: the largest is within 2% of the smooth sky's.
    let sky_max = CubeMap::from_fn(size, smooth_sky)
        .texels
        .iter()
        .map(|t| t[0])
        .fold(0.0f32, f32::max);
    let free_max = free.texels.iter().map(|t| t[0]).fold(0.0f32, f32::max);
    assert!(free_max <= sky_max * 1.02, "{free_max} vs {sky_max}");
}

#[test]
fn overcast_sky_gives_a_negligible_sun() {
    // CIE standard overcast sky: L(θ) = Lz (1 + 2 cos θ) / 3, dark ground.
    let c = CubeMap::from_fn(128, |d| {
        let v = if d[2] > 0.0 {
            (1.0 + 2.0 * d[2]) / 3.0
        } else {
            0.05
        };
        [v as f32; 3]
    });
    let (free, sun) = extract_sun(&c, &SunOptions::default());
    let sky = sky_irradiance(&free);
    assert!(
        sun.irradiance[1] < 0.01 * sky.horizontal[1],
        "sun {} vs sky {}",
        sun.irradiance[1],
        sky.horizontal[1]
    );
    assert!(sun.irradiance[1] >= 0.0);
}

#[test]
fn clipped_sun_is_reported() {
    let size = 128;
    let dir = cube::normalize([0.1, 0.3, 1.0]);
    let mut c = CubeMap::from_fn(size, smooth_sky);
    add_sun_disc(&mut c, dir, 5.0 * SUN_ANGULAR_RADIUS, [1.0e4; 3], 0.5, 16);
    let (_, unclipped) = extract_sun(&c, &SunOptions::default());
    assert!(!unclipped.clipped);
    // Saturate like a sensor: everything above a level becomes that level.
    for t in c.texels.iter_mut() {
        *t = t.map(|v| v.min(3000.0));
    }
    let (_, sun) = extract_sun(&c, &SunOptions::default());
    assert!(sun.clipped, "plateau of {} texels", sun.plateau_texels);
    assert!(sun.irradiance[0] < unclipped.irradiance[0]);
}

#[test]
fn sky_irradiance_matches_analytic_integrals() {
    // L = 1 + z on the upper hemisphere: ∫ (1 + z) z dω = π + 2π/3; the thesis' mean × 2π is
    // the texel-count mean, biased towards the face corners' many small texels.
    let c = CubeMap::from_fn(128, |d| [(1.0 + d[2]) as f32, 1.0, 0.0]);
    let s = sky_irradiance(&c);
    let exact = PI + 2.0 * PI / 3.0;
    assert!(
        (s.horizontal[0] as f64 - exact).abs() < 0.01 * exact,
        "{}",
        s.horizontal[0]
    );
    assert!((s.horizontal[1] as f64 - PI).abs() < 0.01 * PI);
    assert!((s.thesis[1] as f64 - 2.0 * PI).abs() < 1e-4);
}

#[test]
fn enlargement_changes_the_covered_area() {
    let size = 256;
    let mut c = CubeMap::from_fn(size, smooth_sky);
    // A faint sun (50× the sky), so only the area rule decides, not the contrast rule.
    add_sun_disc(
        &mut c,
        [0.0, 0.0, 1.0],
        SUN_ANGULAR_RADIUS,
        [25.0; 3],
        0.0,
        16,
    );
    let a = PI * SUN_ANGULAR_RADIUS.powi(2);
    for f in [1.0, 4.0, 16.0] {
        let (_, sun) = extract_sun(&c, &SunOptions { enlargement: f });
        assert!(sun.solid_angle >= f * a, "{f}: {}", sun.solid_angle);
        let one_more = sun.solid_angle - cube::texel_solid_angle(size, 128, 128);
        assert!(one_more < f * a, "{f}: covers more than needed");
    }
}

#[test]
fn a_sun_larger_than_the_enlarged_disc_is_taken_whole() {
    // A painted sun of 6× the true radius (like low-resolution or blurred HDRIs).
    let size = 128;
    let dir = cube::normalize([0.3, 0.2, 0.9]);
    let clean = CubeMap::from_fn(size, smooth_sky);
    let mut c = clean.clone();
    let added = add_sun_disc(&mut c, dir, 6.0 * SUN_ANGULAR_RADIUS, [2.0e4; 3], 0.0, 16);
    let (free, sun) = extract_sun(&c, &SunOptions::default());
    assert!(sun.solid_angle > 10.0 * PI * SUN_ANGULAR_RADIUS.powi(2));
    let rel = (sun.irradiance[0] as f64 - added[0]).abs() / added[0];
    assert!(rel < 0.01, "{} vs {}", sun.irradiance[0], added[0]);
    let (e_free, e_clean) = (sky_irradiance(&free), sky_irradiance(&clean));
    let rel = (e_free.horizontal[0] - e_clean.horizontal[0]).abs() / e_clean.horizontal[0];
    assert!(
        rel < 0.01,
        "sky {} vs {}",
        e_free.horizontal[0],
        e_clean.horizontal[0]
    );
}
