//! The sparse voxel octree, stored as a tree of 4³ nodes with 64-bit child masks (each node is
//! two octree levels), topology and attributes in separate arrays.
//!
//! Layout (chosen by measurement, see docs/PERFORMANCE.md "Voxels and line spaces": ESVO-style
//! 8-byte child descriptors need about 2.7 B/voxel of topology on thin surfaces, u64 brick masks
//! about 0.57 B/voxel, and the stored form of the bricks, 2³ sub-masks ([`super::packed`]),
//! about 0.38 B/voxel; [`esvo_topology_bytes`] computes the ESVO figure for the same voxels).
//! In memory the bricks are plain u64 masks:
//!
//! - The root covers 4^L voxels per axis (L = [`Svo::levels`] ≥ 2, the smallest power of four
//!   that holds the grid). Levels 0..L−2 are inner [`Node`]s (16 B); level L−1 are bricks, a bare
//!   u64 mask over their 4³ voxels (8 B). No node or brick has an empty mask: there are no empty
//!   subtrees.
//! - Child slot s of a node is the cell at Morton offset s (bit 0: x, bit 1: y, bit 2: z of the
//!   2-bit cell coordinate, interleaved); children of a node are stored contiguously in slot order,
//!   so child s is `first_child + popcount(mask & ((1 << s) − 1))`.
//! - Voxel attributes are in Morton order. A voxel's index is the `first_voxel` of the brick's
//!   parent, plus the popcounts of the sibling bricks before it, plus the popcount of the brick's
//!   mask below the voxel's slot (bricks carry no pointer).
//! - Attributes per voxel: colour RGBA8, linear, premultiplied alpha; normal as 2 × snorm16
//!   octahedral. Per node and brick the filtered value of its 64 cells: the mean of the children's
//!   premultiplied colours with empty cells counting as transparent black (so alpha is coverage),
//!   and the coverage-weighted mean normal of all the voxels below.
//!
//! Worked example: a brick whose voxels (0,0,0) and (1,0,0) are set has mask 0b11; a parent with
//! that brick in slot 5 has bit 5 set; if its `first_voxel` is 100 and its bricks in slots 0..4
//! hold 7 voxels, voxel (1,0,0) of the brick is attribute 100 + 7 + 1 = 108.

use super::Grid;
use super::voxelize::{Brick, Voxels};
use bytemuck::{Pod, Zeroable};

/// An inner node: repr(C), Pod, 16 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
pub struct Node {
    /// Child mask, low and high 32 bits (u32 pairs keep the layout WGSL-friendly).
    pub mask: [u32; 2],
    /// Index of the first child: into [`Svo::nodes`] for levels < L−2, into [`Svo::bricks`] for
    /// level L−2.
    pub first_child: u32,
    /// Attribute index of the first voxel (Morton order) of the subtree.
    pub first_voxel: u32,
}
const _: () = assert!(size_of::<Node>() == 16);

impl Node {
    pub fn mask(&self) -> u64 {
        self.mask[0] as u64 | (self.mask[1] as u64) << 32
    }
}

/// The sparse voxel octree.
#[derive(Debug, Clone, PartialEq)]
pub struct Svo {
    pub grid: Grid,
    /// The root covers 4^levels voxels per axis.
    pub levels: u32,
    /// Inner nodes, level by level from the root, Morton order within a level.
    pub nodes: Vec<Node>,
    /// `level_start[l]`: index of the first node of inner level l (plus the end).
    pub level_start: Vec<u32>,
    /// Bricks (level L−1): masks over 4³ voxels, Morton order.
    pub bricks: Vec<u64>,
    /// Per voxel, Morton order: RGBA8 linear premultiplied (r in the low byte).
    pub voxel_colors: Vec<u32>,
    /// Per voxel: octahedral normal, x in the low 16 bits (snorm16), y in the high.
    pub voxel_normals: Vec<u32>,
    /// Filtered colour per inner node, then per brick (index `nodes.len() + brick`).
    pub node_colors: Vec<u32>,
    /// Filtered normal per inner node, then per brick.
    pub node_normals: Vec<u32>,
}

/// Byte figures of an octree.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SvoStats {
    pub voxels: u64,
    pub nodes: u64,
    pub bricks: u64,
    pub topology_bytes: u64,
    pub attribute_bytes: u64,
    pub esvo_topology_bytes: u64,
    /// The same inner nodes with bricks as u64 masks (the in-memory form, 8 B per brick).
    pub mask64_topology_bytes: u64,
}

/// Packs linear RGBA in 0..1 to RGBA8.
pub fn pack_rgba8(c: [f32; 4]) -> u32 {
    let q = c.map(|x| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u32);
    q[0] | q[1] << 8 | q[2] << 16 | q[3] << 24
}

/// Unpacks RGBA8 to 0..1.
pub fn unpack_rgba8(v: u32) -> [f32; 4] {
    [0, 8, 16, 24].map(|s| ((v >> s) & 255) as f32 / 255.0)
}

/// Octahedral encoding of a normal's direction (zero encodes as zero). +Z would be (0, 0), the
/// zero code, so it is stored one step off, as (0, 1): 1/32767 rad, below the quantization.
pub fn pack_normal(n: [f32; 3]) -> u32 {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if l1 == 0.0 {
        return 0;
    }
    let (mut x, mut y) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * ox.signum();
        y = (1.0 - ox.abs()) * oy.signum();
    }
    let q = |v: f32| ((v.clamp(-1.0, 1.0) * 32767.0).round() as i16) as u16 as u32;
    match q(x) | q(y) << 16 {
        0 => 1 << 16,
        v => v,
    }
}

/// Inverse of [`pack_normal`].
pub fn unpack_normal(v: u32) -> [f32; 3] {
    if v == 0 {
        return [0.0; 3];
    }
    let x = (v & 0xffff) as u16 as i16 as f32 / 32767.0;
    let y = (v >> 16) as u16 as i16 as f32 / 32767.0;
    let z = 1.0 - x.abs() - y.abs();
    let (x, y) = if z < 0.0 {
        ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum())
    } else {
        (x, y)
    };
    super::voxelize_shade::normalize([x, y, z])
}

/// Levels of a 4³-node tree holding `dims` voxels per axis (at least 2).
pub fn levels_for(dims: [u32; 3]) -> u32 {
    let m = dims.iter().copied().max().unwrap_or(1).max(1) as u64;
    let mut l = 1;
    while 4u64.pow(l) < m {
        l += 1;
    }
    l.max(2)
}

/// One level of keys with masks, plus for each parent the index of its first child.
struct Level {
    keys: Vec<u64>,
    masks: Vec<u64>,
    first_child: Vec<u32>,
}

fn parent_level(child_keys: &[u64]) -> Level {
    let mut lv = Level {
        keys: Vec::new(),
        masks: Vec::new(),
        first_child: Vec::new(),
    };
    for (i, &k) in child_keys.iter().enumerate() {
        let p = k >> 6;
        if lv.keys.last() != Some(&p) {
            lv.keys.push(p);
            lv.masks.push(0);
            lv.first_child.push(i as u32);
        }
        *lv.masks.last_mut().unwrap_or(&mut 0) |= 1 << (k & 63);
    }
    lv
}

/// Builds the octree from voxels (bricks in Morton order, as [`super::voxelize`] makes them).
pub fn voxels_to_svo(v: &Voxels) -> Svo {
    let levels = levels_for(v.grid.dims);
    let brick_keys: Vec<u64> = v.bricks.iter().map(|b| b.key).collect();
    // Inner levels bottom-up: parents[0] is level L-2, the last is the root.
    let mut parents: Vec<Level> = Vec::new();
    let mut keys = brick_keys.clone();
    for _ in 0..levels - 1 {
        let lv = parent_level(&keys);
        keys = lv.keys.clone();
        parents.push(lv);
    }
    parents.reverse();
    let brick_first_voxel = prefix_popcounts(v.bricks.iter().map(|b| b.mask));
    let mut level_start = vec![0u32];
    for lv in &parents {
        level_start.push(level_start.last().copied().unwrap_or(0) + lv.keys.len() as u32);
    }
    let mut nodes = Vec::with_capacity(*level_start.last().unwrap_or(&0) as usize);
    for (l, lv) in parents.iter().enumerate() {
        let child_base = if l + 1 < parents.len() {
            level_start[l + 1]
        } else {
            0
        };
        for i in 0..lv.keys.len() {
            nodes.push(Node {
                mask: [lv.masks[i] as u32, (lv.masks[i] >> 32) as u32],
                first_child: child_base + lv.first_child[i],
                first_voxel: 0,
            });
        }
    }
    let mut svo = Svo {
        grid: v.grid,
        levels,
        nodes,
        level_start,
        bricks: v.bricks.iter().map(|b| b.mask).collect(),
        voxel_colors: v
            .colors
            .iter()
            .map(|&c| pack_rgba8(premultiply(c)))
            .collect(),
        voxel_normals: v.normals.iter().map(|&n| pack_normal(n)).collect(),
        node_colors: Vec::new(),
        node_normals: Vec::new(),
    };
    svo.fill_first_voxel(&brick_first_voxel);
    svo.filter_attributes(v);
    svo
}

fn premultiply(c: [f32; 4]) -> [f32; 4] {
    [c[0] * c[3], c[1] * c[3], c[2] * c[3], c[3]]
}

fn prefix_popcounts(masks: impl Iterator<Item = u64>) -> Vec<u32> {
    let mut total = 0u32;
    masks
        .map(|m| {
            let r = total;
            total += m.count_ones();
            r
        })
        .collect()
}

impl Svo {
    /// Number of inner levels (L − 1).
    pub fn inner_levels(&self) -> usize {
        self.level_start.len() - 1
    }

    /// Child index of slot `s` of node `n`.
    pub fn child(&self, n: &Node, s: u32) -> u32 {
        let below = n.mask() & ((1u64 << s) - 1);
        n.first_child + below.count_ones()
    }

    /// Sets `first_voxel` bottom-up: a node's first voxel is its first child's.
    fn fill_first_voxel(&mut self, brick_first_voxel: &[u32]) {
        for l in (0..self.inner_levels()).rev() {
            let is_last = l + 1 == self.inner_levels();
            for i in self.level_start[l]..self.level_start[l + 1] {
                let fc = self.nodes[i as usize].first_child as usize;
                self.nodes[i as usize].first_voxel = if is_last {
                    brick_first_voxel.get(fc).copied().unwrap_or(0)
                } else {
                    self.nodes[fc].first_voxel
                };
            }
        }
    }

    /// Filtered attributes of bricks, then of inner nodes bottom-up (premultiplied means over
    /// 64 cells, empty = transparent black; α-weighted normal sums, see [`filter_cells`]).
    fn filter_attributes(&mut self, v: &Voxels) {
        let mut brick_acc: Vec<([f32; 4], [f32; 3])> = Vec::with_capacity(self.bricks.len());
        let mut at = 0usize;
        for &m in &self.bricks {
            let k = m.count_ones() as usize;
            let cells = (at..at + k).map(|i| {
                let c = premultiply(v.colors[i]);
                (c, v.normals[i].map(|x| x * c[3]))
            });
            brick_acc.push(filter_cells(cells));
            at += k;
        }
        let mut node_acc = vec![([0.0f32; 4], [0.0f32; 3]); self.nodes.len()];
        for l in (0..self.inner_levels()).rev() {
            let is_last = l + 1 == self.inner_levels();
            for i in self.level_start[l] as usize..self.level_start[l + 1] as usize {
                let n = self.nodes[i];
                let k = n.mask().count_ones() as usize;
                let fc = n.first_child as usize;
                let src = if is_last { &brick_acc } else { &node_acc };
                let cells: Vec<_> = src[fc..fc + k].to_vec();
                node_acc[i] = filter_cells(cells.into_iter());
            }
        }
        self.node_colors = node_acc
            .iter()
            .chain(&brick_acc)
            .map(|(c, _)| pack_rgba8(*c))
            .collect();
        self.node_normals = node_acc
            .iter()
            .chain(&brick_acc)
            .map(|(_, n)| pack_normal(*n))
            .collect();
    }

    /// Attribute index of voxel `c`, or None if it is empty.
    pub fn voxel_index(&self, c: [u32; 3]) -> Option<usize> {
        if (0..3).any(|k| c[k] >= self.grid.dims[k]) {
            return None;
        }
        let key = super::morton_encode(c);
        let mut node = self.nodes[0];
        for l in 0..self.inner_levels() {
            let shift = 6 * (self.levels as usize - 1 - l);
            let slot = ((key >> shift) & 63) as u32;
            if node.mask() >> slot & 1 == 0 {
                return None;
            }
            let child = self.child(&node, slot) as usize;
            if l + 1 == self.inner_levels() {
                let brick = self.bricks[child];
                let s = (key & 63) as u32;
                if brick >> s & 1 == 0 {
                    return None;
                }
                let siblings: u32 = self.bricks[node.first_child as usize..child]
                    .iter()
                    .map(|b| b.count_ones())
                    .sum();
                let below = (brick & ((1u64 << s) - 1)).count_ones();
                return Some((node.first_voxel + siblings + below) as usize);
            }
            node = self.nodes[child];
        }
        None
    }

    /// All leaf voxels, as bricks in Morton order (walks the tree; the round-trip check).
    pub fn leaf_bricks(&self) -> Vec<Brick> {
        let mut out = Vec::new();
        self.walk(0, 0, 0, &mut out);
        out
    }

    fn walk(&self, level: usize, node: usize, key: u64, out: &mut Vec<Brick>) {
        let n = self.nodes[node];
        let mut m = n.mask();
        while m != 0 {
            let s = m.trailing_zeros();
            let child = self.child(&n, s) as usize;
            let k = key << 6 | s as u64;
            if level + 1 == self.inner_levels() {
                out.push(Brick {
                    key: k,
                    mask: self.bricks[child],
                });
            } else {
                self.walk(level + 1, child, k, out);
            }
            m &= m - 1;
        }
    }

    /// Byte figures (topology as stored: 16 B per inner node + the packed bricks).
    pub fn stats(&self) -> SvoStats {
        let voxels = self.voxel_colors.len() as u64;
        let topology_bytes = submask_topology_bytes(self.nodes.len(), &self.bricks);
        let attribute_bytes = 4
            * (self.voxel_colors.len()
                + self.voxel_normals.len()
                + self.node_colors.len()
                + self.node_normals.len()) as u64;
        SvoStats {
            voxels,
            nodes: (self.nodes.len() + self.bricks.len()) as u64,
            bricks: self.bricks.len() as u64,
            topology_bytes,
            attribute_bytes,
            esvo_topology_bytes: esvo_topology_bytes(&self.leaf_bricks(), self.levels),
            mask64_topology_bytes: 16 * self.nodes.len() as u64 + 8 * self.bricks.len() as u64,
        }
    }
}

/// Mean of 64 cells from the occupied ones: premultiplied colour, and the normal as the mean of
/// α-weighted normals, kept unnormalized up the tree so that a node's normal is the
/// coverage-weighted mean over all the voxels below it (normalizing per level would weight each
/// child by its coverage alone, losing how well its voxels agree); [`pack_normal`] keeps only
/// the direction.
fn filter_cells(cells: impl Iterator<Item = ([f32; 4], [f32; 3])>) -> ([f32; 4], [f32; 3]) {
    let mut c = [0.0f32; 4];
    let mut n = [0.0f32; 3];
    for (cc, nn) in cells {
        for k in 0..4 {
            c[k] += cc[k];
        }
        for k in 0..3 {
            n[k] += nn[k];
        }
    }
    (c.map(|x| x / 64.0), n.map(|x| x / 64.0))
}

/// Topology bytes of the same voxels as an ESVO octree: one 8-byte child descriptor per octree
/// node that has children (far pointers, contours and page headers not counted).
pub fn esvo_topology_bytes(bricks: &[Brick], levels: u32) -> u64 {
    // Octree level just above the voxels: the non-empty 2³ octants of each brick.
    let octants: u64 = bricks
        .iter()
        .map(|b| (0..8).filter(|o| b.mask >> (8 * o) & 0xff != 0).count() as u64)
        .sum();
    let mut count = octants + bricks.len() as u64;
    let mut keys: Vec<u64> = bricks.iter().map(|b| b.key).collect();
    // Two octree levels per 4³ level above the bricks, up to the root.
    for _ in 0..2 * (levels - 1) {
        keys = keys.iter().map(|k| k >> 3).collect();
        keys.dedup();
        count += keys.len() as u64;
    }
    8 * count
}

/// Topology bytes as stored ([`super::packed`]): 16-byte inner nodes, and each 4³ brick as one
/// byte of non-empty 2³ octants followed by one 8-bit mask per non-empty octant. A plane crossing
/// a brick fills 4 octants with 16 voxels: 5 bytes instead of a u64 mask's 8.
pub fn submask_topology_bytes(inner_nodes: usize, bricks: &[u64]) -> u64 {
    let leaves: u64 = bricks
        .iter()
        .map(|&m| super::packed::brick_bytes(m) as u64)
        .sum();
    16 * inner_nodes as u64 + leaves
}

#[cfg(test)]
mod normal_tests {
    use super::{pack_normal, unpack_normal};

    #[test]
    fn only_the_zero_vector_packs_to_the_zero_code() {
        assert_eq!(pack_normal([0.0; 3]), 0);
        assert_eq!(unpack_normal(0), [0.0; 3]);
        for n in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1e-3],
            [1e-7, 0.0, 2.0],
            [0.0, 0.0, -1.0],
        ] {
            let p = pack_normal(n);
            assert_ne!(p, 0, "{n:?}");
            let u = unpack_normal(p);
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let dot: f32 = (0..3).map(|k| u[k] * n[k] / l).sum();
            assert!(dot > 0.99999, "{n:?} → {u:?}");
        }
    }
}

#[cfg(test)]
mod submask_tests {
    #[test]
    fn submask_bytes_count_one_header_and_one_byte_per_octant() {
        // A full brick: header + 8 octants; one voxel: header + 1; a 4×4 plane z = 0 (slots with
        // z bits 0: octants 0, 1, 2 and 3 hold 4 voxels each): header + 4.
        let plane: u64 = (0..64u64)
            .filter(|s| s >> 2 & 1 == 0 && s >> 5 & 1 == 0)
            .map(|s| 1u64 << s)
            .sum();
        assert_eq!(plane.count_ones(), 16);
        assert_eq!(
            super::submask_topology_bytes(0, &[u64::MAX, 1 << 40, plane]),
            9 + 2 + 5
        );
        assert_eq!(super::submask_topology_bytes(3, &[]), 48);
    }
}
