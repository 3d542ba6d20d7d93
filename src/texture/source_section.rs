//! Kind `texture`: a decoded image, RGBA8 as stored in the source file (sRGB-encoded).

use crate::error::ParseError;
use crate::model::Rgba8Image;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// Section name of a texture referred to by `owner` (a model name, or "terrain").
pub fn texture_section_name(owner: &str, texture: &str) -> String {
    format!("texture:{owner}/{texture}")
}

pub const KIND: &str = "texture";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TextureMeta {
    pub width: u32,
    pub height: u32,
    /// Texel format: `rgba8_srgb` (8-bit, display-encoded) for ingested textures.
    pub format: String,
    pub source: String,
}

pub fn to_section(name: &str, source: &str, img: &Rgba8Image) -> Section {
    let meta = TextureMeta {
        width: img.width,
        height: img.height,
        format: "rgba8_srgb".into(),
        source: source.into(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("texels", ArrayFormat::U8, 4, &img.pixels);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(TextureMeta, Rgba8Image), ParseError> {
    let meta: TextureMeta = v.meta()?;
    // Processed textures (mips, linear f16): level 0 back in sRGB.
    if crate::texture::section::is_processed(&meta.format) {
        return crate::texture::section::level0_rgba8(v);
    }
    let pixels: Vec<[u8; 4]> = v.array_vec("texels")?;
    if pixels.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(ParseError::new(
            "texture section",
            "texel count does not match width × height",
        ));
    }
    Ok((
        meta.clone(),
        Rgba8Image {
            width: meta.width,
            height: meta.height,
            pixels,
        },
    ))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta: TextureMeta = v.meta()?;
    if crate::texture::section::is_processed(&meta.format) {
        return crate::texture::section::summary(v);
    }
    // An ingested texture is one level; coverage: fraction of texels passing the 0.5 alpha test.
    let texels: &[[u8; 4]] = v.array("texels")?;
    let pass = texels.iter().filter(|p| p[3] >= 128).count();
    let coverage = pass as f64 / texels.len().max(1) as f64;
    Ok(
        json!({"width": meta.width, "height": meta.height, "format": meta.format, "source": meta.source,
               "mips": 1, "coverage": [coverage]}),
    )
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let meta: TextureMeta = v.meta()?;
    if crate::texture::section::is_processed(&meta.format) {
        return crate::texture::section::data(v);
    }
    let (_, img) = from_section(v)?;
    Ok(json!({ "texels": img.pixels }))
}
