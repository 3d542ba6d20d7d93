//! `bake build SCENE.eco...` (also plain `bake SCENE.eco`): the whole scene into one pack,
//! through the cached stage graph ([`crate::graph`]).

use super::{Global, Outcome};
use crate::error::Result;
use crate::graph::{BuildOptions, CacheMode, build, progress};
use std::path::PathBuf;

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub(crate) enum ProgressMode {
    /// Bars on a terminal, nothing otherwise.
    #[default]
    Auto,
    /// One JSON event per line on stderr.
    Ndjson,
    None,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct BuildArgs {
    #[command(flatten)]
    pub scene: super::scene::SceneFlags,
    /// Output pack (default: next to the first scene as <stem>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Stage cache folder (default: $BAKE_CACHE, else $XDG_CACHE_HOME/bake, else ~/.cache/bake).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Compute every unit, use and fill no cache, rewrite an up-to-date output.
    #[arg(long, conflicts_with = "cache")]
    pub no_cache: bool,
    /// Write every file the bake read as a Makefile rule (for Ninja, Make, cargo).
    #[arg(long, value_name = "FILE")]
    pub depfile: Option<PathBuf>,
    /// Progress display on stderr.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
    /// Render the baked pack to this PNG afterwards (default camera).
    #[arg(long, value_name = "PNG")]
    pub render: Option<PathBuf>,
    /// Keep the build report in the pack (a `build_report` section) instead of beside it as
    /// PACK.report.json. The report holds wall times: the pack is then no longer the same bytes
    /// from run to run.
    #[arg(long)]
    pub embed_report: bool,
}

/// The pipeline of `--pipeline`/`--preview`/`--set`, and the file it came from.
pub(crate) use crate::graph::preset::resolve as resolve_pipeline;

pub(crate) fn run(args: &BuildArgs, g: &Global) -> Result<Outcome> {
    let (pipeline, pipeline_file) = args.scene.pipeline()?;
    let opts = BuildOptions {
        scenes: args.scene.scenes.clone(),
        output: args.output.clone(),
        sky: args.scene.sky.clone(),
        ingest: args.scene.ingest(g),
        pipeline,
        pipeline_file,
        cache: match (&args.cache, args.no_cache) {
            (_, true) => CacheMode::Off,
            (Some(d), false) => CacheMode::Dir(d.clone()),
            (None, false) => CacheMode::Default,
        },
        depfile: args.depfile.clone(),
        bake_version: None,
    };
    let report = match (args.progress, g.quiet) {
        (ProgressMode::Ndjson, _) => build(&opts, &progress::Ndjson::default())?,
        (ProgressMode::None, _) | (_, true) => build(&opts, &progress::Silent)?,
        (ProgressMode::Auto, false) => {
            if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
                build(&opts, &progress::Terminal::default())?
            } else {
                build(&opts, &progress::Silent)?
            }
        }
    };
    let mut text = format!(
        "{}: {} sections, {} bytes; {} models ({} triangles), {} instances{}\n",
        report.output.display(),
        report.sections,
        report.bytes,
        report.models,
        report.triangles,
        report.instances,
        if report.up_to_date {
            " (up to date)".to_string()
        } else {
            format!(
                "; {:.2} s ({:.2} CPU s), {} units ({} cached)",
                report.wall_seconds,
                report.cpu_seconds,
                report.stages.len(),
                report.cache_hits
            )
        }
    );
    let mut json = serde_json::to_value(&report).unwrap_or_default();
    // The record of the bake that wrote the pack (`bake report`): beside it, or in it.
    if !report.up_to_date {
        let sidecar = crate::report::sidecar_path(&report.output);
        if args.embed_report {
            crate::report::embed(&json, &report.output)?;
            match std::fs::remove_file(&sidecar) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(crate::error::Error::io(&sidecar, e)),
            }
        } else {
            crate::report::write_sidecar(&json, &report.output)?;
        }
    }
    let mut warnings = report.warnings.clone();
    if let Some(png) = &args.render {
        let pack = crate::pack::Pack::open(&report.output)?;
        let out = crate::render::render_pack(&pack, &crate::render::RenderOptions::default())?;
        crate::pack::write_atomic(png, &crate::render::encode_png(&out.image)?)?;
        text.push_str(&format!(
            "{}: {}×{} on {}\n",
            png.display(),
            out.stats.width,
            out.stats.height,
            out.adapter
        ));
        json["render"] =
            serde_json::json!({"output": png, "adapter": out.adapter, "stats": out.stats});
        warnings.extend(out.warnings);
    }
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}
