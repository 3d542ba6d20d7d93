//! HDR sky images: Radiance RGBE `.hdr` (`ingest::rgbe`) and OpenEXR `.exr` (crate `exr`) read as
//! linear float RGB images, plus a small uncompressed RGBE writer for fixtures and tests.
//!
//! Readers take bytes ([`parse_hdr`], [`parse_exr`]) so tests and fuzzers drive them directly;
//! [`load`] reads a file and picks the reader by extension. The image is returned as stored
//! (row 0 at the top); what layout it has (lat-long, cross, face) is decided by `crate::sky`.

use super::rgbe::{RgbeBytes, RgbeImage};
use crate::error::{Error, ParseError, Result, read_file};
use crate::model::FloatImage;
use std::io::Cursor;
use std::path::Path;

/// Largest image accepted, in pixels: a 16k × 8k lat-long (128 Mpixel, 1.5 GiB as f32 RGB).
pub const MAX_PIXELS: u64 = 1 << 27;

/// Reads an HDR sky image (.hdr/.pic or .exr) as a linear float image.
pub fn load(path: &Path) -> Result<FloatImage> {
    let bytes = read_file(path)?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let parsed = match ext.as_str() {
        "hdr" | "pic" => parse_hdr(&bytes),
        "exr" => parse_exr(&bytes),
        _ => {
            return Err(Error::invalid_at(
                path,
                "file name",
                "expected a .hdr, .pic or .exr sky image",
            ));
        }
    };
    parsed.map_err(|e| Error::invalid(path, e))
}

/// A sky image as [`load_keeping_rgbe`] reads it.
#[derive(Debug, Clone, PartialEq)]
pub enum SkyImage {
    Float(FloatImage),
    /// A Radiance image as its RGBE quadruples (a third of the float image's memory).
    Rgbe(RgbeImage),
}

impl SkyImage {
    /// (width, height) in pixels.
    pub fn size(&self) -> (u32, u32) {
        match self {
            SkyImage::Float(i) => (i.width, i.height),
            SkyImage::Rgbe(i) => (i.width, i.height),
        }
    }

    /// The image as floats (decoded now for an RGBE image).
    pub fn into_float(self) -> FloatImage {
        match self {
            SkyImage::Float(i) => i,
            SkyImage::Rgbe(i) => i.to_float_image(),
        }
    }
}

/// Reads an HDR sky image like [`load`], but keeps a Radiance image as its RGBE quadruples
/// (in place in the file's bytes where the scanlines are flat): for the sky stage, which reads
/// each pixel a few times and would otherwise build a float image three times the size.
pub fn load_keeping_rgbe(path: &Path) -> Result<SkyImage> {
    if !is_hdr(path) {
        return load(path).map(SkyImage::Float);
    }
    let bytes = map_or_read(path)?;
    super::rgbe::parse_rgbe(bytes, check_hdr_size)
        .map(SkyImage::Rgbe)
        .map_err(|e| Error::invalid(path, e))
}

/// Parses a Radiance file's bytes as [`load_keeping_rgbe`] does (the same size checks as
/// [`parse_hdr`]); its pixels decode to [`parse_hdr`]'s bits (the fuzz target checks both agree).
pub fn parse_hdr_rgbe(bytes: Vec<u8>) -> Result<RgbeImage, ParseError> {
    super::rgbe::parse_rgbe(RgbeBytes::Owned(bytes), check_hdr_size)
}

/// A file's bytes, mapped (no copy: the page cache's pages are the pixels), or read where it
/// cannot be mapped (a pipe, an empty file).
fn map_or_read(path: &Path) -> Result<RgbeBytes> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    // SAFETY: a read-only map of an input file, as `pack::hash_file` makes; a file changed
    // under the bake is the user's race (`RgbeBytes::Mapped` says what stays safe).
    match unsafe { memmap2::MmapOptions::new().populate().map(&file) } {
        Ok(map) if !map.is_empty() => Ok(RgbeBytes::Mapped(map)),
        _ => read_file(path).map(RgbeBytes::Owned),
    }
}

/// A Radiance file by its extension (.hdr, .pic).
fn is_hdr(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr") || e.eq_ignore_ascii_case("pic"))
}

/// Largest pixel buffer of a Radiance image (float RGB): the `image` crate's default limit.
pub const MAX_HDR_BYTES: u64 = 512 << 20;

/// Decodes a Radiance RGBE image (flat or run-length encoded scanlines).
///
/// The header is read first and its size checked before the pixel buffer is allocated; the
/// scanlines are then decoded in parallel straight into it (`ingest::rgbe`).
pub fn parse_hdr(bytes: &[u8]) -> Result<FloatImage, ParseError> {
    super::rgbe::parse(bytes, check_hdr_size)
}

/// The size checks of a Radiance header, before any pixel buffer is allocated.
fn check_hdr_size(width: u32, height: u32) -> Result<(), ParseError> {
    check_size(width, height)?;
    // A few header bytes cannot make us allocate more than this (the `image` crate's own
    // default cap, which applied here while it decoded these files).
    let bytes_needed = width as u64 * height as u64 * 12;
    if bytes_needed > MAX_HDR_BYTES {
        return Err(ParseError::new(
            "Radiance header",
            format!(
                "{width}×{height} pixels need {} MiB as float RGB; at most {} MiB for a Radiance image",
                bytes_needed >> 20,
                MAX_HDR_BYTES >> 20
            ),
        ));
    }
    Ok(())
}

/// Decodes the first RGB(A) layer of an OpenEXR image (any compression the `exr` crate reads).
pub fn parse_exr(bytes: &[u8]) -> Result<FloatImage, ParseError> {
    use exr::prelude::*;
    // The pixel buffer is allocated from the header's size before any pixel is read: check
    // every layer's size first, so a lying header cannot make us allocate.
    exr_check_header(bytes)?;
    // The pixel buffer is allocated when the first pixel has been decoded, not from the header
    // alone: a file whose chunks are missing fails before the buffer exists.
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |size, _| (size.0, size.1, Vec::new()),
            |px: &mut (usize, usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let w = px.0;
                if px.2.is_empty() {
                    px.2 = vec![[0.0f32; 3]; px.0 * px.1];
                }
                px.2[pos.1 * w + pos.0] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| ParseError::new("OpenEXR file", exr_message(e)))?;
    let (w, h, mut pixels) = image.layer_data.channel_data.pixels;
    check_size(w as u32, h as u32)?;
    pixels.resize(w * h, [0.0; 3]); // (no pixel decoded: cannot happen for a valid layer)
    Ok(FloatImage {
        width: w as u32,
        height: h as u32,
        pixels,
    })
}

/// Size of every layer of an OpenEXR file, from its header alone.
fn exr_layer_sizes(bytes: &[u8]) -> Result<Vec<(u64, u64)>, ParseError> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| ParseError::new("OpenEXR header", exr_message(e)))?;
    Ok(meta
        .headers
        .iter()
        .map(|h| (h.layer_size.0 as u64, h.layer_size.1 as u64))
        .collect())
}

/// Checks an OpenEXR header (read once) before anything is allocated: every layer's size
/// against the pixel limit; and the block layout against the file: every chunk has an 8-byte entry in the offset tables after the header, so a
/// header that declares more chunks than the file can list is refused; and a tile larger than
/// its layer (the `exr` crate allocates a whole tile per block: a 533-byte file from the fuzzer
/// declared 536,870,976×64-pixel tiles for an 8×4 image and cost 1.9 GB) is refused too.
fn exr_check_header(bytes: &[u8]) -> Result<(), ParseError> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| ParseError::new("OpenEXR header", exr_message(e)))?;
    for h in &meta.headers {
        let (w, h) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
        check_size(w.min(u32::MAX as u64) as u32, h.min(u32::MAX as u64) as u32)?;
    }
    let chunks: u64 = meta.headers.iter().map(|h| h.chunk_count as u64).sum();
    if chunks.saturating_mul(8) > bytes.len() as u64 {
        return Err(ParseError::new(
            "OpenEXR offset table",
            format!(
                "the header declares {chunks} chunks, whose offset table alone needs {} bytes; the file has {}",
                chunks.saturating_mul(8),
                bytes.len()
            ),
        ));
    }
    for h in &meta.headers {
        if let exr::meta::BlockDescription::Tiles(t) = &h.blocks {
            let (tw, th) = (t.tile_size.0 as u64, t.tile_size.1 as u64);
            let (w, h) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
            if tw.saturating_mul(th) > (w * h).max(1 << 16) {
                return Err(ParseError::new(
                    "OpenEXR header",
                    format!(
                        "tiles of {tw}×{th} pixels for a {w}×{h} layer; expected tiles no larger than the layer"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The largest layer of an OpenEXR file, from its header alone.
pub fn exr_dimensions(bytes: &[u8]) -> Result<(u64, u64), ParseError> {
    exr_layer_sizes(bytes)?
        .into_iter()
        .max_by_key(|(w, h)| w * h)
        .ok_or_else(|| ParseError::new("OpenEXR header", "no layers"))
}

fn exr_message(e: exr::error::Error) -> String {
    match e {
        exr::error::Error::NotSupported(m) => {
            format!("unsupported: {m} (an RGB or RGBA layer is expected)")
        }
        other => other.to_string(),
    }
}

fn check_size(width: u32, height: u32) -> Result<(), ParseError> {
    if width == 0 || height == 0 || width as u64 * height as u64 > MAX_PIXELS {
        // (u32::MAX stands for sizes past u32; they fail here too.)
        return Err(ParseError::new(
            "image size",
            format!("{width}×{height} pixels; expected 1 to {MAX_PIXELS} pixels"),
        ));
    }
    Ok(())
}

/// Encodes an image as an uncompressed Radiance RGBE file (`-Y H +X W`, flat scanlines).
///
/// RGBE keeps 8 mantissa bits per channel relative to the largest: values round-trip to within
/// 1/256 of the pixel's largest channel. Negative and non-finite values are written as 0.
pub fn write_hdr(img: &FloatImage) -> Vec<u8> {
    let header = format!(
        "#?RADIANCE\n# written by bake\nFORMAT=32-bit_rle_rgbe\n\n-Y {} +X {}\n",
        img.height, img.width
    );
    let mut out = Vec::with_capacity(header.len() + img.pixels.len() * 4);
    out.extend_from_slice(header.as_bytes());
    for p in &img.pixels {
        out.extend_from_slice(&to_rgbe(*p));
    }
    out
}

/// One pixel to RGBE (Ward's `float2rgbe`: mantissas scaled by 256 / 2^e, rounded down).
fn to_rgbe(p: [f32; 3]) -> [u8; 4] {
    let c = p.map(|v| if v.is_finite() && v > 0.0 { v } else { 0.0 });
    let m = c[0].max(c[1]).max(c[2]);
    if m < 1e-32 {
        return [0; 4];
    }
    // m = f · 2^e with f ∈ [0.5, 1).
    let e = m.log2().floor() as i32 + 1;
    let scale = 256.0 / 2f32.powi(e);
    let q = |v: f32| (v * scale).min(255.0) as u8;
    [q(c[0]), q(c[1]), q(c[2]), (e + 128).clamp(0, 255) as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(w: u32, h: u32) -> FloatImage {
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                [0.01 + x * 0.5, 1000.0 / (1.0 + y), 3.0]
            })
            .collect();
        FloatImage {
            width: w,
            height: h,
            pixels,
        }
    }

    #[test]
    fn hdr_round_trips_through_the_writer_and_the_decoder() {
        let img = gradient(13, 7);
        let back = parse_hdr(&write_hdr(&img)).unwrap();
        assert_eq!((back.width, back.height), (13, 7));
        for (a, b) in img.pixels.iter().zip(&back.pixels) {
            let m = a[0].max(a[1]).max(a[2]);
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() <= m / 128.0, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn hdr_known_rgbe_bytes_decode_to_known_values() {
        // Hand-made pixel: mantissas (128, 64, 0), exponent 129 → (1.0, 0.5, 0.0) (+0.5 offset
        // decoders may add: the image crate does not).
        let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n".to_vec();
        bytes.extend_from_slice(&[128, 64, 0, 129]);
        let img = parse_hdr(&bytes).unwrap();
        let p = img.pixels[0];
        assert!(
            (p[0] - 1.0).abs() < 0.01 && (p[1] - 0.5).abs() < 0.01 && p[2] < 0.01,
            "{p:?}"
        );
    }

    #[test]
    fn exr_round_trips_through_the_exr_writer() {
        let img = gradient(9, 5);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sky.exr");
        let px = img.pixels.clone();
        exr::prelude::write_rgb_file(&path, 9, 5, |x, y| {
            let p = px[y * 9 + x];
            (p[0], p[1], p[2])
        })
        .unwrap();
        let back = load(&path).unwrap();
        assert_eq!(back, img);
    }

    #[test]
    fn bad_files_give_clear_errors() {
        let e =
            parse_hdr(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 4\n\x01\x02").unwrap_err();
        assert!(e.place.contains("Radiance"), "{e}");
        // A header that promises more than the allocation cap is refused before any pixel
        // buffer exists (16384 × 8192 is within MAX_PIXELS but needs 1.5 GiB).
        let e = parse_hdr(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8192 +X 16384\n\x02\x02")
            .unwrap_err()
            .to_string();
        assert!(e.contains("16384×8192 pixels need 1536 MiB"), "{e}");
        let e = parse_exr(b"not an exr file at all").unwrap_err();
        assert!(e.place.contains("OpenEXR"), "{e}");
        // The fuzzer's slow find (tests/data/fuzz/exr/): 533 bytes whose header promised a
        // large image; the pixel buffer (and 1.9 GB of memory) came before the missing chunks.
        let timeout = include_bytes!(
            "../../tests/data/fuzz/exr/timeout-a83436e6ce6042c8e1b2cf087c4edf4a407900a2"
        );
        let e = parse_exr(timeout).unwrap_err().to_string();
        assert!(
            e.contains("tiles of 536870976×64 pixels for a 8×4 layer"),
            "{e}"
        );
        let e = load(Path::new("/nonexistent/sky.hdr")).unwrap_err();
        assert_eq!(e.exit_code(), crate::error::exit::IO);
    }
}
