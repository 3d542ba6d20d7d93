//! The orchestrator: a flat list of stage calls from inputs to a pack.
//!
//! Each function takes the model (or a pack) and options and returns the pack sections; file
//! writing happens only in [`crate::pack::PackWriter::write`].

use crate::error::Result;
use crate::ingest::{self, IngestOptions, Ingested};
use crate::model::{Mesh, Scene, Terrain};
use crate::pack::kinds::{self, fit_name};
use crate::pack::{Pack, PackWriter};
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
    pub prt: crate::light::prt::PrtOptions,
    pub lightmap: crate::lightmap::LightmapOptions,
    pub envmaps: crate::envmap::bake::EnvmapOptions,
    pub cluster: crate::envmap::cluster::ClusterOptions,
}

impl BuildOptions {
    /// Quick, noisy lighting for previews.
    pub fn preview(mut self) -> Self {
        self.prt = crate::light::prt::PrtOptions::preview();
        self.envmaps.samples = 64;
        self.lightmap.samples = 16;
        self.lightmap.sun_samples = 4;
        self
    }
}

/// `bake SCENE.eco`: every stage, in data-flow order, into one pack.
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
    let name = first.display().to_string();
    let (mut w, mut warnings) = scene_to_pack(&scene, first);
    // Materials, processed textures, tangents (which may split mesh vertices) and the prepared
    // terrain before any stage reads the meshes.
    warnings.extend(prepare_assets(
        &mut w,
        &crate::material::MaterialOptions::default(),
    )?);
    // The sky first: every lighting stage reads its sun and SH (the built-in sky if none given).
    for s in crate::sky::scene_sky_sections(
        scene.sky.as_ref(),
        &crate::sky::builtin::BuiltinSky::default(),
        &crate::sky::SkyOptions::default(),
    )? {
        w.insert(s);
    }
    // Per-model transfer, then the scene-level lighting that traces the placed models.
    let pack = Pack::from_bytes(&w.to_bytes()?, &name)?;
    let (pw, _, prt_warnings) = crate::light::prt_pack::prt_pack(&pack, &opts.prt, &|_| {})?;
    w = pw;
    warnings.extend(prt_warnings);
    let pack = Pack::from_bytes(&w.to_bytes()?, &name)?;
    for s in crate::lightmap::lightmap_sections(&pack, &opts.lightmap)? {
        w.insert(s);
    }
    for s in crate::lightmap::atlas_sections(&pack, &opts.lightmap)? {
        w.insert(s);
    }
    for s in crate::envmap::envmap_sections(&pack, &opts.envmaps)? {
        w.insert(s);
    }
    let pack = Pack::from_bytes(&w.to_bytes()?, &name)?;
    let (sections, _) = crate::envmap::cluster_sections(&pack, &opts.cluster, false)?;
    for s in sections {
        w.insert(s);
    }
    match crate::bittree::section::to_section(
        "bittree",
        &scene.instances,
        instance_area(&scene),
        &Default::default(),
    ) {
        Ok(s) => w.insert(s),
        Err(e) => warnings.push(format!("no BitTree: {e}")),
    }
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

/// The area the BitTree discretizes: the scene's area of interest, widened to hold every instance.
pub fn instance_area(scene: &Scene) -> crate::model::Rect {
    let pts: Vec<[f32; 3]> = scene.instances.items.iter().map(|i| i.position).collect();
    let (lo, hi) = crate::model::bounds_of(&pts).unwrap_or(([0.0; 3], [1.0; 3]));
    let a = scene.aoi;
    let x0 = a.origin[0].min(lo[0]) - 1e-3;
    let y0 = a.origin[1].min(lo[1]) - 1e-3;
    let x1 = (a.origin[0] + a.extent[0]).max(hi[0]) + 1e-3;
    let y1 = (a.origin[1] + a.extent[1]).max(hi[1]) + 1e-3;
    crate::model::Rect {
        origin: [x0, y0],
        extent: [x1 - x0, y1 - y0],
    }
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

/// The material and terrain stages over a pack being built (`bake SCENE.eco` runs them after
/// ingest, like `bake material` and `bake terrain` would): materials, processed textures and
/// tangents, then the prepared terrain. Returns the stages' warnings.
pub fn prepare_assets(
    w: &mut PackWriter,
    opts: &crate::material::MaterialOptions,
) -> Result<Vec<String>> {
    let pack = crate::pack::Pack::from_bytes(&w.to_bytes()?, "(pack being built)")?;
    let (sections, report) = crate::material::bake_materials(&pack, opts)?;
    let (terrain, _) = crate::terrain::bake_terrain(&pack)?;
    for s in sections.into_iter().chain(terrain) {
        w.insert(s);
    }
    Ok(report.warnings)
}
