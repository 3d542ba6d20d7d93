//! The light map of a placed mesh (kind `lightmap`, section `lightmap:<mesh section>`): an
//! irradiance atlas with one tile per instance, and the atlas' own vertex and index lists (a
//! second UV set; a mesh vertex on a chart border becomes several atlas vertices).
//!
//! The metadata starts with [`super::section::LightmapMeta`]'s fields, so readers of the terrain's
//! light map read this one generically too (`irradiance` of width × height, `indirect`, and where
//! no mesh vertex was split `lightmap_uv`: atlas UVs per instance and mesh vertex).

use super::LightmapMode;
use super::atlas::{AtlasLayout, ChartRect};
use super::objects::AtlasLightmap;
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// The terrain map's kind (`section::KIND`): readers tell the two apart by [`is_atlas`].
pub const KIND: &str = "lightmap";

/// Whether a `lightmap` section is an object atlas (it has the atlas' vertex list).
pub fn is_atlas(v: &SectionView) -> bool {
    v.info("vertex_source").is_some()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AtlasMeta {
    /// The mesh section whose vertices `vertex_source` refers to.
    pub surface: String,
    /// Atlas size in texels.
    pub width: u32,
    pub height: u32,
    pub mode: LightmapMode,
    pub samples: u32,
    pub sun_samples: u32,
    /// Vertex count of that mesh section when the atlas was made (a later vertex split, e.g. by
    /// `bake material`, makes the atlas stale: readers compare).
    pub mesh_vertices: u32,
    /// Scene instance (index into the `instances` section) of every tile.
    pub instances: Vec<u32>,
    /// Texels per tile side; tiles per atlas row.
    pub tile: u32,
    pub columns: u32,
    pub gutter: u32,
    /// Texels per model unit.
    pub density: f32,
    pub texels_covered: u64,
    pub gutter_texels: u64,
}

pub fn to_section(name: &str, meta: &AtlasMeta, map: &AtlasLightmap) -> Section {
    let rgba =
        |t: &[[f32; 3]]| -> Vec<[f32; 4]> { t.iter().map(|t| [t[0], t[1], t[2], 1.0]).collect() };
    let tiles: Vec<[f32; 4]> = (0..map.instances.len()).map(|s| map.tile_rect(s)).collect();
    let l = &map.layout;
    let charts: Vec<[u32; 4]> = l.charts.iter().map(|r| [r.x, r.y, r.w, r.h]).collect();
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(meta)
        .array("irradiance", ArrayFormat::F32, 4, &rgba(&map.texels))
        .array("indirect", ArrayFormat::F32, 4, &rgba(&map.indirect))
        .array("coverage", ArrayFormat::U8, 1, &map.coverage)
        .array("tiles", ArrayFormat::F32, 4, &tiles)
        .array("atlas_uv", ArrayFormat::F32, 2, &l.uv)
        .array("vertex_source", ArrayFormat::U32, 1, &l.vertex_source)
        .array("indices", ArrayFormat::U32, 3, &l.indices)
        .array("triangle_chart", ArrayFormat::U32, 1, &l.triangle_chart)
        .array("charts", ArrayFormat::U32, 4, &charts);
    if let Some(per_vertex) = l.uv_per_mesh_vertex(meta.mesh_vertices as usize) {
        // Atlas UVs per instance slot and mesh vertex: draw the mesh as it is.
        let uv: Vec<[f32; 2]> = (0..map.instances.len())
            .flat_map(|s| {
                let r = map.tile_rect(s);
                per_vertex
                    .iter()
                    .map(move |u| [r[0] + u[0] * r[2], r[1] + u[1] * r[3]])
            })
            .collect();
        b.array("lightmap_uv", ArrayFormat::F32, 2, &uv);
    }
    b.finish()
}

fn bad(what: &str) -> ParseError {
    ParseError::new("lightmap_atlas section", what)
}

/// Checks the sizes the meta promises against each other before anything is indexed.
fn check_meta(m: &AtlasMeta) -> Result<(), ParseError> {
    let n = m.instances.len() as u64;
    if n == 0 || m.tile == 0 || m.columns == 0 {
        return Err(bad("no instances, tiles or columns"));
    }
    let rows = n.div_ceil(m.columns as u64);
    if m.width as u64 != m.columns as u64 * m.tile as u64 || m.height as u64 != rows * m.tile as u64
    {
        return Err(bad("atlas size does not match tile × columns/rows"));
    }
    Ok(())
}

pub fn from_section(v: &SectionView) -> Result<(AtlasMeta, AtlasLightmap), ParseError> {
    let meta: AtlasMeta = v.meta()?;
    check_meta(&meta)?;
    let t: &[[f32; 4]] = v.array("irradiance")?;
    if t.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(bad("texel count does not match width × height"));
    }
    let coverage: Vec<u8> = v.array_vec("coverage")?;
    let ind: &[[f32; 4]] = v.array("indirect")?;
    if coverage.len() != t.len() || ind.len() != t.len() {
        return Err(bad("coverage, indirect and irradiance differ in length"));
    }
    let uv: Vec<[f32; 2]> = v.array_vec("atlas_uv")?;
    let vertex_source: Vec<u32> = v.array_vec("vertex_source")?;
    let indices: Vec<[u32; 3]> = v.array_vec("indices")?;
    let triangle_chart: Vec<u32> = v.array_vec("triangle_chart")?;
    let charts: Vec<[u32; 4]> = v.array_vec("charts")?;
    if uv.len() != vertex_source.len() {
        return Err(bad("atlas_uv and vertex_source differ in length"));
    }
    if vertex_source.iter().any(|&i| i >= meta.mesh_vertices) {
        return Err(bad("vertex_source refers past the mesh's vertices"));
    }
    if indices.iter().flatten().any(|&i| i as usize >= uv.len()) {
        return Err(bad("an index refers past the atlas vertices"));
    }
    if triangle_chart.len() != indices.len()
        || triangle_chart.iter().any(|&c| c as usize >= charts.len())
    {
        return Err(bad("triangle_chart does not match indices and charts"));
    }
    if charts.iter().any(|c| {
        c[0] as u64 + c[2] as u64 > meta.tile as u64 || c[1] as u64 + c[3] as u64 > meta.tile as u64
    }) {
        return Err(bad("a chart lies outside its tile"));
    }
    let layout = AtlasLayout {
        tile: meta.tile,
        gutter: meta.gutter,
        density: meta.density,
        charts: charts
            .iter()
            .map(|c| ChartRect {
                x: c[0],
                y: c[1],
                w: c[2],
                h: c[3],
            })
            .collect(),
        triangle_chart,
        vertex_source,
        uv,
        indices,
    };
    let map = AtlasLightmap {
        layout,
        instances: meta.instances.clone(),
        columns: meta.columns,
        width: meta.width,
        height: meta.height,
        texels: t.iter().map(|x| [x[0], x[1], x[2]]).collect(),
        indirect: ind.iter().map(|x| [x[0], x[1], x[2]]).collect(),
        coverage,
        covered: meta.texels_covered,
        gutter_texels: meta.gutter_texels,
    };
    let tiles: &[[f32; 4]] = v.array("tiles")?;
    if tiles.len() != meta.instances.len() || (0..tiles.len()).any(|s| tiles[s] != map.tile_rect(s))
    {
        return Err(bad("tiles do not match the tile grid"));
    }
    Ok((meta, map))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (m, map) = from_section(v)?;
    let n = map.covered.max(1) as f64;
    // Mean over covered texels only (gutters repeat them, empty space is zero).
    let mean = map
        .texels
        .iter()
        .zip(&map.coverage)
        .filter(|(_, c)| **c == 1)
        .fold([0.0f64; 3], |a, (t, _)| {
            [
                a[0] + t[0] as f64 / n,
                a[1] + t[1] as f64 / n,
                a[2] + t[2] as f64 / n,
            ]
        });
    Ok(
        json!({"surface": m.surface, "instances": m.instances.len(), "charts": map.layout.charts.len(),
        "atlas": [m.width, m.height], "tile": m.tile, "texels_covered": m.texels_covered,
        "gutter_texels": m.gutter_texels, "vertices": map.layout.uv.len(), "mode": m.mode,
        "samples": m.samples, "sun_samples": m.sun_samples, "mean_irradiance": mean}),
    )
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, map) = from_section(v)?;
    let tiles: Vec<[f32; 4]> = (0..map.instances.len()).map(|s| map.tile_rect(s)).collect();
    Ok(
        json!({"irradiance": map.texels, "tiles": tiles, "lightmap_uv": map.layout.uv,
        "vertex_source": map.layout.vertex_source, "indices": map.layout.indices}),
    )
}
