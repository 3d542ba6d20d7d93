//! The dense layout of the thesis (Fig. 8–9), kept as a reference for tests and the benchmark:
//! no pack or GPU pool stores it any more (the `linespace` section is the compact form of
//! [`super::ntree`]).
//!
//! - Node pool: [`NodeEntry`] (8 B, like the thesis' RG32UI texel). Entry 0 is the root; group g
//!   (the n³ children of inner node number g, in BFS order) occupies entries 1 + g·n³ … with child
//!   (x, y, z) at offset x + n·y + n²·z. `word`: bit 0 = holds geometry, bit 1 = has children,
//!   bits 2–31 = the child group (30 bits), or for a leaf the triangle count; the second word:
//!   the child's group again, or the leaf's first index into `tri_indices`.
//! - Line-space pool: `Layout::words()` u32 per group, built as the OR of the child masks of the
//!   group's filled children ([`ChildMasks`]), independently of the shaft table.
//!
//! At n = 10 that is 8,000 B of nodes and 18,752 B of line space per inner node, whether its
//! children hold geometry or not (863 MB for the fixture scene at depth 3 with flat cells, 318 MB
//! with cubic ones; the compact section is 25 MB).

use super::ntree::{NTreeOptions, level_groups_of, mark_cells};
use super::shaft::ChildMasks;
use crate::error::{Error, Result};
use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

/// A node-pool entry: repr(C), Pod, 8 bytes. Example: a node with geometry and children whose
/// group is 5 has word 1 | 2 | 5 << 2 = 23 and second word 5; a leaf touched by 3 triangles
/// listed from index 40 has word 1 | 3 << 2 = 13 and second word 40.
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

/// The thesis' pools of one N-tree.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseNTree {
    pub n: u32,
    pub level_groups: Vec<u32>,
    pub nodes: Vec<NodeEntry>,
    pub linespaces: Vec<u32>,
    pub tri_indices: Vec<u32>,
}

impl DenseNTree {
    /// The entry of child `slot` of group `g`.
    pub fn entry(&self, g: u32, slot: usize) -> NodeEntry {
        let n3 = (self.n * self.n * self.n) as usize;
        self.nodes[1 + g as usize * n3 + slot]
    }

    /// The line space of group `g`.
    pub fn linespace(&self, g: u32) -> &[u32] {
        let w = super::layout::Layout::new(self.n).words();
        &self.linespaces[g as usize * w..(g as usize + 1) * w]
    }

    /// Bytes of the dense pools (node entries, line spaces).
    pub fn bytes(&self) -> (usize, usize) {
        (8 * self.nodes.len(), 4 * self.linespaces.len())
    }
}

/// Builds the dense pools the way the thesis does (and this crate did before the compact
/// form): same cells as [`super::ntree::build_ntree`].
pub fn build_dense(
    tris: &[[[f32; 3]; 3]],
    opts: &NTreeOptions,
    masks: &ChildMasks,
) -> Result<DenseNTree> {
    if masks.layout.n != opts.n {
        return Err(Error::Runtime(
            "child-mask table built for another n".into(),
        ));
    }
    let cells = mark_cells(tris, opts)?;
    let level_groups = level_groups_of(&cells.prefixes, opts.depth);
    let nodes = link_nodes(&cells.prefixes, &cells.pairs, &level_groups, opts);
    Ok(DenseNTree {
        n: opts.n,
        linespaces: build_linespaces(&cells.prefixes, opts.n, masks),
        level_groups,
        nodes,
        tri_indices: cells.pairs.iter().map(|p| p.1).collect(),
    })
}

/// The node pool from the per-level prefixes (groups in BFS order); leaves point at their run
/// of `pairs` (sorted (leaf key, triangle)).
fn link_nodes(
    prefixes: &[Vec<u64>],
    pairs: &[(u64, u32)],
    level_groups: &[u32],
    opts: &NTreeOptions,
) -> Vec<NodeEntry> {
    let mut run = 0usize;
    let n3 = (opts.n * opts.n * opts.n) as u64;
    let depth = opts.depth as usize;
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
    nodes
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
