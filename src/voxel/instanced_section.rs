//! Kind `svo-scene`: the instanced (two-level) SVO ([`super::instanced`]) as one pack section,
//! byte by byte in docs/FORMAT.md ("The `svo-scene` section"). The models' octrees are stored
//! one after another in the `svo` arrays' layout, each model's indices local to its own ranges.

use super::Grid;
use super::instanced::{InstanceRef, InstancedSvo, ModelSvo, TopAggregates, TopGrid};
use super::svo::{Node, Svo};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "svo-scene";

/// The section's layout version: 2 added the top level's filtered attributes (`top_nodes`,
/// `top_colors`, `top_normals`); 3 put the terrain's voxels into them (the top grid covers the
/// terrain's box; the arrays are laid out as in 2). Older sections (version 1: metadata ending
/// at `solid`) are refused with a message to rebuild.
pub const VERSION: u32 = 3;

/// One model's octree inside the section's arrays.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SvoSceneModel {
    /// Mesh section it was voxelized from (`terrain` for the terrain).
    pub mesh_section: String,
    /// Its grid, in the model's own frame (the terrain's: world).
    pub grid: Grid,
    pub levels: u32,
    /// As `SvoMeta::level_start`, local to the model's nodes.
    pub level_start: Vec<u32>,
    /// First element of the model in `nodes`, `leaves` (bytes), `voxel_colors`/`voxel_normals`,
    /// `node_colors`/`node_normals`, and the element counts.
    pub first_node: u32,
    pub first_leaf_byte: u32,
    pub first_voxel: u32,
    pub first_node_attr: u32,
    pub nodes: u32,
    pub leaf_bytes: u32,
    pub voxels: u32,
    pub node_attrs: u32,
}

/// Metadata of an `svo-scene` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SvoSceneMeta {
    pub source: String,
    /// The flattened SVO's grid of the same scene (the scene's resolution).
    pub scene_grid: Grid,
    pub models: Vec<SvoSceneModel>,
    /// The last instance record is the terrain's identity placement (not in the top grid).
    pub terrain: bool,
    pub top: TopGrid,
    pub solid: bool,
    /// [`VERSION`].
    pub version: u32,
}

/// Version 1 metadata (to name it in the refusal).
#[derive(Deserialize)]
struct SvoSceneMetaV1 {
    _source: String,
    _scene_grid: Grid,
    _models: Vec<SvoSceneModel>,
    _terrain: bool,
    _top: TopGrid,
    _solid: bool,
}

pub fn to_section(name: &str, source: &str, s: &InstancedSvo, solid: bool) -> Section {
    let mut nodes: Vec<Node> = Vec::new();
    let mut leaves: Vec<u8> = Vec::new();
    let (mut vc, mut vn, mut nc, mut nn): (Vec<u32>, Vec<u32>, Vec<u32>, Vec<u32>) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut models = Vec::new();
    for m in &s.models {
        let (n, l) = super::packed::pack_leaves(&m.svo);
        models.push(SvoSceneModel {
            mesh_section: m.mesh_section.clone(),
            grid: m.svo.grid,
            levels: m.svo.levels,
            level_start: m.svo.level_start.clone(),
            first_node: nodes.len() as u32,
            first_leaf_byte: leaves.len() as u32,
            first_voxel: vc.len() as u32,
            first_node_attr: nc.len() as u32,
            nodes: n.len() as u32,
            leaf_bytes: l.len() as u32,
            voxels: m.svo.voxel_colors.len() as u32,
            node_attrs: m.svo.node_colors.len() as u32,
        });
        nodes.extend(n);
        leaves.extend(l);
        vc.extend(&m.svo.voxel_colors);
        vn.extend(&m.svo.voxel_normals);
        nc.extend(&m.svo.node_colors);
        nn.extend(&m.svo.node_normals);
    }
    let meta = SvoSceneMeta {
        source: source.to_string(),
        scene_grid: s.scene_grid,
        models,
        terrain: s.terrain,
        top: s.top,
        solid,
        version: VERSION,
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("nodes", ArrayFormat::U32, 4, &nodes)
        .array("leaves", ArrayFormat::U8, 1, &leaves)
        .array("voxel_colors", ArrayFormat::U32, 1, &vc)
        .array("voxel_normals", ArrayFormat::U32, 1, &vn)
        .array("node_colors", ArrayFormat::U32, 1, &nc)
        .array("node_normals", ArrayFormat::U32, 1, &nn)
        .array("instances", ArrayFormat::U32, 8, &s.instances)
        .array("cell_start", ArrayFormat::U32, 1, &s.cell_start)
        .array("cell_instances", ArrayFormat::U32, 1, &s.cell_instances)
        .array("top_nodes", ArrayFormat::U32, 4, &s.aggregates.nodes)
        .array("top_colors", ArrayFormat::U32, 1, &s.aggregates.colors)
        .array("top_normals", ArrayFormat::U32, 1, &s.aggregates.normals);
    b.finish()
}

fn slice<'a, T>(a: &'a [T], first: u32, n: u32, what: &str) -> Result<&'a [T], String> {
    let (f, n) = (first as usize, n as usize);
    a.get(f..f.saturating_add(n))
        .ok_or_else(|| format!("{what}: range {f}..{} past the array ({})", f + n, a.len()))
}

pub fn from_section(v: &SectionView) -> Result<(SvoSceneMeta, InstancedSvo), ParseError> {
    let err = |m: String| ParseError::new("svo-scene section", m);
    let meta: SvoSceneMeta = match v.meta() {
        Ok(m) => m,
        Err(e) => {
            if v.meta::<SvoSceneMetaV1>().is_ok() {
                return Err(err(
                    "a version 1 svo-scene section (without the top level's filtered \
                     attributes); rebuild it with this bake (`bake svo`)"
                        .into(),
                ));
            }
            return Err(e);
        }
    };
    if meta.version != VERSION {
        return Err(err(format!(
            "svo-scene section version {} (this bake reads version {VERSION}: the terrain in the \
             top level's aggregates); rebuild it with this bake (`bake svo`)",
            meta.version
        )));
    }
    let nodes: Vec<Node> = v.array_vec("nodes")?;
    let leaves: &[u8] = v.array("leaves")?;
    let vc: Vec<u32> = v.array_vec("voxel_colors")?;
    let vn: Vec<u32> = v.array_vec("voxel_normals")?;
    let nc: Vec<u32> = v.array_vec("node_colors")?;
    let nn: Vec<u32> = v.array_vec("node_normals")?;
    let instances: Vec<InstanceRef> = v.array_vec("instances")?;
    let cell_start: Vec<u32> = v.array_vec("cell_start")?;
    let cell_instances: Vec<u32> = v.array_vec("cell_instances")?;
    let aggregates = TopAggregates {
        nodes: v.array_vec("top_nodes")?,
        colors: v.array_vec("top_colors")?,
        normals: v.array_vec("top_normals")?,
    };
    let mut models = Vec::with_capacity(meta.models.len());
    for (k, m) in meta.models.iter().enumerate() {
        let what = |a: &str| format!("model {k} {a}");
        let n = slice(&nodes, m.first_node, m.nodes, &what("nodes")).map_err(err)?;
        let l = slice(leaves, m.first_leaf_byte, m.leaf_bytes, &what("leaves")).map_err(err)?;
        let (n, bricks) = super::packed::unpack_leaves(n, &m.level_start, l)
            .map_err(|e| err(format!("model {k}: {e}")))?;
        let svo = Svo {
            grid: m.grid,
            levels: m.levels,
            nodes: n,
            level_start: m.level_start.clone(),
            bricks,
            voxel_colors: slice(&vc, m.first_voxel, m.voxels, &what("voxel_colors"))
                .map_err(err)?
                .to_vec(),
            voxel_normals: slice(&vn, m.first_voxel, m.voxels, &what("voxel_normals"))
                .map_err(err)?
                .to_vec(),
            node_colors: slice(&nc, m.first_node_attr, m.node_attrs, &what("node_colors"))
                .map_err(err)?
                .to_vec(),
            node_normals: slice(&nn, m.first_node_attr, m.node_attrs, &what("node_normals"))
                .map_err(err)?
                .to_vec(),
        };
        super::section::validate(&svo).map_err(|e| err(format!("model {k}: {e}")))?;
        models.push(ModelSvo {
            mesh_section: m.mesh_section.clone(),
            svo,
        });
    }
    let s = InstancedSvo {
        scene_grid: meta.scene_grid,
        models,
        instances,
        terrain: meta.terrain,
        top: meta.top,
        cell_start,
        cell_instances,
        aggregates,
    };
    validate(&s).map_err(err)?;
    Ok((meta, s))
}

/// Structure beyond the octrees: instance records, the top grid's lists.
pub fn validate(s: &InstancedSvo) -> Result<(), String> {
    for (i, r) in s.instances.iter().enumerate() {
        if r.model as usize >= s.models.len() {
            return Err(format!(
                "instance {i}: model {} of {}",
                r.model,
                s.models.len()
            ));
        }
        if r.reserved != 0 {
            return Err(format!("instance {i}: reserved field is not zero"));
        }
        let unit = r.cos * r.cos + r.sin * r.sin;
        // A negative scale mirrors the model (docs/CONVENTIONS.md); zero is refused.
        if !(r.scale != 0.0 && r.scale.is_finite()) || (unit - 1.0).abs() > 1e-4 {
            return Err(format!(
                "instance {i}: scale {} or rotation (cos {}, sin {}) invalid",
                r.scale, r.cos, r.sin
            ));
        }
        if r.position.iter().any(|x| !x.is_finite()) {
            return Err(format!("instance {i}: position not finite"));
        }
    }
    if s.terrain && s.instances.is_empty() {
        return Err("a terrain without its instance record".into());
    }
    let t = &s.top;
    if t.dims.contains(&0) || !(t.cell > 0.0 && t.cell.is_finite()) {
        return Err(format!("top grid {:?} of cell {}", t.dims, t.cell));
    }
    if s.cell_start.len() != t.cells() + 1
        || s.cell_start.first() != Some(&0)
        || s.cell_start.last() != Some(&(s.cell_instances.len() as u32))
        || s.cell_start.windows(2).any(|w| w[0] > w[1])
    {
        return Err("cell_start does not cover cell_instances in order".into());
    }
    let n = s.grid_instances() as u32;
    if let Some(i) = s.cell_instances.iter().position(|&i| i >= n) {
        return Err(format!("cell_instances[{i}] names no gridded instance"));
    }
    let a = &s.aggregates;
    if a.nodes.len() != t.cells() {
        return Err(format!(
            "top_nodes has {} entries for {} cells",
            a.nodes.len(),
            t.cells()
        ));
    }
    let mut next = 0u64;
    for (c, n) in a.nodes.iter().enumerate() {
        if n[2] as u64 != next || n[3] != 0 {
            return Err(format!(
                "top_nodes[{c}]: first sub-cell {} (expected {next}) or reserved {}",
                n[2], n[3]
            ));
        }
        next += a.mask(c).count_ones() as u64;
    }
    let entries = t.cells() as u64 + next;
    if a.colors.len() as u64 != entries || a.normals.len() as u64 != entries {
        return Err(format!(
            "top_colors/top_normals hold {}/{} entries, the cells and sub-cells {entries}",
            a.colors.len(),
            a.normals.len()
        ));
    }
    Ok(())
}

pub fn summary_of(s: &InstancedSvo) -> Value {
    let (voxels, bytes) = s.stats();
    json!({
        "models": s.models.len(),
        "instances": s.grid_instances(),
        "terrain": s.terrain,
        "scene_resolution": s.scene_grid.dims,
        "scene_voxel_size": s.scene_grid.voxel_size[0],
        "model_voxels": voxels,
        "bytes": bytes,
        "top_grid": s.top.dims,
        "top_cell": s.top.cell,
        "cell_references": s.cell_instances.len(),
        "aggregate_sub_cells": s.aggregates.colors.len() - s.aggregates.nodes.len(),
        "model_resolutions": s.models.iter().map(|m| m.svo.grid.dims).collect::<Vec<_>>(),
    })
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, s) = from_section(v)?;
    let mut j = summary_of(&s);
    j["source"] = json!(meta.source);
    j["solid"] = json!(meta.solid);
    Ok(j)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, s) = from_section(v)?;
    Ok(json!({
        "models": s.models.iter().map(|m| json!({
            "mesh_section": m.mesh_section,
            "grid": m.svo.grid,
            "voxels": m.svo.voxel_colors.len(),
        })).collect::<Vec<_>>(),
        "instances": s.instances.iter().map(|r| json!({
            "position": r.position, "scale": r.scale, "cos": r.cos, "sin": r.sin, "model": r.model,
        })).collect::<Vec<_>>(),
    }))
}
