//! `bake envmaps INPUT`: per-instance SH environment maps (section `envmaps`).

use super::{Global, Outcome};
use crate::envmap::bake::EnvmapOptions;
use crate::error::Result;
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct EnvmapsArgs {
    /// A scene pack (with `sh`/`sun` sections from `bake sky` or `bake build`).
    pub input: PathBuf,
    /// Output pack (default: the input pack).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Rays per instance.
    #[arg(long, default_value_t = 256)]
    pub samples: u32,
    /// Ray-tracing backend: cpu (obvhs and the heightfield) or embree (needs a build with the
    /// cargo feature `embree`).
    #[arg(long, default_value = "cpu", value_parser = crate::trace::Tracer::parse)]
    pub tracer: crate::trace::Tracer,
    /// Trace one rotated N-point set per instance instead of two independently rotated halves
    /// (no noise estimate in the section; the cluster stage then cannot denoise).
    #[arg(long)]
    pub no_noise_estimate: bool,
}

pub(crate) fn run(args: &EnvmapsArgs, _g: &Global) -> Result<Outcome> {
    // Refused before any work.
    let refused = |m| crate::error::Error::usage(format!("--tracer {}: {m}", args.tracer.name()));
    args.tracer
        .available_as("envmaps.tracer")
        .map_err(refused)?;
    let (mut w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let pipeline = crate::graph::Pipeline {
        envmaps: EnvmapOptions {
            samples: args.samples,
            tracer: args.tracer,
            noise_estimate: !args.no_noise_estimate,
            ..Default::default()
        },
        ..crate::graph::Pipeline::default()
    };
    let start = std::time::Instant::now();
    // Through the registry's `envmaps` unit (the graph's and `bake unit envmaps`'s): one shard
    // of every instance, joined into the `envmaps` section.
    let o = crate::graph::stage::pack_unit(
        "envmaps",
        &args.input,
        w.sections(),
        &pipeline,
        None,
        Some(crate::graph::stage::Shard::Of(0, 1)),
        &|_| {},
    )?;
    let n = o.report["instances"].as_u64().unwrap_or(0) as usize;
    let sections = crate::graph::stage::join_units("envmaps", vec![(n, o.sections)], &pipeline)?;
    let seconds = start.elapsed().as_secs_f64();
    let n = sections.len();
    for s in sections {
        w.insert(s);
    }
    w.write(&output)?;
    let out = Pack::open(&output)?;
    let mut doc = crate::envmap::section::envmaps_summary(&out.view_named("envmaps")?)
        .map_err(|e| crate::error::Error::invalid(&output, e))?;
    doc["seconds"] = seconds.into();
    Ok(Outcome {
        text: format!("{}: {n} envmaps section, {doc}\n", output.display()),
        json: doc,
        warnings: Vec::new(),
    })
}
