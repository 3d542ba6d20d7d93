//! `bake ingest INPUT`: any single input file into a pack.

use super::{Global, Outcome, parse_size};
use crate::error::Result;
use crate::ingest::IngestOptions;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct IngestArgs {
    /// A .txf .3ds .obj .gltf .glb .raw .hdr .exr or .eco file.
    pub input: PathBuf,
    /// Output pack (default: <input stem>.bake beside the input).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// RAW size in samples, WxH.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// RAW metres per sample step.
    #[arg(long)]
    pub scale: Option<f32>,
    /// Extra folders searched for model files (ECO input).
    #[arg(long = "models", value_name = "DIR")]
    pub models: Vec<PathBuf>,
}

pub(crate) fn run(args: &IngestArgs, g: &Global) -> Result<Outcome> {
    let opts = IngestOptions {
        size: args.size,
        scale: args.scale,
        model_dirs: args.models.clone(),
        color_map: None,
        ..g.ingest_defaults()
    };
    let (w, warnings) = crate::pipeline::ingest_to_pack(&args.input, &opts)?;
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| args.input.with_extension("bake"));
    let bytes = w.to_bytes()?;
    crate::pack::write_atomic(&output, &bytes)?;
    let sections: Vec<_> = w
        .sections()
        .iter()
        .map(|s| serde_json::json!({"name": s.name, "kind": s.kind, "bytes": s.payload.len()}))
        .collect();
    Ok(Outcome {
        json: serde_json::json!({"output": output, "bytes": bytes.len(), "sections": sections}),
        text: format!(
            "{}: {} sections, {} bytes\n",
            output.display(),
            sections.len(),
            bytes.len()
        ),
        warnings: crate::diag::tagged(&crate::diag::INGEST_READER, warnings),
    })
}
