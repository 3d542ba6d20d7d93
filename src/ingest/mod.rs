//! Ingest: every input format into the in-memory model ([`crate::model`]).
//!
//! Each reader takes bytes (`parse`) so fuzzers and tests drive it directly, and has a `load`
//! that reads the file, attaches the path to errors and resolves referenced files.

pub mod eco;
pub mod gltf;
pub mod max3ds;
pub mod obj;
pub mod raw;
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

/// Reads a model file (TXF, 3DS, OBJ, glTF/GLB) into one mesh in model space.
pub fn load_mesh(path: &Path) -> Result<Mesh> {
    let mesh = match InputKind::of(path) {
        Some(InputKind::Txf) => txf::load(path)?,
        Some(InputKind::Max3ds) => max3ds::load(path)?,
        Some(InputKind::Obj) => obj::load(path)?,
        Some(InputKind::Gltf) => gltf::load(path)?,
        _ => return Err(unknown_kind(path)),
    };
    debug_assert_eq!(mesh.validate(), Ok(()));
    Ok(mesh)
}

/// Reads any single input file.
pub fn ingest_file(path: &Path, opts: &IngestOptions) -> Result<Ingested> {
    match InputKind::of(path) {
        Some(InputKind::Txf | InputKind::Max3ds | InputKind::Obj | InputKind::Gltf) => {
            Ok(Ingested::Mesh(load_mesh(path)?))
        }
        Some(InputKind::Raw) => {
            let (w, h) = opts.size.ok_or_else(|| {
                Error::usage(format!(
                    "{}: a RAW height map needs --size WxH (it has no header)",
                    path.display()
                ))
            })?;
            let scale = opts.scale.unwrap_or(1.0);
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
        Some(InputKind::Hdr | InputKind::Exr) => Ok(Ingested::Sky(skyimage::load(path)?)),
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
