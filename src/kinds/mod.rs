//! The section kinds of docs/FORMAT.md in one list, [`KINDS`]: for each kind its name, how its
//! sections are named, the arrays it may have, its decoder, its `bake dump` views (summary and
//! full data) and its own invariants. `bake dump` (and through it `bake report`'s page) and
//! `bake verify` walk this list; a kind that is not in it is unknown to both.
//!
//! Adding a kind: write its codec beside its stage (`to_section`, `from_section`, `summary`,
//! `data`), add one [`SectionKind`] here and its row to docs/FORMAT.md ("Section kinds"; the
//! test `every_registered_kind_has_its_format_row` fails until you do).
#![warn(missing_docs)]

mod checks;

use crate::error::ParseError;
use crate::pack::section::{ArrayFormat, SectionView};

pub use crate::stage::kind::{
    CheckFn, DecodeFn, Finding, Findings, Naming, Schema, SectionKind, ViewFn,
};

use ArrayFormat::{F16, F32, U8, U32};

/// Every kind: those no stage defines ([`KINDS`]), then each registered stage's
/// (`Stage::kinds`, declared in the stage's folder), in registry order.
pub fn all() -> impl Iterator<Item = &'static SectionKind> {
    KINDS.iter().chain(
        crate::graph::stage::REGISTRY
            .iter()
            .flat_map(|s| s.kinds().iter()),
    )
}

/// The kind of `kind`, or `None` for a kind this bake does not know.
pub fn find(kind: &str) -> Option<&'static SectionKind> {
    all().find(|k| k.kind == kind)
}

/// Runs a section through its kind's decoder; an unknown kind is an error.
pub fn decode(kind: &str, v: &SectionView) -> Result<(), ParseError> {
    match find(kind) {
        Some(k) => (k.decode)(v),
        None => Err(ParseError::new(
            "section kind",
            format!("unknown kind {kind:?}"),
        )),
    }
}

/// The kinds of format version 2 that no stage defines (the models' meshes and textures, the
/// instances, the build record and report), in the order of docs/FORMAT.md; the stages'
/// kinds are declared beside them ([`all`] walks both).
pub const KINDS: &[SectionKind] = &[
    SectionKind {
        kind: crate::mesh::section::KIND,
        naming: Naming::Qualified,
        arrays: &[
            ("positions", &[F32], 3),
            ("normals", &[F32], 3),
            ("uvs", &[F32], 2),
            ("indices", &[U32], 3),
            ("triangle_materials", &[U32], 1),
            ("one_sided_materials", &[U32], 1),
            ("skeleton_lines", &[F32], 3),
            ("skeleton_points", &[F32], 3),
        ],
        decode: |v| crate::mesh::section::from_section(v).map(drop),
        views: Some((crate::mesh::section::summary, crate::mesh::section::data)),
        check: Some(checks::mesh),
    },
    SectionKind {
        kind: crate::ingest::instances_section::KIND,
        naming: Naming::Kind,
        arrays: &[("instances", &[U32], 8)],
        decode: |v| crate::ingest::instances_section::from_section(v).map(drop),
        views: Some((
            crate::ingest::instances_section::summary,
            crate::ingest::instances_section::data,
        )),
        check: Some(checks::instances),
    },
    SectionKind {
        kind: crate::texture::source_section::KIND,
        naming: Naming::Qualified,
        arrays: &[
            ("texels", &[U8], 4),
            ("levels", &[U32], 4),
            ("color", &[F16], 4),
            ("coverage", &[F32], 1),
            ("alpha_scale", &[F32], 1),
            ("normal", &[U8], 4),
            ("height", &[F16], 1),
        ],
        decode: decode_texture,
        views: Some((
            crate::texture::source_section::summary,
            crate::texture::source_section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::report::record::BUILD_KIND,
        naming: Naming::Kind,
        arrays: &[],
        decode: crate::report::record::check_build_section,
        views: None,
        check: None,
    },
    SectionKind {
        kind: crate::report::KIND,
        naming: Naming::Kind,
        arrays: &[("json", &[U8], 1)],
        decode: |v| crate::report::from_section(v).map(drop),
        views: Some((crate::report::summary, crate::report::data)),
        check: None,
    },
];

/// A terrain as ingested, or prepared by `bake terrain`.
/// A texture as ingested, or processed by `bake material` (its `format` says which).
fn decode_texture(v: &SectionView) -> Result<(), ParseError> {
    let meta: crate::texture::source_section::TextureMeta = v.meta()?;
    if crate::texture::section::is_processed(&meta.format) {
        crate::texture::section::from_section(v).map(drop)
    } else {
        crate::texture::source_section::from_section(v).map(drop)
    }
}

/// A lat-long sky as ingested, or the cube of `bake sky`.
#[cfg(test)]
mod tests;
