//! Reader (in progress).
use crate::error::{Error, Result};
use crate::model::Mesh;
use std::path::Path;

/// Reads a model file into one mesh.
pub fn load(path: &Path) -> Result<Mesh> {
    Err(Error::invalid_at(
        path,
        "file",
        "this input type is not supported yet",
    ))
}
