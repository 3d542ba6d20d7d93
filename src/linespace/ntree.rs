//! The N-tree: the root box split into n×n×n children, a child split again only if it holds
//! geometry, down to `depth` levels; every inner node carries a line space.
//!
//! GPU layout (after the thesis, Fig. 8–9):
//! - Node pool: [`NodeEntry`] (8 B, like the thesis' RG32UI texel). Entry 0 is the root; group g
//!   (the n³ children of inner node number g, in BFS order) occupies entries 1 + g·n³ … with child
//!   (x, y, z) at offset x + n·y + n²·z. `word`: bit 0 = holds geometry, bit 1 = has children,
//!   bits 2–31 = the child group g (30 bits). `linespace`: the node's line-space index (equal to
//!   its group number).
//! - Line-space pool: `words()` u32 per line space, line space g at g·words (layout in
//!   [`super::linespace`]).
//! - Leaves (bit 1 clear) list the triangles that touch them: bits 2–31 of `word` hold the
//!   count and the second word the first index into the triangle-index pool, so shadow rays
//!   that start or end inside a deepest-level node are tested exactly, leaf by leaf.
//!
//! Leaf cells (level depth) are marked filled by the conservative triangle/box test with a margin
//! of 10⁻³ cell against rounding in the world-to-grid transform: a cell that a triangle touches is
//! never missed, which the line space's one-sided error relies on.

use super::linespace::Layout;
use super::shaft::{ChildMasks, ShaftCells};
use crate::error::{Error, Result};
use crate::voxel::Grid;
use crate::voxel::voxelize::TriSetup;
use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;
use std::sync::Arc;

/// Margin of the triangle/cell tests, in cells.
pub const CELL_MARGIN: f32 = 1e-3;

/// A node-pool entry: repr(C), Pod, 8 bytes. Example: a node with geometry and children whose
/// group is 5 has word 1 | 2 | 5 << 2 = 23 and linespace 5; a leaf touched by 3 triangles listed
/// from index 40 has word 1 | 3 << 2 = 13 and second word 40.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable, Default)]
pub struct NodeEntry {
    pub word: u32,
    pub linespace: u32,
}
const _: () = assert!(size_of::<NodeEntry>() == 8);

impl NodeEntry {
    pub const fn geometry(&self) -> bool {
        self.word & 1 == 1
    }
    pub const fn children(&self) -> bool {
        self.word & 2 == 2
    }
    pub const fn group(&self) -> u32 {
        self.word >> 2
    }
    /// A leaf's triangle range in the triangle-index pool: (first, count).
    pub const fn leaf_triangles(&self) -> (u32, u32) {
        (self.linespace, self.word >> 2)
    }
}

/// Options of [`build_ntree`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NTreeOptions {
    /// Children per axis (2..=12).
    pub n: u32,
    /// Levels below the root (≥ 1); n^depth ≤ 4096 leaf cells per axis.
    pub depth: u32,
}

impl Default for NTreeOptions {
    fn default() -> Self {
        Self::thesis()
    }
}

impl NTreeOptions {
    /// The thesis' configuration: n = 10, depth 3.
    pub const fn thesis() -> Self {
        Self { n: 10, depth: 3 }
    }
}

/// The N-tree with its line spaces.
#[derive(Debug, Clone, PartialEq)]
pub struct NTree {
    pub n: u32,
    pub depth: u32,
    /// World box of the root: minimum corner and size of a leaf cell per axis.
    pub origin: [f32; 3],
    pub leaf_size: [f32; 3],
    pub nodes: Vec<NodeEntry>,
    /// First group of each level 0..depth−1, plus the end.
    pub level_groups: Vec<u32>,
    pub linespaces: Vec<u32>,
    /// Triangle indices of the leaves, leaf after leaf.
    pub tri_indices: Vec<u32>,
    /// Per group, one bit per child with geometry (`occupancy_words()` u64 each): a compact copy
    /// of the node pool's bit 0 that the CPU traversal reads first.
    pub occupancy: Vec<u64>,
    /// The triangles, world space.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// When set, CPU queries read line-space bits as `occupancy & shaft cells` from this shared
    /// per-n table instead of the line-space pool (same bits, [`ShaftCells`]); the pool stays
    /// the packed form the GPU reads.
    pub shafts: Option<Arc<ShaftCells>>,
}

/// Path key of a cell at `levels` below the root: the base-n³ number of its child slots.
pub fn path_key(c: [u32; 3], levels: u32, n: u32) -> u64 {
    let n3 = (n * n * n) as u64;
    let mut key = 0u64;
    for l in (0..levels).rev() {
        let d = c.map(|x| (x / n.pow(l)) % n);
        key = key * n3 + (d[0] + n * d[1] + n * n * d[2]) as u64;
    }
    key
}

fn check_options(o: &NTreeOptions) -> Result<()> {
    if !(2..=12).contains(&o.n) {
        return Err(Error::usage(format!("--n {} must be in 2..=12", o.n)));
    }
    if o.depth == 0 || (o.n as u64).pow(o.depth) > 4096 {
        return Err(Error::usage(format!(
            "--depth {} with --n {} gives {} leaf cells per axis; at most 4096 (and depth ≥ 1)",
            o.depth,
            o.n,
            (o.n as u64).saturating_pow(o.depth)
        )));
    }
    Ok(())
}

/// The root box: the triangles' bounds, padded by a thousandth on each side.
fn root_box(tris: &[[[f32; 3]; 3]]) -> Result<([f32; 3], [f32; 3])> {
    let pts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let (lo, hi) = crate::model::bounds_of(&pts)
        .ok_or_else(|| Error::Runtime("no triangles for the N-tree".into()))?;
    let ext = [0, 1, 2].map(|k| (hi[k] - lo[k]).max(1e-6 * (1.0 + lo[k].abs())));
    let longest = ext.iter().cloned().fold(0.0, f32::max);
    let pad = ext.map(|e| e * 1e-3 + longest * 1e-6);
    Ok((
        [0, 1, 2].map(|k| lo[k] - pad[k]),
        [0, 1, 2].map(|k| ext[k] + 2.0 * pad[k]),
    ))
}

/// Builds the N-tree and its line spaces over world-space triangles.
pub fn build_ntree(
    tris: &[[[f32; 3]; 3]],
    opts: &NTreeOptions,
    masks: &ChildMasks,
) -> Result<NTree> {
    check_options(opts)?;
    if masks.layout.n != opts.n {
        return Err(Error::Runtime(
            "child-mask table built for another n".into(),
        ));
    }
    let (origin, size) = root_box(tris)?;
    let (n, depth) = (opts.n, opts.depth);
    let res = n.pow(depth);
    let leaf_size = size.map(|s| s / res as f32);
    let grid = Grid {
        origin,
        voxel_size: leaf_size,
        dims: [res; 3],
    };
    let setups: Vec<TriSetup> = tris
        .par_iter()
        .map(|t| TriSetup::padded(t.map(|p| grid.to_grid(p)), CELL_MARGIN))
        .collect();
    let pairs = leaf_pairs(&setups, res, depth, n);
    let mut keys: Vec<u64> = pairs.iter().map(|p| p.0).collect();
    keys.dedup();
    let prefixes = level_prefixes(&keys, depth, n);
    let mut tree = NTree {
        n,
        depth,
        origin,
        leaf_size,
        nodes: Vec::new(),
        level_groups: Vec::new(),
        linespaces: Vec::new(),
        tri_indices: pairs.iter().map(|p| p.1).collect(),
        occupancy: Vec::new(),
        triangles: tris.to_vec(),
        shafts: None,
    };
    tree.link_nodes(&prefixes, &pairs);
    tree.linespaces = build_linespaces(&prefixes, n, masks);
    tree.fill_occupancy();
    Ok(tree)
}

/// Sorted unique path keys per level 0..=depth (level 0: the root, key 0).
fn level_prefixes(leaf_keys: &[u64], depth: u32, n: u32) -> Vec<Vec<u64>> {
    let n3 = (n * n * n) as u64;
    let mut out = vec![Vec::new(); depth as usize + 1];
    out[depth as usize] = leaf_keys.to_vec();
    for l in (0..depth as usize).rev() {
        let mut v: Vec<u64> = out[l + 1].iter().map(|k| k / n3).collect();
        v.dedup();
        out[l] = v;
    }
    if out[0].is_empty() {
        out[0].push(0);
    }
    out
}

impl NTree {
    /// Children per node.
    pub fn n3(&self) -> usize {
        (self.n * self.n * self.n) as usize
    }

    pub fn layout(&self) -> Layout {
        Layout::new(self.n)
    }

    /// Number of inner nodes (= groups = line spaces).
    pub fn inner_nodes(&self) -> usize {
        *self.level_groups.last().unwrap_or(&0) as usize
    }

    /// The line space of group g.
    pub fn linespace(&self, g: u32) -> &[u32] {
        let w = self.layout().words();
        &self.linespaces[g as usize * w..(g as usize + 1) * w]
    }

    /// Fills the node pool from the per-level prefixes (groups in BFS order); leaves point at
    /// their run of `pairs` (sorted (leaf key, triangle)).
    fn link_nodes(&mut self, prefixes: &[Vec<u64>], pairs: &[(u64, u32)]) {
        let mut run = 0usize;
        let n3 = self.n3() as u64;
        let depth = self.depth as usize;
        let mut level_groups = vec![0u32];
        for p in &prefixes[..depth] {
            level_groups.push(level_groups.last().copied().unwrap_or(0) + p.len() as u32);
        }
        let groups = *level_groups.last().unwrap_or(&0) as usize;
        let mut nodes = vec![NodeEntry::default(); 1 + groups * n3 as usize];
        nodes[0] = NodeEntry {
            word: 3,
            linespace: 0,
        };
        for l in 0..depth {
            let mut parent = 0usize;
            for (i, &q) in prefixes[l + 1].iter().enumerate() {
                while prefixes[l][parent] != q / n3 {
                    parent += 1;
                }
                let g_parent = level_groups[l] as usize + parent;
                let at = 1 + g_parent * n3 as usize + (q % n3) as usize;
                nodes[at] = if l + 1 < depth {
                    let g = level_groups[l + 1] + i as u32;
                    NodeEntry {
                        word: 3 | g << 2,
                        linespace: g,
                    }
                } else {
                    let first = run;
                    while run < pairs.len() && pairs[run].0 == q {
                        run += 1;
                    }
                    NodeEntry {
                        word: 1 | ((run - first) as u32) << 2,
                        linespace: first as u32,
                    }
                };
            }
        }
        self.nodes = nodes;
        self.level_groups = level_groups;
    }

    /// u64 words of one group's occupancy bits.
    pub fn occupancy_words(&self) -> usize {
        self.n3().div_ceil(64)
    }

    /// Derives [`Self::occupancy`] from the node pool.
    pub fn fill_occupancy(&mut self) {
        let (w, n3) = (self.occupancy_words(), self.n3());
        let mut occ = vec![0u64; self.inner_nodes() * w];
        for (i, e) in self.nodes.iter().enumerate().skip(1) {
            if e.geometry() {
                let (g, s) = ((i - 1) / n3, (i - 1) % n3);
                occ[g * w + s / 64] |= 1 << (s % 64);
            }
        }
        self.occupancy = occ;
    }

    /// Makes CPU queries read line-space bits from `table` (built for this n).
    pub fn use_shaft_table(&mut self, table: Arc<ShaftCells>) -> Result<()> {
        if table.layout.n != self.n {
            return Err(Error::Runtime("shaft table built for another n".into()));
        }
        self.shafts = Some(table);
        Ok(())
    }

    /// The occupancy words of group `g`.
    #[inline]
    pub fn occupancy_of(&self, g: u32) -> &[u64] {
        let w = self.occupancy_words();
        &self.occupancy[g as usize * w..(g as usize + 1) * w]
    }

    /// Line-space bit `bit` of group `g`: from the shared shaft table when one is set, else
    /// from the line-space pool.
    #[inline]
    pub fn linespace_bit(&self, g: u32, bit: u64) -> bool {
        match &self.shafts {
            Some(t) => t.meets(bit, self.occupancy_of(g)),
            None => super::linespace::get(self.linespace(g), bit),
        }
    }

    /// Whether child `slot` of group `g` holds geometry.
    #[inline]
    pub fn filled(&self, g: u32, slot: usize) -> bool {
        self.occupancy[g as usize * self.occupancy_words() + slot / 64] >> (slot % 64) & 1 == 1
    }

    /// Triangles of a leaf entry.
    pub fn leaf_triangles(&self, e: &NodeEntry) -> &[u32] {
        let (a, k) = e.leaf_triangles();
        &self.tri_indices[a as usize..(a + k) as usize]
    }
}

/// Sorted (leaf path key, triangle) pairs of every leaf cell a triangle touches.
fn leaf_pairs(setups: &[TriSetup], res: u32, depth: u32, n: u32) -> Vec<(u64, u32)> {
    let hi = [res as i64 - 1; 3];
    let mut pairs: Vec<(u64, u32)> = setups
        .par_iter()
        .enumerate()
        .flat_map_iter(|(t, s)| {
            let mut out = Vec::new();
            s.for_each_voxel([0; 3], hi, |c| {
                out.push((path_key(c.map(|x| x as u32), depth, n), t as u32));
            });
            out
        })
        .collect();
    pairs.par_sort_unstable();
    pairs
}

/// OR of the child masks of each inner node's filled children, in group order.
fn build_linespaces(prefixes: &[Vec<u64>], n: u32, masks: &ChildMasks) -> Vec<u32> {
    let n3 = (n * n * n) as u64;
    let w = masks.layout.words();
    let depth = prefixes.len() - 1;
    let mut out = Vec::new();
    for l in 0..depth {
        // Children of each parent: a run of prefixes[l+1] with the same key / n³.
        let children = &prefixes[l + 1];
        let mut runs: Vec<(usize, usize)> = Vec::with_capacity(prefixes[l].len());
        let mut start = 0;
        for i in 1..=children.len() {
            if i == children.len() || children[i] / n3 != children[start] / n3 {
                runs.push((start, i));
                start = i;
            }
        }
        let spaces: Vec<Vec<u32>> = runs
            .par_iter()
            .map(|&(a, b)| {
                let mut ls = vec![0u32; w];
                for &q in &children[a..b] {
                    for (d, s) in ls.iter_mut().zip(masks.mask((q % n3) as usize)) {
                        *d |= s;
                    }
                }
                ls
            })
            .collect();
        for s in spaces {
            out.extend(s);
        }
    }
    out
}
