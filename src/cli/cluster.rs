//! `bake cluster INPUT`: replaces per-instance environment maps by cluster samples plus
//! multiquadric interpolation and a per-instance local part (section `clusters`); and the
//! arguments of `bake bench cluster` (measured by `bench::cluster` and `bench::cluster_cause`).

use super::{Global, Outcome};
use crate::envmap::cluster::{ClusterOptions, Noise};
use crate::envmap::section;
use crate::error::{Error, Result};
use crate::pack::Pack;
use std::path::PathBuf;

/// Parses `--noise`: `none`, `auto` (estimated from the maps) or a relative level such as 0.01.
pub(crate) fn parse_noise(s: &str) -> std::result::Result<Noise, String> {
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
pub(crate) struct ClusterArgs {
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
    #[command(flatten)]
    pub budget: BudgetArgs,
}

/// The byte budget and the local part (issue 20; docs/FORMAT.md, `clusters`).
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct BudgetArgs {
    /// Do not Wiener-filter the local part with the `envmaps` section's noise estimate.
    #[arg(long)]
    pub no_denoise: bool,
    /// Principal components of the per-instance local part (0: none).
    #[arg(long, default_value_t = ClusterOptions::DEFAULT.local)]
    pub local: u32,
    /// Byte budget of the samples and the local part (default: raw maps / --compression).
    #[arg(long)]
    pub max_bytes: Option<u64>,
    /// Target compression without --max-bytes (0: no budget, split until the bound holds).
    #[arg(long, default_value_t = ClusterOptions::DEFAULT.compression)]
    pub compression: f32,
}

pub(crate) fn run(args: &ClusterArgs, _g: &Global) -> Result<Outcome> {
    let (w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let pack = Pack::open(&args.input)?;
    let pipeline = crate::graph::Pipeline {
        cluster: ClusterOptions {
            error: args.error,
            k: args.k,
            radius: args.radius,
            noise: args.noise,
            local: args.budget.local,
            max_bytes: args.budget.max_bytes,
            compression: args.budget.compression,
            denoise: !args.budget.no_denoise,
            weights: args.weights,
            ..Default::default()
        },
        ..Default::default()
    };
    // Through the registry's `cluster` unit (the graph's and `bake unit cluster`'s).
    let start = std::time::Instant::now();
    let o = crate::graph::stage::pack_unit(
        "cluster",
        &args.input,
        &crate::graph::stage::pack_sections(&pack, "cluster")?,
        &pipeline,
        None,
        None,
        &|_| {},
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let bytes = super::write_pack(w, o.sections, &output)?;
    let out = Pack::from_bytes(&bytes, "out")?;
    let mut doc = section::clusters_summary(&out.view_named("clusters")?)
        .map_err(|e| Error::invalid(&output, e))?;
    doc["seconds"] = seconds.into();
    doc["rounds"] = o.report["rounds"].clone();
    doc["noise_relative"] = o.report["noise_relative"].clone();
    Ok(Outcome {
        text: format!("{}: {}\n", output.display(), doc),
        json: doc,
        warnings: o.warnings,
    })
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ClusterBenchArgs {
    /// Number of instances, scattered over a 1024 m × 1024 m terrain.
    #[arg(long, default_value_t = 200_000)]
    pub instances: usize,
    /// Per-instance error bound (relative RMS).
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
    /// Fraction of the violating clusters split per round.
    #[arg(long, default_value_t = ClusterOptions::DEFAULT.split_fraction)]
    pub split_fraction: f32,
    /// Neighbours per reconstruction (default: chosen by leave-one-out).
    #[arg(long)]
    pub k: Option<usize>,
    /// Multiquadric constant R in metres (default: chosen by leave-one-out).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Noise the bound allows for: `none` (the stage's default), `auto` or a relative level.
    #[arg(long, default_value = "none", value_parser = parse_noise)]
    pub noise: Noise,
    #[command(flatten)]
    pub budget: BudgetArgs,
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
    /// Rays of the reference maps (with `--cause`: of about 200 instances; else of
    /// `--reference-instances` random instances of traced maps; 0: no reference).
    #[arg(long, default_value_t = 4096)]
    pub reference_samples: u32,
    /// Instances in the high-ray reference subset (traced maps).
    #[arg(long, default_value_t = 1000)]
    pub reference_instances: usize,
    /// Compress this baked pack's `instances` and `envmaps` (the pipeline's traced maps; the
    /// reference is traced on its scene) instead of a generated scene.
    #[arg(long, conflicts_with = "cause")]
    pub pack: Option<PathBuf>,
    /// With `--pack`: measure the maps' noise covariance by two more half-ray traces (for a
    /// pack whose `envmaps` carry no noise estimate) and Wiener-filter the local part with it.
    /// Without it, the pack's own estimate is used as the stage does (unless --no-denoise).
    #[arg(long, requires = "pack")]
    pub denoise: bool,
    /// With `--pack`: scale the noise per instance by the pack's own per-instance estimate
    /// (`noise_variance`): a heteroscedastic Wiener filter (experimental).
    #[arg(long, requires = "pack", conflicts_with = "denoise")]
    pub heteroscedastic: bool,
}

pub(crate) fn bench(a: &ClusterBenchArgs, _g: &Global) -> Result<Outcome> {
    let r = if let Some(pack) = &a.cause {
        let opts = crate::bench::cluster_cause::CauseOptions {
            samples: a.samples,
            error: a.error,
            ref_samples: a.reference_samples,
        };
        crate::bench::cluster_cause::measure_cause(pack, &opts)?
    } else {
        crate::bench::cluster::bench_cluster(&crate::bench::cluster::ClusterBench {
            instances: a.instances,
            cluster: ClusterOptions {
                error: a.error,
                split_fraction: a.split_fraction,
                k: a.k,
                radius: a.radius,
                noise: a.noise,
                local: a.budget.local,
                max_bytes: a.budget.max_bytes,
                compression: a.budget.compression,
                denoise: !a.budget.no_denoise,
                weights: false,
            },
            synthetic: a.synthetic,
            noise_level: a.noise_level,
            samples: a.samples,
            terrain: a.terrain,
            instance_frame: a.instance_frame,
            pack: a.pack.clone(),
            reference_samples: a.reference_samples,
            reference_instances: a.reference_instances,
            export: a.export.clone(),
            scipy: a.scipy,
            python: a.python.clone(),
            repeat: a.repeat,
            denoise: a.denoise,
            heteroscedastic: a.heteroscedastic,
        })?
    };
    Ok(Outcome {
        text: r.text,
        json: r.json,
        warnings: Vec::new(),
    })
}
