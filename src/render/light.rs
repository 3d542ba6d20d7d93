//! The light of the preview renderer: the sky as a lat-long radiance image (from the pack, or an
//! analytic gradient when the pack has none), a directional sun and a sky ambient term.
//!
//! Shading (shaders/common.wgsl, `shade_lambert`), for albedo ρ and unit normal n:
//! `L = ρ/π · (E_sun · max(n·s, 0) + E_sky · (1 + n_z)/2)`, where E_sky is the irradiance the sky
//! gives a horizontal surface, `∫ L(ω) cos θ dω` over the upper hemisphere, and (1 + n_z)/2 the
//! fraction of the sky a tilted surface sees (ground bounce ignored). Later issues replace this
//! with PRT, a Schlick BRDF and shadows.
//!
//! Lat-long convention (docs/CONVENTIONS.md): d = (sin θ cos φ, sin θ sin φ, cos θ), pixel
//! (i, j) of a W×H image has u = (i + 0.5)/W = φ/2π and v = (j + 0.5)/H = θ/π; row 0 is the zenith.

use glam::Vec3;
use std::f32::consts::PI;

/// Sun and ambient light, in linear RGB irradiance (W/m² per channel, or the sky's own units).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Lighting {
    /// Unit vector towards the sun.
    pub sun_direction: [f32; 3],
    /// Irradiance of a surface facing the sun.
    pub sun_irradiance: [f32; 3],
    /// Irradiance of a horizontal surface from the sky.
    pub ambient: [f32; 3],
    /// Solid angle (sr) of the sun's disc drawn in the sky background at `sun_direction` with
    /// radiance `sun_irradiance / sun_solid_angle`: the sky stage's removed texels, so the
    /// sun-free cube plus the disc hold the map's energy. 0: no disc (a sky that still holds
    /// its sun, or none).
    pub sun_solid_angle: f32,
}

/// Ratio of direct sun to sky irradiance used when the pack does not say (a clear day gives 3–6).
pub const SUN_TO_SKY_RATIO: f32 = 4.0;
/// Default sun: elevation 45°, azimuth φ = 225° (from the south-west), for skies without a sun.
pub const DEFAULT_SUN_ELEVATION_DEG: f32 = 45.0;
pub const DEFAULT_SUN_AZIMUTH_DEG: f32 = 225.0;

/// Direction of lat-long pixel centre (i, j).
pub fn latlong_direction(i: u32, j: u32, width: u32, height: u32) -> Vec3 {
    let phi = (i as f32 + 0.5) / width as f32 * 2.0 * PI;
    let theta = (j as f32 + 0.5) / height as f32 * PI;
    Vec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

/// Direction from azimuth φ (degrees, from +X towards +Y) and elevation (degrees above horizon).
pub fn direction_from_angles(azimuth_deg: f32, elevation_deg: f32) -> Vec3 {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
}

/// The built-in sky: a blue zenith fading to a pale horizon, a dark ground below. A `width`×`height`
/// lat-long image of RGBA texels (alpha 1), radiance of order 1.
pub fn analytic_sky(width: u32, height: u32) -> Vec<[f32; 4]> {
    let zenith = Vec3::new(0.25, 0.45, 0.95);
    let horizon = Vec3::new(0.85, 0.9, 1.0);
    let ground = Vec3::new(0.18, 0.16, 0.13);
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for j in 0..height {
        for i in 0..width {
            let z = latlong_direction(i, j, width, height).z;
            let c = if z >= 0.0 {
                horizon.lerp(zenith, z.sqrt())
            } else {
                horizon.lerp(ground, (-z * 8.0).min(1.0))
            };
            out.push([c.x, c.y, c.z, 1.0]);
        }
    }
    out
}

/// Solid angle of one texel of row `j` of a `width`×`height` lat-long image (exact):
/// `(2π/W)(cos θ0 − cos θ1)` for the row's θ range.
pub fn texel_solid_angle(j: u32, width: u32, height: u32) -> f64 {
    let pi = std::f64::consts::PI;
    let (t0, t1) = (
        j as f64 / height as f64 * pi,
        (j + 1) as f64 / height as f64 * pi,
    );
    std::f64::consts::TAU / width as f64 * (t0.cos() - t1.cos())
}

/// `∫ cos θ dω` over one texel of row `j`, upper hemisphere only (exact):
/// `(2π/W) · (sin²θ1 − sin²θ0)/2` with θ clamped to the horizon.
pub fn texel_cosine_weight(j: u32, width: u32, height: u32) -> f64 {
    let (pi, half) = (std::f64::consts::PI, std::f64::consts::FRAC_PI_2);
    let t0 = (j as f64 / height as f64 * pi).min(half);
    let t1 = ((j + 1) as f64 / height as f64 * pi).min(half);
    std::f64::consts::TAU / width as f64 * (t1.sin().powi(2) - t0.sin().powi(2)) / 2.0
}

/// Irradiance of a horizontal surface from the upper hemisphere, `∫ L cos θ dω`, each row's
/// integral taken exactly ([`texel_cosine_weight`]); rows below the horizon count zero.
pub fn sky_irradiance(texels: &[[f32; 4]], width: u32, height: u32) -> [f32; 3] {
    let mut sum = [0.0f64; 3];
    for j in 0..height {
        let w = texel_cosine_weight(j, width, height);
        if w <= 0.0 {
            continue;
        }
        for t in &texels[(j * width) as usize..((j + 1) * width) as usize] {
            for c in 0..3 {
                sum[c] += t[c] as f64 * w;
            }
        }
    }
    sum.map(|s| s as f32)
}

/// A texel brighter than this many times the sky's mean luminance belongs to the sun (a clear
/// sky's sun is 10⁴–10⁵ times brighter than the sky; the brightest sky near it a few times).
pub const SUN_THRESHOLD: f32 = 20.0;

/// The sun found in a lat-long sky.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkySun {
    /// Unit vector: the energy-weighted centroid of the sun texels' excess.
    pub direction: Vec3,
    /// `Σ (T_i − R) ω_i` over the sun texels, R the mean radiance of the rest of the sky.
    pub irradiance: [f32; 3],
    /// Irradiance of a horizontal surface from the sky with the sun texels replaced by R.
    pub sky: [f32; 3],
    pub texels: u32,
}

/// Separates the sun from a lat-long sky: texels above the horizon brighter than
/// [`SUN_THRESHOLD`] × the mean luminance. `None` when there is no such texel (overcast).
/// The preview's own quick split; the `sky` stage does the careful one on the cube map.
pub fn split_sun(texels: &[[f32; 4]], width: u32, height: u32) -> Option<SkySun> {
    let upper = height.div_ceil(2);
    let row = |j: u32| &texels[(j * width) as usize..((j + 1) * width) as usize];
    let (mut lum, mut omega) = (0.0f64, 0.0f64);
    for j in 0..upper {
        let w = texel_solid_angle(j, width, height);
        lum += row(j).iter().map(|t| luminance(t) as f64 * w).sum::<f64>();
        omega += w * width as f64;
    }
    let threshold = (lum / omega) as f32 * SUN_THRESHOLD;
    let is_sun = |t: &[f32; 4]| luminance(t) > threshold;
    // R: mean radiance of the non-sun upper hemisphere.
    let (mut rest, mut rest_omega, mut n) = ([0.0f64; 3], 0.0f64, 0u32);
    for j in 0..upper {
        let w = texel_solid_angle(j, width, height);
        for t in row(j) {
            if is_sun(t) {
                n += 1;
            } else {
                (0..3).for_each(|c| rest[c] += t[c] as f64 * w);
                rest_omega += w;
            }
        }
    }
    if n == 0 || !threshold.is_finite() {
        return None;
    }
    let r = rest.map(|v| (v / rest_omega.max(1e-12)) as f32);
    let (mut irr, mut centroid, mut sky) = ([0.0f64; 3], glam::DVec3::ZERO, [0.0f64; 3]);
    for j in 0..upper {
        let (w, wc) = (
            texel_solid_angle(j, width, height),
            texel_cosine_weight(j, width, height),
        );
        for (i, t) in row(j).iter().enumerate() {
            let seen = if is_sun(t) {
                [r[0], r[1], r[2], 1.0]
            } else {
                *t
            };
            (0..3).for_each(|c| sky[c] += seen[c] as f64 * wc);
            if is_sun(t) {
                let excess = [t[0] - r[0], t[1] - r[1], t[2] - r[2]];
                (0..3).for_each(|c| irr[c] += excess[c].max(0.0) as f64 * w);
                let d = latlong_direction(i as u32, j, width, height).as_dvec3();
                centroid += d * (luminance(excess).max(0.0) as f64 * w);
            }
        }
    }
    Some(SkySun {
        direction: centroid.normalize_or(glam::DVec3::Z).as_vec3(),
        irradiance: irr.map(|v| v as f32),
        sky: sky.map(|v| v as f32),
        texels: n,
    })
}

use crate::color::luminance;

/// The default light. A pack's sky: the sun split from it ([`split_sun`]) and the sun-free sky
/// as ambient; no sun found (overcast) means ambient only. The analytic sky (`analytic`): its
/// irradiance as ambient and a white sun of [`SUN_TO_SKY_RATIO`] times that from the default
/// direction.
pub fn default_lighting(texels: &[[f32; 4]], width: u32, height: u32, analytic: bool) -> Lighting {
    let default_dir = direction_from_angles(DEFAULT_SUN_AZIMUTH_DEG, DEFAULT_SUN_ELEVATION_DEG);
    if analytic {
        let ambient = sky_irradiance(texels, width, height);
        let e = luminance(ambient) * SUN_TO_SKY_RATIO;
        return Lighting {
            sun_direction: default_dir.to_array(),
            sun_irradiance: [e; 3],
            ambient,
            sun_solid_angle: 0.0,
        };
    }
    match split_sun(texels, width, height) {
        Some(sun) => Lighting {
            sun_direction: sun.direction.to_array(),
            sun_irradiance: sun.irradiance,
            ambient: sun.sky,
            sun_solid_angle: 0.0,
        },
        None => Lighting {
            sun_direction: default_dir.to_array(),
            sun_irradiance: [0.0; 3],
            ambient: sky_irradiance(texels, width, height),
            sun_solid_angle: 0.0,
        },
    }
}

/// Exposure that maps an 18 % grey card facing the sun to 0.5 before gamma:
/// `1 − exp(−L·s) = 0.5` with `L = 0.18 (E_sun + E_sky)/π`.
pub fn auto_exposure(light: &Lighting) -> f32 {
    let e = luminance(light.sun_irradiance) + luminance(light.ambient);
    let l = 0.18 * e / PI;
    if l > 0.0 && l.is_finite() {
        std::f32::consts::LN_2 / l
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_sky_gives_pi_times_radiance() {
        // A uniform upper hemisphere of radiance L gives E = π L on a horizontal surface.
        for (w, h) in [(8u32, 4u32), (64, 32), (33, 17)] {
            let texels = vec![[2.0f32, 1.0, 0.5, 1.0]; (w * h) as usize];
            let e = sky_irradiance(&texels, w, h);
            for (c, l) in e.iter().zip([2.0f32, 1.0, 0.5]) {
                assert!((c - PI * l).abs() < 1e-4 * PI * l, "{w}×{h}: {e:?}");
            }
        }
    }

    #[test]
    fn texel_solid_angles_sum_to_the_sphere() {
        let (w, h) = (40u32, 20u32);
        let total: f64 = (0..h).map(|j| texel_solid_angle(j, w, h) * w as f64).sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-9);
    }

    #[test]
    fn the_sun_is_split_from_a_uniform_sky() {
        // Sky radiance 0.5 everywhere, two sun texels of 1000 in row 3 (columns 5 and 6).
        let (w, h) = (32u32, 16u32);
        let mut texels = vec![[0.5f32, 0.5, 0.5, 1.0]; (w * h) as usize];
        texels[(3 * w + 5) as usize] = [1000.0, 900.0, 800.0, 1.0];
        texels[(3 * w + 6) as usize] = [1000.0, 900.0, 800.0, 1.0];
        let sun = split_sun(&texels, w, h).unwrap();
        assert_eq!(sun.texels, 2);
        // Excess over the sky (0.5) times two texels' solid angle, the row θ ∈ [3π/16, 4π/16].
        let omega =
            2.0 * PI as f64 / 32.0 * ((3.0 * PI as f64 / 16.0).cos() - (PI as f64 / 4.0).cos());
        let want = [999.5, 899.5, 799.5].map(|x: f64| (x * 2.0 * omega) as f32);
        for (c, w) in want.iter().enumerate() {
            assert!(
                (sun.irradiance[c] - w).abs() < 1e-3 * w,
                "{:?}",
                sun.irradiance
            );
        }
        // Equal excess: the centroid of the two texel centres (θ = 3.5π/16, φ = 5.5 and 6.5 ×
        // 2π/32), which lies at φ = 6 × 2π/32.
        let at = |phi: f32| {
            let theta = 3.5 * PI / 16.0;
            Vec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            )
        };
        let d = (at(5.5 * 2.0 * PI / 32.0) + at(6.5 * 2.0 * PI / 32.0)).normalize();
        assert!((sun.direction - d).length() < 1e-5, "{}", sun.direction);
        let phi = sun.direction.y.atan2(sun.direction.x);
        assert!((phi - 6.0 * 2.0 * PI / 32.0).abs() < 1e-5);
        // With the sun replaced by the sky's 0.5, the ambient is π · 0.5.
        assert!(
            sun.sky.iter().all(|&e| (e - 0.5 * PI).abs() < 1e-4),
            "{:?}",
            sun.sky
        );
    }

    #[test]
    fn an_overcast_sky_has_no_sun() {
        let (w, h) = (32u32, 16u32);
        let texels: Vec<[f32; 4]> = (0..w * h)
            .map(|k| {
                let z = latlong_direction(k % w, k / w, w, h).z.max(0.0);
                [0.3 + 0.7 * z, 0.3 + 0.7 * z, 0.35 + 0.7 * z, 1.0]
            })
            .collect();
        assert!(split_sun(&texels, w, h).is_none());
        let l = default_lighting(&texels, w, h, false);
        assert_eq!(l.sun_irradiance, [0.0; 3]);
    }

    #[test]
    fn auto_exposure_maps_grey_card_to_half() {
        let l = Lighting {
            sun_direction: [0.0, 0.0, 1.0],
            sun_irradiance: [3.0; 3],
            ambient: [1.0; 3],
            sun_solid_angle: 0.0,
        };
        let s = auto_exposure(&l);
        let grey = 0.18 * 4.0 / PI;
        assert!((1.0 - (-grey * s).exp() - 0.5).abs() < 1e-5);
    }
}
