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

use ArrayFormat::{F16, F32, U8, U16, U32, U64};

/// The kind of `kind`, or `None` for a kind this bake does not know.
pub fn find(kind: &str) -> Option<&'static SectionKind> {
    KINDS.iter().find(|k| k.kind == kind)
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

/// Every kind of format version 2, in the order of docs/FORMAT.md.
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
        kind: crate::terrain::source_section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("heights", &[F32], 1),
            ("four_tap", &[F32], 4),
            ("normals", &[U8], 4),
            ("quadtree", &[F32], 2),
            ("quadtree_levels", &[U32], 4),
        ],
        decode: decode_terrain,
        views: Some((
            crate::terrain::source_section::summary,
            crate::terrain::source_section::data,
        )),
        check: Some(checks::terrain),
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
        kind: crate::sky::source_section::KIND,
        naming: Naming::Kind,
        arrays: &[("texels", &[F32, F16], 4)],
        decode: decode_sky,
        views: Some((
            crate::sky::source_section::summary,
            crate::sky::source_section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::sky::section::SUN_KIND,
        naming: Naming::Kind,
        arrays: &[],
        decode: |v| crate::sky::section::sun_from_section(v).map(drop),
        views: Some((
            crate::sky::section::sun_summary,
            crate::sky::section::sun_data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::sky::section::SH_KIND,
        naming: Naming::Kind,
        arrays: &[("radiance", &[F32], 3), ("irradiance", &[F32], 3)],
        decode: |v| crate::sky::section::sh_from_section(v).map(drop),
        views: Some((
            crate::sky::section::sh_summary,
            crate::sky::section::sh_data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::material::section::KIND,
        naming: Naming::Qualified,
        arrays: &[("params", &[F32], 24)],
        decode: |v| crate::material::section::from_section(v).map(drop),
        views: Some((
            crate::material::section::summary,
            crate::material::section::data,
        )),
        check: Some(checks::material),
    },
    SectionKind {
        kind: crate::mesh::tangents::KIND,
        naming: Naming::Qualified,
        arrays: &[("tangents", &[F32], 4)],
        decode: |v| crate::mesh::tangents::from_section(v).map(drop),
        views: Some((crate::mesh::tangents::summary, crate::mesh::tangents::data)),
        check: Some(checks::tangents),
    },
    SectionKind {
        kind: crate::lightmap::section::KIND,
        naming: Naming::Prefixed,
        arrays: &[
            ("irradiance", &[F32], 4),
            ("indirect", &[F32], 4),
            ("coverage", &[U8], 1),
            ("tiles", &[F32], 4),
            ("atlas_uv", &[F32], 2),
            ("vertex_source", &[U32], 1),
            ("indices", &[U32], 3),
            ("triangle_chart", &[U32], 1),
            ("charts", &[U32], 4),
            ("lightmap_uv", &[F32], 2),
        ],
        decode: decode_lightmap,
        views: Some((
            crate::lightmap::section::summary,
            crate::lightmap::section::data,
        )),
        check: Some(checks::lightmap),
    },
    SectionKind {
        kind: crate::envmap::section::ENVMAPS_KIND,
        naming: Naming::Kind,
        arrays: &[
            ("sky", &[F32], 48),
            ("sun", &[F32], 48),
            ("noise_covariance", &[F32], 96),
            ("noise_variance", &[F32], 1),
        ],
        decode: decode_envmaps,
        views: Some((
            crate::envmap::section::envmaps_summary,
            crate::envmap::section::envmaps_data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::envmap::section::CLUSTERS_KIND,
        naming: Naming::Kind,
        arrays: &[
            ("sample_positions", &[F32], 3),
            ("sample_values", &[F32], 1),
            ("sample_instance", &[U32], 1),
            ("local_basis", &[F32], 1),
            ("local_scale", &[F32], 1),
            ("local_coeffs", &[U8], 1),
            ("neighbours", &[U32], 1),
            ("weights", &[F32], 1),
        ],
        decode: |v| crate::envmap::section::clusters_summary(v).map(drop),
        views: Some((
            crate::envmap::section::clusters_summary,
            crate::envmap::section::clusters_data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::bittree::section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("bits", &[U8], 1),
            ("scale", &[F32], 1),
            ("rotation", &[U16], 1),
            ("model", &[U16], 1),
            ("layer", &[U16], 1),
            ("residual", &[U16], 2),
            ("shared", &[U32], 1),
        ],
        decode: |v| crate::bittree::section::from_section(v).map(drop),
        views: Some((
            crate::bittree::section::summary,
            crate::bittree::section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::prt::pack::KIND,
        naming: Naming::Qualified,
        arrays: &[("transfer", &[F32], 3), ("gpu", &[F32], 4)],
        decode: |v| crate::prt::pack::from_section(v).map(drop),
        views: Some((crate::prt::pack::summary, crate::prt::pack::data)),
        check: Some(checks::prt),
    },
    SectionKind {
        kind: crate::voxel::section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("nodes", &[U32], 4),
            ("leaves", &[U8], 1),
            ("voxel_colors", &[U32], 1),
            ("node_colors", &[U32], 1),
            ("voxel_normals", &[U32], 1),
            ("node_normals", &[U32], 1),
        ],
        decode: |v| crate::voxel::section::from_section(v).map(drop),
        views: Some((crate::voxel::section::summary, crate::voxel::section::data)),
        check: None,
    },
    SectionKind {
        kind: crate::voxel::instanced_section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("nodes", &[U32], 4),
            ("leaves", &[U8], 1),
            ("voxel_colors", &[U32], 1),
            ("voxel_normals", &[U32], 1),
            ("node_colors", &[U32], 1),
            ("node_normals", &[U32], 1),
            ("instances", &[U32], 8),
            ("cell_start", &[U32], 1),
            ("cell_instances", &[U32], 1),
            ("top_nodes", &[U32], 4),
            ("top_colors", &[U32], 1),
            ("top_normals", &[U32], 1),
        ],
        decode: |v| crate::voxel::instanced_section::from_section(v).map(drop),
        views: Some((
            crate::voxel::instanced_section::summary,
            crate::voxel::instanced_section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::linespace::section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("occupancy", &[U64], 1),
            ("first_child", &[U32], 1),
            ("leaf_tris", &[U32], 1),
            ("tri_indices", &[U32], 1),
            ("triangles", &[F32], 9),
            ("shaft_cells", &[U64], 1),
        ],
        decode: |v| crate::linespace::section::from_section(v).map(drop),
        views: Some((
            crate::linespace::section::summary,
            crate::linespace::section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::linespace::instanced_section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("occupancy", &[U64], 1),
            ("first_child", &[U32], 1),
            ("leaf_items", &[U32], 1),
            ("item_indices", &[U32], 1),
            ("triangles", &[F32], 9),
            ("instances", &[U32], 8),
            ("heights", &[F32], 1),
            ("shaft_cells", &[U64], 1),
        ],
        decode: |v| crate::linespace::instanced_section::from_section(v).map(drop),
        views: Some((
            crate::linespace::instanced_section::summary,
            crate::linespace::instanced_section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::lod::section::KIND,
        naming: Naming::Qualified,
        arrays: &[
            ("positions", &[F32], 3),
            ("vertex_source", &[U32], 1),
            ("indices", &[U32], 3),
            ("triangle_materials", &[U32], 1),
            ("impostor_color", &[U8], 4),
            ("impostor_normal", &[U8], 4),
            ("impostor_depth", &[U8], 1),
            ("skeleton_lines", &[F32], 3),
            ("skeleton_points", &[F32], 3),
        ],
        decode: |v| crate::lod::section::from_view(v, None).map(drop),
        views: Some((crate::lod::section::summary, crate::lod::section::data)),
        check: Some(checks::lod),
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
fn decode_terrain(v: &SectionView) -> Result<(), ParseError> {
    if crate::terrain::section::is_prepared(v) {
        crate::terrain::section::from_section(v).map(drop)
    } else {
        crate::terrain::source_section::from_section(v).map(drop)
    }
}

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
fn decode_sky(v: &SectionView) -> Result<(), ParseError> {
    if crate::sky::source_section::is_cube(v)? {
        crate::sky::section::cube_from_section(v).map(drop)
    } else {
        crate::sky::source_section::from_section(v).map(drop)
    }
}

/// The terrain's light map, or an object atlas (told apart by its `vertex_source` array).
fn decode_lightmap(v: &SectionView) -> Result<(), ParseError> {
    if v.info("vertex_source").is_some() {
        crate::lightmap::atlas_section::from_section(v).map(drop)
    } else {
        crate::lightmap::section::from_section(v).map(drop)
    }
}

/// The maps, then their noise arrays against the metadata.
fn decode_envmaps(v: &SectionView) -> Result<(), ParseError> {
    let (m, _, _) = crate::envmap::section::envmaps_from_section(v)?;
    crate::envmap::section::envmaps_noise_from_section(v, &m).map(drop)
}

#[cfg(test)]
mod tests;
