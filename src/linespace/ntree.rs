//! The N-tree: the root box split into n×n×n children, a child split again only if it holds
//! geometry, down to `depth` levels; every inner node carries a line space.
//!
//! Storage (compact, the `linespace` section's arrays and the GPU pools, byte by byte in
//! docs/FORMAT.md):
//! - Groups: inner node g (breadth-first: 0 is the root, then level 1 in path order, …) owns
//!   `occupancy_words()` u64 of occupancy bits, one per child slot x + n·y + n²·z (bit s % 64 of
//!   word s / 64: the child holds geometry), and `first_child[g]`.
//! - Rank-compacted children: every filled child above the deepest level is an inner node, and
//!   the children of a node get consecutive numbers in slot order, so the filled child at slot s
//!   of g is number `first_child[g] + rank(g, s)`, rank = the set occupancy bits below s (a
//!   popcount). For g above the deepest inner level that number is a group; for g on the deepest
//!   inner level (depth − 1) it is a leaf, whose triangles are
//!   `tri_indices[leaf_tris[leaf] .. leaf_tris[leaf + 1]]`.
//! - Line spaces: bit b of group g is `occupancy(g) & cells(b) ≠ 0`, with cells(b) the child
//!   cells shaft b meets ([`ShaftTable`], one table per n, stored once per section; 6 of the 15
//!   face pairs are read as point reflections of stored ones, against the group's occupancy
//!   reversed, which is derived at load time): the same
//!   bits as the thesis' per-node pool (the OR of the filled children's shaft masks), which is
//!   kept as a reference only ([`super::dense`]).
//!
//! Empty slots cost one bit and nothing else: at n = 10, depth 3 a group is 128 B of occupancy
//! and 4 B of `first_child`, where the dense layout spent 8,000 B of node entries and 18,752 B of
//! line space.
//!
use super::layout::Layout;
use super::shaft::{ShaftTable, reverse_slots};
use crate::error::{Error, Result};
use crate::voxel::Grid;
use crate::voxel::voxelize::TriSetup;
use rayon::prelude::*;
use std::sync::Arc;

/// Margin of the triangle/cell tests, in cells.
pub const CELL_MARGIN: f32 = 1e-3;

/// Options of [`build_ntree`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NTreeOptions {
    /// Children per axis (2..=12).
    pub n: u32,
    /// Levels below the root (≥ 1); n^depth ≤ 4096 leaf cells per axis.
    pub depth: u32,
    /// Cubic cells: the root box is a cube of the scene's longest extent (the thesis' N-tree).
    /// Without, each axis of the scene's bounds is split n^depth times, so a flat scene gets
    /// flat cells (the fixture's 100 × 100 × 12 m: 10 × 10 × 1.2 cm leaves, 2.5× as many).
    pub cubic_cells: bool,
}

impl Default for NTreeOptions {
    fn default() -> Self {
        Self::thesis()
    }
}

impl NTreeOptions {
    /// The thesis' configuration: n = 10, depth 3.
    pub const fn thesis() -> Self {
        Self {
            n: 10,
            depth: 3,
            cubic_cells: true,
        }
    }
}

/// The N-tree with its line spaces, in the compact form (module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct NTree {
    pub n: u32,
    pub depth: u32,
    /// World box of the root: minimum corner and size of a leaf cell per axis.
    pub origin: [f32; 3],
    pub leaf_size: [f32; 3],
    /// First group of each level 0..depth−1, plus the end.
    pub level_groups: Vec<u32>,
    /// Per group, one bit per child with geometry (`occupancy_words()` u64 each).
    pub occupancy: Vec<u64>,
    /// Per group, the number of its first filled child: a group (levels below depth − 1) or a
    /// leaf (level depth − 1).
    pub first_child: Vec<u32>,
    /// Per leaf, the first entry of its triangles in `tri_indices`, plus the end.
    pub leaf_tris: Vec<u32>,
    /// Triangle indices of the leaves, leaf after leaf.
    pub tri_indices: Vec<u32>,
    /// The triangles, world space.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// `occupancy` with each group's slots reversed (bit s = slot n³ − 1 − s): what the
    /// reflected face pairs of the shaft table are read against. Derived, not stored.
    pub occupancy_rev: Vec<u64>,
    /// The shared shaft table of this n: line-space bits are `occupancy & cells(shaft)`.
    pub shafts: Arc<ShaftTable>,
    /// Reference only: when set, queries read line-space bits from this dense per-node pool
    /// ([`super::dense`], `Layout::words()` u32 per group) instead of the shaft table.
    pub dense_linespaces: Option<Arc<Vec<u32>>>,
    /// What a full shaft at the deepest line-space level means (query time, not stored).
    pub refine: Refine,
}

/// What a query does in a deepest-level node (its children are leaves) whose line space says
/// the segment's shaft is full. Each choice is one-sided: never lit where a triangle blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub enum Refine {
    /// The thesis: a full shaft is a hit (cheapest; over-occludes by up to a shaft's width).
    Shaft,
    /// Walk the leaves the segment crosses: a hit when one of them holds geometry (over-occludes
    /// by up to a leaf cell; reads occupancy bits only).
    Cells,
    /// Walk the leaves the segment crosses and test their triangles exactly (no over-occlusion;
    /// reads the triangles).
    #[default]
    Exact,
    /// `Shaft`, except in nodes the segment enters within one deepest-node side of its start,
    /// where `Exact` decides: the receiver's own surface continuing into the next node is what
    /// makes the thesis' rule speckle (docs/PERFORMANCE.md, issue 15).
    Near,
}

impl Refine {
    /// The shader's code for the mode.
    pub const fn code(self) -> u32 {
        match self {
            Refine::Shaft => 0,
            Refine::Cells => 1,
            Refine::Exact => 2,
            Refine::Near => 3,
        }
    }
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

pub(super) fn check_options(o: &NTreeOptions) -> Result<()> {
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

/// The root box: the triangles' bounds (or the cube of their longest extent from the same
/// minimum corner), padded by a thousandth on each side.
fn root_box(tris: &[[[f32; 3]; 3]], cubic: bool, extra: f32) -> Result<([f32; 3], [f32; 3])> {
    let pts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let (lo, hi) = crate::model::bounds_of(&pts)
        .ok_or_else(|| Error::Runtime("no triangles for the N-tree".into()))?;
    Ok(root_box_of(
        lo.map(|x| x - extra),
        hi.map(|x| x + extra),
        cubic,
    ))
}

/// [`root_box`] of the bounds `lo`..`hi`.
pub(super) fn root_box_of(lo: [f32; 3], hi: [f32; 3], cubic: bool) -> ([f32; 3], [f32; 3]) {
    let ext = [0, 1, 2].map(|k| (hi[k] - lo[k]).max(1e-6 * (1.0 + lo[k].abs())));
    let longest = ext.iter().cloned().fold(0.0, f32::max);
    let ext = if cubic { [longest; 3] } else { ext };
    let pad = ext.map(|e| e * 1e-3 + longest * 1e-6);
    (
        [0, 1, 2].map(|k| lo[k] - pad[k]),
        [0, 1, 2].map(|k| ext[k] + 2.0 * pad[k]),
    )
}

/// The cells of a build: sorted (leaf path key, triangle) pairs and the sorted unique path
/// keys per level (shared by the compact build and the dense reference).
pub(super) struct Cells {
    pub(super) origin: [f32; 3],
    pub(super) leaf_size: [f32; 3],
    pub(super) pairs: Vec<(u64, u32)>,
    pub(super) prefixes: Vec<Vec<u64>>,
}

/// Marks the leaf cells every triangle touches.
pub(super) fn mark_cells(tris: &[[[f32; 3]; 3]], opts: &NTreeOptions) -> Result<Cells> {
    mark_cells_padded(tris, opts, 0.0)
}

/// [`mark_cells`] with every triangle grown by `margin` (world units) on each side: the root
/// box by as much, and the cell test's margin at least `margin` (never below
/// [`CELL_MARGIN`] cells).
pub(super) fn mark_cells_padded(
    tris: &[[[f32; 3]; 3]],
    opts: &NTreeOptions,
    margin: f32,
) -> Result<Cells> {
    check_options(opts)?;
    let (origin, size) = root_box(tris, opts.cubic_cells, margin)?;
    let (n, depth) = (opts.n, opts.depth);
    let res = n.pow(depth);
    let leaf_size = size.map(|s| s / res as f32);
    let grid = Grid {
        origin,
        voxel_size: leaf_size,
        dims: [res; 3],
    };
    let smallest = leaf_size.iter().cloned().fold(f32::INFINITY, f32::min);
    let cell_margin = CELL_MARGIN.max(margin / smallest);
    let setups: Vec<TriSetup> = tris
        .par_iter()
        .map(|t| TriSetup::padded(t.map(|p| grid.to_grid(p)), cell_margin))
        .collect();
    let pairs = leaf_pairs(&setups, res, depth, n);
    let mut keys: Vec<u64> = pairs.iter().map(|p| p.0).collect();
    keys.dedup();
    let prefixes = level_prefixes(&keys, depth, n);
    Ok(Cells {
        origin,
        leaf_size,
        pairs,
        prefixes,
    })
}

/// Builds the N-tree over world-space triangles; `shafts` is the shaft table of `opts.n`.
pub fn build_ntree(
    tris: &[[[f32; 3]; 3]],
    opts: &NTreeOptions,
    shafts: &Arc<ShaftTable>,
) -> Result<NTree> {
    build_ntree_padded(tris, opts, shafts, 0.0)
}

/// [`build_ntree`] with the triangles' cells grown by `margin` world units (see
/// [`mark_cells_padded`]): a traversal on a segment within `margin` of the one a triangle
/// blocks still reaches its leaves (the instanced tree's models, whose segments are moved into
/// the model's frame with rounding).
pub fn build_ntree_padded(
    tris: &[[[f32; 3]; 3]],
    opts: &NTreeOptions,
    shafts: &Arc<ShaftTable>,
    margin: f32,
) -> Result<NTree> {
    if shafts.layout.n != opts.n {
        return Err(Error::Runtime("shaft table built for another n".into()));
    }
    let cells = mark_cells_padded(tris, opts, margin)?;
    Ok(NTree::from_cells(
        opts,
        cells.origin,
        cells.leaf_size,
        &cells.pairs,
        tris.to_vec(),
        shafts,
    ))
}

impl NTree {
    /// The tree of sorted (leaf path key, item) pairs: the leaves list the items (triangles,
    /// or for a top-level tree instance numbers; `triangles` may then be empty).
    pub(super) fn from_cells(
        opts: &NTreeOptions,
        origin: [f32; 3],
        leaf_size: [f32; 3],
        pairs: &[(u64, u32)],
        triangles: Vec<[[f32; 3]; 3]>,
        shafts: &Arc<ShaftTable>,
    ) -> NTree {
        let (n, depth) = (opts.n, opts.depth);
        let mut keys: Vec<u64> = pairs.iter().map(|p| p.0).collect();
        keys.dedup();
        let prefixes = level_prefixes(&keys, depth, n);
        let mut tree = NTree {
            n,
            depth,
            origin,
            leaf_size,
            level_groups: Vec::new(),
            occupancy: Vec::new(),
            occupancy_rev: Vec::new(),
            first_child: Vec::new(),
            leaf_tris: Vec::new(),
            tri_indices: pairs.iter().map(|p| p.1).collect(),
            triangles,
            shafts: shafts.clone(),
            dense_linespaces: None,
            refine: Refine::default(),
        };
        tree.link_groups(&prefixes);
        tree.fill_reversed();
        tree.leaf_tris = leaf_runs(&prefixes[depth as usize], pairs);
        tree
    }
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

/// First group of each level 0..depth−1, plus the end (groups numbered breadth-first).
pub(super) fn level_groups_of(prefixes: &[Vec<u64>], depth: u32) -> Vec<u32> {
    let mut level_groups = vec![0u32];
    for p in &prefixes[..depth as usize] {
        level_groups.push(level_groups.last().copied().unwrap_or(0) + p.len() as u32);
    }
    level_groups
}

/// Per leaf (sorted keys), the start of its run in `pairs` (sorted by key), plus the end.
fn leaf_runs(leaves: &[u64], pairs: &[(u64, u32)]) -> Vec<u32> {
    let mut out = Vec::with_capacity(leaves.len() + 1);
    let mut run = 0usize;
    for &q in leaves {
        while run < pairs.len() && pairs[run].0 < q {
            run += 1;
        }
        out.push(run as u32);
    }
    out.push(pairs.len() as u32);
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

    /// Number of inner nodes (= groups).
    pub fn inner_nodes(&self) -> usize {
        *self.level_groups.last().unwrap_or(&0) as usize
    }

    /// Number of leaves (filled cells of the deepest level).
    pub fn leaves(&self) -> usize {
        self.leaf_tris.len().saturating_sub(1)
    }

    /// Sets occupancy and `first_child` from the per-level prefixes: the children of the
    /// nodes of level l are the keys of level l + 1, parent by parent, in slot order.
    fn link_groups(&mut self, prefixes: &[Vec<u64>]) {
        let n3 = self.n3() as u64;
        let depth = self.depth as usize;
        self.level_groups = level_groups_of(prefixes, self.depth);
        let groups = self.inner_nodes();
        let w = self.occupancy_words();
        let mut occ = vec![0u64; groups * w];
        let mut first = vec![0u32; groups];
        for l in 0..depth {
            let (g0, mut parent) = (self.level_groups[l] as usize, 0usize);
            // Children of level l + 1 are numbered from level_groups[l + 1] (groups) or 0 (leaves).
            let base = if l + 1 < depth {
                self.level_groups[l + 1]
            } else {
                0
            };
            let mut prev_parent = usize::MAX;
            for (i, &q) in prefixes[l + 1].iter().enumerate() {
                while prefixes[l][parent] != q / n3 {
                    parent += 1;
                }
                let (g, slot) = (g0 + parent, (q % n3) as usize);
                occ[g * w + slot / 64] |= 1 << (slot % 64);
                if parent != prev_parent {
                    first[g] = base + i as u32;
                    prev_parent = parent;
                }
            }
        }
        self.occupancy = occ;
        self.first_child = first;
    }

    /// Derives [`Self::occupancy_rev`] from the occupancy.
    pub fn fill_reversed(&mut self) {
        let (w, n3) = (self.occupancy_words(), self.n3());
        self.occupancy_rev = self
            .occupancy
            .chunks(w)
            .flat_map(|g| reverse_slots(g, n3))
            .collect();
    }

    /// u64 words of one group's occupancy bits.
    pub fn occupancy_words(&self) -> usize {
        self.n3().div_ceil(64)
    }

    /// The occupancy words of group `g`.
    #[inline]
    pub fn occupancy_of(&self, g: u32) -> &[u64] {
        let w = self.occupancy_words();
        &self.occupancy[g as usize * w..(g as usize + 1) * w]
    }

    /// Line-space bit `bit` of group `g`: from the shared shaft table, or from the dense
    /// reference pool when one is set.
    #[inline]
    pub fn linespace_bit(&self, g: u32, bit: u64) -> bool {
        match &self.dense_linespaces {
            None => {
                let w = self.occupancy_words();
                let rev = &self.occupancy_rev[g as usize * w..(g as usize + 1) * w];
                self.shafts.meets(bit, self.occupancy_of(g), rev)
            }
            Some(pool) => {
                let w = self.layout().words();
                super::layout::get(&pool[g as usize * w..(g as usize + 1) * w], bit)
            }
        }
    }

    /// Whether child `slot` of group `g` holds geometry.
    #[inline]
    pub fn filled(&self, g: u32, slot: usize) -> bool {
        self.occupancy[g as usize * self.occupancy_words() + slot / 64] >> (slot % 64) & 1 == 1
    }

    /// The filled children of group `g` below `slot`.
    #[inline]
    pub fn rank(&self, g: u32, slot: usize) -> u32 {
        let occ = self.occupancy_of(g);
        let whole: u32 = occ[..slot / 64].iter().map(|w| w.count_ones()).sum();
        whole + (occ[slot / 64] & ((1u64 << (slot % 64)) - 1)).count_ones()
    }

    /// The number of the filled child at `slot` of group `g`: a group, or on the deepest inner
    /// level a leaf.
    #[inline]
    pub fn child(&self, g: u32, slot: usize) -> u32 {
        self.first_child[g as usize] + self.rank(g, slot)
    }

    /// Triangles of leaf `leaf`.
    pub fn leaf_triangles(&self, leaf: u32) -> &[u32] {
        let (a, b) = (
            self.leaf_tris[leaf as usize],
            self.leaf_tris[leaf as usize + 1],
        );
        &self.tri_indices[a as usize..b as usize]
    }

    /// Bytes of the compact arrays (what the section and the GPU pools hold).
    pub fn bytes(&self) -> usize {
        8 * self.occupancy.len()
            + 4 * (self.first_child.len() + self.leaf_tris.len() + self.tri_indices.len())
            + 36 * self.triangles.len()
            + self.shafts.bytes()
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
