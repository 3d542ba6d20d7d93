//! `bake export`: a pack as one glTF 2.0 scene (GLB, or `.gltf` with the buffer embedded), for
//! viewers and DCC tools. A reader of baked sections (docs/ARCHITECTURE.md, layer `readers`).
//!
//! What goes in (docs/MATERIALS.md, "Export to glTF", has the mapping):
//! - every model (its `mesh:` section, its `material:<model>/<i>` sections and their processed
//!   colour maps) as a glTF mesh with one primitive per material, the vertex arrays shared;
//! - every material as glTF metallic-roughness; colour maps as sRGB PNG images;
//! - every instance through `EXT_mesh_gpu_instancing` (TRANSLATION, ROTATION about +Z, SCALE;
//!   one node per model);
//! - the terrain as one mesh of [`TERRAIN_CHUNK`]² -cell chunks (one primitive each) with
//!   positions, normals and UVs into its colour map;
//! - the `sun` section as a `KHR_lights_punctual` directional light, intensity in lux
//!   ([`LUX_PER_WATT`] × the luminance of the RGB irradiance).
//!
//! Axes: the data keeps bake's Z-up frame (docs/CONVENTIONS.md); one root node rotates it to
//! glTF's Y-up ((x, y, z) → (x, z, −y), −90° about +X), so instance rotations stay quaternions
//! about +Z. Every node, mesh, material and image names the pack section it came from in
//! `extras.section`.

use crate::error::{Error, ParseError, Result};
use crate::ingest::instances_section::{self as instances, InstanceRecord, InstancesMeta};
use crate::material::section::{self as material, MaterialMeta};
use crate::mesh::section as mesh;
use crate::model::{Mesh, Rgba8Image, Terrain};
use crate::pack::Pack;
use crate::terrain::source_section::{self as terrain, TerrainMeta};
use crate::texture::source_section::TextureMeta;
use serde_json::{Map, Value, json};
use std::collections::HashMap;

/// Cells per side of one terrain chunk (one glTF primitive each).
pub const TERRAIN_CHUNK: u32 = 64;

/// Luminous efficacy used to turn the sun's irradiance (W/m², linear RGB) into illuminance (lux):
/// lux = 683 lm/W × Rec. 709 luminance of the RGB irradiance.
pub const LUX_PER_WATT: f32 = 683.0;

/// The root node's rotation, Z-up to Y-up: −90° about +X, (x, y, z) → (x, z, −y).
pub const Z_UP_TO_Y_UP: [f32; 4] = [
    -std::f32::consts::FRAC_1_SQRT_2,
    0.0,
    0.0,
    std::f32::consts::FRAC_1_SQRT_2,
];

/// Albedo of a terrain without a colour map (sRGB 128 grey, as every stage takes it).
const TERRAIN_GREY: f32 = 0.216;

/// Illuminance in lux of a sun of RGB irradiance `e` (W/m²): [`LUX_PER_WATT`] · luminance(e).
pub fn sun_lux(e: [f32; 3]) -> f32 {
    LUX_PER_WATT * crate::color::luminance(e)
}

/// glTF metallic-roughness roughness of a Schlick layer of roughness `r` (= roughness⁴ on import,
/// docs/MATERIALS.md): r^(1/4), clamped to [0, 1].
pub fn gltf_roughness(r: f32) -> f32 {
    r.max(0.0).powf(0.25).min(1.0)
}

/// The quaternion (x, y, z, w) of a rotation by `deg` degrees about +Z (counter-clockwise from
/// above, as ECO rotations are).
pub fn rotation_z(deg: f32) -> [f32; 4] {
    let (s, c) = (deg.to_radians() * 0.5).sin_cos();
    [0.0, 0.0, s, c]
}

/// What an export wrote.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ExportReport {
    pub meshes: usize,
    pub nodes: usize,
    pub materials: usize,
    pub textures: usize,
    pub images: usize,
    pub models: usize,
    pub instances: usize,
    pub terrain_chunks: usize,
    /// The sun's illuminance in lux, `None` without a `sun` section.
    pub sun_lux: Option<f32>,
    pub bytes: usize,
    pub warnings: Vec<crate::diag::Warning>,
}

/// The output container.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Container {
    /// Binary glTF: JSON and buffer in one file.
    Glb,
    /// JSON glTF, the buffer embedded as a base64 data URI (no side files).
    GltfEmbedded,
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// The binary buffer and the JSON arrays that index it.
#[derive(Default)]
struct Doc {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
    images: Vec<Value>,
    textures: Vec<Value>,
    materials: Vec<Value>,
    meshes: Vec<Value>,
    nodes: Vec<Value>,
}

impl Doc {
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float accessor of `N`-component elements (`kind` "SCALAR", "VEC2", ...), with min and
    /// max where `bounds` (POSITION needs them).
    fn floats<const N: usize>(
        &mut self,
        data: &[[f32; N]],
        kind: &str,
        target: Option<u32>,
        bounds: bool,
    ) -> usize {
        let view = self.view(bytemuck::cast_slice(data), target);
        let mut a =
            json!({"bufferView": view, "componentType": FLOAT, "count": data.len(), "type": kind});
        if bounds {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for p in data {
                for k in 0..N {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            a["min"] = json!(lo.to_vec());
            a["max"] = json!(hi.to_vec());
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn indices(&mut self, tris: &[[u32; 3]]) -> usize {
        let view = self.view(bytemuck::cast_slice(tris), Some(ELEMENT_ARRAY_BUFFER));
        self.accessors
            .push(json!({"bufferView": view, "componentType": UNSIGNED_INT,
            "count": tris.len() * 3, "type": "SCALAR"}));
        self.accessors.len() - 1
    }
}

/// A texture section as exported: its glTF texture index and whether any texel's alpha is
/// below 255.
#[derive(Clone, Copy)]
struct Exported {
    texture: usize,
    has_alpha: bool,
}

/// Level 0 of texture section `name` as sRGB RGBA8: the processed colour chain's level 0
/// encoded to sRGB, or an ingested section's texels as they are.
fn texture_image(pack: &Pack, name: &str) -> Result<Rgba8Image> {
    let bad =
        |e: ParseError| Error::invalid_at(pack.path(), format!("section {name:?}"), e.to_string());
    let v = pack.view_named(name)?;
    let meta: TextureMeta = v.meta().map_err(bad)?;
    if meta.format == crate::texture::section::FORMAT_COLOR {
        let (_, img) = crate::texture::section::level0_rgba8(&v).map_err(bad)?;
        return Ok(img);
    }
    let texels: Vec<[u8; 4]> = v.array_vec("texels").map_err(bad)?;
    if texels.len() as u64 != meta.width as u64 * meta.height as u64 || texels.is_empty() {
        return Err(bad(ParseError::new(
            "texels",
            format!("{} texels for {}×{}", texels.len(), meta.width, meta.height),
        )));
    }
    Ok(Rgba8Image {
        width: meta.width,
        height: meta.height,
        pixels: texels,
    })
}

struct Exporter<'a> {
    pack: &'a Pack,
    doc: Doc,
    textures: HashMap<String, Option<Exported>>,
    warnings: Vec<crate::diag::Warning>,
}

impl Exporter<'_> {
    /// The glTF texture of texture section `name` (exported once); a missing section is a
    /// warning and no texture.
    fn texture(&mut self, name: &str) -> Result<Option<Exported>> {
        if let Some(t) = self.textures.get(name) {
            return Ok(*t);
        }
        let out = if self.pack.find(name).is_none() {
            self.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_TEXTURE_MISSING,
                "",
                format!("texture section {name:?} is missing: exported untextured"),
            ));
            None
        } else {
            let img = texture_image(self.pack, name)?;
            let has_alpha = img.pixels.iter().any(|p| p[3] < 255);
            let png = crate::render::encode_png(&img)?;
            let view = self.doc.view(&png, None);
            self.doc
                .images
                .push(json!({"bufferView": view, "mimeType": "image/png",
                "name": name, "extras": {"section": name}}));
            let image = self.doc.images.len() - 1;
            self.doc
                .textures
                .push(json!({"source": image, "sampler": 0, "name": name}));
            Some(Exported {
                texture: self.doc.textures.len() - 1,
                has_alpha,
            })
        };
        self.textures.insert(name.to_string(), out);
        Ok(out)
    }

    /// One glTF material from a `material:` section (or, where the pack has none, from the
    /// mesh's own material: its diffuse colour, roughness 1).
    fn material(
        &mut self,
        mesh_section: &str,
        index: usize,
        input: &crate::model::Material,
        converted: Option<(&str, &MaterialMeta)>,
    ) -> Result<usize> {
        let double_sided = input.double_sided;
        let (name, base, roughness, opacity, emission, color_map, section) = match converted {
            Some((section, m)) => {
                let s = &m.material;
                let bottom = &s.layers[1];
                (
                    m.name.clone(),
                    bottom.color,
                    gltf_roughness(s.layers[0].roughness),
                    s.opacity,
                    s.emission,
                    m.color_map.clone(),
                    Some(section.to_string()),
                )
            }
            None => {
                self.warnings.push(crate::diag::Warning::new(&crate::diag::EXPORT_MATERIAL_MISSING, "", format!(
                    "{mesh_section}: material {index} has no material section: exported with its diffuse colour"
                )));
                let d = input.diffuse;
                (
                    input.name.clone(),
                    [d[0], d[1], d[2]],
                    1.0,
                    d[3] * (1.0 - input.transparency),
                    [input.emission[0], input.emission[1], input.emission[2]],
                    None,
                    None,
                )
            }
        };
        let tex = match &color_map {
            Some(c) => self.texture(c)?,
            None => None,
        };
        let clamp = |x: f32| {
            if x.is_finite() {
                x.clamp(0.0, 1.0)
            } else {
                0.0
            }
        };
        let mut pbr = json!({
            "baseColorFactor": [clamp(base[0]), clamp(base[1]), clamp(base[2]), clamp(opacity)],
            "metallicFactor": 0.0,
            "roughnessFactor": clamp(roughness),
        });
        if let Some(t) = tex {
            pbr["baseColorTexture"] = json!({"index": t.texture});
        }
        let masked = tex.is_some_and(|t| t.has_alpha) || opacity < 1.0;
        let mut m = json!({
            "name": name,
            "pbrMetallicRoughness": pbr,
            "doubleSided": double_sided,
            "extras": {"section": section, "mesh_section": mesh_section, "index": index,
                       "color_map": color_map},
        });
        if masked {
            m["alphaMode"] = json!("MASK");
            m["alphaCutoff"] = json!(0.5);
        }
        if emission.iter().any(|&e| e > 0.0) {
            m["emissiveFactor"] = json!(emission.map(clamp));
        }
        self.doc.materials.push(m);
        Ok(self.doc.materials.len() - 1)
    }

    /// A model's mesh: shared vertex accessors, one primitive per material that has triangles.
    fn model_mesh(
        &mut self,
        name: &str,
        section: &str,
        materials: &HashMap<(String, u32), (String, MaterialMeta)>,
    ) -> Result<usize> {
        let v = self.pack.view_named(section)?;
        let (_, m): (_, Mesh) = mesh::from_section(&v).map_err(|e| {
            Error::invalid_at(
                self.pack.path(),
                format!("section {section:?}"),
                e.to_string(),
            )
        })?;
        let normals: Vec<[f32; 3]> = m.normals.iter().map(|&n| unit(n)).collect();
        let pos = self
            .doc
            .floats(&m.positions, "VEC3", Some(ARRAY_BUFFER), true);
        let nrm = self.doc.floats(&normals, "VEC3", Some(ARRAY_BUFFER), false);
        let uv = self.doc.floats(&m.uvs, "VEC2", Some(ARRAY_BUFFER), false);
        let mut primitives = Vec::new();
        for (i, input) in m.materials.iter().enumerate() {
            let tris: Vec<[u32; 3]> = m
                .indices
                .iter()
                .zip(&m.triangle_materials)
                .filter(|(_, mat)| **mat as usize == i)
                .map(|(t, _)| *t)
                .collect();
            if tris.is_empty() {
                continue;
            }
            let converted = materials
                .get(&(section.to_string(), i as u32))
                .map(|(s, mm)| (s.as_str(), mm));
            let material = self.material(section, i, input, converted)?;
            let idx = self.doc.indices(&tris);
            primitives.push(json!({
                "attributes": {"POSITION": pos, "NORMAL": nrm, "TEXCOORD_0": uv},
                "indices": idx, "material": material, "mode": 4,
            }));
        }
        if primitives.is_empty() {
            return Err(Error::invalid_at(
                self.pack.path(),
                format!("section {section:?}"),
                "the mesh has no triangles",
            ));
        }
        self.doc
            .meshes
            .push(json!({"name": name, "primitives": primitives,
            "extras": {"section": section}}));
        Ok(self.doc.meshes.len() - 1)
    }

    /// One node per model, its instances through `EXT_mesh_gpu_instancing`.
    fn instanced_node(
        &mut self,
        name: &str,
        section: &str,
        mesh: usize,
        list: &[InstanceRecord],
    ) -> usize {
        let t: Vec<[f32; 3]> = list.iter().map(|r| r.position).collect();
        let r: Vec<[f32; 4]> = list.iter().map(|r| rotation_z(r.rotation_deg)).collect();
        let s: Vec<[f32; 3]> = list.iter().map(|r| [r.scale; 3]).collect();
        let ta = self.doc.floats(&t, "VEC3", None, true);
        let ra = self.doc.floats(&r, "VEC4", None, false);
        let sa = self.doc.floats(&s, "VEC3", None, false);
        self.doc.nodes.push(json!({
            "name": name, "mesh": mesh,
            "extensions": {"EXT_mesh_gpu_instancing": {"attributes":
                {"TRANSLATION": ta, "ROTATION": ra, "SCALE": sa}}},
            "extras": {"section": section, "instances_section": instances::KIND,
                       "instances": list.len()},
        }));
        self.doc.nodes.len() - 1
    }

    /// The terrain as one mesh of chunk primitives; returns its node and the chunk count.
    fn terrain(&mut self, name: &str) -> Result<Option<(usize, usize)>> {
        let v = self.pack.view_named(name)?;
        let bad = |e: ParseError| {
            Error::invalid_at(self.pack.path(), format!("section {name:?}"), e.to_string())
        };
        let meta: TerrainMeta = v.meta().map_err(bad)?;
        let (_, t): (_, Terrain) = terrain::from_section(&v).map_err(bad)?;
        if t.width < 2 || t.height < 2 {
            self.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_TERRAIN_TOO_SMALL,
                "",
                format!(
                    "terrain {name:?} is {}×{}: fewer than 2×2 samples, not exported",
                    t.width, t.height
                ),
            ));
            return Ok(None);
        }
        let packed: Vec<[u8; 4]> = match v.array_vec::<[u8; 4]>("normals") {
            Ok(n) if n.len() == t.heights.len() => n,
            _ => crate::terrain::prepare::terrain_normal_map(&t),
        };
        let color = match &meta.color_section {
            Some(c) => self.texture(c)?,
            None => None,
        };
        let grey = if color.is_some() { 1.0 } else { TERRAIN_GREY };
        let mut pbr = json!({"baseColorFactor": [grey, grey, grey, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 1.0});
        if let Some(c) = color {
            pbr["baseColorTexture"] = json!({"index": c.texture});
        }
        self.doc
            .materials
            .push(json!({"name": "terrain", "pbrMetallicRoughness": pbr,
            "doubleSided": false,
            "extras": {"section": name, "color_map": meta.color_section}}));
        let material = self.doc.materials.len() - 1;
        let (w, h) = (t.width, t.height);
        let dx = t.extent[0] / (w - 1) as f32;
        let dy = t.extent[1] / (h - 1) as f32;
        let mut primitives = Vec::new();
        for cy in (0..h - 1).step_by(TERRAIN_CHUNK as usize) {
            for cx in (0..w - 1).step_by(TERRAIN_CHUNK as usize) {
                let (x1, y1) = (
                    (cx + TERRAIN_CHUNK).min(w - 1),
                    (cy + TERRAIN_CHUNK).min(h - 1),
                );
                let cols = x1 - cx + 1;
                let mut pos = Vec::new();
                let mut nrm = Vec::new();
                let mut uv = Vec::new();
                for j in cy..=y1 {
                    for i in cx..=x1 {
                        let k = (j * w + i) as usize;
                        pos.push([
                            t.origin[0] + i as f32 * dx,
                            t.origin[1] + j as f32 * dy,
                            t.heights[k],
                        ]);
                        let n = packed[k];
                        nrm.push(unit([0, 1, 2].map(|c| n[c] as f32 / 255.0 * 2.0 - 1.0)));
                        // The colour map's row 0 is north (y = y0 + extent): v = 0 there.
                        uv.push([i as f32 / (w - 1) as f32, 1.0 - j as f32 / (h - 1) as f32]);
                    }
                }
                let mut tris = Vec::new();
                for j in 0..y1 - cy {
                    for i in 0..x1 - cx {
                        let a = j * cols + i;
                        let (b, c, d) = (a + 1, a + cols + 1, a + cols);
                        // Split along (i, j)–(i + 1, j + 1), counter-clockwise from above.
                        tris.push([a, b, c]);
                        tris.push([a, c, d]);
                    }
                }
                let p = self.doc.floats(&pos, "VEC3", Some(ARRAY_BUFFER), true);
                let n = self.doc.floats(&nrm, "VEC3", Some(ARRAY_BUFFER), false);
                let u = self.doc.floats(&uv, "VEC2", Some(ARRAY_BUFFER), false);
                let idx = self.doc.indices(&tris);
                primitives.push(json!({
                    "attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": u},
                    "indices": idx, "material": material, "mode": 4,
                    "extras": {"cells": [cx, cy, x1, y1]},
                }));
            }
        }
        let chunks = primitives.len();
        self.doc
            .meshes
            .push(json!({"name": "terrain", "primitives": primitives,
            "extras": {"section": name, "chunk_cells": TERRAIN_CHUNK}}));
        let mesh = self.doc.meshes.len() - 1;
        self.doc.nodes.push(json!({"name": "terrain", "mesh": mesh,
            "extras": {"section": name}}));
        Ok(Some((self.doc.nodes.len() - 1, chunks)))
    }
}

fn unit(n: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 1e-12 && l.is_finite() {
        n.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The pack as a glTF document: the file's bytes and what they hold. Fails (invalid input)
/// on a pack without any mesh section.
pub fn export(pack: &Pack, container: Container) -> Result<(Vec<u8>, ExportReport)> {
    if pack.of_kind(mesh::KIND).next().is_none() {
        return Err(Error::invalid_at(
            pack.path(),
            "section table",
            "the pack has no mesh section: nothing to export (bake export needs a pack with models, \
             e.g. from `bake SCENE.eco` or `bake ingest MODEL`)",
        ));
    }
    let mut ex = Exporter {
        pack,
        doc: Doc::default(),
        textures: HashMap::new(),
        warnings: Vec::new(),
    };
    let mut report = ExportReport::default();
    // Material sections by (mesh section, index).
    let mut materials = HashMap::new();
    for e in pack.of_kind(material::KIND) {
        let v = pack.view(e)?;
        let m = material::from_section(&v).map_err(|err| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                err.to_string(),
            )
        })?;
        materials.insert((m.mesh_section.clone(), m.index), (e.name.clone(), m));
    }
    let mut children = Vec::new();
    // Models: (name, mesh section, instances), from the instances section or one per mesh.
    let mut models: Vec<(String, String, Option<Vec<InstanceRecord>>)> = Vec::new();
    if let Some(e) = pack.of_kind(instances::KIND).next() {
        let v = pack.view(e)?;
        let bad = |err: ParseError| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                err.to_string(),
            )
        };
        let meta: InstancesMeta = v.meta().map_err(bad)?;
        let list: Vec<InstanceRecord> = v.array_vec("instances").map_err(bad)?;
        let mut per_model = vec![Vec::new(); meta.models.len()];
        for (k, r) in list.iter().enumerate() {
            per_model
                .get_mut(r.model as usize)
                .ok_or_else(|| {
                    bad(ParseError::new(
                        format!("instance {k}"),
                        format!("model index {} past {}", r.model, meta.models.len()),
                    ))
                })?
                .push(*r);
        }
        for ((name, section), list) in meta.models.iter().zip(&meta.mesh_sections).zip(per_model) {
            models.push((name.clone(), section.clone(), Some(list)));
        }
    } else {
        for e in pack.of_kind(mesh::KIND) {
            let name = e.name.trim_start_matches("mesh:").to_string();
            models.push((name, e.name.clone(), None));
        }
    }
    for (name, section, list) in &models {
        if pack.find(section).is_none() {
            ex.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_MESH_MISSING,
                "",
                format!("model {name:?}: mesh section {section:?} is missing, not exported"),
            ));
            continue;
        }
        let mesh = ex.model_mesh(name, section, &materials)?;
        report.models += 1;
        match list {
            Some(list) if list.is_empty() => ex.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_MODEL_WITHOUT_INSTANCES,
                "",
                format!("model {name:?} has no instances: its mesh is exported without a node"),
            )),
            Some(list) => {
                children.push(ex.instanced_node(name, section, mesh, list));
                report.instances += list.len();
            }
            None => {
                ex.doc.nodes.push(json!({"name": name, "mesh": mesh,
                    "extras": {"section": section}}));
                children.push(ex.doc.nodes.len() - 1);
            }
        }
    }
    if let Some(e) = pack.of_kind(terrain::KIND).next()
        && let Some((node, chunks)) = ex.terrain(&e.name.clone())?
    {
        children.push(node);
        report.terrain_chunks = chunks;
    }
    let mut lights = Vec::new();
    if let Some(e) = pack.of_kind(crate::sky::section::SUN_KIND).next() {
        let v = pack.view(e)?;
        let sun = crate::sky::section::sun_from_section(&v).map_err(|err| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                err.to_string(),
            )
        })?;
        let lux = sun_lux(sun.irradiance);
        let peak = sun.irradiance.iter().cloned().fold(0.0f32, f32::max);
        let color = if peak > 0.0 {
            sun.irradiance.map(|c| (c / peak).clamp(0.0, 1.0))
        } else {
            [1.0; 3]
        };
        lights.push(json!({"name": "sun", "type": "directional", "color": color,
            "intensity": lux,
            "extras": {"section": e.name, "irradiance": sun.irradiance,
                       "lux_per_watt": LUX_PER_WATT}}));
        // The light shines along the node's −Z: turn +Z onto the direction towards the sun.
        let d = glam::Vec3::from(unit(sun.direction));
        let q = glam::Quat::from_rotation_arc(glam::Vec3::Z, d).normalize();
        ex.doc
            .nodes
            .push(json!({"name": "sun", "rotation": q.to_array(),
            "extensions": {"KHR_lights_punctual": {"light": 0}},
            "extras": {"section": e.name, "direction": sun.direction}}));
        children.push(ex.doc.nodes.len() - 1);
        report.sun_lux = Some(lux);
    }
    let pack_name = pack
        .path()
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    ex.doc.nodes.push(json!({"name": "bake Z-up to glTF Y-up", "rotation": Z_UP_TO_Y_UP,
        "children": children,
        "extras": {"pack": pack_name, "axes": "children in bake's frame: Z up, metres; this node maps (x, y, z) to (x, z, -y)"}}));
    let root = ex.doc.nodes.len() - 1;

    let mut used = Vec::new();
    if report.instances > 0 {
        used.push("EXT_mesh_gpu_instancing");
    }
    if !lights.is_empty() {
        used.push("KHR_lights_punctual");
    }
    let doc = std::mem::take(&mut ex.doc);
    report.meshes = doc.meshes.len();
    report.nodes = doc.nodes.len();
    report.materials = doc.materials.len();
    report.textures = doc.textures.len();
    report.images = doc.images.len();
    let mut bin = doc.bin;
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let mut buffer = Map::new();
    buffer.insert("byteLength".into(), json!(bin.len()));
    if container == Container::GltfEmbedded {
        use base64::Engine;
        let b64 = base64::engine::general_purpose::STANDARD.encode(&bin);
        buffer.insert(
            "uri".into(),
            json!(format!("data:application/octet-stream;base64,{b64}")),
        );
    }
    let mut gltf = json!({
        "asset": {"version": "2.0", "generator": format!("bake {} export", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"name": pack_name, "nodes": [root]}],
        "nodes": doc.nodes,
        "meshes": doc.meshes,
        "materials": doc.materials,
        "accessors": doc.accessors,
        "bufferViews": doc.views,
        "buffers": [Value::Object(buffer)],
    });
    if !doc.textures.is_empty() {
        gltf["textures"] = json!(doc.textures);
        gltf["images"] = json!(doc.images);
        // Trilinear, repeat (9987 LINEAR_MIPMAP_LINEAR, 9729 LINEAR, 10497 REPEAT).
        gltf["samplers"] =
            json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]);
    }
    if !used.is_empty() {
        gltf["extensionsUsed"] = json!(used);
    }
    if !lights.is_empty() {
        gltf["extensions"] = json!({"KHR_lights_punctual": {"lights": lights}});
    }
    let text = serde_json::to_vec(&gltf)
        .map_err(|e| Error::runtime(format!("glTF JSON encoding failed: {e}")))?;
    let bytes = match container {
        Container::GltfEmbedded => text,
        Container::Glb => glb(text, &bin),
    };
    report.bytes = bytes.len();
    report.warnings = ex.warnings;
    Ok((bytes, report))
}

/// The GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded).
fn glb(mut json: Vec<u8>, bin: &[u8]) -> Vec<u8> {
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roughness_inverts_the_import_mapping() {
        for g in [0.0f32, 0.3, 0.5, 1.0] {
            assert!((gltf_roughness(g.powi(4)) - g).abs() < 1e-6);
        }
    }

    #[test]
    fn the_root_rotation_maps_z_up_to_y_up() {
        let q = glam::Quat::from_array(Z_UP_TO_Y_UP);
        let p = q * glam::Vec3::new(1.0, 2.0, 3.0);
        assert!((p - glam::Vec3::new(1.0, 3.0, -2.0)).length() < 1e-6, "{p}");
    }

    #[test]
    fn rotation_z_turns_x_towards_y() {
        let q = glam::Quat::from_array(rotation_z(90.0));
        assert!((q * glam::Vec3::X - glam::Vec3::Y).length() < 1e-6);
    }
}
