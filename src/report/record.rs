//! The `build` section: the record of the bake that wrote a pack (its build key and every file
//! it read, by source name), written last by `bake SCENE.eco` (docs/FORMAT.md, "Build records
//! and cache entries"). The graph writes it and compares it; readers decode it from here.

use crate::pack::{Section, SectionBuilder};
use serde::{Deserialize, Serialize};

pub use crate::stage::FileDep;

/// Kind and name of the section recording the build.
pub const BUILD_KIND: &str = "build";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct BuildMeta {
    pub(crate) key: String,
    pub(crate) files: Vec<FileDep>,
    pub(crate) models: u64,
    pub(crate) instances: u64,
    pub(crate) triangles: u64,
}

/// Decodes a `build` section (for `bake verify`).
pub fn check_build_section(
    v: &crate::pack::section::SectionView,
) -> std::result::Result<(), crate::error::ParseError> {
    let m: BuildMeta = v.meta()?;
    if m.key.len() != 64 || !m.key.bytes().all(|c| c.is_ascii_hexdigit()) {
        return Err(crate::error::ParseError::new(
            "build section",
            "the build key is not 64 hex digits",
        ));
    }
    Ok(())
}

pub(crate) fn build_section(meta: &BuildMeta) -> Section {
    let mut b = SectionBuilder::new(BUILD_KIND, BUILD_KIND);
    b.meta(meta);
    b.finish()
}
