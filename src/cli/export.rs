//! `bake export PACK -o scene.glb`: the pack as a glTF 2.0 scene ([`crate::export`]).

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::export::{Container, ExportOptions, export};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ExportArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    /// The scene to write: `.glb` (binary glTF) or `.gltf` (JSON, its buffer in a side file
    /// `<stem>-<content hash>.bin` beside it; `--embed-buffer` embeds it instead).
    #[arg(short, long, value_name = "GLB")]
    pub output: PathBuf,
    /// Multiply the terrain's light map (direct sun with its shadows, sky, bounce) into its base
    /// colour and mark the material unlit (`KHR_materials_unlit`), so that viewers without
    /// light-map support show the baked light (docs/MATERIALS.md, "Export to glTF").
    #[arg(long)]
    pub bake_light: bool,
    /// Write every model vertex's PRT ambient (the renderer's eq. 4.8 under the pack's light,
    /// averaged over the model's instances) as `COLOR_0`, divided by one scale for the file so
    /// that the brightest vertex is 1 (docs/MATERIALS.md, "Export to glTF"). Needs `prt` sections.
    #[arg(long)]
    pub vertex_ambient: bool,
    /// Export every model's levels of detail (the `lod` sections' mesh levels 1..) as meshes on
    /// nodes that the model node names through `MSFT_lod` (with `MSFT_screencoverage` and bake's
    /// selection rule in its extras), for viewers that pick a level (docs/MATERIALS.md).
    #[arg(long)]
    pub lod: bool,
    /// Export the materials' normal maps as `normalTexture` (linear PNG, glTF's tangent frame)
    /// with the pack's tangents as `TANGENT` (docs/MATERIALS.md).
    #[arg(long)]
    pub normal_maps: bool,
    /// Export the terrain at every N-th grid sample (and its last row and column): N² fewer
    /// triangles; the largest height error against the full grid is reported
    /// (`terrain_max_error_m`; docs/MATERIALS.md). 1: every sample.
    #[arg(long, value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub terrain_step: u32,
    /// `.gltf`: embed the buffer as a base64 data URI (one file, a third larger) instead of
    /// writing it beside the `.gltf`.
    #[arg(long)]
    pub embed_buffer: bool,
}

pub(crate) fn run(args: &ExportArgs, _g: &Global) -> Result<Outcome> {
    let ext = args
        .output
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let container = match ext.as_deref() {
        Some("glb") => Container::Glb,
        Some("gltf") if args.embed_buffer => Container::GltfEmbedded,
        Some("gltf") => Container::GltfSideFile,
        _ => {
            return Err(Error::usage(format!(
                "{}: the output must end in .glb or .gltf",
                args.output.display()
            )));
        }
    };
    if args.embed_buffer && container != Container::GltfEmbedded {
        return Err(Error::usage(format!(
            "{}: --embed-buffer is for .gltf output (a .glb holds its buffer)",
            args.output.display()
        )));
    }
    let pack = Pack::open(&args.pack)?;
    let opts = ExportOptions {
        container,
        bake_light: args.bake_light,
        vertex_ambient: args.vertex_ambient,
        lod: args.lod,
        normal_maps: args.normal_maps,
        terrain_step: args.terrain_step,
    };
    // Written to a temporary file and renamed, as packs are: a failed run leaves no output.
    let report = export(&pack, opts, &args.output)?;
    let text = format!(
        "{}{}: {} bytes; {} models, {} instances, {} meshes, {} materials, {} textures, {} terrain chunks{}{}{}{}{}\n",
        args.output.display(),
        report
            .side_file
            .as_ref()
            .map_or(String::new(), |f| format!(" (buffer {f})")),
        report.bytes,
        report.models,
        report.instances,
        report.meshes,
        report.materials,
        report.textures,
        report.terrain_chunks,
        if report.terrain_step > 1 {
            format!(
                " (terrain step {}, height error ≤ {:.3} m)",
                report.terrain_step, report.terrain_max_error_m
            )
        } else {
            String::new()
        },
        report.lightmap.as_ref().map_or(String::new(), |l| format!(
            ", light map {l}{}",
            if report.bake_light {
                " (baked into the base colour)"
            } else {
                ""
            }
        )),
        report
            .sun_lux
            .map_or(String::new(), |l| format!(", sun {l:.0} lx")),
        if report.lod_meshes > 0 {
            format!(", {} LOD meshes (MSFT_lod)", report.lod_meshes)
        } else {
            String::new()
        },
        report
            .vertex_ambient_scale
            .map_or(String::new(), |s| format!(
                ", COLOR_0 on {} models (scale {s:.4} W/m²/sr)",
                report.vertex_ambient_models
            ))
    );
    let warnings = report.warnings.clone();
    Ok(Outcome::written(
        &report,
        &args.output,
        report.bytes,
        text,
        warnings,
    ))
}
