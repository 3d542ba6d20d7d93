//! The two-layer material under the ambient light (issue 35, found by the path-traced ground
//! truth): the top layer's glossy reflection of the environment and its Fresnel loss on the way
//! to and from the bottom layer. Without them a model's ambient term was the bottom layer's
//! `albedo·E/π` alone, which reads 0.62–0.80 of the path tracer's on the fixture's objects and
//! leaves (a glossy bench top at a grazing view mirrors the bright sky near the horizon) and
//! 1.0 with the top layer taken out of the reference (docs/VALIDATION.md).
//!
//! For a Schlick material (docs/MATERIALS.md) seen from `v = cos θ_o` on its lit side, the light
//! the stack reflects from an environment of radiance L(ω) is
//! `(1 − τ)·[∫ f_top L cos + (1 − S(v))·∫ (1 − S(v'))·C_bottom/π·L cos] + τ·∫_other C_bottom/π·L cos`.
//! The runtime splits it into what the ambient term already knows, the irradiance `E` of the seen
//! side (PRT, light map or sky) and `E_other` of the other side, plus the radiance `L_R` of the
//! environment in the mirror direction of the view:
//! - **diffuse**: `(1 − S(v))·(1 − S̄)` times the bottom albedo, `S̄ = C + (1 − C)/21` the
//!   cosine-weighted mean of `S` (`2∫(1 − u)⁵u du = 1/21`), exact for a uniform environment;
//!   plus the top layer's own Lambertian part `a_top·C_top`;
//! - **gloss**: the top layer's glossy directional albedo `b·(C·X(v, r) + (1 − C)·Y(v, r))`
//!   (its specular part `c·S(v)` beside it) times `L_R`: the split-sum approximation (the lobe's
//!   integral times the environment in its peak direction), `X` and `Y` in a table over v and r
//!   ([`GlossLut`], the same numbers the GPU reads from `AmbientParams`).
//!
//! Limits: an isotropic lobe (isotropy 1; every converted material has it), the bottom layer's
//! own glossy and specular parts left out (every converted material's bottom layer is diffuse),
//! `L_R` from the order-4 SH of the environment without convolving it with the lobe, the
//! Fresnel transmission's mean taken over a uniform environment. A layer of reflectivity 0 is
//! no interface (S ≡ 0): an authored spec-0 colour keeps exactly its old ambient term.

use crate::material::schlick::{SchlickLayer, SchlickMaterial};
use std::sync::OnceLock;

/// Table size: view cosines (0 to 1) × roughness steps (`r^(1/4)` from 0 to 1).
pub const LUT_V: usize = 32;
pub const LUT_R: usize = 16;
/// Stratified samples per side of the half-vector grid each table entry integrates.
const LUT_SAMPLES: usize = 96;

/// `(X, Y)` per entry, roughness-major: `xy[ir * LUT_V + iv]`.
#[derive(Debug, Clone, PartialEq)]
pub struct GlossLut {
    pub xy: Vec<[f32; 2]>,
}

/// The process's table (built once, deterministic).
pub fn gloss_lut() -> &'static GlossLut {
    static LUT: OnceLock<GlossLut> = OnceLock::new();
    LUT.get_or_init(GlossLut::build)
}

/// Smith's masking of the GGX lobe `Z/π` with α² = r (src/material/schlick.rs `shadowing`).
fn masking(r: f32, v: f32) -> f64 {
    let (r, v) = (r.max(1e-4) as f64, v as f64);
    2.0 * v / (v + (r + (1.0 - r) * v * v).sqrt())
}

impl GlossLut {
    fn build() -> GlossLut {
        let mut xy = Vec::with_capacity(LUT_V * LUT_R);
        for ir in 0..LUT_R {
            let s = ir as f32 / (LUT_R - 1) as f32;
            let r = s.powi(4).max(1e-4);
            for iv in 0..LUT_V {
                let v = (iv as f32 / (LUT_V - 1) as f32).max(1e-3);
                let (x, y) = integrate(v, r);
                xy.push([x as f32, y as f32]);
            }
        }
        GlossLut { xy }
    }

    /// `(X, Y)` at view cosine `v` and roughness `r`, bilinear in (v, r^(1/4)).
    pub fn lookup(&self, v: f32, r: f32) -> [f32; 2] {
        let fv = v.clamp(0.0, 1.0) * (LUT_V - 1) as f32;
        let fr = r.clamp(0.0, 1.0).sqrt().sqrt() * (LUT_R - 1) as f32;
        let (iv, ir) = ((fv as usize).min(LUT_V - 2), (fr as usize).min(LUT_R - 2));
        let (av, ar) = (fv - iv as f32, fr - ir as f32);
        let at = |i: usize, j: usize| self.xy[j * LUT_V + i];
        std::array::from_fn(|k| {
            let a = at(iv, ir)[k] + (at(iv + 1, ir)[k] - at(iv, ir)[k]) * av;
            let b = at(iv, ir + 1)[k] + (at(iv + 1, ir + 1)[k] - at(iv, ir + 1)[k]) * av;
            a + (b - a) * ar
        })
    }

    /// The table as `AmbientParams` carries it: two entries per vec4.
    pub fn packed(&self) -> Vec<[f32; 4]> {
        self.xy
            .chunks(2)
            .map(|p| [p[0][0], p[0][1], p[1][0], p[1][1]])
            .collect()
    }
}

/// `X = ∫ G G' Z/(4π v v') v' dω'` and `Y` the same weighted by `(1 − u)⁵`, u = ω_o·h: the GGX
/// half vectors on a stratified grid (pdf `D(h)·h_z`), so each sample weighs `G G' u/(v h_z)`.
fn integrate(v: f32, r: f32) -> (f64, f64) {
    let wo = [(1.0 - (v * v) as f64).max(0.0).sqrt(), 0.0, v as f64];
    let n = LUT_SAMPLES;
    let (mut x, mut y) = (0.0f64, 0.0f64);
    let r64 = r as f64;
    for i in 0..n {
        let xi = (i as f64 + 0.5) / n as f64;
        let cos2 = (1.0 - xi) / (1.0 + (r64 - 1.0) * xi);
        let hz = cos2.max(0.0).sqrt();
        let sin = (1.0 - cos2).max(0.0).sqrt();
        for j in 0..n {
            let phi = 2.0 * std::f64::consts::PI * (j as f64 + 0.5) / n as f64;
            let h = [sin * phi.cos(), sin * phi.sin(), hz];
            let u = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2];
            if u <= 0.0 {
                continue;
            }
            let wi_z = 2.0 * u * h[2] - wo[2];
            if wi_z <= 0.0 {
                continue;
            }
            let w = masking(r, v) * masking(r, wi_z as f32) * u / (v as f64 * hz);
            x += w;
            y += w * (1.0 - u).powi(5);
        }
    }
    let k = 1.0 / (n * n) as f64;
    (x * k, y * k)
}

/// How the material turns the ambient term's inputs into reflected light on the seen side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmbientLayers {
    /// Multiplies the bottom albedo under `E_seen/π`: `(1 − S(v))(1 − S̄)`.
    pub diffuse: [f32; 3],
    /// Added to it: the top layer's Lambertian albedo `a·C`.
    pub top_diffuse: [f32; 3],
    /// Multiplies the environment's radiance in the mirror direction.
    pub gloss: [f32; 3],
    /// τ: the share of the other side's light transmitted.
    pub translucence: f32,
}

impl AmbientLayers {
    /// A Lambertian surface: the bottom albedo alone, nothing mirrored.
    pub const LAMBERT: AmbientLayers = AmbientLayers {
        diffuse: [1.0; 3],
        top_diffuse: [0.0; 3],
        gloss: [0.0; 3],
        translucence: 0.0,
    };
}

fn fresnel(l: &SchlickLayer, u: f32, k: usize) -> f32 {
    if l.color == [0.0; 3] {
        return 0.0;
    }
    let c = l.color[k];
    c + (1.0 - c) * (1.0 - u.clamp(0.0, 1.0)).powi(5)
}

/// The layers' factors for material `m` seen at view cosine `v` (the facing normal's).
pub fn ambient_layers(m: &SchlickMaterial, v: f32) -> AmbientLayers {
    let top = &m.layers[0];
    let v = v.clamp(0.0, 1.0);
    let interface = top.color != [0.0; 3];
    let xy = if interface {
        gloss_lut().lookup(v, top.roughness)
    } else {
        [0.0; 2]
    };
    AmbientLayers {
        diffuse: std::array::from_fn(|k| {
            let c = if interface { top.color[k] } else { 0.0 };
            let mean = c + (1.0 - c) / 21.0;
            (1.0 - fresnel(top, v, k)) * (1.0 - if interface { mean } else { 0.0 })
        }),
        top_diffuse: top.color.map(|c| c * top.diffuse),
        gloss: std::array::from_fn(|k| {
            if !interface {
                return 0.0;
            }
            let c = top.color[k];
            top.glossy * (c * xy[0] + (1.0 - c) * xy[1]) + top.specular * fresnel(top, v, k)
        }),
        translucence: m.translucence,
    }
}

/// The reflected ambient light of the seen side: `e_seen` and `e_other` are `E/π` of the two
/// sides (albedo-free), `albedo` the bottom layer's, `l_r` the environment's radiance in the
/// view's mirror direction.
pub fn reflect_ambient(
    layers: &AmbientLayers,
    albedo: [f32; 3],
    e_seen: [f32; 3],
    e_other: [f32; 3],
    l_r: [f32; 3],
) -> [f32; 3] {
    let t = layers.translucence;
    std::array::from_fn(|c| {
        let d = (1.0 - t) * e_seen[c] * (layers.diffuse[c] * albedo[c] + layers.top_diffuse[c])
            + t * e_other[c] * albedo[c];
        d.max(0.0) + (1.0 - t) * layers.gloss[c] * l_r[c].max(0.0)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(r: f32, weights: [f32; 3], c: [f32; 3]) -> SchlickLayer {
        SchlickLayer {
            roughness: r,
            isotropy: 1.0,
            diffuse: weights[0],
            glossy: weights[1],
            specular: weights[2],
            color: c,
        }
    }

    fn material(top: SchlickLayer, bottom: [f32; 3], tau: f32) -> SchlickMaterial {
        SchlickMaterial {
            layers: [top, layer(1.0, [1.0, 0.0, 0.0], bottom)],
            bump_height: 0.0,
            translucence: tau,
            color_map: None,
            normal_map: crate::material::schlick::NormalMap::None,
            emission: [0.0; 3],
            opacity: 1.0,
        }
    }

    /// ∫ f(ω_i, ω_o) cos θ_i over the whole sphere by a plain (θ, φ) midpoint grid over
    /// `SchlickMaterial::eval`: a second algorithm, sharing nothing with the table's
    /// importance-sampled half vectors.
    fn brute_albedo(m: &SchlickMaterial, v: f32) -> [f32; 3] {
        let wo = [(1.0 - v * v).sqrt(), 0.0, v];
        let (nt, np) = (1200usize, 600usize);
        let mut out = [0.0f64; 3];
        for i in 0..nt {
            // cos θ uniform in (−1, 1): dω = d(cos θ) dφ.
            let z = -1.0 + 2.0 * (i as f64 + 0.5) / nt as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            for j in 0..np {
                let phi = 2.0 * std::f64::consts::PI * (j as f64 + 0.5) / np as f64;
                let wi = [(s * phi.cos()) as f32, (s * phi.sin()) as f32, z as f32];
                let f = m.eval(wi, wo, [1.0; 3]);
                for k in 0..3 {
                    out[k] += f[k] as f64 * z.abs();
                }
            }
        }
        let dw = 2.0 / nt as f64 * 2.0 * std::f64::consts::PI / np as f64;
        out.map(|x| (x * dw) as f32)
    }

    #[test]
    fn the_ambient_term_under_a_uniform_sky_is_the_materials_albedo() {
        // A uniform environment of radiance 1 from every direction: E/π = 1 on both sides and
        // L_R = 1, so the split formula must give ∫ f cos over the sphere, the brute-force
        // integral of the BRDF itself. The diffuse and translucent parts are exact there; the
        // glossy part is the table's (interpolated) integral.
        let cases = [
            // the thesis' leaf: wax C 0.075, r 0.1, τ 0.3
            material(
                layer(0.1, [0.0, 1.0, 0.0], [0.075; 3]),
                [0.35, 0.6, 0.25],
                0.3,
            ),
            // the fixture's 3DS bench top: C 0.29, r 0.072
            material(
                layer(0.072, [0.0, 1.0, 0.0], [0.29; 3]),
                [0.78, 0.59, 0.39],
                0.0,
            ),
            // a rough coloured top layer with a Lambertian part
            material(layer(0.6, [0.3, 0.7, 0.0], [0.5, 0.2, 0.1]), [0.5; 3], 0.0),
            // no interface: exactly Lambertian
            material(layer(0.1, [0.0, 1.0, 0.0], [0.0; 3]), [0.8; 3], 0.0),
        ];
        let mut worst = 0.0f32;
        for m in &cases {
            for v in [0.05f32, 0.2, 0.45, 0.7, 0.95] {
                let want = brute_albedo(m, v);
                let layers = ambient_layers(m, v);
                let got = reflect_ambient(
                    &layers,
                    m.bottom_color([1.0; 3]),
                    [1.0; 3],
                    [1.0; 3],
                    [1.0; 3],
                );
                for k in 0..3 {
                    let e = (got[k] - want[k]).abs();
                    worst = worst.max(e);
                    assert!(
                        e <= 0.01,
                        "v = {v}, channel {k}: split formula {} vs brute force {} ({m:?})",
                        got[k],
                        want[k]
                    );
                }
            }
        }
        assert!(
            worst > 0.0,
            "the two integrals cannot agree to the last bit"
        );
    }

    #[test]
    fn the_table_matches_its_integral_between_entries() {
        // Off-grid (v, r): the bilinear lookup against the direct integral.
        let lut = gloss_lut();
        for (v, r) in [
            (0.13f32, 0.02f32),
            (0.5, 0.1),
            (0.77, 0.33),
            (0.33, 0.0073),
            (0.9, 0.8),
        ] {
            let (x, y) = integrate(v, r);
            let got = lut.lookup(v, r);
            assert!(
                (got[0] as f64 - x).abs() <= 0.02,
                "X({v}, {r}) = {x}, table {}",
                got[0]
            );
            assert!(
                (got[1] as f64 - y).abs() <= 0.01,
                "Y({v}, {r}) = {y}, table {}",
                got[1]
            );
        }
        // A white glossy layer reflects at most what arrives (the white furnace).
        assert!(
            lut.xy
                .iter()
                .all(|p| p[0] <= 1.0 + 1e-3 && p[1] >= 0.0 && p[1] <= p[0])
        );
    }

    #[test]
    fn a_lambertian_material_keeps_albedo_times_irradiance() {
        let m = material(layer(0.1, [0.0, 1.0, 0.0], [0.0; 3]), [0.8; 3], 0.0);
        let l = ambient_layers(&m, 0.3);
        assert_eq!(
            l,
            AmbientLayers {
                translucence: 0.0,
                ..AmbientLayers::LAMBERT
            }
        );
        let got = reflect_ambient(&l, [0.8; 3], [2.0; 3], [0.0; 3], [5.0; 3]);
        assert_eq!(got, [1.6; 3]);
    }
}
