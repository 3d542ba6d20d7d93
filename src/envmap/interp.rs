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

use super::kdtree::{KdTree, dist2};

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
    let scale = a
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for col in 0..n {
        let (piv, best) = (col..n)
            .map(|r| (r, a[r * n + col].abs()))
            .fold((col, -1.0), |acc, x| if x.1 > acc.1 { x } else { acc });
        if best / scale < PIVOT_TOLERANCE {
            return Err(IllConditioned {
                pivot: best / scale,
                step: col,
            });
        }
        if piv != col {
            for c in 0..n {
                a.swap(piv * n + c, col * n + c);
            }
            b.swap(piv, col);
        }
        let d = a[col * n + col];
        // Row slices instead of indexing: the same arithmetic, without bounds checks in the
        // innermost loop.
        let (top, bottom) = a.split_at_mut((col + 1) * n);
        let pivot_row = &top[col * n + col..col * n + n];
        let (b_top, b_bottom) = b.split_at_mut(col + 1);
        for (row, br) in bottom.chunks_exact_mut(n).zip(b_bottom.iter_mut()) {
            let f = row[col] / d;
            if f != 0.0 {
                for (x, &pv) in row[col..].iter_mut().zip(pivot_row) {
                    *x -= f * pv;
                }
                *br -= f * b_top[col];
            }
        }
    }
    for r in (0..n).rev() {
        let mut s = b[r];
        for c in r + 1..n {
            s -= a[r * n + c] * b[c];
        }
        b[r] = s / a[r * n + r];
    }
    Ok(())
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
    multiquadric_weights_with(xs, x, r, constant_term, w, &mut Vec::new())
}

/// [`multiquadric_weights`] with a caller-provided matrix buffer (no allocation per call).
pub fn multiquadric_weights_with(
    xs: &[[f32; 3]],
    x: [f32; 3],
    r: f32,
    constant_term: bool,
    w: &mut Vec<f64>,
    a: &mut Vec<f64>,
) -> Result<(), IllConditioned> {
    let n = xs.len();
    let m = if constant_term && n > 1 { n + 1 } else { n };
    let r2 = (r as f64) * (r as f64);
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
    w.clear();
    w.extend(xs.iter().map(|p| (dist2(*p, x) as f64 + r2).sqrt()));
    if m > n {
        w.push(1.0);
    } else if n == 1 && constant_term {
        // One neighbour and a constant: the interpolant is that neighbour's value.
        w[0] = 1.0;
        return Ok(());
    }
    solve_in_place(a, w, m)?;
    w.truncate(n);
    Ok(())
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
        let xs: Vec<[f32; 3]> = nb.iter().map(|&(_, i)| self.tree.point(i)).collect();
        match multiquadric_weights(&xs, x, self.radius, self.constant_term, w) {
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
    use crate::fixtures::Rng;

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
