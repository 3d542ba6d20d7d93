//! The reconstruction parameters (k, R), chosen by cross-validation at the clustering's
//! sample density.

use super::*;

/// Chooses (k, R) by cross-validation at a sample density near the clustering's: every t-th
/// instance (t = 16 for large sets) acts as a sample, and a deterministic subset of the other
/// instances is reconstructed from its k nearest such samples; the candidate with the smallest
/// relative RMS error wins. (Validating at the instances' own density picks an R suited to
/// neighbours a metre apart, not to cluster samples ten metres apart.)
pub(super) fn choose_parameters(
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
pub(super) struct Validation<'a> {
    pub(super) tree: &'a KdTree,
    /// Instance index of each tree point.
    pub(super) ids: &'a [u32],
    pub(super) positions: &'a [[f32; 3]],
    pub(super) values: &'a [f32],
    pub(super) dim: usize,
}

impl Validation<'_> {
    /// Squared error of instance i reconstructed from its k nearest thinned samples other than
    /// itself.
    pub(super) fn error(&self, i: usize, k: usize, r: f32) -> f64 {
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
        if crate::envmap::interp::multiquadric_weights(&xs, self.positions[i], r, true, &mut w)
            .is_err()
        {
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
