//! Processed textures as kind `texture` sections (the same kind and metadata as ingested
//! textures, told apart by `format`; see src/texture/source_section.rs).
//!
//! Formats and arrays (all levels concatenated, level 0 first, each row-major, row 0 at the top):
//!
//! | format | arrays |
//! |---|---|
//! | `rgba16f_linear` (colour map) | `texels` u8×4 (the input, as ingested), `levels` u32×4 (width, height, first texel, texel count), `color` f16×4 (linear RGB, straight alpha scaled for coverage), `coverage` f32 and `alpha_scale` f32 per level, `normal` u8×4, `height` f16 |
//! | `normal_rgba8` (authored normal map) | `texels`, `levels`, `normal` u8×4 |
//!
//! `normal`: `(r, g, b) = (n + 1)/2` of the unit normal, `a` = length of the filtered normal
//! (Toksvig; 255 at level 0). The `levels` table applies to every per-texel array.

use super::mips::{ColorMips, MipLevel};
use super::normalmap::{NormalMips, encode_normal, normalize};
use super::{ProcessedTexture, TextureRole};
use crate::error::ParseError;
use crate::model::Rgba8Image;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use crate::texture::source_section::{KIND, TextureMeta};
use half::f16;
use rayon::prelude::*;
use serde_json::{Value, json};

pub const FORMAT_COLOR: &str = "rgba16f_linear";
pub const FORMAT_NORMAL: &str = "normal_rgba8";

/// Whether a texture section's format is one this module writes.
pub fn is_processed(format: &str) -> bool {
    format == FORMAT_COLOR || format == FORMAT_NORMAL
}

fn level_table<T>(levels: &[MipLevel<T>]) -> Vec<[u32; 4]> {
    let mut first = 0u32;
    levels
        .iter()
        .map(|l| {
            let n = l.texels.len() as u32;
            let row = [l.width, l.height, first, n];
            first += n;
            row
        })
        .collect()
}

/// Encodes a processed texture; `original` (the decoded input) is kept as the ingest `texels`
/// array so readers of the ingest layout (the renderer, the PRT alpha test) keep working.
pub fn to_section(
    name: &str,
    source: &str,
    original: &Rgba8Image,
    t: &ProcessedTexture,
) -> Section {
    let base = &t.normals.levels[0];
    let format = match t.role {
        TextureRole::Color => FORMAT_COLOR,
        TextureRole::Normal => FORMAT_NORMAL,
    };
    let meta = TextureMeta {
        width: base.width,
        height: base.height,
        format: format.into(),
        source: source.into(),
    };
    let mut normal: Vec<[u8; 4]> = Vec::new();
    for l in &t.normals.levels {
        normal.par_extend(l.texels.par_iter().map(|&(n, len)| encode_normal(n, len)));
    }
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("texels", ArrayFormat::U8, 4, &original.pixels)
        .array(
            "levels",
            ArrayFormat::U32,
            4,
            &level_table(&t.normals.levels),
        );
    if let Some(c) = &t.color {
        let mut color: Vec<[u16; 4]> = Vec::new();
        for l in &c.levels {
            color.par_extend(
                l.texels
                    .par_iter()
                    .map(|p| p.map(|x| f16::from_f32(x).to_bits())),
            );
        }
        b.array("color", ArrayFormat::F16, 4, &color)
            .array("coverage", ArrayFormat::F32, 1, &c.coverage)
            .array("alpha_scale", ArrayFormat::F32, 1, &c.alpha_scale);
    }
    b.array("normal", ArrayFormat::U8, 4, &normal);
    if let Some(h) = &t.heights {
        let heights: Vec<u16> = h
            .iter()
            .flat_map(|l| l.texels.iter().map(|&x| f16::from_f32(x).to_bits()))
            .collect();
        b.array("height", ArrayFormat::F16, 1, &heights);
    }
    b.finish()
}

/// The level table, checked against the base size and the array lengths.
pub fn levels(
    v: &SectionView,
    meta: &TextureMeta,
    array: &str,
) -> Result<Vec<[u32; 4]>, ParseError> {
    let table: Vec<[u32; 4]> = v.array_vec("levels")?;
    let count = v.info(array).map_or(0, |a| a.count);
    let sizes = super::mips::mip_sizes(meta.width, meta.height);
    let mut first = 0u64;
    let ok = table.len() == sizes.len()
        && table.iter().zip(&sizes).all(|(row, &(w, h))| {
            let good = row[0] == w
                && row[1] == h
                && row[2] as u64 == first
                && row[3] as u64 == w as u64 * h as u64;
            first += row[3] as u64;
            good
        })
        && first == count;
    if !ok {
        return Err(ParseError::new(
            "texture section, array levels",
            format!(
                "mip table does not describe a {}×{} chain of {count} {array} texels",
                meta.width, meta.height
            ),
        ));
    }
    Ok(table)
}

fn split<T: Clone>(flat: &[T], table: &[[u32; 4]]) -> Vec<MipLevel<T>> {
    table
        .iter()
        .map(|r| MipLevel {
            width: r[0],
            height: r[1],
            texels: flat[r[2] as usize..(r[2] + r[3]) as usize].to_vec(),
        })
        .collect()
}

/// Decodes a processed texture section (f16 widened to f32, normals decoded).
pub fn from_section(v: &SectionView) -> Result<(TextureMeta, ProcessedTexture), ParseError> {
    let meta: TextureMeta = v.meta()?;
    let table = levels(v, &meta, "normal")?;
    let normal: Vec<[u8; 4]> = v.array_vec("normal")?;
    let decode = |p: &[u8; 4]| {
        let n = [0, 1, 2].map(|k| p[k] as f32 / 255.0 * 2.0 - 1.0);
        (normalize(n), p[3] as f32 / 255.0)
    };
    let normals = NormalMips {
        levels: split(&normal.iter().map(decode).collect::<Vec<_>>(), &table),
    };
    let (role, color, heights) = if meta.format == super::section::FORMAT_COLOR {
        let color: Vec<[u16; 4]> = v.array_vec("color")?;
        let heights: Vec<u16> = v.array_vec("height")?;
        if color.len() != normal.len() || heights.len() != normal.len() {
            return Err(ParseError::new(
                "texture section",
                "color, height and normal arrays differ in length",
            ));
        }
        let widen = |b: u16| f16::from_bits(b).to_f32();
        let color_levels = split(
            &color.iter().map(|p| p.map(widen)).collect::<Vec<_>>(),
            &table,
        );
        let coverage: Vec<f32> = v.array_vec("coverage")?;
        let alpha_scale: Vec<f32> = v.array_vec("alpha_scale")?;
        if coverage.len() != table.len() || alpha_scale.len() != table.len() {
            return Err(ParseError::new(
                "texture section",
                "coverage or alpha_scale is not one value per level",
            ));
        }
        let heights = split(
            &heights.iter().map(|&b| widen(b)).collect::<Vec<_>>(),
            &table,
        );
        let mips = ColorMips {
            levels: color_levels,
            coverage,
            alpha_scale,
        };
        (TextureRole::Color, Some(mips), Some(heights))
    } else {
        (TextureRole::Normal, None, None)
    };
    Ok((
        meta,
        ProcessedTexture {
            role,
            color,
            normals,
            heights,
        },
    ))
}

/// Level 0 as an sRGB RGBA8 image (for readers that only want a picture).
pub fn level0_rgba8(v: &SectionView) -> Result<(TextureMeta, Rgba8Image), ParseError> {
    let (meta, t) = from_section(v)?;
    let pixels = match &t.color {
        Some(c) => {
            super::linear::encode_rgba8(&c.levels[0].texels, super::linear::TransferFunction::Srgb)
        }
        None => t.normals.levels[0]
            .texels
            .iter()
            .map(|&(n, len)| encode_normal(n, len))
            .collect(),
    };
    let img = Rgba8Image {
        width: meta.width,
        height: meta.height,
        pixels,
    };
    Ok((meta, img))
}

/// Summary of a processed texture: the ingest keys plus `mips` and `coverage` per level.
pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta: TextureMeta = v.meta()?;
    let table = levels(v, &meta, "normal")?;
    let coverage: Vec<f32> = if v.info("coverage").is_some() {
        v.array_vec("coverage")?
    } else {
        Vec::new()
    };
    let role = if meta.format == FORMAT_COLOR {
        "color"
    } else {
        "normal"
    };
    Ok(json!({
        "width": meta.width, "height": meta.height, "format": meta.format, "source": meta.source,
        "role": role, "mips": table.len(), "coverage": coverage,
    }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, t) = from_section(v)?;
    let levels: Vec<Value> = t
        .normals
        .levels
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let mut o = json!({"width": l.width, "height": l.height,
                "normal": l.texels.iter().map(|&(n, len)| encode_normal(n, len)).collect::<Vec<_>>()});
            if let Some(c) = &t.color {
                o["color"] = json!(c.levels[k].texels);
                o["coverage"] = json!(c.coverage[k]);
                o["alpha_scale"] = json!(c.alpha_scale[k]);
            }
            o
        })
        .collect();
    Ok(json!({ "levels": levels }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{TextureOptions, process_texture};

    fn sample_image() -> Rgba8Image {
        let leaf = crate::texture::mips::tests::leaf(64);
        let pixels = crate::texture::linear::encode_rgba8(
            &leaf.texels,
            crate::texture::linear::TransferFunction::Srgb,
        );
        Rgba8Image {
            width: 64,
            height: 64,
            pixels,
        }
    }

    #[test]
    fn processed_texture_round_trips_through_a_pack() {
        let img = sample_image();
        let t = process_texture(&img, TextureRole::Color, &TextureOptions::for_size(64, 64));
        let s = to_section("texture:leaf/leaf.png", "leaf.png", &img, &t);
        let mut w = crate::pack::PackWriter::new();
        w.insert(s);
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
        let view = pack.view_named("texture:leaf/leaf.png").unwrap();
        let (meta, back) = from_section(&view).unwrap();
        assert_eq!(meta.format, FORMAT_COLOR);
        let (c0, c1) = (t.color.as_ref().unwrap(), back.color.as_ref().unwrap());
        assert_eq!(c0.coverage, c1.coverage);
        assert_eq!(c1.levels.len(), 7);
        for (a, b) in c0.levels[0].texels.iter().zip(&c1.levels[0].texels) {
            for k in 0..4 {
                assert!((a[k] - b[k]).abs() <= 1e-3 * a[k].abs().max(1.0));
            }
        }
        // The shared `texture` kind's summary carries mips and coverage.
        let sum = crate::texture::source_section::summary(&view).unwrap();
        assert_eq!(sum["mips"], 7);
        assert_eq!(sum["coverage"].as_array().unwrap().len(), 7);
        // Level 0 back to sRGB equals the input, and the ingest texels are kept as they were.
        assert_eq!(view.array::<[u8; 4]>("texels").unwrap(), &img.pixels[..]);
        let (_, l0) = level0_rgba8(&view).unwrap();
        assert_eq!(l0.pixels, img.pixels);
    }
}
