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

mod ambient;

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
use std::io::{Seek, Write};
use std::path::Path;

/// Cells per side of one terrain chunk (one glTF primitive each).
pub(crate) const TERRAIN_CHUNK: u32 = 64;

/// Luminous efficacy used to turn the sun's irradiance (W/m², linear RGB) into illuminance (lux):
/// lux = 683 lm/W × Rec. 709 luminance of the RGB irradiance.
pub(crate) const LUX_PER_WATT: f32 = 683.0;

/// The root node's rotation, Z-up to Y-up: −90° about +X, (x, y, z) → (x, z, −y).
pub(crate) const Z_UP_TO_Y_UP: [f32; 4] = [
    -std::f32::consts::FRAC_1_SQRT_2,
    0.0,
    0.0,
    std::f32::consts::FRAC_1_SQRT_2,
];

/// Albedo of a terrain without a colour map (sRGB 128 grey, as every stage takes it).
const TERRAIN_GREY: f32 = 0.216;

/// Illuminance in lux of a sun of RGB irradiance `e` (W/m²): [`LUX_PER_WATT`] · luminance(e).
pub(crate) fn sun_lux(e: [f32; 3]) -> f32 {
    LUX_PER_WATT * crate::color::luminance(e)
}

/// glTF metallic-roughness roughness of a Schlick layer of roughness `r` (= roughness⁴ on import,
/// docs/MATERIALS.md): r^(1/4), clamped to [0, 1].
pub(crate) fn gltf_roughness(r: f32) -> f32 {
    r.max(0.0).powf(0.25).min(1.0)
}

/// The quaternion (x, y, z, w) of a rotation by `deg` degrees about +Z (counter-clockwise from
/// above, as ECO rotations are).
pub(crate) fn rotation_z(deg: f32) -> [f32; 4] {
    let (s, c) = (deg.to_radians() * 0.5).sin_cos();
    [0.0, 0.0, s, c]
}

/// What an export wrote.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub(crate) struct ExportReport {
    pub meshes: usize,
    pub nodes: usize,
    pub materials: usize,
    pub textures: usize,
    pub images: usize,
    pub models: usize,
    pub instances: usize,
    pub terrain_chunks: usize,
    /// `--terrain-step`: the grid step of the exported terrain (1: every sample).
    pub terrain_step: u32,
    /// The largest vertical distance (m) of any terrain grid sample from the exported terrain
    /// surface: 0 at step 1, else the height error of the coarser grid (`--terrain-step`).
    pub terrain_max_error_m: f32,
    /// `.gltf` with a side file: the buffer's file name, beside the output (its bytes are in
    /// `bytes`).
    pub side_file: Option<String>,
    /// The terrain's light-map section, exported as a texture on TEXCOORD_1.
    pub lightmap: Option<String>,
    /// Whether the light map was multiplied into the terrain's (unlit) base colour.
    pub bake_light: bool,
    /// Meshes of `lod` levels 1.. and skeletons (`--lod`).
    pub lod_meshes: usize,
    /// Models given COLOR_0 (`--vertex-ambient`).
    pub vertex_ambient_models: usize,
    /// W/m²/sr: the ambient radiance of an albedo-1 surface is COLOR_0 × this
    /// (`--vertex-ambient`).
    pub vertex_ambient_scale: Option<f32>,
    /// The sun's illuminance in lux, `None` without a `sun` section.
    pub sun_lux: Option<f32>,
    pub bytes: usize,
    pub warnings: Vec<crate::diag::Warning>,
}

/// What [`export`] writes beside the container.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ExportOptions {
    pub container: Container,
    /// Multiply the terrain's light map into its base colour, the material unlit
    /// (`KHR_materials_unlit`), so that viewers without light-map support show the baked light.
    pub bake_light: bool,
    /// Every model vertex's PRT ambient (the renderer's, under the pack's light) as `COLOR_0`,
    /// divided by one scale for the file (docs/MATERIALS.md). Needs a `prt` section.
    pub vertex_ambient: bool,
    /// Every model's `lod` levels 1.. as meshes, on nodes named by the model node's `MSFT_lod`.
    pub lod: bool,
    /// Normal maps as `normalTexture` (linear PNG in glTF's tangent frame) with the pack's
    /// tangents as `TANGENT`, where a material has a normal map and its model tangents.
    pub normal_maps: bool,
    /// The terrain at every `terrain_step`-th grid sample (and the last row and column), ≥ 1.
    pub terrain_step: u32,
}

/// The output container.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Container {
    /// Binary glTF: JSON and buffer in one file.
    Glb,
    /// JSON glTF, the buffer embedded as a base64 data URI (no side files).
    GltfEmbedded,
    /// JSON glTF and its buffer as a side file beside it, named by the output's stem and the
    /// buffer's content ([`side_file_name`]), as gltfpack writes `.gltf`.
    GltfSideFile,
}

/// The side file of a `.gltf` whose buffer has BLAKE3 `hash`: `<stem>-<16 hex digits>.bin`. A
/// name per content keeps the previous scene whole until the new `.gltf` replaces it (its
/// buffer is written first, under another name); the replaced buffer is removed afterwards.
pub(crate) fn side_file_name(output: &Path, hash: &blake3::Hash) -> String {
    let stem = output
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    format!("{stem}-{}.bin", &hash.to_hex()[..16])
}

/// Whether `name` is a side file [`side_file_name`] makes for `output`'s stem.
fn is_side_file_of(output: &Path, name: &str) -> bool {
    let stem = output
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    name.strip_prefix(&stem)
        .and_then(|r| r.strip_prefix('-'))
        .and_then(|r| r.strip_suffix(".bin"))
        .is_some_and(|h| h.len() == 16 && h.bytes().all(|b| b.is_ascii_hexdigit()))
}

const ARRAY_BUFFER: u32 = 34962;
/// Sampler 0: trilinear, repeat (colour maps); sampler 1: bilinear, clamped to the edge (the
/// light map, which the renderer reads clamped).
const SAMPLER_REPEAT: usize = 0;
const SAMPLER_CLAMP: usize = 1;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// The binary buffer, streamed to an unnamed temporary file beside the output as it is made
/// (a 4097² terrain is about a gigabyte of vertices and indices): only its length stays in
/// memory. The first write error is kept and reported when the file is assembled.
struct Bin {
    out: std::io::BufWriter<std::fs::File>,
    len: u64,
    error: Option<std::io::Error>,
}

impl Bin {
    fn new(dir: &Path) -> Result<Bin> {
        let file = tempfile::tempfile_in(dir).map_err(|e| Error::io(dir, e))?;
        Ok(Bin {
            out: std::io::BufWriter::with_capacity(1 << 20, file),
            len: 0,
            error: None,
        })
    }

    fn put(&mut self, bytes: &[u8]) {
        if self.error.is_none()
            && let Err(e) = self.out.write_all(bytes)
        {
            self.error = Some(e);
        }
        self.len += bytes.len() as u64;
    }

    /// Zero bytes up to a multiple of 4; returns the offset reached.
    fn align(&mut self) -> u64 {
        let pad = (4 - self.len % 4) % 4;
        self.put(&[0u8; 3][..pad as usize]);
        self.len
    }

    /// The finished buffer (length a multiple of 4), rewound for reading.
    fn finish(mut self, dir: &Path) -> Result<(std::fs::File, u64)> {
        self.align();
        if let Some(e) = self.error {
            return Err(Error::io(dir, e));
        }
        let mut file = self
            .out
            .into_inner()
            .map_err(|e| Error::io(dir, e.into_error()))?;
        file.seek(std::io::SeekFrom::Start(0))
            .map_err(|e| Error::io(dir, e))?;
        Ok((file, self.len))
    }
}

/// The binary buffer and the JSON arrays that index it.
struct Doc {
    bin: Bin,
    views: Vec<Value>,
    accessors: Vec<Value>,
    images: Vec<Value>,
    textures: Vec<Value>,
    materials: Vec<Value>,
    meshes: Vec<Value>,
    nodes: Vec<Value>,
}

impl Doc {
    fn new(dir: &Path) -> Result<Doc> {
        Ok(Doc {
            bin: Bin::new(dir)?,
            views: Vec::new(),
            accessors: Vec::new(),
            images: Vec::new(),
            textures: Vec::new(),
            materials: Vec::new(),
            meshes: Vec::new(),
            nodes: Vec::new(),
        })
    }

    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        let offset = self.bin.align();
        let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.put(bytes);
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

    /// A PNG image in the buffer and a texture of it; returns the texture's index.
    fn png_texture(&mut self, png: &[u8], name: &str, extras: Value, sampler: usize) -> usize {
        let view = self.view(png, None);
        self.images
            .push(json!({"bufferView": view, "mimeType": "image/png",
            "name": name, "extras": extras}));
        let image = self.images.len() - 1;
        self.textures
            .push(json!({"source": image, "sampler": sampler, "name": name}));
        self.textures.len() - 1
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

/// A model's lower levels as exported: their meshes (levels 1..), `MSFT_screencoverage` and the
/// selection rule for the node's extras.
struct Lods {
    meshes: Vec<usize>,
    /// The skeleton's mesh (lines and points), after the mesh levels.
    skeleton: Option<usize>,
    screen: Vec<f32>,
    info: Value,
}

/// The geometry of one glTF mesh of a model (see [`Exporter::geometry_mesh`]).
struct Geometry<'a> {
    positions: &'a [[f32; 3]],
    /// Per vertex, the mesh vertex it copies (a `lod` level); `None`: the mesh's own vertices.
    source: Option<&'a [u32]>,
    indices: &'a [[u32; 3]],
    triangle_materials: &'a [u32],
}

struct Exporter<'a> {
    pack: &'a Pack,
    bake_light: bool,
    /// Whether a material is `KHR_materials_unlit`.
    unlit: bool,
    /// The terrain's light-map section, where exported.
    lightmap: Option<String>,
    /// `--vertex-ambient`: the models' COLOR_0.
    ambient: Option<ambient::VertexAmbient>,
    /// glTF materials made, by (mesh section, mesh material): shared by a model's levels.
    made: HashMap<(String, usize), usize>,
    /// Whether a node carries `MSFT_lod`.
    lod_used: bool,
    /// `--normal-maps`.
    normal_maps: bool,
    /// `--terrain-step` (≥ 1).
    terrain_step: u32,
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
            let texture =
                self.doc
                    .png_texture(&png, name, json!({"section": name}), SAMPLER_REPEAT);
            Some(Exported { texture, has_alpha })
        };
        self.textures.insert(name.to_string(), out);
        Ok(out)
    }

    /// The glTF texture of the normal map in texture section `name` (its `normal` array's level
    /// 0), exported once. bake's tangent frame has the bitangent along increasing v (down the
    /// image, src/mesh/tangents.rs); glTF's has it up the image (+Y up): the green channel is
    /// mirrored (G → 255 − G) and the TANGENT's w negated, so both files give the same normal
    /// (t·x + b·y + n·z with b and y both turned). Linear PNG (glTF reads normal textures as
    /// data, not colour).
    fn normal_texture(&mut self, name: &str) -> Result<Option<usize>> {
        let key = format!("normal map {name}");
        if let Some(t) = self.textures.get(&key) {
            return Ok(t.map(|e| e.texture));
        }
        let bad = |e: ParseError| {
            Error::invalid_at(self.pack.path(), format!("section {name:?}"), e.to_string())
        };
        let out = match self.pack.find(name) {
            None => None,
            Some(_) => {
                let v = self.pack.view_named(name)?;
                let meta: TextureMeta = v.meta().map_err(bad)?;
                let table = crate::texture::section::levels(&v, &meta, "normal").map_err(bad)?;
                let normal: &[[u8; 4]] = v.array("normal").map_err(bad)?;
                let l0 = table.first().copied().unwrap_or_default();
                let texels = normal
                    .get(l0[2] as usize..(l0[2] + l0[3]) as usize)
                    .filter(|t| !t.is_empty() && t.len() as u64 == l0[0] as u64 * l0[1] as u64)
                    .ok_or_else(|| bad(ParseError::new("normal", "level 0 outside the array")))?;
                let img = Rgba8Image {
                    width: l0[0],
                    height: l0[1],
                    pixels: texels
                        .iter()
                        .map(|p| [p[0], 255 - p[1], p[2], 255])
                        .collect(),
                };
                let png = crate::render::encode_png(&img)?;
                let texture = self.doc.png_texture(
                    &png,
                    &format!("{name} normal"),
                    json!({"section": name, "array": "normal",
                           "frame": "glTF (+Y up the image): bake's green mirrored, TANGENT w negated"}),
                    SAMPLER_REPEAT,
                );
                Some(Exported {
                    texture,
                    has_alpha: false,
                })
            }
        };
        self.textures.insert(key, out);
        Ok(out.map(|e| e.texture))
    }

    /// One glTF material from a `material:` section (or, where the pack has none, from the
    /// mesh's own material: its diffuse colour, roughness 1).
    fn material(
        &mut self,
        mesh_section: &str,
        index: usize,
        input: &crate::model::Material,
        converted: Option<(&str, &MaterialMeta)>,
        tangents: bool,
    ) -> Result<usize> {
        let double_sided = input.double_sided;
        let normal_map = match converted {
            Some((_, m)) if self.normal_maps && tangents => m.normal_map.clone(),
            _ => None,
        };
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
        let normal = match &normal_map {
            Some(n) => self.normal_texture(n)?,
            None => None,
        };
        let masked = tex.is_some_and(|t| t.has_alpha) || opacity < 1.0;
        let mut m = json!({
            "name": name,
            "pbrMetallicRoughness": pbr,
            "doubleSided": double_sided,
            "extras": {"section": section, "mesh_section": mesh_section, "index": index,
                       "color_map": color_map},
        });
        if let Some(t) = normal {
            m["normalTexture"] = json!({"index": t});
            m["extras"]["normal_map"] = json!(normal_map);
        }
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

    /// A model's mesh (level 0): shared vertex accessors, one primitive per material that has
    /// triangles. Returns the glTF mesh and the pack's mesh.
    fn model_mesh(
        &mut self,
        name: &str,
        section: &str,
        materials: &HashMap<(String, u32), (String, MaterialMeta)>,
    ) -> Result<(usize, Mesh)> {
        let v = self.pack.view_named(section)?;
        let (_, m): (_, Mesh) = mesh::from_section(&v).map_err(|e| {
            Error::invalid_at(
                self.pack.path(),
                format!("section {section:?}"),
                e.to_string(),
            )
        })?;
        let geometry = Geometry {
            positions: &m.positions,
            source: None,
            indices: &m.indices,
            triangle_materials: &m.triangle_materials,
        };
        let mesh = self.geometry_mesh(name, section, &m, geometry, materials, json!({}))?;
        Ok((mesh, m))
    }

    /// One glTF mesh of a model's geometry: level 0 (the mesh's own vertices) or a `lod` level
    /// (its vertices, each a copy of mesh vertex `source[i]`: normal, UV and COLOR_0 gathered
    /// from it). Materials are made once per model and shared between its levels.
    fn geometry_mesh(
        &mut self,
        name: &str,
        section: &str,
        m: &Mesh,
        g: Geometry,
        materials: &HashMap<(String, u32), (String, MaterialMeta)>,
        mut extras: Value,
    ) -> Result<usize> {
        let gather = |a: &[[f32; 3]]| -> Vec<[f32; 3]> {
            match g.source {
                None => a.to_vec(),
                Some(src) => src
                    .iter()
                    .map(|&s| a.get(s as usize).copied().unwrap_or([0.0; 3]))
                    .collect(),
            }
        };
        let normals: Vec<[f32; 3]> = gather(&m.normals).into_iter().map(unit).collect();
        let uvs: Vec<[f32; 2]> = match g.source {
            None => m.uvs.clone(),
            Some(src) => src
                .iter()
                .map(|&s| m.uvs.get(s as usize).copied().unwrap_or([0.0; 2]))
                .collect(),
        };
        let pos = self
            .doc
            .floats(g.positions, "VEC3", Some(ARRAY_BUFFER), true);
        let nrm = self.doc.floats(&normals, "VEC3", Some(ARRAY_BUFFER), false);
        let uv = self.doc.floats(&uvs, "VEC2", Some(ARRAY_BUFFER), false);
        // TANGENT (`--normal-maps`): the pack's tangents in glTF's frame (w negated: see
        // `normal_texture`), gathered like the normals.
        let tangent = match self.normal_maps {
            true => match model_tangents(self.pack, section, m.positions.len())? {
                Some(t) => {
                    let t: Vec<[f32; 4]> = match g.source {
                        None => t,
                        Some(src) => src
                            .iter()
                            .map(|&s| t.get(s as usize).copied().unwrap_or([1.0, 0.0, 0.0, 1.0]))
                            .collect(),
                    };
                    let t: Vec<[f32; 4]> = t.iter().map(|v| [v[0], v[1], v[2], -v[3]]).collect();
                    Some(self.doc.floats(&t, "VEC4", Some(ARRAY_BUFFER), false))
                }
                None => None,
            },
            false => None,
        };
        // COLOR_0 (`--vertex-ambient`): one accessor, or one per material where they differ.
        // Taken out for the loop (self.material borrows self) and put back at the end.
        let amb = self.ambient.take();
        let colors = amb.as_ref().and_then(|a| a.models.get(section));
        let mut color_of = HashMap::new();
        extras["section"] = json!(section);
        if let Some(c) = colors {
            let scale = amb.as_ref().map_or(1.0, |a| a.scale);
            let source = amb.as_ref().map(|a| a.source);
            extras["vertex_ambient"] = json!({
                "section": c.prt_section, "attribute": "COLOR_0", "scale": scale,
                "unit": "W/m^2/sr", "instances": c.instances, "light": source,
                "per_material": matches!(c.colors, ambient::Colors::PerMaterial(_)),
                "radiance": "L_ambient = base colour * COLOR_0 * scale (front side, eq. 4.8, mean over the model's instances)"});
        }
        let mut primitives = Vec::new();
        for (i, input) in m.materials.iter().enumerate() {
            let tris: Vec<[u32; 3]> = g
                .indices
                .iter()
                .zip(g.triangle_materials)
                .filter(|(_, mat)| **mat as usize == i)
                .map(|(t, _)| *t)
                .collect();
            if tris.is_empty() {
                continue;
            }
            let material = match self.made.get(&(section.to_string(), i)) {
                Some(&k) => k,
                None => {
                    let converted = materials
                        .get(&(section.to_string(), i as u32))
                        .map(|(s, mm)| (s.as_str(), mm));
                    let k = self.material(section, i, input, converted, tangent.is_some())?;
                    self.made.insert((section.to_string(), i), k);
                    k
                }
            };
            let idx = self.doc.indices(&tris);
            let mut attributes = json!({"POSITION": pos, "NORMAL": nrm, "TEXCOORD_0": uv});
            if let Some(t) = tangent
                && self.doc.materials[material].get("normalTexture").is_some()
            {
                attributes["TANGENT"] = json!(t);
            }
            if let Some(c) = colors {
                let key = match c.colors {
                    ambient::Colors::Shared(_) => usize::MAX,
                    ambient::Colors::PerMaterial(_) => i,
                };
                let acc = match color_of.get(&key) {
                    Some(&a) => a,
                    None => {
                        let values = gather(c.colors.of(i));
                        let a = self.doc.floats(&values, "VEC3", Some(ARRAY_BUFFER), false);
                        color_of.insert(key, a);
                        a
                    }
                };
                attributes["COLOR_0"] = json!(acc);
            }
            primitives.push(json!({
                "attributes": attributes,
                "indices": idx, "material": material, "mode": 4,
            }));
        }
        self.ambient = amb;
        if primitives.is_empty() {
            return Err(Error::invalid_at(
                self.pack.path(),
                format!("section {section:?}"),
                "the mesh has no triangles",
            ));
        }
        self.doc
            .meshes
            .push(json!({"name": name, "primitives": primitives, "extras": extras}));
        Ok(self.doc.meshes.len() - 1)
    }

    /// The `lod` levels 1.. of a model as meshes (`<name> lod<l>`), where the pack has a `lod`
    /// section with more than one level; `None` otherwise.
    fn lod_meshes(
        &mut self,
        name: &str,
        section: &str,
        m: &Mesh,
        materials: &HashMap<(String, u32), (String, MaterialMeta)>,
    ) -> Result<Option<Lods>> {
        let Some(view) = crate::lod::section::read(self.pack, section)? else {
            return Ok(None);
        };
        let meta = &view.meta;
        if meta.levels.len() < 2 && meta.skeleton.is_none() {
            return Ok(None);
        }
        let lod_section = crate::lod::section::lod_section_name(section);
        let mut meshes = Vec::new();
        for (l, level) in meta.levels.iter().enumerate().skip(1) {
            let first = level.first_vertex as usize;
            let source = &view.vertex_source[first..first + level.vertex_count as usize];
            let (indices, triangle_materials) = view.level_triangles(l);
            let g = Geometry {
                positions: view.level_positions(l),
                source: Some(source),
                indices,
                triangle_materials,
            };
            let extras = json!({"lod_section": lod_section, "level": l, "error": level.error});
            meshes.push(self.geometry_mesh(
                &format!("{name} lod{l}"),
                section,
                m,
                g,
                materials,
                extras,
            )?);
        }
        // The skeleton (TXF line and point arrays), the renderer's farthest representation: a
        // mesh of a LINES and a POINTS primitive in the model's mean albedo.
        let mut skeleton = None;
        if let Some(sk) = &meta.skeleton
            && (!view.skeleton_lines.is_empty() || !view.skeleton_points.is_empty())
        {
            let albedo = sk
                .albedo
                .map(|c| crate::color::srgb_to_linear(c as f32 / 255.0));
            self.doc.materials.push(json!({
                "name": format!("{name} skeleton"),
                "pbrMetallicRoughness": {"baseColorFactor": [albedo[0], albedo[1], albedo[2], 1.0],
                    "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "extras": {"section": lod_section, "skeleton_albedo_srgb8": sk.albedo}}));
            let material = self.doc.materials.len() - 1;
            let mut primitives = Vec::new();
            let lines = view.skeleton_lines.len() / 2 * 2;
            if lines > 0 {
                let a = self.doc.floats(
                    &view.skeleton_lines[..lines],
                    "VEC3",
                    Some(ARRAY_BUFFER),
                    true,
                );
                primitives
                    .push(json!({"attributes": {"POSITION": a}, "material": material, "mode": 1}));
            }
            if !view.skeleton_points.is_empty() {
                let a = self
                    .doc
                    .floats(view.skeleton_points, "VEC3", Some(ARRAY_BUFFER), true);
                primitives
                    .push(json!({"attributes": {"POSITION": a}, "material": material, "mode": 0}));
            }
            self.doc
                .meshes
                .push(json!({"name": format!("{name} skeleton"),
                "primitives": primitives,
                "extras": {"section": section, "lod_section": lod_section, "skeleton": true}}));
            skeleton = Some((self.doc.meshes.len() - 1, sk.pixels));
        }
        let k = crate::lod::select::reference_k();
        let tau = crate::lod::select::DEFAULT_TAU;
        let errors: Vec<f32> = meta.levels.iter().map(|l| l.error).collect();
        // The fraction of the reference view's height the bounding sphere's diameter covers
        // where the renderer switches to each level: 2R·k/(d·H) at d = e·k/τ, i.e. 2R·τ/(e·H).
        let coverage = |e: f32| {
            if e > 0.0 {
                2.0 * meta.radius * tau / (e * crate::lod::select::REFERENCE_HEIGHT as f32)
            } else {
                f32::INFINITY
            }
        };
        let mut screen: Vec<f32> = errors[1..].iter().map(|&e| coverage(e)).collect();
        if let Some((_, pixels)) = skeleton {
            // Drawn where the sphere's radius projects to at most `pixels`: a diameter of 2P.
            screen.push(2.0 * pixels / crate::lod::select::REFERENCE_HEIGHT as f32);
        }
        // Non-increasing, as MSFT_screencoverage reads them.
        for i in 1..screen.len() {
            screen[i] = screen[i].min(screen[i - 1]);
        }
        screen.push(0.0);
        let info = json!({
            "section": lod_section, "errors": errors, "centre": meta.centre,
            "radius": meta.radius,
            "switch_distance": errors.iter()
                .map(|&e| crate::lod::select::switch_distance(e, 1.0, k, tau)).collect::<Vec<_>>(),
            "reference": {"height": crate::lod::select::REFERENCE_HEIGHT,
                          "fov_y_deg": crate::lod::select::REFERENCE_FOV_Y_DEG, "tau": tau},
            "rule": "level l where e_l * s * k <= tau * d (largest such l); k = H / (2 tan(fov_y / 2)) pixels per unit at distance 1, s the instance scale, d the distance from the eye to the placed sphere centre"});
        let mut info = info;
        if let Some((_, pixels)) = skeleton {
            info["skeleton"] = json!({"pixels": pixels,
                "rule": "drawn where radius * s * k <= pixels * d, before any mesh level"});
        }
        Ok(Some(Lods {
            meshes,
            skeleton: skeleton.map(|s| s.0),
            screen,
            info,
        }))
    }

    /// A model's node (instanced through `EXT_mesh_gpu_instancing` where `list` is given, else
    /// at the origin) and, with `lods`, one node per lower level (the same instance accessors)
    /// named by the first one's `MSFT_lod`; the lower levels are not in the scene's hierarchy.
    fn model_node(
        &mut self,
        name: &str,
        section: &str,
        mesh: usize,
        list: Option<&[InstanceRecord]>,
        lods: Option<&Lods>,
    ) -> usize {
        let mut extensions = json!({});
        let mut extras = json!({"section": section});
        if let Some(list) = list {
            let t: Vec<[f32; 3]> = list.iter().map(|r| r.position).collect();
            let r: Vec<[f32; 4]> = list.iter().map(|r| rotation_z(r.rotation_deg)).collect();
            let s: Vec<[f32; 3]> = list.iter().map(|r| [r.scale; 3]).collect();
            let ta = self.doc.floats(&t, "VEC3", None, true);
            let ra = self.doc.floats(&r, "VEC4", None, false);
            let sa = self.doc.floats(&s, "VEC3", None, false);
            extensions["EXT_mesh_gpu_instancing"] =
                json!({"attributes": {"TRANSLATION": ta, "ROTATION": ra, "SCALE": sa}});
            extras["instances_section"] = json!(instances::KIND);
            extras["instances"] = json!(list.len());
        }
        let with = |mesh: usize, name: String, extensions: &Value, extras: Value| {
            let mut n = json!({"name": name, "mesh": mesh, "extras": extras});
            if extensions.as_object().is_some_and(|o| !o.is_empty()) {
                n["extensions"] = extensions.clone();
            }
            n
        };
        let node = self.doc.nodes.len();
        self.doc
            .nodes
            .push(with(mesh, name.to_string(), &extensions, extras.clone()));
        if let Some(lods) = lods {
            let mut ids = Vec::new();
            for (l, &m) in lods.meshes.iter().enumerate() {
                let mut e = extras.clone();
                e["lod_level"] = json!(l + 1);
                ids.push(self.doc.nodes.len());
                self.doc
                    .nodes
                    .push(with(m, format!("{name} lod{}", l + 1), &extensions, e));
            }
            if let Some(m) = lods.skeleton {
                let mut e = extras.clone();
                e["lod_level"] = json!("skeleton");
                ids.push(self.doc.nodes.len());
                // The same instances (three.js does not instance lines and points: its page
                // places them itself, scripts/threejs/page.js).
                self.doc
                    .nodes
                    .push(with(m, format!("{name} skeleton"), &extensions, e));
            }
            let n = &mut self.doc.nodes[node];
            n["extensions"]["MSFT_lod"] = json!({"ids": ids});
            n["extras"]["MSFT_screencoverage"] = json!(lods.screen);
            n["extras"]["lod"] = lods.info.clone();
            n["extras"]["lod"]["nodes"] = json!(ids[..lods.meshes.len()]);
            if lods.skeleton.is_some() {
                n["extras"]["lod"]["skeleton"]["node"] = json!(ids.last());
            }
            self.lod_used = true;
        }
        node
    }

    /// The terrain as one mesh of chunk primitives (every `terrain_step`-th grid sample); returns
    /// its node, the chunk count and the largest height error of the step
    /// ([`terrain_step_error`]).
    fn terrain(&mut self, name: &str) -> Result<Option<(usize, usize, f32)>> {
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
        let light = terrain_light(self.pack)?;
        let grey = if color.is_some() { 1.0 } else { TERRAIN_GREY };
        let mut pbr = json!({"baseColorFactor": [grey, grey, grey, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 1.0});
        if let Some(c) = color {
            pbr["baseColorTexture"] = json!({"index": c.texture});
        }
        let mut extras = json!({"section": name, "color_map": meta.color_section});
        let mut unlit = false;
        if let Some(l) = &light {
            let lightmap = self.doc.png_texture(
                &crate::render::encode_png(&l.encoded())?,
                &l.section,
                json!({"section": l.section, "array": "irradiance",
                       "irradiance_scale": l.scale}),
                SAMPLER_CLAMP,
            );
            extras["lightmap"] = json!({
                "section": l.section, "array": "irradiance",
                "texture": {"index": lightmap, "texCoord": 1},
                "irradiance_scale": l.scale, "unit": "W/m^2",
                "encoding": "sRGB 8-bit of E / irradiance_scale (linear RGB irradiance E)",
                "radiance": "L = albedo * E / pi"});
            if self.bake_light {
                let albedo = match &meta.color_section {
                    Some(c) if color.is_some() => Some(texture_image(self.pack, c)?),
                    _ => None,
                };
                let img = l.lit_albedo(albedo.as_ref(), TERRAIN_GREY);
                let name = format!(
                    "{} x {}",
                    meta.color_section.as_deref().unwrap_or("grey"),
                    l.section
                );
                let lit = self.doc.png_texture(
                    &crate::render::encode_png(&img)?,
                    &name,
                    json!({"sections": [meta.color_section, l.section],
                           "irradiance_scale": l.scale}),
                    SAMPLER_CLAMP,
                );
                pbr["baseColorFactor"] = json!([1.0, 1.0, 1.0, 1.0]);
                pbr["baseColorTexture"] = json!({"index": lit});
                extras["bake_light"] = json!({
                    "sections": [meta.color_section, l.section],
                    "color_texture": color.map(|c| c.texture),
                    "irradiance_scale": l.scale,
                    "base_color": "albedo * E / irradiance_scale (E: the light map's irradiance)",
                    "radiance": "L = base colour * irradiance_scale / pi (W/m^2/sr)"});
                unlit = true;
            }
        } else if self.bake_light {
            self.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_NO_LIGHT_MAP,
                name,
                "--bake-light: the pack has no light map of the terrain; exported lit",
            ));
        }
        let mut m = json!({"name": "terrain", "pbrMetallicRoughness": pbr,
            "doubleSided": false, "extras": extras});
        if unlit {
            m["extensions"] = json!({"KHR_materials_unlit": {}});
            self.unlit = true;
        }
        self.lightmap = light.as_ref().map(|l| l.section.clone());
        self.doc.materials.push(m);
        let material = self.doc.materials.len() - 1;
        let (w, h) = (t.width, t.height);
        let dx = t.extent[0] / (w - 1) as f32;
        let dy = t.extent[1] / (h - 1) as f32;
        // The exported grid columns and rows: every step-th sample and the last (step 1: all).
        let xs = step_samples(w, self.terrain_step);
        let ys = step_samples(h, self.terrain_step);
        let mut primitives = Vec::new();
        for cy in (0..ys.len() - 1).step_by(TERRAIN_CHUNK as usize) {
            for cx in (0..xs.len() - 1).step_by(TERRAIN_CHUNK as usize) {
                let (x1, y1) = (
                    (cx + TERRAIN_CHUNK as usize).min(xs.len() - 1),
                    (cy + TERRAIN_CHUNK as usize).min(ys.len() - 1),
                );
                let cols = (x1 - cx + 1) as u32;
                let mut pos = Vec::new();
                let mut nrm = Vec::new();
                let mut uv = Vec::new();
                for &j in &ys[cy..=y1] {
                    for &i in &xs[cx..=x1] {
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
                for j in 0..(y1 - cy) as u32 {
                    for i in 0..(x1 - cx) as u32 {
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
                let mut attributes = json!({"POSITION": p, "NORMAL": n, "TEXCOORD_0": u});
                if light.is_some() {
                    // The light map spans the terrain's extent as the colour map does (texel
                    // centres at (k + 1/2)/size of it): the same coordinates, one accessor.
                    attributes["TEXCOORD_1"] = json!(u);
                }
                primitives.push(json!({
                    "attributes": attributes,
                    "indices": idx, "material": material, "mode": 4,
                    "extras": {"cells": [xs[cx], ys[cy], xs[x1], ys[y1]]},
                }));
            }
        }
        let chunks = primitives.len();
        let mut extras = json!({"section": name, "chunk_cells": TERRAIN_CHUNK});
        let error = if self.terrain_step > 1 {
            let e = terrain_step_error(&t.heights, w, &xs, &ys);
            extras["step"] = json!(self.terrain_step);
            extras["max_height_error_m"] = json!(e);
            e
        } else {
            0.0
        };
        self.doc
            .meshes
            .push(json!({"name": "terrain", "primitives": primitives, "extras": extras}));
        let mesh = self.doc.meshes.len() - 1;
        self.doc.nodes.push(json!({"name": "terrain", "mesh": mesh,
            "extras": {"section": name}}));
        Ok(Some((self.doc.nodes.len() - 1, chunks, error)))
    }
}

/// The terrain's light map (the first `lightmap` section whose surface is "terrain"): its total
/// irradiance (direct sun with its visibility, sky, bounce), row 0 north, texel centres at
/// (k + ½)/size of the extent.
/// The grid indices `0, step, 2·step, …` below `n` and `n − 1` (every index at step 1).
fn step_samples(n: u32, step: u32) -> Vec<u32> {
    let mut v: Vec<u32> = (0..n).step_by(step.max(1) as usize).collect();
    if v.last() != Some(&(n - 1)) {
        v.push(n - 1);
    }
    v
}

/// The largest |height − surface| over the grid samples (`w` per row), the surface being the grid's
/// columns `xs` and rows `ys` triangulated as exported (each cell split along its (i, j)–(i + 1,
/// j + 1) diagonal) and interpolated linearly within each triangle.
fn terrain_step_error(heights: &[f32], w: u32, xs: &[u32], ys: &[u32]) -> f32 {
    let at = |i: u32, j: u32| heights[(j * w + i) as usize] as f64;
    let mut worst = 0.0f64;
    for c in 0..ys.len().saturating_sub(1) {
        let (j0, j1) = (ys[c], ys[c + 1]);
        for a in 0..xs.len().saturating_sub(1) {
            let (i0, i1) = (xs[a], xs[a + 1]);
            let (h00, h10, h01, h11) = (at(i0, j0), at(i1, j0), at(i0, j1), at(i1, j1));
            for j in j0..=j1 {
                let v = (j - j0) as f64 / (j1 - j0) as f64;
                for i in i0..=i1 {
                    let u = (i - i0) as f64 / (i1 - i0) as f64;
                    // Below the diagonal (u ≥ v): triangle (00, 10, 11); above: (00, 11, 01).
                    let s = if u >= v {
                        h00 + u * (h10 - h00) + v * (h11 - h10)
                    } else {
                        h00 + v * (h01 - h00) + u * (h11 - h01)
                    };
                    worst = worst.max((at(i, j) - s).abs());
                }
            }
        }
    }
    worst as f32
}

struct TerrainLight {
    section: String,
    width: u32,
    height: u32,
    texels: Vec<[f32; 3]>,
    /// The largest component of any texel (W/m²): the 8-bit encodings divide by it.
    scale: f32,
}

/// The `tangents` section of mesh section `mesh_section` (one per vertex), or `None` where the
/// pack has none or its count does not match.
fn model_tangents(
    pack: &Pack,
    mesh_section: &str,
    vertices: usize,
) -> Result<Option<Vec<[f32; 4]>>> {
    for e in pack.of_kind(crate::mesh::tangents::KIND) {
        let v = pack.view(e)?;
        let (meta, t) = crate::mesh::tangents::from_section(&v).map_err(|err| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                err.to_string(),
            )
        })?;
        if meta.mesh_section == mesh_section {
            return Ok((t.len() == vertices).then_some(t));
        }
    }
    Ok(None)
}

fn terrain_light(pack: &Pack) -> Result<Option<TerrainLight>> {
    use crate::lightmap::section::{self as lightmap, LightmapMeta};
    for e in pack.of_kind(lightmap::KIND) {
        let v = pack.view(e)?;
        let bad = |err: ParseError| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                err.to_string(),
            )
        };
        let meta: LightmapMeta = v.meta().map_err(bad)?;
        if meta.surface != "terrain" {
            continue;
        }
        let t: &[[f32; 4]] = v.array("irradiance").map_err(bad)?;
        if t.is_empty() || t.len() as u64 != meta.width as u64 * meta.height as u64 {
            return Err(bad(ParseError::new(
                "irradiance",
                format!("{} texels for {}×{}", t.len(), meta.width, meta.height),
            )));
        }
        let texels: Vec<[f32; 3]> = t
            .iter()
            .map(|x| [0, 1, 2].map(|c| if x[c].is_finite() { x[c].max(0.0) } else { 0.0 }))
            .collect();
        let scale = texels.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
        if scale <= 0.0 {
            return Ok(None);
        }
        return Ok(Some(TerrainLight {
            section: e.name.clone(),
            width: meta.width,
            height: meta.height,
            texels,
            scale,
        }));
    }
    Ok(None)
}

/// A linear value in [0, 1] as an 8-bit sRGB code.
fn srgb8(l: f32) -> u8 {
    (crate::color::linear_to_srgb(l.clamp(0.0, 1.0)) * 255.0).round() as u8
}

impl TerrainLight {
    /// The irradiance at texture coordinates (u, v), bilinear between texel centres and clamped
    /// to the edge: the arithmetic of the renderer's `light_map_bilinear` (shaders/ambient.wgsl).
    fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        bilinear(&self.texels, self.width, self.height, u, v)
    }

    /// The light map as 8-bit sRGB of E / scale.
    fn encoded(&self) -> Rgba8Image {
        Rgba8Image {
            width: self.width,
            height: self.height,
            pixels: self
                .texels
                .iter()
                .map(|e| {
                    let [r, g, b] = e.map(|c| srgb8(c / self.scale));
                    [r, g, b, 255]
                })
                .collect(),
        }
    }

    /// albedo × E / scale as 8-bit sRGB, at the finer of the colour map's and the light map's
    /// resolutions (each sampled bilinearly at the texel centres); `grey` without a colour map.
    fn lit_albedo(&self, color: Option<&Rgba8Image>, grey: f32) -> Rgba8Image {
        let linear: Option<Vec<[f32; 3]>> = color.map(|c| {
            c.pixels
                .iter()
                .map(|p| [0, 1, 2].map(|k| crate::color::srgb_to_linear(p[k] as f32 / 255.0)))
                .collect()
        });
        let (w, h) = match color {
            Some(c) => (c.width.max(self.width), c.height.max(self.height)),
            None => (self.width, self.height),
        };
        let mut pixels = Vec::with_capacity(w as usize * h as usize);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
                let a = match (color, &linear) {
                    (Some(c), Some(l)) => bilinear(l, c.width, c.height, u, v),
                    _ => [grey; 3],
                };
                let e = self.sample(u, v);
                let [r, g, b] = [0, 1, 2].map(|k| srgb8(a[k] * e[k] / self.scale));
                pixels.push([r, g, b, 255]);
            }
        }
        Rgba8Image {
            width: w,
            height: h,
            pixels,
        }
    }
}

/// Bilinear lookup of a `w`×`h` grid of texels at (u, v), texel centres at (k + ½)/size,
/// clamped to the edge.
fn bilinear(texels: &[[f32; 3]], w: u32, h: u32, u: f32, v: f32) -> [f32; 3] {
    let fx = u * w as f32 - 0.5;
    let fy = v * h as f32 - 0.5;
    let (x0, y0) = (fx.floor(), fy.floor());
    let (ax, ay) = (fx - x0, fy - y0);
    let at = |x: i64, y: i64| {
        texels[(y.clamp(0, h as i64 - 1) * w as i64 + x.clamp(0, w as i64 - 1)) as usize]
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let (t00, t10, t01, t11) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    std::array::from_fn(|c| {
        let top = t00[c] + (t10[c] - t00[c]) * ax;
        let bottom = t01[c] + (t11[c] - t01[c]) * ax;
        top + (bottom - top) * ay
    })
}

fn unit(n: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 1e-12 && l.is_finite() {
        n.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The pack as a glTF document written to `output` (through a temporary file renamed at the
/// end: a failed export leaves no output); returns what it holds. The binary buffer is streamed
/// to disk as it is made, so memory holds one section's arrays at a time, not the file. Fails
/// (invalid input) on a pack without any mesh section, before anything is created.
pub(crate) fn export(pack: &Pack, opts: ExportOptions, output: &Path) -> Result<ExportReport> {
    let container = opts.container;
    if pack.of_kind(mesh::KIND).next().is_none() {
        return Err(Error::invalid_at(
            pack.path(),
            "section table",
            "the pack has no mesh section: nothing to export (bake export needs a pack with models, \
             e.g. from `bake SCENE.eco` or `bake ingest MODEL`)",
        ));
    }
    let dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let mut warnings = Vec::new();
    // Before anything is created: a pack without PRT is refused here.
    let vertex_ambient = if opts.vertex_ambient {
        Some(ambient::load(pack, &mut warnings)?)
    } else {
        None
    };
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut ex = Exporter {
        pack,
        bake_light: opts.bake_light,
        unlit: false,
        lightmap: None,
        ambient: vertex_ambient,
        made: HashMap::new(),
        lod_used: false,
        normal_maps: opts.normal_maps,
        terrain_step: opts.terrain_step.max(1),
        doc: Doc::new(&dir)?,
        textures: HashMap::new(),
        warnings,
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
        let (mesh, m) = ex.model_mesh(name, section, &materials)?;
        let lods = if opts.lod {
            ex.lod_meshes(name, section, &m, &materials)?
        } else {
            None
        };
        drop(m);
        report.lod_meshes += lods
            .as_ref()
            .map_or(0, |l| l.meshes.len() + l.skeleton.is_some() as usize);
        report.models += 1;
        match list {
            Some(list) if list.is_empty() => ex.warnings.push(crate::diag::Warning::new(
                &crate::diag::EXPORT_MODEL_WITHOUT_INSTANCES,
                "",
                format!("model {name:?} has no instances: its mesh is exported without a node"),
            )),
            Some(list) => {
                children.push(ex.model_node(name, section, mesh, Some(list), lods.as_ref()));
                report.instances += list.len();
            }
            None => children.push(ex.model_node(name, section, mesh, None, lods.as_ref())),
        }
    }
    if let Some(e) = pack.of_kind(terrain::KIND).next()
        && let Some((node, chunks, error)) = ex.terrain(&e.name.clone())?
    {
        children.push(node);
        report.terrain_chunks = chunks;
        report.terrain_step = ex.terrain_step;
        report.terrain_max_error_m = error;
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
    let mut root_extras = json!({"pack": pack_name, "axes": "children in bake's frame: Z up, metres; this node maps (x, y, z) to (x, z, -y)"});
    if let Some(a) = &ex.ambient {
        root_extras["vertex_ambient_scale"] = json!(a.scale);
    }
    ex.doc.nodes.push(
        json!({"name": "bake Z-up to glTF Y-up", "rotation": Z_UP_TO_Y_UP,
        "children": children, "extras": root_extras}),
    );
    let root = ex.doc.nodes.len() - 1;

    let mut used = Vec::new();
    if report.instances > 0 {
        used.push("EXT_mesh_gpu_instancing");
    }
    if !lights.is_empty() {
        used.push("KHR_lights_punctual");
    }
    if ex.unlit {
        used.push("KHR_materials_unlit");
    }
    if ex.lod_used {
        used.push("MSFT_lod");
    }
    let doc = ex.doc;
    report.meshes = doc.meshes.len();
    report.nodes = doc.nodes.len();
    report.materials = doc.materials.len();
    report.textures = doc.textures.len();
    report.images = doc.images.len();
    report.lightmap = ex.lightmap.clone();
    report.bake_light = ex.unlit;
    if let Some(a) = &ex.ambient {
        report.vertex_ambient_models = a.models.len();
        report.vertex_ambient_scale = Some(a.scale);
    }
    let (mut bin, bin_len) = doc.bin.finish(&dir)?;
    let mut buffer = Map::new();
    buffer.insert("byteLength".into(), json!(bin_len));
    // The embedded buffer's data URI is streamed into the JSON text where this marker stands.
    const URI_MARK: &str = "\u{1}bake-buffer\u{1}";
    let mut side = None;
    match container {
        Container::Glb => {}
        Container::GltfEmbedded => {
            buffer.insert("uri".into(), json!(URI_MARK));
        }
        Container::GltfSideFile => {
            // The buffer first, under a name of its content: the previous scene stays whole.
            let mut hasher = blake3::Hasher::new();
            std::io::copy(&mut bin, &mut hasher).map_err(|e| Error::io(&dir, e))?;
            let name = side_file_name(output, &hasher.finalize());
            let path = dir.join(&name);
            bin.seek(std::io::SeekFrom::Start(0))
                .map_err(|e| Error::io(&dir, e))?;
            crate::pack::write_atomic_with(&path, |w| {
                std::io::copy(&mut bin, w).map_err(|e| Error::io(&path, e))
            })?;
            buffer.insert("uri".into(), json!(name));
            side = Some((name, bin_len));
        }
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
        // Sampler 1: bilinear, clamped (33071 CLAMP_TO_EDGE), for the light map.
        gltf["samplers"] = json!([
            {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497},
            {"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}]);
    }
    if !used.is_empty() {
        gltf["extensionsUsed"] = json!(used);
    }
    if !lights.is_empty() {
        gltf["extensions"] = json!({"KHR_lights_punctual": {"lights": lights}});
    }
    let text = serde_json::to_vec(&gltf)
        .map_err(|e| Error::runtime(format!("glTF JSON encoding failed: {e}")))?;
    drop(gltf);
    let io = |e: std::io::Error| Error::io(output, e);
    report.bytes = crate::pack::write_atomic_with(output, |w| match container {
        Container::Glb => {
            let mut json = text;
            while !json.len().is_multiple_of(4) {
                json.push(b' ');
            }
            let total = 12 + 8 + json.len() as u64 + if bin_len == 0 { 0 } else { 8 + bin_len };
            let total32 = u32::try_from(total).map_err(|_| {
                Error::runtime(format!(
                    "the GLB would be {total} bytes: more than the format's 4 GiB (write .gltf, or \
                     export a smaller pack)"
                ))
            })?;
            w.write_all(b"glTF").map_err(io)?;
            w.write_all(&2u32.to_le_bytes()).map_err(io)?;
            w.write_all(&total32.to_le_bytes()).map_err(io)?;
            w.write_all(&(json.len() as u32).to_le_bytes())
                .map_err(io)?;
            w.write_all(b"JSON").map_err(io)?;
            w.write_all(&json).map_err(io)?;
            if bin_len > 0 {
                w.write_all(&(bin_len as u32).to_le_bytes()).map_err(io)?;
                w.write_all(b"BIN\0").map_err(io)?;
                std::io::copy(&mut bin, w).map_err(io)?;
            }
            Ok(total as usize)
        }
        Container::GltfEmbedded => {
            let mark = serde_json::to_string(URI_MARK).expect("a string");
            let at = text
                .windows(mark.len())
                .position(|x| x == mark.as_bytes())
                .expect("the buffer's URI marker is in the JSON");
            let prefix = b"\"data:application/octet-stream;base64,";
            w.write_all(&text[..at]).map_err(io)?;
            w.write_all(prefix).map_err(io)?;
            {
                let mut enc = base64::write::EncoderWriter::new(
                    &mut *w,
                    &base64::engine::general_purpose::STANDARD,
                );
                std::io::copy(&mut bin, &mut enc).map_err(io)?;
                enc.finish().map_err(io)?;
            }
            w.write_all(b"\"").map_err(io)?;
            w.write_all(&text[at + mark.len()..]).map_err(io)?;
            let b64 = bin_len.div_ceil(3) * 4;
            Ok(text.len() - mark.len() + prefix.len() + b64 as usize + 1)
        }
        Container::GltfSideFile => {
            w.write_all(&text).map_err(io)?;
            Ok(text.len())
        }
    })?;
    if let Some((name, len)) = side {
        // The buffers of scenes this output replaced (same stem, another content).
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for e in entries.flatten() {
                let n = e.file_name().to_string_lossy().into_owned();
                if n != name && is_side_file_of(output, &n) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        report.side_file = Some(name);
        report.bytes += len as usize;
    }
    report.warnings = ex.warnings;
    Ok(report)
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
