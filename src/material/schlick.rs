//! The two-layer Schlick material (seed 000, Table 3.1) and its BRDF.
//!
//! Schlick, "An Inexpensive BRDF Model for Physically-based Rendering" (1994). One layer reflects
//! `C·a/π + S(u)·D(t, v, v', w)` with the Fresnel approximation `S(u) = C + (1 − C)(1 − u)^5`
//! on the glossy lobe (the Lambertian part `a/π` carries the colour `C` alone: deviation 3 below)
//! and the directional factor
//!
//! ```text
//! D = b·[G(v)G(v')·Z(t)·A(w) / (4π v v')] + c·δ(mirror)
//! Z(t) = r / (1 + r t² − t²)²          (r = roughness: Z/π is exactly GGX with α² = r)
//! A(w) = sqrt(p / (p² − p² w² + w²))   (p = isotropy, w = cos of the half vector's azimuth to the tangent)
//! G(v) = 2v / (v + sqrt(r + (1 − r)v²))  (Smith masking of Z; Schlick: v / (r − r v + v))
//! ```
//!
//! with `a + b + c = 1` (diffuse, glossy, specular), `t = n·h`, `u = v·h`, `v = n·ωo`, `v' = n·ωi`.
//! Two layers stack as Schlick's heterogeneous model: the top layer (a leaf's wax) reflects
//! `S_top(u)·D_top`; the bottom layer reflects `S_bottom(u)·D_bottom` of what the top layer
//! lets through on the way in and out, `(1 − S_top(v'))·(1 − S_top(v))`. (Schlick's single
//! factor `1 − S_top(u)` of the half-vector angle lets a white diffuse bottom under a glossy
//! top reflect more than arrives at grazing views: 1.016 for the leaf at 75°.) Translucence `τ` splits the whole: `(1 − τ)` of it as above on the lit
//! side, `τ` transmitted as diffuse forward scattering (`τ · C_bottom / π` on the far side), as in
//! seed 000 eq. 4.8. All directions are in the tangent frame: `n = +Z`, tangent `+X`.
//!
//! Deviations from Schlick: his masking `v / (r − rv + v)` masks too little at grazing angles
//! for his own `Z` (a white glossy layer with r = 0.01 reflects 1.09 of the light arriving at
//! 86°), so `G` is the Smith masking function that belongs to `Z` (GGX), with which the single-
//! scattering lobe never reflects more than arrives. His glossy term also adds `(1 − G(v)G(v'))/π` to refill the energy the
//! shadowing removes; that refill can push the albedo of a white, rough, anisotropic layer past 1,
//! so it is left out (the white-furnace test holds the model to energy conservation). Third, a
//! layer of reflectivity `C = 0` is no interface (`S ≡ 0`, the exact Fresnel term of index 1)
//! and a layer's Lambertian part is `C·a/π` without `S(u)`: so an authored OpenGL colour of
//! specular 0 is exactly Lambertian (issue 35: the top layer's `(1 − u)^5` took 55 % of a plate's
//! light at a 6° view without reflecting it), while the thesis' leaf keeps its wax layer's
//! Fresnel loss.

use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// One reflection layer of Table 3.1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SchlickLayer {
    /// 0 = smooth, 1 = rough.
    pub roughness: f32,
    /// 0 = anisotropic, 1 = isotropic.
    pub isotropy: f32,
    /// Weights of diffuse, glossy and specular reflection; they sum to 1.
    pub diffuse: f32,
    pub glossy: f32,
    pub specular: f32,
    /// RGB reflectivity (the Fresnel colour at normal incidence), linear.
    pub color: [f32; 3],
}

/// Where a material's normal map comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum NormalMap {
    /// Flat: the geometric normal.
    None,
    /// A normal map the input named (mesh texture index).
    Explicit(u32),
    /// Derived from the colour map's mean-colour height (mesh texture index of the colour map).
    FromColor(u32),
}

/// The two-layer Schlick material of Table 3.1 (plus emission and opacity, which glTF and 3DS
/// inputs carry and the table has no place for).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SchlickMaterial {
    /// `[top, bottom]`: top = the wax layer, bottom = the cell layer the colour map modulates.
    pub layers: [SchlickLayer; 2],
    /// Amplitude of the bump map in metres (the height map spans ± this).
    pub bump_height: f32,
    /// 0 = opaque, 1 = all light passes (diffuse forward scattering).
    pub translucence: f32,
    /// Mesh texture index of the colour map (multiplies the bottom layer's colour only).
    pub color_map: Option<u32>,
    pub normal_map: NormalMap,
    /// Emitted radiance factor, linear RGB (glTF emissive, OpenGL emission).
    pub emission: [f32; 3],
    /// Opacity multiplied into the colour map's alpha before the alpha test (1 = opaque).
    pub opacity: f32,
}

impl SchlickLayer {
    /// The masking factor G(v): Smith's for the GGX distribution `Z/π` (see the module note).
    fn shadowing(&self, v: f32) -> f32 {
        let r = self.roughness.max(1e-4);
        2.0 * v / (v + (r + (1.0 - r) * v * v).sqrt())
    }

    /// Schlick's Fresnel approximation for colour channel `k`. A layer of reflectivity 0 in
    /// every channel is no interface (the exact Fresnel term of a refractive index of 1, which
    /// Schlick's approximation misses): it reflects nothing and lets all light through, so an
    /// authored material of specular 0 is its Lambertian bottom layer.
    fn fresnel(&self, u: f32, k: usize) -> f32 {
        if self.color == [0.0; 3] {
            return 0.0;
        }
        let c = self.color[k];
        c + (1.0 - c) * (1.0 - u.clamp(0.0, 1.0)).powi(5)
    }

    /// The glossy lobe's D without the colour: G·G'·Z·A / (4π v v').
    fn glossy_lobe(&self, wi: [f32; 3], wo: [f32; 3], h: [f32; 3]) -> f32 {
        let (v, vp) = (wo[2], wi[2]);
        let r = self.roughness.max(1e-4);
        let t = h[2];
        let z = r / (1.0 + r * t * t - t * t).powi(2);
        let p = self.isotropy.clamp(1e-4, 1.0);
        let hxy = (h[0] * h[0] + h[1] * h[1]).sqrt();
        // w = cos of the angle between the tangent (+X) and h projected on the surface.
        let w = if hxy > 1e-7 { h[0] / hxy } else { 1.0 };
        let a = (p / (p * p - p * p * w * w + w * w)).sqrt();
        self.shadowing(v) * self.shadowing(vp) * z * a / (4.0 * PI * v * vp)
    }

    /// The layer's non-delta reflectance `S(u)·(a/π + b·glossy)` for light from `wi` seen from `wo`
    /// (both above the surface), given the half vector `h` and `u = wo·h`.
    /// The diffuse part is Lambertian, `C·a/π` (a body colour has no Fresnel factor; with
    /// `S(u)` on it a diffuse layer of colour 0.5 reflected up to 4 % more at grazing views);
    /// the glossy lobe carries `S(u)`.
    fn reflectance(&self, wi: [f32; 3], wo: [f32; 3], h: [f32; 3], u: f32) -> [f32; 3] {
        let g = self.glossy * self.glossy_lobe(wi, wo, h);
        [0, 1, 2].map(|k| self.color[k] * self.diffuse / PI + self.fresnel(u, k) * g)
    }
}

/// The shortest filtered-normal length [`toksvig_roughness`] takes (|n̄| below it counts as it).
pub const TOKSVIG_MIN_LENGTH: f32 = 1e-3;

/// Toksvig's correction (Toksvig 2004, "Mipmapping Normal Maps"; seed 000 §4.7.3) of a Schlick
/// roughness `r` for a filtered normal of length `length` = |n̄| ≤ 1: r is GGX's α² (module note),
/// whose Blinn–Phong exponent is s = 2/r − 2; Toksvig's factor f = |n̄| / (|n̄| + s(1 − |n̄|))
/// scales the exponent, and the roughness of f·s is r' = 2/(f·s + 2). r' = r at |n̄| = 1 and grows
/// to 1 (diffuse) as |n̄| → 0. (The seed multiplies the roughness by |n̄|, which would make a
/// filtered bumpy surface glossier, against its own words that such surfaces become diffuse.)
pub fn toksvig_roughness(r: f32, length: f32) -> f32 {
    let r = r.clamp(1e-4, 1.0);
    let n = length.clamp(TOKSVIG_MIN_LENGTH, 1.0);
    let s = 2.0 / r - 2.0;
    let f = n / (n + s * (1.0 - n));
    2.0 / (f * s + 2.0)
}

fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 {
        v.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

impl SchlickMaterial {
    /// The material with both layers' roughness corrected by [`toksvig_roughness`] for a
    /// filtered normal of length `length`.
    pub fn with_toksvig(&self, length: f32) -> SchlickMaterial {
        let mut m = *self;
        for l in &mut m.layers {
            l.roughness = toksvig_roughness(l.roughness, length);
        }
        m
    }

    /// The BRDF/BTDF (without the specular delta) for unit directions in the tangent frame, light
    /// arriving from `wi`, leaving towards `wo`, with `map` the colour map's linear RGB at the
    /// point (use `[1; 3]` without one). Light on one side and the viewer on the other sees the
    /// translucent part; the material is two-sided (the lit side counts as the front).
    pub fn eval(&self, wi: [f32; 3], wo: [f32; 3], map: [f32; 3]) -> [f32; 3] {
        if wi[2] == 0.0 || wo[2] == 0.0 {
            return [0.0; 3];
        }
        let bottom = self.bottom_color(map);
        if (wi[2] > 0.0) != (wo[2] > 0.0) {
            return bottom.map(|c| self.translucence * c / PI);
        }
        // Two-sided: mirror both directions to the lit side.
        let flip = |d: [f32; 3]| if d[2] < 0.0 { [d[0], d[1], -d[2]] } else { d };
        let (wi, wo) = (flip(wi), flip(wo));
        let h = normalize([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
        let u = (wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2]).clamp(0.0, 1.0);
        let [top, bot] = &self.layers;
        let rt = top.reflectance(wi, wo, h, u);
        let mut b = *bot;
        b.color = bottom;
        let rb = b.reflectance(wi, wo, h, u);
        // Light reaches the bottom layer through the top one on the way in and on the way out.
        let through = |k: usize| (1.0 - top.fresnel(wi[2], k)) * (1.0 - top.fresnel(wo[2], k));
        [0, 1, 2].map(|k| (1.0 - self.translucence) * (rt[k] + through(k) * rb[k]))
    }

    /// The fraction of light from `wo`'s mirror direction reflected into `wo` by the specular
    /// (delta) terms of both layers.
    pub fn specular_albedo(&self, wo: [f32; 3], map: [f32; 3]) -> [f32; 3] {
        let u = wo[2].abs();
        let [top, bot] = &self.layers;
        let mut b = *bot;
        b.color = self.bottom_color(map);
        [0, 1, 2].map(|k| {
            let st = top.fresnel(u, k);
            (1.0 - self.translucence)
                * (st * top.specular + (1.0 - st).powi(2) * b.fresnel(u, k) * bot.specular)
        })
    }

    /// The bottom layer's colour times the colour map.
    pub fn bottom_color(&self, map: [f32; 3]) -> [f32; 3] {
        let c = self.layers[1].color;
        [c[0] * map[0], c[1] * map[1], c[2] * map[2]]
    }

    /// Checks the invariants of Table 3.1: weights in [0, 1] summing to 1, parameters in range.
    pub fn validate(&self) -> Result<(), String> {
        for (k, l) in self.layers.iter().enumerate() {
            let which = ["top", "bottom"][k];
            let sum = l.diffuse + l.glossy + l.specular;
            if (sum - 1.0).abs() > 1e-4 {
                return Err(format!("{which} layer weights sum to {sum}, not 1"));
            }
            let unit = [l.roughness, l.isotropy, l.diffuse, l.glossy, l.specular];
            if unit
                .iter()
                .chain(&l.color)
                .any(|x| !(0.0..=1.0).contains(x))
            {
                return Err(format!("{which} layer has a parameter outside [0, 1]"));
            }
        }
        if !(0.0..=1.0).contains(&self.translucence) || !(0.0..=1.0).contains(&self.opacity) {
            return Err("translucence or opacity outside [0, 1]".into());
        }
        if !self.bump_height.is_finite() {
            return Err("bump height is not finite".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {

    /// Toksvig's r' against the exponent-variance form 1/s' = 1/s + σ² with σ² = (1 − |n̄|)/|n̄|
    /// (Toksvig 2004 eq. 3 for a Gaussian of normals), at both ends and on a grid.
    #[test]
    fn toksvig_roughness_adds_the_filtered_normals_variance_to_the_exponents() {
        for r in [0.005f32, 0.0154, 0.1, 0.5, 0.9] {
            assert!((toksvig_roughness(r, 1.0) - r).abs() < 1e-6, "{r}");
            assert!(toksvig_roughness(r, 0.0) > 0.99, "{r}");
            let mut last = r;
            for k in (1..100).rev() {
                let len = k as f64 / 100.0;
                let s = 2.0 / r as f64 - 2.0;
                let s2 = 1.0 / (1.0 / s + (1.0 - len) / len);
                let want = 2.0 / (s2 + 2.0);
                let got = toksvig_roughness(r, len as f32);
                assert!((got as f64 - want).abs() < 1e-5, "{r} {len}: {got} {want}");
                assert!(got >= last, "rougher as |n̄| shrinks");
                last = got;
            }
        }
    }

    use super::*;

    /// An authored OpenGL material of specular 0 (top layer C = 0) is Lambertian: its diffuse
    /// colour / π at every pair of directions, grazing ones included (issue 35: a flat plate
    /// lost 15 % of Lambert at 18° and 55 % at 6° to the top layer's Fresnel term).
    #[test]
    fn authored_specular_zero_is_lambertian() {
        let m = crate::model::Material {
            diffuse: [1.0, 0.5, 0.25, 1.0],
            specular: [0.0, 0.0, 0.0, 1.0],
            shininess: 10.0,
            ..Default::default()
        };
        let s = crate::material::convert::material_to_schlick(&m);
        let mut rng = crate::rng::Rng::new(7);
        for _ in 0..2000 {
            let mut dir = || {
                let z: f32 = rng.f32().max(1e-3);
                let phi = std::f32::consts::TAU * rng.f32();
                let r = (1.0 - z * z).sqrt();
                [r * phi.cos(), r * phi.sin(), z]
            };
            let (wi, wo) = (dir(), dir());
            let f = s.eval(wi, wo, [1.0; 3]);
            for k in 0..3 {
                let want = [1.0, 0.5, 0.25][k] / PI;
                assert!((f[k] - want).abs() < 1e-6, "{wi:?} {wo:?}: {f:?}");
            }
        }
        // The thesis' leaf keeps its wax layer's Fresnel loss at grazing views.
        let leaf = crate::material::convert::LEAF_DEFAULT;
        let f = leaf.eval([0.0, 0.0, 1.0], [0.995, 0.0, 0.0998], [1.0; 3]);
        let f0 = leaf.eval([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0; 3]);
        assert!(f[0] < 0.9 * f0[0], "{f:?} {f0:?}");
    }

    fn layer(r: f32, p: f32, w: [f32; 3], c: f32) -> SchlickLayer {
        SchlickLayer {
            roughness: r,
            isotropy: p,
            diffuse: w[0],
            glossy: w[1],
            specular: w[2],
            color: [c; 3],
        }
    }

    fn material(top: SchlickLayer, bottom: SchlickLayer, tau: f32) -> SchlickMaterial {
        SchlickMaterial {
            layers: [top, bottom],
            bump_height: 0.001,
            translucence: tau,
            color_map: None,
            normal_map: NormalMap::None,
            emission: [0.0; 3],
            opacity: 1.0,
        }
    }

    fn dir(theta: f32, phi: f32) -> [f32; 3] {
        [
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        ]
    }

    /// ∫ f(wi, wo) |cos θi| dωi over the whole sphere plus the delta part, by a midpoint rule in
    /// (θ, φ) that resolves lobes down to roughness 0.01.
    fn albedo(m: &SchlickMaterial, wo: [f32; 3]) -> f32 {
        let (nt, np) = (720, 360);
        let (dt, dp) = (PI / nt as f32, 2.0 * PI / np as f32);
        let mut sum = 0.0f64;
        for i in 0..nt {
            let th = (i as f32 + 0.5) * dt;
            let w = (th.sin() * th.cos().abs() * dt * dp) as f64;
            for j in 0..np {
                let wi = dir(th, (j as f32 + 0.5) * dp);
                sum += m.eval(wi, wo, [1.0; 3])[1] as f64 * w;
            }
        }
        sum as f32 + m.specular_albedo(wo, [1.0; 3])[1]
    }

    #[test]
    fn white_furnace_reflects_no_more_than_arrives() {
        let leaf = crate::material::convert::LEAF_DEFAULT;
        let mut cases = vec![leaf];
        for &r in &[0.01, 0.1, 0.5, 1.0] {
            for &p in &[1.0, 0.2] {
                for w in [[0.0, 1.0, 0.0], [0.3, 0.5, 0.2], [1.0, 0.0, 0.0]] {
                    for &tau in &[0.0, 0.3] {
                        let top = layer(r, p, w, 1.0);
                        let bottom = layer(r, p, [1.0, 0.0, 0.0], 1.0);
                        cases.push(material(top, bottom, tau));
                        cases.push(material(layer(r, p, w, 0.075), bottom, tau));
                    }
                }
            }
        }
        for m in &mut cases {
            m.layers[1].color = [1.0; 3];
            m.validate().unwrap();
            for &th in &[0.0f32, 0.5, 1.0, 1.3, 1.5] {
                for &phi in &[0.0f32, 0.7] {
                    let a = albedo(m, dir(th, phi));
                    assert!(a <= 1.005, "albedo {a} > 1 at θ {th}, φ {phi} for {m:?}");
                    assert!(a >= 0.0);
                }
            }
        }
    }

    #[test]
    fn lambertian_white_layer_has_unit_albedo() {
        // A purely diffuse white top layer (S = 1, so nothing reaches the bottom) is a
        // Lambertian reflector: albedo 1 for every view direction (oracle: 1/π · π).
        let m = material(
            layer(0.5, 1.0, [1.0, 0.0, 0.0], 1.0),
            layer(0.5, 1.0, [1.0, 0.0, 0.0], 0.3),
            0.0,
        );
        for &th in &[0.0f32, 0.8, 1.4] {
            let a = albedo(&m, dir(th, 0.0));
            assert!((a - 1.0).abs() < 2e-3, "albedo {a} at θ {th}");
        }
    }

    #[test]
    fn reciprocity_holds() {
        let m = crate::material::convert::LEAF_DEFAULT;
        for (a, b) in [((0.3, 0.1), (1.1, 2.0)), ((1.2, 0.0), (0.2, 3.0))] {
            let (x, y) = (dir(a.0, a.1), dir(b.0, b.1));
            let (f, g) = (m.eval(x, y, [0.5; 3]), m.eval(y, x, [0.5; 3]));
            for k in 0..3 {
                assert!((f[k] - g[k]).abs() <= 1e-5 * f[k].abs().max(1.0));
            }
        }
    }
}
