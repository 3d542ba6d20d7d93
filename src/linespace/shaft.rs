//! The shaft between two boundary patches of a node, and the exact test whether it meets a child
//! cell.
//!
//! For axis-aligned rectangles A and B, every point of the shaft conv(A ∪ B) is (1−λ)a + λb, and
//! for fixed λ these points form the axis-aligned box (1−λ)A + λB whose bounds are linear in λ.
//! So the shaft's interior meets the open cell (c, c+1)³ exactly when some λ in [0, 1] satisfies
//! six strict linear inequalities: an interval intersection, evaluated in integers (patches and
//! cells lie on the integer lattice of node-local units), hence exact and deterministic.
//!
//! The test is on interiors: a shaft that only touches a cell's face does not meet it. That is
//! still conservative: a segment from patch A to patch B that hits geometry at x has x in the
//! closed cells around x, which the (closed) triangle/box test marks filled, and since the shaft
//! has an interior, one of those cells meets it in the interior.
//! [`shaft_meets_cell_sat`] is the brute-force oracle: separating axes over all edge-direction
//! cross products, in integers.

use super::layout::{FACES, Layout, face_axis, face_side, set};
use rayon::prelude::*;

/// A patch as a degenerate box: integer bounds per axis in node-local units.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PatchBox {
    pub lo: [i64; 3],
    pub hi: [i64; 3],
}

/// The box of patch `p` of face `f` at resolution n.
pub fn patch_box(n: u32, f: usize, p: u32) -> PatchBox {
    let k = face_axis(f);
    let (a, b) = ((k + 1) % 3, (k + 2) % 3);
    let (u, v) = ((p % n) as i64, (p / n) as i64);
    let plane = face_side(f) as i64 * n as i64;
    let mut lo = [0; 3];
    let mut hi = [0; 3];
    lo[k] = plane;
    hi[k] = plane;
    lo[a] = u;
    hi[a] = u + 1;
    lo[b] = v;
    hi[b] = v + 1;
    PatchBox { lo, hi }
}

/// Whether the interior of the shaft conv(A ∪ B) meets the open cell (c, c+1)³.
#[allow(clippy::needless_range_loop)]
pub fn shaft_meets_cell(a: &PatchBox, b: &PatchBox, c: [i64; 3]) -> bool {
    // Feasible λ: max(lower bounds) < min(upper bounds), bounds as fractions num/den, den > 0.
    let (mut lo_n, mut lo_d) = (0i64, 1i64);
    let (mut hi_n, mut hi_d) = (1i64, 1i64);
    for k in 0..3 {
        // lo_k(λ) < c+1:  (c+1 − a.lo) − λ(b.lo − a.lo) > 0;  hi_k(λ) > c:  (a.hi − c) + λ(b.hi − a.hi) > 0.
        let cons = [
            (c[k] + 1 - a.lo[k], a.lo[k] - b.lo[k]),
            (a.hi[k] - c[k], b.hi[k] - a.hi[k]),
        ];
        for (p, q) in cons {
            if q == 0 {
                if p <= 0 {
                    return false;
                }
            } else if q > 0 {
                // λ > −p/q
                if -p * lo_d > lo_n * q {
                    (lo_n, lo_d) = (-p, q);
                }
            } else if p * hi_d < hi_n * -q {
                // λ < p/(−q)
                (hi_n, hi_d) = (p, -q);
            }
        }
    }
    lo_n * hi_d < hi_n * lo_d
}

/// Brute-force oracle: the interiors of conv(A ∪ B) and the cell are disjoint exactly when some
/// axis weakly separates them; candidate axes are the cross products of all pairs of edge
/// directions (coordinate axes and the 16 corner-to-corner directions), a superset of the face
/// normals and edge-edge axes that the separating-axis theorem needs.
pub fn shaft_meets_cell_sat(a: &PatchBox, b: &PatchBox, c: [i64; 3]) -> bool {
    let corners = |p: &PatchBox| -> Vec<[i64; 3]> {
        (0..8)
            .map(|i| [0, 1, 2].map(|k| if i >> k & 1 == 1 { p.hi[k] } else { p.lo[k] }))
            .collect()
    };
    let mut hull = corners(a);
    hull.extend(corners(b));
    let cell: Vec<[i64; 3]> = (0..8)
        .map(|i| [0, 1, 2].map(|k| c[k] + (i >> k & 1) as i64))
        .collect();
    let mut dirs: Vec<[i64; 3]> = vec![[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    for p in &hull[..8] {
        for q in &hull[8..] {
            dirs.push([q[0] - p[0], q[1] - p[1], q[2] - p[2]]);
        }
    }
    let dot = |u: [i64; 3], v: [i64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    for (i, u) in dirs.iter().enumerate() {
        for v in &dirs[i + 1..] {
            let axis = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            if axis == [0; 3] {
                continue;
            }
            let (s0, s1) = hull.iter().fold((i64::MAX, i64::MIN), |(lo, hi), p| {
                let d = dot(axis, *p);
                (lo.min(d), hi.max(d))
            });
            let (c0, c1) = cell.iter().fold((i64::MAX, i64::MIN), |(lo, hi), p| {
                let d = dot(axis, *p);
                (lo.min(d), hi.max(d))
            });
            if s1 <= c0 || c1 <= s0 {
                return false;
            }
        }
    }
    true
}

/// For every child position, the line-space mask of the shafts that meet it: `n³ · words`
/// u32, child (x, y, z) at index x + n·y + n²·z. A node's line space is the OR of the masks of
/// its filled children, so the table is built once per n.
#[derive(Debug, Clone, PartialEq)]
pub struct ChildMasks {
    pub layout: Layout,
    pub masks: Vec<u32>,
}

impl ChildMasks {
    /// The mask of child `c` (linear index).
    pub fn mask(&self, c: usize) -> &[u32] {
        let w = self.layout.words();
        &self.masks[c * w..(c + 1) * w]
    }

    /// Builds the table: each shaft walks only the cells of its bounding box.
    pub fn build(n: u32) -> ChildMasks {
        let layout = Layout::new(n);
        let pp = layout.patches() as u32;
        let shafts: Vec<(usize, u32, usize, u32)> = (0..FACES)
            .flat_map(|fa| (fa + 1..FACES).map(move |fb| (fa, fb)))
            .flat_map(|(fa, fb)| {
                (0..pp).flat_map(move |pa| (0..pp).map(move |pb| (fa, pa, fb, pb)))
            })
            .collect();
        let hits: Vec<Vec<u32>> = shafts
            .par_iter()
            .map(|&(fa, pa, fb, pb)| {
                cells_of_shaft(n, &patch_box(n, fa, pa), &patch_box(n, fb, pb))
            })
            .collect();
        let w = layout.words();
        let mut masks = vec![0u32; (n * n * n) as usize * w];
        for (&(fa, pa, fb, pb), cells) in shafts.iter().zip(&hits) {
            let bit = layout.bit(fa, pa, fb, pb).unwrap_or(0);
            for &c in cells {
                set(&mut masks[c as usize * w..(c as usize + 1) * w], bit);
            }
        }
        ChildMasks { layout, masks }
    }
}

/// The child masks transposed: for every shaft (line-space bit), the child cells it meets, as
/// `words` u64 of n³ bits per shaft (cell x + n·y + n²·z at bit c % 64 of word c / 64, like
/// [`super::ntree::NTree::occupancy`]). A node's line-space bit b is then
/// `occupancy(node) & cells(b) ≠ 0`, bit for bit the OR of its filled children's masks: one table
/// per n (19.2 MB at n = 10) answers every node's line space, instead of 18,752 B per node.
/// This is the form the `linespace` section stores (array `shaft_cells`) and the GPU reads.
#[derive(Clone, PartialEq)]
pub struct ShaftCells {
    pub layout: Layout,
    /// u64 words per shaft: n³ / 64 rounded up.
    pub words: usize,
    pub cells: Vec<u64>,
}

impl std::fmt::Debug for ShaftCells {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ShaftCells {{ n: {}, words: {} }}",
            self.layout.n, self.words
        )
    }
}

impl ShaftCells {
    /// Transposes the child masks (one pass over their set bits).
    pub fn from_masks(m: &ChildMasks) -> ShaftCells {
        let layout = m.layout;
        let n3 = (layout.n * layout.n * layout.n) as usize;
        let words = n3.div_ceil(64);
        let mut cells = vec![0u64; layout.bits() as usize * words];
        for c in 0..n3 {
            for (i, &w) in m.mask(c).iter().enumerate() {
                let mut w = w;
                while w != 0 {
                    let b = i * 32 + w.trailing_zeros() as usize;
                    w &= w - 1;
                    cells[b * words + c / 64] |= 1 << (c % 64);
                }
            }
        }
        ShaftCells {
            layout,
            words,
            cells,
        }
    }

    /// Builds the table directly: each shaft walks only the cells of its bounding box (the same
    /// cells as [`ChildMasks::build`], transposed; test `shaft_table_equals_the_transposed_child_masks`).
    pub fn build(n: u32) -> ShaftCells {
        let layout = Layout::new(n);
        let pp = layout.patches() as u32;
        let n3 = (n * n * n) as usize;
        let words = n3.div_ceil(64);
        let mut cells = vec![0u64; layout.bits() as usize * words];
        // Bit b = pair·n⁴ + pa·n² + pb (fa < fb), so chunk b of `cells` is shaft b.
        let pairs: Vec<(usize, usize)> = (0..FACES)
            .flat_map(|fa| (fa + 1..FACES).map(move |fb| (fa, fb)))
            .collect();
        cells
            .par_chunks_mut(words)
            .enumerate()
            .for_each(|(b, out)| {
                let b = b as u64;
                let pp2 = pp as u64 * pp as u64;
                let (fa, fb) = pairs[(b / pp2) as usize];
                let (pa, pb) = ((b % pp2 / pp as u64) as u32, (b % pp as u64) as u32);
                for c in cells_of_shaft(n, &patch_box(n, fa, pa), &patch_box(n, fb, pb)) {
                    out[c as usize / 64] |= 1 << (c % 64);
                }
            });
        ShaftCells {
            layout,
            words,
            cells,
        }
    }

    /// Bytes of the table.
    pub fn bytes(&self) -> usize {
        8 * self.cells.len()
    }

    /// Whether shaft `bit` meets a cell set in `occupancy` (`words` u64).
    #[inline]
    pub fn meets(&self, bit: u64, occupancy: &[u64]) -> bool {
        let at = bit as usize * self.words;
        self.cells[at..at + self.words]
            .iter()
            .zip(occupancy)
            .fold(0, |acc, (a, b)| acc | (a & b))
            != 0
    }
}

/// Where the [`ShaftTable`] keeps each of the 15 face pairs (in `pair_index` order): its row
/// block among the 9 stored pairs, and whether it is the point reflection of the stored pair
/// (then read with patches p → n² − 1 − p against the reversed occupancy).
pub const PAIR_ROWS: [(u32, bool); 15] = pair_rows();

/// The 9 stored face pairs: the 3 opposite pairs and the 6 adjacent pairs whose first face is a
/// minimum face (even f), in ascending order.
const fn stored_pair(fa: usize, fb: usize) -> bool {
    fa / 2 == fb / 2 || fa & 1 == 0
}

const fn pair_rows() -> [(u32, bool); 15] {
    let mut out = [(0u32, false); 15];
    let mut stored = [[0u32; 6]; 6];
    let (mut k, mut fa) = (0u32, 0);
    while fa < FACES {
        let mut fb = fa + 1;
        while fb < FACES {
            if stored_pair(fa, fb) {
                stored[fa][fb] = k;
                k += 1;
            }
            fb += 1;
        }
        fa += 1;
    }
    fa = 0;
    while fa < FACES {
        let mut fb = fa + 1;
        while fb < FACES {
            let p = super::layout::pair_index(fa, fb);
            out[p] = if stored_pair(fa, fb) {
                (stored[fa][fb], false)
            } else {
                // The point reflection x → n − x swaps the sides of both faces.
                (stored[fa ^ 1][fb ^ 1], true)
            };
            fb += 1;
        }
        fa += 1;
    }
    out
}

/// The shaft table as stored (`shaft_cells` of the `linespace` section) and read by the GPU:
/// [`ShaftCells`] for 9 of the 15 face pairs (`words` u64 per shaft, row r = block·n⁴ + pa·n² +
/// pb). The other 6 pairs are the point reflections x → n − x of stored ones: reflection maps
/// face f to f ^ 1, patch p to n² − 1 − p and child slot s to n³ − 1 − s, so shaft b of a
/// reflected pair meets `occupancy` exactly where its stored partner meets the reversed
/// occupancy (bit s of it = bit n³ − 1 − s of `occupancy`). 11.5 MB at n = 10 instead of 19.2.
#[derive(Clone, PartialEq)]
pub struct ShaftTable {
    pub layout: Layout,
    /// u64 words per shaft: n³ / 64 rounded up.
    pub words: usize,
    pub cells: Vec<u64>,
}

impl std::fmt::Debug for ShaftTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ShaftTable {{ n: {}, words: {} }}",
            self.layout.n, self.words
        )
    }
}

impl ShaftTable {
    /// Shafts stored: 9n⁴.
    pub const fn rows(layout: Layout) -> u64 {
        9 * layout.patches() * layout.patches()
    }

    /// Keeps the stored pairs of a full table.
    pub fn from_cells(full: &ShaftCells) -> ShaftTable {
        let (layout, w) = (full.layout, full.words);
        let p4 = layout.patches() * layout.patches();
        let mut cells = vec![0u64; Self::rows(layout) as usize * w];
        for (pair, &(block, reflected)) in PAIR_ROWS.iter().enumerate() {
            if !reflected {
                let src = pair as u64 * p4 * w as u64;
                let dst = block as u64 * p4 * w as u64;
                let len = (p4 * w as u64) as usize;
                cells[dst as usize..dst as usize + len]
                    .copy_from_slice(&full.cells[src as usize..src as usize + len]);
            }
        }
        ShaftTable {
            layout,
            words: w,
            cells,
        }
    }

    /// Builds the table of n.
    pub fn build(n: u32) -> ShaftTable {
        Self::from_cells(&ShaftCells::build(n))
    }

    /// Bytes of the table.
    pub fn bytes(&self) -> usize {
        8 * self.cells.len()
    }

    /// The stored row of line-space bit `bit` and whether it reads the reversed occupancy.
    #[inline]
    pub fn row(&self, bit: u64) -> (usize, bool) {
        let pp = self.layout.patches();
        let p4 = pp * pp;
        let (block, reflected) = PAIR_ROWS[(bit / p4) as usize];
        let (pa, pb) = (bit % p4 / pp, bit % pp);
        let (pa, pb) = if reflected {
            (pp - 1 - pa, pp - 1 - pb)
        } else {
            (pa, pb)
        };
        ((block as u64 * p4 + pa * pp + pb) as usize, reflected)
    }

    /// Whether shaft `bit` meets a cell set in `occupancy` (`reversed`: the same bits from
    /// slot n³ − 1 down, [`reverse_slots`]).
    #[inline]
    pub fn meets(&self, bit: u64, occupancy: &[u64], reversed: &[u64]) -> bool {
        let (row, reflected) = self.row(bit);
        let at = row * self.words;
        let occ = if reflected { reversed } else { occupancy };
        self.cells[at..at + self.words]
            .iter()
            .zip(occ)
            .fold(0, |acc, (a, b)| acc | (a & b))
            != 0
    }
}

/// Bit s of the result is bit n3 − 1 − s of `words` (n3 bits in ⌈n3/64⌉ u64, x-fastest slots).
pub fn reverse_slots(words: &[u64], n3: usize) -> Vec<u64> {
    let mut out = vec![0u64; words.len()];
    for s in 0..n3 {
        if words[s / 64] >> (s % 64) & 1 == 1 {
            let r = n3 - 1 - s;
            out[r / 64] |= 1 << (r % 64);
        }
    }
    out
}

/// Linear indices of the cells whose interior the shaft's interior meets.
pub fn cells_of_shaft(n: u32, a: &PatchBox, b: &PatchBox) -> Vec<u32> {
    let n = n as i64;
    let lo = [0, 1, 2].map(|k| a.lo[k].min(b.lo[k]).clamp(0, n - 1));
    let hi = [0, 1, 2].map(|k| (a.hi[k].max(b.hi[k]) - 1).clamp(0, n - 1));
    let mut out = Vec::new();
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            for x in lo[0]..=hi[0] {
                if shaft_meets_cell(a, b, [x, y, z]) {
                    out.push((x + n * y + n * n * z) as u32);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interval_test_equals_the_separating_axis_oracle() {
        for n in [2u32, 3, 4] {
            let pp = n * n;
            for fa in 0..6 {
                for fb in 0..6 {
                    for pa in 0..pp {
                        for pb in (0..pp).step_by(if n == 4 { 3 } else { 1 }) {
                            let (a, b) = (patch_box(n, fa, pa), patch_box(n, fb, pb));
                            for c in 0..n * n * n {
                                let c = [c % n, c / n % n, c / (n * n)].map(|x| x as i64);
                                let fast = fa != fb && shaft_meets_cell(&a, &b, c);
                                assert_eq!(
                                    fast,
                                    shaft_meets_cell_sat(&a, &b, c),
                                    "n {n} {fa}:{pa} {fb}:{pb} {c:?}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn reflected_pairs_read_the_stored_partner_against_reversed_occupancy() {
        for n in [2u32, 3, 4, 5] {
            let full = ShaftCells::build(n);
            let table = ShaftTable::from_cells(&full);
            let n3 = (n * n * n) as usize;
            let mut rng = 0x9e37_79b9_7f4a_7c15u64;
            for _ in 0..40 {
                let mut occ = vec![0u64; full.words];
                for s in 0..n3 {
                    rng ^= rng << 13;
                    rng ^= rng >> 7;
                    rng ^= rng << 17;
                    if rng.is_multiple_of(11) {
                        occ[s / 64] |= 1 << (s % 64);
                    }
                }
                let rev = reverse_slots(&occ, n3);
                for b in 0..full.layout.bits() {
                    assert_eq!(
                        table.meets(b, &occ, &rev),
                        full.meets(b, &occ),
                        "n {n} bit {b}"
                    );
                }
            }
        }
        assert_eq!(PAIR_ROWS.iter().filter(|r| !r.1).count(), 9);
        assert_eq!(PAIR_ROWS[5], (2, true)); // (1, 2) is the reflection of (0, 3)
    }

    #[test]
    fn straight_shaft_meets_only_its_column() {
        // Patch (1,1) on −Z to patch (1,1) on +Z at n = 3: exactly the column x = y = 1.
        let (a, b) = (patch_box(3, 4, 4), patch_box(3, 5, 4));
        let cells = cells_of_shaft(3, &a, &b);
        assert_eq!(cells, vec![4, 13, 22]);
    }
}
