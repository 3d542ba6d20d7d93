//! Input materials (OpenGL fixed-function, OBJ/MTL Phong, glTF metallic-roughness) to the
//! two-layer Schlick material of Table 3.1.
//!
//! The mapping (docs/MATERIALS.md repeats it):
//!
//! * **Default material**: OpenGL's (diffuse 0.8 grey, specular and emission black, shininess
//!   0) or Xfrog's, which real TXF plant files carry (seed 000 3.1.1: diffuse 0.7 grey, ambient
//!   0.1 grey, specular and emission black, shininess 0); seed 000 3.1.2 gives both the
//!   thesis' leaf, [`LEAF_DEFAULT`]. Top (wax): roughness 0.1, isotropy 1, glossy 1,
//!   reflectivity 0.075 grey. Bottom: diffuse 1, colour (1, 1, 1) × colour map. Bump ±1 mm,
//!   translucence 0.3 (or the TXF set's own value). Without a colour map (Xfrog's untextured
//!   stems) the bottom is the default's own grey (0.8 or 0.7) and the translucence the TXF
//!   set's value, else 0.
//! * **Authored fixed-function material**: the Phong exponent `n = shininess` becomes the top
//!   layer's roughness `r = 2 / (n + 2)` (Blinn-Phong ↔ Beckmann/GGX: `α² = 2/(n + 2)`, and
//!   Schlick's `Z/π` is GGX with `α² = r`); the top layer is glossy with reflectivity
//!   `spec.rgb · 8/(n + 2)` (OpenGL's highlight-to-diffuse ratio, see [`specular_to_reflectivity`]);
//!   the bottom layer is diffuse with colour `diff.rgb` (× colour map, OpenGL's modulate). `emis`
//!   becomes emission, `1 − transparency` (× `diff.a`) the opacity; ambient is dropped (ambient
//!   light comes from the sky). Translucence is the TXF set's value, else 0; bump ±1 mm when a
//!   normal map exists.
//! * **glTF metallic-roughness**: `r = α² = roughness⁴` (glTF roughness is perceptual, `α =
//!   roughness²`); top layer glossy with reflectivity `lerp(0.04, base, metallic)`; bottom layer
//!   diffuse with `base × (1 − metallic)`; emission as given; translucence 0.
//!
//! OpenGL colours are lighting coefficients that act on linear values in the fixed-function
//! equation, so they are taken as linear; glTF factors are linear by definition.

use super::schlick::{NormalMap, SchlickLayer, SchlickMaterial};
use crate::model::{Material, MaterialSource};

/// The leaf defaults of seed 000 3.1.2 (no maps: [`material_to_schlick`] attaches them).
pub const LEAF_DEFAULT: SchlickMaterial = SchlickMaterial {
    layers: [
        SchlickLayer {
            roughness: 0.1,
            isotropy: 1.0,
            diffuse: 0.0,
            glossy: 1.0,
            specular: 0.0,
            color: [0.075; 3],
        },
        SchlickLayer {
            roughness: 1.0,
            isotropy: 1.0,
            diffuse: 1.0,
            glossy: 0.0,
            specular: 0.0,
            color: [1.0; 3],
        },
    ],
    bump_height: 0.001,
    translucence: 0.3,
    color_map: None,
    normal_map: NormalMap::None,
    emission: [0.0; 3],
    opacity: 1.0,
};

pub use crate::texture::BUMP_HEIGHT_M;

/// Whether `m` is OpenGL's default material (ambient and alpha ignored).
pub fn is_default_opengl(m: &Material) -> bool {
    m.source == MaterialSource::FixedFunction
        && grey(&m.diffuse, 0.8)
        && grey(&m.specular, 0.0)
        && grey(&m.emission, 0.0)
        && m.shininess.abs() < 1e-3
}

/// Whether `m` is the Xfrog default that real TXF plant files carry (seed 000 3.1.1's listing:
/// `diff 0.70 0.70 0.70 1.00`, `ambi 0.10 0.10 0.10 1.00`, `spec 0 0 0 1`, `emis 0 0 0 1`,
/// `shin 0.00`; alpha ignored). The ambient 0.1 is part of the signature: an authored 0.7 grey
/// with another ambient is taken as authored.
pub fn is_default_xfrog(m: &Material) -> bool {
    m.source == MaterialSource::FixedFunction
        && grey(&m.diffuse, 0.7)
        && grey(&m.ambient, 0.1)
        && grey(&m.specular, 0.0)
        && grey(&m.emission, 0.0)
        && m.shininess.abs() < 1e-3
}

/// Whether `m` is a default material (OpenGL's or Xfrog's) and so gets the thesis' leaf.
pub fn is_default_material(m: &Material) -> bool {
    is_default_opengl(m) || is_default_xfrog(m)
}

/// Whether the RGB of `a` is `v` grey (to 1e-3; TXF writes two decimals).
fn grey(a: &[f32; 4], v: f32) -> bool {
    a[..3].iter().all(|&c| (c - v).abs() < 1e-3)
}

/// Converts one input material; see the module documentation for the mapping.
pub fn material_to_schlick(m: &Material) -> SchlickMaterial {
    let mut out = match m.source {
        // A TXF set header's translucence of 0 means "not set" (Xfrog writes 0): the leaf's 0.3.
        _ if is_default_material(m) && m.color_map.is_some() => SchlickMaterial {
            translucence: m.translucence.filter(|&t| t > 0.0).map_or(0.3, unit),
            ..LEAF_DEFAULT
        },
        // Without a colour map the part is no leaf blade (Xfrog's untextured stems carry the
        // default material too): the wax top layer stays, the bottom keeps the default's own
        // grey (OpenGL's 0.8, Xfrog's 0.7) instead of the white that only makes sense under a
        // leaf texture, and it transmits only what the TXF set says (a closed stem lit through
        // its back faces would glow).
        _ if is_default_material(m) => {
            let mut leaf = LEAF_DEFAULT;
            leaf.layers[1].color = rgb(&m.diffuse);
            leaf.translucence = m.translucence.map_or(0.0, unit);
            leaf
        }
        MaterialSource::FixedFunction => fixed_function(m),
        MaterialSource::MetallicRoughness {
            metallic,
            roughness,
        } => metallic_roughness(m, metallic, roughness),
    };
    out.color_map = m.color_map;
    out.normal_map = match (m.normal_map, m.color_map) {
        (Some(n), _) => NormalMap::Explicit(n),
        // glTF materials carry their own normal maps; a colour map is not a height field there.
        (None, Some(c)) if m.source == MaterialSource::FixedFunction => NormalMap::FromColor(c),
        _ => NormalMap::None,
    };
    out.bump_height = match out.normal_map {
        NormalMap::None => 0.0,
        _ => BUMP_HEIGHT_M,
    };
    out.opacity = unit(m.diffuse[3] * (1.0 - m.transparency));
    out
}

/// The diffuse albedo of an input material, linear RGB without its colour map: the bottom
/// layer's colour of [`material_to_schlick`] (authored OpenGL/3DS/MTL colours are lighting
/// coefficients and so linear; glTF's base colour factor is linear; the thesis' leaf is white
/// under its colour map). The one albedo of every stage that traces light (PRT, light maps,
/// env maps, voxels, impostors) and of the renderer; multiply by the colour map's linear texel.
pub fn diffuse_albedo(m: &Material) -> [f32; 3] {
    material_to_schlick(m).layers[1].color
}

/// The translucence the light-tracing stages use for `m`: the converted material's
/// ([`material_to_schlick`]: the TXF set's value, else 0 for authored and untextured default
/// materials), except a textured default material (the thesis' leaf) without a TXF value, which
/// takes `leaf_default` (the PRT option `default_translucence`, 0.3 as in the leaf's Schlick
/// material unless set otherwise).
pub fn translucence(m: &Material, leaf_default: f32) -> f32 {
    let t = if is_default_material(m)
        && m.color_map.is_some()
        && m.translucence.is_none_or(|t| t <= 0.0)
    {
        leaf_default
    } else {
        material_to_schlick(m).translucence
    };
    unit(t)
}

fn unit(x: f32) -> f32 {
    if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

fn rgb(c: &[f32; 4]) -> [f32; 3] {
    [unit(c[0]), unit(c[1]), unit(c[2])]
}

fn glossy_layer(roughness: f32, color: [f32; 3]) -> SchlickLayer {
    SchlickLayer {
        roughness: unit(roughness),
        isotropy: 1.0,
        diffuse: 0.0,
        glossy: 1.0,
        specular: 0.0,
        color,
    }
}

fn diffuse_layer(color: [f32; 3]) -> SchlickLayer {
    SchlickLayer {
        roughness: 1.0,
        isotropy: 1.0,
        diffuse: 1.0,
        glossy: 0.0,
        specular: 0.0,
        color,
    }
}

/// Phong exponent to Schlick roughness: `r = 2 / (n + 2)`.
pub fn shininess_to_roughness(n: f32) -> f32 {
    let n = if n.is_finite() { n.max(0.0) } else { 0.0 };
    2.0 / (n + 2.0)
}

/// OpenGL's specular colour to the top layer's reflectivity: `spec · 8/(n + 2)`, which gives the
/// glossy peak at normal incidence (`C/(4π r) = C (n+2)/(8π)`) the same ratio to the diffuse term
/// as OpenGL's `spec·(n·h)^n` has to `diff·(n·l)` (and keeps a white OpenGL highlight from turning
/// the top layer into a mirror that hides the colour map).
pub fn specular_to_reflectivity(spec: &[f32; 4], shininess: f32) -> [f32; 3] {
    let n = if shininess.is_finite() {
        shininess.max(0.0)
    } else {
        0.0
    };
    rgb(spec).map(|c| unit(c * 8.0 / (n + 2.0)))
}

fn fixed_function(m: &Material) -> SchlickMaterial {
    SchlickMaterial {
        layers: [
            glossy_layer(
                shininess_to_roughness(m.shininess),
                specular_to_reflectivity(&m.specular, m.shininess),
            ),
            diffuse_layer(rgb(&m.diffuse)),
        ],
        bump_height: 0.0,
        translucence: m.translucence.map_or(0.0, unit),
        color_map: None,
        normal_map: NormalMap::None,
        emission: rgb(&m.emission),
        opacity: 1.0,
    }
}

fn metallic_roughness(m: &Material, metallic: f32, roughness: f32) -> SchlickMaterial {
    let base = rgb(&m.diffuse);
    let k = unit(metallic);
    let f0 = base.map(|b| 0.04 * (1.0 - k) + b * k);
    let alpha = unit(roughness).powi(2);
    SchlickMaterial {
        layers: [
            glossy_layer(alpha * alpha, f0),
            diffuse_layer(base.map(|b| b * (1.0 - k))),
        ],
        bump_height: 0.0,
        translucence: 0.0,
        color_map: None,
        normal_map: NormalMap::None,
        emission: m.emission[..3]
            .iter()
            .map(|&e| if e.is_finite() { e.max(0.0) } else { 0.0 })
            .collect::<Vec<_>>()
            .try_into()
            .unwrap_or([0.0; 3]),
        opacity: 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_opengl_material_becomes_the_leaf() {
        let m = Material {
            color_map: Some(0),
            ..Material::default()
        };
        let s = material_to_schlick(&m);
        assert_eq!(s.layers, LEAF_DEFAULT.layers);
        assert_eq!(s.translucence, 0.3);
        assert_eq!(s.bump_height, 0.001);
        assert_eq!(s.color_map, Some(0));
        assert_eq!(s.normal_map, NormalMap::FromColor(0));
        s.validate().unwrap();
        // The TXF set header's translucence wins over the thesis' 0.3.
        let t = Material {
            translucence: Some(0.6),
            ..m.clone()
        };
        assert_eq!(material_to_schlick(&t).translucence, 0.6);
        let unset = Material {
            translucence: Some(0.0),
            ..m.clone()
        };
        assert_eq!(material_to_schlick(&unset).translucence, 0.3);
    }

    #[test]
    fn untextured_default_material_is_an_opaque_grey_stem() {
        let s = material_to_schlick(&Material::default());
        assert_eq!(s.layers[0], LEAF_DEFAULT.layers[0]);
        assert_eq!(s.layers[1].color, [0.8; 3]);
        assert_eq!(s.translucence, 0.0);
        assert_eq!(s.normal_map, NormalMap::None);
        s.validate().unwrap();
        let set = Material {
            translucence: Some(0.2),
            ..Material::default()
        };
        assert_eq!(material_to_schlick(&set).translucence, 0.2);
    }

    /// Seed 000 3.1.1's listing, as the TXF reader stores it.
    fn xfrog_default() -> Material {
        Material {
            name: "Default".into(),
            diffuse: [0.7, 0.7, 0.7, 1.0],
            ambient: [0.1, 0.1, 0.1, 1.0],
            specular: [0.0, 0.0, 0.0, 1.0],
            emission: [0.0, 0.0, 0.0, 1.0],
            shininess: 0.0,
            transparency: 0.0,
            translucence: Some(0.0),
            color_map: Some(1),
            normal_map: None,
            source: MaterialSource::FixedFunction,
            double_sided: true,
        }
    }

    #[test]
    fn xfrog_default_material_becomes_the_leaf() {
        let m = xfrog_default();
        assert!(is_default_xfrog(&m) && is_default_material(&m));
        assert!(!is_default_opengl(&m));
        let s = material_to_schlick(&m);
        s.validate().unwrap();
        // Table 3.1's leaf, written out (not through LEAF_DEFAULT): wax r 0.1, p 1, glossy 1,
        // 0.075 grey; cell layer diffuse 1, white × colour map; ±1 mm; τ 0.3 (TXF 0 = unset).
        let [top, bottom] = s.layers;
        assert_eq!(
            (
                top.roughness,
                top.isotropy,
                top.diffuse,
                top.glossy,
                top.specular
            ),
            (0.1, 1.0, 0.0, 1.0, 0.0)
        );
        assert_eq!(top.color, [0.075; 3]);
        assert_eq!(
            (bottom.diffuse, bottom.glossy, bottom.specular),
            (1.0, 0.0, 0.0)
        );
        assert_eq!(bottom.color, [1.0; 3]);
        assert_eq!((s.bump_height, s.translucence), (0.001, 0.3));
        assert_eq!(s.color_map, Some(1));
        assert_eq!(s.normal_map, NormalMap::FromColor(1));
        assert_eq!((s.emission, s.opacity), ([0.0; 3], 1.0));
        // The untextured-stem rule on top: the default's own 0.7 grey, τ from the set or 0.
        let stem = material_to_schlick(&Material {
            color_map: None,
            translucence: None,
            ..m.clone()
        });
        assert_eq!(stem.layers[0], top);
        assert_eq!(stem.layers[1].color, [0.7; 3]);
        assert_eq!((stem.translucence, stem.bump_height), (0.0, 0.0));
        assert_eq!(stem.normal_map, NormalMap::None);
        // Near misses stay authored: another ambient, a highlight, a tint.
        for other in [
            Material {
                ambient: [0.2, 0.2, 0.2, 1.0],
                ..m.clone()
            },
            Material {
                shininess: 10.0,
                ..m.clone()
            },
            Material {
                diffuse: [0.7, 0.6, 0.7, 1.0],
                ..m.clone()
            },
        ] {
            assert!(!is_default_material(&other), "{other:?}");
            assert_eq!(
                material_to_schlick(&other).layers[1].color,
                rgb(&other.diffuse)
            );
        }
    }

    #[test]
    fn authored_txf_material_maps_shininess_and_colours() {
        // A TXF <Colors> entry: diff 0.2 0.5 0.1 1, spec 0.3 0.3 0.3 1, shin 30, emis 0.
        let m = Material {
            name: "bark".into(),
            diffuse: [0.2, 0.5, 0.1, 1.0],
            ambient: [0.1, 0.1, 0.1, 1.0],
            specular: [0.3, 0.3, 0.3, 1.0],
            emission: [0.0, 0.0, 0.0, 1.0],
            shininess: 30.0,
            transparency: 0.25,
            translucence: None,
            color_map: Some(2),
            normal_map: None,
            source: MaterialSource::FixedFunction,
            double_sided: true,
        };
        assert!(!is_default_opengl(&m));
        let s = material_to_schlick(&m);
        s.validate().unwrap();
        let [top, bottom] = s.layers;
        // r = 2/(n+2) = 2/32.
        assert!((top.roughness - 0.0625).abs() < 1e-6);
        assert_eq!((top.diffuse, top.glossy, top.specular), (0.0, 1.0, 0.0));
        // 0.3 · 8/32: the thesis' wax reflectivity, 0.075.
        assert!(top.color.iter().all(|&c| (c - 0.075).abs() < 1e-6));
        assert_eq!(
            (bottom.diffuse, bottom.glossy, bottom.specular),
            (1.0, 0.0, 0.0)
        );
        assert_eq!(bottom.color, [0.2, 0.5, 0.1]);
        assert_eq!(s.translucence, 0.0);
        assert_eq!(s.opacity, 0.75);
        assert_eq!(s.normal_map, NormalMap::FromColor(2));
    }

    #[test]
    fn shininess_mapping_matches_blinn_phong_peak() {
        // Independent oracle: normalized Blinn-Phong (n+2)/(2π)·t^n and GGX with α² = 2/(n+2)
        // have the same value at t = 1: (n+2)/(2π) vs 1/(π α²).
        for n in [1.0f32, 10.0, 100.0] {
            let r = shininess_to_roughness(n);
            let ggx_peak = 1.0 / (std::f32::consts::PI * r);
            let phong_peak = (n + 2.0) / (2.0 * std::f32::consts::PI);
            assert!((ggx_peak - phong_peak).abs() < 1e-4 * phong_peak);
        }
    }

    #[test]
    fn gltf_metal_and_dielectric() {
        let base = Material {
            diffuse: [0.9, 0.6, 0.2, 1.0],
            ..Material::default()
        };
        let metal = Material {
            source: MaterialSource::MetallicRoughness {
                metallic: 1.0,
                roughness: 0.5,
            },
            ..base.clone()
        };
        let s = material_to_schlick(&metal);
        s.validate().unwrap();
        assert_eq!(s.layers[0].color, [0.9, 0.6, 0.2]);
        assert_eq!(s.layers[1].color, [0.0; 3]);
        assert!((s.layers[0].roughness - 0.0625).abs() < 1e-6);
        let plastic = Material {
            source: MaterialSource::MetallicRoughness {
                metallic: 0.0,
                roughness: 1.0,
            },
            ..base
        };
        let s = material_to_schlick(&plastic);
        assert_eq!(s.layers[0].color, [0.04; 3]);
        assert_eq!(s.layers[1].color, [0.9, 0.6, 0.2]);
        assert_eq!(s.normal_map, NormalMap::None);
    }
}
