//! `bake material IN [-o OUT]`: converts every mesh's materials to two-layer Schlick, processes
//! their textures (linear, mips, coverage, normal maps) and adds MikkTSpace tangents. IN is a
//! pack or any input file (ingested first).

use super::{Global, Outcome};
use crate::error::Result;
use crate::material::MaterialOptions;
use crate::texture::linear::TransferFunction;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct MaterialArgs {
    /// A pack (.bake) or a model file (.txf .3ds .obj .gltf .glb) or scene (.eco).
    pub input: PathBuf,
    /// Output pack (default: the input pack, or <input stem>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Transfer curve of the colour maps' 8-bit values.
    #[arg(long, value_enum, default_value_t = TransferFunction::Srgb)]
    pub transfer: TransferFunction,
    /// Keep the thesis' plain mean alpha in mips (no coverage-preserving scale).
    #[arg(long)]
    pub no_coverage: bool,
}

pub(crate) fn run(args: &MaterialArgs, g: &Global) -> Result<Outcome> {
    let (w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let opts = MaterialOptions {
        transfer: args.transfer,
        preserve_coverage: !args.no_coverage,
    };
    let bar = g.progress(1, "material");
    // Through the registry's `material` unit (the graph's and `bake unit model`'s), over every
    // mesh of the pack at once.
    let pipeline = crate::graph::Pipeline {
        material: opts,
        ..crate::graph::Pipeline::default()
    };
    let o = crate::graph::stage::pack_unit(
        "material",
        &args.input,
        w.sections(),
        &pipeline,
        None,
        None,
        &|_| {},
    )?;
    bar.finish_and_clear();
    let bytes = super::write_pack(w, o.sections, &output)?;
    // The report as the stage made it, with its warnings' messages (the unit returns them apart).
    let mut report = o.report;
    report["warnings"] = o.warnings.iter().map(|w| w.message.clone()).collect();
    let text = format!(
        "{}: {} materials ({} leaf defaults), {} textures, {} meshes with tangents ({} vertices split)\n",
        output.display(),
        report["materials"],
        report["leaf_defaults"],
        report["textures"],
        report["meshes"],
        report["split_vertices"]
    );
    Ok(Outcome::written(
        &report,
        &output,
        bytes.len(),
        text,
        o.warnings,
    ))
}
