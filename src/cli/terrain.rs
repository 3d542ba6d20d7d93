//! `bake terrain IN [-o OUT]`: prepares every terrain of a pack (or of a RAW/ECO input, ingested
//! first): the four-tap height texture, the normal map and the min/max quadtree.

use super::{Global, Outcome, parse_size};
use crate::error::Result;
use crate::ingest::IngestOptions;
use crate::pack::PackWriter;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct TerrainArgs {
    /// A pack (.bake), a RAW height map or an ECO scene.
    pub input: PathBuf,
    /// Output pack (default: the input pack, or <input stem>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// RAW size in samples, WxH.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// RAW metres per sample step.
    #[arg(long)]
    pub scale: Option<f32>,
}

/// A pack stays a pack; anything else is ingested with the RAW options.
fn open(args: &TerrainArgs) -> Result<(PackWriter, PathBuf)> {
    let is_pack = args
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bake"));
    if is_pack {
        return super::open_or_ingest(&args.input, args.output.clone());
    }
    let opts = IngestOptions {
        size: args.size,
        scale: args.scale,
        ..Default::default()
    };
    let (w, _) = crate::pipeline::ingest_to_pack(&args.input, &opts)?;
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| Path::new(&args.input).with_extension("bake"));
    Ok((w, out))
}

pub(crate) fn run(args: &TerrainArgs, g: &Global) -> Result<Outcome> {
    let (w, output) = open(args)?;
    let bar = g.progress(1, "terrain");
    // Through the registry's `terrain` unit (the graph's and `bake unit terrain`'s).
    let o = crate::graph::stage::pack_unit(
        "terrain",
        &args.input,
        w.sections(),
        &crate::graph::Pipeline::default(),
        None,
        None,
        &|_| {},
    )?;
    bar.finish_and_clear();
    let report = o.report;
    let warnings = if report["terrains"] == 0 {
        crate::diag::tagged(
            &crate::terrain::stage::TERRAIN_NONE,
            [format!(
                "{}: no terrain section to prepare",
                args.input.display()
            )],
        )
    } else {
        Vec::new()
    };
    let bytes = super::write_pack(w, o.sections, &output)?;
    let text = format!(
        "{}: {} terrain(s), {} samples, quadtree levels {:?}\n",
        output.display(),
        report["terrains"],
        report["samples"],
        report["quadtree_levels"]
            .as_array()
            .map(|l| l.iter().filter_map(|v| v.as_u64()).collect::<Vec<_>>())
            .unwrap_or_default()
    );
    Ok(Outcome::written(
        &report,
        &output,
        bytes.len(),
        text,
        warnings,
    ))
}
