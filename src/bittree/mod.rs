//! BitTree (seed 000, 5.1.1): implicit instance positions.
//!
//! The area of interest is discretized into cells so small that no cell holds two instances. A
//! hierarchy splits each occupied cell of a level into n = 4, 16 or 64 children (2×2, 4×4 or 8×8)
//! and stores one bit per child (1 = holds at least one instance), refining only occupied cells.
//! Bits are written level by level (breadth first), children of a node in row-major order
//! (x fastest). Leaves at the last level are single cells; a decoded position is the centre of its
//! cell, so it is within half a cell diagonal of the original. Instances come back in leaf order
//! (breadth first), which [`encode_bittree`] returns as a permutation so per-instance attributes
//! (scale, rotation, model, layer) can be stored beside the bits in the same order.
//!
//! Real scenes hold coincident and near-coincident instances (a plant placed twice, two layers
//! scattered over one spot), which no depth separates. The tree is therefore refined only until
//! every cell's instances lie within [`MIN_CELL`] of each other (or `max_levels` is reached):
//! instances still sharing a leaf there are listed in [`BitTree::shared`], one leaf index per
//! further instance (4 bytes each), and decode to the same cell centre, next to each other in
//! leaf order, within half a cell of their positions like every other instance.

pub mod section;
pub mod stage;

use crate::model::Rect;

/// Options of the BitTree encoder.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BitTreeOptions {
    /// Children per level: 4, 16 or 64.
    pub children: u32,
    /// Deepest level allowed; instances still sharing a cell there share a leaf
    /// ([`BitTree::shared`]).
    pub max_levels: u32,
}

impl BitTreeOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: BitTreeOptions = BitTreeOptions {
        children: 16,
        max_levels: 24,
    };
}

impl Default for BitTreeOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Instances this close (metres, in x and in y) may share a leaf instead of forcing deeper levels.
pub const MIN_CELL: f64 = 1e-3;

/// An encoded BitTree.
#[derive(Debug, Clone, PartialEq)]
pub struct BitTree {
    pub area: Rect,
    pub children: u32,
    pub levels: u32,
    /// Number of instances: the leaves plus `shared.len()`.
    pub count: u64,
    /// The bit stream, packed little-endian into bytes (bit k of the stream is bit k%8 of byte k/8).
    pub bits: Vec<u8>,
    /// Number of bits used in `bits`.
    pub bit_len: u64,
    /// For each instance beyond the first in a leaf, that leaf's index (in leaf order,
    /// non-decreasing); empty when every instance has its own cell.
    pub shared: Vec<u32>,
}

impl BitTree {
    /// Children per axis (2, 4 or 8).
    pub fn side(&self) -> u32 {
        side_of(self.children)
    }
    /// Cell size at the deepest level in x and y.
    pub fn cell_size(&self) -> [f32; 2] {
        let cells = (self.side() as f64).powi(self.levels as i32);
        [
            (self.area.extent[0] as f64 / cells) as f32,
            (self.area.extent[1] as f64 / cells) as f32,
        ]
    }
}

fn side_of(children: u32) -> u32 {
    match children {
        4 => 2,
        16 => 4,
        _ => 8,
    }
}

/// Why a BitTree could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BitTreeError {
    #[error("children per level must be 4, 16 or 64, not {0}")]
    Children(u32),
    #[error("shared-leaf list is not non-decreasing leaf indices below {0}")]
    Shared(u64),
    #[error("the area of interest has no extent")]
    EmptyArea,
    #[error("bit stream ends early at bit {0}")]
    Truncated(u64),
    #[error("bit stream decodes to {0} leaves, expected {1}")]
    CountMismatch(u64, u64),
}

/// Integer cell of a point at `cells` cells per axis, clamped into the area.
fn cell_of(p: [f32; 2], area: &Rect, cells: u64) -> [u64; 2] {
    let mut c = [0u64; 2];
    for k in 0..2 {
        let t = ((p[k] - area.origin[k]) as f64 / area.extent[k] as f64).clamp(0.0, 1.0);
        c[k] = ((t * cells as f64) as u64).min(cells - 1);
    }
    c
}

/// The points' path keys in a tree of `levels` levels, sorted: breadth-first leaf order is the
/// order of the digit sequences (most significant level first), i.e. of the interleaved
/// base-`side` keys; ties (a shared leaf) in input order.
fn keyed_points(points: &[[f32; 2]], area: &Rect, side: u64, levels: u32) -> Vec<(u128, u32)> {
    let cells = side.pow(levels);
    let mut keyed: Vec<(u128, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| (path_key(cell_of(*p, area, cells), side, levels), i as u32))
        .collect();
    keyed.sort_unstable();
    keyed
}

/// The leaf order of `points` in the grid of a tree over `area` with `children` per node and
/// `levels` levels: `order[k]` is the point decoded as the k-th position, as [`encode_bittree`]
/// returns it. A reader that keeps per-instance data in input order pairs the decoded
/// positions with it through this.
pub fn leaf_order(points: &[[f32; 2]], area: &Rect, children: u32, levels: u32) -> Vec<u32> {
    keyed_points(points, area, side_of(children) as u64, levels)
        .into_iter()
        .map(|(_, i)| i)
        .collect()
}

/// The deepest-level cell (column, row) of a point in that grid, clamped into the area.
pub fn leaf_cell(p: [f32; 2], area: &Rect, children: u32, levels: u32) -> [u64; 2] {
    cell_of(p, area, (side_of(children) as u64).pow(levels))
}

/// Encodes positions (x, y) inside `area`. Returns the tree and the leaf order: `order[k]` is the
/// index of the input instance decoded as the k-th position.
pub fn encode_bittree(
    points: &[[f32; 2]],
    area: Rect,
    opts: &BitTreeOptions,
) -> Result<(BitTree, Vec<u32>), BitTreeError> {
    if ![4, 16, 64].contains(&opts.children) {
        return Err(BitTreeError::Children(opts.children));
    }
    if area.extent[0] <= 0.0 || area.extent[1] <= 0.0 {
        return Err(BitTreeError::EmptyArea);
    }
    let side = side_of(opts.children) as u64;
    let levels = choose_levels(points, &area, side, opts.max_levels);
    let keyed = keyed_points(points, &area, side, levels);
    let mut bits = BitWriter::default();
    // Nodes of the current level as ranges of `keyed` sharing the same prefix.
    let mut nodes: Vec<(usize, usize)> = if keyed.is_empty() {
        Vec::new()
    } else {
        vec![(0, keyed.len())]
    };
    let n = side * side;
    for level in 0..levels {
        let exp = levels - 1 - level; // this level's digit is the coefficient of (side²)^exp
        let mut next = Vec::with_capacity(nodes.len() * 2);
        for &(lo, hi) in &nodes {
            let mut k = lo;
            for child in 0..n {
                let start = k;
                while k < hi && digit(keyed[k].0, exp, side) == child as u128 {
                    k += 1;
                }
                bits.push(k > start);
                if k > start {
                    next.push((start, k));
                }
            }
        }
        nodes = next;
    }
    let shared = nodes
        .iter()
        .enumerate()
        .flat_map(|(leaf, &(lo, hi))| std::iter::repeat_n(leaf as u32, hi - lo - 1))
        .collect();
    let order = keyed.iter().map(|&(_, i)| i).collect();
    let tree = BitTree {
        area,
        children: opts.children,
        levels,
        count: points.len() as u64,
        bit_len: bits.len,
        bits: bits.bytes,
        shared,
    };
    Ok((tree, order))
}

/// The interleaved path key: per level, digit = row·side + column, most significant level first.
fn path_key(c: [u64; 2], side: u64, levels: u32) -> u128 {
    let mut key = 0u128;
    for level in 0..levels {
        let div = side.pow(levels - 1 - level);
        let d = ((c[1] / div) % side) * side + (c[0] / div) % side;
        key = key * (side * side) as u128 + d as u128;
    }
    key
}

fn digit(key: u128, exp: u32, side: u64) -> u128 {
    let base = (side * side) as u128;
    (key / base.pow(exp)) % base
}

/// The fewest levels at which the points sharing any one cell lie within [`MIN_CELL`] of each
/// other (in x and in y), at most `max_levels`.
fn choose_levels(points: &[[f32; 2]], area: &Rect, side: u64, max_levels: u32) -> u32 {
    let max_levels = max_levels
        .min(126 / (2 * side.trailing_zeros()).max(1))
        .max(1);
    let mut keyed: Vec<([u64; 2], usize)> = Vec::with_capacity(points.len());
    for levels in 1..max_levels {
        let cells = side.pow(levels);
        keyed.clear();
        keyed.extend(
            points
                .iter()
                .enumerate()
                .map(|(i, p)| (cell_of(*p, area, cells), i)),
        );
        keyed.sort_unstable();
        let separated = keyed
            .chunk_by(|a, b| a.0 == b.0)
            .all(|run| run.len() == 1 || within_min_cell(run.iter().map(|&(_, i)| points[i])));
        if separated {
            return levels;
        }
    }
    max_levels
}

/// Whether points lie within [`MIN_CELL`] of each other in x and in y (their bounding box).
fn within_min_cell(points: impl Iterator<Item = [f32; 2]>) -> bool {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for p in points {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..2).all(|k| ((hi[k] - lo[k]) as f64) <= MIN_CELL)
}

/// Decodes cell-centre positions (x, y) in leaf order (instances sharing a leaf next to each
/// other).
pub fn decode_bittree(tree: &BitTree) -> Result<Vec<[f32; 2]>, BitTreeError> {
    let leaves = tree
        .count
        .checked_sub(tree.shared.len() as u64)
        .ok_or(BitTreeError::CountMismatch(0, tree.count))?;
    if tree.shared.windows(2).any(|w| w[0] > w[1])
        || tree.shared.last().is_some_and(|&l| l as u64 >= leaves)
    {
        return Err(BitTreeError::Shared(leaves));
    }
    let side = side_of(tree.children) as u64;
    let n = side * side;
    let mut reader = BitReader {
        bytes: &tree.bits,
        pos: 0,
        len: tree.bit_len,
    };
    // Cells of occupied nodes at the current level, in stream order.
    let mut nodes: Vec<[u64; 2]> = if leaves == 0 {
        Vec::new()
    } else {
        vec![[0, 0]]
    };
    for _ in 0..tree.levels {
        let mut next = Vec::with_capacity(nodes.len().min(leaves as usize) * 2);
        for &c in &nodes {
            for child in 0..n {
                if reader.next()? {
                    next.push([c[0] * side + child % side, c[1] * side + child / side]);
                    if next.len() as u64 > leaves {
                        return Err(BitTreeError::CountMismatch(next.len() as u64, leaves));
                    }
                }
            }
        }
        nodes = next;
    }
    if nodes.len() as u64 != leaves {
        return Err(BitTreeError::CountMismatch(nodes.len() as u64, leaves));
    }
    let cell = tree.cell_size();
    let mut out = Vec::with_capacity(tree.count as usize);
    let mut shared = tree.shared.iter().peekable();
    for (leaf, c) in nodes.iter().enumerate() {
        let p = [
            tree.area.origin[0] + (c[0] as f32 + 0.5) * cell[0],
            tree.area.origin[1] + (c[1] as f32 + 0.5) * cell[1],
        ];
        out.push(p);
        while shared.next_if(|&&l| l as usize == leaf).is_some() {
            out.push(p);
        }
    }
    Ok(out)
}

#[derive(Default)]
struct BitWriter {
    bytes: Vec<u8>,
    len: u64,
}

impl BitWriter {
    fn push(&mut self, bit: bool) {
        if self.len.is_multiple_of(8) {
            self.bytes.push(0);
        }
        if bit {
            *self.bytes.last_mut().expect("pushed above") |= 1 << (self.len % 8);
        }
        self.len += 1;
    }
}

struct BitReader<'a> {
    bytes: &'a [u8],
    pos: u64,
    len: u64,
}

impl BitReader<'_> {
    fn next(&mut self) -> Result<bool, BitTreeError> {
        if self.pos >= self.len || (self.pos / 8) as usize >= self.bytes.len() {
            return Err(BitTreeError::Truncated(self.pos));
        }
        let b = (self.bytes[(self.pos / 8) as usize] >> (self.pos % 8)) & 1;
        self.pos += 1;
        Ok(b == 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn area() -> Rect {
        Rect {
            origin: [10.0, -5.0],
            extent: [100.0, 50.0],
        }
    }

    fn random_points(n: usize, seed: u64) -> Vec<[f32; 2]> {
        let mut rng = Rng::new(seed);
        let a = area();
        (0..n)
            .map(|_| {
                [
                    a.origin[0] + rng.f32() * a.extent[0],
                    a.origin[1] + rng.f32() * a.extent[1],
                ]
            })
            .collect()
    }

    #[test]
    fn round_trip_within_the_cell_for_every_branching() {
        for children in [4, 16, 64] {
            let pts = random_points(2000, children as u64);
            let (tree, order) = encode_bittree(
                &pts,
                area(),
                &BitTreeOptions {
                    children,
                    max_levels: 24,
                },
            )
            .unwrap();
            let dec = decode_bittree(&tree).unwrap();
            assert_eq!(dec.len(), pts.len());
            let cell = tree.cell_size();
            for (k, d) in dec.iter().enumerate() {
                let p = pts[order[k] as usize];
                assert!(
                    (d[0] - p[0]).abs() <= 0.5 * cell[0] * 1.0001 + 1e-4,
                    "{children}: {d:?} vs {p:?}, cell {cell:?}"
                );
                assert!((d[1] - p[1]).abs() <= 0.5 * cell[1] * 1.0001 + 1e-4);
            }
            // Order is a permutation.
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert!(sorted.iter().enumerate().all(|(i, &v)| i as u32 == v));
            // The chosen level is the smallest without clashes: one level less must clash.
            if tree.levels > 1 {
                let cells = (tree.side() as u64).pow(tree.levels - 1);
                let mut keys: Vec<_> = pts.iter().map(|p| cell_of(*p, &area(), cells)).collect();
                keys.sort_unstable();
                assert!(keys.windows(2).any(|w| w[0] == w[1]));
            }
        }
    }

    #[test]
    fn bit_count_matches_brute_force_occupancy() {
        // Oracle: the number of bits is n × (number of occupied nodes on levels 0..L-1), counted directly.
        let pts = random_points(500, 9);
        let (tree, _) = encode_bittree(&pts, area(), &BitTreeOptions::default()).unwrap();
        let side = tree.side() as u64;
        let mut expected = 0u64;
        for level in 0..tree.levels {
            let cells = side.pow(level);
            let mut occ: Vec<_> = pts
                .iter()
                .map(|p| {
                    cell_of(*p, &area(), side.pow(tree.levels))
                        .map(|c| c / side.pow(tree.levels - level))
                })
                .collect();
            occ.sort_unstable();
            occ.dedup();
            assert!(occ.len() as u64 <= cells * cells);
            expected += occ.len() as u64 * side * side;
        }
        assert_eq!(tree.bit_len, expected);
    }

    #[test]
    fn full_grid_overhead_is_a_third_for_four_children() {
        // 64×64 instances, one per cell: 4096 leaf bits plus 1024 + 256 + ... + 4 inner bits.
        let a = Rect {
            origin: [0.0, 0.0],
            extent: [64.0, 64.0],
        };
        let pts: Vec<[f32; 2]> = (0..64 * 64)
            .map(|k| [(k % 64) as f32 + 0.5, (k / 64) as f32 + 0.5])
            .collect();
        let (tree, _) = encode_bittree(
            &pts,
            a,
            &BitTreeOptions {
                children: 4,
                max_levels: 24,
            },
        )
        .unwrap();
        assert_eq!(tree.levels, 6);
        let overhead = tree.bit_len as f64 / 4096.0 - 1.0;
        assert!((overhead - 1.0 / 3.0).abs() < 0.01, "{overhead}");
        let dec = decode_bittree(&tree).unwrap();
        assert_eq!(dec.len(), 4096);
    }

    /// Checks a tree against its points: every instance decodes within half a cell, `order` is a
    /// permutation, and the bit and shared-leaf counts equal a brute-force count of the occupied
    /// cells of every level.
    fn check_against_brute_force(pts: &[[f32; 2]], tree: &BitTree, order: &[u32], a: &Rect) {
        let dec = decode_bittree(tree).unwrap();
        assert_eq!(dec.len(), pts.len());
        let cell = tree.cell_size();
        for (k, d) in dec.iter().enumerate() {
            let p = pts[order[k] as usize];
            for c in 0..2 {
                assert!(
                    (d[c] - p[c]).abs() <= 0.5 * cell[c] * 1.0001 + 1e-4,
                    "{d:?} vs {p:?}, cell {cell:?}"
                );
            }
        }
        let mut sorted = order.to_vec();
        sorted.sort_unstable();
        assert!(sorted.iter().enumerate().all(|(i, &v)| i as u32 == v));
        let side = tree.side() as u64;
        let finest: Vec<[u64; 2]> = pts
            .iter()
            .map(|p| cell_of(*p, a, side.pow(tree.levels)))
            .collect();
        let mut bits = 0u64;
        for level in 0..tree.levels {
            let mut occ: Vec<_> = finest
                .iter()
                .map(|c| c.map(|x| x / side.pow(tree.levels - level)))
                .collect();
            occ.sort_unstable();
            occ.dedup();
            bits += occ.len() as u64 * side * side;
        }
        assert_eq!(tree.bit_len, bits);
        let mut leaves = finest.clone();
        leaves.sort_unstable();
        leaves.dedup();
        assert_eq!(tree.shared.len(), pts.len() - leaves.len());
    }

    /// Brute force: every pair of points in one of `cells`² cells is within MIN_CELL in x and y.
    fn only_close_points_share(pts: &[[f32; 2]], cells: u64) -> bool {
        let mut by_cell: std::collections::BTreeMap<[u64; 2], Vec<[f32; 2]>> = Default::default();
        for p in pts {
            by_cell
                .entry(cell_of(*p, &area(), cells))
                .or_default()
                .push(*p);
        }
        by_cell.values().all(|v| {
            v.iter().all(|p| {
                v.iter().all(|q| {
                    ((p[0] - q[0]).abs() as f64) <= MIN_CELL
                        && ((p[1] - q[1]).abs() as f64) <= MIN_CELL
                })
            })
        })
    }

    #[test]
    fn coincident_and_near_coincident_instances_share_leaves() {
        let mut pts = random_points(2000, 21);
        let mut rng = Rng::new(4);
        // 30 exact copies, 5 triples and 10 instances 0.1 mm beside others.
        for k in 0..30 {
            pts.push(pts[k * 37]);
        }
        for k in 0..5 {
            pts.push(pts[k * 101 + 7]);
            pts.push(pts[k * 101 + 7]);
        }
        for k in 0..10 {
            let p = pts[k * 53 + 3];
            pts.push([p[0] + 1e-4 * rng.f32(), p[1] - 1e-4 * rng.f32()]);
        }
        for children in [4, 16, 64] {
            let opts = BitTreeOptions {
                children,
                max_levels: 24,
            };
            let (tree, order) = encode_bittree(&pts, area(), &opts).unwrap();
            // The fewest levels at which every shared cell's instances lie within MIN_CELL.
            let side = tree.side() as u64;
            assert!(only_close_points_share(&pts, side.pow(tree.levels)));
            assert!(!only_close_points_share(&pts, side.pow(tree.levels - 1)));
            assert!(tree.shared.len() >= 30 + 10, "{}", tree.shared.len());
            check_against_brute_force(&pts, &tree, &order, &area());
        }
        // A tree of one spot: every instance shares the single leaf.
        let same = vec![[30.0, 4.0]; 5];
        let (tree, order) = encode_bittree(&same, area(), &BitTreeOptions::default()).unwrap();
        assert_eq!(tree.shared, vec![0; 4]);
        check_against_brute_force(&same, &tree, &order, &area());
    }

    #[test]
    fn a_200000_instance_scatter_of_the_generated_scene_encodes() {
        // The generated scene's placement (fixtures::large): uniform u, v written with 6 decimals
        // over a 4096 m terrain; instances that land on one spot share a leaf.
        let a = Rect {
            origin: [0.0, 0.0],
            extent: [4096.0, 4096.0],
        };
        let mut rng = Rng::new(0x5ca1e);
        let mut pts: Vec<[f32; 2]> = (0..200_000)
            .map(|_| {
                let q = |x: f32| (x as f64 * 1e6).round() as f32 * 1e-6 * 4096.0;
                [q(rng.f32()), q(rng.f32())]
            })
            .collect();
        // And a handful of duplicates, as an artist's second placement pass makes them.
        for k in 0..20 {
            pts.push(pts[k * 9973]);
        }
        let (tree, order) = encode_bittree(&pts, a, &BitTreeOptions::default()).unwrap();
        assert!(tree.shared.len() >= 20);
        check_against_brute_force(&pts, &tree, &order, &a);
        // The duplicates cost their 4 bytes each and not one bit: the tree without them has the
        // same levels and the same bits.
        let (alone, _) = encode_bittree(&pts[..200_000], a, &BitTreeOptions::default()).unwrap();
        assert_eq!((alone.levels, &alone.bits), (tree.levels, &tree.bits));
        assert_eq!(alone.shared.len() + 20, tree.shared.len());
    }

    #[test]
    fn corrupt_streams_are_errors() {
        let (mut tree, _) =
            encode_bittree(&random_points(50, 3), area(), &BitTreeOptions::default()).unwrap();
        tree.bit_len -= 5;
        assert!(decode_bittree(&tree).is_err());
        let (mut tree, _) =
            encode_bittree(&random_points(50, 3), area(), &BitTreeOptions::default()).unwrap();
        tree.count = 49;
        assert!(decode_bittree(&tree).is_err());
        // Shared-leaf lists out of order, past the leaves or longer than the instances.
        let mut pts = random_points(50, 3);
        pts.push(pts[10]);
        pts.push(pts[40]);
        let (tree, _) = encode_bittree(&pts, area(), &BitTreeOptions::default()).unwrap();
        assert_eq!(tree.shared.len(), 2);
        assert!(decode_bittree(&tree).is_ok());
        for shared in [vec![30, 10], vec![10, 50], vec![1; 60]] {
            let bad = BitTree {
                shared,
                ..tree.clone()
            };
            assert!(decode_bittree(&bad).is_err(), "{:?}", bad.shared);
        }
        assert!(matches!(
            encode_bittree(
                &pts,
                area(),
                &BitTreeOptions {
                    children: 8,
                    max_levels: 4
                }
            ),
            Err(BitTreeError::Children(8))
        ));
    }

    #[test]
    fn empty_input() {
        let (tree, order) = encode_bittree(&[], area(), &BitTreeOptions::default()).unwrap();
        assert!(order.is_empty());
        assert_eq!(decode_bittree(&tree).unwrap(), Vec::<[f32; 2]>::new());
    }
}
