//! Kind `terrain`: a height map in metres on a corner-aligned grid (row 0 south).

use crate::error::ParseError;
use crate::model::Terrain;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "terrain";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerrainMeta {
    pub width: u32,
    pub height: u32,
    pub origin: [f32; 2],
    pub extent: [f32; 2],
    /// The texture section holding the colour map, if any.
    pub color_section: Option<String>,
    pub source: String,
}

pub fn to_section(name: &str, source: &str, t: &Terrain, color_section: Option<String>) -> Section {
    let meta = TerrainMeta {
        width: t.width,
        height: t.height,
        origin: t.origin,
        extent: t.extent,
        color_section,
        source: source.to_string(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("heights", ArrayFormat::F32, 1, &t.heights);
    b.finish()
}

/// Decodes the terrain (without its colour map, which lives in its own texture section).
pub fn from_section(v: &SectionView) -> Result<(TerrainMeta, Terrain), ParseError> {
    let meta: TerrainMeta = v.meta()?;
    let heights: Vec<f32> = v.array_vec("heights")?;
    if heights.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(ParseError::new(
            "terrain section",
            format!(
                "{} heights for a {}×{} grid",
                heights.len(),
                meta.width,
                meta.height
            ),
        ));
    }
    let t = Terrain {
        width: meta.width,
        height: meta.height,
        heights,
        origin: meta.origin,
        extent: meta.extent,
        color: None,
    };
    Ok((meta, t))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, t) = from_section(v)?;
    let (lo, hi) = t.height_range();
    Ok(json!({
        "width": t.width, "height": t.height, "origin": t.origin, "extent": t.extent,
        "min_height": lo, "max_height": hi, "color": meta.color_section, "source": meta.source,
        // 0 until `bake terrain` has prepared the section (src/terrain/section.rs).
        "quadtree_levels": v.info("quadtree_levels").map_or(0, |a| a.count),
    }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, t) = from_section(v)?;
    Ok(json!({ "heights": t.heights }))
}
