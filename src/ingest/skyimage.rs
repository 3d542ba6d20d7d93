//! Reader (in progress).
use crate::error::{Error, Result};
use crate::model::FloatImage;
use std::path::Path;

/// Reads an HDR sky image (.hdr or .exr) as a linear float image.
pub fn load(path: &Path) -> Result<FloatImage> {
    Err(Error::invalid_at(
        path,
        "file",
        "this input type is not supported yet",
    ))
}
