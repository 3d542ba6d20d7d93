//! Building blocks of the orchestrator ([`crate::graph`]): a scene's sections from the model,
//! single inputs into packs, the BitTree's area.

use crate::error::Result;
use crate::ingest::confine::SourceNames;
use crate::ingest::{self, IngestOptions, Ingested};
use crate::model::{Mesh, Scene, Terrain};
use crate::pack::PackWriter;
use crate::pack::fit_name;
use rayon::prelude::*;
use std::path::Path;

/// Adds a model's mesh (read from `source`) and its decoded textures, their sources named by
/// `names`. Missing or undecodable textures become warnings (the mesh still renders,
/// untextured).
pub fn add_mesh(
    w: &mut PackWriter,
    model: &str,
    source: &Path,
    names: &SourceNames,
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
                let name = fit_name(crate::texture::source_section::texture_section_name(
                    model, &t.name,
                ));
                w.insert(crate::texture::source_section::to_section(
                    &name,
                    &names.name(&t.path),
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
    let name = fit_name(crate::mesh::section::mesh_section_name(model));
    w.insert(crate::mesh::section::to_section(
        &name,
        &names.name(source),
        mesh,
        &sections,
    ));
}

/// Adds a terrain and its colour map; `source` is the name of the file that named them.
pub fn add_terrain(w: &mut PackWriter, source: &str, t: &Terrain) {
    for s in terrain_sections(source, t) {
        w.insert(s);
    }
}

/// The sections of an ingested terrain: its colour map (if any) and the terrain; `source` is
/// the name ([`SourceNames`]) of the file that named them (the ECO file, or the RAW file).
pub fn terrain_sections(source: &str, t: &Terrain) -> Vec<crate::pack::Section> {
    let mut out = Vec::new();
    let color = t.color.as_ref().map(|img| {
        let name = crate::texture::source_section::texture_section_name("terrain", "color");
        out.push(crate::texture::source_section::to_section(
            &name, source, img,
        ));
        name
    });
    out.push(crate::terrain::source_section::to_section(
        "terrain", source, t, color,
    ));
    out
}

/// Every section of a scene read from `eco`, its files named by `names`.
pub fn scene_to_pack(scene: &Scene, eco: &Path, names: &SourceNames) -> (PackWriter, Vec<String>) {
    let mut w = PackWriter::new();
    let mut warnings = scene.warnings.clone();
    if let Some(t) = &scene.terrain {
        add_terrain(&mut w, &SourceNames::first_name(eco), t);
    }
    let mut mesh_sections = Vec::new();
    for m in &scene.models {
        add_mesh(&mut w, &m.name, &m.path, names, &m.mesh, &mut warnings);
        mesh_sections.push(fit_name(crate::mesh::section::mesh_section_name(&m.name)));
    }
    w.insert(crate::ingest::instances_section::to_section(
        "instances",
        &scene.instances,
        mesh_sections,
    ));
    if let Some(sky) = &scene.sky {
        w.insert(crate::sky::source_section::to_section("sky", "", sky));
    }
    (w, warnings)
}

/// `bake ingest INPUT`: one input file into a pack.
pub fn ingest_to_pack(input: &Path, opts: &IngestOptions) -> Result<(PackWriter, Vec<String>)> {
    let mut w = PackWriter::new();
    let mut warnings = Vec::new();
    let names = ingest::eco::scene_names(input, opts);
    match ingest::ingest_file(input, opts)? {
        Ingested::Mesh(mesh) => {
            let name = input
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            warnings.extend(mesh.warnings.iter().cloned());
            add_mesh(&mut w, &name, input, &names, &mesh, &mut warnings);
        }
        Ingested::Terrain(t) => add_terrain(&mut w, &SourceNames::first_name(input), &t),
        Ingested::Sky(img) => w.insert(crate::sky::source_section::to_section(
            "sky",
            &SourceNames::first_name(input),
            &img,
        )),
        Ingested::Scene(scene) => {
            let (sw, sw_warn) = scene_to_pack(&scene, input, &names);
            w = sw;
            warnings = sw_warn;
        }
    }
    Ok((w, warnings))
}

/// The material and terrain stages over a pack being built (`bake SCENE.eco` runs them after
/// ingest, like `bake material` and `bake terrain` would): materials, processed textures and
/// tangents, then the prepared terrain. Returns the stages' warnings.
pub fn prepare_assets(
    w: &mut PackWriter,
    opts: &crate::material::MaterialOptions,
) -> Result<Vec<String>> {
    let pack = w.view("(pack being built)");
    let (sections, report) = crate::material::bake_materials(&pack, opts)?;
    let (terrain, _) = crate::terrain::bake_terrain(&pack)?;
    for s in sections.into_iter().chain(terrain) {
        w.insert(s);
    }
    Ok(report.warnings)
}
