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
use super::kdtree::{KdTree, dist2};
use rayon::prelude::*;

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
}

impl ClusterOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: ClusterOptions = ClusterOptions {
        error: 0.02,
        k: None,
        radius: None,
        split_fraction: 0.5,
        noise: Noise::None,
    };
}

impl Default for ClusterOptions {
    fn default() -> Self {
        Self::DEFAULT
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
    /// Relative noise level the bound allowed for (0 without [`Noise`]).
    pub noise: f32,
    /// Reconstructions that fell back to the nearest sample because the system was ill-conditioned.
    pub ill_conditioned: usize,
    pub rounds: usize,
    /// Instance evaluations (reconstruction + error) over all rounds.
    pub evaluations: usize,
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
    pub fn exceeds(&self, e: f64, wsq: f64) -> bool {
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
        let split = select_splits(&p, &clusters, &cache.err, &cache.wsq, opts.split_fraction);
        if split.is_empty() {
            return finish(
                &p,
                clusters,
                samples,
                &cache.err,
                cache.ill_count(),
                rounds,
                cache.evaluations,
                loo,
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
    let rms = ((values.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()
        / values.len().max(1) as f64)
        .sqrt()) as f32;
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
/// ascending cluster order.
pub(crate) fn select_splits(
    p: &Problem,
    clusters: &[Vec<u32>],
    err: &[f64],
    wsq: &[f64],
    fraction: f32,
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
    if violating.is_empty() {
        return Vec::new();
    }
    violating.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let take = ((violating.len() as f32 * fraction).ceil() as usize).clamp(1, violating.len());
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
    }
}

/// Per instance: its k nearest samples, the distance to the k-th, its squared error.
struct NeighbourCache {
    k: usize,
    /// k sample instance indices per instance, nearest first; `u32::MAX` pads short lists.
    nbrs: Vec<u32>,
    /// Squared distance to the k-th nearest sample (infinite while fewer than k samples exist).
    kth: Vec<f32>,
    err: Vec<f64>,
    /// Σ w_j² of each instance's weights.
    wsq: Vec<f64>,
    ill: Vec<bool>,
    /// Marks the removed samples of the current update (cleared after use).
    removed_mark: Vec<bool>,
    /// Each instance's place on the Morton curve: evaluations run in this order, so that
    /// consecutive ones share neighbour sets and factorizations.
    rank: Vec<u32>,
    evaluations: usize,
}

impl NeighbourCache {
    fn new(positions: &[[f32; 3]], k: usize) -> Self {
        let n = positions.len();
        let mut rank = vec![0u32; n];
        for (z, &i) in super::kdtree::morton_order(positions).iter().enumerate() {
            rank[i as usize] = z as u32;
        }
        NeighbourCache {
            rank,
            k,
            nbrs: vec![u32::MAX; n * k],
            kth: vec![f32::INFINITY; n],
            err: vec![0.0; n],
            wsq: vec![0.0; n],
            ill: vec![false; n],
            removed_mark: vec![false; n],
            evaluations: 0,
        }
    }

    fn ill_count(&self) -> usize {
        self.ill.iter().filter(|&&b| b).count()
    }

    /// Re-evaluates the instances whose neighbour lists can have changed.
    fn update(&mut self, p: &Problem, samples: &[u32], removed: &[u32], added: &[u32]) {
        let mut dirty = self.dirty(p.positions, removed, added);
        dirty.par_sort_unstable_by_key(|&i| self.rank[i as usize]);
        let tree = SampleTree::new(p.positions, samples);
        let k = self.k;
        let fresh: Vec<(Vec<u32>, f32, InstanceError)> = dirty
            .par_iter()
            .map_init(Scratch::default, |s, &i| {
                let x = p.positions[i as usize];
                let (ids, kth) = tree.nearest(x, k, s.prev, &mut s.nb);
                s.prev = s.nb.last().map(|&(d2, _)| (x, d2));
                let e = instance_error(p, i as usize, &ids, s);
                (ids, kth, e)
            })
            .collect();
        self.evaluations += dirty.len();
        for (&i, (ids, kth, e)) in dirty.iter().zip(fresh) {
            let i = i as usize;
            let slot = &mut self.nbrs[i * k..(i + 1) * k];
            slot.fill(u32::MAX);
            slot[..ids.len()].copy_from_slice(&ids);
            self.kth[i] = kth;
            self.err[i] = e.e;
            self.wsq[i] = e.wsq;
            self.ill[i] = e.ill;
        }
    }

    /// Instances that used a removed sample or have an added one within their k-th distance.
    fn dirty(&mut self, positions: &[[f32; 3]], removed: &[u32], added: &[u32]) -> Vec<u32> {
        for &r in removed {
            self.removed_mark[r as usize] = true;
        }
        let added_tree = SampleTree::new(positions, added);
        let (k, nbrs, kth, mark) = (self.k, &self.nbrs, &self.kth, &self.removed_mark);
        let dirty: Vec<u32> = (0..positions.len() as u32)
            .into_par_iter()
            .map_init(Vec::new, |nb, i| {
                let iu = i as usize;
                let used_removed = nbrs[iu * k..(iu + 1) * k]
                    .iter()
                    .any(|&s| s != u32::MAX && mark[s as usize]);
                let closer = !added.is_empty() && {
                    added_tree.tree.nearest(positions[iu], 1, nb);
                    nb[0].0 <= kth[iu]
                };
                (used_removed || closer).then_some(i)
            })
            .flatten()
            .collect();
        for &r in removed {
            self.removed_mark[r as usize] = false;
        }
        dirty
    }
}

/// A k-d tree over sample instances, built in instance-index order so that the tree's ties (by
/// its own index) are ties by instance index, whatever the cluster numbering.
struct SampleTree {
    tree: KdTree,
    ids: Vec<u32>,
}

impl SampleTree {
    fn new(positions: &[[f32; 3]], samples: &[u32]) -> Self {
        let mut ids = samples.to_vec();
        ids.sort_unstable();
        let pts: Vec<[f32; 3]> = ids.iter().map(|&s| positions[s as usize]).collect();
        SampleTree {
            tree: KdTree::build(&pts),
            ids,
        }
    }

    /// The k nearest samples (instance indices, nearest first) and the k-th squared distance
    /// (infinite when there are fewer than k samples); `prev` is the last query's point and
    /// k-th squared distance, if any (see [`KdTree::nearest_after`]).
    fn nearest(
        &self,
        x: [f32; 3],
        k: usize,
        prev: Option<([f32; 3], f32)>,
        nb: &mut Vec<(f32, u32)>,
    ) -> (Vec<u32>, f32) {
        self.tree.nearest_after(x, k, prev, nb);
        let kth = if nb.len() < k {
            f32::INFINITY
        } else {
            nb[k - 1].0
        };
        (nb.iter().map(|&(_, j)| self.ids[j as usize]).collect(), kth)
    }
}

/// Per-thread buffers of [`instance_error`].
#[derive(Default)]
pub(crate) struct Scratch {
    nb: Vec<(f32, u32)>,
    /// The previous query's point and k-th squared distance (a bound for the next search).
    prev: Option<([f32; 3], f32)>,
    solver: MultiquadricSolver,
    w: Vec<f64>,
    acc: Vec<f64>,
}

/// An instance's reconstruction error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct InstanceError {
    /// Squared error summed over the coefficients.
    pub e: f64,
    /// Σ w_j² of the weights.
    pub wsq: f64,
    /// The system was ill-conditioned; the nearest sample was used.
    pub ill: bool,
}

/// Reconstruction error of instance i from the given samples (instance indices, nearest first).
pub(crate) fn instance_error(p: &Problem, i: usize, nb: &[u32], s: &mut Scratch) -> InstanceError {
    if nb.is_empty() {
        return InstanceError {
            e: 0.0,
            wsq: 0.0,
            ill: false,
        };
    }
    let x = p.positions[i];
    let pos = |j: u32| p.positions[j as usize];
    let ill = s
        .solver
        .weights(nb, pos, x, p.radius, true, &mut s.w)
        .is_err();
    if ill {
        s.w.clear();
        s.w.resize(nb.len(), 0.0);
        s.w[0] = 1.0;
    }
    // Accumulate sample by sample: each sample's coefficients are contiguous.
    let dim = p.dim;
    s.acc.clear();
    s.acc.resize(dim, 0.0);
    for (&j, &wj) in nb.iter().zip(&s.w) {
        let v = &p.values[j as usize * dim..(j as usize + 1) * dim];
        for (a, &x) in s.acc.iter_mut().zip(v) {
            *a += wj * x as f64;
        }
    }
    let own = &p.values[i * dim..(i + 1) * dim];
    let e = s
        .acc
        .iter()
        .zip(own)
        .map(|(&rec, &o)| ((rec as f32 - o) as f64).powi(2))
        .sum();
    let wsq = s.w.iter().map(|w| w * w).sum();
    InstanceError { e, wsq, ill }
}

pub(crate) fn relative(err: f64, dim: usize, rms: f32) -> f32 {
    if rms == 0.0 {
        0.0
    } else {
        ((err / dim as f64).sqrt() / rms as f64) as f32
    }
}

/// Estimates the relative RMS noise per coefficient from the data. For a deterministic subset of
/// at most 4,000 instances, a plane (in x and y: instances stand on a terrain) is fitted by least
/// squares to the values of the instance's 8 nearest neighbours and predicts the instance's value
/// as Σ a_j v_j. A smooth field leaves only a second-order residual; independent noise σ leaves
/// E[residual²] = σ²(1 + Σ a_j²). Hence σ² ≈ Σ residual² / Σ (1 + Σ a_j²), summed over instances
/// and coefficients. Returned relative to the RMS of all coefficients. (The estimator's own
/// variance cannot be used instead: the baking uses a quasi-random direction set, whose error is
/// not that of independent samples.)
pub fn estimate_noise(positions: &[[f32; 3]], values: &[f32], dim: usize) -> f32 {
    let n = positions.len();
    if n < 4 || dim == 0 {
        return 0.0;
    }
    let rms2 = values.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / values.len() as f64;
    let tree = KdTree::build(positions);
    let stride = (n / 4000).max(1);
    let parts: Vec<(f64, f64)> = (0..n)
        .into_par_iter()
        .step_by(stride)
        .map_init(Vec::new, |nb, i| {
            tree.nearest(positions[i], 9, nb);
            nb.retain(|&(_, j)| j as usize != i);
            let Some(a) = plane_prediction_weights(positions, i, nb) else {
                return (0.0, 0.0);
            };
            let res2: f64 = (0..dim)
                .map(|c| {
                    let pred: f64 = nb
                        .iter()
                        .zip(&a)
                        .map(|(&(_, j), aj)| aj * values[j as usize * dim + c] as f64)
                        .sum();
                    (values[i * dim + c] as f64 - pred).powi(2)
                })
                .sum();
            (
                res2,
                dim as f64 * (1.0 + a.iter().map(|x| x * x).sum::<f64>()),
            )
        })
        .collect();
    let (res, lev) = parts.iter().fold((0.0, 0.0), |s, p| (s.0 + p.0, s.1 + p.1));
    if lev == 0.0 || rms2 == 0.0 {
        0.0
    } else {
        ((res / lev) / rms2).sqrt() as f32
    }
}

/// Weights a_j with which the least-squares plane v = c0 + c1·dx + c2·dy through the neighbours
/// predicts the value at instance i: a = e0ᵀ (XᵀX)⁻¹ Xᵀ. None when the neighbours are collinear.
fn plane_prediction_weights(
    positions: &[[f32; 3]],
    i: usize,
    nb: &[(f32, u32)],
) -> Option<Vec<f64>> {
    let o = positions[i];
    let rows: Vec<[f64; 3]> = nb
        .iter()
        .map(|&(_, j)| {
            let p = positions[j as usize];
            [1.0, (p[0] - o[0]) as f64, (p[1] - o[1]) as f64]
        })
        .collect();
    let mut xtx = vec![0.0f64; 9];
    for r in &rows {
        for a in 0..3 {
            for b in 0..3 {
                xtx[a * 3 + b] += r[a] * r[b];
            }
        }
    }
    let mut u = vec![1.0, 0.0, 0.0];
    super::interp::solve_in_place(&mut xtx, &mut u, 3).ok()?;
    Some(
        rows.iter()
            .map(|r| r[0] * u[0] + r[1] * u[1] + r[2] * u[2])
            .collect(),
    )
}

/// Squared reconstruction error of every instance from the given samples (a fresh
/// interpolator: the check of a finished clustering).
pub fn evaluate_all(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    samples: &[u32],
    radius: f32,
    k: usize,
) -> Vec<f64> {
    let (pts, vals) = gather_samples(positions, values, dim, samples);
    let ip = Interpolator::new(&pts, &vals, dim, radius, k);
    (0..positions.len())
        .into_par_iter()
        .map_init(
            || vec![0.0f32; dim],
            |out, i| {
                ip.reconstruct(positions[i], out);
                out.iter()
                    .zip(&values[i * dim..(i + 1) * dim])
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum::<f64>()
            },
        )
        .collect()
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

/// Chooses (k, R) by cross-validation at a sample density near the clustering's: every t-th
/// instance (t = 16 for large sets) acts as a sample, and a deterministic subset of the other
/// instances is reconstructed from its k nearest such samples; the candidate with the smallest
/// relative RMS error wins. (Validating at the instances' own density picks an R suited to
/// neighbours a metre apart, not to cluster samples ten metres apart.)
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
    let t = (n / 200).clamp(1, 16);
    let thin: Vec<u32> = (0..n as u32).step_by(t).collect();
    let thin_pos: Vec<[f32; 3]> = thin.iter().map(|&i| positions[i as usize]).collect();
    let tree = KdTree::build(&thin_pos);
    let m = thin.len();
    let mut nb = Vec::new();
    let mut spacing: Vec<f32> = thin_pos
        .iter()
        .step_by((m / 500).max(1))
        .map(|p| {
            tree.nearest(*p, 2, &mut nb);
            nb.get(1).map_or(0.0, |x| x.0.sqrt())
        })
        .collect();
    spacing.sort_by(f32::total_cmp);
    let s = spacing[spacing.len() / 2].max(1e-3);
    let queries: Vec<usize> = (0..n)
        .filter(|i| t == 1 || i % t != 0)
        .step_by((n / 500).max(1))
        .collect();
    let ks: Vec<usize> = match opts.k {
        Some(k) => vec![k.clamp(1, m - 1)],
        None => [4usize, 8, 16].iter().map(|&k| k.min(m - 1)).collect(),
    };
    let rs: Vec<f32> = match opts.radius {
        Some(r) => vec![r],
        None => [0.5f32, 1.0, 2.0, 4.0].iter().map(|f| f * s).collect(),
    };
    let ctx = Validation {
        tree: &tree,
        ids: &thin,
        positions,
        values,
        dim,
    };
    let mut scores = Vec::new();
    for &k in &ks {
        for &r in &rs {
            let err: f64 = queries
                .par_iter()
                .map(|&i| ctx.error(i, k, r))
                .collect::<Vec<f64>>()
                .iter()
                .sum();
            scores.push((k, r, relative(err / queries.len() as f64, dim, rms)));
        }
    }
    let best = scores
        .iter()
        .fold(scores[0], |b, &c| if c.2 < b.2 { c } else { b });
    (best.0, best.1, scores)
}

/// The thinned sample set of [`choose_parameters`].
struct Validation<'a> {
    tree: &'a KdTree,
    /// Instance index of each tree point.
    ids: &'a [u32],
    positions: &'a [[f32; 3]],
    values: &'a [f32],
    dim: usize,
}

impl Validation<'_> {
    /// Squared error of instance i reconstructed from its k nearest thinned samples other than
    /// itself.
    fn error(&self, i: usize, k: usize, r: f32) -> f64 {
        let mut nb = Vec::new();
        self.tree.nearest(self.positions[i], k + 1, &mut nb);
        let mut ids: Vec<usize> = nb
            .iter()
            .map(|&(_, j)| self.ids[j as usize] as usize)
            .filter(|&j| j != i)
            .collect();
        ids.truncate(k);
        let xs: Vec<[f32; 3]> = ids.iter().map(|&j| self.positions[j]).collect();
        let mut w = Vec::new();
        if super::interp::multiquadric_weights(&xs, self.positions[i], r, true, &mut w).is_err() {
            w = vec![0.0; ids.len()];
            w[0] = 1.0;
        }
        let dim = self.dim;
        let own = &self.values[i * dim..(i + 1) * dim];
        (0..dim)
            .map(|c| {
                let rec: f64 = ids
                    .iter()
                    .zip(&w)
                    .map(|(&j, wj)| wj * self.values[j * dim + c] as f64)
                    .sum();
                (rec - own[c] as f64).powi(2)
            })
            .sum()
    }
}

#[cfg(test)]
#[path = "cluster_tests.rs"]
mod tests;
