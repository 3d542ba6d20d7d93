//! `bake mitsuba PACK -o DIR`: the placed scene as a Mitsuba 3 scene for the ground-truth
//! harness (see src/mitsuba.rs, scripts/groundtruth/).

use super::{Global, Outcome};
use crate::error::Result;
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct MitsubaArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    /// Output folder (scene.xml, direct.xml, geometry.xml, meshes/, textures/, sky.exr, ...).
    #[arg(short, long)]
    pub output: PathBuf,
    /// The view, as `bake render`'s.
    #[command(flatten)]
    pub camera: super::render::ViewArgs,
    /// Rows of the envmap (0: four times the sky cube's face size, plus one, at most 2049).
    #[arg(long, default_value_t = 0)]
    pub envmap_height: u32,
    /// Default `max_depth` of scene.xml's volpath integrator.
    #[arg(long, default_value_t = 12)]
    pub max_depth: u32,
    /// Each model as a shapegroup with one instance per record (default: one world-space mesh
    /// per model and material; Mitsuba's JIT variants compile each instance into the kernel).
    #[arg(long)]
    pub shapegroups: bool,
}

pub(crate) fn run(args: &MitsubaArgs, _g: &Global) -> Result<Outcome> {
    let view = args.camera.options();
    let opts = crate::mitsuba::ExportOptions {
        envmap_height: args.envmap_height,
        max_depth: args.max_depth,
        instancing: args.shapegroups,
    };
    let pack = Pack::open(&args.pack)?;
    let s = crate::mitsuba::export(&pack, &view, &opts, &args.output)?;
    let text = format!(
        "{}: Mitsuba scene, {} instances of {} models ({} shapes), {} terrain triangles, \
         {} Schlick and {} diffuse materials ({} masked), envmap {}×{}\n",
        args.output.display(),
        s.instances,
        s.models,
        s.shapes,
        s.terrain_triangles,
        s.schlick_materials,
        s.diffuse_materials,
        s.masked_materials,
        s.envmap[0],
        s.envmap[1]
    );
    Ok(Outcome {
        json: serde_json::to_value(&s).expect("JSON of plain values"),
        text,
        warnings: s.warnings,
    })
}
