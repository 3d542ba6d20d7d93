//! Top-down clustering of per-instance environment maps (seed 000, 4.6.3.1, after Heckel et al.
//! 1999) with multiquadric reconstruction (4.6.3.2).
//!
//! Start with one cluster of all instances. Each cluster is represented by one sample: the member
//! nearest to the cluster's mean position, stored exactly. Every instance is reconstructed from the
//! k nearest cluster samples by the multiquadric; its error is the sum of squared differences over
//! all coefficients (eq. 4.7 with the difference the thesis' print omits), a cluster's error the sum
//! over its members. While some instance exceeds the bound, the clusters with the largest error are
//! split by the plane through their mean position orthogonal to their principal axis (eigenvectors
//! by Jacobi rotation). Deviation from the thesis, for speed: each round splits the worst
//! `split_fraction` of the violating clusters (worst first), not only the single worst, then
//! re-evaluates all instances in parallel.

use super::interp::{Interpolator, Reconstruction};
use super::kdtree::{KdTree, dist2};
use rayon::prelude::*;

/// Options of [`cluster_envmaps`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusterOptions {
    /// Bound on every instance's error: RMS over its coefficients of (reconstruction − original),
    /// relative to the RMS of all original coefficients.
    pub error: f32,
    /// Neighbours per reconstruction (None: chosen by leave-one-out).
    pub k: Option<usize>,
    /// Multiquadric constant R in metres (None: chosen by leave-one-out).
    pub radius: Option<f32>,
    /// Fraction of the violating clusters split per round.
    pub split_fraction: f32,
}

impl Default for ClusterOptions {
    fn default() -> Self {
        ClusterOptions {
            error: 0.02,
            k: None,
            radius: None,
            split_fraction: 0.5,
        }
    }
}

/// The result: which instances are samples, and how well everything is reconstructed.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    /// Instance index of each cluster's sample, in cluster order.
    pub samples: Vec<u32>,
    /// Cluster of each instance.
    pub assignment: Vec<u32>,
    pub radius: f32,
    pub k: usize,
    /// Per-instance relative RMS error (see [`ClusterOptions::error`]).
    pub errors: Vec<f32>,
    /// RMS of all original coefficients (the reference of the relative errors).
    pub rms: f32,
    /// Reconstructions that fell back to the nearest sample because the system was ill-conditioned.
    pub ill_conditioned: usize,
    pub rounds: usize,
    /// Leave-one-out scores of the (k, R) candidates tried: (k, R, relative RMS error).
    pub loo: Vec<(usize, f32, f32)>,
}

impl Clustering {
    pub fn rms_error(&self) -> f32 {
        (self.errors.iter().map(|e| (*e as f64).powi(2)).sum::<f64>()
            / self.errors.len().max(1) as f64)
            .sqrt() as f32
    }
    pub fn max_error(&self) -> f32 {
        self.errors.iter().fold(0.0, |m, &e| m.max(e))
    }
}

/// Clusters `values` (`dim` floats per instance, at `positions`).
pub fn cluster_envmaps(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
) -> Clustering {
    let n = positions.len();
    assert_eq!(
        values.len(),
        n * dim,
        "values must hold dim floats per instance"
    );
    let rms = ((values.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()
        / values.len().max(1) as f64)
        .sqrt()) as f32;
    let (k, radius, loo) = choose_parameters(positions, values, dim, rms, opts);
    let mut clusters: Vec<Vec<u32>> = if n == 0 {
        Vec::new()
    } else {
        vec![(0..n as u32).collect()]
    };
    let mut rounds = 0;
    loop {
        rounds += 1;
        let samples: Vec<u32> = clusters
            .iter()
            .map(|m| representative(positions, m))
            .collect();
        let (errors, ill) = evaluate(positions, values, dim, &samples, radius, k);
        let rel: Vec<f32> = errors.iter().map(|&e| relative(e, dim, rms)).collect();
        let mut violating: Vec<(f64, usize)> = clusters
            .iter()
            .enumerate()
            .filter(|(_, m)| m.len() > 1 && m.iter().any(|&i| rel[i as usize] > opts.error))
            .map(|(c, m)| (m.iter().map(|&i| errors[i as usize]).sum::<f64>(), c))
            .collect();
        if violating.is_empty() {
            let mut assignment = vec![0u32; n];
            for (c, m) in clusters.iter().enumerate() {
                for &i in m {
                    assignment[i as usize] = c as u32;
                }
            }
            return Clustering {
                samples,
                assignment,
                radius,
                k,
                errors: rel,
                rms,
                ill_conditioned: ill,
                rounds,
                loo,
            };
        }
        violating.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let take = ((violating.len() as f32 * opts.split_fraction).ceil() as usize)
            .clamp(1, violating.len());
        let mut split: Vec<usize> = violating[..take].iter().map(|&(_, c)| c).collect();
        split.sort_unstable();
        for &c in split.iter().rev() {
            let members = std::mem::take(&mut clusters[c]);
            let (a, b) = split_cluster(positions, &members);
            clusters[c] = a;
            clusters.push(b);
        }
    }
}

fn relative(err: f64, dim: usize, rms: f32) -> f32 {
    if rms == 0.0 {
        0.0
    } else {
        ((err / dim as f64).sqrt() / rms as f64) as f32
    }
}

/// Squared reconstruction error of every instance from the given samples.
fn evaluate(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    samples: &[u32],
    radius: f32,
    k: usize,
) -> (Vec<f64>, usize) {
    let (pts, vals) = gather_samples(positions, values, dim, samples);
    let ip = Interpolator::new(&pts, &vals, dim, radius, k);
    let res: Vec<(f64, bool)> = (0..positions.len())
        .into_par_iter()
        .map_init(
            || vec![0.0f32; dim],
            |out, i| {
                let how = ip.reconstruct(positions[i], out);
                let own = &values[i * dim..(i + 1) * dim];
                let e = out
                    .iter()
                    .zip(own)
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum::<f64>();
                (e, how == Reconstruction::NearestFallback)
            },
        )
        .collect();
    let ill = res.iter().filter(|r| r.1).count();
    (res.into_iter().map(|r| r.0).collect(), ill)
}

/// Positions and values (`dim` floats each) of the given sample instances, in sample order.
pub fn gather_samples(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    samples: &[u32],
) -> (Vec<[f32; 3]>, Vec<f32>) {
    let pts = samples.iter().map(|&s| positions[s as usize]).collect();
    let vals = samples
        .iter()
        .flat_map(|&s| {
            values[s as usize * dim..(s as usize + 1) * dim]
                .iter()
                .copied()
        })
        .collect();
    (pts, vals)
}

/// The member nearest to the mean position (ties: lowest index).
fn representative(positions: &[[f32; 3]], members: &[u32]) -> u32 {
    let m = mean(positions, members);
    *members
        .iter()
        .min_by(|&&a, &&b| {
            dist2(positions[a as usize], m)
                .total_cmp(&dist2(positions[b as usize], m))
                .then(a.cmp(&b))
        })
        .expect("clusters are never empty")
}

fn mean(positions: &[[f32; 3]], members: &[u32]) -> [f32; 3] {
    let mut s = [0.0f64; 3];
    for &i in members {
        for a in 0..3 {
            s[a] += positions[i as usize][a] as f64;
        }
    }
    let n = members.len().max(1) as f64;
    [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
}

/// Splits by the plane through the mean orthogonal to the principal axis; falls back to halving
/// the members sorted along that axis when all of them lie on one side.
fn split_cluster(positions: &[[f32; 3]], members: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let m = mean(positions, members);
    let mut cov = [[0.0f64; 3]; 3];
    for &i in members {
        let p = positions[i as usize];
        let d = [
            (p[0] - m[0]) as f64,
            (p[1] - m[1]) as f64,
            (p[2] - m[2]) as f64,
        ];
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += d[r] * d[c];
            }
        }
    }
    let (vals, vecs) = jacobi_eigen(cov);
    let axis_idx = (0..3)
        .max_by(|&a, &b| vals[a].total_cmp(&vals[b]))
        .unwrap_or(0);
    let axis = [vecs[0][axis_idx], vecs[1][axis_idx], vecs[2][axis_idx]];
    let proj = |i: u32| {
        let p = positions[i as usize];
        (p[0] - m[0]) as f64 * axis[0]
            + (p[1] - m[1]) as f64 * axis[1]
            + (p[2] - m[2]) as f64 * axis[2]
    };
    let (a, b): (Vec<u32>, Vec<u32>) = members.iter().partition(|&&i| proj(i) < 0.0);
    if !a.is_empty() && !b.is_empty() {
        return (a, b);
    }
    let mut sorted = members.to_vec();
    sorted.sort_by(|&x, &y| proj(x).total_cmp(&proj(y)).then(x.cmp(&y)));
    let half = sorted.len() / 2;
    let b = sorted.split_off(half);
    (sorted, b)
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations (Press et al. 1992).
/// Returns the eigenvalues and the eigenvectors as columns.
pub fn jacobi_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..50 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        if off < 1e-30 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A' = Jᵀ A J with the rotation in the (p, q) plane.
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * rp[k] - s * rq[k];
                a[q][k] = s * rp[k] + c * rq[k];
            }
            for row in v.iter_mut() {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = c * vkp - s * vkq;
                row[q] = s * vkp + c * vkq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

/// Chooses (k, R) by leave-one-out: for a deterministic subset of instances, reconstruct each from
/// its k nearest *other* instances and keep the candidate with the smallest relative RMS error.
fn choose_parameters(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    rms: f32,
    opts: &ClusterOptions,
) -> (usize, f32, Vec<(usize, f32, f32)>) {
    let n = positions.len();
    let default_k = opts.k.unwrap_or(8).clamp(1, n.max(1));
    if n < 3 || (opts.k.is_some() && opts.radius.is_some()) {
        return (default_k, opts.radius.unwrap_or(1.0), Vec::new());
    }
    let tree = KdTree::build(positions);
    let stride = (n / 500).max(1);
    let subset: Vec<usize> = (0..n).step_by(stride).collect();
    let mut nb = Vec::new();
    let mut spacing: Vec<f32> = subset
        .iter()
        .map(|&i| {
            tree.nearest(positions[i], 2, &mut nb);
            nb.get(1).map_or(0.0, |x| x.0.sqrt())
        })
        .collect();
    spacing.sort_by(f32::total_cmp);
    let s = spacing[spacing.len() / 2].max(1e-3);
    let ks: Vec<usize> = match opts.k {
        Some(k) => vec![k.clamp(1, n - 1)],
        None => [4usize, 8, 16].iter().map(|&k| k.min(n - 1)).collect(),
    };
    let rs: Vec<f32> = match opts.radius {
        Some(r) => vec![r],
        None => [0.5f32, 1.0, 2.0, 4.0].iter().map(|f| f * s).collect(),
    };
    let mut scores = Vec::new();
    for &k in &ks {
        for &r in &rs {
            let err: f64 = subset
                .par_iter()
                .map(|&i| loo_error(&tree, positions, values, dim, i, k, r))
                .collect::<Vec<f64>>()
                .iter()
                .sum();
            scores.push((k, r, relative(err / subset.len() as f64, dim, rms)));
        }
    }
    let best = scores
        .iter()
        .fold(scores[0], |b, &c| if c.2 < b.2 { c } else { b });
    (best.0, best.1, scores)
}

fn loo_error(
    tree: &KdTree,
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    i: usize,
    k: usize,
    r: f32,
) -> f64 {
    let mut nb = Vec::new();
    tree.nearest(positions[i], k + 1, &mut nb);
    nb.retain(|&(_, j)| j as usize != i);
    nb.truncate(k);
    let xs: Vec<[f32; 3]> = nb.iter().map(|&(_, j)| positions[j as usize]).collect();
    let mut w = Vec::new();
    if super::interp::multiquadric_weights(&xs, positions[i], r, true, &mut w).is_err() {
        w = vec![0.0; nb.len()];
        w[0] = 1.0;
    }
    let own = &values[i * dim..(i + 1) * dim];
    (0..dim)
        .map(|c| {
            let rec: f64 = nb
                .iter()
                .zip(&w)
                .map(|(&(_, j), wj)| wj * values[j as usize * dim + c] as f64)
                .sum();
            (rec - own[c] as f64).powi(2)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::Rng;

    /// A smooth field with a sharp feature: 96 coefficients per instance.
    pub fn synthetic(n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<f32>) {
        let mut rng = Rng::new(seed);
        let pos: Vec<[f32; 3]> = (0..n)
            .map(|_| [rng.f32() * 100.0, rng.f32() * 100.0, rng.f32() * 2.0])
            .collect();
        let vals = pos
            .iter()
            .flat_map(|p| {
                (0..96).map(move |c| {
                    let f = 0.02 + 0.01 * (c % 7) as f32;
                    (1.0 + 0.5 * (p[0] * f).sin() * (p[1] * f * 0.7).cos()) / (1 + c / 3) as f32
                })
            })
            .collect();
        (pos, vals)
    }

    #[test]
    fn jacobi_diagonalizes() {
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 1.0]];
        let (vals, v) = jacobi_eigen(a);
        for k in 0..3 {
            let col = [v[0][k], v[1][k], v[2][k]];
            for r in 0..3 {
                let av: f64 = (0..3).map(|c| a[r][c] * col[c]).sum();
                assert!((av - vals[k] * col[r]).abs() < 1e-9);
            }
        }
        assert!((vals.iter().sum::<f64>() - 8.0).abs() < 1e-9);
    }

    #[test]
    fn bound_holds_on_every_instance_and_samples_are_exact() {
        let (pos, vals) = synthetic(3000, 11);
        for bound in [0.05f32, 0.01] {
            let c = cluster_envmaps(
                &pos,
                &vals,
                96,
                &ClusterOptions {
                    error: bound,
                    ..Default::default()
                },
            );
            assert!(c.max_error() <= bound, "{} > {bound}", c.max_error());
            assert!(c.samples.len() < 3000, "{} clusters", c.samples.len());
            // Independent check of the errors with a fresh interpolator.
            let pts: Vec<[f32; 3]> = c.samples.iter().map(|&s| pos[s as usize]).collect();
            let sv: Vec<f32> = c
                .samples
                .iter()
                .flat_map(|&s| vals[s as usize * 96..(s as usize + 1) * 96].to_vec())
                .collect();
            let ip = Interpolator::new(&pts, &sv, 96, c.radius, c.k);
            let mut out = vec![0.0; 96];
            for &s in &c.samples {
                ip.reconstruct(pos[s as usize], &mut out);
                let own = &vals[s as usize * 96..(s as usize + 1) * 96];
                assert!(
                    out.iter()
                        .zip(own)
                        .all(|(a, b)| (a - b).abs() < 1e-3 * c.rms.max(1.0))
                );
            }
            for i in (0..3000).step_by(37) {
                ip.reconstruct(pos[i], &mut out);
                let e: f64 = out
                    .iter()
                    .zip(&vals[i * 96..(i + 1) * 96])
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum();
                assert!(relative(e, 96, c.rms) <= bound * 1.001 + 1e-6);
            }
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let (pos, vals) = synthetic(1500, 4);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| cluster_envmaps(&pos, &vals, 96, &ClusterOptions::default()))
        };
        assert_eq!(run(1), run(2));
    }

    #[test]
    fn constant_field_needs_one_cluster() {
        let pos: Vec<[f32; 3]> = (0..100)
            .map(|i| [i as f32, (i * 7 % 13) as f32, 0.0])
            .collect();
        let vals = vec![0.7f32; 100 * 96];
        let c = cluster_envmaps(&pos, &vals, 96, &ClusterOptions::default());
        assert_eq!(c.samples.len(), 1);
        assert!(c.max_error() < 1e-4);
    }
}
