//! Kind `linespace`: the N-tree's GPU pools as a pack section, and its `dump` views. Arrays:
//! `nodes` (u32×2 node pool), `linespaces` (u32 line-space pool), `tri_indices` (u32: the
//! leaves' triangle lists), `triangles` (f32×9, world space).

use super::ntree::{NTree, NodeEntry};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "linespace";

/// Metadata of a `linespace` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinespaceMeta {
    pub source: String,
    pub n: u32,
    pub depth: u32,
    pub origin: [f32; 3],
    pub leaf_size: [f32; 3],
    pub level_groups: Vec<u32>,
    /// Always "symmetric-15n4" (see `linespace::linespace`).
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
        layout: "symmetric-15n4".into(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("nodes", ArrayFormat::U32, 2, &t.nodes)
        .array("linespaces", ArrayFormat::U32, 1, &t.linespaces)
        .array("tri_indices", ArrayFormat::U32, 1, &t.tri_indices)
        .array("triangles", ArrayFormat::F32, 9, &t.triangles);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(LinespaceMeta, NTree), ParseError> {
    let meta: LinespaceMeta = v.meta()?;
    let mut t = NTree {
        n: meta.n,
        depth: meta.depth,
        origin: meta.origin,
        leaf_size: meta.leaf_size,
        nodes: v.array_vec::<NodeEntry>("nodes")?,
        level_groups: meta.level_groups.clone(),
        linespaces: v.array_vec("linespaces")?,
        tri_indices: v.array_vec("tri_indices")?,
        triangles: v.array_vec("triangles")?,
        occupancy: Vec::new(),
        shafts: None,
    };
    validate(&t).map_err(|m| ParseError::new("linespace section", m))?;
    t.fill_occupancy();
    validate(&t).map_err(|m| ParseError::new("linespace section", m))?;
    Ok((meta, t))
}

/// Structural invariants: pool sizes agree, child groups and triangle indices in range.
pub fn validate(t: &NTree) -> Result<(), String> {
    if !(2..=12).contains(&t.n) || t.depth == 0 || t.level_groups.len() != t.depth as usize + 1 {
        return Err(format!("bad n {} / depth {}", t.n, t.depth));
    }
    let groups = t.inner_nodes();
    if t.nodes.len() != 1 + groups * t.n3() {
        return Err("node pool size does not match the groups".into());
    }
    if t.linespaces.len() != groups * t.layout().words() {
        return Err("line-space pool size does not match the groups".into());
    }
    if t.nodes
        .iter()
        .any(|e| e.children() && e.group() as usize >= groups)
    {
        return Err("a child group out of range".into());
    }
    let leaf_out_of_range = t.nodes.iter().any(|e| {
        let (a, k) = e.leaf_triangles();
        e.geometry() && !e.children() && a as u64 + k as u64 > t.tri_indices.len() as u64
    });
    if leaf_out_of_range {
        return Err("a leaf's triangle range is out of range".into());
    }
    if t.tri_indices
        .iter()
        .any(|&i| i as usize >= t.triangles.len())
    {
        return Err("a triangle index out of range".into());
    }
    Ok(())
}

pub fn summary_of(t: &NTree) -> Value {
    let filled = 1 + t.nodes[1..].iter().filter(|e| e.geometry()).count();
    let bytes =
        8 * t.nodes.len() + 4 * (t.linespaces.len() + t.tri_indices.len()) + 36 * t.triangles.len();
    json!({
        "n": t.n,
        "depth": t.depth,
        "nodes": filled,
        "inner_nodes": t.inner_nodes(),
        "bits_per_linespace": t.layout().bits(),
        "bytes": bytes,
        "linespace_bytes": 4 * t.linespaces.len(),
        "triangles": t.triangles.len(),
    })
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
    let levels: Vec<Value> = t
        .level_groups
        .windows(2)
        .enumerate()
        .map(|(l, w)| {
            let ones: u64 = (w[0]..w[1])
                .map(|g| t.linespace(g).iter().map(|x| x.count_ones() as u64).sum::<u64>())
                .sum();
            let bits = (w[1] - w[0]) as u64 * t.layout().bits();
            json!({"level": l, "inner_nodes": w[1] - w[0], "full_shaft_fraction": if bits == 0 { 0.0 } else { ones as f64 / bits as f64 }})
        })
        .collect();
    Ok(json!({ "levels": levels, "origin": t.origin, "leaf_size": t.leaf_size }))
}
