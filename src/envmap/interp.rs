//! Hardy's multiquadric interpolation (seed 000, 4.6.3.2) over the k nearest samples.
//!
//! For a point x with neighbours x_1..x_k: solve A·α = C with A_ij = sqrt(‖x_i − x_j‖² + R²)
//! (Gaussian elimination with partial pivoting: A is symmetric but neither definite nor
//! diagonally dominant), then C(x) = Σ_j α_j sqrt(‖x − x_j‖² + R²). Because A is symmetric this
//! equals Σ_j w_j C_j with A·w = φ(x): one right-hand side instead of one per coefficient, and
//! the weights w are what a runtime can store per instance.
//!
//! Improvement over the thesis (on by default, `constant_term`): the pure multiquadric does not
//! reproduce a constant field (one sample at distance d gives C·sqrt(d² + R²)/R). As in standard RBF
//! practice (and scipy's `RBFInterpolator`, degree 0) the system is augmented with a constant:
//! [A 1; 1ᵀ 0]·[w; μ] = [φ(x); 1], so the weights sum to one and constants are exact.

use crate::kdtree::{KdTree, dist2};

/// Smallest pivot relative to the largest matrix entry before a system counts as ill-conditioned.
pub const PIVOT_TOLERANCE: f64 = 1e-12;

/// The system for a point could not be solved reliably.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "ill-conditioned multiquadric system: relative pivot {pivot:e} at step {step} (R too large for the sample spacing, or coincident samples)"
)]
pub struct IllConditioned {
    pub pivot: f64,
    pub step: usize,
}

/// Solves A·x = b in place (A is n×n row-major) by Gaussian elimination with partial pivoting.
pub fn solve_in_place(a: &mut [f64], b: &mut [f64], n: usize) -> Result<(), IllConditioned> {
    let mut piv = vec![0usize; n];
    factor_in_place(a, &mut piv, n)?;
    solve_factored(a, &piv, b, n);
    Ok(())
}

/// Gaussian elimination with partial pivoting of the n×n row-major `a`, kept as a factorization:
/// the multipliers below the diagonal (rows swapped with their multipliers), U on and above it,
/// the pivot row of each step in `piv`. [`solve_factored`] then applies to a right-hand side
/// exactly the operations the elimination would have applied to it, in the same order, so a
/// factorization reused for another right-hand side gives bit-identical results.
pub fn factor_in_place(a: &mut [f64], piv: &mut [usize], n: usize) -> Result<(), IllConditioned> {
    // Sizes of the default neighbour counts (k = 4, 8, 16 plus the constant term) get loops
    // of known length, which the compiler unrolls; the arithmetic is the same.
    match n {
        5 => factor_sized::<5>(a, piv, n),
        9 => factor_sized::<9>(a, piv, n),
        17 => factor_sized::<17>(a, piv, n),
        _ => factor_sized::<0>(a, piv, n),
    }
}

/// Solves with a factorization from [`factor_in_place`].
pub fn solve_factored(lu: &[f64], piv: &[usize], b: &mut [f64], n: usize) {
    match n {
        5 => solve_sized::<5>(lu, piv, b, n),
        9 => solve_sized::<9>(lu, piv, b, n),
        17 => solve_sized::<17>(lu, piv, b, n),
        _ => solve_sized::<0>(lu, piv, b, n),
    }
}

/// [`factor_in_place`] for size `M` (0: the size is `n`).
fn factor_sized<const M: usize>(
    a: &mut [f64],
    piv: &mut [usize],
    n: usize,
) -> Result<(), IllConditioned> {
    let n = if M == 0 { n } else { M };
    let (a, piv) = (&mut a[..n * n], &mut piv[..n]);
    let scale = a
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for col in 0..n {
        let (mut p, mut best) = (col, -1.0);
        for r in col..n {
            let v = a[r * n + col].abs();
            if v > best {
                (p, best) = (r, v);
            }
        }
        if best / scale < PIVOT_TOLERANCE {
            return Err(IllConditioned {
                pivot: best / scale,
                step: col,
            });
        }
        piv[col] = p;
        if p != col {
            for c in 0..n {
                a.swap(p * n + c, col * n + c);
            }
        }
        let d = a[col * n + col];
        // Row slices instead of indexing: no bounds checks in the innermost loop.
        let (top, bottom) = a.split_at_mut((col + 1) * n);
        let pivot_row = &top[col * n + col + 1..col * n + n];
        for row in bottom.chunks_exact_mut(n) {
            let f = row[col] / d;
            row[col] = f;
            if f != 0.0 {
                for (x, &pv) in row[col + 1..].iter_mut().zip(pivot_row) {
                    *x -= f * pv;
                }
            }
        }
    }
    Ok(())
}

/// [`solve_factored`] for size `M` (0: the size is `n`).
fn solve_sized<const M: usize>(lu: &[f64], piv: &[usize], b: &mut [f64], n: usize) {
    let n = if M == 0 { n } else { M };
    let (lu, piv, b) = (&lu[..n * n], &piv[..n], &mut b[..n]);
    // Every row swap first: a row's multipliers travelled with it, and each entry of b meets
    // the same subtractions in the same order as during the elimination.
    for (col, &p) in piv.iter().enumerate() {
        b.swap(p, col);
    }
    for col in 0..n {
        let bc = b[col];
        for r in col + 1..n {
            let f = lu[r * n + col];
            if f != 0.0 {
                b[r] -= f * bc;
            }
        }
    }
    for r in (0..n).rev() {
        let mut s = b[r];
        for c in r + 1..n {
            s -= lu[r * n + c] * b[c];
        }
        b[r] = s / lu[r * n + r];
    }
}

/// Fills the (augmented, m×m) multiquadric matrix of the points `xs`.
fn fill_matrix(xs: &[[f32; 3]], r2: f64, m: usize, a: &mut Vec<f64>) {
    let n = xs.len();
    a.clear();
    a.resize(m * m, 0.0);
    for i in 0..n {
        for j in i..n {
            let v = (dist2(xs[i], xs[j]) as f64 + r2).sqrt();
            a[i * m + j] = v;
            a[j * m + i] = v;
        }
        if m > n {
            a[i * m + n] = 1.0;
            a[n * m + i] = 1.0;
        }
    }
}

/// The right-hand side φ(x) (with the constant term's 1 when augmented).
fn fill_rhs(xs: &[[f32; 3]], x: [f32; 3], r2: f64, m: usize, b: &mut Vec<f64>) {
    b.clear();
    b.extend(xs.iter().map(|p| (dist2(*p, x) as f64 + r2).sqrt()));
    if m > xs.len() {
        b.push(1.0);
    }
}

/// Multiquadric weights of the neighbours `xs` for point `x`: C(x) = Σ w_j C_j.
/// With `constant_term` the system is augmented by a constant (see the module doc).
pub fn multiquadric_weights(
    xs: &[[f32; 3]],
    x: [f32; 3],
    r: f32,
    constant_term: bool,
    w: &mut Vec<f64>,
) -> Result<(), IllConditioned> {
    let n = xs.len();
    let m = if constant_term && n > 1 { n + 1 } else { n };
    let r2 = (r as f64) * (r as f64);
    if n == 1 && constant_term {
        // One neighbour and a constant: the interpolant is that neighbour's value.
        w.clear();
        w.push(1.0);
        return Ok(());
    }
    let mut a = Vec::new();
    fill_matrix(xs, r2, m, &mut a);
    fill_rhs(xs, x, r2, m, w);
    solve_in_place(&mut a, w, m)?;
    w.truncate(n);
    Ok(())
}

/// Multiquadric weights for neighbour sets named by ids, with the factorizations of the last
/// few sets kept: neighbouring points (queried in spatial order) often share their k nearest
/// samples, and then only the right-hand side changes. The system is always set up in
/// ascending id order, so the weights of a point do not depend on its query order, on what
/// was cached, or on the thread that computed them.
#[derive(Debug, Default)]
pub struct MultiquadricSolver {
    cache: Vec<Factored>,
    /// The slot the next new factorization replaces once the cache is full (round robin).
    next: usize,
    /// id << 32 | caller's slot, in id order (one integer compare per sorting step); the
    /// right-hand side.
    order: Vec<u64>,
    b: Vec<f64>,
    /// Solves that reused a cached factorization, and those that factored.
    pub reused: u64,
    pub factored_count: u64,
}

/// Factorizations a [`MultiquadricSolver`] keeps (a Morton-order walk returns to a recent
/// neighbour set after a few steps more often than right away).
const CACHED_SYSTEMS: usize = 16;

/// One cached system: its sorted ids (and their hash), radius, constant term, positions in id
/// order and factorization (or why it has none).
#[derive(Debug, Default)]
struct Factored {
    hash: u64,
    key: Vec<u32>,
    radius: f32,
    constant_term: bool,
    xs: Vec<[f32; 3]>,
    lu: Vec<f64>,
    piv: Vec<usize>,
    result: Option<Result<(), IllConditioned>>,
}

impl Factored {
    fn matches(&self, hash: u64, order: &[u64], r: f32, constant_term: bool) -> bool {
        self.hash == hash
            && self.radius.to_bits() == r.to_bits()
            && self.constant_term == constant_term
            && self.key.len() == order.len()
            && self
                .key
                .iter()
                .zip(order)
                .all(|(&k, &o)| k == (o >> 32) as u32)
    }
}

impl MultiquadricSolver {
    /// Weights (in the order of `ids`) of the samples `ids` at positions `pos(id)` for point x.
    pub fn weights(
        &mut self,
        ids: &[u32],
        pos: impl Fn(u32) -> [f32; 3],
        x: [f32; 3],
        r: f32,
        constant_term: bool,
        w: &mut Vec<f64>,
    ) -> Result<(), IllConditioned> {
        let n = ids.len();
        w.clear();
        if n == 1 && constant_term {
            w.push(1.0);
            return Ok(());
        }
        self.order.clear();
        self.order.extend(
            ids.iter()
                .enumerate()
                .map(|(s, &id)| (id as u64) << 32 | s as u64),
        );
        self.order.sort_unstable();
        // FNV-1a over the sorted ids: a cheap first test before comparing whole keys.
        let hash = self.order.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &o| {
            (h ^ (o >> 32)).wrapping_mul(0x100_0000_01b3)
        });
        let m = if constant_term && n > 1 { n + 1 } else { n };
        let r2 = (r as f64) * (r as f64);
        let found = self
            .cache
            .iter()
            .position(|f| f.matches(hash, &self.order, r, constant_term));
        let slot = match found {
            Some(s) => {
                self.reused += 1;
                s
            }
            None => {
                self.factored_count += 1;
                let s = if self.cache.len() < CACHED_SYSTEMS {
                    self.cache.push(Factored::default());
                    self.cache.len() - 1
                } else {
                    self.next = (self.next + 1) % CACHED_SYSTEMS;
                    self.next
                };
                let f = &mut self.cache[s];
                f.hash = hash;
                f.key.clear();
                f.key.extend(self.order.iter().map(|&o| (o >> 32) as u32));
                f.xs.clear();
                f.xs.extend(f.key.iter().map(|&id| pos(id)));
                (f.radius, f.constant_term) = (r, constant_term);
                fill_matrix(&f.xs, r2, m, &mut f.lu);
                f.piv.resize(m, 0);
                f.result = Some(factor_in_place(&mut f.lu, &mut f.piv, m));
                s
            }
        };
        let f = &self.cache[slot];
        f.result.unwrap_or(Ok(()))?;
        fill_rhs(&f.xs, x, r2, m, &mut self.b);
        solve_factored(&f.lu, &f.piv, &mut self.b, m);
        w.resize(n, 0.0);
        for (&o, &v) in self.order.iter().zip(&self.b) {
            w[o as u32 as usize] = v;
        }
        Ok(())
    }
}

/// Interpolates `dim`-vectors stored at sample points.
pub struct Interpolator<'a> {
    pub tree: KdTree,
    pub values: &'a [f32],
    pub dim: usize,
    pub radius: f32,
    pub k: usize,
    /// Augment the system with a constant term (see the module doc).
    pub constant_term: bool,
}

/// How a reconstruction was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reconstruction {
    Multiquadric,
    /// The system was ill-conditioned: the nearest sample's value was used instead.
    NearestFallback,
}

impl<'a> Interpolator<'a> {
    pub fn new(points: &[[f32; 3]], values: &'a [f32], dim: usize, radius: f32, k: usize) -> Self {
        assert_eq!(values.len(), points.len() * dim);
        Interpolator {
            tree: KdTree::build(points),
            values,
            dim,
            radius,
            k,
            constant_term: true,
        }
    }

    /// Neighbours (sample indices) and weights of point x.
    pub fn weights(
        &self,
        x: [f32; 3],
        nb: &mut Vec<(f32, u32)>,
        w: &mut Vec<f64>,
    ) -> Reconstruction {
        self.tree.nearest(x, self.k.min(self.tree.len()), nb);
        let ids: Vec<u32> = nb.iter().map(|&(_, i)| i).collect();
        let mut solver = MultiquadricSolver::default();
        let pos = |i| self.tree.point(i);
        match solver.weights(&ids, pos, x, self.radius, self.constant_term, w) {
            Ok(()) => Reconstruction::Multiquadric,
            Err(_) => {
                w.clear();
                w.resize(nb.len(), 0.0);
                if !w.is_empty() {
                    w[0] = 1.0;
                }
                Reconstruction::NearestFallback
            }
        }
    }

    /// Reconstructs the vector at x into `out` (length dim).
    pub fn reconstruct(&self, x: [f32; 3], out: &mut [f32]) -> Reconstruction {
        let mut nb = Vec::with_capacity(self.k);
        let mut w = Vec::with_capacity(self.k);
        let how = self.weights(x, &mut nb, &mut w);
        let mut acc = vec![0.0f64; self.dim];
        for (&(_, i), &wj) in nb.iter().zip(&w) {
            let v = &self.values[i as usize * self.dim..(i as usize + 1) * self.dim];
            for (a, &c) in acc.iter_mut().zip(v) {
                *a += wj * c as f64;
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = a as f32;
        }
        how
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn solver_matches_a_known_system() {
        // A chosen so that the first pivot is zero without pivoting.
        let mut a = vec![0.0, 2.0, 1.0, 1.0, 1.0, 1.0, 2.0, 1.0, 3.0];
        let x = [1.0, -2.0, 3.0];
        let mut b: Vec<f64> = (0..3)
            .map(|r| (0..3).map(|c| a[r * 3 + c] * x[c]).sum())
            .collect();
        solve_in_place(&mut a, &mut b, 3).unwrap();
        for k in 0..3 {
            assert!((b[k] - x[k]).abs() < 1e-12);
        }
        let mut sing = vec![1.0, 2.0, 2.0, 4.0];
        assert!(solve_in_place(&mut sing, &mut [1.0, 2.0], 2).is_err());
    }

    #[test]
    fn fixed_size_elimination_equals_the_general_one_bit_for_bit() {
        let mut rng = Rng::new(11);
        for n in [5usize, 9, 17] {
            let a: Vec<f64> = (0..n * n).map(|_| rng.f32() as f64 * 2.0 - 1.0).collect();
            let b: Vec<f64> = (0..n).map(|_| rng.f32() as f64).collect();
            let (mut a1, mut a2) = (a.clone(), a.clone());
            let (mut p1, mut p2) = (vec![0; n], vec![0; n]);
            factor_sized::<0>(&mut a1, &mut p1, n).unwrap();
            factor_in_place(&mut a2, &mut p2, n).unwrap();
            assert_eq!(a1, a2);
            assert_eq!(p1, p2);
            let (mut b1, mut b2) = (b.clone(), b.clone());
            solve_sized::<0>(&a1, &p1, &mut b1, n);
            solve_factored(&a2, &p2, &mut b2, n);
            assert_eq!(b1, b2);
            // And it solves the system.
            for r in 0..n {
                let ax: f64 = (0..n).map(|c| a[r * n + c] * b1[c]).sum();
                assert!((ax - b[r]).abs() < 1e-9, "n {n} row {r}");
            }
        }
    }

    #[test]
    fn cached_factorizations_give_the_weights_of_a_fresh_solve() {
        let mut rng = Rng::new(12);
        let pts: Vec<[f32; 3]> = (0..80)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, rng.f32()])
            .collect();
        let tree = KdTree::build(&pts);
        let queries: Vec<[f32; 3]> = (0..400)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, rng.f32()])
            .collect();
        let order = crate::kdtree::morton_order(&queries);
        let pos = |i: u32| pts[i as usize];
        let (mut cached, mut nb) = (MultiquadricSolver::default(), Vec::new());
        let (mut w1, mut w2, mut w3) = (Vec::new(), Vec::new(), Vec::new());
        for &q in &order {
            let x = queries[q as usize];
            tree.nearest(x, 8, &mut nb);
            let ids: Vec<u32> = nb.iter().map(|&(_, i)| i).collect();
            cached.weights(&ids, pos, x, 1.5, true, &mut w1).unwrap();
            let mut fresh = MultiquadricSolver::default();
            fresh.weights(&ids, pos, x, 1.5, true, &mut w2).unwrap();
            assert_eq!(w1, w2);
            // The caller's order only permutes the weights.
            let rev: Vec<u32> = ids.iter().rev().copied().collect();
            fresh.weights(&rev, pos, x, 1.5, true, &mut w3).unwrap();
            w3.reverse();
            assert_eq!(w1, w3);
            // And they are the multiquadric weights (independent setup in the caller's order).
            let xs: Vec<[f32; 3]> = ids.iter().map(|&i| pts[i as usize]).collect();
            multiquadric_weights(&xs, x, 1.5, true, &mut w3).unwrap();
            for (a, b) in w1.iter().zip(&w3) {
                assert!((a - b).abs() < 1e-9);
            }
        }
        assert!(cached.reused > 100, "reused {}", cached.reused);
        assert_eq!(cached.reused + cached.factored_count, 400);
    }

    #[test]
    fn exact_at_samples_and_reproduces_hardy_formula() {
        let mut rng = Rng::new(3);
        let pts: Vec<[f32; 3]> = (0..60)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, 0.0])
            .collect();
        let dim = 4;
        let vals: Vec<f32> = pts
            .iter()
            .flat_map(|p| [p[0].sin(), p[1].cos(), p[0] * p[1] * 0.1, 1.0])
            .collect();
        let mut ip = Interpolator::new(&pts, &vals, dim, 1.5, 8);
        ip.constant_term = false;
        let mut out = vec![0.0; dim];
        for (i, p) in pts.iter().enumerate() {
            assert_eq!(ip.reconstruct(*p, &mut out), Reconstruction::Multiquadric);
            for c in 0..dim {
                assert!(
                    (out[c] - vals[i * dim + c]).abs() < 1e-4,
                    "sample {i} coef {c}"
                );
            }
        }
        // Off-sample: Σ w_j C_j equals Σ α_j φ_j(x) with α solved per coefficient (eq. 4.5/4.6).
        let x = [5.1, 4.9, 0.0];
        ip.reconstruct(x, &mut out);
        let mut nb = Vec::new();
        ip.tree.nearest(x, 8, &mut nb);
        let xs: Vec<[f32; 3]> = nb.iter().map(|&(_, i)| pts[i as usize]).collect();
        for c in 0..dim {
            let mut a: Vec<f64> = (0..64)
                .map(|e| (dist2(xs[e / 8], xs[e % 8]) as f64 + 2.25).sqrt())
                .collect();
            let mut alpha: Vec<f64> = nb
                .iter()
                .map(|&(_, i)| vals[i as usize * dim + c] as f64)
                .collect();
            solve_in_place(&mut a, &mut alpha, 8).unwrap();
            let direct: f64 = xs
                .iter()
                .zip(&alpha)
                .map(|(p, al)| al * (dist2(*p, x) as f64 + 2.25).sqrt())
                .sum();
            assert!((direct as f32 - out[c]).abs() < 1e-4);
        }
    }

    #[test]
    fn constant_term_reproduces_constants_and_stays_exact_at_samples() {
        let mut rng = Rng::new(8);
        let pts: Vec<[f32; 3]> = (0..40)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, 0.0])
            .collect();
        let vals: Vec<f32> = pts.iter().map(|p| 2.5 + 0.0 * p[0]).collect();
        let ip = Interpolator::new(&pts, &vals, 1, 3.0, 8);
        let mut out = [0.0];
        for _ in 0..50 {
            ip.reconstruct([rng.f32() * 10.0, rng.f32() * 10.0, 0.0], &mut out);
            assert!((out[0] - 2.5).abs() < 1e-4, "{}", out[0]);
        }
        let vals: Vec<f32> = pts.iter().map(|p| p[0].sin() + p[1]).collect();
        let ip = Interpolator::new(&pts, &vals, 1, 3.0, 8);
        for (i, p) in pts.iter().enumerate() {
            ip.reconstruct(*p, &mut out);
            assert!((out[0] - vals[i]).abs() < 1e-4);
        }
        // Without it, a constant is not reproduced off the samples (the thesis' formula).
        let vals = vec![2.5f32; 40];
        let mut ip = Interpolator::new(&pts, &vals, 1, 3.0, 8);
        ip.constant_term = false;
        ip.reconstruct([20.0, 20.0, 0.0], &mut out);
        assert!((out[0] - 2.5).abs() > 1e-3);
    }

    #[test]
    fn coincident_samples_are_reported_and_fall_back() {
        let pts = vec![[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let vals = vec![1.0, 2.0, 3.0];
        let ip = Interpolator::new(&pts, &vals, 1, 0.5, 3);
        let mut out = [0.0];
        assert_eq!(
            ip.reconstruct([0.2, 0.0, 0.0], &mut out),
            Reconstruction::NearestFallback
        );
        assert_eq!(out[0], 1.0);
    }
}
