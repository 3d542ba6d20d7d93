//! `bake svo INPUT`: voxelize a model or a pack (its meshes, or its whole scene) into a sparse
//! voxel octree section.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::stage::{CommandScope, pack_sections, scene_unit};
use crate::ingest::limits::Limits;
use crate::pack::{Pack, PackWriter};
use crate::voxel::geometry::{Geometry, SceneStage, pack_geometry, placed_size};
use crate::voxel::section;
use crate::voxel::svo::voxels_to_svo;
use crate::voxel::voxelize::{VoxelizeOptions, mesh_to_voxels};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct SvoArgs {
    /// A model (.txf .3ds .obj .gltf .glb) or a .bake pack with mesh sections or a scene.
    pub input: PathBuf,
    /// Output pack (default: the input pack itself, or <model>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Voxels along the longest axis of the bounds.
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=(1 << 21)))]
    pub resolution: u32,
    /// Fill the inside of closed meshes too.
    #[arg(long)]
    pub solid: bool,
}

/// Whether a path is a pack (by extension).
pub(crate) fn is_pack(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bake"))
}

/// Reads the geometry of a model file or a pack for `stage`; missing textures become warnings.
/// A pack's placed scene is checked against the memory budget before it is built.
pub(crate) fn load_geometry(
    path: &Path,
    stage: SceneStage,
    limits: &Limits,
    warnings: &mut Vec<String>,
) -> Result<(Geometry, Option<Pack>)> {
    if is_pack(path) {
        let pack = Pack::open(path)?;
        placed_size(&pack)?.check(stage, limits, path)?;
        let g = pack_geometry(&pack)?;
        return Ok((g, Some(pack)));
    }
    let mesh = crate::ingest::load_mesh(path)?;
    warnings.extend(mesh.warnings.iter().cloned());
    let mut textures = Vec::with_capacity(mesh.textures.len());
    for t in &mesh.textures {
        match crate::ingest::texture::load(&t.path) {
            Ok(img) => textures.push(Some(img)),
            Err(e) => {
                warnings.push(format!(
                    "texture {:?} skipped (voxels untextured): {e}",
                    t.name
                ));
                textures.push(None);
            }
        }
    }
    Ok((Geometry { mesh, textures }, None))
}

/// The pack an output starts from: the input pack's sections, or for a model input its mesh
/// (so `bake linespace` and later stages can chain on the output).
pub(crate) fn start_pack(
    input: &Path,
    pack: Option<&Pack>,
    geo: &Geometry,
    warnings: &mut Vec<String>,
) -> PackWriter {
    match pack {
        Some(p) => PackWriter::from_pack(p),
        None => {
            let mut w = PackWriter::new();
            let name = input
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let names = crate::ingest::confine::SourceNames::around(input);
            crate::pipeline::add_mesh(&mut w, &name, input, &names, &geo.mesh, warnings);
            w
        }
    }
}

pub(crate) fn run(args: &SvoArgs, g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let limits = g.ingest_defaults().limits;
    if is_pack(&args.input) {
        return run_pack(args, &limits);
    }
    let (geo, pack) = load_geometry(&args.input, SceneStage::Svo, &limits, &mut warnings)?;
    if geo.mesh.indices.is_empty() {
        return Err(Error::invalid_at(
            &args.input,
            "geometry",
            "no triangles to voxelize",
        ));
    }
    let opts = VoxelizeOptions {
        solid: args.solid,
        ..VoxelizeOptions::surface(args.resolution)
    };
    let start = std::time::Instant::now();
    let voxels = mesh_to_voxels(&geo.mesh, &geo.textures, &opts)?;
    let svo = voxels_to_svo(&voxels);
    let seconds = start.elapsed().as_secs_f64();
    let mut own = Vec::new();
    if voxels.skipped_triangles > 0 {
        own.push(crate::diag::Warning::new(
            &crate::voxel::stage::SVO_TRIANGLES_WITHOUT_VOXEL,
            "",
            format!(
                "{} triangles left no voxel (outside the grid or alpha-tested away)",
                voxels.skipped_triangles
            ),
        ));
    }
    if voxels.open_columns > 0 {
        own.push(crate::diag::Warning::new(&crate::voxel::stage::SVO_MESH_NOT_CLOSED, "", format!(
            "solid fill: {} columns crossed the surface an odd number of times (mesh not closed)",
            voxels.open_columns
        )));
    }
    let output = args.output.clone().unwrap_or_else(|| match &pack {
        Some(_) => args.input.clone(),
        None => args.input.with_extension("bake"),
    });
    let mut w = start_pack(&args.input, pack.as_ref(), &geo, &mut warnings);
    let source = crate::ingest::confine::SourceNames::first_name(&args.input);
    w.insert(section::to_section("svo", &source, &svo, args.solid));
    w.write(&output)?;
    let mut json = section::summary_of(&svo);
    json["output"] = serde_json::json!(output);
    json["seconds"] = serde_json::json!(seconds);
    json["triangles"] = serde_json::json!(geo.mesh.indices.len());
    let text = format!(
        "{}: svo {:?} voxels, {} voxels, {} nodes, {:.3} B/voxel topology, {:.2} B/voxel total ({:.3} s)\n",
        output.display(),
        svo.grid.dims,
        json["voxels"],
        json["nodes"],
        json["topology_bytes_per_voxel"].as_f64().unwrap_or(0.0),
        json["bytes_per_voxel"].as_f64().unwrap_or(0.0),
        seconds
    );
    let mut warnings = crate::diag::tagged(&crate::diag::INGEST_READER, warnings);
    warnings.extend(own);
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}

/// A pack: the registry's `svo` unit (the graph's and `bake unit svo`'s) over the pack's
/// sections: the flattened `svo` section, or the two-level `svo-scene` where the placed scene
/// exceeds the budget as one mesh.
fn run_pack(args: &SvoArgs, limits: &Limits) -> Result<Outcome> {
    let pack = Pack::open(&args.input)?;
    let pipeline = crate::graph::Pipeline {
        svo: VoxelizeOptions {
            solid: args.solid,
            ..VoxelizeOptions::surface(args.resolution)
        },
        ..Default::default()
    };
    let at = CommandScope {
        input: &args.input,
        limits,
        plan: None,
    };
    let start = std::time::Instant::now();
    let o = scene_unit(
        "svo",
        &at,
        &pack_sections(&pack, "svo")?,
        &pipeline,
        &|_| {},
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let output = args.output.clone().unwrap_or_else(|| args.input.clone());
    let two_level = o
        .sections
        .iter()
        .any(|s| s.kind == crate::voxel::instanced_section::KIND);
    let mut w = PackWriter::from_pack(&pack);
    for s in o.sections {
        w.insert(s);
    }
    w.write(&output)?;
    let mut json = o.report;
    json["output"] = serde_json::json!(output);
    json["seconds"] = serde_json::json!(seconds);
    let text = if two_level {
        format!(
            "{}: svo-scene (two-level: the placed scene exceeds --max-memory as one mesh) of {} \
             models, {} instances, scene grid {}, {} model voxels, {} bytes ({:.3} s)\n",
            output.display(),
            json["models"],
            json["instances"],
            dims(&json["scene_resolution"]),
            json["model_voxels"],
            json["bytes"],
            seconds
        )
    } else {
        format!(
            "{}: svo {} voxels, {} voxels, {} nodes, {:.3} B/voxel topology, {:.2} B/voxel total ({:.3} s)\n",
            output.display(),
            dims(&json["resolution"]),
            json["voxels"],
            json["nodes"],
            json["topology_bytes_per_voxel"].as_f64().unwrap_or(0.0),
            json["bytes_per_voxel"].as_f64().unwrap_or(0.0),
            seconds
        )
    };
    Ok(Outcome {
        json,
        text,
        warnings: o.warnings,
    })
}

/// A grid's dimensions as `[x, y, z]` (as `{:?}` of `[u32; 3]` prints them).
fn dims(v: &serde_json::Value) -> String {
    let d: Vec<u64> = v
        .as_array()
        .map(|a| a.iter().filter_map(|x| x.as_u64()).collect())
        .unwrap_or_default();
    format!("{d:?}")
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct SvoBenchArgs {
    /// Model or pack to voxelize (default: a procedural 70,000-triangle closed blob).
    pub model: Option<PathBuf>,
    /// Voxels along the longest axis.
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(1..=(1 << 21)))]
    pub resolution: u32,
    /// Repetitions (the best time is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
}

/// `bake bench svo`: voxelization + octree build, best of `repeat`.
pub(crate) fn bench(a: &SvoBenchArgs, g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let limits = g.ingest_defaults().limits;
    let (geo, name) = match &a.model {
        Some(p) => (
            load_geometry(p, SceneStage::Svo, &limits, &mut warnings)?.0,
            p.display().to_string(),
        ),
        None => (
            Geometry {
                mesh: crate::voxel::geometry::procedural_blob(250, 140),
                textures: Vec::new(),
            },
            "procedural blob (250×140×2 triangles)".to_string(),
        ),
    };
    let r = crate::bench::svo::bench_svo(&geo, &name, a.resolution, a.repeat)?;
    Ok(Outcome {
        json: r.json,
        text: r.text,
        warnings: crate::diag::tagged(&crate::diag::INGEST_READER, warnings),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dump::{DumpOptions, dump_json};

    /// `bake svo` and `bake linespace` on a pack with a mesh section, then `bake dump`.
    #[test]
    fn svo_and_linespace_commands_add_sections_that_dump_shows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("box.bake");
        let mesh = crate::voxel::tests::box_mesh([0.0, 0.0, 0.0], [2.0, 1.0, 1.0]);
        let mut w = PackWriter::new();
        w.insert(crate::mesh::section::to_section(
            "mesh:box",
            "box",
            &mesh,
            &[],
        ));
        w.write(&path).unwrap();
        let g = Global::default();
        let args = SvoArgs {
            input: path.clone(),
            output: None,
            resolution: 16,
            solid: true,
        };
        let out = run(&args, &g).unwrap();
        assert_eq!(out.json["resolution"], serde_json::json!([16, 8, 8]));
        let la = crate::cli::linespace::LinespaceArgs {
            input: path.clone(),
            output: None,
            n: 4,
            depth: 2,
            flat_cells: false,
        };
        crate::cli::linespace::run(&la, &g).unwrap();
        let pack = Pack::open(&path).unwrap();
        let doc = dump_json(
            &pack,
            &DumpOptions {
                full: true,
                section: None,
            },
        )
        .unwrap();
        let secs = doc["sections"].as_array().unwrap();
        let svo = secs.iter().find(|s| s["kind"] == "svo").unwrap();
        // A solid 16×8×8 box: every voxel.
        assert_eq!(svo["summary"]["voxels"], 16 * 8 * 8);
        for k in [
            "resolution",
            "origin",
            "voxel_size",
            "voxels",
            "nodes",
            "bytes",
            "bytes_per_voxel",
            "topology_bytes_per_voxel",
        ] {
            assert!(svo["summary"].get(k).is_some(), "summary lacks {k}");
        }
        assert_eq!(svo["data"]["voxels"].as_array().unwrap().len(), 16 * 8 * 8);
        let ls = secs.iter().find(|s| s["kind"] == "linespace").unwrap();
        for k in [
            "n",
            "depth",
            "nodes",
            "inner_nodes",
            "bits_per_linespace",
            "bytes",
        ] {
            assert!(ls["summary"].get(k).is_some(), "summary lacks {k}");
        }
        assert_eq!(ls["summary"]["bits_per_linespace"], 15 * 256);
        assert!(
            secs.iter().any(|s| s["kind"] == "mesh"),
            "the mesh section was kept"
        );
    }
}
