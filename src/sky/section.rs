//! Pack sections of the sky stage and their `dump` views:
//!
//! - kind `sky`, layout `cube`: the sun-free sky as a cube map, `texels` = 6·size² × RGBA half
//!   floats (f16 bits, alpha 1), faces +X, −X, +Y, −Y, +Z, −Z, each row-major from row 0 (the
//!   layout `crate::cube` documents), ready for a `Rgba16Float` cube texture upload. The
//!   metadata starts with the same fields as the lat-long `sky` kind (`sky::source_section`), so one
//!   summary serves both. Radiance above the f16 maximum (65504) is clamped and counted.
//! - kind `sun`: the extracted sun ([`Sun`]), metadata only.
//! - kind `sh`: the sun-free sky's order-4 SH, `radiance` and `irradiance` (16 × RGB f32 each).

use super::cube::CubeMap;
use super::sun::{SkyIrradiance, Sun};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use crate::sh::{COEFFS, ORDER, ShIrradiance, ShRadiance};
use exr::prelude::f16;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const SKY_KIND: &str = crate::sky::source_section::KIND;
pub const SUN_KIND: &str = "sun";
pub const SH_KIND: &str = "sh";
/// The `layout` of a cube-map sky section.
pub const CUBE_LAYOUT: &str = "cube";
/// Largest finite half float.
const F16_MAX: f32 = 65504.0;

/// Metadata of a cube-map sky section (the first four fields are `source_section::SkyMeta`'s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CubeSkyMeta {
    /// Face size (texels per edge).
    pub width: u32,
    /// Face size again (square faces).
    pub height: u32,
    /// Always `cube`.
    pub layout: String,
    pub source: String,
    pub faces: u32,
    /// `rgba16f`.
    pub format: String,
    /// Texels clamped to the f16 range.
    pub clamped: u64,
    /// Irradiance of this (sun-free) sky.
    pub sky: SkyIrradiance,
}

/// Encodes the sun-free sky cube map.
pub fn cube_to_section(name: &str, source: &str, cube: &CubeMap, sky: &SkyIrradiance) -> Section {
    use rayon::prelude::*;
    let clamped = cube
        .texels
        .par_iter()
        .filter(|t| t.iter().any(|&v| v.is_nan() || v.abs() > F16_MAX))
        .count() as u64;
    // NaN becomes 0; ±∞ and out-of-range values the largest half float.
    let h = |v: f32| {
        f16::from_f32(if v.is_nan() {
            0.0
        } else {
            v.clamp(-F16_MAX, F16_MAX)
        })
        .to_bits()
    };
    // (Converted straight into the section's buffer, in parallel.)
    let fill = move |out: &mut [[u16; 4]]| {
        out.par_iter_mut()
            .zip(&cube.texels)
            .for_each(|(o, t)| *o = [h(t[0]), h(t[1]), h(t[2]), h(1.0)]);
    };
    let meta = CubeSkyMeta {
        width: cube.size,
        height: cube.size,
        layout: CUBE_LAYOUT.into(),
        source: source.into(),
        faces: 6,
        format: "rgba16f".into(),
        clamped,
        sky: *sky,
    };
    let mut b = SectionBuilder::new(SKY_KIND, name);
    b.meta(&meta)
        .array_fill("texels", ArrayFormat::F16, 4, cube.texels.len(), fill);
    b.finish()
}

/// Decodes a cube-map sky section.
pub fn cube_from_section(v: &SectionView) -> Result<(CubeSkyMeta, CubeMap), ParseError> {
    let meta: CubeSkyMeta = v.meta()?;
    if meta.layout != CUBE_LAYOUT || meta.width != meta.height || meta.faces != 6 {
        return Err(ParseError::new(
            "sky section",
            format!(
                "layout {:?} {}×{} with {} faces; expected a cube of 6 square faces",
                meta.layout, meta.width, meta.height, meta.faces
            ),
        ));
    }
    let texels: &[[u16; 4]] = v.array("texels")?;
    if texels.len() as u64 != 6 * meta.width as u64 * meta.width as u64 {
        return Err(ParseError::new(
            "sky section",
            "texel count does not match 6 × size²",
        ));
    }
    let texels = texels
        .iter()
        .map(|t| [0, 1, 2].map(|k| f16::from_bits(t[k]).to_f32()))
        .collect();
    let size = meta.width;
    Ok((meta, CubeMap { size, texels }))
}

/// Summary of a cube-map sky section (called by `source_section::summary` for layout `cube`).
pub fn cube_summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, cube) = cube_from_section(v)?;
    let max = cube.texels.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
    Ok(json!({
        "width": meta.width, "height": meta.height, "layout": meta.layout, "faces": meta.faces,
        "format": meta.format, "max_radiance": max, "clamped": meta.clamped, "source": meta.source,
        "irradiance_horizontal": meta.sky.horizontal, "I_H_thesis": meta.sky.thesis,
    }))
}

/// Full data of a cube-map sky section: texels per face (RGB).
pub fn cube_data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, cube) = cube_from_section(v)?;
    let faces: Vec<Value> = super::cube::Face::ALL
        .iter()
        .map(|&f| json!({"face": f.name(), "texels": cube.face(f)}))
        .collect();
    Ok(json!({ "faces": faces }))
}

/// Encodes the sun.
pub fn sun_to_section(name: &str, sun: &Sun) -> Section {
    let mut b = SectionBuilder::new(SUN_KIND, name);
    b.meta(sun);
    b.finish()
}

pub fn sun_from_section(v: &SectionView) -> Result<Sun, ParseError> {
    v.meta()
}

pub fn sun_summary(v: &SectionView) -> Result<Value, ParseError> {
    serde_json::to_value(sun_from_section(v)?)
        .map_err(|e| ParseError::new("sun section", e.to_string()))
}

pub fn sun_data(v: &SectionView) -> Result<Value, ParseError> {
    sun_summary(v)
}

/// Metadata of an `sh` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShMeta {
    pub order: u32,
    /// What the coefficients describe, e.g. `sky radiance without the sun`.
    pub content: String,
    /// The basis convention, spelled out.
    pub convention: String,
}

/// Encodes radiance SH and their irradiance convolution.
pub fn sh_to_section(name: &str, content: &str, sh: &ShRadiance) -> Section {
    let meta = ShMeta {
        order: ORDER as u32,
        content: content.into(),
        convention: "real orthonormal, Condon-Shortley phase, index l(l+1)+m".into(),
    };
    let mut b = SectionBuilder::new(SH_KIND, name);
    b.meta(&meta)
        .array("radiance", ArrayFormat::F32, 3, &sh.coeffs)
        .array(
            "irradiance",
            ArrayFormat::F32,
            3,
            &sh.to_irradiance().coeffs,
        );
    b.finish()
}

pub fn sh_from_section(v: &SectionView) -> Result<(ShMeta, ShRadiance, ShIrradiance), ParseError> {
    let meta: ShMeta = v.meta()?;
    let read = |name: &str| -> Result<[[f32; 3]; COEFFS], ParseError> {
        let c: Vec<[f32; 3]> = v.array_vec(name)?;
        c.try_into().map_err(|c: Vec<_>| {
            ParseError::new(
                "sh section",
                format!(
                    "array {name:?} holds {} coefficients, expected {COEFFS}",
                    c.len()
                ),
            )
        })
    };
    if meta.order as usize != ORDER {
        return Err(ParseError::new(
            "sh section",
            format!("order {}; this build reads order {ORDER}", meta.order),
        ));
    }
    let radiance = ShRadiance {
        coeffs: read("radiance")?,
    };
    let irradiance = ShIrradiance {
        coeffs: read("irradiance")?,
    };
    Ok((meta, radiance, irradiance))
}

pub fn sh_summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, r, _) = sh_from_section(v)?;
    Ok(
        json!({"order": meta.order, "content": meta.content, "convention": meta.convention, "coefficients": r.coeffs}),
    )
}

pub fn sh_data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, r, e) = sh_from_section(v)?;
    Ok(json!({"radiance": r.coeffs, "irradiance": e.coeffs}))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pack::{Pack, PackWriter};
    use crate::sky::sun::{SunOptions, extract_sun, sky_irradiance};

    fn pack_of(sections: Vec<Section>) -> Vec<u8> {
        let mut w = PackWriter::new();
        for s in sections {
            w.insert(s);
        }
        w.to_bytes().unwrap()
    }

    #[test]
    fn sections_round_trip_and_dump() {
        let mut cube = CubeMap::from_fn(8, |d| [d[0] as f32 + 2.0, 1.5, 1e6]);
        cube.texels[3][0] = 7.0;
        let (free, sun) = extract_sun(&cube, &SunOptions::default());
        let sky = sky_irradiance(&free);
        let sh = crate::sh::project_cube(&free);
        let bytes = pack_of(vec![
            cube_to_section("sky", "test", &free, &sky),
            sun_to_section("sun", &sun),
            sh_to_section("sh", "sky radiance without the sun", &sh),
        ]);
        let pack = Pack::from_bytes(&bytes, "t.bake").unwrap();
        let (meta, back) = cube_from_section(&pack.view_named("sky").unwrap()).unwrap();
        assert_eq!(meta.clamped, free.texels.len() as u64); // every texel had 1e6 in blue
        for (a, b) in free.texels.iter().zip(&back.texels) {
            assert!((a[0] - b[0]).abs() <= a[0].abs() * 1e-3); // f16: 11-bit mantissa
            assert_eq!(b[2], 65504.0);
        }
        assert_eq!(
            sun_from_section(&pack.view_named("sun").unwrap()).unwrap(),
            sun
        );
        let (_, r, e) = sh_from_section(&pack.view_named("sh").unwrap()).unwrap();
        assert_eq!((r, e), (sh, sh.to_irradiance()));
        let doc = crate::dump::dump_json(
            &pack,
            &crate::dump::DumpOptions {
                full: true,
                section: None,
            },
        )
        .unwrap();
        let s = &doc["sections"][0]["summary"];
        assert_eq!(
            (s["width"].as_u64(), s["layout"].as_str()),
            (Some(8), Some("cube"))
        );
        assert_eq!(s["faces"], 6);
        assert_eq!(doc["sections"][1]["summary"]["texels"], sun.texels);
        assert_eq!(doc["sections"][2]["summary"]["order"], 4);
        assert_eq!(doc["sections"][0]["data"]["faces"][4]["face"], "+Z");
    }

    #[test]
    fn a_truncated_cube_section_is_an_error_not_a_panic() {
        let cube = CubeMap::filled(4, [1.0; 3]);
        let s = cube_to_section("sky", "", &cube, &sky_irradiance(&cube));
        let mut b = SectionBuilder::new(SKY_KIND, "sky");
        let mut meta: CubeSkyMeta = SectionView::parse(&s.payload, 0).unwrap().meta().unwrap();
        meta.width = 5;
        meta.height = 5;
        b.meta(&meta)
            .array("texels", ArrayFormat::F16, 4, &[[0u16; 4]; 96]);
        let bytes = pack_of(vec![b.finish()]);
        let pack = Pack::from_bytes(&bytes, "t.bake").unwrap();
        let e = cube_from_section(&pack.view_named("sky").unwrap()).unwrap_err();
        assert!(e.message.contains("texel count"), "{e}");
    }
}
