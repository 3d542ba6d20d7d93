//! Kind `linespace-scene`: the two-level line-space structure ([`super::instanced`]) as one
//! pack section, byte by byte in docs/FORMAT.md ("The `linespace-scene` section"). The top
//! tree's arrays come first, then every model's, each tree's numbers local to its own ranges
//! (as the `linespace` section stores one tree).

use super::instanced::{ModelTree, SceneLinespace, SceneTerrain};
use super::ntree::{NTree, NTreeOptions, Refine};
use super::section::LAYOUT;
use super::shaft::ShaftTable;
use crate::error::ParseError;
use crate::model::Terrain;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use crate::voxel::instanced::InstanceRef;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use std::sync::Arc;

pub const KIND: &str = "linespace-scene";

/// One tree's place in the section's arrays (its elements follow the previous tree's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TreeMeta {
    pub depth: u32,
    pub origin: [f32; 3],
    pub leaf_size: [f32; 3],
    /// As `LinespaceMeta::level_groups`: G = the last entry.
    pub level_groups: Vec<u32>,
    /// L: leaves (`leaf_items` holds L + 1 entries of this tree).
    pub leaves: u32,
    /// Entries of this tree in `item_indices`.
    pub items: u32,
    /// Triangles of this tree in `triangles` (0 for the top tree).
    pub triangles: u32,
}

/// A model's tree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneModelMeta {
    pub mesh_section: String,
    pub tree: TreeMeta,
}

/// The terrain's height grid (`heights` holds width × height samples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerrainGrid {
    pub width: u32,
    pub height: u32,
    pub origin: [f32; 2],
    pub extent: [f32; 2],
}

/// Metadata of a `linespace-scene` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinespaceSceneMeta {
    pub source: String,
    /// The models' N-tree options (the top tree has the same n, its own depth).
    pub n: u32,
    pub depth: u32,
    pub cubic_cells: bool,
    /// World units the models' triangle cells were grown by (divided by each model's
    /// smallest |scale|).
    pub frame_margin: f32,
    /// [`LAYOUT`], as the `linespace` section.
    pub layout: String,
    /// The top tree over the instances (None: no instance).
    pub top: Option<TreeMeta>,
    pub models: Vec<SceneModelMeta>,
    pub terrain: Option<TerrainGrid>,
}

fn tree_meta(t: &NTree) -> TreeMeta {
    TreeMeta {
        depth: t.depth,
        origin: t.origin,
        leaf_size: t.leaf_size,
        level_groups: t.level_groups.clone(),
        leaves: t.leaves() as u32,
        items: t.tri_indices.len() as u32,
        triangles: t.triangles.len() as u32,
    }
}

pub fn to_section(name: &str, source: &str, s: &SceneLinespace) -> Section {
    let trees: Vec<&NTree> = s
        .top
        .iter()
        .chain(s.models.iter().map(|m| &m.tree))
        .collect();
    let cat = |f: &dyn Fn(&NTree) -> &[u32]| -> Vec<u32> {
        trees.iter().flat_map(|t| f(t).iter().copied()).collect()
    };
    let occupancy: Vec<u64> = trees
        .iter()
        .flat_map(|t| t.occupancy.iter().copied())
        .collect();
    let triangles: Vec<[[f32; 3]; 3]> = trees
        .iter()
        .flat_map(|t| t.triangles.iter().copied())
        .collect();
    let meta = LinespaceSceneMeta {
        source: source.into(),
        n: s.opts.n,
        depth: s.opts.depth,
        cubic_cells: s.opts.cubic_cells,
        frame_margin: s.frame_margin,
        layout: LAYOUT.into(),
        top: s.top.as_ref().map(tree_meta),
        models: s
            .models
            .iter()
            .map(|m| SceneModelMeta {
                mesh_section: m.mesh_section.clone(),
                tree: tree_meta(&m.tree),
            })
            .collect(),
        terrain: s.terrain.as_ref().map(|t| TerrainGrid {
            width: t.terrain.width,
            height: t.terrain.height,
            origin: t.terrain.origin,
            extent: t.terrain.extent,
        }),
    };
    let heights: &[f32] = s
        .terrain
        .as_ref()
        .map_or(&[], |t| t.terrain.heights.as_slice());
    let shaft_cells: &[u64] = trees.first().map_or(&[], |t| t.shafts.cells.as_slice());
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("occupancy", ArrayFormat::U64, 1, &occupancy)
        .array(
            "first_child",
            ArrayFormat::U32,
            1,
            &cat(&|t| &t.first_child),
        )
        .array("leaf_items", ArrayFormat::U32, 1, &cat(&|t| &t.leaf_tris))
        .array(
            "item_indices",
            ArrayFormat::U32,
            1,
            &cat(&|t| &t.tri_indices),
        )
        .array("triangles", ArrayFormat::F32, 9, &triangles)
        .array("instances", ArrayFormat::U32, 8, &s.instances)
        .array("heights", ArrayFormat::F32, 1, heights)
        .array("shaft_cells", ArrayFormat::U64, 1, shaft_cells);
    b.finish()
}

/// Takes `n` elements from `at` on, advancing it.
fn take<T: Clone>(a: &[T], at: &mut usize, n: usize, what: &str) -> Result<Vec<T>, String> {
    let r = a.get(*at..at.saturating_add(n)).ok_or_else(|| {
        format!(
            "{what}: {n} elements from {at} past the array ({})",
            a.len()
        )
    })?;
    *at += n;
    Ok(r.to_vec())
}

/// Cursors into the shared arrays.
struct Arrays<'a> {
    occupancy: &'a [u64],
    first_child: &'a [u32],
    leaf_items: &'a [u32],
    item_indices: &'a [u32],
    triangles: &'a [[[f32; 3]; 3]],
    at: [usize; 5],
}

impl Arrays<'_> {
    fn tree(
        &mut self,
        m: &TreeMeta,
        n: u32,
        shafts: &Arc<ShaftTable>,
        items: Option<usize>,
    ) -> Result<NTree, String> {
        if !(1..=12).contains(&m.depth)
            || (n as u64).pow(m.depth) > 4096
            || m.level_groups.len() != m.depth as usize + 1
        {
            return Err(format!("bad depth {}", m.depth));
        }
        let groups = *m.level_groups.last().unwrap_or(&0) as usize;
        let words = ((n * n * n) as usize).div_ceil(64);
        let mut t = NTree {
            n,
            depth: m.depth,
            origin: m.origin,
            leaf_size: m.leaf_size,
            level_groups: m.level_groups.clone(),
            occupancy: take(
                self.occupancy,
                &mut self.at[0],
                groups.saturating_mul(words),
                "occupancy",
            )?,
            first_child: take(self.first_child, &mut self.at[1], groups, "first_child")?,
            leaf_tris: take(
                self.leaf_items,
                &mut self.at[2],
                m.leaves as usize + 1,
                "leaf_items",
            )?,
            tri_indices: take(
                self.item_indices,
                &mut self.at[3],
                m.items as usize,
                "item_indices",
            )?,
            triangles: take(
                self.triangles,
                &mut self.at[4],
                m.triangles as usize,
                "triangles",
            )?,
            occupancy_rev: Vec::new(),
            shafts: shafts.clone(),
            dense_linespaces: None,
            refine: Refine::default(),
        };
        super::section::validate_items(&t, items.unwrap_or(t.triangles.len()))?;
        t.fill_reversed();
        Ok(t)
    }
}

pub fn from_section(v: &SectionView) -> Result<(LinespaceSceneMeta, SceneLinespace), ParseError> {
    let meta: LinespaceSceneMeta = v.meta()?;
    let bad = |m: String| ParseError::new("linespace-scene section", m);
    let shafts = super::section::read_shafts(v, &meta.layout, meta.n, &bad)?;
    let occupancy: Vec<u64> = v.array_vec("occupancy")?;
    let first_child: Vec<u32> = v.array_vec("first_child")?;
    let leaf_items: Vec<u32> = v.array_vec("leaf_items")?;
    let item_indices: Vec<u32> = v.array_vec("item_indices")?;
    let triangles: Vec<[[f32; 3]; 3]> = v.array_vec("triangles")?;
    let instances: Vec<InstanceRef> = v.array_vec("instances")?;
    let heights: Vec<f32> = v.array_vec("heights")?;
    let mut arrays = Arrays {
        occupancy: &occupancy,
        first_child: &first_child,
        leaf_items: &leaf_items,
        item_indices: &item_indices,
        triangles: &triangles,
        at: [0; 5],
    };
    let top = meta
        .top
        .as_ref()
        .map(|m| {
            let mut t = arrays.tree(m, meta.n, &shafts, Some(instances.len()))?;
            t.refine = Refine::Exact;
            Ok::<_, String>(t)
        })
        .transpose()
        .map_err(|e| bad(format!("top tree: {e}")))?;
    let mut models = Vec::with_capacity(meta.models.len());
    for (k, m) in meta.models.iter().enumerate() {
        let tree = arrays
            .tree(&m.tree, meta.n, &shafts, None)
            .map_err(|e| bad(format!("model {k} ({}): {e}", m.mesh_section)))?;
        models.push(ModelTree {
            mesh_section: m.mesh_section.clone(),
            tree,
        });
    }
    let ends = [
        occupancy.len(),
        first_child.len(),
        leaf_items.len(),
        item_indices.len(),
        triangles.len(),
    ];
    if arrays.at != ends {
        return Err(bad(format!(
            "the trees take {:?} elements of occupancy, first_child, leaf_items, item_indices, \
             triangles; the arrays hold {ends:?}",
            arrays.at
        )));
    }
    if top.is_none() != instances.is_empty() {
        return Err(bad(
            "a top tree without instances, or instances without one".into(),
        ));
    }
    for (i, r) in instances.iter().enumerate() {
        let ok = (r.model as usize) < models.len()
            && r.scale != 0.0
            && [r.scale, r.cos, r.sin]
                .iter()
                .chain(&r.position)
                .all(|x| x.is_finite());
        if !ok {
            return Err(bad(format!(
                "instance {i}: model {} of {}, or a transform that is not finite / zero scale",
                r.model,
                models.len()
            )));
        }
    }
    let terrain = match &meta.terrain {
        None if heights.is_empty() => None,
        None => return Err(bad("heights without a terrain".into())),
        Some(g) => {
            if heights.len() as u64 != g.width as u64 * g.height as u64 {
                return Err(bad(format!(
                    "{} heights for a {}×{} terrain",
                    heights.len(),
                    g.width,
                    g.height
                )));
            }
            let t = Terrain {
                width: g.width,
                height: g.height,
                heights,
                origin: g.origin,
                extent: g.extent,
                color: None,
            };
            Some(SceneTerrain::new(&t).map_err(|e| bad(format!("terrain: {e}")))?)
        }
    };
    let s = SceneLinespace {
        opts: NTreeOptions {
            n: meta.n,
            depth: meta.depth,
            cubic_cells: meta.cubic_cells,
        },
        models,
        instances,
        top,
        terrain,
        frame_margin: meta.frame_margin,
    };
    Ok((meta, s))
}

pub fn summary_of(s: &SceneLinespace) -> Value {
    json!({
        "n": s.opts.n,
        "depth": s.opts.depth,
        "models": s.models.len(),
        "instances": s.instances.len(),
        "top_depth": s.top.as_ref().map(|t| t.depth),
        "top_inner_nodes": s.top.as_ref().map_or(0, |t| t.inner_nodes()),
        "top_leaves": s.top.as_ref().map_or(0, |t| t.leaves()),
        "top_references": s.top.as_ref().map_or(0, |t| t.tri_indices.len()),
        "model_triangles": s.models.iter().map(|m| m.tree.triangles.len()).sum::<usize>(),
        "model_inner_nodes": s.models.iter().map(|m| m.tree.inner_nodes()).sum::<usize>(),
        "placed_triangles": s.placed_triangles(),
        "terrain_samples": s.terrain.as_ref().map_or(0, |t| t.terrain.heights.len()),
        "frame_margin": s.frame_margin,
        "bytes": s.bytes(),
    })
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, s) = from_section(v)?;
    let mut j = summary_of(&s);
    j["source"] = json!(meta.source);
    j["layout"] = json!(meta.layout);
    Ok(j)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, s) = from_section(v)?;
    let models: Vec<Value> = meta
        .models
        .iter()
        .zip(&s.models)
        .map(|(m, t)| {
            json!({
                "mesh_section": m.mesh_section,
                "origin": m.tree.origin,
                "leaf_size": m.tree.leaf_size,
                "inner_nodes": t.tree.inner_nodes(),
                "leaves": t.tree.leaves(),
                "triangles": t.tree.triangles.len(),
            })
        })
        .collect();
    Ok(json!({ "models": models, "top": meta.top, "terrain": meta.terrain }))
}
