//! Texture decoding: png/jpg/tga/bmp through `image`, SGI `.rgb` through [`super::sgi`].

use crate::error::{Error, Result};
use crate::model::Rgba8Image;
use std::path::Path;

/// Decodes an image file into RGBA8 (values as stored, usually sRGB).
pub fn load(path: &Path) -> Result<Rgba8Image> {
    let bytes = crate::error::read_file(path)?;
    decode(&bytes).map_err(|e| Error::invalid(path, e))
}

/// Decodes image bytes (format guessed from the content).
pub fn decode(bytes: &[u8]) -> Result<Rgba8Image, crate::error::ParseError> {
    let img = image::load_from_memory(bytes)
        .map_err(|e| crate::error::ParseError::new("image", e.to_string()))?
        .to_rgba8();
    let (width, height) = img.dimensions();
    let pixels = img.pixels().map(|p| p.0).collect();
    Ok(Rgba8Image {
        width,
        height,
        pixels,
    })
}
