//! Terrain stage (seed 000 3.3.2, 4.5.5): the ingested height map to GPU- and ray-tracer-ready
//! data. [`prepare`] makes the four-tap texture and the normal map, [`quadtree`] the min/max
//! quadtree other stages query, [`section`] stores them in the terrain's section.

pub mod prepare;
pub mod quadtree;
pub mod section;
pub mod source_section;
pub mod stage;

pub use prepare::{PreparedTerrain, prepare_terrain};
pub use quadtree::MinMaxQuadtree;

use crate::error::{Error, ParseError, Result};
use crate::pack::{Pack, Section};

/// What the terrain stage did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct TerrainReport {
    pub terrains: usize,
    pub samples: u64,
    pub quadtree_levels: Vec<usize>,
}

/// The colour of a terrain without a colour map: sRGB 128 grey (the renderer uploads it as its
/// one-texel colour map).
pub const DEFAULT_COLOR_SRGB8: [u8; 4] = [128, 128, 128, 255];

/// The linear albedo of a terrain without a colour map ([`DEFAULT_COLOR_SRGB8`] decoded, 0.216):
/// the one value the tracing stages and the renderer use.
pub fn default_albedo() -> [f32; 3] {
    [crate::color::srgb_to_linear(DEFAULT_COLOR_SRGB8[0] as f32 / 255.0); 3]
}

/// Prepares every terrain section of `pack`; returns the replacement sections.
pub fn bake_terrain(pack: &Pack) -> Result<(Vec<Section>, TerrainReport)> {
    let mut out = Vec::new();
    let mut report = TerrainReport::default();
    for e in pack.of_kind(crate::terrain::source_section::KIND) {
        let place = |m: String| {
            Error::invalid(
                pack.path(),
                ParseError::new(format!("section {:?}", e.name), m),
            )
        };
        let view = pack.view(e)?;
        let (meta, t) = crate::terrain::source_section::from_section(&view)
            .map_err(|m| place(m.to_string()))?;
        let p = prepare_terrain(&t).map_err(place)?;
        out.push(section::to_section(&e.name, &meta, &t, &p).map_err(place)?);
        report.terrains += 1;
        report.samples += t.heights.len() as u64;
        report.quadtree_levels.push(p.quadtree.levels());
    }
    Ok((out, report))
}
