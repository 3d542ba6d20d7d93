//! The per-instance reconstruction error: each instance's k nearest samples (cached across
//! rounds), its multiquadric error, the noise estimate, and the evaluation of every instance.

use super::*;

/// Per instance: its k nearest samples, the distance to the k-th, its squared error.
pub(super) struct NeighbourCache {
    pub(super) k: usize,
    /// k sample instance indices per instance, nearest first; `u32::MAX` pads short lists.
    pub(super) nbrs: Vec<u32>,
    /// Squared distance to the k-th nearest sample (infinite while fewer than k samples exist).
    pub(super) kth: Vec<f32>,
    pub(super) err: Vec<f64>,
    /// Σ w_j² of each instance's weights.
    pub(super) wsq: Vec<f64>,
    pub(super) ill: Vec<bool>,
    /// Marks the removed samples of the current update (cleared after use).
    pub(super) removed_mark: Vec<bool>,
    /// Each instance's place on the Morton curve: evaluations run in this order, so that
    /// consecutive ones share neighbour sets and factorizations.
    pub(super) rank: Vec<u32>,
    pub(super) evaluations: usize,
}

impl NeighbourCache {
    pub(super) fn new(positions: &[[f32; 3]], k: usize) -> Self {
        let n = positions.len();
        let mut rank = vec![0u32; n];
        for (z, &i) in crate::kdtree::morton_order(positions).iter().enumerate() {
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

    pub(super) fn ill_count(&self) -> usize {
        self.ill.iter().filter(|&&b| b).count()
    }

    /// Re-evaluates the instances whose neighbour lists can have changed.
    pub(super) fn update(&mut self, p: &Problem, samples: &[u32], removed: &[u32], added: &[u32]) {
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
    pub(super) fn dirty(
        &mut self,
        positions: &[[f32; 3]],
        removed: &[u32],
        added: &[u32],
    ) -> Vec<u32> {
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
pub(super) struct SampleTree {
    pub(super) tree: KdTree,
    pub(super) ids: Vec<u32>,
}

impl SampleTree {
    pub(super) fn new(positions: &[[f32; 3]], samples: &[u32]) -> Self {
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
    pub(super) fn nearest(
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
    pub(super) nb: Vec<(f32, u32)>,
    /// The previous query's point and k-th squared distance (a bound for the next search).
    pub(super) prev: Option<([f32; 3], f32)>,
    pub(super) solver: MultiquadricSolver,
    pub(super) w: Vec<f64>,
    pub(super) acc: Vec<f64>,
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
pub(super) fn plane_prediction_weights(
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
    crate::envmap::interp::solve_in_place(&mut xtx, &mut u, 3).ok()?;
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
