//! Tests of the clustering: the bound, exactness at samples, equality with a straightforward
//! reference (full re-evaluation with brute-force neighbours), thread-count independence, and
//! the noise estimate and noise-aware bound.

use super::*;
use crate::rng::Rng;

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

/// Standard normal deviates (Box–Muller) from a fixture stream.
fn gauss(rng: &mut Rng) -> f32 {
    let u1 = (rng.f32() as f64).max(1e-12);
    let u2 = rng.f32() as f64;
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// `synthetic` plus independent Gaussian noise of relative RMS `sigma` on every coefficient.
fn noisy(n: usize, seed: u64, sigma: f32) -> (Vec<[f32; 3]>, Vec<f32>, Vec<f32>) {
    let (pos, truth) = synthetic(n, seed);
    let rms = (truth.iter().map(|v| (v * v) as f64).sum::<f64>() / truth.len() as f64).sqrt();
    let mut rng = Rng::new(seed ^ 0xabcd);
    let vals = truth
        .iter()
        .map(|v| v + sigma * rms as f32 * gauss(&mut rng))
        .collect();
    (pos, vals, truth)
}

/// The straightforward algorithm: every round, every instance's k nearest samples by brute force
/// and its error from scratch.
fn reference(pos: &[[f32; 3]], vals: &[f32], opts: &ClusterOptions) -> Clustering {
    let (p, loo) = prepare(pos, vals, 96, opts);
    let all: Vec<u32> = (0..pos.len() as u32).collect();
    let mut samples = vec![representative(pos, &all)];
    let mut clusters = vec![all];
    let mut rounds = 1;
    let mut s = Scratch::default();
    loop {
        let (mut err, mut wsq) = (Vec::new(), Vec::new());
        let mut ill = 0;
        for (i, x) in pos.iter().enumerate() {
            let mut by_dist: Vec<(f32, u32)> = samples
                .iter()
                .map(|&j| (dist2(pos[j as usize], *x), j))
                .collect();
            by_dist.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let nb: Vec<u32> = by_dist.iter().take(p.k).map(|t| t.1).collect();
            let e = instance_error(&p, i, &nb, &mut s);
            err.push(e.e);
            wsq.push(e.wsq);
            ill += e.ill as usize;
        }
        let split = select_splits(&p, &clusters, &err, &wsq, opts.split_fraction, usize::MAX);
        if split.is_empty() {
            return finish(&p, clusters, samples, &err, ill, rounds, 0, loo, false);
        }
        apply_splits(pos, &mut clusters, &mut samples, &split);
        rounds += 1;
    }
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
        let fresh = evaluate_all(&pos, &vals, 96, &c.samples, c.radius, c.k);
        for (i, &e) in fresh.iter().enumerate() {
            assert!(
                relative(e, 96, c.rms) <= bound * 1.001 + 1e-6,
                "instance {i}"
            );
            assert!((relative(e, 96, c.rms) - c.errors[i]).abs() < 1e-4 * bound);
        }
    }
}

#[test]
fn incremental_equals_full_reference() {
    let (pos, vals) = synthetic(900, 21);
    let (npos, nvals, _) = noisy(700, 5, 0.01);
    let cases = [
        (
            ClusterOptions {
                error: 0.02,
                ..Default::default()
            },
            false,
        ),
        (
            ClusterOptions {
                error: 0.01,
                k: Some(4),
                radius: Some(3.0),
                split_fraction: 1.0,
                ..Default::default()
            },
            false,
        ),
        (
            ClusterOptions {
                error: 0.005,
                k: Some(12),
                split_fraction: 0.3,
                ..Default::default()
            },
            false,
        ),
        (
            ClusterOptions {
                error: 0.01,
                noise: Noise::Estimate,
                ..Default::default()
            },
            true,
        ),
    ];
    for (opts, use_noisy) in cases {
        let (p, v) = if use_noisy {
            (&npos, &nvals)
        } else {
            (&pos, &vals)
        };
        let mut fast = cluster_envmaps(p, v, 96, &opts);
        let slow = reference(p, v, &opts);
        assert!(
            fast.rounds > 3 && fast.samples.len() > 10,
            "{opts:?}: too easy a case"
        );
        assert!(
            fast.evaluations < fast.rounds * p.len(),
            "{opts:?}: nothing was cached"
        );
        fast.evaluations = 0;
        assert_eq!(fast, slow, "{opts:?}");
    }
}

#[test]
fn deterministic_across_thread_counts() {
    let (pos, vals, _) = noisy(1500, 4, 0.005);
    let opts = ClusterOptions {
        error: 0.01,
        noise: Noise::Estimate,
        ..Default::default()
    };
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| cluster_envmaps(&pos, &vals, 96, &opts))
    };
    let one = run(1);
    assert!(one.samples.len() > 10);
    assert_eq!(one, run(2));
    assert_eq!(one, run(5));
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

#[test]
fn noise_estimate_recovers_known_noise() {
    let (pos, clean) = synthetic(6000, 9);
    assert!(estimate_noise(&pos, &clean, 96) < 0.002);
    for sigma in [0.005f32, 0.01, 0.03] {
        let (pos, vals, _) = noisy(6000, 9, sigma);
        let est = estimate_noise(&pos, &vals, 96);
        assert!(
            (est / sigma - 1.0).abs() < 0.15,
            "σ {sigma}: estimated {est}"
        );
    }
}

#[test]
fn noise_aware_bound_compresses_noisy_maps_and_meets_the_bound_on_the_field() {
    let (pos, vals, truth) = noisy(2000, 13, 0.01);
    let plain = ClusterOptions {
        error: 0.01,
        k: Some(8),
        radius: Some(5.0),
        ..Default::default()
    };
    let blind = cluster_envmaps(&pos, &vals, 96, &plain);
    // A bound at the noise level cannot compress: most instances become samples.
    assert!(blind.samples.len() > 1000, "{}", blind.samples.len());
    let aware = cluster_envmaps(
        &pos,
        &vals,
        96,
        &ClusterOptions {
            noise: Noise::Estimate,
            ..plain
        },
    );
    assert!(aware.samples.len() < 300, "{}", aware.samples.len());
    assert!((aware.noise / 0.01 - 1.0).abs() < 0.15, "{}", aware.noise);
    // The clustering resolves the noise-free field: reconstructing it from the noise-free values
    // at the same samples meets the bound in the RMS. Per instance the test is one of expectation:
    // the noise part of an instance's error (σ²(1 + Σw²), Σw² ≤ 1) fluctuates with a relative
    // spread of sqrt(2/96), so the worst instance may exceed E by up to ~4 spreads.
    let e = evaluate_all(&pos, &truth, 96, &aware.samples, aware.radius, aware.k);
    let rel: Vec<f32> = e.iter().map(|&x| relative(x, 96, aware.rms)).collect();
    let rms = (rel.iter().map(|r| (r * r) as f64).sum::<f64>() / rel.len() as f64).sqrt();
    assert!(rms <= 0.01, "field RMS error {rms}");
    let margin = (0.01f64.powi(2) + 4.0 * (2.0f64 / 96.0).sqrt() * 0.01f64.powi(2) * 2.0).sqrt();
    let worst = rel.iter().fold(0.0f32, |m, &x| m.max(x));
    assert!((worst as f64) <= margin, "field error {worst} > {margin}");
}
