//! How right line-space soft shadows are: per receiver, the line-space visibility of a quad area
//! light against the exact visibility from obvhs shadow rays to the **same** light points, many
//! of them (`bake bench linespace --accuracy`: 64 × 64 = 4,096 stratified samples by default).
//!
//! With the same points on both sides the difference is the method's own error, not sampling
//! noise: the line space errs only towards occlusion, so a receiver may come out darker than
//! exact but never brighter (`brighter_than_exact` counts receivers where it did, and must be 0).
//! With 4,096 stratified points the exact fraction is itself within about 1/64 of the light's
//! true visible area, so `mean_abs_error` is also the error against the area integral.

use super::ntree::NTree;
use super::query::{AreaLight, ExactShadow, QueryStats, Segment};
use crate::rng::Rng;
use rayon::prelude::*;

/// `per_side²` stratified points of the light: one uniformly jittered point per cell of a
/// `per_side × per_side` grid over the quad, cells row-major (deterministic for a seed).
pub fn stratified_points(light: &AreaLight, per_side: u32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::new(seed);
    let k = per_side.max(1);
    (0..k * k)
        .map(|i| {
            let s = ((i % k) as f32 + rng.f32()) / k as f32;
            let t = ((i / k) as f32 + rng.f32()) / k as f32;
            [0, 1, 2].map(|j| light.corner[j] + s * light.edge_u[j] + t * light.edge_v[j])
        })
        .collect()
}

/// Visibility fractions of the receivers, line space and exact, on the same light points.
#[derive(Debug, Clone, PartialEq)]
pub struct Visibilities {
    pub linespace: Vec<f32>,
    pub exact: Vec<f32>,
    /// Wall seconds of each side (all threads).
    pub linespace_seconds: f64,
    pub exact_seconds: f64,
    pub stats: QueryStats,
}

/// Lit fraction of each receiver by `occluded`, over `points`.
fn fractions(
    receivers: &[[f32; 3]],
    points: &[[f32; 3]],
    offset: f32,
    occluded: impl Fn(&Segment, &mut QueryStats) -> bool + Sync,
) -> (Vec<f32>, QueryStats) {
    let per: Vec<(f32, QueryStats)> = receivers
        .par_iter()
        .map(|&p| {
            let mut st = QueryStats::default();
            let lit = points
                .iter()
                .filter(|&&q| !occluded(&Segment::between(p, q, offset), &mut st))
                .count();
            (lit as f32 / points.len().max(1) as f32, st)
        })
        .collect();
    let stats: QueryStats = per.iter().map(|(_, s)| *s).sum();
    (per.into_iter().map(|(f, _)| f).collect(), stats)
}

/// Exact visibility of every receiver (obvhs rays), with the wall seconds.
pub fn exact_visibility(
    exact: &ExactShadow,
    receivers: &[[f32; 3]],
    points: &[[f32; 3]],
    offset: f32,
) -> (Vec<f32>, f64) {
    let t0 = std::time::Instant::now();
    let (ex, _) = fractions(receivers, points, offset, |s, _| exact.occluded(s));
    (ex, t0.elapsed().as_secs_f64())
}

/// Line-space visibility of every receiver, with the wall seconds and the query counters.
pub fn linespace_visibility(
    tree: &NTree,
    receivers: &[[f32; 3]],
    points: &[[f32; 3]],
    offset: f32,
) -> (Vec<f32>, f64, QueryStats) {
    let t0 = std::time::Instant::now();
    let (ls, stats) = fractions(receivers, points, offset, |s, st| {
        tree.segment_occluded(s, st)
    });
    (ls, t0.elapsed().as_secs_f64(), stats)
}

/// Both sides' visibility for every receiver.
pub fn measure_visibility(
    tree: &NTree,
    exact: &ExactShadow,
    receivers: &[[f32; 3]],
    points: &[[f32; 3]],
    offset: f32,
) -> Visibilities {
    let (ex, exact_seconds) = exact_visibility(exact, receivers, points, offset);
    let (ls, linespace_seconds, stats) = linespace_visibility(tree, receivers, points, offset);
    Visibilities {
        linespace: ls,
        exact: ex,
        linespace_seconds,
        exact_seconds,
        stats,
    }
}

/// Error of line-space visibility against exact visibility (stable JSON keys).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct AccuracyReport {
    pub receivers: usize,
    pub light_samples: usize,
    /// Mean over receivers of |line space − exact|.
    pub mean_abs_error: f64,
    pub max_abs_error: f64,
    /// Share of receivers darker than exact by more than 0.1.
    pub darker_share: f64,
    /// Receivers brighter than exact (must be 0: the error is one-sided).
    pub brighter_than_exact: usize,
    /// Receivers whose fraction differs at all.
    pub differing: usize,
    /// Mean visibility on each side.
    pub mean_linespace: f64,
    pub mean_exact: f64,
}

/// Compares the two sides of [`measure_visibility`].
pub fn compare(v: &Visibilities, light_samples: usize) -> AccuracyReport {
    let n = v.exact.len();
    let pairs = || {
        v.linespace
            .iter()
            .zip(&v.exact)
            .map(|(&l, &e)| (l as f64, e as f64))
    };
    let share = |k: usize| if n == 0 { 0.0 } else { k as f64 / n as f64 };
    let mean = |x: f64| if n == 0 { 0.0 } else { x / n as f64 };
    AccuracyReport {
        receivers: n,
        light_samples,
        mean_abs_error: mean(pairs().map(|(l, e)| (l - e).abs()).sum()),
        max_abs_error: pairs().map(|(l, e)| (l - e).abs()).fold(0.0, f64::max),
        darker_share: share(pairs().filter(|(l, e)| e - l > 0.1).count()),
        brighter_than_exact: pairs().filter(|(l, e)| l > e).count(),
        differing: pairs().filter(|(l, e)| l != e).count(),
        mean_linespace: mean(pairs().map(|(l, _)| l).sum()),
        mean_exact: mean(pairs().map(|(_, e)| e).sum()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linespace::ntree::{NTreeOptions, Refine, build_ntree};
    use crate::linespace::shaft::ShaftTable;
    use std::sync::Arc;

    #[test]
    fn stratified_points_cover_each_cell_once() {
        let light = AreaLight {
            corner: [1.0, 2.0, 3.0],
            edge_u: [4.0, 0.0, 0.0],
            edge_v: [0.0, 2.0, 0.0],
            samples: 1,
        };
        let pts = stratified_points(&light, 8, 3);
        assert_eq!(pts.len(), 64);
        for (i, p) in pts.iter().enumerate() {
            let (s, t) = ((p[0] - 1.0) / 4.0 * 8.0, (p[1] - 2.0) / 2.0 * 8.0);
            assert_eq!((s.floor() as usize, t.floor() as usize), (i % 8, i / 8));
            assert_eq!(p[2], 3.0);
        }
        assert_eq!(pts, stratified_points(&light, 8, 3));
    }

    /// A plate over a ground quad under a light: every refinement is one-sided, the exact one
    /// has no error, and the coarser ones are darker.
    #[test]
    fn accuracy_is_one_sided_and_exact_refinement_has_no_error() {
        let ground = [
            [-5.0, -5.0, 0.0],
            [5.0, -5.0, 0.0],
            [5.0, 5.0, 0.0],
            [-5.0, 5.0, 0.0],
        ];
        let plate = [
            [-1.0, -1.0, 2.0],
            [1.0, -1.0, 2.0],
            [1.0, 1.0, 2.0],
            [-1.0, 1.0, 2.0],
        ];
        let quad = |q: [[f32; 3]; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]];
        let tris: Vec<[[f32; 3]; 3]> = quad(ground).into_iter().chain(quad(plate)).collect();
        let mut t = build_ntree(
            &tris,
            &NTreeOptions {
                n: 4,
                depth: 2,
                cubic_cells: true,
            },
            &Arc::new(ShaftTable::build(4)),
        )
        .unwrap();
        let light = AreaLight {
            corner: [-1.0, -1.0, 4.0],
            edge_u: [2.0, 0.0, 0.0],
            edge_v: [0.0, 2.0, 0.0],
            samples: 1,
        };
        let receivers: Vec<[f32; 3]> = (0..200)
            .map(|i| {
                [
                    -3.0 + 6.0 * (i % 20) as f32 / 19.0,
                    -3.0 + 6.0 * (i / 20) as f32 / 9.0,
                    0.0,
                ]
            })
            .collect();
        let pts = stratified_points(&light, 16, 1);
        let exact = ExactShadow::new(&tris);
        let mut errors = Vec::new();
        for refine in [Refine::Shaft, Refine::Cells, Refine::Exact] {
            t.refine = refine;
            let r = compare(&measure_visibility(&t, &exact, &receivers, &pts, 1e-3), 256);
            assert_eq!(r.brighter_than_exact, 0, "{refine:?}: {r:?}");
            assert_eq!(r.receivers, 200);
            errors.push(r.mean_abs_error);
            if refine == Refine::Exact {
                assert_eq!(r.differing, 0, "{r:?}");
            }
            assert!(r.mean_exact > 0.2 && r.mean_exact < 0.95, "{r:?}");
        }
        assert!(
            errors[0] >= errors[1] && errors[1] >= errors[2],
            "{errors:?}"
        );
    }
}
