//! Texture decoding: SGI `.rgb` through [`super::sgi`] (recognised by its magic 474, whatever
//! the extension), png/jpg/tga/bmp through `image`.

use crate::error::{Error, ParseError, Result};
use crate::model::Rgba8Image;
use std::path::Path;

/// Decodes an image file into RGBA8 (values as stored, usually sRGB).
pub fn load(path: &Path) -> Result<Rgba8Image> {
    let bytes = crate::error::read_file(path)?;
    decode(&bytes).map_err(|e| Error::invalid(path, e))
}

/// Decodes image bytes (format guessed from the content).
pub fn decode(bytes: &[u8]) -> Result<Rgba8Image, ParseError> {
    if super::sgi::is_sgi(bytes) {
        return super::sgi::decode(bytes);
    }
    let img = image::load_from_memory(bytes)
        .map_err(|e| ParseError::new("image", e.to_string()))?
        .to_rgba8();
    let (width, height) = img.dimensions();
    let pixels = img.pixels().map(|p| p.0).collect();
    Ok(Rgba8Image {
        width,
        height,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sgi_is_dispatched_by_magic() {
        let img = Rgba8Image {
            width: 2,
            height: 1,
            pixels: vec![[1, 2, 3, 4], [5, 6, 7, 8]],
        };
        assert_eq!(decode(&super::super::sgi::encode(&img, true)).unwrap(), img);
        assert!(decode(b"not an image").is_err());
    }
}
