//! RAW height maps: headerless W×H samples, row-major, row 0 south; 8-bit, or 16-bit
//! little-endian when the file is twice as large. Heights in metres = sample × scale.

use crate::error::{Error, ParseError, Result};
use crate::model::Terrain;
use std::path::{Path, PathBuf};

/// What the ECO line (or the command line) says about a RAW file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawSpec {
    pub width: u32,
    pub height: u32,
    /// Metres per sample step.
    pub scale: f32,
    pub origin: [f32; 2],
    pub extent: [f32; 2],
}

/// Decodes RAW samples into heights in metres.
pub fn parse(bytes: &[u8], spec: &RawSpec) -> Result<Vec<f32>, ParseError> {
    if spec.width == 0 || spec.height == 0 {
        return Err(ParseError::new(
            "size",
            format!("terrain size {}×{} is empty", spec.width, spec.height),
        ));
    }
    let n = spec.width as u64 * spec.height as u64;
    if bytes.len() as u64 == n {
        Ok(bytes.iter().map(|&s| s as f32 * spec.scale).collect())
    } else if bytes.len() as u64 == 2 * n {
        Ok(bytes
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]) as f32 * spec.scale)
            .collect())
    } else {
        Err(ParseError::new(
            "file size",
            format!(
                "{} bytes, expected {} (8-bit) or {} (16-bit) for {}×{} samples",
                bytes.len(),
                n,
                2 * n,
                spec.width,
                spec.height
            ),
        ))
    }
}

/// The colour map beside a RAW file: same stem with an image extension.
pub fn find_color_map(raw: &Path) -> Option<PathBuf> {
    [
        "png", "jpg", "jpeg", "tga", "bmp", "rgb", "PNG", "JPG", "TGA", "BMP", "RGB",
    ]
    .iter()
    .map(|ext| raw.with_extension(ext))
    .find(|p| p.is_file())
}

/// Reads a RAW terrain and its colour map (given, or found beside it).
pub fn load(path: &Path, spec: &RawSpec, color_map: Option<&Path>) -> Result<Terrain> {
    let bytes = crate::error::read_file(path)?;
    let heights = parse(&bytes, spec).map_err(|e| Error::invalid(path, e))?;
    let color_path = color_map
        .map(Path::to_path_buf)
        .or_else(|| find_color_map(path));
    let color = match color_path {
        Some(p) => Some(super::texture::load(&p)?),
        None => None,
    };
    Ok(Terrain {
        width: spec.width,
        height: spec.height,
        heights,
        origin: spec.origin,
        extent: spec.extent,
        color,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(w: u32, h: u32) -> RawSpec {
        RawSpec {
            width: w,
            height: h,
            scale: 0.5,
            origin: [10.0, 20.0],
            extent: [30.0, 40.0],
        }
    }

    #[test]
    fn eight_and_sixteen_bit_by_size() {
        let s = spec(3, 2);
        assert_eq!(
            parse(&[0, 1, 2, 3, 4, 255], &s).unwrap(),
            vec![0.0, 0.5, 1.0, 1.5, 2.0, 127.5]
        );
        let sixteen: Vec<u8> = [0u16, 1, 256, 1000, 65535, 2]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        assert_eq!(
            parse(&sixteen, &s).unwrap(),
            vec![0.0, 0.5, 128.0, 500.0, 32767.5, 1.0]
        );
        let err = parse(&[0; 7], &s).unwrap_err();
        assert!(
            err.message.contains("expected 6 (8-bit) or 12 (16-bit)"),
            "{err}"
        );
    }

    #[test]
    fn corner_aligned_bottom_up_placement() {
        let s = spec(3, 2);
        let t = Terrain {
            width: 3,
            height: 2,
            heights: parse(&[0, 2, 4, 10, 12, 14], &s).unwrap(),
            origin: s.origin,
            extent: s.extent,
            color: None,
        };
        // Row 0 is the southern edge y = y0; the last column is x = x0 + extent.
        assert_eq!(t.position(0, 0), [10.0, 20.0, 0.0]);
        assert_eq!(t.position(2, 1), [40.0, 60.0, 7.0]);
        // Bilinear: centre of the first cell = mean of its four corners.
        let h = t.height_at(17.5, 40.0);
        assert!((h - (0.0 + 1.0 + 5.0 + 6.0) / 4.0).abs() < 1e-5, "{h}");
        // Clamped outside the grid.
        assert_eq!(t.height_at(-100.0, -100.0), 0.0);
        assert_eq!(t.height_at(1e4, 1e4), 7.0);
    }
}
