//! Kind `svo`: a sparse voxel octree (layout in [`super::svo`]) as a pack section, and its `dump`
//! views. Arrays: `nodes` (u32×4 per inner node), `leaves` (u8: the bricks as 2³ sub-masks, see
//! [`super::packed`]), `voxel_colors`, `voxel_normals`, `node_colors`, `node_normals` (u32 each).

use super::Grid;
use super::svo::{Node, Svo};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "svo";

/// Metadata of an `svo` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SvoMeta {
    pub source: String,
    pub grid: Grid,
    pub levels: u32,
    pub level_start: Vec<u32>,
    pub solid: bool,
}

pub fn to_section(name: &str, source: &str, svo: &Svo, solid: bool) -> Section {
    let meta = SvoMeta {
        source: source.to_string(),
        grid: svo.grid,
        levels: svo.levels,
        level_start: svo.level_start.clone(),
        solid,
    };
    let (nodes, leaves) = super::packed::pack_leaves(svo);
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("nodes", ArrayFormat::U32, 4, &nodes)
        .array("leaves", ArrayFormat::U8, 1, &leaves)
        .array("voxel_colors", ArrayFormat::U32, 1, &svo.voxel_colors)
        .array("voxel_normals", ArrayFormat::U32, 1, &svo.voxel_normals)
        .array("node_colors", ArrayFormat::U32, 1, &svo.node_colors)
        .array("node_normals", ArrayFormat::U32, 1, &svo.node_normals);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(SvoMeta, Svo), ParseError> {
    let meta: SvoMeta = v.meta()?;
    let stored: Vec<Node> = v.array_vec("nodes")?;
    let leaves: &[u8] = v.array("leaves")?;
    let (nodes, bricks) = super::packed::unpack_leaves(&stored, &meta.level_start, leaves)
        .map_err(|m| ParseError::new("svo section", m))?;
    let svo = Svo {
        grid: meta.grid,
        levels: meta.levels,
        nodes,
        level_start: meta.level_start.clone(),
        bricks,
        voxel_colors: v.array_vec("voxel_colors")?,
        voxel_normals: v.array_vec("voxel_normals")?,
        node_colors: v.array_vec("node_colors")?,
        node_normals: v.array_vec("node_normals")?,
    };
    validate(&svo).map_err(|m| ParseError::new("svo section", m))?;
    Ok((meta, svo))
}

/// Structural invariants: level table, child ranges, no empty masks, attribute counts.
pub fn validate(s: &Svo) -> Result<(), String> {
    if s.levels < 2 || s.levels > 11 || s.level_start.len() != s.levels as usize {
        return Err(format!("bad level table for {} levels", s.levels));
    }
    if s.level_start.first() != Some(&0) || s.level_start.last() != Some(&(s.nodes.len() as u32)) {
        return Err("level table does not cover the node array".into());
    }
    if s.level_start.windows(2).any(|w| w[0] > w[1]) {
        return Err("level table is not increasing".into());
    }
    let (gm, dims) = (4u64.pow(s.levels), s.grid.dims);
    if dims.iter().any(|&d| d == 0 || d as u64 > gm) {
        return Err(format!("grid {dims:?} does not fit {} levels", s.levels));
    }
    for l in 0..s.inner_levels() {
        let last = l + 1 == s.inner_levels();
        let limit = if last { s.bricks.len() } else { s.nodes.len() } as u64;
        for n in &s.nodes[s.level_start[l] as usize..s.level_start[l + 1] as usize] {
            let k = n.mask().count_ones() as u64;
            if k == 0 || n.first_child as u64 + k > limit {
                return Err("a node has an empty mask or children out of range".into());
            }
        }
    }
    if s.bricks.contains(&0) {
        return Err("an empty brick".into());
    }
    let voxels: u64 = s.bricks.iter().map(|b| b.count_ones() as u64).sum();
    let attrs = s.nodes.len() + s.bricks.len();
    if voxels != s.voxel_colors.len() as u64
        || voxels != s.voxel_normals.len() as u64
        || s.node_colors.len() != attrs
        || s.node_normals.len() != attrs
    {
        return Err("attribute arrays do not match the voxel and node counts".into());
    }
    Ok(())
}

/// The summary of `bake dump`.
pub fn summary_of(svo: &Svo) -> Value {
    let st = svo.stats();
    let bytes = st.topology_bytes + st.attribute_bytes;
    let per = |b: u64| {
        if st.voxels == 0 {
            0.0
        } else {
            b as f64 / st.voxels as f64
        }
    };
    json!({
        "resolution": svo.grid.dims,
        "origin": svo.grid.origin,
        "voxel_size": svo.grid.voxel_size,
        "voxels": st.voxels,
        "nodes": st.nodes,
        "bytes": bytes,
        "bytes_per_voxel": per(bytes),
        "topology_bytes_per_voxel": per(st.topology_bytes),
        "levels": svo.levels,
        "esvo_topology_bytes_per_voxel": per(st.esvo_topology_bytes),
        "mask64_topology_bytes_per_voxel": per(st.mask64_topology_bytes),
    })
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, svo) = from_section(v)?;
    let mut s = summary_of(&svo);
    s["source"] = json!(meta.source);
    s["solid"] = json!(meta.solid);
    Ok(s)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, svo) = from_section(v)?;
    let keys = super::voxelize::keys_of_bricks(&svo.leaf_bricks());
    let voxels: Vec<[u32; 3]> = keys.iter().map(|&k| super::morton_decode(k)).collect();
    Ok(json!({ "voxels": voxels }))
}
