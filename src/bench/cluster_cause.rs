//! `bake bench cluster --cause PACK`: why the pipeline's traced environment maps do not cluster
//! (issue 20, item 1). On a baked pack's own scene (instances, terrain, sky, sun) the maps are
//! traced twice with half the rays each and independent per-instance rotations (two seeds), in
//! the world frame, and measured:
//! - the Monte-Carlo noise: per instance σ_i² = Σ_c (A−B)² / (4·dim) is the noise variance of the
//!   mean (A+B)/2 (independent halves), reported relative to the RMS of all coefficients;
//! - the difference between neighbours at about 1, 2, 5 and 10 m (all pairs within ±25 % of the
//!   distance), raw and with the two instances' noise removed (D² − σ_i² − σ_j²);
//! - how each bound behaves: the clustering of (A+B)/2 with the per-instance bound without and
//!   with the noise-aware allowance (measured σ, and σ estimated from the data), and for fixed
//!   sample sets (every t-th instance) the per-instance maximum, the worst cluster's summed
//!   error (eq. 4.7, as the cluster's RMS), the scene RMS, and the scene RMS with the noise the
//!   reconstruction cannot remove subtracted.

use super::Report;
use crate::envmap::cluster::{self, ClusterOptions, Noise};
use crate::envmap::section::{DIM, flatten};
use crate::error::Result;
use rayon::prelude::*;
use serde_json::json;
use std::path::Path;

/// Options of [`measure_cause`].
#[derive(Debug, Clone, Copy)]
pub struct CauseOptions {
    /// Rays per instance of the full estimate (each half gets half of them).
    pub samples: u32,
    /// The per-instance error bound the clusterings use.
    pub error: f32,
    /// Rays of the reference maps of a subset of (at most about 200) instances.
    pub ref_samples: u32,
}

/// Instance positions and two estimates of their maps (flattened, `DIM` per instance).
pub type HalfEstimates = (Vec<[f32; 3]>, Vec<f32>, Vec<f32>);

/// The two half-sample estimates of a pack's scene, world frame, flattened (`DIM` per instance),
/// and for the instances `subset` a reference traced with `ref_samples` rays (a third seed).
pub fn half_estimates(
    pack: &crate::pack::Pack,
    samples: u32,
    subset: &[usize],
    ref_samples: u32,
) -> Result<(HalfEstimates, Vec<f32>)> {
    let light = crate::lightmap::scene_lighting(pack)?;
    let scene = crate::trace::pack_scene::trace_scene(pack)?;
    let n = scene.instance_count;
    let rot: Vec<f32> = scene
        .instances
        .items
        .iter()
        .map(|i| i.rotation_deg)
        .collect();
    let world = |maps: Vec<crate::envmap::bake::InstanceMaps>, rot: &[f32]| {
        let (mut sky, mut sun): (Vec<_>, Vec<_>) = maps.into_iter().unzip();
        crate::envmap::to_world_frame(&mut sky, &mut sun, rot);
        flatten(&sky, &sun)
    };
    let opts = |samples: u32, seed: u64| crate::envmap::bake::EnvmapOptions {
        samples: samples.max(1),
        seed,
        // One N-point set per half (the difference of the two halves is the noise).
        noise_estimate: false,
        ..crate::envmap::bake::EnvmapOptions::DEFAULT
    };
    let half = |seed: u64| -> Result<Vec<f32>> {
        let maps = crate::envmap::instance_maps(&scene, &light, &opts(samples / 2, seed), 0..n)?;
        Ok(world(maps, &rot))
    };
    let a = half(0x00a1_1ce5)?;
    let b = half(0x00b0_b005)?;
    let ro = opts(ref_samples, 0x0072_ef00);
    let mut reference: Vec<crate::envmap::bake::InstanceMaps> = Vec::new();
    for &i in subset {
        reference.extend(crate::envmap::instance_maps(&scene, &light, &ro, i..i + 1)?);
    }
    let sub_rot: Vec<f32> = subset.iter().map(|&i| rot[i]).collect();
    let reference = world(reference, &sub_rot);
    let pos = scene.instances.items.iter().map(|i| i.position).collect();
    Ok(((pos, a, b), reference))
}

/// Per-instance noise variance of the mean (A+B)/2 (per coefficient).
pub fn noise_variance(a: &[f32], b: &[f32], dim: usize) -> Vec<f64> {
    a.par_chunks(dim)
        .zip(b.par_chunks(dim))
        .map(|(x, y)| {
            x.iter()
                .zip(y)
                .map(|(p, q)| ((p - q) as f64).powi(2))
                .sum::<f64>()
                / (4.0 * dim as f64)
        })
        .collect()
}

/// Neighbour differences of `v` at distance `d` (pairs within [0.75 d, 1.25 d] in the plane):
/// (pairs, mean squared difference per coefficient, mean of σ_i² + σ_j²). Brute force over pairs.
pub fn pair_differences(
    pos: &[[f32; 3]],
    v: &[f32],
    var: &[f64],
    dim: usize,
    d: f32,
) -> (usize, f64, f64) {
    let (lo, hi) = ((0.75 * d).powi(2), (1.25 * d).powi(2));
    let n = pos.len();
    let (pairs, diff, noise) = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut s = (0usize, 0.0f64, 0.0f64);
            for j in i + 1..n {
                let (dx, dy) = (pos[i][0] - pos[j][0], pos[i][1] - pos[j][1]);
                let r2 = dx * dx + dy * dy;
                if r2 < lo || r2 > hi {
                    continue;
                }
                let e: f64 = v[i * dim..(i + 1) * dim]
                    .iter()
                    .zip(&v[j * dim..(j + 1) * dim])
                    .map(|(p, q)| ((p - q) as f64).powi(2))
                    .sum();
                s.0 += 1;
                s.1 += e / dim as f64;
                s.2 += var[i] + var[j];
            }
            s
        })
        .reduce(|| (0, 0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    let m = pairs.max(1) as f64;
    (pairs, diff / m, noise / m)
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// The measurement (see the module doc) on the scene of a baked pack.
pub fn measure_cause(pack_path: &Path, o: &CauseOptions) -> Result<Report> {
    let pack = crate::pack::Pack::open(pack_path)?;
    let t0 = std::time::Instant::now();
    let total = crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
        .map_err(|e| crate::error::Error::invalid(pack_path, e))?
        .1
        .items
        .len();
    let subset: Vec<usize> = (0..total).step_by((total / 200).max(1)).collect();
    let ((pos, a, b), reference) = half_estimates(&pack, o.samples, &subset, o.ref_samples)?;
    let trace_seconds = t0.elapsed().as_secs_f64();
    let v: Vec<f32> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
    let n = pos.len();
    let rms = (v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let var = noise_variance(&a, &b, DIM);
    let rel = |x: f64| x.max(0.0).sqrt() / rms.max(f64::MIN_POSITIVE);
    let per_inst: Vec<f64> = var.iter().map(|&s| rel(s)).collect();
    let sigma = rel(var.iter().sum::<f64>() / n.max(1) as f64);
    let over = per_inst.iter().filter(|&&s| s > o.error as f64).count();
    let estimated = cluster::estimate_noise(&pos, &v, DIM);
    let noise = json!({
        "relative_rms": sigma, "median": quantile(per_inst.clone(), 0.5),
        "p90": quantile(per_inst.clone(), 0.9), "max": quantile(per_inst, 1.0),
        "fraction_over_error_bound": over as f64 / n.max(1) as f64,
        "estimate_noise_from_data": estimated,
    });
    let neighbours: Vec<serde_json::Value> = [1.0f32, 2.0, 5.0, 10.0]
        .iter()
        .map(|&d| {
            let (pairs, diff, nse) = pair_differences(&pos, &v, &var, DIM, d);
            json!({"distance_m": d, "pairs": pairs, "rms_difference_relative": rel(diff),
                "noise_part_relative": rel(nse), "field_difference_relative": rel(diff - nse)})
        })
        .collect();
    // The same with one scalar per instance divided out (its map's norm over the scene's mean
    // norm): how much of the neighbour difference is an overall scale (local occlusion).
    let norms: Vec<f64> = v
        .chunks(DIM)
        .map(|m| m.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt())
        .collect();
    let mean_norm = norms.iter().sum::<f64>() / n.max(1) as f64;
    let scale: Vec<f64> = norms.iter().map(|&x| (x / mean_norm).max(1e-6)).collect();
    let vs: Vec<f32> = v
        .chunks(DIM)
        .zip(&scale)
        .flat_map(|(m, &s)| m.iter().map(move |x| (*x as f64 / s) as f32))
        .collect();
    let vars: Vec<f64> = var.iter().zip(&scale).map(|(x, s)| x / (s * s)).collect();
    let scalar_spread =
        rel(scale.iter().map(|s| (s - 1.0).powi(2)).sum::<f64>() / n as f64 * rms * rms);
    let scaled: Vec<serde_json::Value> = [1.0f32, 2.0, 5.0, 10.0]
        .iter()
        .map(|&d| {
            let (pairs, diff, nse) = pair_differences(&pos, &vs, &vars, DIM, d);
            json!({"distance_m": d, "pairs": pairs, "rms_difference_relative": rel(diff),
                "noise_part_relative": rel(nse), "field_difference_relative": rel(diff - nse)})
        })
        .collect();
    // The clustering itself under the per-instance bound, without and with the noise allowance.
    let base = ClusterOptions {
        error: o.error,
        ..Default::default()
    };
    let raw = (n * DIM * 4) as f64;
    let clusterings: Vec<serde_json::Value> = [
        ("per-instance", Noise::None),
        (
            "per-instance, noise-aware (measured σ)",
            Noise::Given(sigma as f32),
        ),
        (
            "per-instance, noise-aware (σ estimated from the data)",
            Noise::Estimate,
        ),
    ]
    .iter()
    .map(|&(name, noise)| {
        let t = std::time::Instant::now();
        let c = cluster::cluster_envmaps(&pos, &v, DIM, &ClusterOptions { noise, ..base });
        let packed = c.samples.len() as f64 * (12.0 + 4.0 + DIM as f64 * 4.0);
        json!({"bound": name, "noise_relative": c.noise, "clusters": c.samples.len(),
            "compression": raw / packed, "rms_error_relative": c.rms_error(),
            "max_error_relative": c.max_error(), "k": c.k, "radius": c.radius,
            "seconds": t.elapsed().as_secs_f64()})
    })
    .collect();
    // Fixed sample sets: every t-th instance, (k, R) as the clustering would choose them.
    let (p, _) = cluster::prepare(&pos, &v, DIM, &base);
    let mut fixed = Vec::new();
    for t in [2usize, 4, 8, 16, 32] {
        let samples: Vec<u32> = (0..n as u32).step_by(t).collect();
        if samples.len() < p.k + 1 {
            continue;
        }
        let err = cluster::evaluate_all(&pos, &v, DIM, &samples, p.radius, p.k);
        let e: Vec<f64> = err.iter().map(|&x| x / DIM as f64).collect();
        // Clusters: each instance with its nearest sample (Voronoi cells).
        let stree = crate::kdtree::KdTree::build(
            &samples.iter().map(|&s| pos[s as usize]).collect::<Vec<_>>(),
        );
        let mut sum = vec![(0.0f64, 0usize); samples.len()];
        let mut nb = Vec::new();
        for (i, x) in pos.iter().enumerate() {
            stree.nearest(*x, 1, &mut nb);
            let c = &mut sum[nb[0].1 as usize];
            c.0 += e[i];
            c.1 += 1;
        }
        let cl: Vec<f64> = sum.iter().map(|&(s, m)| rel(s / m.max(1) as f64)).collect();
        let scene_ms = e.iter().sum::<f64>() / n as f64;
        // The noise a reconstruction cannot follow: the instance's own (non-samples; samples
        // reproduce themselves exactly).
        let is_sample = |i: usize| i.is_multiple_of(t);
        let own_noise: f64 = (0..n)
            .filter(|&i| !is_sample(i))
            .map(|i| var[i])
            .sum::<f64>()
            / n as f64;
        let inst: Vec<f64> = e.iter().map(|&x| rel(x)).collect();
        // Against the high-ray reference of the subset: the reconstruction from the samples.
        let (sp, sv) = cluster::gather_samples(&pos, &v, DIM, &samples);
        let ip = crate::envmap::interp::Interpolator::new(&sp, &sv, DIM, p.radius, p.k);
        let mut out = vec![0.0f32; DIM];
        let mut vs_ref = 0.0f64;
        for (r, &i) in subset.iter().enumerate() {
            ip.reconstruct(pos[i], &mut out);
            vs_ref += out
                .iter()
                .zip(&reference[r * DIM..(r + 1) * DIM])
                .map(|(x, y)| ((x - y) as f64).powi(2))
                .sum::<f64>();
        }
        let vs_ref = rel(vs_ref / (subset.len().max(1) * DIM) as f64);
        fixed.push(json!({
            "every": t, "samples": samples.len(), "compression": raw / (samples.len() as f64 * (16.0 + 4.0 * DIM as f64)),
            "per_instance_max": quantile(inst.clone(), 1.0),
            "per_instance_fraction_over_bound": inst.iter().filter(|&&x| x > o.error as f64).count() as f64 / n as f64,
            "cluster_summed_worst": quantile(cl.clone(), 1.0),
            "cluster_summed_fraction_over_bound": cl.iter().filter(|&&x| x > o.error as f64).count() as f64 / cl.len() as f64,
            "scene_rms": rel(scene_ms),
            "scene_rms_noise_removed": rel(scene_ms - own_noise),
            "rms_error_vs_reference": vs_ref,
        }));
    }
    // The per-instance maps themselves against the reference: their noise, checked.
    let own_vs_ref: f64 = subset
        .iter()
        .enumerate()
        .map(|(r, &i)| {
            v[i * DIM..(i + 1) * DIM]
                .iter()
                .zip(&reference[r * DIM..(r + 1) * DIM])
                .map(|(x, y)| ((x - y) as f64).powi(2))
                .sum::<f64>()
        })
        .sum::<f64>()
        / (subset.len().max(1) * DIM) as f64;
    let json = json!({
        "reference": {"instances": subset.len(), "samples": o.ref_samples,
            "per_instance_maps_rms_error_vs_reference": rel(own_vs_ref)},
        "pack": pack_path, "instances": n, "samples": o.samples, "error_bound": o.error,
        "rms": rms, "trace_seconds": trace_seconds, "threads": rayon::current_num_threads(),
        "noise": noise, "neighbours": neighbours,
        "neighbours_per_instance_scale_removed": scaled, "instance_scale_rms_spread": scalar_spread, "clusterings": clusterings,
        "fixed_sample_sets": fixed,
    });
    let text = format!("{json:#}\n");
    Ok(Report { json, text })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_estimates_give_the_noise_of_their_mean() {
        // A = f + n, B = f − n: the mean is f, its noise n (σ² = mean n² per coefficient).
        let f = [1.0f32, 2.0, 3.0, 4.0];
        let nz = [0.5f32, -0.5, 1.0, 0.0];
        let a: Vec<f32> = f.iter().zip(&nz).map(|(x, n)| x + n).collect();
        let b: Vec<f32> = f.iter().zip(&nz).map(|(x, n)| x - n).collect();
        let v = noise_variance(&a, &b, 2);
        assert!(
            (v[0] - 0.25).abs() < 1e-12 && (v[1] - 0.5).abs() < 1e-12,
            "{v:?}"
        );
    }

    #[test]
    fn pair_differences_match_a_linear_field() {
        // v = x on a line of instances 1 m apart: pairs at 2 m (±25 %) are exactly those two
        // apart, each with squared difference 4; noise terms add up per pair.
        let pos: Vec<[f32; 3]> = (0..10).map(|i| [i as f32, 0.0, 0.0]).collect();
        let v: Vec<f32> = (0..10).map(|i| i as f32).collect();
        let var = vec![0.1f64; 10];
        let (pairs, diff, noise) = pair_differences(&pos, &v, &var, 1, 2.0);
        assert_eq!(pairs, 8);
        assert!((diff - 4.0).abs() < 1e-9 && (noise - 0.2).abs() < 1e-12);
    }
}
