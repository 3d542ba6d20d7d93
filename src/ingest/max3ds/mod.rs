//! Autodesk 3D Studio (`.3ds`) reader: our own chunk reader, several objects merged into one
//! mesh in model space, materials and texture file names.
//! Phases, one file each: `chunks.rs` (the chunk reader and parser), `keyframer.rs` (the
//! node hierarchy and object placement), `mesh.rs` (one mesh from the placed objects).
//!
//! # Chunks read
//! A 3DS file is a little-endian tree of chunks `{u16 id, u32 length (including the 6-byte
//! header)}`. Read: main 0x4D4D → editor 0x3D3D (master scale 0x0100, materials 0xAFFF, objects
//! 0x4000 → triangle mesh 0x4100 → vertices 0x4110, faces 0x4120 (→ face materials 0x4130,
//! smoothing groups 0x4150), UVs 0x4140, mesh matrix 0x4160) and the keyframer 0xB000 (node
//! chunks 0xB002..0xB007 → name/hierarchy 0xB010, dummy name 0xB011, pivot 0xB013, position,
//! rotation, scale and roll tracks 0xB020/0xB021/0xB022/0xB024). Materials: name 0xA000,
//! ambient/diffuse/specular 0xA010/0xA020/0xA030 (colour sub-chunks 0x0010 RGB f32, 0x0011 RGB
//! u8, 0x0012 linear RGB u8, 0x0013 linear RGB f32: the first one present wins, as in assimp),
//! shininess 0xA040 and shininess strength 0xA041, transparency 0xA050 (percent sub-chunks 0x0030
//! u16 / 0x0031 f32), texture map 0xA200 → file name 0xA300. Unknown chunks are skipped by length.
//!
//! # Coordinates: the mesh matrix, the way assimp does it
//! 3DS stores vertices already transformed into the scene; 0x4160 holds the matrix that did it.
//! We follow assimp 5.x (`3DSLoader.cpp`, `3DSConverter.cpp`) so that our positions agree with
//! `assimp info` (its Y-up output is our Z-up: assimp (X, Y, Z) = our (x, z, −y)):
//! - without keyframer nodes, vertices are used as stored and the matrix is ignored;
//! - with keyframer nodes, each object is matched by name to the first node (depth-first) of the
//!   hierarchy assimp builds from 0xB010 (its "hierarchy + 1" heuristic, reproduced here), its
//!   vertices are taken back to local space by the inverse mesh matrix, mirrored in x when the
//!   matrix has a negative determinant, moved by −pivot, and then placed by the product of the
//!   node transforms from the first key of each track (rotation by −angle, the 3DS sign; camera
//!   roll about z; scale; position). Objects no node refers to keep their stored positions.
//! - positions are finally divided by the master scale (0x0100) when it is non-zero.
//!
//! Normals are computed from the final positions with the smoothing groups (0x4150): a corner's
//! normal averages the area-weighted normals of the faces that touch the same position and share a
//! smoothing bit; faces without a group are flat. Texture v is flipped (3DS has v = 0 at the
//! bottom of the image, the model has it at the top).
//!
//! # Broken files
//! Never a panic, never an allocation sized by an unchecked count (every count is checked against
//! the bytes left in its chunk first). A chunk whose length runs past the end of the file is an
//! error (truncated file); one that runs past its parent but not the file is clamped to the
//! parent, with a warning; a length below 6 skips just the header, with a warning (assimp does the
//! same). Faces with a vertex index out of range are dropped with a counted warning (assimp clamps
//! the index to the last vertex instead, which keeps a degenerate face); missing UVs become
//! (0, 0) with a warning when the object uses a textured material. A material name in 0x4130 that
//! no material has gives the default material, with a warning. A file without any triangle is an
//! error, as in assimp.

use crate::error::{Error, ParseError, Result};
use crate::model::{Material, Mesh, TextureRef};
use glam::{Mat3, Mat4, Vec3};
use std::path::{Path, PathBuf};

mod chunks;
mod keyframer;
mod mesh;
#[cfg(test)]
mod tests;

use chunks::*;
use keyframer::*;
use mesh::*;

/// At most this many warnings are kept verbatim; the rest are counted.
const MAX_WARNINGS: usize = 32;

/// Reads a `.3ds` file: parses it and resolves texture names against the file's folder (with a
/// case-insensitive fallback, since 3DS names are usually 8.3 upper case).
pub fn load(path: &Path) -> Result<Mesh> {
    let bytes = crate::error::read_file(path)?;
    let mut mesh = parse(&bytes).map_err(|e| Error::invalid(path, e))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    for t in &mut mesh.textures {
        t.path = resolve_texture(dir, &t.name);
    }
    Ok(mesh)
}

/// Resolves a texture name relative to `dir`: exact name first, then a case-insensitive match
/// of the file name in its folder. Backslashes (DOS paths) count as separators.
pub fn resolve_texture(dir: &Path, name: &str) -> PathBuf {
    let rel = name.replace('\\', "/");
    let exact = dir.join(&rel);
    if exact.is_file() {
        return exact;
    }
    // A bare name's parent is "", which `read_dir` refuses: that is the current folder.
    let folder = match exact.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Some(file) = exact.file_name().and_then(|f| f.to_str()) else {
        return exact;
    };
    let found = std::fs::read_dir(&folder).ok().and_then(|entries| {
        entries
            .filter_map(|e| e.ok())
            .map(|e| e.file_name())
            .filter(|f| f.to_str().is_some_and(|f| f.eq_ignore_ascii_case(file)))
            .min()
    });
    match found {
        Some(f) => exact.with_file_name(f),
        None => exact,
    }
}

/// Parses a whole 3DS file into one mesh (texture paths are the names as written).
pub fn parse(bytes: &[u8]) -> Result<Mesh, ParseError> {
    if bytes.len() < 6 {
        return Err(ParseError::at_byte(
            0,
            format!(
                "file has {} bytes, too short for a 3DS chunk header (6 bytes)",
                bytes.len()
            ),
        ));
    }
    let id = u16::from_le_bytes([bytes[0], bytes[1]]);
    if id != MAIN {
        return Err(ParseError::at_byte(
            0,
            format!("not a 3DS file: expected main chunk 0x4D4D, found 0x{id:04X}"),
        ));
    }
    let mut p = Parser {
        data: bytes,
        file: File3ds::default(),
        warn: Warnings::default(),
    };
    let mut pos = 0;
    while let Some(c) = p.next_chunk(&mut pos, bytes.len())? {
        if c.id == MAIN {
            p.main(&c)?;
        }
    }
    let Parser { file, mut warn, .. } = p;
    let mesh = build_mesh(file, &mut warn)?;
    Ok(Mesh {
        warnings: warn.finish(),
        ..mesh
    })
}
