//! The prepared terrain in its kind `terrain` section: the ingest arrays (metadata, `heights`)
//! plus `normals` u8×4 per sample (the four-tap texture is not stored: it repeats the heights
//! four times, so readers derive it, [`super::prepare::four_tap`]), `quadtree` f32×2 (`[min, max]` per node,
//! all levels finest first) and `quadtree_levels` u32×4 (`width, height, first node, 0` per
//! level). Readers of the ingest layout keep working; `bake dump` adds `quadtree_levels`.

use super::prepare::PreparedTerrain;
use super::quadtree::{MinMaxQuadtree, QuadLevel};
use crate::error::ParseError;
use crate::model::Terrain;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use crate::terrain::source_section::{KIND, TerrainMeta};

/// Encodes the terrain with its prepared arrays. Fails when the quadtree has more nodes than a
/// u32 offset holds (a grid past 2^31 samples).
pub fn to_section(
    name: &str,
    meta: &TerrainMeta,
    t: &Terrain,
    p: &PreparedTerrain,
) -> Result<Section, String> {
    let levels: Vec<[u32; 4]> = p
        .quadtree
        .level_table()
        .iter()
        .map(|l| u32::try_from(l.first).map(|f| [l.width, l.height, f, 0]))
        .collect::<Result<_, _>>()
        .map_err(|_| "quadtree too large for 32-bit node offsets".to_string())?;
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(meta)
        .array("heights", ArrayFormat::F32, 1, &t.heights)
        .array("normals", ArrayFormat::U8, 4, &p.normals)
        .array("quadtree", ArrayFormat::F32, 2, p.quadtree.nodes())
        .array("quadtree_levels", ArrayFormat::U32, 4, &levels);
    Ok(b.finish())
}

/// Whether a terrain section carries the prepared arrays.
pub fn is_prepared(v: &SectionView) -> bool {
    v.info("quadtree_levels").is_some()
}

/// Reads the quadtree of a prepared terrain section.
pub fn quadtree_from_section(v: &SectionView) -> Result<MinMaxQuadtree, ParseError> {
    let levels: Vec<[u32; 4]> = v.array_vec("quadtree_levels")?;
    let nodes: Vec<[f32; 2]> = v.array_vec("quadtree")?;
    let levels = levels
        .iter()
        .map(|l| QuadLevel {
            width: l[0],
            height: l[1],
            first: l[2] as u64,
        })
        .collect();
    MinMaxQuadtree::from_parts(levels, nodes)
        .map_err(|m| ParseError::new("terrain section, array quadtree", m))
}

/// Reads the prepared arrays back, checked against the grid size.
pub fn from_section(
    v: &SectionView,
) -> Result<(TerrainMeta, Terrain, PreparedTerrain), ParseError> {
    let (meta, t) = crate::terrain::source_section::from_section(v)?;
    let normals: Vec<[u8; 4]> = v.array_vec("normals")?;
    if normals.len() != t.heights.len() {
        return Err(ParseError::new(
            "terrain section, array normals",
            "normals is not one texel per sample",
        ));
    }
    let four_tap = super::prepare::four_tap(&t.heights, t.width, t.height);
    let quadtree = quadtree_from_section(v)?;
    let l0 = quadtree.level(0);
    if (l0.width, l0.height) != (t.width.max(2) - 1, t.height.max(2) - 1) {
        return Err(ParseError::new(
            "terrain section, array quadtree_levels",
            "level 0 is not one node per grid cell",
        ));
    }
    Ok((
        meta,
        t,
        PreparedTerrain {
            four_tap,
            normals,
            quadtree,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prepared_terrain_round_trips_and_dumps_its_levels() {
        let t = Terrain {
            width: 33,
            height: 17,
            heights: (0..33 * 17)
                .map(|k| ((k * 7919) % 113) as f32 * 0.5)
                .collect(),
            origin: [0.0, 0.0],
            extent: [64.0, 32.0],
            color: None,
        };
        let p = super::super::prepare::prepare_terrain(&t).unwrap();
        let meta = TerrainMeta {
            width: 33,
            height: 17,
            origin: t.origin,
            extent: t.extent,
            color_section: None,
            source: "test".into(),
        };
        let mut w = crate::pack::PackWriter::new();
        w.insert(to_section("terrain", &meta, &t, &p).unwrap());
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "mem").unwrap();
        let v = pack.view_named("terrain").unwrap();
        let (_, t2, p2) = from_section(&v).unwrap();
        assert_eq!(t2.heights, t.heights);
        assert_eq!(p2, p);
        let s = crate::terrain::source_section::summary(&v).unwrap();
        assert_eq!(s["quadtree_levels"], p.quadtree.levels());
        assert_eq!(p.quadtree.levels(), 6); // 32×16 cells → 16×8 → 8×4 → 4×2 → 2×1 → 1×1
    }
}
