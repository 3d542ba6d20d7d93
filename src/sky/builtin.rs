//! The built-in clear sky (Preetham, Shirley & Smits 1999, "A practical analytic model for
//! daylight"), used when a scene names no sky, so every scene bakes.
//!
//! The sky is the Perez distribution of luminance Y and chromaticity x, y with the paper's
//! turbidity fits (appendix A.2), converted xyY → XYZ → linear Rec. 709. Units are photometric:
//! luminance in kcd/m² (the paper's zenith formula), so the sun's and sky's irradiance come out in
//! klx. The sun is a disc of the true angular radius whose normal illuminance follows Meinel's
//! air-mass attenuation `133 klx · 0.7^(AM^0.678)` (AM by Kasten & Young 1989) and whose colour
//! reddens with a Rayleigh-like λ⁻⁴ optical depth (an approximation, normalized to luminance 1).
//! Below the horizon: a grey Lambertian ground of albedo 0.2 lit by sun and sky.

use super::cube::CubeMap;
use super::sun::{self, SUN_ANGULAR_RADIUS};
use std::f64::consts::PI;

/// Parameters of the built-in sky.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BuiltinSky {
    /// Sun elevation above the horizon, degrees (clamped to 0..90; Preetham's fits end there).
    pub sun_elevation_deg: f64,
    /// Sun azimuth, degrees counter-clockwise from +X (east) towards +Y (north).
    pub sun_azimuth_deg: f64,
    /// Atmospheric turbidity (2 = very clear, 3 = clear, 6 = hazy); the fits hold for 2..10.
    pub turbidity: f64,
    /// Albedo of the ground below the horizon.
    pub ground_albedo: f64,
    /// Texels per cube face edge.
    pub face_size: u32,
}

impl Default for BuiltinSky {
    /// A clear afternoon: sun 40° high in the south-west.
    fn default() -> Self {
        BuiltinSky {
            sun_elevation_deg: 40.0,
            sun_azimuth_deg: 225.0,
            turbidity: 3.0,
            ground_albedo: 0.2,
            face_size: 256,
        }
    }
}

impl BuiltinSky {
    /// Unit direction towards the sun (Z up).
    pub fn sun_direction(&self) -> [f64; 3] {
        let el = self.sun_elevation_deg.clamp(0.0, 90.0).to_radians();
        let az = self.sun_azimuth_deg.to_radians();
        [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()]
    }
}

/// Perez et al. luminance distribution `(1 + A e^{B / cos θ})(1 + C e^{D γ} + E cos² γ)`.
fn perez(c: &[f64; 5], cos_theta: f64, gamma: f64) -> f64 {
    let cos_g = gamma.cos();
    (1.0 + c[0] * (c[1] / cos_theta.max(0.01)).exp())
        * (1.0 + c[2] * (c[3] * gamma).exp() + c[4] * cos_g * cos_g)
}

/// The paper's coefficient fits for Y, x and y at turbidity t.
fn coefficients(t: f64) -> [[f64; 5]; 3] {
    [
        [
            0.1787 * t - 1.4630,
            -0.3554 * t + 0.4275,
            -0.0227 * t + 5.3251,
            0.1206 * t - 2.5771,
            -0.0670 * t + 0.3703,
        ],
        [
            -0.0193 * t - 0.2592,
            -0.0665 * t + 0.0008,
            -0.0004 * t + 0.2125,
            -0.0641 * t - 0.8989,
            -0.0033 * t + 0.0452,
        ],
        [
            -0.0167 * t - 0.2608,
            -0.0950 * t + 0.0092,
            -0.0079 * t + 0.2102,
            -0.0441 * t - 1.6537,
            -0.0109 * t + 0.0529,
        ],
    ]
}

/// Zenith luminance (kcd/m²) and chromaticity (x, y) for turbidity t and sun zenith angle ts.
fn zenith(t: f64, ts: f64) -> [f64; 3] {
    let chi = (4.0 / 9.0 - t / 120.0) * (PI - 2.0 * ts);
    let yz = (4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192;
    let (t2, s2, s3) = (t * t, ts * ts, ts * ts * ts);
    let xz = t2 * (0.00166 * s3 - 0.00375 * s2 + 0.00209 * ts)
        + t * (-0.02903 * s3 + 0.06377 * s2 - 0.03202 * ts + 0.00394)
        + (0.11693 * s3 - 0.21196 * s2 + 0.06052 * ts + 0.25886);
    let yz_c = t2 * (0.00275 * s3 - 0.00610 * s2 + 0.00317 * ts)
        + t * (-0.04214 * s3 + 0.08970 * s2 - 0.04153 * ts + 0.00516)
        + (0.15346 * s3 - 0.26756 * s2 + 0.06670 * ts + 0.26688);
    [yz, xz, yz_c]
}

/// CIE xyY to linear Rec. 709 RGB.
fn xyy_to_rgb(x: f64, y: f64, lum: f64) -> [f32; 3] {
    let cx = x * lum / y;
    let cz = (1.0 - x - y) * lum / y;
    [
        3.2406 * cx - 1.5372 * lum - 0.4986 * cz,
        -0.9689 * cx + 1.8758 * lum + 0.0415 * cz,
        0.0557 * cx - 0.2040 * lum + 1.0570 * cz,
    ]
    .map(|v| v.max(0.0) as f32)
}

/// Sky radiance (kcd/m², RGB) of the upper hemisphere in unit direction `d` (z ≥ 0), no sun.
pub fn sky_radiance(p: &BuiltinSky, d: [f64; 3]) -> [f32; 3] {
    let s = p.sun_direction();
    let ts = s[2].clamp(0.0, 1.0).acos();
    let cos_theta = d[2].max(0.0);
    let gamma = (d[0] * s[0] + d[1] * s[1] + d[2] * s[2])
        .clamp(-1.0, 1.0)
        .acos();
    let coef = coefficients(p.turbidity);
    let z = zenith(p.turbidity, ts);
    let v: [f64; 3] =
        [0, 1, 2].map(|k| z[k] * perez(&coef[k], cos_theta, gamma) / perez(&coef[k], 1.0, ts));
    xyy_to_rgb(v[1], v[2], v[0])
}

/// Normal illuminance of the sun (klx) and its colour (luminance 1) at the given elevation.
pub fn sun_illuminance(p: &BuiltinSky) -> (f64, [f64; 3]) {
    let zenith_deg = 90.0 - p.sun_elevation_deg.clamp(0.0, 90.0);
    let am =
        1.0 / (zenith_deg.to_radians().cos() + 0.50572 * (96.07995 - zenith_deg).powf(-1.6364));
    let e = 133.0 * 0.7f64.powf(am.powf(0.678));
    // Rayleigh-like optical depth per channel at 610, 550 and 465 nm, scaled by turbidity.
    let depth =
        [610.0f64, 550.0, 465.0].map(|l| 0.008569 * (l / 1000.0).powi(-4) * p.turbidity / 3.0);
    let tau = depth.map(|t| (-t * am).exp());
    let lum = 0.2126 * tau[0] + 0.7152 * tau[1] + 0.0722 * tau[2];
    (e, tau.map(|t| t / lum))
}

/// The built-in sky as a world-axis cube map, sun disc included.
pub fn builtin_sky(p: &BuiltinSky) -> CubeMap {
    let s = p.sun_direction();
    let (e_sun, colour) = sun_illuminance(p);
    // Ground: Lambertian, lit by the sky's horizontal irradiance and the sun.
    let sky_only = CubeMap::from_fn(64, |d| {
        if d[2] > 0.0 {
            sky_radiance(p, d)
        } else {
            [0.0; 3]
        }
    });
    let e_sky = sun::sky_irradiance(&sky_only).horizontal;
    let ground: [f32; 3] = [0, 1, 2].map(|k| {
        (p.ground_albedo / PI * (e_sky[k] as f64 + e_sun * colour[k] * s[2].max(0.0))) as f32
    });
    let mut cube = CubeMap::from_fn(p.face_size, |d| {
        if d[2] > 0.0 {
            sky_radiance(p, d)
        } else {
            ground
        }
    });
    // Disc radiance so that the disc delivers e_sun: E = L0 · 2π(1 − cos r).
    let omega_sun = 2.0 * PI * (1.0 - SUN_ANGULAR_RADIUS.cos());
    let l0 = colour.map(|c| (e_sun * c / omega_sun) as f32);
    sun::add_sun_disc(&mut cube, s, SUN_ANGULAR_RADIUS, l0, 0.0, 16);
    cube
}

/// The built-in sky as a lat-long image (for consumers that read lat-long skies).
pub fn builtin_sky_latlong(p: &BuiltinSky, width: u32, height: u32) -> crate::model::FloatImage {
    super::cube_to_latlong(&builtin_sky(p), width, height)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cube;

    #[test]
    fn zenith_luminance_matches_the_papers_formula_values() {
        // Preetham fig. 8 region: T = 2..6, sun 30° high: zenith luminance a few kcd/m².
        let y = zenith(3.0, 60f64.to_radians())[0];
        assert!(y > 2.0 && y < 8.0, "{y}");
        // Chromaticity of a clear zenith is bluish: x, y below the white point (0.3127, 0.329).
        let [_, x, yc] = zenith(2.5, 45f64.to_radians());
        assert!(x < 0.3127 && yc < 0.329, "{x} {yc}");
    }

    #[test]
    fn sky_is_brighter_near_the_sun_and_blue_overhead() {
        let p = BuiltinSky::default();
        let s = p.sun_direction();
        let near = sky_radiance(&p, cube::normalize([s[0], s[1], s[2] + 0.1]));
        let away = sky_radiance(&p, cube::normalize([-s[0], -s[1], s[2] + 0.1]));
        assert!(sun::luminance(near) > 2.0 * sun::luminance(away));
        let zen = sky_radiance(&p, [0.0, 0.0, 1.0]);
        assert!(zen[2] > zen[0], "{zen:?}");
    }

    #[test]
    fn extraction_recovers_the_builtin_sun() {
        let p = BuiltinSky {
            face_size: 256,
            ..BuiltinSky::default()
        };
        let cube = builtin_sky(&p);
        let (_, found) = sun::extract_sun(&cube, &sun::SunOptions::default());
        let s = p.sun_direction();
        let d = found.direction;
        let dot = s[0] * d[0] as f64 + s[1] * d[1] as f64 + s[2] * d[2] as f64;
        assert!(dot.acos() < 0.004, "{}", dot.acos());
        let (e, _) = sun_illuminance(&p);
        let got = sun::luminance(found.irradiance) as f64;
        // The circumsolar sky under the disc is counted with it: within 2%.
        assert!((got - e).abs() < 0.02 * e, "{got} vs {e}");
        // Daylight magnitudes: ~80–100 klx of sun at 40°, sky 10–30 klx on the ground.
        assert!(e > 60.0 && e < 110.0, "{e}");
    }

    #[test]
    fn low_sun_is_redder() {
        let high = sun_illuminance(&BuiltinSky {
            sun_elevation_deg: 60.0,
            ..BuiltinSky::default()
        });
        let low = sun_illuminance(&BuiltinSky {
            sun_elevation_deg: 5.0,
            ..BuiltinSky::default()
        });
        assert!(low.0 < high.0);
        assert!(low.1[0] / low.1[2] > high.1[0] / high.1[2]);
    }
}
