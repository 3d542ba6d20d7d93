//! `bake mitsuba PACK -o DIR`: the placed scene as a Mitsuba 3 scene for the ground-truth
//! harness (see src/mitsuba.rs, scripts/groundtruth/).

use super::{Global, Outcome, parse_vec3};
use crate::error::Result;
use crate::pack::Pack;
use crate::render::RenderOptions;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct MitsubaArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    /// Output folder (scene.xml, direct.xml, geometry.xml, meshes/, textures/, sky.exr, ...).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Image width in pixels (as `bake render --width`).
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Camera position x,y,z in metres (default: `bake render`'s framing).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<[f32; 3]>,
    /// Point looked at x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<[f32; 3]>,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = crate::render::camera::DEFAULT_FOV_Y_DEG)]
    pub fov: f32,
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

pub fn run(args: &MitsubaArgs, _g: &Global) -> Result<Outcome> {
    let view = RenderOptions {
        width: args.width,
        height: args.height,
        eye: args.eye,
        target: args.target,
        fov_y_deg: args.fov,
        ..RenderOptions::default()
    };
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
