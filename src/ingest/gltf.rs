//! glTF 2.0 reader (`.gltf` with external or embedded buffers, `.glb`), through the `gltf` crate.
//!
//! Every node of the default scene (or the first scene; without scenes, every root node) that
//! has a mesh contributes its primitives, transformed by the node's world matrix (the product of
//! the local matrices down the hierarchy). A node reached twice (a cycle, or a node with two
//! parents, both forbidden by the spec) is an error. Primitives of mode Triangles are read as
//! they are; TriangleStrip and TriangleFan are converted to triangles; Points and Lines modes are
//! skipped with a warning. A mirroring world matrix (negative determinant) reverses the winding
//! so the front faces stay front faces.
//!
//! Axes: glTF is Y-up, bake is Z-up. Positions and normals are rotated by +90° about x:
//! (x, y, z) → (x, −z, y). Texture coordinates are kept (glTF already has v = 0 at the top).
//!
//! Materials: metallic-roughness goes to [`MaterialSource::MetallicRoughness`]; the base colour
//! factor goes to `diffuse` (linear, as glTF defines it); alpha mode Blend gives
//! `transparency = 1 − alpha`. The base colour texture and normal texture become
//! [`TextureRef`]s when their image is a URI (resolved against the file's folder,
//! percent-decoded); images embedded in a buffer view or a data URI are not extracted yet, which
//! is a warning and the material is untextured. Primitives without material get the OpenGL
//! default material.
//!
//! Missing normals become face normals (the triangles' vertices are unshared); missing texture
//! coordinates become (0, 0) with a warning. Indices past the vertex count, non-finite positions,
//! missing buffers and unreadable accessors are errors naming the mesh, primitive and accessor.

use crate::error::{Error, ParseError, Result};
use crate::model::{Material, MaterialSource, Mesh, TextureRef};
use glam::{Mat3, Mat4, Vec3};
use gltf::mesh::Mode;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Reads a `.gltf` or `.glb` file; external buffers and texture URIs are resolved against the
/// file's folder.
pub fn load(path: &Path) -> Result<Mesh> {
    load_in(path, &super::confine::Roots::around(path, &[]))
}

/// Reads a `.gltf` or `.glb` file whose external buffers must lie inside `roots`: they are
/// checked before any is opened (`data:` URIs and the GLB blob read no file).
pub fn load_in(path: &Path, roots: &super::confine::Roots) -> Result<Mesh> {
    let bytes = crate::error::read_file(path)?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut warnings = Vec::new();
    if let Ok((doc, _)) = read_document(&bytes, &mut warnings) {
        for b in doc.buffers() {
            if let gltf::buffer::Source::Uri(uri) = b.source()
                && let Ok(Some(file)) = buffer_file(uri)
            {
                roots.check(path, "buffer", uri, &dir.join(file))?;
            }
        }
    }
    parse_with_base(&bytes, Some(dir)).map_err(|e| Error::invalid(path, e))
}

/// Parses a glTF or GLB file held in memory; only embedded buffers (GLB blob, data URIs) can be
/// read, and texture paths are the URIs as written.
pub fn parse(bytes: &[u8]) -> Result<Mesh, ParseError> {
    parse_with_base(bytes, None)
}

fn parse_with_base(bytes: &[u8], base: Option<&Path>) -> Result<Mesh, ParseError> {
    let mut warnings = Vec::new();
    let (doc, blob) = read_document(bytes, &mut warnings)?;
    for b in doc.buffers() {
        if let gltf::buffer::Source::Uri(uri) = b.source() {
            buffer_file(uri)
                .map_err(|m| ParseError::new(format!("buffers[{}].uri", b.index()), m))?;
        }
    }
    let buffers = gltf::import_buffers(&doc, base, blob)
        .map_err(|e| ParseError::new("buffers", format!("cannot load buffer data: {e}")))?;
    let doc = &doc;
    let mut ctx = Ctx {
        base,
        buffers: &buffers,
        mesh: Mesh::default(),
        material_map: HashMap::new(),
        texture_map: HashMap::new(),
        skipped_modes: 0,
        no_uvs: 0,
    };
    for (node, world) in scene_nodes(doc)? {
        if let Some(m) = node.mesh() {
            let name = node
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("node {}", node.index()));
            ctx.add_mesh(&m, world)?;
            ctx.mesh.objects.push(name);
        }
    }
    ctx.mesh.warnings.splice(0..0, warnings);
    ctx.finish()
}

/// Required extensions that only change materials or lights: ignoring them keeps the geometry
/// right, so they are warnings. Any other required extension (Draco, meshopt, quantization)
/// changes how geometry is stored and is an error.
const IGNORABLE_EXTENSIONS: [&str; 4] = [
    "KHR_materials_",
    "KHR_texture_",
    "KHR_technique_webgl",
    "KHR_lights_",
];

/// Parses the JSON (and the GLB container) and validates it like the `gltf` crate does, except
/// that POSITION accessors without min/max (required by the spec, but only a hint; assimp reads
/// such files) and material-only required extensions are warnings.
fn read_document(
    bytes: &[u8],
    warnings: &mut Vec<String>,
) -> Result<(gltf::Document, Option<Vec<u8>>), ParseError> {
    use gltf::json::validation::{Error as V, Validate};
    let bad = |e: &dyn std::fmt::Display| {
        ParseError::new("document", format!("not a valid glTF 2.0 file: {e}"))
    };
    let (json, blob) = if bytes.starts_with(b"glTF") {
        check_glb_length(bytes)?;
        let glb = gltf::binary::Glb::from_slice(bytes).map_err(|e| bad(&e))?;
        (glb.json.into_owned(), glb.bin.map(|b| b.into_owned()))
    } else {
        (bytes.to_vec(), None)
    };
    let root = gltf::json::Root::from_slice(&json).map_err(|e| bad(&e))?;
    check_position_accessors(&root)?;
    check_image_sources(&root)?;
    let mut errors = Vec::new();
    let mut unsupported = Vec::new();
    let mut no_min_max = 0;
    root.validate(&root, gltf::json::Path::new, &mut |path, error| {
        let path = path().to_string();
        if let (V::Unsupported, Some(ext)) = (error, extension_at(&root, &path)) {
            if IGNORABLE_EXTENSIONS.iter().any(|p| ext.starts_with(p)) {
                warnings.push(format!(
                    "required extension {ext} is not supported; ignored (materials may differ)"
                ));
            } else {
                unsupported.push(ext);
            }
        } else if matches!(error, V::Missing) && (path.ends_with(".min") || path.ends_with(".max"))
        {
            no_min_max += 1;
        } else {
            errors.push(format!("{path}: {error}"));
        }
    });
    if !unsupported.is_empty() {
        return Err(ParseError::new(
            "extensionsRequired",
            format!(
                "required extension {} is not supported",
                unsupported.join(", ")
            ),
        ));
    }
    if no_min_max > 0 {
        warnings.push(format!(
            "{no_min_max} accessor min/max values missing (ignored)"
        ));
    }
    if !errors.is_empty() {
        let n = errors.len();
        errors.truncate(5);
        return Err(bad(&format!(
            "{n} validation errors: {}",
            errors.join("; ")
        )));
    }
    Ok((gltf::Document::from_json_without_validation(root), blob))
}

/// The GLB header's total length covers at least the header: `gltf` 1.4 subtracts the header
/// size from it unchecked (an overflow panic in debug builds).
fn check_glb_length(bytes: &[u8]) -> Result<(), ParseError> {
    let length = bytes
        .get(8..12)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
    match length {
        Some(l) if l >= 12 => Ok(()),
        _ => Err(ParseError::at_byte(
            8,
            "GLB header: total length missing or shorter than the 12-byte header",
        )),
    }
}

/// An image has a `uri` or a `bufferView` with a `mimeType` (glTF 2.0, 5.18): `gltf` 1.4's
/// `Image::source` unwraps both, and its validation does not check them.
fn check_image_sources(root: &gltf::json::Root) -> Result<(), ParseError> {
    for (k, img) in root.images.iter().enumerate() {
        let ok = match (&img.uri, &img.buffer_view) {
            (Some(_), None) => true,
            (None, Some(v)) => img.mime_type.is_some() && v.value() < root.buffer_views.len(),
            _ => false,
        };
        if !ok {
            return Err(ParseError::new(
                format!("images[{k}]"),
                "an image needs a uri, or a bufferView with a mimeType",
            ));
        }
    }
    Ok(())
}

/// The accessors a primitive is read through, checked before `gltf`'s reader touches them:
/// type and component type as the semantic requires (the reader asserts or panics otherwise),
/// a count from 1 to the limit, and every byte inside its view and buffer (checked arithmetic:
/// the reader's own bounds arithmetic overflows). Sparse accessors are not supported.
fn check_primitive_accessors(
    p: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    place: &str,
) -> Result<(), ParseError> {
    use gltf::accessor::{DataType as D, Dimensions as N};
    use gltf::mesh::Semantic as S;
    let limit = super::limits::Limits::DEFAULT;
    let vertices = limit.max_vertices as usize;
    for (sem, a) in p.attributes() {
        let (ok, what) = match sem {
            S::Positions => (
                a.dimensions() == N::Vec3 && a.data_type() == D::F32,
                "POSITION: VEC3 float",
            ),
            S::Normals => (
                a.dimensions() == N::Vec3 && a.data_type() == D::F32,
                "NORMAL: VEC3 float",
            ),
            S::TexCoords(0) => (
                a.dimensions() == N::Vec2 && matches!(a.data_type(), D::F32 | D::U8 | D::U16),
                "TEXCOORD_0: VEC2 float, unsigned byte or unsigned short",
            ),
            _ => continue, // not read
        };
        if !ok {
            return Err(ParseError::new(
                place,
                format!("accessor {}: expected {what}", a.index()),
            ));
        }
        check_accessor_bytes(&a, buffers, vertices, place)?;
    }
    if let Some(a) = p.indices() {
        if a.dimensions() != N::Scalar || !matches!(a.data_type(), D::U8 | D::U16 | D::U32) {
            let msg = format!(
                "indices accessor {}: expected SCALAR unsigned byte, short or int",
                a.index()
            );
            return Err(ParseError::new(place, msg));
        }
        check_accessor_bytes(&a, buffers, 3 * limit.max_triangles as usize, place)?;
    }
    Ok(())
}

/// One accessor's count against `max` and its bytes against its view and buffer.
fn check_accessor_bytes(
    a: &gltf::Accessor,
    buffers: &[gltf::buffer::Data],
    max: usize,
    place: &str,
) -> Result<(), ParseError> {
    let bad = |m: String| ParseError::new(place, format!("accessor {}: {m}", a.index()));
    if a.sparse().is_some() {
        return Err(bad("sparse accessors are not supported".into()));
    }
    if a.count() == 0 || a.count() > max {
        return Err(bad(format!("count {} outside 1..={max}", a.count())));
    }
    let Some(view) = a.view() else {
        return Err(bad("no bufferView".into()));
    };
    let size = a.size();
    let stride = view.stride().unwrap_or(size);
    let end = (a.count() - 1)
        .checked_mul(stride)
        .and_then(|n| n.checked_add(size))
        .and_then(|n| n.checked_add(a.offset()));
    let view_end = view.offset().checked_add(view.length());
    let buffer_len = buffers.get(view.buffer().index()).map_or(0, |d| d.0.len());
    match (end, view_end) {
        (Some(e), Some(ve)) if stride >= size && e <= view.length() && ve <= buffer_len => Ok(()),
        _ => Err(bad(format!(
            "{} elements of {size} bytes (stride {stride}) at offset {} do not fit bufferView {} ({} bytes at {} in a {buffer_len}-byte buffer)",
            a.count(),
            a.offset(),
            view.index(),
            view.length(),
            view.offset()
        ))),
    }
}

/// `gltf-json` 1.4's validation indexes `accessors` with each primitive's POSITION accessor
/// unchecked (a panic on a dangling index): check those indices first.
fn check_position_accessors(root: &gltf::json::Root) -> Result<(), ParseError> {
    use gltf::json::validation::Checked;
    let pos = Checked::Valid(gltf::json::mesh::Semantic::Positions);
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(a) = prim.attributes.get(&pos)
                && a.value() >= root.accessors.len()
            {
                return Err(ParseError::new(
                    format!("meshes[{m}].primitives[{p}].attributes.POSITION"),
                    format!(
                        "accessor {} does not exist ({} accessors)",
                        a.value(),
                        root.accessors.len()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The extension named by a validation path like `extensionsRequired[0]` (the path may carry
/// the value after it: `extensionsRequired[0] = "KHR_x"`).
fn extension_at(root: &gltf::json::Root, path: &str) -> Option<String> {
    let rest = path.strip_prefix("extensionsRequired[")?;
    let k: usize = rest[..rest.find(']')?].parse().ok()?;
    root.extensions_required.get(k).cloned()
}

fn hex(c: u8) -> Option<u8> {
    (c as char).to_digit(16).map(|d| d as u8)
}

/// The nodes to draw with their world matrices (glTF axes), depth-first.
fn scene_nodes(doc: &gltf::Document) -> Result<Vec<(gltf::Node<'_>, Mat4)>, ParseError> {
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let mut is_child = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    is_child[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(ParseError::new(
                format!("node {}", node.index()),
                "node is reached twice in the hierarchy (recursive or shared nodes are not allowed)",
            ));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let children: Vec<_> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, world));
        }
        out.push((node, world));
    }
    Ok(out)
}

struct Ctx<'a> {
    base: Option<&'a Path>,
    buffers: &'a [gltf::buffer::Data],
    mesh: Mesh,
    /// glTF material index (None = default) → index in `mesh.materials`.
    material_map: HashMap<Option<usize>, u32>,
    /// glTF image index → index in `mesh.textures` (None: not extractable).
    texture_map: HashMap<usize, Option<u32>>,
    skipped_modes: usize,
    no_uvs: usize,
}

/// glTF (Y-up) to bake (Z-up): (x, y, z) → (x, −z, y). Columns: x → x, y → z, z → −y.
const Y_UP_TO_Z_UP: Mat4 = Mat4::from_cols_array(&[
    1.0, 0.0, 0.0, 0.0, //
    0.0, 0.0, 1.0, 0.0, //
    0.0, -1.0, 0.0, 0.0, //
    0.0, 0.0, 0.0, 1.0,
]);

impl Ctx<'_> {
    fn add_mesh(&mut self, m: &gltf::Mesh, world: Mat4) -> Result<(), ParseError> {
        for p in m.primitives() {
            let place = format!("mesh {} primitive {}", m.index(), p.index());
            match p.mode() {
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => {
                    self.add_primitive(&p, world, &place)?
                }
                _ => self.skipped_modes += 1,
            }
        }
        Ok(())
    }

    fn add_primitive(
        &mut self,
        p: &gltf::Primitive,
        world: Mat4,
        place: &str,
    ) -> Result<(), ParseError> {
        check_primitive_accessors(p, self.buffers, place)?;
        let reader = p.reader(|b| self.buffers.get(b.index()).map(|d| &d.0[..]));
        let err = |what: &str| ParseError::new(place, what.to_string());
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| err("POSITION missing or outside its buffer"))?
            .collect();
        if let Some(k) = positions
            .iter()
            .position(|v| !v.iter().all(|c| c.is_finite()))
        {
            return Err(err(&format!(
                "position {k} is not finite: {:?}",
                positions[k]
            )));
        }
        let n = positions.len();
        let raw: Vec<u32> = match (p.indices(), reader.read_indices()) {
            (_, Some(i)) => i.into_u32().collect(),
            (Some(a), None) => {
                return Err(err(&format!(
                    "indices (accessor {}) outside their buffer",
                    a.index()
                )));
            }
            (None, None) => (0..n as u32).collect(),
        };
        if let Some(&bad) = raw.iter().find(|&&i| i as usize >= n) {
            return Err(err(&format!("index {bad} out of range ({n} vertices)")));
        }
        let mut tris = assemble(p.mode(), &raw);
        let total = Y_UP_TO_Z_UP * world;
        if total.determinant() < 0.0 {
            for t in &mut tris {
                t.swap(1, 2);
            }
        }
        let normal_m = Mat3::from_mat4(total).inverse().transpose();
        let normals: Option<Vec<[f32; 3]>> = reader.read_normals().map(|i| i.collect());
        let uvs: Option<Vec<[f32; 2]>> = reader.read_tex_coords(0).map(|t| t.into_f32().collect());
        let uvs = match uvs.filter(|u| u.len() == n) {
            Some(u) => u,
            None => {
                self.no_uvs += 1;
                vec![[0.0, 0.0]; n]
            }
        };
        let mat = self.material(p.material());
        let pos: Vec<[f32; 3]> = positions
            .iter()
            .map(|v| total.transform_point3(Vec3::from_array(*v)).to_array())
            .collect();
        let part = match normals.filter(|v| v.len() == n) {
            Some(nrm) => Mesh {
                normals: nrm
                    .iter()
                    .map(|v| {
                        (normal_m * Vec3::from_array(*v))
                            .normalize_or(Vec3::Z)
                            .to_array()
                    })
                    .collect(),
                positions: pos,
                uvs,
                triangle_materials: vec![mat; tris.len()],
                indices: tris,
                ..Mesh::default()
            },
            None => super::obj::flat_mesh(&pos, &uvs, &tris, mat),
        };
        // `append` offsets material and texture indices by the current counts: ours already
        // index the shared lists, so append with them set aside.
        let keep = (
            std::mem::take(&mut self.mesh.materials),
            std::mem::take(&mut self.mesh.textures),
        );
        self.mesh.append(part);
        (self.mesh.materials, self.mesh.textures) = keep;
        Ok(())
    }

    /// The index of a glTF material in our list, converting it on first use.
    fn material(&mut self, m: gltf::Material) -> u32 {
        if let Some(&i) = self.material_map.get(&m.index()) {
            return i;
        }
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_factor();
        let name = match (m.name(), m.index()) {
            (Some(n), _) => n.to_string(),
            (None, Some(i)) => format!("material {i}"),
            (None, None) => "default".into(),
        };
        let mut out = Material {
            name,
            // glTF's `doubleSided` (default false, also for the default material): a one-sided
            // material's back faces are culled, so the PRT stage need not light them.
            double_sided: m.double_sided(),
            ..Material::default()
        };
        if m.index().is_some() {
            out.diffuse = base;
            out.source = MaterialSource::MetallicRoughness {
                metallic: pbr.metallic_factor(),
                roughness: pbr.roughness_factor(),
            };
            if m.alpha_mode() == gltf::material::AlphaMode::Blend {
                out.transparency = 1.0 - base[3];
            }
            let e = m.emissive_factor();
            out.emission = [e[0], e[1], e[2], 1.0];
            out.color_map = pbr
                .base_color_texture()
                .and_then(|t| self.texture(t.texture()));
            out.normal_map = m.normal_texture().and_then(|t| self.texture(t.texture()));
        }
        let i = self.mesh.materials.len() as u32;
        self.mesh.materials.push(out);
        self.material_map.insert(m.index(), i);
        i
    }

    /// The index of a texture's image in `mesh.textures`, if it is a file URI.
    fn texture(&mut self, t: gltf::Texture) -> Option<u32> {
        let image = t.source();
        if let Some(&i) = self.texture_map.get(&image.index()) {
            return i;
        }
        let r = match image.source() {
            gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
                let name = percent_decode(uri);
                let path = match self.base {
                    Some(b) => b.join(&name),
                    None => PathBuf::from(&name),
                };
                self.mesh.textures.push(TextureRef { name, path });
                Some(self.mesh.textures.len() as u32 - 1)
            }
            _ => {
                self.mesh.warnings.push(format!(
                    "image {} is embedded (buffer view or data URI); not extracted, material untextured",
                    image.index()
                ));
                None
            }
        };
        self.texture_map.insert(image.index(), r);
        r
    }

    fn finish(mut self) -> Result<Mesh, ParseError> {
        if self.skipped_modes > 0 {
            self.mesh.warnings.push(format!(
                "{} point or line primitives skipped",
                self.skipped_modes
            ));
        }
        if self.no_uvs > 0 {
            self.mesh.warnings.push(format!(
                "{} primitives without TEXCOORD_0; texture coordinates set to (0, 0)",
                self.no_uvs
            ));
        }
        if self.mesh.indices.is_empty() {
            return Err(ParseError::new(
                "scene",
                format!(
                    "no triangles to read ({} point or line primitives skipped)",
                    self.skipped_modes
                ),
            ));
        }
        Ok(self.mesh)
    }
}

/// Triangles from an index list in the given mode (strips alternate their winding; fans share
/// the first vertex). Degenerate strip triangles (two equal indices) are kept.
fn assemble(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => (2..idx.len())
            .map(|k| {
                if k % 2 == 0 {
                    [idx[k - 2], idx[k - 1], idx[k]]
                } else {
                    [idx[k - 1], idx[k - 2], idx[k]]
                }
            })
            .collect(),
        Mode::TriangleFan => (2..idx.len())
            .map(|k| [idx[0], idx[k - 1], idx[k]])
            .collect(),
        _ => idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
    }
}

/// Decodes `%XX` escapes of a URI (invalid escapes are kept as written).
/// The file a buffer URI reads, as `gltf::import_buffers` will read it: `None` for a `data:`
/// URI, the percent-decoded relative path, or the path of a `file:` URI (absolute ones are then
/// refused by confinement). Other schemes, and percent-escapes that do not decode to UTF-8
/// (`gltf` 1.4 unwraps that decoding), are errors.
fn buffer_file(uri: &str) -> Result<Option<PathBuf>, String> {
    if uri.starts_with("data:") {
        return Ok(None);
    }
    if let Some(rest) = uri
        .strip_prefix("file://")
        .or_else(|| uri.strip_prefix("file:"))
    {
        return Ok(Some(PathBuf::from(rest)));
    }
    if uri.contains(':') {
        return Err(format!(
            "unsupported URI scheme in {uri:?} (data: or a relative path expected)"
        ));
    }
    let decoded = percent_decode_bytes(uri);
    String::from_utf8(decoded)
        .map(|s| Some(PathBuf::from(s)))
        .map_err(|_| format!("URI {uri:?} does not percent-decode to UTF-8"))
}

pub(crate) fn percent_decode(s: &str) -> String {
    String::from_utf8_lossy(&percent_decode_bytes(s)).into_owned()
}

fn percent_decode_bytes(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push(h * 16 + l);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression (found by tests/fuzz_smoke.rs): a POSITION accessor of another type tripped
    /// an assertion in `gltf`'s reader ("left: 12, right: 2"); counts past the view, or 0,
    /// overflowed its bounds arithmetic.
    #[test]
    fn accessors_of_the_wrong_type_or_size_are_errors_not_panics() {
        let buf = "data:application/octet-stream;base64,".to_string() + &"A".repeat(48);
        let doc = |acc: &str| {
            format!(
                r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
"buffers":[{{"byteLength":36,"uri":"{buf}"}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
"accessors":[{acc}]}}"#
            )
        };
        let ok = r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}"#;
        assert!(parse(doc(ok).as_bytes()).is_ok());
        for (acc, msg) in [
            (
                r#"{"bufferView":0,"componentType":5123,"count":3,"type":"SCALAR"}"#,
                "expected POSITION",
            ),
            (
                r#"{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3"}"#,
                "do not fit",
            ),
            (
                r#"{"bufferView":0,"componentType":5126,"count":0,"type":"VEC3"}"#,
                "count 0",
            ),
            (
                r#"{"bufferView":0,"byteOffset":4294967295,"componentType":5126,"count":3,"type":"VEC3"}"#,
                "do not fit",
            ),
        ] {
            let e = parse(doc(acc).as_bytes()).unwrap_err();
            assert!(e.message.contains(msg), "{acc}: {e}");
        }
    }

    /// Regression (cargo-fuzz gltf, crash-d46bcd94): a buffer URI whose percent-escapes do not
    /// decode to UTF-8 panicked in `gltf::import` (`urlencoding::decode(..).unwrap()`); a
    /// `file:` URI would have been read from anywhere.
    #[test]
    fn crash_d46bcd94_buffer_uris_that_do_not_decode_are_errors() {
        let doc = |uri: &str| {
            format!(
                r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":4,"uri":"{uri}"}}]}}"#
            )
        };
        for (uri, msg) in [
            ("a%AB.bin", "percent-decode"),
            ("http://x/b.bin", "unsupported URI scheme"),
        ] {
            let e = parse(doc(uri).as_bytes()).unwrap_err();
            assert_eq!(e.place, "buffers[0].uri", "{e}");
            assert!(e.message.contains(msg), "{e}");
        }
        let crash = include_bytes!(
            "../../tests/data/fuzz/gltf/crash-d46bcd943fe4b7f738cab0ee7f75cb198d056cc5"
        );
        assert!(parse(crash).is_err());
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/m.gltf");
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(dir.path().join("b.bin"), [0u8; 4]).unwrap();
        let abs = format!("file://{}", dir.path().join("b.bin").display());
        std::fs::write(&p, doc(&abs)).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(
            e.contains("outside the scene") && e.contains("--allow-path"),
            "{e}"
        );
    }

    /// Regression (found by tests/fuzz_smoke.rs): a GLB whose header length is under 12
    /// overflowed a subtraction in `gltf::binary::Glb::from_slice` (a panic in debug builds).
    #[test]
    fn glb_length_under_the_header_size_is_an_error_not_a_panic() {
        for len in [0u32, 11] {
            let mut b = b"glTF".to_vec();
            b.extend(2u32.to_le_bytes());
            b.extend(len.to_le_bytes());
            let e = parse(&b).unwrap_err();
            assert_eq!(e.place, "byte 8", "{e}");
        }
        assert!(parse(b"glTF\x02\0\0").is_err());
    }

    /// Regression (found by tests/fuzz_smoke.rs): an image with neither uri nor bufferView
    /// panicked in `gltf::Image::source` (`Option::unwrap()` on a `None` value).
    #[test]
    fn image_without_a_source_is_an_error_not_a_panic() {
        for img in [
            r#"{}"#,
            r#"{"bufferView":0}"#,
            r#"{"uri":"a.png","bufferView":0}"#,
        ] {
            let doc = format!(
                r#"{{"asset":{{"version":"2.0"}},"images":[{img}],"buffers":[{{"byteLength":4,"uri":"data:application/octet-stream;base64,AAAAAA=="}}],"bufferViews":[{{"buffer":0,"byteLength":4}}]}}"#
            );
            let e = parse(doc.as_bytes()).unwrap_err();
            assert_eq!(e.place, "images[0]", "{img}: {e}");
        }
    }

    /// Regression (found by tests/fuzz_smoke.rs): a POSITION accessor index past the accessor
    /// list panicked inside gltf-json's validation ("index out of bounds: the len is 0").
    #[test]
    fn dangling_position_accessor_is_an_error_not_a_panic() {
        let doc = br#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]}"#;
        let e = parse(doc).unwrap_err();
        assert_eq!(e.place, "meshes[0].primitives[0].attributes.POSITION");
        assert!(e.message.contains("accessor 0 does not exist"), "{e}");
    }

    fn base64(data: &[u8]) -> String {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in data.chunks(3) {
            let n = (c[0] as u32) << 16
                | (*c.get(1).unwrap_or(&0) as u32) << 8
                | *c.get(2).unwrap_or(&0) as u32;
            for k in 0..4 {
                if k <= c.len() {
                    s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
                } else {
                    s.push('=');
                }
            }
        }
        s
    }

    /// Four positions (a unit square in glTF's x/y) then three u16 indices, padded to 56 bytes.
    fn buffer(indices: [u16; 3], first: [f32; 3]) -> Vec<u8> {
        let mut b = Vec::new();
        let pos = [first, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
        for p in pos {
            b.extend(p.iter().flat_map(|c| c.to_le_bytes()));
        }
        b.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
        b.extend([0, 0]);
        b
    }

    /// parent (translation z = 5) → child (scale 2, mesh 0: indexed triangle, textured
    /// material); strip (translation x = 10, mesh 1: 4-vertex triangle strip, no material).
    fn document(uri: Option<&str>, nodes: &str) -> String {
        let buf = match uri {
            Some(u) => format!(r#"{{"byteLength": 56, "uri": "{u}"}}"#),
            None => r#"{"byteLength": 56}"#.to_string(),
        };
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0, 2]}}],
  "nodes": {nodes},
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 2, "material": 0}}]}},
             {{"primitives": [{{"attributes": {{"POSITION": 1}}, "mode": 5}}]}}],
  "materials": [{{"name": "Paint", "pbrMetallicRoughness": {{"baseColorFactor": [0.5, 0.25, 1, 1],
     "metallicFactor": 0.3, "roughnessFactor": 0.7, "baseColorTexture": {{"index": 0}}}}}}],
  "textures": [{{"source": 0}}], "images": [{{"uri": "tex%20a.png"}}],
  "buffers": [{buf}],
  "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
                  {{"buffer": 0, "byteOffset": 48, "byteLength": 6}}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
    {{"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}}]}}"#
        )
    }

    const NODES: &str = r#"[{"name": "parent", "translation": [0, 0, 5], "children": [1]},
      {"name": "child", "scale": [2, 2, 2], "mesh": 0},
      {"name": "strip", "translation": [10, 0, 0], "mesh": 1}]"#;

    fn embedded(indices: [u16; 3], first: [f32; 3], nodes: &str) -> Vec<u8> {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64(&buffer(indices, first))
        );
        document(Some(&uri), nodes).into_bytes()
    }

    fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        let mut j = json.as_bytes().to_vec();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let total = 12 + 8 + j.len() + 8 + bin.len();
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((j.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(j);
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(bin);
        out
    }

    fn check_scene(m: &Mesh) {
        assert_eq!(m.objects, vec!["child".to_string(), "strip".to_string()]);
        assert_eq!(m.indices.len(), 3, "1 triangle + a 4-vertex strip");
        // child: glTF world T(0,0,5)·S(2), then (x, y, z) → (x, −z, y).
        let tri: Vec<_> = m.indices[0]
            .iter()
            .map(|&i| m.positions[i as usize])
            .collect();
        assert_eq!(tri, [[0.0, -5.0, 0.0], [2.0, -5.0, 0.0], [0.0, -5.0, 2.0]]);
        // glTF +z normal becomes −y; no normals in the file, so face normals.
        for &i in &m.indices[0] {
            assert_eq!(m.normals[i as usize], [0.0, -1.0, 0.0]);
        }
        // strip: both triangles keep the square's orientation (−y after the axis swap).
        for t in &m.indices[1..] {
            let [a, b, c] = t.map(|i| Vec3::from_array(m.positions[i as usize]));
            assert!((b - a).cross(c - a).y < 0.0);
            assert!(t.iter().all(|&i| m.positions[i as usize][0] >= 10.0));
        }
        let paint = &m.materials[m.triangle_materials[0] as usize];
        assert_eq!(paint.name, "Paint");
        assert_eq!(paint.diffuse, [0.5, 0.25, 1.0, 1.0]);
        assert_eq!(
            paint.source,
            MaterialSource::MetallicRoughness {
                metallic: 0.3,
                roughness: 0.7
            }
        );
        assert_eq!(
            m.textures[paint.color_map.unwrap() as usize].name,
            "tex a.png"
        );
        assert!(!paint.double_sided, "glTF doubleSided defaults to false");
        let default = &m.materials[m.triangle_materials[1] as usize];
        assert_eq!(default.name, "default");
        assert!(
            !default.double_sided,
            "glTF's default material is one-sided"
        );
        assert!(m.warnings.iter().any(|w| w.contains("TEXCOORD_0")));
        assert_eq!(m.validate(), Ok(()));
    }

    #[test]
    fn node_transforms_axes_strips_and_materials() {
        check_scene(&parse(&embedded([0, 1, 2], [0.0; 3], NODES)).unwrap());
    }

    #[test]
    fn double_sided_is_read_from_the_material() {
        let json = String::from_utf8(embedded([0, 1, 2], [0.0; 3], NODES)).unwrap();
        let two = json.replace(
            r#""name": "Paint","#,
            r#""name": "Paint", "doubleSided": true,"#,
        );
        assert_ne!(two, json);
        let m = parse(two.as_bytes()).unwrap();
        assert!(m.materials[m.triangle_materials[0] as usize].double_sided);
        assert!(!m.materials[m.triangle_materials[1] as usize].double_sided);
        let one = json.replace(
            r#""name": "Paint","#,
            r#""name": "Paint", "doubleSided": false,"#,
        );
        let m = parse(one.as_bytes()).unwrap();
        assert!(!m.materials[m.triangle_materials[0] as usize].double_sided);
    }

    #[test]
    fn a_one_sided_gltf_material_gets_a_zero_back_transfer_through_the_pack() {
        // File → ingest (mesh section with `one_sided_materials`) → PRT stage: the triangle of
        // the one-sided "Paint" has a zero back side, the default material's strip too (glTF's
        // default material is one-sided), and `prt.sides = "both"` traces them all.
        let dir = tempfile::tempdir().unwrap();
        let json = String::from_utf8(embedded([0, 1, 2], [0.0; 3], NODES)).unwrap();
        let two = json.replace(
            r#""name": "Paint","#,
            r#""name": "Paint", "doubleSided": true,"#,
        );
        let bake = |doc: &str, sides| {
            let file = dir.path().join("m.gltf");
            std::fs::write(&file, doc).unwrap();
            let (w, _) = crate::pipeline::ingest_to_pack(&file, &Default::default()).unwrap();
            let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "m.bake").unwrap();
            let opts = crate::prt::transfer::PrtOptions {
                samples: 16,
                bounces: 1,
                sides,
                ..Default::default()
            };
            let (w, _, _) = crate::prt::pack::prt_pack(&pack, &opts, &|_| {}).unwrap();
            let out = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "o.bake").unwrap();
            let mesh_name = out
                .of_kind(crate::mesh::section::KIND)
                .next()
                .unwrap()
                .name
                .clone();
            let (_, mesh) =
                crate::mesh::section::from_section(&out.view_named(&mesh_name).unwrap()).unwrap();
            let prt_name = crate::prt::pack::section_name(&mesh_name);
            let (_, t) =
                crate::prt::pack::from_section(&out.view_named(&prt_name).unwrap()).unwrap();
            (mesh, t)
        };
        use crate::prt::transfer::PrtSides;
        let zero = |t: &crate::prt::transfer::Transfer, v: usize, side: usize| {
            (0..2).all(|set| t.get(v, side, set).iter().all(|c| *c == [0.0; 3]))
        };
        let (mesh, auto) = bake(&json, PrtSides::Auto);
        assert!(mesh.materials.iter().all(|m| !m.double_sided));
        for v in 0..mesh.positions.len() {
            assert!(!zero(&auto, v, 0) && zero(&auto, v, 1), "vertex {v}");
        }
        let (_, both) = bake(&json, PrtSides::Both);
        for v in 0..mesh.positions.len() {
            assert!(!zero(&both, v, 1), "vertex {v}");
            assert_eq!(auto.get(v, 0, 0), both.get(v, 0, 0));
        }
        assert!(auto.rays < both.rays);
        let (mesh, two_sided) = bake(&two, PrtSides::Auto);
        let paint = mesh.indices[0];
        for v in 0..mesh.positions.len() {
            let back_traced = !zero(&two_sided, v, 1);
            assert_eq!(back_traced, paint.contains(&(v as u32)), "vertex {v}");
        }
    }

    #[test]
    fn glb_and_external_buffer_give_the_same_mesh() {
        let bin = buffer([0, 1, 2], [0.0; 3]);
        check_scene(&parse(&glb(&document(None, NODES), &bin)).unwrap());
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("b.bin"), &bin).unwrap();
        std::fs::write(dir.path().join("s.gltf"), document(Some("b.bin"), NODES)).unwrap();
        let m = load(&dir.path().join("s.gltf")).unwrap();
        check_scene(&m);
        assert_eq!(m.textures[0].path, dir.path().join("tex a.png"));
        std::fs::remove_file(dir.path().join("b.bin")).unwrap();
        let e = load(&dir.path().join("s.gltf")).unwrap_err().to_string();
        assert!(e.contains("buffers: cannot load buffer data"), "{e}");
    }

    #[test]
    fn broken_files_are_clear_errors() {
        let e = parse(&embedded([0, 1, 7], [0.0; 3], NODES)).unwrap_err();
        assert_eq!(e.place, "mesh 0 primitive 0");
        assert!(
            e.message.contains("index 7 out of range (3 vertices)"),
            "{e}"
        );
        let e = parse(&embedded([0, 1, 2], [f32::INFINITY, 0.0, 0.0], NODES)).unwrap_err();
        assert!(e.message.contains("not finite"), "{e}");
        let cycle = r#"[{"children": [1]}, {"children": [0], "mesh": 0}, {"mesh": 1}]"#;
        let e = parse(&embedded([0, 1, 2], [0.0; 3], cycle)).unwrap_err();
        assert!(e.message.contains("reached twice"), "{e}");
        let e = parse(b"{\"asset\": 5}").unwrap_err();
        assert!(e.message.contains("not a valid glTF"), "{e}");
    }

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("a%20b%2Fc%zz%"), "a b/c%zz%");
    }
}
