//! Material stage (seed 000 3.1.2, Table 3.1): every mesh of a pack gets its materials converted
//! to two-layer Schlick ([`convert`], [`schlick`]), its colour maps and normal maps processed into
//! mip chains (crate::texture), and MikkTSpace tangent frames (crate::mesh::tangents).
//!
//! [`bake_materials`] reads a pack and returns the sections to insert: `material:<model>/<i>`
//! (kind `material`), the processed textures under their ingest names (kind `texture`, replacing
//! the decoded RGBA8), `tangents:<model>`, and the mesh section again where tangent seams split
//! vertices. Running it twice gives the same pack (processed textures are kept as they are).

pub mod convert;
pub mod schlick;
pub mod section;
pub mod stage;

use crate::error::{Error, ParseError, Result};
use crate::mesh::section::MeshMeta;
use crate::mesh::tangents;
use crate::model::Mesh;
use crate::pack::{Pack, Section};
use crate::texture::{TextureOptions, TextureRole, process_texture};
use rayon::prelude::*;
use schlick::{NormalMap, SchlickMaterial};

/// Options of [`bake_materials`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialOptions {
    pub transfer: crate::texture::linear::TransferFunction,
    /// Scale mip alpha to keep the alpha-tested area (Castaño); off = the thesis' plain mean.
    pub preserve_coverage: bool,
}

impl MaterialOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: MaterialOptions = MaterialOptions {
        transfer: crate::texture::linear::TransferFunction::Srgb,
        preserve_coverage: true,
    };
}

impl Default for MaterialOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the stage did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct MaterialReport {
    pub meshes: usize,
    pub materials: usize,
    pub leaf_defaults: usize,
    pub textures: usize,
    /// Source texels processed (level 0).
    pub texels: u64,
    pub split_vertices: usize,
    pub warnings: Vec<String>,
}

/// One texture to process: mesh texture index, role, section name.
struct TextureJob {
    index: usize,
    role: TextureRole,
    section: String,
}

/// Converts the materials, textures and tangents of every mesh in `pack`.
pub fn bake_materials(
    pack: &Pack,
    opts: &MaterialOptions,
) -> Result<(Vec<Section>, MaterialReport)> {
    let mut out = Vec::new();
    let mut report = MaterialReport::default();
    for e in pack.of_kind(crate::mesh::section::KIND) {
        let view = pack.view(e)?;
        let (meta, mesh) =
            crate::mesh::section::from_section(&view).map_err(|m| in_section(pack, &e.name, m))?;
        let model = e.name.strip_prefix("mesh:").unwrap_or(&e.name).to_string();
        bake_mesh(
            pack,
            &e.name,
            &model,
            &meta,
            &mesh,
            opts,
            &mut out,
            &mut report,
        )?;
        report.meshes += 1;
    }
    Ok((out, report))
}

fn in_section(pack: &Pack, name: &str, e: ParseError) -> Error {
    Error::invalid(
        pack.path(),
        ParseError::new(format!("section {name:?}: {}", e.place), e.message),
    )
}

#[allow(clippy::too_many_arguments)]
fn bake_mesh(
    pack: &Pack,
    mesh_section: &str,
    model: &str,
    meta: &MeshMeta,
    mesh: &Mesh,
    opts: &MaterialOptions,
    out: &mut Vec<Section>,
    report: &mut MaterialReport,
) -> Result<()> {
    let materials: Vec<SchlickMaterial> = mesh
        .materials
        .iter()
        .map(convert::material_to_schlick)
        .collect();
    report.leaf_defaults += mesh
        .materials
        .iter()
        .filter(|m| convert::is_default_material(m))
        .count();
    let tex_section = |i: u32| {
        meta.textures
            .get(i as usize)
            .and_then(|t| t.section.clone())
    };
    let jobs = texture_jobs(meta, &materials, &mut report.warnings, model);
    let processed: Vec<Result<Option<(Section, u64)>>> = jobs
        .par_iter()
        .map(|j| process_job(pack, mesh, &materials, j, opts))
        .collect();
    for r in processed {
        if let Some((s, texels)) = r? {
            out.push(s);
            report.textures += 1;
            report.texels += texels;
        }
    }
    // Tangents before the material sections: a split rewrites the mesh section.
    let frames = tangents::generate_tangents(mesh);
    if frames.split_vertices > 0 {
        let sections: Vec<Option<String>> =
            meta.textures.iter().map(|t| t.section.clone()).collect();
        let source = meta.source.clone();
        out.push(crate::mesh::section::to_section(
            mesh_section,
            &source,
            &frames.mesh,
            &sections,
        ));
        report.split_vertices += frames.split_vertices;
    }
    out.push(tangents::to_section(
        &tangents::tangents_section_name(model),
        mesh_section,
        &frames,
    ));
    for (i, (m, s)) in mesh.materials.iter().zip(&materials).enumerate() {
        let normal = match s.normal_map {
            NormalMap::None => None,
            NormalMap::Explicit(k) | NormalMap::FromColor(k) => tex_section(k),
        };
        let meta = section::MaterialMeta {
            name: m.name.clone(),
            mesh_section: mesh_section.to_string(),
            index: i as u32,
            material: *s,
            color_map: s.color_map.and_then(tex_section),
            normal_map: normal,
        };
        out.push(section::to_section(
            &section::material_section_name(model, i),
            &meta,
        ));
        report.materials += 1;
    }
    Ok(())
}

/// The textures the materials use, each once, with its role (colour wins when a texture is both).
fn texture_jobs(
    meta: &MeshMeta,
    materials: &[SchlickMaterial],
    warnings: &mut Vec<String>,
    model: &str,
) -> Vec<TextureJob> {
    let mut roles: Vec<Option<TextureRole>> = vec![None; meta.textures.len()];
    for m in materials {
        if let NormalMap::Explicit(k) = m.normal_map
            && let Some(r) = roles.get_mut(k as usize)
        {
            r.get_or_insert(TextureRole::Normal);
        }
        if let Some(r) = m.color_map.and_then(|k| roles.get_mut(k as usize)) {
            *r = Some(TextureRole::Color);
        }
    }
    let mut jobs = Vec::new();
    for (index, (t, role)) in meta.textures.iter().zip(roles).enumerate() {
        match (role, &t.section) {
            (Some(role), Some(section)) => jobs.push(TextureJob {
                index,
                role,
                section: section.clone(),
            }),
            (Some(_), None) => warnings.push(format!(
                "{model}: texture {:?} is not in the pack; its material renders untextured",
                t.name
            )),
            _ => {}
        }
    }
    jobs
}

/// Metres per texel of texture `index` as the mesh maps it (geometric mean over the triangles
/// of the materials using it as colour map), or `None` when no triangle maps it with area.
pub fn texel_size(
    mesh: &Mesh,
    materials: &[SchlickMaterial],
    index: usize,
    texels: (u32, u32),
) -> Option<f32> {
    let (mut world, mut uv) = (0.0f64, 0.0f64);
    for (tri, &m) in mesh.indices.iter().zip(&mesh.triangle_materials) {
        if materials.get(m as usize).and_then(|s| s.color_map) != Some(index as u32) {
            continue;
        }
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
        let (e1, e2) = (
            [0, 1, 2].map(|k| (b[k] - a[k]) as f64),
            [0, 1, 2].map(|k| (c[k] - a[k]) as f64),
        );
        let cr = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        world += 0.5 * (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt();
        let [ta, tb, tc] = tri.map(|i| mesh.uvs[i as usize]);
        let d = (tb[0] - ta[0]) as f64 * (tc[1] - ta[1]) as f64
            - (tc[0] - ta[0]) as f64 * (tb[1] - ta[1]) as f64;
        uv += 0.5 * d.abs();
    }
    let texel_uv = 1.0 / (texels.0 as f64 * texels.1 as f64).sqrt().max(1.0);
    (world > 0.0 && uv > 1e-12).then(|| ((world / uv).sqrt() * texel_uv) as f32)
}

fn process_job(
    pack: &Pack,
    mesh: &Mesh,
    materials: &[SchlickMaterial],
    j: &TextureJob,
    opts: &MaterialOptions,
) -> Result<Option<(Section, u64)>> {
    let view = pack.view_named(&j.section)?;
    let meta: crate::texture::source_section::TextureMeta =
        view.meta().map_err(|m| in_section(pack, &j.section, m))?;
    if crate::texture::section::is_processed(&meta.format) {
        return Ok(None);
    }
    let (meta, img) = crate::texture::source_section::from_section(&view)
        .map_err(|m| in_section(pack, &j.section, m))?;
    let mut topts = TextureOptions::for_size(img.width, img.height);
    topts.transfer = opts.transfer;
    topts.mips.preserve_coverage = opts.preserve_coverage;
    if let Some(ts) = texel_size(mesh, materials, j.index, (img.width, img.height)) {
        topts.slope = TextureOptions::slope_for(convert::BUMP_HEIGHT_M, ts);
    }
    let t = process_texture(&img, j.role, &topts);
    let texels = img.pixels.len() as u64;
    Ok(Some((
        crate::texture::section::to_section(&j.section, &meta.source, &img, &t),
        texels,
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, MaterialSource, TextureRef};
    use crate::pack::PackWriter;

    /// A pack like `bake ingest plant.txf` writes: one quad leaf with the default material and
    /// a leaf texture, one triangle with an authored material.
    pub(crate) fn leaf_pack() -> Vec<u8> {
        let leaf = crate::texture::mips::tests::leaf(64);
        let pixels = crate::texture::linear::encode_rgba8(
            &leaf.texels,
            crate::texture::linear::TransferFunction::Srgb,
        );
        let img = crate::model::Rgba8Image {
            width: 64,
            height: 64,
            pixels,
        };
        let mesh = Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [0.05, 0.0, 0.0],
                [0.05, 0.0, 0.05],
                [0.0, 0.0, 0.05],
                [0.0, 1.0, 0.0],
            ],
            normals: vec![[0.0, -1.0, 0.0]; 5],
            uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0], [0.5, 0.5]],
            indices: vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]],
            triangle_materials: vec![0, 0, 1],
            materials: vec![
                Material {
                    name: "leaf".into(),
                    color_map: Some(0),
                    ..Material::default()
                },
                Material {
                    name: "bark".into(),
                    diffuse: [0.3, 0.2, 0.1, 1.0],
                    specular: [0.1, 0.1, 0.1, 1.0],
                    shininess: 8.0,
                    source: MaterialSource::FixedFunction,
                    ..Material::default()
                },
            ],
            textures: vec![TextureRef {
                name: "leaf.png".into(),
                path: "leaf.png".into(),
            }],
            ..Default::default()
        };
        let mut w = PackWriter::new();
        let tex = crate::texture::source_section::texture_section_name("plant.txf", "leaf.png");
        w.insert(crate::texture::source_section::to_section(
            &tex, "leaf.png", &img,
        ));
        w.insert(crate::mesh::section::to_section(
            "mesh:plant.txf",
            "plant.txf",
            &mesh,
            &[Some(tex)],
        ));
        w.to_bytes().unwrap()
    }

    fn run(bytes: &[u8]) -> Vec<u8> {
        let pack = Pack::from_bytes(bytes, "mem").unwrap();
        let (sections, report) = bake_materials(&pack, &MaterialOptions::default()).unwrap();
        assert!(report.warnings.is_empty(), "{:?}", report.warnings);
        let mut w = PackWriter::from_pack(&pack);
        for s in sections {
            w.insert(s);
        }
        w.to_bytes().unwrap()
    }

    #[test]
    fn a_leaf_pack_gets_materials_mips_and_tangents() {
        let out = run(&leaf_pack());
        let pack = Pack::from_bytes(&out, "out").unwrap();
        let doc = crate::dump::dump_json(&pack, &Default::default()).unwrap();
        let find = |name: &str| {
            doc["sections"]
                .as_array()
                .unwrap()
                .iter()
                .find(|s| s["name"] == name)
                .cloned()
                .unwrap_or_else(|| panic!("no {name}"))
        };
        let leaf = &find("material:plant.txf/0")["summary"];
        assert_eq!(leaf["layers"][0]["roughness"], 0.1f32 as f64);
        assert_eq!(leaf["layers"][0]["glossy"], 1.0);
        assert_eq!(leaf["layers"][1]["diffuse"], 1.0);
        assert_eq!(leaf["translucence"], 0.3f32 as f64);
        assert_eq!(leaf["color_map"], "texture:plant.txf/leaf.png");
        assert_eq!(leaf["normal_map"], "texture:plant.txf/leaf.png");
        let bark = &find("material:plant.txf/1")["summary"];
        assert_eq!(bark["layers"][0]["roughness"], 0.2f32 as f64);
        assert_eq!(bark["color_map"], serde_json::Value::Null);
        let tex = &find("texture:plant.txf/leaf.png")["summary"];
        assert_eq!(tex["mips"], 7);
        let cov = tex["coverage"].as_array().unwrap();
        assert_eq!(cov.len(), 7);
        let c0 = cov[0].as_f64().unwrap();
        for c in &cov[..4] {
            assert!((c.as_f64().unwrap() - c0).abs() <= 0.02, "{cov:?}");
        }
        let tan = &find("tangents:plant.txf")["summary"];
        // Triangle 2 maps the shared edge (0, 1) with another orientation: a vertex splits,
        // and the rewritten mesh section has one tangent per vertex.
        assert_eq!(tan["vertices"], 6);
        assert_eq!(find("mesh:plant.txf")["summary"]["vertices"], 6);
        // Running the stage again changes nothing (processed textures are kept).
        assert!(run(&out) == out, "a second run changed the pack");
    }
}
