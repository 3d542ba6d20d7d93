//! `bake lightmap INPUT`: the terrain's light map (section `lightmap:terrain`) and atlas light
//! maps of the meshes placed at most `--lightmap-max-instances` times (`lightmap:<mesh>`).

use super::{Global, Outcome};
use crate::error::Result;
use crate::lightmap::{LightmapMode, LightmapOptions};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LightmapArgs {
    /// A scene pack (with `sh`/`sun` sections from `bake sky` or `bake build`).
    pub input: PathBuf,
    /// Output pack (default: the input pack).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Texels per side (default: the terrain grid size).
    #[arg(long)]
    pub resolution: Option<u32>,
    /// Hemisphere samples per texel.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// `physical` (visibility, true sun disc, one bounce) or `thesis` (seed 001's estimator).
    #[arg(long, value_enum, default_value_t = LightmapMode::Physical)]
    pub mode: LightmapMode,
    /// Models placed at most this many times (the 3DS objects) get an atlas light map.
    #[arg(long, default_value_t = 16)]
    pub lightmap_max_instances: u32,
    /// Texels per side of one instance's atlas tile (doubled while the charts do not fit).
    #[arg(long, default_value_t = 64)]
    pub atlas_tile: u32,
    /// Gutter texels around every chart.
    #[arg(long, default_value_t = 2)]
    pub gutter: u32,
    /// Ray-tracing backend: cpu (obvhs and the heightfield) or embree (needs a build with the
    /// cargo feature `embree`).
    #[arg(long, default_value = "cpu", value_parser = crate::trace::Tracer::parse)]
    pub tracer: crate::trace::Tracer,
}

pub(crate) fn run(args: &LightmapArgs, _g: &Global) -> Result<Outcome> {
    // Refused before any work.
    let refused = |m| crate::error::Error::usage(format!("--tracer {}: {m}", args.tracer.name()));
    args.tracer
        .available_as("lightmap.tracer")
        .map_err(refused)?;
    let (mut w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let opts = LightmapOptions {
        resolution: args.resolution,
        samples: args.samples,
        mode: args.mode,
        max_instances: args.lightmap_max_instances,
        atlas: crate::lightmap::atlas::AtlasOptions {
            tile: args.atlas_tile,
            gutter: args.gutter.max(1),
            ..Default::default()
        },
        tracer: args.tracer,
        ..Default::default()
    };
    let pipeline = crate::graph::Pipeline {
        lightmap: opts,
        ..crate::graph::Pipeline::default()
    };
    let start = std::time::Instant::now();
    // Through the registry's `lightmap` (the terrain's) and `atlas` (the objects') units, the
    // graph's and `bake unit`'s.
    let mut sections = Vec::new();
    for stage in ["lightmap", "atlas"] {
        let o = crate::graph::stage::pack_unit(
            stage,
            &args.input,
            w.sections(),
            &pipeline,
            None,
            None,
            &|_| {},
        )?;
        sections.extend(o.sections);
    }
    let seconds = start.elapsed().as_secs_f64();
    let mut summaries = Vec::new();
    for s in sections {
        let v = crate::pack::section::SectionView::parse(&s.payload, 0)
            .map_err(|e| crate::error::Error::invalid(&output, e))?;
        summaries.push(
            crate::lightmap::section::summary(&v)
                .map_err(|e| crate::error::Error::invalid(&output, e))?,
        );
        w.insert(s);
    }
    w.write(&output)?;
    let doc = serde_json::json!({"output": output, "lightmaps": summaries, "seconds": seconds});
    Ok(Outcome {
        text: format!(
            "{}: {} light map(s) in {seconds:.2} s\n",
            output.display(),
            summaries.len()
        ),
        json: doc,
        warnings: Vec::new(),
    })
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LightmapBenchArgs {
    /// A scene pack with `sh`/`sun` sections (default: the generated fixture scene with its sky).
    pub input: Option<PathBuf>,
    /// Hemisphere samples per texel.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// Repetitions (the best time is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
    /// Ray-tracing backend, as `bake lightmap --tracer`: cpu or embree (needs a build with the
    /// cargo feature `embree`).
    #[arg(long, default_value = "cpu", value_parser = crate::trace::Tracer::parse)]
    pub tracer: crate::trace::Tracer,
    /// Error mode (issue 37): the terrain light map's rows START..END by each estimator of
    /// `--compare` against the ray estimator at `--reference-samples`, per-texel errors and
    /// CPU seconds, in this process.
    #[arg(long, value_name = "START..END")]
    pub rows: Option<String>,
    /// Estimators to compare: VISIBILITY:SAMPLES:SUN_SAMPLES[:LATTICE[:RES[:STEP]]],
    /// comma-separated (VISIBILITY horizons or rays; RES the map's texels per side, sampled
    /// bilinearly at the reference's texels, empty or absent: the reference's; STEP
    /// `lightmap.trace_step`, 1 to 8).
    #[arg(
        long,
        default_value = "rays:64:16,horizons:64:16,horizons:32:8,horizons:16:4,horizons:16:4:2"
    )]
    pub compare: String,
    /// Hemisphere rays of the reference (its sun rays: a quarter of them).
    #[arg(long, default_value_t = 1024)]
    pub reference_samples: u32,
    /// Error mode: texel-space filters applied to each estimator's rows, their error (bias
    /// included) against the reference: KIND:RADIUS[:RANGE], comma-separated; KIND `box` or
    /// `bilateral` (the part without the direct sun filtered) or `bilateral-total` (the whole
    /// irradiance); RANGE the bilateral's relative range (empty: none).
    #[arg(long, default_value = "")]
    pub filters: String,
}

/// `bake bench lightmap` (crate::bench::lightmap).
pub(crate) fn bench(a: &LightmapBenchArgs, _g: &Global) -> Result<Outcome> {
    // Refused before any work, as `bake lightmap` does.
    a.tracer
        .available_as("lightmap.tracer")
        .map_err(|m| crate::error::Error::usage(format!("--tracer {}: {m}", a.tracer.name())))?;
    if let Some(rows) = &a.rows {
        let bad = |m: String| crate::error::Error::usage(m);
        let (s, e) = rows
            .split_once("..")
            .ok_or_else(|| bad(format!("--rows {rows}: expected START..END")))?;
        let parse = |v: &str| {
            v.trim()
                .parse::<u32>()
                .map_err(|e| bad(format!("--rows {rows}: {e}")))
        };
        let configs = a
            .compare
            .split(',')
            .map(crate::bench::lightmap::Estimator::parse)
            .collect::<std::result::Result<Vec<_>, _>>()
            .map_err(bad)?;
        let filters = crate::bench::lightmap::parse_filters(&a.filters).map_err(bad)?;
        let r = crate::bench::lightmap::bench_lightmap_error(
            a.input.as_deref(),
            parse(s)?..parse(e)?,
            &configs,
            a.reference_samples,
            &filters,
        )?;
        return Ok(r.into());
    }
    let r =
        crate::bench::lightmap::bench_lightmap(a.input.as_deref(), a.samples, a.repeat, a.tracer)?;
    Ok(r.into())
}
