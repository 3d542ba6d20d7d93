//! `bake cluster INPUT`: replaces per-instance environment maps by cluster samples plus
//! multiquadric interpolation (section `clusters`); and `bake bench cluster`, the clustering and
//! interpolation benchmark on a generated 200,000-instance scene, optionally side by side with
//! scipy's `RBFInterpolator` (scripts/bench-scipy-rbf.py).

use super::{Global, Outcome};
use crate::envmap::cluster::{ClusterOptions, Noise};
use crate::envmap::section::{self, DIM};
use crate::error::{Error, Result};
use crate::pack::Pack;
use std::path::{Path, PathBuf};

/// Parses `--noise`: `none`, `auto` (estimated from the maps) or a relative level such as 0.01.
pub fn parse_noise(s: &str) -> std::result::Result<Noise, String> {
    match s {
        "none" => Ok(Noise::None),
        "auto" => Ok(Noise::Estimate),
        _ => match s.parse::<f32>() {
            Ok(v) if v.is_finite() && v >= 0.0 => Ok(Noise::Given(v)),
            _ => Err(format!(
                "expected `none`, `auto` or a non-negative relative noise level, got `{s}`"
            )),
        },
    }
}

#[derive(Debug, Clone, clap::Args)]
pub struct ClusterArgs {
    /// A pack with `instances` and `envmaps` sections.
    pub input: PathBuf,
    /// Output pack (default: the input pack).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Error bound on every instance: RMS error relative to the RMS of all coefficients.
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
    /// Neighbours per reconstruction (default: chosen by leave-one-out).
    #[arg(long)]
    pub k: Option<usize>,
    /// Multiquadric constant R in metres (default: chosen by leave-one-out).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Noise in the maps the bound allows for: `none`, `auto` (estimated from the maps) or a
    /// relative RMS level (e.g. 0.03 for 3 % Monte-Carlo noise).
    #[arg(long, default_value = "none", value_parser = parse_noise)]
    pub noise: Noise,
    /// Also store every instance's neighbours and weights (the runtime need not solve).
    #[arg(long)]
    pub weights: bool,
}

pub fn run(args: &ClusterArgs, _g: &Global) -> Result<Outcome> {
    let (w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let pack = Pack::open(&args.input)?;
    let opts = ClusterOptions {
        error: args.error,
        k: args.k,
        radius: args.radius,
        noise: args.noise,
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let (sections, c, warning) =
        crate::envmap::cluster_sections_warned(&pack, &opts, args.weights)?;
    let seconds = start.elapsed().as_secs_f64();
    let bytes = super::write_pack(w, sections, &output)?;
    let out = Pack::from_bytes(&bytes, "out")?;
    let mut doc = section::clusters_summary(&out.view_named("clusters")?)
        .map_err(|e| Error::invalid(&output, e))?;
    doc["seconds"] = seconds.into();
    doc["rounds"] = c.rounds.into();
    doc["noise_relative"] = c.noise.into();
    Ok(Outcome {
        text: format!("{}: {}\n", output.display(), doc),
        json: doc,
        warnings: warning.into_iter().collect(),
    })
}

#[derive(Debug, Clone, clap::Args)]
pub struct ClusterBenchArgs {
    /// Number of instances, scattered over a 1024 m × 1024 m terrain.
    #[arg(long, default_value_t = 200_000)]
    pub instances: usize,
    /// Per-instance error bound (relative RMS).
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
    /// Fraction of the violating clusters split per round.
    #[arg(long, default_value_t = 0.5)]
    pub split_fraction: f32,
    /// Neighbours per reconstruction (default: chosen by leave-one-out).
    #[arg(long)]
    pub k: Option<usize>,
    /// Multiquadric constant R in metres (default: chosen by leave-one-out).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Noise the bound allows for: `none`, `auto` or a relative level.
    #[arg(long, default_value = "auto", value_parser = parse_noise)]
    pub noise: Noise,
    /// Use synthetic maps (terrain occlusion plus per-instance noise) instead of traced ones.
    #[arg(long)]
    pub synthetic: bool,
    /// Relative RMS of the per-instance noise of the synthetic maps.
    #[arg(long, default_value_t = 0.005)]
    pub noise_level: f32,
    /// Rays per instance for the traced environment maps.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// Terrain samples per side (1 m apart).
    #[arg(long, default_value_t = 1024)]
    pub terrain: u32,
    /// Cluster the traced maps in each instance's frame (as stored) instead of the world frame.
    #[arg(long)]
    pub instance_frame: bool,
    /// Write positions, values, samples, params.json (and truth.f32 for synthetic maps) as
    /// little-endian f32 files into this folder (for a peer tool).
    #[arg(long)]
    pub export: Option<PathBuf>,
    /// Also run scripts/bench-scipy-rbf.py on the same data and report both.
    #[arg(long)]
    pub scipy: bool,
    /// Python interpreter for `--scipy`.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// Runs of the interpolation (bake's neighbours, weights and reconstruction, and scipy's
    /// fit and evaluation); the fastest of each is reported (the machine is shared).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub repeat: u32,
    /// Instead: measure why a baked pack's traced maps do (not) cluster (noise from two
    /// half-sample estimates, neighbour differences, the bounds; `--samples` rays in all,
    /// `--error` the bound). See `bench::cluster_cause`.
    #[arg(long)]
    pub cause: Option<PathBuf>,
    /// With `--cause`: rays of the reference maps of about 200 instances.
    #[arg(long, default_value_t = 4096)]
    pub reference_samples: u32,
}

/// One timed run of the interpolation: wall and CPU seconds of the weights alone and with the
/// reconstruction, the stored weights' size, the reconstructed maps.
struct Interpolation {
    t_weights: f64,
    t_interp: f64,
    cpu_weights: Option<f64>,
    cpu_interp: Option<f64>,
    weights_bytes: u64,
    rec: Vec<f32>,
}

/// The maps of the benchmark scene: positions, values, the noise-free values if known.
type BenchScene = (Vec<[f32; 3]>, Vec<f32>, Option<Vec<f32>>);

pub fn bench(a: &ClusterBenchArgs, _g: &Global) -> Result<Outcome> {
    if let Some(pack) = &a.cause {
        let opts = crate::bench::cluster_cause::CauseOptions {
            samples: a.samples,
            error: a.error,
            ref_samples: a.reference_samples,
        };
        let r = crate::bench::cluster_cause::measure_cause(pack, &opts)?;
        return Ok(Outcome {
            text: r.text,
            json: r.json,
            warnings: Vec::new(),
        });
    }
    let t_envmaps = std::time::Instant::now();
    let (positions, values, truth) = if a.synthetic {
        synthetic_scene(a)
    } else {
        traced_scene(a)?
    };
    let envmap_seconds = t_envmaps.elapsed().as_secs_f64();
    let opts = ClusterOptions {
        error: a.error,
        split_fraction: a.split_fraction,
        k: a.k,
        radius: a.radius,
        noise: a.noise,
    };
    let (t0, cpu0) = (std::time::Instant::now(), crate::bench::cpu_seconds());
    let c = crate::envmap::cluster::cluster_envmaps(&positions, &values, DIM, &opts);
    let t_cluster = t0.elapsed().as_secs_f64();
    let cpu_cluster = crate::bench::cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    let cpu = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| b - a);
    let mut best: Option<Interpolation> = None;
    for _ in 0..a.repeat {
        let (t1, cpu_t1) = (std::time::Instant::now(), crate::bench::cpu_seconds());
        let (nb, w) = crate::envmap::instance_weights(&positions, &values, DIM, &c);
        let t_weights = t1.elapsed().as_secs_f64();
        let cpu1 = crate::bench::cpu_seconds();
        let rec = crate::envmap::apply_weights(&values, DIM, &c.samples, c.k, &nb, &w);
        let run = Interpolation {
            t_weights,
            t_interp: t1.elapsed().as_secs_f64(),
            cpu_weights: cpu(cpu_t1, cpu1),
            cpu_interp: cpu(cpu_t1, crate::bench::cpu_seconds()),
            weights_bytes: (nb.len() * 4 + w.len() * 4) as u64,
            rec,
        };
        if best.as_ref().is_none_or(|b| run.t_interp < b.t_interp) {
            best = Some(run);
        }
    }
    let Interpolation {
        t_weights,
        t_interp,
        cpu_weights,
        cpu_interp,
        weights_bytes,
        rec,
    } = best.expect("repeat >= 1");
    let rel = |reference: &[f32]| relative_rms(&rec, reference, c.rms);
    let raw = (positions.len() * DIM * 4) as u64;
    let packed = c.samples.len() as u64 * (12 + 4 + DIM as u64 * 4);
    let mut doc = serde_json::json!({
        "instances": positions.len(), "clusters": c.samples.len(), "k": c.k, "radius": c.radius,
        "raw_bytes": raw, "packed_bytes": packed, "compression": raw as f64 / packed as f64,
        "error_bound": a.error, "noise_relative": c.noise,
        "rms_error_relative": c.rms_error(), "max_error_relative": c.max_error(),
        "rms_error_vs_truth": truth.as_deref().map(rel),
        "rounds": c.rounds, "evaluations": c.evaluations, "seconds": t_cluster,
        "weights_seconds": t_weights, "interpolation_seconds": t_interp,
        "interpolation_rms_error_relative": rel(&values),
        "cluster_and_weights_seconds": t_cluster + t_weights,
        "cluster_and_weights_cpu_seconds": cpu_cluster.zip(cpu_weights).map(|(a, b)| a + b),
        "cluster_cpu_seconds": cpu_cluster, "interpolation_cpu_seconds": cpu_interp,
        "repeat": a.repeat,
        "envmap_seconds": envmap_seconds, "synthetic": a.synthetic,
        "weights_bytes": weights_bytes, "ill_conditioned": c.ill_conditioned,
        "threads": rayon::current_num_threads(),
        "loo": c.loo.iter().map(|&(k, r, e)| serde_json::json!({"k": k, "radius": r, "rms_error_relative": e})).collect::<Vec<_>>(),
    });
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
        export(dir, &positions, &values, truth.as_deref(), &c)?;
    }
    if let (true, Some(dir)) = (a.scipy, &dir) {
        let peer = run_scipy(&a.python, dir, a.repeat)?;
        let speedup = peer["seconds"].as_f64().unwrap_or(0.0) / t_interp;
        doc["scipy"] = peer;
        doc["speedup_interpolation_vs_scipy"] = speedup.into();
    }
    Ok(Outcome {
        text: format!("{doc:#}\n"),
        json: doc,
        warnings: Vec::new(),
    })
}

/// RMS of (a − b) relative to `rms`.
fn relative_rms(a: &[f32], b: &[f32], rms: f32) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    (s / a.len().max(1) as f64).sqrt() / rms.max(f32::MIN_POSITIVE) as f64
}

fn export(
    dir: &Path,
    positions: &[[f32; 3]],
    values: &[f32],
    truth: Option<&[f32]>,
    c: &crate::envmap::cluster::Clustering,
) -> Result<()> {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let flat: Vec<f32> = positions.iter().flatten().copied().collect();
    let samples: Vec<f32> = c.samples.iter().map(|&s| s as f32).collect();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let params =
        serde_json::json!({"dim": DIM, "k": c.k, "radius": c.radius, "instances": positions.len()});
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

/// Instance positions on the benchmark terrain, with synthetic maps (terrain occlusion + noise).
fn synthetic_scene(a: &ClusterBenchArgs) -> BenchScene {
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
    (positions, m.noisy, Some(m.truth))
}

/// A generated scene (procedural alpha-tested plant on a hilly terrain, built-in sky) and its
/// traced environment maps, in the world frame unless `--instance-frame`.
fn traced_scene(a: &ClusterBenchArgs) -> Result<BenchScene> {
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
    let maps = crate::envmap::bake::bake_envmaps(
        &scene,
        &crate::envmap::bake::EnvmapOptions {
            samples: a.samples,
            seed: 1,
        },
    );
    let (mut sky_maps, mut sun_maps): (Vec<_>, Vec<_>) = maps.into_iter().unzip();
    if !a.instance_frame {
        crate::envmap::to_world_frame(&mut sky_maps, &mut sun_maps, &rotations);
    }
    Ok((positions, section::flatten(&sky_maps, &sun_maps), None))
}
