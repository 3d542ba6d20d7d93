//! Ingest: every input format into the in-memory model ([`crate::model`]).
//!
//! Each reader takes bytes (`parse`) so fuzzers and tests drive it directly, and has a `load`
//! that reads the file, attaches the path to errors and resolves referenced files.

pub mod confine;
pub mod eco;
pub mod gltf;
pub mod instances_section;
pub mod limits;
pub mod max3ds;
pub mod obj;
pub mod raw;
pub mod rgbe;
pub mod sgi;
pub mod skyimage;
pub mod texture;
pub mod txf;

use crate::error::{Error, Result};
use crate::model::{FloatImage, Mesh, Scene, Terrain};
use std::path::{Path, PathBuf};

/// What a single input file turned into.
#[derive(Debug, Clone, PartialEq)]
pub enum Ingested {
    Mesh(Mesh),
    Terrain(Terrain),
    Sky(FloatImage),
    Scene(Scene),
}

/// Options for reading inputs.
#[derive(Debug, Clone, Default)]
pub struct IngestOptions {
    /// RAW size (width, height) when a RAW file is ingested on its own.
    pub size: Option<(u32, u32)>,
    /// RAW metres per step when a RAW file is ingested on its own.
    pub scale: Option<f32>,
    /// Extra folders searched for ECO model names (after the ECO file's own folder).
    pub model_dirs: Vec<PathBuf>,
    /// Colour map for a RAW terrain (default: same stem with an image extension).
    pub color_map: Option<PathBuf>,
    /// Further folders a scene may read from (`--allow-path`; see [`confine`]).
    pub allow_paths: Vec<PathBuf>,
    /// Limits on declared sizes (`--max-memory`; see [`limits`]).
    pub limits: limits::Limits,
}

/// What reading one input may touch: the folders it may read from and the size limits.
#[derive(Debug, Clone, Default)]
pub struct ReadPolicy {
    pub roots: confine::Roots,
    pub limits: limits::Limits,
}

impl ReadPolicy {
    /// The folder of `file`, plus `extra` folders, with the default limits.
    pub fn around(file: &Path, extra: &[PathBuf]) -> ReadPolicy {
        ReadPolicy {
            roots: confine::Roots::around(file, extra),
            limits: limits::Limits::DEFAULT,
        }
    }
}

/// The kinds of input, by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputKind {
    Txf,
    Max3ds,
    Obj,
    Gltf,
    Raw,
    Hdr,
    Exr,
    Eco,
}

impl InputKind {
    /// The kind of a path by its extension (case-insensitive).
    pub fn of(path: &Path) -> Option<InputKind> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "txf" => InputKind::Txf,
            "3ds" => InputKind::Max3ds,
            "obj" => InputKind::Obj,
            "gltf" | "glb" => InputKind::Gltf,
            "raw" | "r8" | "r16" => InputKind::Raw,
            "hdr" | "pic" => InputKind::Hdr,
            "exr" => InputKind::Exr,
            "eco" => InputKind::Eco,
            _ => return None,
        })
    }
}

fn unknown_kind(path: &Path) -> Error {
    Error::invalid_at(
        path,
        "file name",
        "unknown input type; expected one of .txf .3ds .obj .gltf .glb .raw .hdr .exr .eco",
    )
}

/// A known input that is not a model where a model is read (`bake svo scene.eco`).
fn not_a_model(path: &Path, kind: InputKind) -> Error {
    let (what, hint) = match kind {
        InputKind::Eco => (
            "a scene",
            "; bake it into a pack first (`bake SCENE.eco -o S.bake`) and pass S.bake",
        ),
        InputKind::Raw => ("a height map", ""),
        _ => ("an image", ""),
    };
    Error::invalid_at(
        path,
        "file name",
        format!(
            "{what}, not a model: expected one of .txf .3ds .obj .gltf .glb (or a .bake pack where the command takes one){hint}"
        ),
    )
}

/// Reads a model file (TXF, 3DS, OBJ, glTF/GLB) into one mesh in model space; the files it
/// refers to must lie in its own folder.
pub fn load_mesh(path: &Path) -> Result<Mesh> {
    load_mesh_in(path, &ReadPolicy::around(path, &[]))
}

/// Reads a model file under a policy: MTL files, glTF buffers and textures must lie inside the
/// roots, and the mesh and its textures within the limits.
pub fn load_mesh_in(path: &Path, policy: &ReadPolicy) -> Result<Mesh> {
    let mesh = match InputKind::of(path) {
        Some(InputKind::Txf) => txf::load(path)?,
        Some(InputKind::Max3ds) => max3ds::load(path)?,
        Some(InputKind::Obj) => obj::load_in(path, &policy.roots)?,
        Some(InputKind::Gltf) => gltf::load_in(path, &policy.roots)?,
        Some(kind) => return Err(not_a_model(path, kind)),
        None => return Err(unknown_kind(path)),
    };
    debug_assert_eq!(mesh.validate(), Ok(()));
    check_mesh_size(path, &mesh, &policy.limits)?;
    check_textures(path, &mesh, policy)?;
    Ok(mesh)
}

/// The mesh's vertex and triangle counts and decoded size against the limits. (Readers check
/// declared counts against the bytes that hold them before allocating, so what they allocate
/// is bounded by the file size; this bounds what later stages multiply.)
fn check_mesh_size(path: &Path, mesh: &Mesh, l: &limits::Limits) -> Result<()> {
    let (v, t) = (mesh.positions.len() as u64, mesh.indices.len() as u64);
    limits::check_count("mesh", "vertices", v, l.max_vertices)
        .and_then(|_| limits::check_count("mesh", "triangles", t, l.max_triangles))
        .map_err(|e| Error::invalid(path, e))?;
    l.check_memory(path, "mesh", "the mesh", v * 32 + t * 16)
}

/// Every texture of a mesh lies inside the roots, and its header's size is within the limits.
fn check_textures(model: &Path, mesh: &Mesh, policy: &ReadPolicy) -> Result<()> {
    for t in &mesh.textures {
        let (inside, resolved) = policy.roots.resolve(&t.path);
        if !inside {
            let (referrer, place) = reference_place(model, &t.name);
            return Err(policy
                .roots
                .refusal(&referrer, place, "texture", &t.name, &resolved));
        }
        check_image_header(&t.path, "texture", &policy.limits)?;
    }
    Ok(())
}

/// The file (the model, or one of an OBJ's MTL libraries) and place where a texture is named.
fn reference_place(model: &Path, name: &str) -> (PathBuf, String) {
    let bytes = std::fs::read(model).unwrap_or_default();
    let binary =
        matches!(InputKind::of(model), Some(InputKind::Max3ds)) || bytes.starts_with(b"glTF");
    if let Some(p) = confine::place_of(&bytes, name, binary) {
        return (model.to_path_buf(), p);
    }
    let dir = model.parent().unwrap_or(Path::new(""));
    for mtl in obj::mtl_names(&bytes) {
        let path = dir.join(mtl);
        let text = std::fs::read(&path).unwrap_or_default();
        if let Some(p) = confine::place_of(&text, name, false) {
            return (path, p);
        }
    }
    (model.to_path_buf(), "reference".into())
}

/// An image file's declared size against the limits, from its header (read in part); files
/// that are missing or unreadable are left to the decoder, which reports them.
pub fn check_image_header(path: &Path, what: &str, l: &limits::Limits) -> Result<()> {
    use std::io::Read;
    let mut head = Vec::new();
    let Ok(f) = std::fs::File::open(path) else {
        return Ok(());
    };
    let _ = f.take(256 << 10).read_to_end(&mut head);
    let Some((w, h)) = limits::image_dimensions(&head) else {
        return Ok(());
    };
    let what = format!("{what} {w}×{h}");
    limits::check_count("header", "pixels", w * h, l.max_image_pixels)
        .map_err(|e| Error::invalid(path, e))?;
    l.check_memory(path, "header", &what, w * h * 4)
}

/// Reads any single input file.
pub fn ingest_file(path: &Path, opts: &IngestOptions) -> Result<Ingested> {
    match InputKind::of(path) {
        Some(InputKind::Txf | InputKind::Max3ds | InputKind::Obj | InputKind::Gltf) => {
            let extra: Vec<PathBuf> = opts
                .model_dirs
                .iter()
                .chain(&opts.allow_paths)
                .cloned()
                .collect();
            let policy = ReadPolicy {
                roots: confine::Roots::around(path, &extra),
                limits: opts.limits,
            };
            Ok(Ingested::Mesh(load_mesh_in(path, &policy)?))
        }
        Some(InputKind::Raw) => {
            let (w, h) = opts.size.ok_or_else(|| {
                Error::usage(format!(
                    "{}: a RAW height map needs --size WxH (it has no header)",
                    path.display()
                ))
            })?;
            let scale = opts.scale.unwrap_or(1.0);
            let decoded = w as u64 * h as u64 * 4;
            opts.limits
                .check_memory(path, "--size", "the terrain", decoded)?;
            let spec = raw::RawSpec {
                width: w,
                height: h,
                scale,
                origin: [0.0, 0.0],
                extent: [(w - 1).max(1) as f32, (h - 1).max(1) as f32],
            };
            Ok(Ingested::Terrain(raw::load(
                path,
                &spec,
                opts.color_map.as_deref(),
            )?))
        }
        Some(InputKind::Hdr | InputKind::Exr) => {
            check_image_header(path, "sky", &opts.limits)?;
            Ok(Ingested::Sky(skyimage::load(path)?))
        }
        Some(InputKind::Eco) => Ok(Ingested::Scene(eco::load_scene(
            &[path.to_path_buf()],
            opts,
        )?)),
        None => Err(unknown_kind(path)),
    }
}

/// The files a model file makes its reader open besides itself and its texture images (which
/// are in `Mesh::textures`): the MTL files of an OBJ, the external buffers of a glTF. Only files
/// that exist are listed (a missing one is the reader's error or warning). For dependency lists.
pub fn mesh_side_files(path: &Path) -> Vec<PathBuf> {
    let dir = path.parent().unwrap_or(Path::new(""));
    let Ok(bytes) = std::fs::read(path) else {
        return Vec::new();
    };
    let names: Vec<String> = match InputKind::of(path) {
        Some(InputKind::Obj) => String::from_utf8_lossy(&bytes)
            .lines()
            .filter_map(|l| l.trim_start().strip_prefix("mtllib"))
            .flat_map(|rest| rest.split_whitespace().map(str::to_string))
            .collect(),
        Some(InputKind::Gltf) => ::gltf::Gltf::from_slice_without_validation(&bytes)
            .map(|g| {
                g.document
                    .buffers()
                    .filter_map(|b| match b.source() {
                        ::gltf::buffer::Source::Uri(u) if !u.starts_with("data:") => {
                            Some(gltf::percent_decode(u))
                        }
                        _ => None,
                    })
                    .collect()
            })
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    let mut out: Vec<PathBuf> = names
        .iter()
        .map(|n| dir.join(n))
        .filter(|p| p.is_file())
        .collect();
    out.dedup();
    out
}
