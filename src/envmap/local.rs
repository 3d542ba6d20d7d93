//! The per-instance local part of the clustered maps (issue 20, item 2).
//!
//! Traced maps differ between neighbouring instances by far more than any bound (local occlusion
//! by the neighbours' crowns and trunks: docs/PERFORMANCE.md, "the cause"), so a field shared
//! between instances cannot reproduce them. The stage therefore splits each instance's map into
//! - a shared smooth part: the cluster samples' multiquadric interpolation (world frame), and
//! - a local part: the residual (map − shared) projected onto the p leading principal
//!   components of all instances' residuals (a basis of p × dim floats, stored once), with p
//!   coefficients per instance quantized to 8 bits (per component scale = max |coefficient| /
//!   127, stored as u8 with 128 = 0).
//!
//! Reconstruction (renderer and CPU reference alike, `render::ambient::env::cluster_maps`):
//! `map = shared(x) + Σ_k (q_k − 128) · scale_k · basis_k`, then rotated into the instance's
//! frame. The principal components are of the uncentred second moment Σ r rᵀ (no mean to store),
//! by cyclic Jacobi rotations; the residual's white Monte-Carlo noise spreads over all dim
//! directions, so p ≪ dim components keep the correlated local occlusion and drop most of the
//! noise.

use rayon::prelude::*;

/// The local part of every instance.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalPart {
    /// Components p.
    pub components: usize,
    pub dim: usize,
    /// p × dim, component-major, unit vectors, largest eigenvalue first.
    pub basis: Vec<f32>,
    /// Per component: the value of one quantization step.
    pub scale: Vec<f32>,
    /// Instances × p, `q − 128` steps of `scale`.
    pub coeffs: Vec<u8>,
}

/// Bytes a local part of p components takes for n instances.
pub fn local_bytes(n: usize, p: usize, dim: usize) -> u64 {
    if p == 0 {
        return 0;
    }
    (n * p + p * dim * 4 + p * 4) as u64
}

impl LocalPart {
    /// Adds instance i's local part to `out` (dim floats).
    pub fn add_to(&self, i: usize, out: &mut [f32]) {
        let p = self.components;
        for (k, &q) in self.coeffs[i * p..(i + 1) * p].iter().enumerate() {
            let a = (q as i32 - 128) as f32 * self.scale[k];
            if a == 0.0 {
                continue;
            }
            for (o, &b) in out
                .iter_mut()
                .zip(&self.basis[k * self.dim..(k + 1) * self.dim])
            {
                *o += a * b;
            }
        }
    }

    /// Adds every instance's local part to `shared` (instances × dim).
    pub fn add_all(&self, shared: &mut [f32]) {
        shared
            .par_chunks_mut(self.dim)
            .enumerate()
            .for_each(|(i, o)| self.add_to(i, o));
    }
}

/// Fits the local part of `residual` (instances × dim): the p leading principal components and
/// the quantized coefficients. Deterministic whatever the thread count (fixed blocks, summed in
/// order).
pub fn fit(residual: &[f32], dim: usize, p: usize) -> LocalPart {
    fit_denoised(residual, dim, p, None, None)
}

/// [`fit`], and with `noise` (the dim × dim covariance of the maps' Monte-Carlo noise per
/// instance, row-major) each component's coefficients shrunk by max(0, 1 − ν_k / λ_k) (ν_k the
/// noise variance along the component, λ_k its mean squared coefficient): a Wiener filter of
/// the per-instance part. The cluster stage's default with the `envmaps` section's noise
/// estimate (the tracer's two independent halves; `ClusterOptions::denoise`). With `scale`
/// (heteroscedastic; experimental, `bake bench cluster --heteroscedastic`), instance i's noise
/// covariance is taken as `scale[i]` × the mean covariance `noise`, so its coefficients shrink
/// by max(0, 1 − scale_i ν_k / λ_k).
pub fn fit_denoised(
    residual: &[f32],
    dim: usize,
    p: usize,
    noise: Option<&[f64]>,
    scale: Option<&[f32]>,
) -> LocalPart {
    let n = residual.len() / dim.max(1);
    let p = p.min(dim);
    const BLOCK: usize = 1024;
    let partial: Vec<Vec<f64>> = residual
        .par_chunks(dim * BLOCK)
        .map(|blk| {
            let mut m = vec![0.0f64; dim * dim];
            for r in blk.chunks_exact(dim) {
                for a in 0..dim {
                    let ra = r[a] as f64;
                    if ra == 0.0 {
                        continue;
                    }
                    let row = &mut m[a * dim..(a + 1) * dim];
                    for (x, &rb) in row[a..].iter_mut().zip(&r[a..]) {
                        *x += ra * rb as f64;
                    }
                }
            }
            m
        })
        .collect();
    let mut m = vec![0.0f64; dim * dim];
    for blk in &partial {
        for (a, b) in m.iter_mut().zip(blk) {
            *a += b;
        }
    }
    for a in 0..dim {
        for b in 0..a {
            m[a * dim + b] = m[b * dim + a];
        }
    }
    let (vals, vecs) = jacobi_eigen_n(m, dim);
    let mut order: Vec<usize> = (0..dim).collect();
    order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]).then(a.cmp(&b)));
    let mut basis = vec![0.0f32; p * dim];
    for (k, &e) in order.iter().take(p).enumerate() {
        let col: Vec<f64> = (0..dim).map(|r| vecs[r * dim + e]).collect();
        // Sign fixed: the largest component positive.
        let big = col
            .iter()
            .enumerate()
            .fold(0, |b, (i, x)| if x.abs() > col[b].abs() { i } else { b });
        let s = if col[big] < 0.0 { -1.0 } else { 1.0 };
        for (d, &x) in basis[k * dim..(k + 1) * dim].iter_mut().zip(&col) {
            *d = (s * x) as f32;
        }
    }
    let bs = &basis;
    let proj: Vec<f32> = residual
        .par_chunks(dim)
        .flat_map_iter(move |r| {
            (0..p).map(move |k| {
                let b = &bs[k * dim..(k + 1) * dim];
                r.iter()
                    .zip(b)
                    .map(|(&x, &y)| x as f64 * y as f64)
                    .sum::<f64>() as f32
            })
        })
        .collect();
    let mut proj = proj;
    if let Some(nc) = noise {
        // Per component: ν_k (the noise variance along it) and λ_k (its mean squared
        // coefficient).
        let nl: Vec<(f64, f64)> = (0..p)
            .map(|k| {
                let b = &basis[k * dim..(k + 1) * dim];
                let nu: f64 = (0..dim)
                    .map(|r| {
                        b[r] as f64 * (0..dim).map(|c| nc[r * dim + c] * b[c] as f64).sum::<f64>()
                    })
                    .sum();
                let lambda = (0..n)
                    .map(|i| (proj[i * p + k] as f64).powi(2))
                    .sum::<f64>()
                    / n.max(1) as f64;
                (nu, lambda)
            })
            .collect();
        for (j, a) in proj.iter_mut().enumerate() {
            let (nu, lambda) = nl[j % p];
            let s = scale.map_or(1.0, |s| s[j / p] as f64);
            let f = if lambda > 0.0 {
                (1.0 - s * nu / lambda).max(0.0)
            } else {
                0.0
            };
            *a *= f as f32;
        }
    }
    let mut scale = vec![0.0f32; p];
    for (i, &a) in proj.iter().enumerate() {
        scale[i % p.max(1)] = scale[i % p.max(1)].max(a.abs());
    }
    for s in &mut scale {
        *s /= 127.0;
    }
    let coeffs = proj
        .iter()
        .enumerate()
        .map(|(i, &a)| {
            let s = scale[i % p.max(1)];
            let q = if s > 0.0 { (a / s).round() } else { 0.0 };
            (q.clamp(-127.0, 127.0) as i32 + 128) as u8
        })
        .collect();
    debug_assert_eq!(proj.len(), n * p);
    LocalPart {
        components: p,
        dim,
        basis,
        scale,
        coeffs,
    }
}

/// When cyclic Jacobi rotations stop (besides a sweep limit): the squared off-diagonal norm
/// below an absolute bound, or its norm relative to the diagonal's absolute sum.
#[derive(Debug, Clone, Copy)]
pub enum JacobiStop {
    OffSquaredBelow(f64),
    OffRelativeToDiagonal(f64),
}

/// Eigen-decomposition of a symmetric n×n matrix (row-major) by cyclic Jacobi rotations.
/// Returns the eigenvalues and the eigenvectors as columns (row-major n×n).
pub fn jacobi_eigen_n(a: Vec<f64>, n: usize) -> (Vec<f64>, Vec<f64>) {
    jacobi_eigen_with(a, n, 60, JacobiStop::OffRelativeToDiagonal(1e-15))
}

/// [`jacobi_eigen_n`] with a given sweep limit and stopping rule (Press et al. 1992).
pub(crate) fn jacobi_eigen_with(
    mut a: Vec<f64>,
    n: usize,
    sweeps: usize,
    stop: JacobiStop,
) -> (Vec<f64>, Vec<f64>) {
    let mut v = vec![0.0f64; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    let diag: f64 = (0..n).map(|i| a[i * n + i].abs()).sum::<f64>().max(1e-300);
    for _sweep in 0..sweeps {
        let mut off = 0.0;
        for p in 0..n {
            for q in p + 1..n {
                off += a[p * n + q].powi(2);
            }
        }
        let done = match stop {
            JacobiStop::OffSquaredBelow(bound) => off < bound,
            JacobiStop::OffRelativeToDiagonal(rel) => off.sqrt() <= rel * diag,
        };
        if done {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p * n + q];
                if apq.abs() <= 1e-300 {
                    continue;
                }
                let theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                let t = if theta == 0.0 {
                    1.0
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k * n + p], a[k * n + q]);
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p * n + k], a[q * n + k]);
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_n_diagonalizes_a_symmetric_matrix() {
        let n = 7;
        let mut rng = crate::rng::Rng::new(5);
        let b: Vec<f64> = (0..n * n).map(|_| rng.f32() as f64 - 0.5).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum();
            }
        }
        let (vals, v) = jacobi_eigen_n(a.clone(), n);
        for e in 0..n {
            for i in 0..n {
                let av: f64 = (0..n).map(|j| a[i * n + j] * v[j * n + e]).sum();
                assert!((av - vals[e] * v[i * n + e]).abs() < 1e-10);
            }
        }
    }

    #[test]
    fn a_low_rank_residual_is_carried_by_its_components() {
        // Residuals in a 3-dimensional subspace of 96: three components reproduce them to the
        // quantization step (max / 127 per component).
        let (n, dim) = (2000, 96);
        let mut rng = crate::rng::Rng::new(9);
        let dirs: Vec<f32> = (0..3 * dim).map(|_| rng.f32() - 0.5).collect();
        let res: Vec<f32> = (0..n)
            .flat_map(|_| {
                let a = [
                    rng.f32() - 0.5,
                    2.0 * (rng.f32() - 0.5),
                    0.3 * (rng.f32() - 0.5),
                ];
                let d = dirs.clone();
                (0..dim).map(move |c| (0..3).map(|k| a[k] * d[k * dim + c]).sum::<f32>())
            })
            .collect();
        let l = fit(&res, dim, 3);
        let mut err = 0.0f64;
        let mut tot = 0.0f64;
        for i in 0..n {
            let mut out = vec![0.0f32; dim];
            l.add_to(i, &mut out);
            for (o, r) in out.iter().zip(&res[i * dim..(i + 1) * dim]) {
                err += ((o - r) as f64).powi(2);
                tot += (*r as f64).powi(2);
            }
        }
        assert!((err / tot).sqrt() < 0.01, "{}", (err / tot).sqrt());
    }

    #[test]
    fn the_wiener_filter_drops_components_that_are_only_noise() {
        // Two directions of signal plus isotropic noise σ: with the noise covariance σ² I the
        // filtered local part is closer to the signal than the plain one.
        let (n, dim, sigma) = (3000, 96, 0.05f32);
        let mut rng = crate::rng::Rng::new(13);
        let dirs: Vec<f32> = (0..2 * dim).map(|_| rng.f32() - 0.5).collect();
        let mut signal = Vec::with_capacity(n * dim);
        let mut noisy = Vec::with_capacity(n * dim);
        for _ in 0..n {
            let a = [rng.f32() - 0.5, rng.f32() - 0.5];
            for c in 0..dim {
                let s = a[0] * dirs[c] + a[1] * dirs[dim + c];
                let g = (0..4).map(|_| rng.f32() - 0.5).sum::<f32>() * 3.0f32.sqrt();
                signal.push(s);
                noisy.push(s + sigma * g);
            }
        }
        let mut cov = vec![0.0f64; dim * dim];
        for c in 0..dim {
            cov[c * dim + c] = (sigma as f64).powi(2);
        }
        let err = |l: &LocalPart| {
            let mut e = 0.0f64;
            for i in 0..n {
                let mut out = vec![0.0f32; dim];
                l.add_to(i, &mut out);
                for (o, s) in out.iter().zip(&signal[i * dim..(i + 1) * dim]) {
                    e += ((o - s) as f64).powi(2);
                }
            }
            e
        };
        let plain = err(&fit(&noisy, dim, 6));
        let filtered = err(&fit_denoised(&noisy, dim, 6, Some(&cov), None));
        assert!(filtered < 0.6 * plain, "{filtered} vs {plain}");
    }
}
