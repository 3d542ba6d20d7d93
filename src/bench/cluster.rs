//! `bake bench cluster`: the environment-map compression (issue 20) and interpolation (issue 7)
//! benchmark. Maps: synthetic (`envmap::synthetic`: terrain occlusion plus noise, with the
//! noise-free field as the reference), traced on a generated scene (one procedural plant on the
//! bench terrain), or a baked pack's own traced maps (`--pack`: the default pipeline's). The
//! stage's compression ([`crate::envmap::compress`]: split loop within the byte budget, local
//! part) is timed, then every instance's neighbours, weights and reconstruction (fastest of
//! `repeat` runs), optionally side by side with scipy's `RBFInterpolator`
//! (scripts/bench-scipy-rbf.py).
//!
//! The error is stated against the input maps (which carry the Monte-Carlo noise) and, for
//! traced maps, against a high-ray reference of a random subset of the instances: traced with
//! `reference_samples` rays in two independent halves (other seeds than the input), whose
//! difference gives the reference's own noise; the error against the reference is reported raw
//! and with that noise subtracted (e² − σ_ref², the part the reference's noise does not explain).

use super::{Report, Timing, time_once};
use crate::envmap::cluster::{ClusterOptions, Clustering};
use crate::envmap::section::{self, DIM};
use crate::error::{Error, Result};
use serde_json::json;
use std::path::{Path, PathBuf};

/// Options of [`bench_cluster`] (the command line's, without clap).
#[derive(Debug, Clone)]
pub struct ClusterBench {
    pub instances: usize,
    /// The stage's options (bound, budget, local part, k, R, noise).
    pub cluster: ClusterOptions,
    pub synthetic: bool,
    pub noise_level: f32,
    pub samples: u32,
    pub terrain: u32,
    pub instance_frame: bool,
    /// A baked pack whose `instances` and `envmaps` are compressed (its scene traced for the
    /// reference) instead of a generated scene.
    pub pack: Option<PathBuf>,
    /// Rays per reference map (0: no reference).
    pub reference_samples: u32,
    /// Instances in the reference subset.
    pub reference_instances: usize,
    pub export: Option<PathBuf>,
    pub scipy: bool,
    pub python: String,
    pub repeat: u32,
    /// With `pack`: trace the scene twice more with half the pack's rays each, take the noise
    /// covariance from their difference, and Wiener-filter the local part with it
    /// (experimental).
    pub denoise: bool,
    /// Scale the noise per instance by its own estimate (the pack's `noise_variance` over its
    /// mean): a heteroscedastic Wiener filter (experimental).
    pub heteroscedastic: bool,
}

/// A reference for some instances: their indices, their maps (world frame, `DIM` each) and the
/// reference's own noise variance per coefficient (0 for an exact one).
pub struct Reference {
    pub subset: Vec<usize>,
    pub maps: Vec<f32>,
    pub noise_var: f64,
    pub exact: bool,
}

/// The maps of a bench scene: positions, values (world frame unless `instance_frame`), the
/// reference.
pub struct BenchScene {
    pub positions: Vec<[f32; 3]>,
    pub values: Vec<f32>,
    pub reference: Option<Reference>,
    /// The maps' noise covariance per instance (dim × dim), if measured (`denoise`).
    pub noise: Option<Vec<f64>>,
    /// Per-instance noise scale (`heteroscedastic`).
    pub noise_scale: Option<Vec<f32>>,
}

/// One timed run of the interpolation.
struct Interpolation {
    weights: Timing,
    all: Timing,
    weights_bytes: u64,
    rec: Vec<f32>,
}

/// The benchmark (see the module doc).
pub fn bench_cluster(a: &ClusterBench) -> Result<Report> {
    let (t_maps, scene) = time_once(|| scene(a));
    let BenchScene {
        positions,
        values,
        reference,
        noise,
        noise_scale,
    } = scene?;
    let opts = a.cluster;
    let (t_compress, z) = time_once(|| {
        crate::envmap::compress_denoised(
            &positions,
            &values,
            DIM,
            &opts,
            noise.as_deref(),
            noise_scale.as_deref(),
        )
    });
    let c = &z.clustering;
    let rows = z.sample_rows(&values, DIM);
    let mut best: Option<Interpolation> = None;
    for _ in 0..a.repeat.max(1) {
        let (all, (weights, nb, w, rec)) = time_once(|| {
            let (weights, (nb, w)) =
                time_once(|| crate::envmap::instance_weights(&positions, &values, DIM, c));
            let mut rec = crate::envmap::apply_weights_rows(&rows, DIM, c.k, &nb, &w);
            if let Some(l) = &z.local {
                l.add_all(&mut rec);
            }
            (weights, nb, w, rec)
        });
        let run = Interpolation {
            weights,
            all,
            weights_bytes: (nb.len() * 4 + w.len() * 4) as u64,
            rec,
        };
        if best.as_ref().is_none_or(|b| run.all.wall < b.all.wall) {
            best = Some(run);
        }
    }
    let Interpolation {
        weights,
        all,
        weights_bytes,
        rec,
    } = best.expect("repeat >= 1");
    let raw = (positions.len() * DIM * 4) as u64;
    let packed = z.packed_bytes(DIM);
    let add = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| a + b);
    let mut doc = json!({
        "instances": positions.len(), "clusters": c.samples.len(), "k": c.k, "radius": c.radius,
        "raw_bytes": raw, "packed_bytes": packed, "compression": z.compression(DIM),
        "max_bytes": z.budget, "budget_limited": c.budget_limited,
        "local_components": z.local.as_ref().map_or(0, |l| l.components),
        "local_bytes": packed - c.samples.len() as u64 * crate::envmap::cluster::sample_bytes(DIM),
        "error_bound": opts.error, "noise_relative": c.noise,
        "rms_error_relative": z.rms_error(), "max_error_relative": z.max_error(),
        "shared_rms_error_relative": c.rms_error(),
        "interpolation_rms_error_relative": relative_rms(&rec, &values, c.rms),
        "rounds": c.rounds, "evaluations": c.evaluations,
        "seconds": t_compress.wall, "cpu_seconds": t_compress.cpu,
        "weights_seconds": weights.wall, "interpolation_seconds": all.wall,
        "cluster_and_weights_seconds": t_compress.wall + weights.wall,
        "cluster_and_weights_cpu_seconds": add(t_compress.cpu, weights.cpu),
        "interpolation_cpu_seconds": all.cpu,
        "repeat": a.repeat, "envmap_seconds": t_maps.wall, "envmap_cpu_seconds": t_maps.cpu,
        "synthetic": a.synthetic, "pack": a.pack.as_ref().map(|p| p.display().to_string()),
        "denoise": noise.is_some(),
        "weights_bytes": weights_bytes, "ill_conditioned": c.ill_conditioned,
        "threads": rayon::current_num_threads(),
        "peak_rss_bytes": peak_rss(),
        "loo": c.loo.iter().map(|&(k, r, e)| json!({"k": k, "radius": r, "rms_error_relative": e})).collect::<Vec<_>>(),
    });
    doc["heteroscedastic"] = noise_scale.is_some().into();
    doc["input_noise_relative"] = json!(noise.as_ref().map(|nc| {
        let tr: f64 = (0..DIM).map(|i| nc[i * DIM + i]).sum();
        (tr / DIM as f64).sqrt() / c.rms.max(f32::MIN_POSITIVE) as f64
    }));
    if let Some(r) = &reference {
        doc["reference"] = reference_errors(r, &rec, &values, c.rms, a);
        if r.exact {
            doc["rms_error_vs_truth"] = doc["reference"]["rms_error_relative"].clone();
        }
    }
    let tmp;
    let dir = match (&a.export, a.scipy) {
        (Some(d), _) => Some(d.clone()),
        (None, true) => {
            tmp = tempfile::tempdir().map_err(|e| Error::io("temporary folder", e))?;
            Some(tmp.path().to_path_buf())
        }
        (None, false) => None,
    };
    if let Some(dir) = &dir {
        let truth = reference.as_ref().filter(|r| r.exact).map(|r| &r.maps[..]);
        export(dir, &positions, &values, truth, c)?;
    }
    if let (true, Some(dir)) = (a.scipy, &dir) {
        let peer = run_scipy(&a.python, dir, a.repeat)?;
        let speedup = peer["seconds"].as_f64().unwrap_or(0.0) / all.wall;
        doc["scipy"] = peer;
        doc["speedup_interpolation_vs_scipy"] = speedup.into();
    }
    Ok(Report {
        text: format!("{doc:#}\n"),
        json: doc,
    })
}

/// The errors of the reconstruction `rec` against the reference on its subset.
fn reference_errors(
    r: &Reference,
    rec: &[f32],
    values: &[f32],
    rms: f32,
    a: &ClusterBench,
) -> serde_json::Value {
    let gather = |v: &[f32]| -> Vec<f32> {
        r.subset
            .iter()
            .flat_map(|&i| v[i * DIM..(i + 1) * DIM].iter().copied())
            .collect()
    };
    let (sub_rec, sub_in) = (gather(rec), gather(values));
    let per: Vec<f32> = crate::envmap::relative_errors(&sub_rec, &r.maps, DIM, rms);
    let e = relative_rms(&sub_rec, &r.maps, rms);
    let e_in = relative_rms(&sub_in, &r.maps, rms);
    let sigma = (r.noise_var.max(0.0)).sqrt() / rms.max(f32::MIN_POSITIVE) as f64;
    let corrected = |x: f64| (x * x - sigma * sigma).max(0.0).sqrt();
    let mut sorted = per.clone();
    sorted.sort_by(f32::total_cmp);
    let q = |f: f64| {
        sorted
            .get(((sorted.len().max(1) - 1) as f64 * f) as usize)
            .copied()
    };
    json!({
        "instances": r.subset.len(),
        "samples": if r.exact { serde_json::Value::Null } else { a.reference_samples.into() },
        "exact": r.exact,
        "noise_relative": sigma,
        "rms_error_relative": e,
        "rms_error_relative_noise_removed": corrected(e),
        "p90_error_relative": q(0.9), "max_error_relative": q(1.0),
        "input_rms_error_relative": e_in,
        "input_rms_error_relative_noise_removed": corrected(e_in),
    })
}

/// Peak resident memory of this process (VmHWM), bytes; None off Linux.
pub fn peak_rss() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// RMS of (a − b) relative to `rms`.
pub fn relative_rms(a: &[f32], b: &[f32], rms: f32) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    (s / a.len().max(1) as f64).sqrt() / rms.max(f32::MIN_POSITIVE) as f64
}

/// A deterministic random subset of `m` of `0..n`, ascending.
pub fn random_subset(n: usize, m: usize, seed: u64) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    let mut rng = crate::rng::Rng::new(seed);
    let m = m.min(n);
    for i in 0..m {
        let j = i + ((rng.f32() as f64 * (n - i) as f64) as usize).min(n - i - 1);
        idx.swap(i, j);
    }
    idx.truncate(m);
    idx.sort_unstable();
    idx
}

fn scene(a: &ClusterBench) -> Result<BenchScene> {
    if let Some(p) = &a.pack {
        return pack_scene(p, a);
    }
    if a.synthetic {
        return Ok(synthetic_scene(a));
    }
    traced_scene(a)
}

/// Instance positions on the benchmark terrain, with synthetic maps (terrain occlusion + noise);
/// the reference is the noise-free field of every instance.
fn synthetic_scene(a: &ClusterBench) -> BenchScene {
    use crate::envmap::synthetic::{bench_terrain_height, synthetic_envmaps};
    let extent = (a.terrain.max(2) - 1) as f32;
    let mut rng = crate::rng::Rng::new(2005);
    let positions: Vec<[f32; 3]> = (0..a.instances)
        .map(|_| {
            let (x, y) = (rng.f32() * extent, rng.f32() * extent);
            [x, y, bench_terrain_height(x, y)]
        })
        .collect();
    let m = synthetic_envmaps(&positions, &bench_terrain_height, a.noise_level, 2005);
    BenchScene {
        reference: Some(Reference {
            subset: (0..positions.len()).collect(),
            maps: m.truth,
            noise_var: 0.0,
            exact: true,
        }),
        positions,
        values: m.noisy,
        noise: None,
        noise_scale: None,
    }
}

/// Seeds of the reference's two halves (independent of the input's).
const REFERENCE_SEEDS: [u64; 2] = [0x0072_ef00, 0x0072_ef01];

/// Two half-ray traces of `subset` → the reference (mean) and its noise variance of the mean
/// per coefficient; maps in the world frame.
fn trace_reference(
    subset: Vec<usize>,
    rotations: &[f32],
    samples: u32,
    trace: impl Fn(
        &crate::envmap::bake::EnvmapOptions,
        &[usize],
    ) -> Vec<crate::envmap::bake::InstanceMaps>,
) -> Reference {
    let rot: Vec<f32> = subset.iter().map(|&i| rotations[i]).collect();
    let half = |seed: u64| {
        let o = crate::envmap::bake::EnvmapOptions {
            samples: (samples / 2).max(1),
            seed,
            // One N-point set per half (the difference of the two halves is the noise).
            noise_estimate: false,
            ..crate::envmap::bake::EnvmapOptions::DEFAULT
        };
        let (mut sky, mut sun): (Vec<_>, Vec<_>) = trace(&o, &subset).into_iter().unzip();
        crate::envmap::to_world_frame(&mut sky, &mut sun, &rot);
        section::flatten(&sky, &sun)
    };
    let (ra, rb) = (half(REFERENCE_SEEDS[0]), half(REFERENCE_SEEDS[1]));
    let var = crate::bench::cluster_cause::noise_variance(&ra, &rb, DIM);
    let noise_var = var.iter().sum::<f64>() / var.len().max(1) as f64;
    Reference {
        subset,
        maps: ra.iter().zip(&rb).map(|(x, y)| 0.5 * (x + y)).collect(),
        noise_var,
        exact: false,
    }
}

/// A baked pack's instances and traced maps (world frame), and a reference traced on its scene.
fn pack_scene(path: &Path, a: &ClusterBench) -> Result<BenchScene> {
    let pack = crate::pack::Pack::open(path)?;
    let bad = |e| Error::invalid(path, e);
    let (_, inst) = crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
        .map_err(bad)?;
    let (_, mut sky, mut sun) =
        section::envmaps_from_section(&pack.view_named("envmaps")?).map_err(bad)?;
    let positions: Vec<[f32; 3]> = inst.items.iter().map(|i| i.position).collect();
    let rotations: Vec<f32> = inst.items.iter().map(|i| i.rotation_deg).collect();
    crate::envmap::to_world_frame(&mut sky, &mut sun, &rotations);
    let values = section::flatten(&sky, &sun);
    let traced = if a.reference_samples > 0 || a.denoise {
        Some((
            crate::lightmap::scene_lighting(&pack)?,
            crate::trace::pack_scene::trace_scene(&pack)?,
        ))
    } else {
        None
    };
    let reference = match (&traced, a.reference_samples > 0) {
        (Some((light, ts)), true) => {
            let subset = random_subset(positions.len(), a.reference_instances, 4096);
            Some(trace_reference(
                subset,
                &rotations,
                a.reference_samples,
                // The options are the CPU tracer's, which always builds.
                |o, s| {
                    crate::envmap::instance_maps_subset(ts, light, o, s)
                        .expect("the cpu tracer always builds")
                },
            ))
        }
        _ => None,
    };
    let noise = match (&traced, a.denoise) {
        (Some((light, ts)), true) => {
            let (meta, _, _) =
                section::envmaps_from_section(&pack.view_named("envmaps")?).map_err(bad)?;
            let all: Vec<usize> = (0..positions.len()).collect();
            let half = |seed: u64| {
                let o = crate::envmap::bake::EnvmapOptions {
                    samples: (meta.samples / 2).max(1),
                    seed,
                    // One N-point set per half (the difference of the two halves is the noise).
                    noise_estimate: false,
                    ..crate::envmap::bake::EnvmapOptions::DEFAULT
                };
                let maps = crate::envmap::instance_maps_subset(ts, light, &o, &all)
                    .expect("the cpu tracer always builds");
                let (mut sky, mut sun): (Vec<_>, Vec<_>) = maps.into_iter().unzip();
                crate::envmap::to_world_frame(&mut sky, &mut sun, &rotations);
                section::flatten(&sky, &sun)
            };
            let (ha, hb) = (half(0x00de_0a15), half(0x00de_0b15));
            Some(section::EnvmapNoise {
                covariance: noise_covariance(&ha, &hb, DIM),
                variance: Vec::new(),
            })
        }
        _ => {
            let ev = pack.view_named("envmaps")?;
            let m = section::EnvmapsMeta::decode(&ev).map_err(bad)?;
            section::envmaps_noise_from_section(&ev, &m)
                .map_err(bad)?
                .filter(|_| a.cluster.denoise)
        }
    };
    let noise_scale = match (&noise, a.heteroscedastic) {
        (Some(nz), true) if !a.denoise => {
            let mean = nz.variance.iter().map(|&v| v as f64).sum::<f64>()
                / nz.variance.len().max(1) as f64;
            // Each instance's own estimate (one difference) is noisy: averaged over its 16
            // nearest instances (noise varies with the stand's density, smoothly).
            let tree = crate::kdtree::KdTree::build(&positions);
            let mut nb = Vec::new();
            Some(
                positions
                    .iter()
                    .map(|&q| {
                        tree.nearest(q, 16, &mut nb);
                        let v = nb
                            .iter()
                            .map(|&(_, j)| nz.variance[j as usize] as f64)
                            .sum::<f64>()
                            / nb.len().max(1) as f64;
                        if mean > 0.0 { (v / mean) as f32 } else { 1.0 }
                    })
                    .collect(),
            )
        }
        _ => None,
    };
    Ok(BenchScene {
        positions,
        values,
        reference,
        noise: noise.map(|nz| nz.covariance),
        noise_scale,
    })
}

/// A generated scene (procedural alpha-tested plant on a hilly terrain, built-in sky) and its
/// traced environment maps, in the world frame unless `instance_frame`.
fn traced_scene(a: &ClusterBench) -> Result<BenchScene> {
    use crate::trace::{AlphaMask, BuildPreset, InstanceTransform, ModelBvh, SceneBvh};
    use std::sync::Arc;
    let n = a.terrain.max(2);
    let extent = (n - 1) as f32;
    let heights = (0..n * n)
        .map(|k| crate::envmap::synthetic::bench_terrain_height((k % n) as f32, (k / n) as f32))
        .collect();
    let terrain = crate::model::Terrain {
        width: n,
        height: n,
        heights,
        origin: [0.0, 0.0],
        extent: [extent; 2],
        color: None,
    };
    let (plant, leaf) = crate::prt::plant::procedural_plant(300, 7);
    let masks = vec![Some(AlphaMask::from_rgba8(&leaf)); plant.materials.len()];
    let plant_bvh = Arc::new(ModelBvh::build(&plant, &masks, BuildPreset::Medium)?);
    let ground = Arc::new(ModelBvh::build(
        &crate::trace::pack_scene::terrain_mesh(&terrain),
        &[],
        BuildPreset::Fast,
    )?);
    let mut rng = crate::rng::Rng::new(2005);
    let mut transforms = Vec::with_capacity(a.instances + 1);
    for _ in 0..a.instances {
        let (x, y) = (rng.f32() * extent, rng.f32() * extent);
        transforms.push(InstanceTransform {
            model: 0,
            translation: [x, y, terrain.height_at(x, y)],
            scale: 0.8 + 0.6 * rng.f32(),
            rotation_deg: rng.f32() * 360.0,
        });
    }
    transforms.push(InstanceTransform {
        model: 1,
        translation: [0.0; 3],
        scale: 1.0,
        rotation_deg: 0.0,
    });
    let positions: Vec<[f32; 3]> = transforms[..a.instances]
        .iter()
        .map(|t| t.translation)
        .collect();
    let rotations: Vec<f32> = transforms[..a.instances]
        .iter()
        .map(|t| t.rotation_deg)
        .collect();
    let height = plant.bounds().map_or(1.0, |(lo, hi)| hi[2] - lo[2]);
    let probe_height = transforms[..a.instances]
        .iter()
        .map(|t| 0.5 * height * t.scale)
        .collect();
    let bvh = SceneBvh::build(vec![plant_bvh, ground], transforms)?;
    let sky = crate::sky::builtin::BuiltinSky::default();
    let cube = crate::sky::builtin::builtin_sky(&sky);
    let (cube, sun) = crate::sky::sun::extract_sun(&cube, &Default::default());
    let mut albedo = vec![[0.25, 0.4, 0.15]; a.instances];
    albedo.push([0.2, 0.25, 0.15]);
    let scene = crate::envmap::bake::EnvmapScene {
        bvh: &bvh,
        count: a.instances,
        probe_height,
        albedo,
        sky: crate::sh::project_cube(&cube),
        sun: Some(crate::envmap::bake::SunLight {
            direction: sun.direction,
            irradiance: sun.irradiance,
        }),
    };
    let traced = crate::envmap::bake::trace_envmaps_range(
        &scene,
        &crate::envmap::bake::EnvmapOptions {
            samples: a.samples,
            seed: 1,
            ..crate::envmap::bake::EnvmapOptions::DEFAULT
        },
        0..a.instances,
    );
    // The tracer's own noise estimate (world frame), as the stage reads it from `envmaps`.
    let noise = (a.cluster.denoise && !a.instance_frame && traced.diffs.len() == a.instances)
        .then(|| section::noise_from_differences(&traced.diffs).covariance);
    let (mut sky_maps, mut sun_maps): (Vec<_>, Vec<_>) = traced.maps.into_iter().unzip();
    let reference = (a.reference_samples > 0 && !a.instance_frame).then(|| {
        let subset = random_subset(a.instances, a.reference_instances, 4096);
        trace_reference(subset, &rotations, a.reference_samples, |o, s| {
            crate::envmap::bake::bake_envmaps_subset(&scene, o, s)
        })
    });
    if !a.instance_frame {
        crate::envmap::to_world_frame(&mut sky_maps, &mut sun_maps, &rotations);
    }
    Ok(BenchScene {
        positions,
        values: section::flatten(&sky_maps, &sun_maps),
        reference,
        noise,
        noise_scale: None,
    })
}

/// Noise covariance (dim × dim) of the mean of two independent half estimates: Σ (A−B)(A−B)ᵀ /
/// (4 n) — the noise of one full-ray estimate.
pub fn noise_covariance(a: &[f32], b: &[f32], dim: usize) -> Vec<f64> {
    let n = a.len() / dim.max(1);
    let mut m = vec![0.0f64; dim * dim];
    for (x, y) in a.chunks_exact(dim).zip(b.chunks_exact(dim)) {
        let d: Vec<f64> = x.iter().zip(y).map(|(p, q)| (p - q) as f64).collect();
        for r in 0..dim {
            for c in 0..dim {
                m[r * dim + c] += d[r] * d[c];
            }
        }
    }
    for v in &mut m {
        *v /= 4.0 * n.max(1) as f64;
    }
    m
}

fn export(
    dir: &Path,
    positions: &[[f32; 3]],
    values: &[f32],
    truth: Option<&[f32]>,
    c: &Clustering,
) -> Result<()> {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let flat: Vec<f32> = positions.iter().flatten().copied().collect();
    let samples: Vec<f32> = c.samples.iter().map(|&s| s as f32).collect();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let params = json!({"dim": DIM, "k": c.k, "radius": c.radius, "instances": positions.len()});
    let mut files = vec![
        ("positions.f32", f32s(&flat)),
        ("values.f32", f32s(values)),
        ("samples.f32", f32s(&samples)),
        ("params.json", params.to_string().into_bytes()),
    ];
    if let Some(t) = truth {
        files.push(("truth.f32", f32s(t)));
    }
    for (name, data) in files {
        crate::pack::write_atomic(&dir.join(name), &data)?;
    }
    Ok(())
}

/// Runs the scipy peer on an exported folder; its last output line is a JSON object.
fn run_scipy(python: &str, dir: &Path, repeat: u32) -> Result<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/bench-scipy-rbf.py");
    let out = std::process::Command::new(python)
        .arg(&script)
        .arg(dir)
        .arg(repeat.to_string())
        .output()
        .map_err(|e| Error::io(&script, e))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(Error::usage(format!(
            "{} failed ({}): {}",
            script.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let last = stdout.lines().last().unwrap_or("");
    serde_json::from_str(last).map_err(|e| {
        Error::usage(format!(
            "{}: expected a JSON line, got `{last}` ({e})",
            script.display()
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tracers_noise_estimate_brings_the_compressed_maps_closer_to_a_high_ray_reference() {
        // A dense generated forest (2,000 instances on 128 m × 128 m, 64 rays: noisy maps), the
        // stage's defaults (20×, 8 local components): with the tracer's noise covariance the
        // Wiener-filtered local part is at least as close to a 2,048-ray reference as the plain
        // one, and closer than the noisy input itself is.
        let run = |denoise: bool| {
            let r = bench_cluster(&ClusterBench {
                instances: 2000,
                cluster: ClusterOptions {
                    denoise,
                    ..ClusterOptions::DEFAULT
                },
                synthetic: false,
                noise_level: 0.0,
                samples: 64,
                terrain: 128,
                instance_frame: false,
                pack: None,
                reference_samples: 2048,
                reference_instances: 150,
                export: None,
                scipy: false,
                python: String::new(),
                repeat: 1,
                denoise: false,
                heteroscedastic: false,
            })
            .unwrap();
            r.json
        };
        let (plain, filtered) = (run(false), run(true));
        assert_eq!(plain["denoise"], false);
        assert_eq!(filtered["denoise"], true);
        assert!(plain["local_components"].as_u64().unwrap() > 0, "{plain}");
        let e = |d: &serde_json::Value, k: &str| d["reference"][k].as_f64().unwrap();
        let (ep, ef) = (
            e(&plain, "rms_error_relative"),
            e(&filtered, "rms_error_relative"),
        );
        let input = e(&plain, "input_rms_error_relative");
        eprintln!(
            "vs 2,048-ray reference: plain {ep:.4}, denoised {ef:.4}, input {input:.4}; input noise {}",
            filtered["input_noise_relative"]
        );
        assert!(ef <= ep, "denoised {ef} vs plain {ep}");
        assert!(ef < input, "denoised {ef} vs input {input}");
        // The stated noise matches the input's error against the reference (which is the
        // input's noise, up to the reference's own): within 25 %.
        let stated = filtered["input_noise_relative"].as_f64().unwrap();
        let measured = e(&plain, "input_rms_error_relative_noise_removed");
        assert!(
            (stated / measured - 1.0).abs() < 0.25,
            "stated {stated} vs measured {measured}"
        );
    }
}
