//! Kind `sky`: the sky as a linear float image (lat-long as ingested; see docs/CONVENTIONS.md).

use crate::error::ParseError;
use crate::model::FloatImage;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "sky";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkyMeta {
    pub width: u32,
    pub height: u32,
    /// `latlong` for an ingested image.
    pub layout: String,
    pub source: String,
}

pub fn to_section(name: &str, source: &str, img: &FloatImage) -> Section {
    let meta = SkyMeta {
        width: img.width,
        height: img.height,
        layout: "latlong".into(),
        source: source.into(),
    };
    let texels: Vec<[f32; 4]> = img.pixels.iter().map(|p| [p[0], p[1], p[2], 1.0]).collect();
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta).array("texels", ArrayFormat::F32, 4, &texels);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(SkyMeta, FloatImage), ParseError> {
    let meta: SkyMeta = v.meta()?;
    if meta.layout == crate::sky::section::CUBE_LAYOUT {
        return Err(ParseError::new(
            "sky section",
            "a cube-map sky; read it with sky::section::cube_from_section",
        ));
    }
    let texels: Vec<[f32; 4]> = v.array_vec("texels")?;
    if texels.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(ParseError::new(
            "sky section",
            "texel count does not match width × height",
        ));
    }
    let pixels = texels.iter().map(|t| [t[0], t[1], t[2]]).collect();
    Ok((
        meta.clone(),
        FloatImage {
            width: meta.width,
            height: meta.height,
            pixels,
        },
    ))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    if is_cube(v)? {
        return crate::sky::section::cube_summary(v);
    }
    let (meta, img) = from_section(v)?;
    let max = img.pixels.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
    Ok(
        json!({"width": meta.width, "height": meta.height, "layout": meta.layout, "max_radiance": max, "source": meta.source}),
    )
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    if is_cube(v)? {
        return crate::sky::section::cube_data(v);
    }
    let (_, img) = from_section(v)?;
    Ok(json!({ "texels": img.pixels }))
}

/// Whether a `sky` section holds a cube map (layout `cube`, written by `crate::sky::section`)
/// rather than a lat-long image; the cube's metadata starts with [`SkyMeta`]'s fields.
pub fn is_cube(v: &SectionView) -> Result<bool, ParseError> {
    let meta: SkyMeta = v.meta()?;
    Ok(meta.layout == crate::sky::section::CUBE_LAYOUT)
}
