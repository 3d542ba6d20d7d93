//! `bake build SCENE.eco...` (also plain `bake SCENE.eco`): the whole scene into one pack.

use super::{Global, Outcome};
use crate::error::Result;
use crate::ingest::IngestOptions;
use crate::pipeline::{BuildOptions, build};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct BuildArgs {
    /// One or more ECO files of one scene.
    #[arg(required = true)]
    pub scenes: Vec<PathBuf>,
    /// Output pack (default: next to the first scene as <stem>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// HDR sky (.hdr or .exr, lat-long).
    #[arg(long)]
    pub sky: Option<PathBuf>,
    /// Extra folders searched for model files (after the ECO file's folder).
    #[arg(long = "models", value_name = "DIR")]
    pub models: Vec<PathBuf>,
    /// Colour map of the terrain (default: beside the RAW file).
    #[arg(long)]
    pub color_map: Option<PathBuf>,
    /// Quick, noisy lighting (PRT 64 paths, 64 environment-map rays, 16 light-map rays).
    #[arg(long)]
    pub preview: bool,
    /// Render the baked pack to this PNG afterwards (default camera).
    #[arg(long, value_name = "PNG")]
    pub render: Option<PathBuf>,
}

pub fn run(args: &BuildArgs, g: &Global) -> Result<Outcome> {
    let opts = BuildOptions {
        scenes: args.scenes.clone(),
        output: args.output.clone(),
        sky: args.sky.clone(),
        ingest: IngestOptions {
            model_dirs: args.models.clone(),
            color_map: args.color_map.clone(),
            ..g.ingest_defaults()
        },
        ..Default::default()
    };
    let opts = if args.preview { opts.preview() } else { opts };
    let bar = g.progress(1, "build");
    let report = build(&opts)?;
    bar.finish_and_clear();
    let mut text = format!(
        "{}: {} sections, {} bytes; {} models ({} triangles), {} instances\n",
        report.output.display(),
        report.sections,
        report.bytes,
        report.models,
        report.triangles,
        report.instances
    );
    let mut json = serde_json::to_value(&report).unwrap_or_default();
    let mut warnings = report.warnings;
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
