//! Top-down clustering of per-instance environment maps (seed 000, 4.6.3.1, after Heckel et al.
//! 1999) with multiquadric reconstruction (4.6.3.2).
//! The clustering loop is here; `error.rs` holds the per-instance error, `split.rs` the
//! cluster split, `params.rs` the choice of (k, R).
//!
//! Start with one cluster of all instances. Each cluster is represented by one sample: the member
//! nearest to the cluster's mean position, stored exactly. Every instance is reconstructed from the
//! k nearest cluster samples by the multiquadric; its error is the sum of squared differences over
//! all coefficients (eq. 4.7 with the difference the thesis' print omits), a cluster's error the sum
//! over its members. While some instance exceeds the bound, the clusters with the largest error are
//! split by the plane through their mean position orthogonal to their principal axis (eigenvectors
//! by Jacobi rotation). Deviation from the thesis, for speed: each round splits the worst
//! `split_fraction` of the violating clusters (worst first), not only the single worst.
//!
//! Incremental evaluation (exact, not an approximation): an instance's reconstruction depends only
//! on its k nearest samples (ordered by distance, ties by instance index). After a round's splits
//! only instances whose neighbour list can change are re-evaluated: those that used a removed
//! sample, and those with a new sample no farther than their current k-th neighbour. All other
//! errors are cached, so the result is identical to re-evaluating every instance every round (the
//! tests check this against such a reference) at a fraction of the cost once clusters are small.
//!
//! Noise-aware bound: traced maps carry Monte-Carlo noise of relative RMS σ. Against noisy
//! originals a perfect reconstruction of the noise-free field still shows an error ≈ σ, so a bound
//! below σ would split down to single instances. With a noise level (given, or estimated from the
//! data by [`estimate_noise`]) an instance passes when e² ≤ E² + σ²: the expected squared error
//! against noisy data is the error against the noise-free field plus σ².

use super::interp::{Interpolator, MultiquadricSolver};
use crate::kdtree::{KdTree, dist2};
use rayon::prelude::*;

mod error;
mod params;
mod split;
#[cfg(test)]
mod tests;

pub use error::*;
use params::*;
pub use split::*;

/// How much Monte-Carlo noise the bound allows for (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Noise {
    /// The maps are exact: the bound applies to the error itself.
    #[default]
    None,
    /// Relative RMS noise per coefficient (relative to the RMS of all coefficients).
    Given(f32),
    /// Estimated from the data ([`estimate_noise`]).
    Estimate,
}

/// Options of [`cluster_envmaps`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
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
    /// Noise level the bound allows for.
    pub noise: Noise,
    /// Principal components of the per-instance local part (`envmap::local`), stored when the
    /// shared part alone does not meet the bound within the byte budget; 0: none.
    pub local: u32,
    /// Byte budget of the section's samples and local part (not the optional stored weights);
    /// None: the raw maps' bytes / `compression`.
    pub max_bytes: Option<u64>,
    /// Target compression when `max_bytes` is None (raw maps over samples + local part);
    /// 0: no budget (split until the bound holds, as before version 3).
    pub compression: f32,
    /// Wiener-filter the local part with the `envmaps` section's noise estimate, when it has
    /// one (`local::fit_denoised`; cluster stage version 4).
    pub denoise: bool,
    /// Also store every instance's neighbours and weights in the `clusters` section (the
    /// runtime need not solve; `bake cluster --weights`). Left out of the serialized options
    /// when off, so that the keys and build records of pipelines without it stay as they were.
    #[serde(skip_serializing_if = "is_false")]
    pub weights: bool,
}

fn is_false(b: &bool) -> bool {
    !*b
}

impl ClusterOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: ClusterOptions = ClusterOptions {
        error: 0.02,
        k: None,
        radius: None,
        split_fraction: 1.0,
        noise: Noise::None,
        local: 8,
        max_bytes: None,
        compression: 20.0,
        denoise: true,
        weights: false,
    };

    /// The byte budget for n instances of `dim` floats (None: unlimited).
    pub fn budget(&self, n: usize, dim: usize) -> Option<u64> {
        match self.max_bytes {
            Some(b) => Some(b),
            None if self.compression > 0.0 => {
                Some(((n * dim * 4) as f64 / self.compression as f64).floor() as u64)
            }
            None => None,
        }
    }

    /// The most samples the budget leaves beside a local part of `local` components.
    pub fn max_samples(&self, n: usize, dim: usize, local: usize) -> usize {
        match self.budget(n, dim) {
            None => usize::MAX,
            Some(b) => {
                let rest = b.saturating_sub(super::local::local_bytes(n, local, dim));
                ((rest / sample_bytes(dim)) as usize).max(1)
            }
        }
    }
}

impl Default for ClusterOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Bytes of one stored sample: position, instance index, `dim` floats.
pub fn sample_bytes(dim: usize) -> u64 {
    (12 + 4 + dim * 4) as u64
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
    /// Relative noise level the bound allowed for (0 without [`Noise`]).
    pub noise: f32,
    /// Reconstructions that fell back to the nearest sample because the system was ill-conditioned.
    pub ill_conditioned: usize,
    pub rounds: usize,
    /// Instance evaluations (reconstruction + error) over all rounds.
    pub evaluations: usize,
    /// Leave-one-out scores of the (k, R) candidates tried: (k, R, relative RMS error).
    pub loo: Vec<(usize, f32, f32)>,
    /// The split loop stopped at the sample budget with some instance over the bound.
    pub budget_limited: bool,
}

impl Clustering {
    pub fn rms_error(&self) -> f32 {
        rms_of(&self.errors)
    }
    pub fn max_error(&self) -> f32 {
        max_of(&self.errors)
    }
}

/// RMS of a list of values, such as per-instance errors (0 for none), summed in f64.
pub fn rms_of(values: &[f32]) -> f32 {
    (values.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / values.len().max(1) as f64).sqrt()
        as f32
}

/// The largest per-instance error (0 for none).
pub fn max_of(errors: &[f32]) -> f32 {
    errors.iter().fold(0.0, |m, &e| m.max(e))
}

/// The data being clustered and the fixed parameters of one run.
#[derive(Clone, Copy)]
pub(crate) struct Problem<'a> {
    pub positions: &'a [[f32; 3]],
    pub values: &'a [f32],
    pub dim: usize,
    pub k: usize,
    pub radius: f32,
    pub rms: f32,
    pub error: f32,
    pub noise: f32,
}

impl Problem<'_> {
    /// Whether a squared error breaks the (noise-aware) bound; `wsq` is Σ w_j² of the instance's
    /// weights (the noise of the samples that reaches the reconstruction).
    pub(crate) fn exceeds(&self, e: f64, wsq: f64) -> bool {
        let r = relative(e, self.dim, self.rms) as f64;
        r * r > (self.error as f64).powi(2) + (self.noise as f64).powi(2) * (1.0 + wsq)
    }
}

/// Clusters `values` (`dim` floats per instance, at `positions`).
pub fn cluster_envmaps(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
) -> Clustering {
    cluster_envmaps_limited(positions, values, dim, opts, usize::MAX)
}

/// [`cluster_envmaps`] with at most `max_samples` samples: the worst clusters are split first,
/// and a round splits no more clusters than the budget has samples left.
pub fn cluster_envmaps_limited(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
    max_samples: usize,
) -> Clustering {
    let (p, loo) = prepare(positions, values, dim, opts);
    let n = positions.len();
    let mut clusters: Vec<Vec<u32>> = Vec::new();
    let mut samples: Vec<u32> = Vec::new();
    let mut cache = NeighbourCache::new(p.positions, p.k);
    if n > 0 {
        let all: Vec<u32> = (0..n as u32).collect();
        samples.push(representative(positions, &all));
        clusters.push(all);
        cache.update(&p, &samples, &[], &samples.clone());
    }
    let mut rounds = 1;
    loop {
        let room = max_samples.saturating_sub(samples.len());
        let split = select_splits(
            &p,
            &clusters,
            &cache.err,
            &cache.wsq,
            opts.split_fraction,
            room,
        );
        if split.is_empty() {
            let limited = room == 0
                && select_splits(&p, &clusters, &cache.err, &cache.wsq, 1.0, 1).len() == 1;
            return finish(
                &p,
                clusters,
                samples,
                &cache.err,
                cache.ill_count(),
                rounds,
                cache.evaluations,
                loo,
                limited,
            );
        }
        let (removed, added) = apply_splits(positions, &mut clusters, &mut samples, &split);
        cache.update(&p, &samples, &removed, &added);
        rounds += 1;
    }
}

/// RMS, (k, R) and noise level of a run.
pub(crate) fn prepare<'a>(
    positions: &'a [[f32; 3]],
    values: &'a [f32],
    dim: usize,
    opts: &ClusterOptions,
) -> (Problem<'a>, Vec<(usize, f32, f32)>) {
    assert_eq!(
        values.len(),
        positions.len() * dim,
        "values must hold dim floats per instance"
    );
    let rms = rms_of(values);
    let (k, radius, loo) = choose_parameters(positions, values, dim, rms, opts);
    let noise = match opts.noise {
        Noise::None => 0.0,
        Noise::Given(s) => s.max(0.0),
        Noise::Estimate => estimate_noise(positions, values, dim),
    };
    let p = Problem {
        positions,
        values,
        dim,
        k,
        radius,
        rms,
        error: opts.error,
        noise,
    };
    (p, loo)
}

/// The clusters to split this round: the worst `fraction` of those with a member over the bound
/// (clusters of one instance cannot be split), by summed squared error, worst first; returned in
/// ascending cluster order; at most `limit` of them.
pub(crate) fn select_splits(
    p: &Problem,
    clusters: &[Vec<u32>],
    err: &[f64],
    wsq: &[f64],
    fraction: f32,
    limit: usize,
) -> Vec<usize> {
    let mut violating: Vec<(f64, usize)> = clusters
        .par_iter()
        .enumerate()
        .filter(|(_, m)| {
            m.len() > 1
                && m.iter()
                    .any(|&i| p.exceeds(err[i as usize], wsq[i as usize]))
        })
        .map(|(c, m)| (m.iter().map(|&i| err[i as usize]).sum::<f64>(), c))
        .collect();
    if violating.is_empty() || limit == 0 {
        return Vec::new();
    }
    violating.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let take = ((violating.len() as f32 * fraction).ceil() as usize)
        .clamp(1, violating.len())
        .min(limit);
    let mut split: Vec<usize> = violating[..take].iter().map(|&(_, c)| c).collect();
    split.sort_unstable();
    split
}

/// Splits the given clusters (ascending order): cluster c keeps one half, the other half is
/// appended. Returns the samples that disappeared and those that are new (instance indices).
pub(crate) fn apply_splits(
    positions: &[[f32; 3]],
    clusters: &mut Vec<Vec<u32>>,
    samples: &mut Vec<u32>,
    split: &[usize],
) -> (Vec<u32>, Vec<u32>) {
    // The halves and their samples are independent per cluster: computed in parallel, applied in
    // a fixed order.
    let halves: Vec<(Vec<u32>, Vec<u32>, u32, u32)> = split
        .par_iter()
        .map(|&c| {
            let (a, b) = split_cluster(positions, &clusters[c]);
            let (ra, rb) = (representative(positions, &a), representative(positions, &b));
            (a, b, ra, rb)
        })
        .collect();
    let (mut removed, mut added) = (Vec::new(), Vec::new());
    for (&c, (a, b, ra, rb)) in split.iter().zip(halves).rev() {
        let old = samples[c];
        if old != ra && old != rb {
            removed.push(old);
        }
        added.extend([ra, rb].into_iter().filter(|&s| s != old));
        clusters[c] = a;
        samples[c] = ra;
        clusters.push(b);
        samples.push(rb);
    }
    (removed, added)
}

#[allow(clippy::too_many_arguments)]
fn finish(
    p: &Problem,
    clusters: Vec<Vec<u32>>,
    samples: Vec<u32>,
    err: &[f64],
    ill_conditioned: usize,
    rounds: usize,
    evaluations: usize,
    loo: Vec<(usize, f32, f32)>,
    budget_limited: bool,
) -> Clustering {
    let mut assignment = vec![0u32; p.positions.len()];
    for (c, m) in clusters.iter().enumerate() {
        for &i in m {
            assignment[i as usize] = c as u32;
        }
    }
    Clustering {
        samples,
        assignment,
        radius: p.radius,
        k: p.k,
        errors: err.iter().map(|&e| relative(e, p.dim, p.rms)).collect(),
        rms: p.rms,
        noise: p.noise,
        ill_conditioned,
        rounds,
        evaluations,
        loo,
        budget_limited,
    }
}
