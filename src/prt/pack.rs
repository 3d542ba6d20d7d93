//! Kind `prt`: the per-vertex transfer of one mesh section, baked by [`prt_mesh`] (the
//! registered `prt` stage's unit, which `bake prt` runs for every mesh of a pack).
//!
//! Section layout (one per mesh, named `prt:<model>`):
//! - metadata (postcard, [`PrtMeta`]): the mesh section it belongs to, counts, sampling
//!   parameters, the materials used, whether albedo is folded in (always true, see
//!   [`crate::prt::transfer`]);
//! - `transfer`: f32 × 3, `vertices · 2 · 2 · 16` elements, full precision, indexed
//!   `[vertex][side][set][coefficient] → RGB` (side 0 = front, set 0 = all paths, set 1 = paths
//!   with at least one bounce);
//! - `gpu`: f32 × 4, `vertices · 2 · 5` elements, the thesis' packed layout per vertex and side
//!   (see [`crate::prt::transfer::pack_gpu`]).

use super::transfer::{
    self as prt, COEFFS, GPU_VEC4_PER_SIDE, PER_VERTEX, PrtMaterial, PrtOptions, SETS, SIDES,
    Transfer,
};
use crate::diag::Warning;
use crate::error::{Error, ParseError, Result};
use crate::model::Rgba8Image;
use crate::pack::fit_name;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Pack, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "prt";

/// Metadata of a `prt` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrtMeta {
    /// Name of the mesh section whose vertices this transfer belongs to.
    pub mesh: String,
    pub vertices: u32,
    /// SH order (bands).
    pub order: u32,
    pub samples: u32,
    pub bounces: u32,
    pub sides: u32,
    pub sets: u32,
    /// The receiving vertex's albedo (and the diffuse 1/π) is folded into the transfer.
    pub albedo_folded: bool,
    pub materials: Vec<PrtMaterial>,
    pub rays: u64,
    pub skipped_vertices: u32,
}

/// Section name of a model's transfer, from its mesh section name (`mesh:NAME` → `prt:NAME`).
pub fn section_name(mesh_section: &str) -> String {
    let model = mesh_section.strip_prefix("mesh:").unwrap_or(mesh_section);
    fit_name(format!("prt:{model}"))
}

pub fn to_section(name: &str, mesh_section: &str, t: &Transfer, mats: &[PrtMaterial]) -> Section {
    let meta = PrtMeta {
        mesh: mesh_section.to_string(),
        vertices: t.vertices,
        order: prt::ORDER as u32,
        samples: t.samples,
        bounces: t.bounces,
        sides: SIDES as u32,
        sets: SETS as u32,
        albedo_folded: true,
        materials: mats.to_vec(),
        rays: t.rays,
        skipped_vertices: t.skipped_vertices,
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("transfer", ArrayFormat::F32, 3, &t.coeffs)
        .array("gpu", ArrayFormat::F32, 4, &prt::pack_gpu(t));
    b.finish()
}

/// Decodes a `prt` section; array lengths are checked against the vertex count.
pub fn from_section(v: &SectionView) -> Result<(PrtMeta, Transfer), ParseError> {
    let meta: PrtMeta = v.meta()?;
    if meta.order as usize != prt::ORDER
        || meta.sides as usize != SIDES
        || meta.sets as usize != SETS
    {
        return Err(ParseError::new(
            "prt section metadata",
            format!(
                "order {}, {} sides, {} sets; this build reads order {}, {SIDES} sides, {SETS} sets",
                meta.order,
                meta.sides,
                meta.sets,
                prt::ORDER
            ),
        ));
    }
    let want = meta.vertices as u64 * PER_VERTEX as u64;
    let have = v.info("transfer").map_or(0, |a| a.count);
    if have != want {
        return Err(ParseError::new(
            "prt section array \"transfer\"",
            format!(
                "{have} elements, expected {want} for {} vertices",
                meta.vertices
            ),
        ));
    }
    let coeffs: Vec<[f32; 3]> = v.array_vec("transfer")?;
    let t = Transfer {
        vertices: meta.vertices,
        samples: meta.samples,
        bounces: meta.bounces,
        coeffs,
        rays: meta.rays,
        skipped_vertices: meta.skipped_vertices,
    };
    Ok((meta, t))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta: PrtMeta = v.meta()?;
    Ok(json!({
        "vertices": meta.vertices,
        "order": meta.order,
        "samples": meta.samples,
        "sides": meta.sides,
        "sets": meta.sets,
        "bounces": meta.bounces,
        "mesh": meta.mesh,
        "albedo_folded": meta.albedo_folded,
        "skipped_vertices": meta.skipped_vertices,
    }))
}

/// `transfer` indexed [vertex][side][set][coefficient] → [r, g, b]; `gpu` [vertex][side][5] → vec4.
pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, t) = from_section(v)?;
    let transfer: Vec<Value> = t
        .coeffs
        .chunks_exact(PER_VERTEX)
        .map(|vx| {
            vx.chunks_exact(SETS * COEFFS)
                .map(|side| {
                    side.chunks_exact(COEFFS)
                        .map(|set| json!(set))
                        .collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
                .into()
        })
        .collect();
    let gpu: Vec<Value> = prt::pack_gpu(&t)
        .chunks_exact(SIDES * GPU_VEC4_PER_SIDE)
        .map(|vx| {
            vx.chunks_exact(GPU_VEC4_PER_SIDE)
                .map(|s| json!(s))
                .collect::<Vec<_>>()
                .into()
        })
        .collect();
    Ok(json!({ "transfer": transfer, "gpu": gpu }))
}

/// What [`prt_mesh`] did for one mesh (the `prt` unit's report).
#[derive(Debug, Clone, Serialize)]
pub struct MeshPrtReport {
    pub mesh: String,
    pub section: String,
    pub vertices: u32,
    pub triangles: usize,
    pub rays: u64,
    pub seconds: f64,
    pub skipped_vertices: u32,
}

/// Total vertex count of the pack's meshes (for progress bars).
pub fn mesh_vertex_count(pack: &Pack) -> u64 {
    pack.of_kind(crate::mesh::section::KIND)
        .filter_map(|e| pack.view(e).ok())
        .map(|v| v.info("positions").map_or(0, |a| a.count))
        .sum()
}

/// (Tests.) Bakes a `prt` section for every mesh section of `pack` and returns the pack with them added
/// (replacing older ones), a report per mesh and warnings (textures without a decoded section
/// count as opaque and white). TXF meshes get `opts.default_translucence` where a material has
/// none, other meshes 0.
#[cfg(test)]
pub(crate) fn prt_pack(
    pack: &Pack,
    opts: &PrtOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(crate::pack::PackWriter, Vec<MeshPrtReport>, Vec<Warning>)> {
    let mut w = crate::pack::PackWriter::from_pack(pack);
    let mut reports = Vec::new();
    let mut warnings = Vec::new();
    let meshes: Vec<_> = pack.of_kind(crate::mesh::section::KIND).cloned().collect();
    for e in &meshes {
        let (section, report) = prt_mesh(pack, &e.name, opts, progress, &mut warnings)?;
        w.insert(section);
        reports.push(report);
    }
    Ok((w, reports, warnings))
}

/// The `prt` section of one mesh section of `pack` (reads the mesh and its textures only).
pub fn prt_mesh(
    pack: &Pack,
    mesh_section: &str,
    opts: &PrtOptions,
    progress: &(dyn Fn(u64) + Sync),
    warnings: &mut Vec<Warning>,
) -> Result<(Section, MeshPrtReport)> {
    let start = std::time::Instant::now();
    let view = pack.view_named(mesh_section)?;
    let (meta, mesh) = crate::mesh::section::from_section(&view)
        .map_err(|err| Error::invalid(pack.path(), err))?;
    let textures = mesh_textures(pack, mesh_section, &meta, warnings);
    let is_txf = meta.source.to_ascii_lowercase().ends_with(".txf");
    let o = PrtOptions {
        default_translucence: if is_txf {
            opts.default_translucence
        } else {
            0.0
        },
        ..opts.clone()
    };
    let mats = prt::prt_materials(&mesh, &textures, o.default_translucence);
    let masks = prt::alpha_masks(&mesh, &textures);
    let scene = prt::PrtScene::build(&mesh, &masks, &o)?;
    if scene.skipped_triangles() > 0 {
        warnings.push(Warning::new(
            &super::stage::PRT_TRIANGLES_NON_FINITE,
            "",
            format!(
                "{}: {} triangles with non-finite positions left out of the BVH",
                mesh_section,
                scene.skipped_triangles()
            ),
        ));
    }
    let t = match (&scene, o.tracer) {
        // The GPU walks the CPU backend's CWBVH.
        (prt::PrtScene::Cpu(bvh), prt::PrtTracer::Gpu) => {
            let gpu = crate::gpu::shared_gpu().map_err(|e| {
                Error::runtime(format!("{mesh_section}: prt.tracer = \"gpu\": {e}"))
            })?;
            super::gpu::bake_prt_gpu(gpu, bvh, &mesh, &mats, &o, progress)?
        }
        _ => scene.bake(&mesh, &mats, &o, progress),
    };
    let name = section_name(mesh_section);
    let section = to_section(&name, mesh_section, &t, &mats);
    let report = MeshPrtReport {
        mesh: mesh_section.to_string(),
        section: name,
        vertices: t.vertices,
        triangles: mesh.indices.len(),
        rays: t.rays,
        seconds: start.elapsed().as_secs_f64(),
        skipped_vertices: t.skipped_vertices,
    };
    Ok((section, report))
}

/// The decoded textures a mesh section refers to (`None` where there is no usable section).
pub fn mesh_textures(
    pack: &Pack,
    mesh_section: &str,
    meta: &crate::mesh::section::MeshMeta,
    warnings: &mut Vec<Warning>,
) -> Vec<Option<Rgba8Image>> {
    meta.textures
        .iter()
        .map(|t| {
            let decoded = t.section.as_ref().map(|s| {
                pack.view_named(s).and_then(|v| {
                    crate::texture::source_section::from_section(&v)
                        .map_err(|err| Error::invalid(pack.path(), err))
                })
            });
            match decoded {
                Some(Ok((_, img))) => Some(img),
                Some(Err(err)) => {
                    warnings.push(Warning::new(
                        &super::stage::PRT_TEXTURE_UNREADABLE,
                        "",
                        format!("{mesh_section}: texture {:?}: {err}", t.name),
                    ));
                    None
                }
                None => {
                    warnings.push(Warning::new(
                        &super::stage::PRT_TEXTURE_MISSING,
                        "",
                        format!(
                            "{mesh_section}: texture {:?} was not decoded into the pack; \
                         treated as opaque and white",
                            t.name
                        ),
                    ));
                    None
                }
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pack::PackWriter;
    use crate::prt::plant::procedural_plant;

    fn plant_pack() -> Pack {
        let (mesh, tex) = procedural_plant(200, 2);
        let mut w = PackWriter::new();
        let tex_name =
            crate::texture::source_section::texture_section_name("plant.txf", "leaf.png");
        w.insert(crate::texture::source_section::to_section(
            &tex_name, "leaf.png", &tex,
        ));
        w.insert(crate::mesh::section::to_section(
            "mesh:plant.txf",
            "plant.txf",
            &mesh,
            &[Some(tex_name)],
        ));
        Pack::from_bytes(&w.to_bytes().unwrap(), "plant.bake").unwrap()
    }

    #[test]
    fn prt_section_round_trips_and_dumps() {
        let pack = plant_pack();
        let opts = PrtOptions {
            samples: 16,
            bounces: 2,
            ..PrtOptions::default()
        };
        let (w, reports, warnings) = prt_pack(&pack, &opts, &|_| {}).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(reports.len(), 1);
        let out = Pack::from_bytes(&w.to_bytes().unwrap(), "out.bake").unwrap();
        let view = out.view_named("prt:plant.txf").unwrap();
        let (meta, t) = from_section(&view).unwrap();
        assert_eq!(meta.mesh, "mesh:plant.txf");
        assert_eq!(
            meta.materials[0].translucence, 0.3,
            "TXF default translucence"
        );
        assert_eq!(t.vertices as usize, out_vertices(&out));
        let s = summary(&view).unwrap();
        assert_eq!(s["sides"], 2);
        assert_eq!(s["sets"], 2);
        assert_eq!(s["order"], 4);
        assert_eq!(s["samples"], 16);
        let d = data(&view).unwrap();
        let v7 = &d["transfer"][7];
        assert_eq!(v7.as_array().unwrap().len(), 2);
        assert_eq!(v7[1][0].as_array().unwrap().len(), 16);
        assert_eq!(
            v7[1][0][3][2].as_f64().unwrap() as f32,
            t.get(7, 1, 0)[3][2]
        );
        assert_eq!(d["gpu"][7].as_array().unwrap().len(), 2);
        assert_eq!(d["gpu"][7][0].as_array().unwrap().len(), 5);
        // The dump registry knows the kind.
        let doc = crate::dump::dump_json(&out, &crate::dump::DumpOptions::default()).unwrap();
        let prt = doc["sections"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["kind"] == KIND)
            .unwrap();
        assert_eq!(prt["summary"]["vertices"], t.vertices);
    }

    fn out_vertices(p: &Pack) -> usize {
        p.view_named("mesh:plant.txf")
            .unwrap()
            .info("positions")
            .unwrap()
            .count as usize
    }

    #[test]
    fn truncated_transfer_is_rejected_with_its_place() {
        let t = Transfer {
            vertices: 3,
            samples: 1,
            bounces: 0,
            coeffs: vec![[0.0; 3]; 2 * PER_VERTEX],
            rays: 0,
            skipped_vertices: 0,
        };
        // pack_gpu would index past the end: build the section by hand.
        let meta = PrtMeta {
            mesh: "mesh:x".into(),
            vertices: 3,
            order: 4,
            samples: 1,
            bounces: 0,
            sides: 2,
            sets: 2,
            albedo_folded: true,
            materials: vec![],
            rays: 0,
            skipped_vertices: 0,
        };
        let mut b = SectionBuilder::new(KIND, "prt:x");
        b.meta(&meta)
            .array("transfer", ArrayFormat::F32, 3, &t.coeffs);
        let mut w = PackWriter::new();
        w.insert(b.finish());
        let pack = Pack::from_bytes(&w.to_bytes().unwrap(), "bad.bake").unwrap();
        let err = from_section(&pack.view_named("prt:x").unwrap()).unwrap_err();
        assert!(err.place.contains("transfer"), "{err}");
        assert!(err.message.contains("expected 192"), "{err}");
    }

    #[test]
    fn missing_texture_section_is_a_warning_not_an_error() {
        let (mesh, _) = procedural_plant(50, 2);
        let mut w = PackWriter::new();
        w.insert(crate::mesh::section::to_section(
            "mesh:p.obj",
            "p.obj",
            &mesh,
            &[None],
        ));
        let pack = Pack::from_bytes(&w.to_bytes().unwrap(), "p.bake").unwrap();
        let opts = PrtOptions {
            samples: 4,
            ..PrtOptions::default()
        };
        let (_, _, warnings) = prt_pack(&pack, &opts, &|_| {}).unwrap();
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].message.contains("leaf.png"));
        assert_eq!(warnings[0].id, crate::prt::stage::PRT_TEXTURE_MISSING.id);
    }
}
