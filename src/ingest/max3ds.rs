//! Autodesk 3D Studio (`.3ds`) reader: our own chunk reader, several objects merged into one
//! mesh in model space, materials and texture file names.
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
use std::collections::HashMap;
use std::path::{Path, PathBuf};

const MAIN: u16 = 0x4D4D;
const EDITOR: u16 = 0x3D3D;
const MASTER_SCALE: u16 = 0x0100;
const OBJECT: u16 = 0x4000;
const TRIMESH: u16 = 0x4100;
const VERTICES: u16 = 0x4110;
const FACES: u16 = 0x4120;
const FACE_MATERIALS: u16 = 0x4130;
const UVS: u16 = 0x4140;
const SMOOTHING: u16 = 0x4150;
const MESH_MATRIX: u16 = 0x4160;
const MATERIAL: u16 = 0xAFFF;
const MAT_NAME: u16 = 0xA000;
const MAT_AMBIENT: u16 = 0xA010;
const MAT_DIFFUSE: u16 = 0xA020;
const MAT_SPECULAR: u16 = 0xA030;
const MAT_SHININESS: u16 = 0xA040;
const MAT_SHIN_STRENGTH: u16 = 0xA041;
const MAT_TRANSPARENCY: u16 = 0xA050;
const MAT_TEXTURE: u16 = 0xA200;
const MAP_FILE: u16 = 0xA300;
const RGB_F32: u16 = 0x0010;
const RGB_U8: u16 = 0x0011;
const LIN_RGB_U8: u16 = 0x0012;
const LIN_RGB_F32: u16 = 0x0013;
const PERCENT_U16: u16 = 0x0030;
const PERCENT_F32: u16 = 0x0031;
const KEYFRAMER: u16 = 0xB000;
const KF_OBJECT: u16 = 0xB002;
const KF_CAMERA: u16 = 0xB003;
const KF_CAM_TARGET: u16 = 0xB004;
const KF_LIGHT_TARGET: u16 = 0xB006;
const KF_SPOT: u16 = 0xB007;
const KF_NAME: u16 = 0xB010;
const KF_DUMMY_NAME: u16 = 0xB011;
const KF_PIVOT: u16 = 0xB013;
const KF_POS: u16 = 0xB020;
const KF_ROT: u16 = 0xB021;
const KF_SCALE: u16 = 0xB022;
const KF_ROLL: u16 = 0xB024;

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
    let folder = exact.parent().map(Path::to_path_buf).unwrap_or_default();
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
        Some(f) => folder.join(f),
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

/// Warnings, capped so a file of a million zero-length chunks does not make a million strings.
#[derive(Default)]
struct Warnings {
    list: Vec<String>,
    dropped: usize,
}

impl Warnings {
    fn push(&mut self, w: String) {
        if self.list.len() < MAX_WARNINGS {
            self.list.push(w);
        } else {
            self.dropped += 1;
        }
    }
    fn finish(mut self) -> Vec<String> {
        if self.dropped > 0 {
            self.list
                .push(format!("... and {} more warnings", self.dropped));
        }
        self.list
    }
}

/// One chunk: id, header offset, body range.
#[derive(Debug, Clone, Copy)]
struct Chunk {
    id: u16,
    at: usize,
    body: usize,
    end: usize,
}

impl Chunk {
    fn place(&self) -> String {
        format!("byte {} (chunk 0x{:04X})", self.at, self.id)
    }
    fn err(&self, message: impl Into<String>) -> ParseError {
        ParseError::new(self.place(), message)
    }
}

/// A bounds-checked reader over one chunk's body.
struct Cur<'a> {
    data: &'a [u8],
    pos: usize,
    chunk: Chunk,
}

impl<'a> Cur<'a> {
    fn new(data: &'a [u8], chunk: Chunk) -> Self {
        Cur {
            data,
            pos: chunk.body,
            chunk,
        }
    }
    fn left(&self) -> usize {
        self.chunk.end.saturating_sub(self.pos)
    }
    /// Checks that `n` more bytes are in the chunk before anything is read or allocated.
    fn need(&self, n: usize, what: &str) -> Result<(), ParseError> {
        if n > self.left() {
            return Err(self.chunk.err(format!(
                "{what} needs {n} bytes at byte {}, but the chunk has only {} left",
                self.pos,
                self.left()
            )));
        }
        Ok(())
    }
    fn bytes<const N: usize>(&mut self, what: &str) -> Result<[u8; N], ParseError> {
        self.need(N, what)?;
        let mut b = [0; N];
        b.copy_from_slice(&self.data[self.pos..self.pos + N]);
        self.pos += N;
        Ok(b)
    }
    fn u16(&mut self, what: &str) -> Result<u16, ParseError> {
        self.bytes::<2>(what).map(u16::from_le_bytes)
    }
    fn u32(&mut self, what: &str) -> Result<u32, ParseError> {
        self.bytes::<4>(what).map(u32::from_le_bytes)
    }
    fn f32(&mut self, what: &str) -> Result<f32, ParseError> {
        self.bytes::<4>(what).map(f32::from_le_bytes)
    }
    fn vec3(&mut self, what: &str) -> Result<Vec3, ParseError> {
        Ok(Vec3::new(self.f32(what)?, self.f32(what)?, self.f32(what)?))
    }
    fn skip(&mut self, n: usize, what: &str) -> Result<(), ParseError> {
        self.need(n, what)?;
        self.pos += n;
        Ok(())
    }
    /// A NUL-terminated string; one that runs to the chunk's end without a NUL is accepted.
    fn cstr(&mut self) -> String {
        let end = self.chunk.end.min(self.data.len());
        let body = &self.data[self.pos.min(end)..end];
        let n = body.iter().position(|&b| b == 0).unwrap_or(body.len());
        let s = String::from_utf8_lossy(&body[..n]).into_owned();
        self.pos = (self.pos + n + 1).min(end);
        s
    }
}

/// A raw 3DS material: the model material plus its texture file name.
struct RawMaterial {
    material: Material,
    texture: Option<String>,
}

/// One triangle-mesh object as stored.
#[derive(Default)]
struct Object {
    name: String,
    positions: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    faces: Vec<[u16; 3]>,
    smoothing: Vec<u32>,
    /// Per face: index into the file's materials, or `None` for the default material.
    face_materials: Vec<Option<u32>>,
    matrix: Option<Mat4>,
}

/// A keyframer node, as assimp's hierarchy builder makes it.
#[derive(Debug, Default, Clone)]
struct Node {
    name: String,
    parent: Option<usize>,
    children: Vec<usize>,
    hierarchy_pos: i32,
    pivot: Vec3,
    /// First key of each track: (frame, value).
    pos: Option<(u32, Vec3)>,
    rot: Option<(u32, f32, Vec3)>,
    scale: Option<(u32, Vec3)>,
    roll: Option<(u32, f32)>,
}

/// Everything read from the file.
struct File3ds {
    master_scale: f32,
    materials: Vec<RawMaterial>,
    objects: Vec<Object>,
    /// Node 0 is the root.
    nodes: Vec<Node>,
    current: usize,
    last_index: i32,
}

impl Default for File3ds {
    fn default() -> Self {
        File3ds {
            master_scale: 1.0,
            materials: Vec::new(),
            objects: Vec::new(),
            nodes: vec![Node {
                name: "UNNAMED".into(),
                hierarchy_pos: -1,
                ..Node::default()
            }],
            current: 0,
            last_index: -1,
        }
    }
}

struct Parser<'a> {
    data: &'a [u8],
    file: File3ds,
    warn: Warnings,
}

impl<'a> Parser<'a> {
    /// The next chunk in `pos..end`, or `None` when fewer than 6 bytes are left.
    fn next_chunk(&mut self, pos: &mut usize, end: usize) -> Result<Option<Chunk>, ParseError> {
        loop {
            if end.saturating_sub(*pos) < 6 {
                return Ok(None);
            }
            let at = *pos;
            let d = self.data;
            let id = u16::from_le_bytes([d[at], d[at + 1]]);
            let len = u32::from_le_bytes([d[at + 2], d[at + 3], d[at + 4], d[at + 5]]) as usize;
            if len < 6 {
                self.warn.push(format!(
                    "byte {at} (chunk 0x{id:04X}): length {len} is below the 6-byte header; skipped"
                ));
                *pos = at + 6;
                continue;
            }
            if len > d.len() - at {
                return Err(ParseError::new(
                    format!("byte {at} (chunk 0x{id:04X})"),
                    format!(
                        "chunk length {len} runs past the end of the file ({} bytes left): truncated file?",
                        d.len() - at
                    ),
                ));
            }
            let mut cend = at + len;
            if cend > end {
                self.warn.push(format!(
                    "byte {at} (chunk 0x{id:04X}): length {len} runs past its parent's end at byte {end}; clamped"
                ));
                cend = end;
            }
            *pos = cend;
            return Ok(Some(Chunk {
                id,
                at,
                body: at + 6,
                end: cend,
            }));
        }
    }

    /// Calls `f` for every sub-chunk of `c` from byte `from`.
    fn each(
        &mut self,
        from: usize,
        end: usize,
        mut f: impl FnMut(&mut Self, Chunk) -> Result<(), ParseError>,
    ) -> Result<(), ParseError> {
        let mut pos = from;
        while let Some(sub) = self.next_chunk(&mut pos, end)? {
            f(self, sub)?;
        }
        Ok(())
    }

    fn main(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| match sub.id {
            EDITOR => p.editor(&sub),
            KEYFRAMER => p.keyframer(&sub),
            _ => Ok(()),
        })
    }

    fn editor(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| match sub.id {
            MASTER_SCALE => {
                p.file.master_scale = Cur::new(p.data, sub).f32("master scale")?;
                Ok(())
            }
            MATERIAL => p.material(&sub),
            OBJECT => p.object(&sub),
            _ => Ok(()),
        })
    }

    fn object(&mut self, c: &Chunk) -> Result<(), ParseError> {
        let mut cur = Cur::new(self.data, *c);
        let name = cur.cstr();
        self.each(cur.pos, c.end, |p, sub| {
            if sub.id == TRIMESH {
                p.file.objects.push(Object {
                    name: name.clone(),
                    ..Object::default()
                });
                p.trimesh(&sub)?;
            }
            Ok(())
        })
    }

    fn object_mut(&mut self) -> &mut Object {
        self.file
            .objects
            .last_mut()
            .expect("trimesh pushes an object first")
    }

    fn trimesh(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| {
            let mut cur = Cur::new(p.data, sub);
            match sub.id {
                VERTICES => {
                    let n = cur.u16("vertex count")? as usize;
                    cur.need(n * 12, &format!("{n} vertices"))?;
                    let o = p.object_mut();
                    o.positions.reserve(n);
                    for _ in 0..n {
                        o.positions.push(cur.vec3("vertex")?.to_array());
                    }
                }
                UVS => {
                    let n = cur.u16("UV count")? as usize;
                    cur.need(n * 8, &format!("{n} texture coordinates"))?;
                    let o = p.object_mut();
                    o.uvs.reserve(n);
                    for _ in 0..n {
                        o.uvs.push([cur.f32("u")?, cur.f32("v")?]);
                    }
                }
                MESH_MATRIX => {
                    let mut m = [0.0f32; 12];
                    for v in &mut m {
                        *v = cur.f32("mesh matrix")?;
                    }
                    p.object_mut().matrix = Some(mesh_matrix(&m));
                }
                FACES => p.faces(&sub, &mut cur)?,
                _ => {}
            }
            Ok(())
        })
    }

    fn faces(&mut self, c: &Chunk, cur: &mut Cur) -> Result<(), ParseError> {
        let n = cur.u16("face count")? as usize;
        cur.need(n * 8, &format!("{n} faces"))?;
        let o = self.object_mut();
        o.faces.reserve(n);
        for _ in 0..n {
            let a = cur.u16("face")?;
            let b = cur.u16("face")?;
            let d = cur.u16("face")?;
            cur.u16("face flags")?;
            o.faces.push([a, b, d]);
        }
        let total = o.faces.len();
        o.face_materials.resize(total, None);
        o.smoothing.resize(total, 0);
        self.each(cur.pos, c.end, |p, sub| {
            let mut cur = Cur::new(p.data, sub);
            match sub.id {
                FACE_MATERIALS => p.face_materials(&sub, &mut cur)?,
                SMOOTHING => {
                    let n = (sub.end - sub.body) / 4;
                    let o = p.object_mut();
                    if n > o.smoothing.len() {
                        return Err(sub.err(format!(
                            "{n} smoothing groups for {} faces",
                            o.smoothing.len()
                        )));
                    }
                    for k in 0..n {
                        let g = cur.u32("smoothing group")?;
                        p.object_mut().smoothing[k] = g;
                    }
                }
                _ => {}
            }
            Ok(())
        })
    }

    fn face_materials(&mut self, c: &Chunk, cur: &mut Cur) -> Result<(), ParseError> {
        let name = cur.cstr();
        let index = self
            .file
            .materials
            .iter()
            .position(|m| {
                !m.material.name.is_empty() && m.material.name.eq_ignore_ascii_case(&name)
            })
            .map(|i| i as u32);
        if index.is_none() {
            self.warn.push(format!(
                "{}: unknown material {name:?}; its faces get the default material",
                c.place()
            ));
        }
        let n = cur.u16("face material count")? as usize;
        cur.need(n * 2, &format!("{n} face indices"))?;
        let mut bad = 0;
        for _ in 0..n {
            let f = cur.u16("face index")? as usize;
            let o = self.object_mut();
            match o.face_materials.get_mut(f) {
                Some(m) => *m = index,
                None => bad += 1,
            }
        }
        if bad > 0 {
            self.warn.push(format!(
                "{}: {bad} face indices of material {name:?} are out of range; ignored",
                c.place()
            ));
        }
        Ok(())
    }

    fn material(&mut self, c: &Chunk) -> Result<(), ParseError> {
        let mut raw = RawMaterial {
            material: Material {
                name: format!("UNNAMED_{}", self.file.materials.len()),
                ..Material::default()
            },
            texture: None,
        };
        let mut strength = None;
        self.each(c.body, c.end, |p, sub| {
            let m = &mut raw.material;
            match sub.id {
                MAT_NAME => {
                    let name = Cur::new(p.data, sub).cstr();
                    if !name.is_empty() {
                        m.name = name;
                    }
                }
                MAT_AMBIENT => m.ambient = p.color(&sub)?.unwrap_or(m.ambient),
                MAT_DIFFUSE => m.diffuse = p.color(&sub)?.unwrap_or(m.diffuse),
                MAT_SPECULAR => m.specular = p.color(&sub)?.unwrap_or(m.specular),
                MAT_SHININESS => {
                    if let Some(pc) = p.percent(&sub)? {
                        m.shininess = (pc / 100.0).clamp(0.0, 1.0) * 128.0;
                    }
                }
                MAT_SHIN_STRENGTH => strength = p.percent(&sub)?,
                MAT_TRANSPARENCY => {
                    if let Some(pc) = p.percent(&sub)? {
                        m.transparency = (pc / 100.0).clamp(0.0, 1.0);
                    }
                }
                MAT_TEXTURE => {
                    p.each(sub.body, sub.end, |p, map| {
                        if map.id == MAP_FILE {
                            let name = Cur::new(p.data, map).cstr();
                            if !name.is_empty() {
                                raw.texture = Some(name);
                            }
                        }
                        Ok(())
                    })?;
                }
                _ => {}
            }
            Ok(())
        })?;
        // Shininess strength scales the specular colour (OpenGL has no separate factor).
        if let Some(s) = strength {
            let s = (s / 100.0).clamp(0.0, 1.0);
            for k in 0..3 {
                raw.material.specular[k] *= s;
            }
        }
        self.file.materials.push(raw);
        Ok(())
    }

    /// The first colour sub-chunk of `c` (RGB as f32 or u8, gamma or linear), as RGBA.
    fn color(&mut self, c: &Chunk) -> Result<Option<[f32; 4]>, ParseError> {
        let mut out = None;
        self.each(c.body, c.end, |p, sub| {
            if out.is_some() {
                return Ok(());
            }
            let mut cur = Cur::new(p.data, sub);
            out = match sub.id {
                RGB_F32 | LIN_RGB_F32 => {
                    let v = cur.vec3("colour")?;
                    Some([v.x, v.y, v.z, 1.0])
                }
                RGB_U8 | LIN_RGB_U8 => {
                    let b = cur.bytes::<3>("colour")?;
                    Some([
                        b[0] as f32 / 255.0,
                        b[1] as f32 / 255.0,
                        b[2] as f32 / 255.0,
                        1.0,
                    ])
                }
                _ => None,
            };
            Ok(())
        })?;
        Ok(out)
    }

    /// The first percent sub-chunk of `c` (0..100).
    fn percent(&mut self, c: &Chunk) -> Result<Option<f32>, ParseError> {
        let mut out = None;
        self.each(c.body, c.end, |p, sub| {
            if out.is_some() {
                return Ok(());
            }
            let mut cur = Cur::new(p.data, sub);
            out = match sub.id {
                PERCENT_U16 => Some(cur.u16("percent")? as f32),
                PERCENT_F32 => Some(cur.f32("percent")?),
                _ => None,
            };
            Ok(())
        })?;
        Ok(out.filter(|v| v.is_finite()))
    }

    fn keyframer(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| {
            if (KF_OBJECT..=KF_SPOT).contains(&sub.id) {
                let kind = sub.id;
                p.each(sub.body, sub.end, |p, t| p.track_chunk(kind, &t))?;
            }
            Ok(())
        })
    }

    /// One sub-chunk of a keyframer node chunk of type `kind` (0xB002..0xB007).
    fn track_chunk(&mut self, kind: u16, c: &Chunk) -> Result<(), ParseError> {
        let mut cur = Cur::new(self.data, *c);
        let f = &mut self.file;
        match c.id {
            KF_NAME => kf_name(f, kind, &mut cur)?,
            KF_DUMMY_NAME => {
                let name = cur.cstr();
                let n = &mut f.nodes[f.current];
                if n.name == "$$$DUMMY" {
                    n.name = name;
                }
            }
            KF_PIVOT if kind == KF_OBJECT => f.nodes[f.current].pivot = cur.vec3("pivot")?,
            KF_POS if kind != KF_CAM_TARGET && kind != KF_LIGHT_TARGET => {
                let k = first_key(&mut cur, false, |c| c.vec3("position key"))?;
                f.nodes[f.current].pos = k;
            }
            KF_ROT => {
                let k = first_key(&mut cur, false, |c| {
                    Ok((c.f32("rotation angle")?, c.vec3("rotation axis")?))
                })?;
                f.nodes[f.current].rot = k.map(|(t, (a, axis))| (t, a, axis));
            }
            KF_SCALE => {
                let k = first_key(&mut cur, true, |c| c.vec3("scale key"))?;
                f.nodes[f.current].scale = k;
            }
            KF_ROLL if kind == KF_CAMERA => {
                let k = first_key(&mut cur, false, |c| c.f32("roll key"))?;
                f.nodes[f.current].roll = k;
            }
            _ => {}
        }
        Ok(())
    }
}

/// The 0x4160 matrix: four columns of three floats (x axis, y axis, z axis, translation).
fn mesh_matrix(m: &[f32; 12]) -> Mat4 {
    Mat4::from_cols(
        Vec3::new(m[0], m[1], m[2]).extend(0.0),
        Vec3::new(m[3], m[4], m[5]).extend(0.0),
        Vec3::new(m[6], m[7], m[8]).extend(0.0),
        Vec3::new(m[9], m[10], m[11]).extend(1.0),
    )
}

/// 0xB010: a node's name and hierarchy position, placed in the tree the way assimp's
/// `ParseHierarchyChunk` does (its heuristic decides parents, so we reproduce it exactly).
fn kf_name(f: &mut File3ds, kind: u16, cur: &mut Cur) -> Result<(), ParseError> {
    let name = cur.cstr();
    if let Some(found) = find_node(&f.nodes, 0, &name)
        && kind != KF_OBJECT
    {
        f.current = found;
        return Ok(());
    }
    cur.skip(4, "node flags")?;
    // assimp adds 1 in 16 bits: "no parent" (0xFFFF) becomes 0.
    let hierarchy = cur.u16("node hierarchy")?.wrapping_add(1) as i32;
    let node = f.nodes.len();
    f.nodes.push(Node {
        name,
        hierarchy_pos: hierarchy,
        ..Node::default()
    });
    let current = f.current;
    if current != 0 && f.nodes[current].hierarchy_pos == hierarchy {
        let parent = f.nodes[current].parent.unwrap_or(0);
        attach(f, parent, node);
        f.last_index += 1;
    } else if hierarchy >= f.last_index {
        attach(f, current, node);
        f.last_index = hierarchy;
    } else {
        let mut at = Some(current);
        let parent = loop {
            match at {
                None => break 0,
                Some(a) if f.nodes[a].hierarchy_pos == hierarchy => {
                    break f.nodes[a].parent.unwrap_or(a);
                }
                Some(a) => at = f.nodes[a].parent,
            }
        };
        attach(f, parent, node);
        f.last_index += 1;
    }
    f.current = node;
    Ok(())
}

fn attach(f: &mut File3ds, parent: usize, child: usize) {
    f.nodes[child].parent = Some(parent);
    f.nodes[parent].children.push(child);
}

/// Depth-first search by name from `at` (names compare case-sensitively, as in assimp).
fn find_node(nodes: &[Node], at: usize, name: &str) -> Option<usize> {
    let mut stack = vec![at];
    while let Some(n) = stack.pop() {
        if nodes[n].name == name {
            return Some(n);
        }
        stack.extend(nodes[n].children.iter().rev());
    }
    None
}

/// Reads a key track (`u16 flags, 8 bytes, count, keys`) and returns its earliest key (first
/// among equal frames), which is the one assimp uses for the node transform. Nothing is
/// allocated: every key is checked against the chunk as it is read.
fn first_key<T>(
    cur: &mut Cur,
    u16_count: bool,
    mut value: impl FnMut(&mut Cur) -> Result<T, ParseError>,
) -> Result<Option<(u32, T)>, ParseError> {
    cur.skip(10, "track header")?;
    let n = if u16_count {
        let n = cur.u16("key count")? as u32;
        cur.skip(2, "key count")?;
        n
    } else {
        cur.u32("key count")?
    };
    let mut best: Option<(u32, T)> = None;
    for _ in 0..n {
        let frame = cur.u32("key frame")?;
        let flags = cur.u16("key flags")?;
        // Tension, continuity, bias, ease to, ease from: 4 bytes each when flagged.
        cur.skip(4 * (flags & 0x1F).count_ones() as usize, "key spline data")?;
        let v = value(cur)?;
        if best.as_ref().is_none_or(|(t, _)| frame < *t) {
            best = Some((frame, v));
        }
    }
    Ok(best)
}

/// A node's own transform from its first keys (assimp `AddNodeToGraph`).
fn node_transform(n: &Node) -> Mat4 {
    let mut m = if let Some((_, angle, axis)) = n.rot {
        let axis = if axis == Vec3::ZERO { Vec3::Y } else { axis };
        // assimp negates w of the axis-angle quaternion: a rotation by -angle.
        Mat4::from_mat3(Mat3::from_axis_angle(axis.normalize(), -angle))
    } else if let Some((_, roll)) = n.roll {
        Mat4::from_rotation_z(-roll.to_radians())
    } else {
        Mat4::IDENTITY
    };
    if let Some((_, s)) = n.scale {
        let s = Vec3::select(s.cmpeq(Vec3::ZERO), Vec3::ONE, s);
        m.x_axis *= s.x;
        m.y_axis *= s.y;
        m.z_axis *= s.z;
        m.x_axis.w = 0.0;
        m.y_axis.w = 0.0;
        m.z_axis.w = 0.0;
    }
    if let Some((_, p)) = n.pos {
        m.w_axis += p.extend(0.0);
    }
    m
}

/// World transforms of all nodes, and the depth-first order in which assimp visits them.
fn node_worlds(nodes: &[Node]) -> (Vec<Mat4>, Vec<usize>) {
    let mut world = vec![Mat4::IDENTITY; nodes.len()];
    let mut order = Vec::with_capacity(nodes.len());
    let mut stack = vec![(0usize, Mat4::IDENTITY)];
    while let Some((n, parent)) = stack.pop() {
        world[n] = parent * node_transform(&nodes[n]);
        order.push(n);
        for &c in nodes[n].children.iter().rev() {
            stack.push((c, world[n]));
        }
    }
    (world, order)
}

/// The transform taking an object's stored vertices to model space (see the file comment).
fn object_transform(
    f: &File3ds,
    o: &Object,
    placement: Option<(Mat4, Vec3)>,
    warn: &mut Warnings,
) -> Mat4 {
    let scale = if f.master_scale != 0.0 && f.master_scale.is_finite() {
        Mat4::from_scale(Vec3::splat(1.0 / f.master_scale))
    } else {
        Mat4::IDENTITY
    };
    let Some((world, pivot)) = placement else {
        return scale;
    };
    let m = o.matrix.unwrap_or(Mat4::IDENTITY);
    let det = m.determinant();
    let inv = if det != 0.0 && det.is_finite() {
        m.inverse()
    } else {
        warn.push(format!(
            "object {:?}: mesh matrix (0x4160) is singular; vertices used as stored",
            o.name
        ));
        Mat4::IDENTITY
    };
    let flip = if det < 0.0 {
        Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0))
    } else {
        Mat4::IDENTITY
    };
    scale * world * Mat4::from_translation(-pivot) * flip * inv
}

/// Merges the objects into one mesh with the file's materials.
fn build_mesh(f: File3ds, warn: &mut Warnings) -> Result<Mesh, ParseError> {
    let (world, order) = node_worlds(&f.nodes);
    let has_hierarchy = !f.nodes[0].children.is_empty();
    let mut materials: Vec<Material> = Vec::with_capacity(f.materials.len() + 1);
    let mut textures: Vec<TextureRef> = Vec::new();
    for raw in &f.materials {
        let mut m = raw.material.clone();
        if let Some(name) = &raw.texture {
            let i = match textures.iter().position(|t| &t.name == name) {
                Some(i) => i,
                None => {
                    textures.push(TextureRef {
                        name: name.clone(),
                        path: PathBuf::from(name),
                    });
                    textures.len() - 1
                }
            };
            m.color_map = Some(i as u32);
        }
        materials.push(m);
    }
    let default_material = materials.len() as u32;
    let mut used_default = false;
    let mut mesh = Mesh::default();
    for o in &f.objects {
        let placement = if has_hierarchy {
            let node = order
                .iter()
                .copied()
                .find(|&n| n != 0 && f.nodes[n].name == o.name);
            if node.is_none() && !o.faces.is_empty() {
                warn.push(format!(
                    "object {:?} is not in the keyframer hierarchy; kept as stored",
                    o.name
                ));
            }
            node.map(|n| (world[n], f.nodes[n].pivot))
        } else {
            None
        };
        let t = object_transform(&f, o, placement, warn);
        let part = object_mesh(o, t, &materials, default_material, warn);
        used_default |= part.triangle_materials.contains(&default_material);
        if !part.indices.is_empty() {
            mesh.objects.push(o.name.clone());
            mesh.append(part);
        }
    }
    if mesh.indices.is_empty() {
        return Err(ParseError::new(
            "file",
            format!(
                "no triangles: {} objects, none with faces that refer to existing vertices",
                f.objects.len()
            ),
        ));
    }
    if used_default {
        materials.push(Material {
            name: "default".into(),
            ..Material::default()
        });
    }
    mesh.materials = materials;
    mesh.textures = textures;
    Ok(mesh)
}

/// One object's triangles: transformed, with smoothing-group normals and flipped v.
fn object_mesh(
    o: &Object,
    t: Mat4,
    materials: &[Material],
    default_material: u32,
    warn: &mut Warnings,
) -> Mesh {
    let nv = o.positions.len();
    let positions: Vec<Vec3> = o
        .positions
        .iter()
        .map(|p| t.transform_point3(Vec3::from_array(*p)))
        .collect();
    let mut faces = Vec::with_capacity(o.faces.len());
    let mut dropped = 0;
    for (i, face) in o.faces.iter().enumerate() {
        if face.iter().any(|&v| v as usize >= nv) {
            dropped += 1;
            continue;
        }
        let m = o
            .face_materials
            .get(i)
            .copied()
            .flatten()
            .unwrap_or(default_material);
        faces.push((i, *face, m));
    }
    if dropped > 0 {
        warn.push(format!(
            "object {:?}: {dropped} of {} faces refer to vertices past {nv}; dropped",
            o.name,
            o.faces.len()
        ));
    }
    let textured = faces.iter().any(|f| {
        materials
            .get(f.2 as usize)
            .is_some_and(|m| m.color_map.is_some())
    });
    if textured && o.uvs.len() < nv {
        warn.push(format!(
            "object {:?}: {} texture coordinates (0x4140) for {nv} vertices; missing ones are (0, 0)",
            o.name,
            o.uvs.len()
        ));
    }
    // A mirroring transform reverses the winding: flip the cross product back.
    let sign = t.determinant().signum();
    let face_normals: Vec<Vec3> = faces
        .iter()
        .map(|(_, f, _)| {
            let [a, b, c] = f.map(|v| positions[v as usize]);
            (b - a).cross(c - a) * sign
        })
        .collect();
    let normals = smooth_normals(&positions, &faces, &face_normals, &o.smoothing);
    let mut mesh = Mesh::default();
    let mut remap: HashMap<(u16, [u32; 3]), u32> = HashMap::new();
    for (k, (_, f, m)) in faces.iter().enumerate() {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let v = f[c];
            let n = normals[3 * k + c];
            let key = (v, n.to_array().map(f32::to_bits));
            tri[c] = *remap.entry(key).or_insert_with(|| {
                let uv = o.uvs.get(v as usize).copied().unwrap_or([0.0, 1.0]);
                mesh.positions.push(positions[v as usize].to_array());
                mesh.normals.push(n.to_array());
                mesh.uvs.push([uv[0], 1.0 - uv[1]]);
                (mesh.positions.len() - 1) as u32
            });
        }
        mesh.indices.push(tri);
        mesh.triangle_materials.push(*m);
    }
    mesh
}

/// Per face corner: the normalized sum of the normals of the faces at the same position that
/// share a smoothing group bit with the corner's face (the face itself always counts).
fn smooth_normals(
    positions: &[Vec3],
    faces: &[(usize, [u16; 3], u32)],
    face_normals: &[Vec3],
    smoothing: &[u32],
) -> Vec<Vec3> {
    let group = |k: usize| smoothing.get(faces[k].0).copied().unwrap_or(0);
    let mut at: HashMap<[u32; 3], Vec<u32>> = HashMap::new();
    for (k, (_, f, _)) in faces.iter().enumerate() {
        if group(k) != 0 {
            for &v in f {
                let key = positions[v as usize].to_array().map(f32::to_bits);
                at.entry(key).or_default().push(k as u32);
            }
        }
    }
    let mut out = Vec::with_capacity(faces.len() * 3);
    for (k, (_, f, _)) in faces.iter().enumerate() {
        let g = group(k);
        for &v in f {
            let mut n = face_normals[k];
            if g != 0 {
                let key = positions[v as usize].to_array().map(f32::to_bits);
                n = at[&key]
                    .iter()
                    .filter(|&&j| group(j as usize) & g != 0)
                    .map(|&j| face_normals[j as usize])
                    .sum();
            }
            out.push(n.try_normalize().unwrap_or(Vec3::Z));
        }
    }
    out
}
