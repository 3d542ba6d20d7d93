//! Bit layout of one line space: which bit says whether the shaft between two boundary patches
//! of a node holds geometry.
//!
//! Faces: f = 2·axis + side (0: −X, 1: +X, 2: −Y, 3: +Y, 4: −Z, 5: +Z); side 0 is the plane
//! coordinate 0, side 1 the plane coordinate n (node-local units, one unit per child). A face of
//! axis k is split into n×n patches; patch (u, v) spans [u, u+1] on axis (k+1) mod 3 and [v, v+1]
//! on axis (k+2) mod 3, and has index p = u + n·v.
//!
//! The thesis stores the full (6n²)² matrix (360,000 bits at n = 10). Entries of two patches on
//! the same face are always empty (no shaft), and entry(s, e) = entry(e, s), so this layout keeps
//! only the 15 face pairs fa < fb: bit = pair(fa, fb)·n⁴ + pa·n² + pb, pair() numbering the pairs
//! (0,1), (0,2) … (4,5) as 0…14. That is 15n⁴ bits (150,000 at n = 10: 4,688 u32 words, 18,752
//! bytes, against the thesis' 11,250 words). Bit b lives in word b / 32 at bit b mod 32, read as
//! `(w >> (b & 31)) & 1` (the thesis' listing shifts left, which reads the wrong bit).

/// Number of faces of a node.
pub const FACES: usize = 6;

/// The axis of face `f`.
pub const fn face_axis(f: usize) -> usize {
    f / 2
}

/// 0 for the minimum face of an axis, 1 for the maximum.
pub const fn face_side(f: usize) -> usize {
    f % 2
}

/// Index of the unordered face pair (a < b) among the 15.
pub const fn pair_index(a: usize, b: usize) -> usize {
    // Pairs before row a: 5 + 4 + … (a terms) = a·(11 − a)/2.
    a * (11 - a) / 2 + (b - a - 1)
}

/// The bit layout for resolution n.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    pub n: u32,
}

impl Layout {
    pub const fn new(n: u32) -> Self {
        Self { n }
    }

    /// Patches per face.
    pub const fn patches(&self) -> u64 {
        (self.n * self.n) as u64
    }

    /// Bits of one line space: 15·n⁴.
    pub const fn bits(&self) -> u64 {
        15 * self.patches() * self.patches()
    }

    /// u32 words of one line space.
    pub const fn words(&self) -> usize {
        self.bits().div_ceil(32) as usize
    }

    /// Bit of the shaft between patch `pa` of face `fa` and patch `pb` of face `fb`, in either
    /// order; None for two patches of the same face (no shaft).
    pub const fn bit(&self, fa: usize, pa: u32, fb: usize, pb: u32) -> Option<u64> {
        if fa == fb {
            return None;
        }
        let (f1, p1, f2, p2) = if fa < fb {
            (fa, pa, fb, pb)
        } else {
            (fb, pb, fa, pa)
        };
        let pp = self.patches();
        Some(pair_index(f1, f2) as u64 * pp * pp + p1 as u64 * pp + p2 as u64)
    }

    /// Index in the thesis' full (6n²)² matrix (row: start patch, column: end patch).
    pub const fn full_index(&self, fa: usize, pa: u32, fb: usize, pb: u32) -> u64 {
        let pp = self.patches();
        (fa as u64 * pp + pa as u64) * 6 * pp + fb as u64 * pp + pb as u64
    }

    /// Expands a line space to the thesis' full matrix (for comparison and documentation).
    pub fn expand_full(&self, words: &[u32]) -> Vec<u32> {
        let pp = self.patches() as u32;
        let total = (6 * pp as u64).pow(2);
        let mut out = vec![0u32; total.div_ceil(32) as usize];
        for fa in 0..FACES {
            for pa in 0..pp {
                for fb in 0..FACES {
                    for pb in 0..pp {
                        if self.bit(fa, pa, fb, pb).is_some_and(|b| get(words, b)) {
                            set(&mut out, self.full_index(fa, pa, fb, pb));
                        }
                    }
                }
            }
        }
        out
    }
}

/// Reads bit `b`.
#[inline]
pub fn get(words: &[u32], b: u64) -> bool {
    (words[(b >> 5) as usize] >> (b & 31)) & 1 == 1
}

/// Sets bit `b`.
#[inline]
pub fn set(words: &mut [u32], b: u64) {
    words[(b >> 5) as usize] |= 1 << (b & 31);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_indices_enumerate_the_15_pairs_in_order() {
        let mut k = 0;
        for a in 0..6 {
            for b in a + 1..6 {
                assert_eq!(pair_index(a, b), k);
                k += 1;
            }
        }
        assert_eq!(k, 15);
    }

    #[test]
    fn bits_are_a_bijection_onto_15_n4() {
        let l = Layout::new(3);
        let mut seen = vec![false; l.bits() as usize];
        for fa in 0..6 {
            for fb in fa + 1..6 {
                for pa in 0..9 {
                    for pb in 0..9 {
                        let b = l.bit(fa, pa, fb, pb).unwrap();
                        assert_eq!(Some(b), l.bit(fb, pb, fa, pa));
                        assert!(!seen[b as usize]);
                        seen[b as usize] = true;
                    }
                }
            }
        }
        assert!(seen.iter().all(|s| *s));
        assert_eq!(Layout::new(10).words(), 4688);
        assert_eq!(l.bit(2, 1, 2, 5), None);
    }

    #[test]
    fn bit_read_shifts_right_not_left() {
        // Regression for the thesis' listing: bit 3 of 0b1000 is set, bit 0 is not.
        let w = [0b1000u32];
        assert!(get(&w, 3));
        assert!(!get(&w, 0));
    }
}
