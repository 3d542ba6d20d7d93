//! Resource limits: what a size declared in an input may make bake allocate.
//!
//! Every reader checks a declared count against the bytes that must follow it before it
//! allocates (a vertex count against its chunk, an RLE row against its table, a glTF accessor
//! against its buffer view), so most allocations are bounded by the file's size. Where a small
//! file can legitimately declare a large result (image dimensions with RLE or deflate, a RAW
//! size from the ECO line, many instance lines) the declared size is checked against these
//! limits first. The defaults ([`Limits::DEFAULT`], documented in README.md):
//!
//! | limit | default | what |
//! |---|---|---|
//! | `max_memory` | 4 GiB (`--max-memory`) | decoded size of one input file: a texture, the terrain, a model, the instances |
//! | `max_image_pixels` | 2²⁸ (16384 × 16384) | pixels of one texture or sky image |
//! | `max_vertices` | 2²⁶ | vertices of one model |
//! | `max_triangles` | 2²⁶ | triangles of one model |
//! | `max_instances` | 2²⁴ | instances of one scene |
//!
//! Exceeding one is invalid input (exit 4) naming the file, the place and the limit; bake never
//! aborts on an allocation.

use crate::error::{Error, ParseError, Result};
use std::path::Path;

/// Limits on declared sizes; see the module docs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Bytes the decoded data of one input file may take.
    pub max_memory: u64,
    pub max_image_pixels: u64,
    pub max_vertices: u64,
    pub max_triangles: u64,
    pub max_instances: u64,
}

impl Limits {
    pub const DEFAULT: Limits = Limits {
        max_memory: 4 << 30,
        max_image_pixels: 1 << 28,
        max_vertices: 1 << 26,
        max_triangles: 1 << 26,
        max_instances: 1 << 24,
    };

    /// The defaults with another memory budget.
    pub const fn with_memory(bytes: u64) -> Limits {
        Limits {
            max_memory: bytes,
            ..Limits::DEFAULT
        }
    }

    /// Checks the decoded size of `what` in `file` against the memory budget.
    pub fn check_memory(&self, file: &Path, place: &str, what: &str, bytes: u64) -> Result<()> {
        if bytes <= self.max_memory {
            return Ok(());
        }
        Err(Error::invalid(
            file,
            ParseError::new(
                place,
                format!(
                    "{what} would take {} when decoded, more than the {} budget (--max-memory)",
                    human(bytes),
                    human(self.max_memory)
                ),
            ),
        ))
    }
}

impl Default for Limits {
    fn default() -> Self {
        Limits::DEFAULT
    }
}

/// A count checked against its limit in a reader (no file name yet).
pub fn check_count(place: &str, what: &str, count: u64, limit: u64) -> Result<(), ParseError> {
    if count <= limit {
        return Ok(());
    }
    Err(ParseError::new(
        place,
        format!("{count} {what} declared, more than the limit of {limit}"),
    ))
}

/// `1.5 GiB`-style sizes for messages.
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["bytes", "KiB", "MiB", "GiB", "TiB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1024.0 && u < UNITS.len() - 1 {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} bytes")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// Parses `--max-memory`: bytes, or a number with K, M, G or T (powers of 1024).
pub fn parse_bytes(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let (num, shift) = match t.char_indices().last() {
        Some((k, c)) if c.is_ascii_alphabetic() => {
            let shift = match c.to_ascii_uppercase() {
                'K' => 10,
                'M' => 20,
                'G' => 30,
                'T' => 40,
                _ => return Err(format!("{s:?}: unit must be K, M, G or T")),
            };
            (&t[..k], shift)
        }
        _ => (t, 0),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a size (e.g. 512M, 4G)"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("{s:?}: the budget must be positive"));
    }
    Ok((v * (1u64 << shift) as f64) as u64)
}

/// Width and height from an image file's header, without decoding it (SGI, png, jpg, tga,
/// bmp, hdr, exr); `None` when the header cannot be read (the decoder will say why).
pub fn image_dimensions(bytes: &[u8]) -> Option<(u64, u64)> {
    if super::sgi::is_sgi(bytes) && bytes.len() >= 10 {
        let be = |k: usize| u16::from_be_bytes([bytes[k], bytes[k + 1]]) as u64;
        return Some((be(6), be(8)));
    }
    if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        return super::skyimage::exr_dimensions(bytes).ok();
    }
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .ok()?;
    reader
        .into_dimensions()
        .ok()
        .map(|(w, h)| (w as u64, h as u64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_units() {
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("1.5g"), Ok(3 << 29));
        assert!(parse_bytes("0").is_err());
        assert!(parse_bytes("12Q").unwrap_err().contains("unit"));
        assert!(parse_bytes("lots").is_err());
    }

    #[test]
    fn budget_errors_name_file_place_and_budget() {
        let l = Limits::with_memory(1 << 20);
        assert!(
            l.check_memory(Path::new("a.rgb"), "header", "texture", 1 << 20)
                .is_ok()
        );
        let e = l
            .check_memory(Path::new("a.rgb"), "header", "texture 4096×4096", 64 << 20)
            .unwrap_err();
        assert_eq!(e.exit_code(), 4);
        assert_eq!(
            e.to_string(),
            "a.rgb: header: texture 4096×4096 would take 64.0 MiB when decoded, more than the 1.0 MiB budget (--max-memory)"
        );
        let c = check_count("line 3", "vertices", 10, 5).unwrap_err();
        assert_eq!(
            c.to_string(),
            "line 3: 10 vertices declared, more than the limit of 5"
        );
    }

    #[test]
    fn dimensions_come_from_headers() {
        let img = crate::model::Rgba8Image {
            width: 3,
            height: 2,
            pixels: vec![[0; 4]; 6],
        };
        assert_eq!(
            image_dimensions(&super::super::sgi::encode(&img, true)),
            Some((3, 2))
        );
        let hdr = super::super::skyimage::write_hdr(&crate::model::FloatImage {
            width: 5,
            height: 4,
            pixels: vec![[1.0; 3]; 20],
        });
        assert_eq!(image_dimensions(&hdr), Some((5, 4)));
        assert_eq!(image_dimensions(b"nothing"), None);
    }
}
