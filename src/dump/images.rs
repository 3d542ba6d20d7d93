//! `bake dump PACK --png DIR`: every image-like section as files a user can open.
//!
//! - `texture` (processed): each colour mip as sRGB RGBA8 PNG (`.color.mipK.png`), each normal
//!   mip as RGBA8 PNG (xyz·½+½, alpha = the averaged normal's length, the Toksvig input:
//!   `.normal.mipK.png`), each height mip as 16-bit grey (`.height.mipK.png`); a source texture
//!   (`rgba8`) as it was read (`.png`).
//! - `terrain`: the heights as 16-bit grey from the lowest (0) to the highest sample (65535)
//!   (`.height.png`) and, when prepared, the normal map (`.normal.png`); north up, as the colour
//!   map.
//! - `lightmap` (terrain, north up, and object atlases), `sky` (the six cube faces
//!   `.face+X.png` ... in storage order, and a 2:1 lat-long `.latlong.png`, bilinear from the
//!   cube; or a source lat-long sky): tone-mapped PNG and linear OpenEXR (RGB, f32) of the same
//!   texels. The tone map is 1 − exp(−L·s) per channel, sRGB-encoded, with s = ln 2 / mean
//!   luminance, so the image's mean maps to half the display range.
//!
//! File names are the section's name with every character outside `A-Za-z0-9._-` replaced by
//! `_`, then the suffixes above. Pure: returns the files' bytes; `cli::dump` writes them.

use crate::error::{Error, ParseError, Result};
use crate::model::FloatImage;
use crate::pack::Pack;
use crate::pack::section::SectionView;
use std::collections::BTreeSet;

/// One file of `--png`: its name in the folder, its bytes, and what it shows.
#[derive(Debug, Clone)]
pub struct ImageFile {
    /// The file's name in the folder.
    pub file: String,
    /// The section it shows.
    pub section: String,
    /// What it shows (a texture, a face of the sky, a light map, ...).
    pub what: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The PNG file's bytes.
    pub bytes: Vec<u8>,
}

/// The files of every image-like section of `pack`, in section order.
pub fn section_images(pack: &Pack) -> Result<Vec<ImageFile>> {
    let mut out = Vec::new();
    let mut stems = BTreeSet::new();
    for e in pack.sections() {
        let v = pack.view(e)?;
        let mut stem = sanitize(&e.name);
        let mut n = 2;
        while !stems.insert(stem.clone()) {
            stem = format!("{}-{n}", sanitize(&e.name));
            n += 1;
        }
        let mut files = Files {
            stem,
            section: e.name.clone(),
            out: &mut out,
        };
        let at = |err: ParseError| {
            let place = format!("section {:?}, {}", e.name, err.place);
            Error::invalid(pack.path(), ParseError::new(place, err.message))
        };
        match e.kind.as_str() {
            "texture" => texture(&v, &mut files).map_err(at)?,
            "terrain" => terrain(&v, &mut files).map_err(at)?,
            "lightmap" => lightmap(&v, &mut files).map_err(at)?,
            "sky" => sky(&v, &mut files).map_err(at)?,
            "lod" => lod(&v, &mut files).map_err(at)?,
            _ => {}
        }
    }
    Ok(out)
}

fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

struct Files<'a> {
    stem: String,
    section: String,
    out: &'a mut Vec<ImageFile>,
}

impl Files<'_> {
    fn push(&mut self, suffix: &str, what: &str, (width, height): (u32, u32), bytes: Vec<u8>) {
        self.out.push(ImageFile {
            file: format!("{}{suffix}", self.stem),
            section: self.section.clone(),
            what: what.to_string(),
            width,
            height,
            bytes,
        });
    }

    /// A linear RGB image as a tone-mapped PNG and an OpenEXR file.
    fn hdr(&mut self, suffix: &str, what: &str, img: &FloatImage) -> Result<(), ParseError> {
        let size = (img.width, img.height);
        let mapped =
            crate::render::reference::tone_map_image(&img.pixels, exposure(&img.pixels), size);
        let png = rgba8_png(img.width, img.height, &mapped.pixels)?;
        self.push(&format!("{suffix}.png"), what, size, png);
        self.push(&format!("{suffix}.exr"), what, size, exr_rgb(img)?);
        Ok(())
    }
}

fn encode_error(e: impl std::fmt::Display) -> ParseError {
    ParseError::new("image encoding", e.to_string())
}

fn rgba8_png(width: u32, height: u32, pixels: &[[u8; 4]]) -> Result<Vec<u8>, ParseError> {
    let img = crate::model::Rgba8Image {
        width,
        height,
        pixels: pixels.to_vec(),
    };
    crate::render::encode_png(&img).map_err(encode_error)
}

fn grey16_png(width: u32, height: u32, values: &[u16]) -> Result<Vec<u8>, ParseError> {
    let buf = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(width, height, values.to_vec())
        .ok_or_else(|| encode_error("image buffer does not match its size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut out, image::ImageFormat::Png)
        .map_err(encode_error)?;
    Ok(out.into_inner())
}

/// Linear RGB, f32 channels, one scan line per block.
pub fn exr_rgb(img: &FloatImage) -> Result<Vec<u8>, ParseError> {
    use exr::prelude::*;
    let w = img.width as usize;
    let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
        let t = img.pixels[p.y() * w + p.x()];
        (t[0], t[1], t[2])
    });
    let image = Image::from_channels((w, img.height as usize), channels);
    let mut out = std::io::Cursor::new(Vec::new());
    image
        .write()
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(encode_error)?;
    Ok(out.into_inner())
}

/// The exposure of the tone map (`render::reference::tone_map`): ln 2 over the mean finite luminance (1 for a black image).
pub fn exposure(texels: &[[f32; 3]]) -> f32 {
    let (sum, n) = texels
        .iter()
        .map(crate::color::luminance)
        .filter(|l| l.is_finite() && *l >= 0.0)
        .fold((0.0f64, 0usize), |(s, n), l| (s + l as f64, n + 1));
    let mean = if n > 0 { sum / n as f64 } else { 0.0 };
    if mean > 0.0 {
        (std::f64::consts::LN_2 / mean) as f32
    } else {
        1.0
    }
}

/// Rows in reverse order (row 0 south becomes the bottom row of the file).
fn flip_rows<T: Clone>(v: &[T], width: u32) -> Vec<T> {
    v.chunks(width.max(1) as usize)
        .rev()
        .flatten()
        .cloned()
        .collect()
}

fn texture(v: &SectionView, f: &mut Files) -> Result<(), ParseError> {
    let meta: crate::texture::source_section::TextureMeta = v.meta()?;
    if !crate::texture::section::is_processed(&meta.format) {
        let (_, img) = crate::texture::source_section::from_section(v)?;
        let png = rgba8_png(img.width, img.height, &img.pixels)?;
        f.push(
            ".png",
            "source texture (as read)",
            (img.width, img.height),
            png,
        );
        return Ok(());
    }
    let (_, t) = crate::texture::section::from_section(v)?;
    if let Some(color) = &t.color {
        for (k, l) in color.levels.iter().enumerate() {
            let px = crate::texture::linear::encode_rgba8(
                &l.texels,
                crate::texture::linear::TransferFunction::Srgb,
            );
            let what = format!("colour mip {k} (sRGB, straight alpha)");
            let png = rgba8_png(l.width, l.height, &px)?;
            f.push(
                &format!(".color.mip{k}.png"),
                &what,
                (l.width, l.height),
                png,
            );
        }
    }
    for (k, l) in t.normals.levels.iter().enumerate() {
        let px: Vec<[u8; 4]> = l
            .texels
            .iter()
            .map(|&(n, len)| crate::texture::normalmap::encode_normal(n, len))
            .collect();
        let what = format!("normal mip {k} (xyz·½+½, alpha: averaged length)");
        let png = rgba8_png(l.width, l.height, &px)?;
        f.push(
            &format!(".normal.mip{k}.png"),
            &what,
            (l.width, l.height),
            png,
        );
    }
    for (k, l) in t.heights.iter().flatten().enumerate() {
        let px: Vec<u16> = l
            .texels
            .iter()
            .map(|h| (h.clamp(0.0, 1.0) * 65535.0).round() as u16)
            .collect();
        let what = format!("height mip {k} (0..1 as 16-bit grey)");
        let png = grey16_png(l.width, l.height, &px)?;
        f.push(
            &format!(".height.mip{k}.png"),
            &what,
            (l.width, l.height),
            png,
        );
    }
    Ok(())
}

fn terrain(v: &SectionView, f: &mut Files) -> Result<(), ParseError> {
    let (_, t) = crate::terrain::source_section::from_section(v)?;
    let (lo, hi) = t
        .heights
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &h| {
            (a.min(h), b.max(h))
        });
    let span = if hi > lo { hi - lo } else { 1.0 };
    let grey: Vec<u16> = t
        .heights
        .iter()
        .map(|&h| ((h - lo) / span * 65535.0).round().clamp(0.0, 65535.0) as u16)
        .collect();
    let what = format!("heights {lo} m (black) to {hi} m (white), north up");
    let png = grey16_png(t.width, t.height, &flip_rows(&grey, t.width))?;
    f.push(".height.png", &what, (t.width, t.height), png);
    if v.info("normals").is_some() {
        let normals: Vec<[u8; 4]> = v.array_vec("normals")?;
        if normals.len() == t.heights.len() {
            let png = rgba8_png(t.width, t.height, &flip_rows(&normals, t.width))?;
            f.push(
                ".normal.png",
                "normal map as stored, north up",
                (t.width, t.height),
                png,
            );
        }
    }
    Ok(())
}

fn lightmap(v: &SectionView, f: &mut Files) -> Result<(), ParseError> {
    if crate::lightmap::atlas_section::is_atlas(v) {
        let (_, a) = crate::lightmap::atlas_section::from_section(v)?;
        let img = FloatImage {
            width: a.width,
            height: a.height,
            pixels: a.texels,
        };
        return f.hdr(
            "",
            "object light-map atlas (irradiance), row 0 at v = 0",
            &img,
        );
    }
    let (_, m) = crate::lightmap::section::from_section(v)?;
    let img = FloatImage {
        width: m.width,
        height: m.height,
        pixels: m.texels,
    };
    f.hdr("", "terrain light map (irradiance), north up", &img)
}

/// The impostor atlas of a `lod` section: albedo with alpha, and the normal as stored.
fn lod(v: &SectionView, f: &mut Files) -> Result<(), ParseError> {
    let view = crate::lod::section::from_view(v, None)?;
    let (Some(m), Some(a)) = (&view.meta.impostor, &view.impostor) else {
        return Ok(());
    };
    let side = m.side() as u32;
    let color = rgba8_png(side, side, a.color)?;
    f.push(
        ".impostor-color.png",
        "impostor atlas: sRGB albedo, alpha-tested coverage (hemi-octahedral views, row 0 at the top)",
        (side, side),
        color,
    );
    let normal = rgba8_png(side, side, a.normal)?;
    f.push(
        ".impostor-normal.png",
        "impostor atlas: (n+1)/2 of the model-space normal, A = coverage",
        (side, side),
        normal,
    );
    Ok(())
}

fn sky(v: &SectionView, f: &mut Files) -> Result<(), ParseError> {
    if let Ok((_, cube)) = crate::sky::section::cube_from_section(v) {
        for face in crate::cube::Face::ALL {
            let img = FloatImage {
                width: cube.size,
                height: cube.size,
                pixels: cube.face(face).to_vec(),
            };
            let what = format!("sky cube face {} (radiance)", face.name());
            f.hdr(&format!(".face{}", face.name()), &what, &img)?;
        }
        let ll = crate::sky::cube_to_latlong(&cube, 4 * cube.size, 2 * cube.size);
        return f.hdr(".latlong", "sky lat-long from the cube (radiance)", &ll);
    }
    let (_, img) = crate::sky::source_section::from_section(v)?;
    f.hdr(".latlong", "source sky lat-long (radiance)", &img)
}
