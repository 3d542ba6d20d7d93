//! Kind `linespace`: the N-tree in its compact form (src/linespace/ntree.rs) as a pack section,
//! and its `dump` views. Arrays: `occupancy` u64 (per group, one bit per child with geometry),
//! `first_child` u32 (per group), `leaf_tris` u32 (per leaf, plus the end), `tri_indices` u32,
//! `triangles` f32×9 (world space), `shaft_cells` u64 (the shaft table of n). Byte layout in
//! docs/FORMAT.md.

use super::ntree::{NTree, Refine};
use super::shaft::ShaftTable;
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use std::sync::Arc;

pub const KIND: &str = "linespace";

/// The `layout` this version writes and reads.
pub const LAYOUT: &str = "compact-shaft-table-1";

/// Metadata of a `linespace` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinespaceMeta {
    pub source: String,
    pub n: u32,
    pub depth: u32,
    pub origin: [f32; 3],
    pub leaf_size: [f32; 3],
    pub level_groups: Vec<u32>,
    /// [`LAYOUT`]; sections of the dense layout ("symmetric-15n4") are rejected.
    pub layout: String,
}

pub fn to_section(name: &str, source: &str, t: &NTree) -> Section {
    let meta = LinespaceMeta {
        source: source.into(),
        n: t.n,
        depth: t.depth,
        origin: t.origin,
        leaf_size: t.leaf_size,
        level_groups: t.level_groups.clone(),
        layout: LAYOUT.into(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("occupancy", ArrayFormat::U64, 1, &t.occupancy)
        .array("first_child", ArrayFormat::U32, 1, &t.first_child)
        .array("leaf_tris", ArrayFormat::U32, 1, &t.leaf_tris)
        .array("tri_indices", ArrayFormat::U32, 1, &t.tri_indices)
        .array("triangles", ArrayFormat::F32, 9, &t.triangles)
        .array("shaft_cells", ArrayFormat::U64, 1, &t.shafts.cells);
    b.finish()
}

/// The shaft table of a line-space section (`linespace` or `linespace-scene`): its layout
/// name checked against [`LAYOUT`], `n` in 2..=12, and `shaft_cells` of the size `n` gives.
pub(super) fn read_shafts(
    v: &SectionView,
    layout_name: &str,
    n: u32,
    bad: &dyn Fn(String) -> ParseError,
) -> Result<Arc<ShaftTable>, ParseError> {
    if layout_name != LAYOUT {
        return Err(bad(format!(
            "layout {layout_name:?}, this bake reads {LAYOUT:?} (rebuild it with `bake linespace`)"
        )));
    }
    if !(2..=12).contains(&n) {
        return Err(bad(format!("bad n {n}")));
    }
    let layout = super::layout::Layout::new(n);
    let words = ((n * n * n) as usize).div_ceil(64);
    let cells: Vec<u64> = v.array_vec("shaft_cells")?;
    let need = ShaftTable::rows(layout) * words as u64;
    if cells.len() as u64 != need {
        return Err(bad(format!(
            "shaft_cells holds {} words, n = {n} needs {need}",
            cells.len()
        )));
    }
    Ok(Arc::new(ShaftTable {
        layout,
        words,
        cells,
    }))
}

pub fn from_section(v: &SectionView) -> Result<(LinespaceMeta, NTree), ParseError> {
    let meta: LinespaceMeta = v.meta()?;
    let bad = |m: String| ParseError::new("linespace section", m);
    let shafts = read_shafts(v, &meta.layout, meta.n, &bad)?;
    let mut t = NTree {
        n: meta.n,
        depth: meta.depth,
        origin: meta.origin,
        leaf_size: meta.leaf_size,
        level_groups: meta.level_groups.clone(),
        occupancy: v.array_vec("occupancy")?,
        first_child: v.array_vec("first_child")?,
        leaf_tris: v.array_vec("leaf_tris")?,
        tri_indices: v.array_vec("tri_indices")?,
        triangles: v.array_vec("triangles")?,
        occupancy_rev: Vec::new(),
        shafts,
        dense_linespaces: None,
        refine: Refine::default(),
    };
    validate(&t).map_err(bad)?;
    t.fill_reversed();
    Ok((meta, t))
}

/// Structural invariants: array sizes agree with the groups, every child number and triangle
/// range in range (a query then never reads out of bounds).
pub fn validate(t: &NTree) -> Result<(), String> {
    validate_items(t, t.triangles.len())
}

/// [`validate`] with the leaves' entries numbering `items` things (a top-level tree's
/// instances, where `triangles` is empty).
pub fn validate_items(t: &NTree, items: usize) -> Result<(), String> {
    if !(2..=12).contains(&t.n) || t.depth == 0 || t.level_groups.len() != t.depth as usize + 1 {
        return Err(format!("bad n {} / depth {}", t.n, t.depth));
    }
    if t.level_groups[0] != 0 || t.level_groups.windows(2).any(|w| w[0] > w[1]) {
        return Err("level_groups not ascending from 0".into());
    }
    let groups = t.inner_nodes();
    if groups == 0 || t.occupancy.len() != groups * t.occupancy_words() {
        return Err("occupancy size does not match the groups".into());
    }
    if t.first_child.len() != groups {
        return Err("first_child size does not match the groups".into());
    }
    let n3 = t.n3();
    if !n3.is_multiple_of(64) {
        let spare = !0u64 << (n3 % 64);
        let w = t.occupancy_words();
        if (0..groups).any(|g| t.occupancy[g * w + w - 1] & spare != 0) {
            return Err("occupancy bits set past the n³ child slots".into());
        }
    }
    let deepest = t.level_groups[t.depth as usize - 1] as usize;
    let count = |g: usize| t.rank(g as u32, n3 - 1) + t.filled(g as u32, n3 - 1) as u32;
    for g in 0..groups {
        let (end, limit) = (
            t.first_child[g] as u64 + count(g) as u64,
            if g < deepest {
                groups as u64
            } else {
                t.leaves() as u64
            },
        );
        if end > limit {
            return Err(format!("group {g}: children {end} past {limit}"));
        }
    }
    if t.leaf_tris.is_empty()
        || t.leaf_tris.windows(2).any(|w| w[0] > w[1])
        || *t.leaf_tris.last().unwrap_or(&0) as usize != t.tri_indices.len()
    {
        return Err("leaf_tris not ascending to the end of tri_indices".into());
    }
    if t.tri_indices.iter().any(|&i| i as usize >= items) {
        return Err("a triangle index out of range".into());
    }
    Ok(())
}

pub fn summary_of(t: &NTree) -> Value {
    let filled: u64 = t.occupancy.iter().map(|w| w.count_ones() as u64).sum();
    json!({
        "n": t.n,
        "depth": t.depth,
        "nodes": 1 + filled,
        "inner_nodes": t.inner_nodes(),
        "leaves": t.leaves(),
        "bits_per_linespace": t.layout().bits(),
        "bytes": t.bytes(),
        "occupancy_bytes": 8 * t.occupancy.len(),
        "shaft_table_bytes": t.shafts.bytes(),
        "triangle_bytes": 36 * t.triangles.len() + 4 * (t.tri_indices.len() + t.leaf_tris.len()),
        "dense_bytes": dense_bytes(t),
        "triangles": t.triangles.len(),
    })
}

/// What the thesis' dense pools of the same tree would take (node entries and line spaces).
pub fn dense_bytes(t: &NTree) -> u64 {
    let g = t.inner_nodes() as u64;
    8 * (1 + g * t.n3() as u64) + 4 * g * t.layout().words() as u64
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, t) = from_section(v)?;
    let mut s = summary_of(&t);
    s["source"] = json!(meta.source);
    s["layout"] = json!(meta.layout);
    Ok(s)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, t) = from_section(v)?;
    let bits = t.layout().bits();
    let levels: Vec<Value> = t
        .level_groups
        .windows(2)
        .enumerate()
        .map(|(l, w)| {
            // Sampled: every 97th shaft of each group (the full count is 15n⁴ ANDs per group).
            let (mut ones, mut seen) = (0u64, 0u64);
            for g in w[0]..w[1] {
                for b in (0..bits).step_by(97) {
                    ones += t.linespace_bit(g, b) as u64;
                    seen += 1;
                }
            }
            json!({"level": l, "inner_nodes": w[1] - w[0], "full_shaft_fraction": if seen == 0 { 0.0 } else { ones as f64 / seen as f64 }})
        })
        .collect();
    Ok(json!({ "levels": levels, "origin": t.origin, "leaf_size": t.leaf_size }))
}
