//! The orchestrator: a flat list of stage calls from inputs to a pack.
//!
//! Each function takes the model (or a pack) and options and returns the pack sections; file
//! writing happens only in [`crate::pack::PackWriter::write`].

use crate::error::Result;
use crate::ingest::{self, IngestOptions, Ingested};
use crate::model::{Mesh, Scene, Terrain};
use crate::pack::PackWriter;
use crate::pack::kinds::{self, fit_name};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What a build did, for the report printed by the CLI.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct BuildReport {
    pub output: PathBuf,
    pub sections: usize,
    pub bytes: u64,
    pub models: usize,
    pub instances: usize,
    pub triangles: u64,
    pub warnings: Vec<String>,
}

/// Adds a model's mesh and its decoded textures. Missing or undecodable textures become warnings
/// (the mesh still renders, untextured).
pub fn add_mesh(
    w: &mut PackWriter,
    model: &str,
    source: &Path,
    mesh: &Mesh,
    warnings: &mut Vec<String>,
) {
    let decoded: Vec<_> = mesh
        .textures
        .par_iter()
        .map(|t| ingest::texture::load(&t.path))
        .collect();
    let mut sections = Vec::with_capacity(decoded.len());
    for (t, img) in mesh.textures.iter().zip(decoded) {
        match img {
            Ok(img) => {
                let name = fit_name(kinds::texture_section_name(model, &t.name));
                w.insert(kinds::texture::to_section(
                    &name,
                    &t.path.display().to_string(),
                    &img,
                ));
                sections.push(Some(name));
            }
            Err(e) => {
                warnings.push(format!("texture {:?} of {model} skipped: {e}", t.name));
                sections.push(None);
            }
        }
    }
    let name = fit_name(kinds::mesh_section_name(model));
    w.insert(kinds::mesh::to_section(
        &name,
        &source.display().to_string(),
        mesh,
        &sections,
    ));
}

/// Adds a terrain and its colour map.
pub fn add_terrain(w: &mut PackWriter, source: &Path, t: &Terrain) {
    let color = t.color.as_ref().map(|img| {
        let name = kinds::texture_section_name("terrain", "color");
        w.insert(kinds::texture::to_section(
            &name,
            &source.display().to_string(),
            img,
        ));
        name
    });
    w.insert(kinds::terrain::to_section(
        "terrain",
        &source.display().to_string(),
        t,
        color,
    ));
}

/// Every section of a scene.
pub fn scene_to_pack(scene: &Scene, eco: &Path) -> (PackWriter, Vec<String>) {
    let mut w = PackWriter::new();
    let mut warnings = scene.warnings.clone();
    if let Some(t) = &scene.terrain {
        add_terrain(&mut w, eco, t);
    }
    let mut mesh_sections = Vec::new();
    for m in &scene.models {
        add_mesh(&mut w, &m.name, &m.path, &m.mesh, &mut warnings);
        mesh_sections.push(fit_name(kinds::mesh_section_name(&m.name)));
    }
    w.insert(kinds::instances::to_section(
        "instances",
        &scene.instances,
        mesh_sections,
    ));
    if let Some(sky) = &scene.sky {
        w.insert(kinds::sky::to_section("sky", "", sky));
    }
    (w, warnings)
}

/// Options of `bake build`.
#[derive(Debug, Clone, Default)]
pub struct BuildOptions {
    pub scenes: Vec<PathBuf>,
    pub output: Option<PathBuf>,
    pub sky: Option<PathBuf>,
    pub ingest: IngestOptions,
}

/// `bake SCENE.eco`: ingest the whole scene into one pack.
pub fn build(opts: &BuildOptions) -> Result<BuildReport> {
    let first = opts
        .scenes
        .first()
        .ok_or_else(|| crate::error::Error::usage("no scene given"))?;
    let mut scene = ingest::eco::load_scene(&opts.scenes, &opts.ingest)?;
    if let Some(sky) = &opts.sky {
        scene.sky = Some(ingest::skyimage::load(sky)?);
    }
    let output = opts
        .output
        .clone()
        .unwrap_or_else(|| first.with_extension("bake"));
    let (w, warnings) = scene_to_pack(&scene, first);
    let bytes = w.to_bytes()?;
    crate::pack::write_atomic(&output, &bytes)?;
    Ok(BuildReport {
        output,
        sections: w.sections().len(),
        bytes: bytes.len() as u64,
        models: scene.models.len(),
        instances: scene.instances.items.len(),
        triangles: scene
            .models
            .iter()
            .map(|m| m.mesh.indices.len() as u64)
            .sum(),
        warnings,
    })
}

/// `bake ingest INPUT`: one input file into a pack.
pub fn ingest_to_pack(input: &Path, opts: &IngestOptions) -> Result<(PackWriter, Vec<String>)> {
    let mut w = PackWriter::new();
    let mut warnings = Vec::new();
    match ingest::ingest_file(input, opts)? {
        Ingested::Mesh(mesh) => {
            let name = input
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            warnings.extend(mesh.warnings.iter().cloned());
            add_mesh(&mut w, &name, input, &mesh, &mut warnings);
        }
        Ingested::Terrain(t) => add_terrain(&mut w, input, &t),
        Ingested::Sky(img) => w.insert(kinds::sky::to_section(
            "sky",
            &input.display().to_string(),
            &img,
        )),
        Ingested::Scene(scene) => {
            let (sw, sw_warn) = scene_to_pack(&scene, input);
            w = sw;
            warnings = sw_warn;
        }
    }
    Ok((w, warnings))
}
