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
    // Output vertices: one per (stored vertex, normal). Each stored vertex keeps a short chain
    // of the output vertices made from it (no hashing: this is the reader's hot loop).
    let mut mesh = Mesh::default();
    let mut head = vec![u32::MAX; nv];
    let mut next: Vec<u32> = Vec::with_capacity(faces.len() * 3);
    for (k, (_, f, m)) in faces.iter().enumerate() {
        let mut tri = [0u32; 3];
        for c in 0..3 {
            let v = f[c] as usize;
            let n = normals[3 * k + c].to_array();
            let mut at = head[v];
            while at != u32::MAX && mesh.normals[at as usize] != n {
                at = next[at as usize];
            }
            if at == u32::MAX {
                let uv = o.uvs.get(v).copied().unwrap_or([0.0, 1.0]);
                at = mesh.positions.len() as u32;
                mesh.positions.push(positions[v].to_array());
                mesh.normals.push(n);
                mesh.uvs.push([uv[0], 1.0 - uv[1]]);
                next.push(head[v]);
                head[v] = at;
            }
            tri[c] = at;
        }
        mesh.indices.push(tri);
        mesh.triangle_materials.push(*m);
    }
    mesh
}

/// Per face corner: the normalized sum of the normals of the faces that touch the same position
/// and share a smoothing group bit with the corner's face (the face itself always counts).
fn smooth_normals(
    positions: &[Vec3],
    faces: &[(usize, [u16; 3], u32)],
    face_normals: &[Vec3],
    smoothing: &[u32],
) -> Vec<Vec3> {
    let group = |k: usize| smoothing.get(faces[k].0).copied().unwrap_or(0);
    let pid = position_ids(positions);
    // Faces per position id, as compressed rows (counting sort).
    let npos = pid.iter().map(|&p| p as usize + 1).max().unwrap_or(0);
    let mut start = vec![0u32; npos + 1];
    for (k, (_, f, _)) in faces.iter().enumerate() {
        if group(k) != 0 {
            for &v in f {
                start[pid[v as usize] as usize + 1] += 1;
            }
        }
    }
    for i in 0..npos {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut rows = vec![0u32; start[npos] as usize];
    for (k, (_, f, _)) in faces.iter().enumerate() {
        if group(k) != 0 {
            for &v in f {
                let p = pid[v as usize] as usize;
                rows[fill[p] as usize] = k as u32;
                fill[p] += 1;
            }
        }
    }
    let mut out = Vec::with_capacity(faces.len() * 3);
    for (k, (_, f, _)) in faces.iter().enumerate() {
        let g = group(k);
        for &v in f {
            let mut n = face_normals[k];
            if g != 0 {
                let p = pid[v as usize] as usize;
                n = rows[start[p] as usize..start[p + 1] as usize]
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

/// For each vertex, an id shared by all vertices at exactly the same position (3DS duplicates
/// vertices along texture seams; smoothing must see through that).
fn position_ids(positions: &[Vec3]) -> Vec<u32> {
    let key = |i: u32| positions[i as usize].to_array().map(f32::to_bits);
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    order.sort_unstable_by_key(|&i| key(i));
    let mut ids = vec![0u32; positions.len()];
    let mut id = 0;
    for w in 0..order.len() {
        if w > 0 && key(order[w]) != key(order[w - 1]) {
            id += 1;
        }
        ids[order[w] as usize] = id;
    }
    ids
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::object3ds::{
        Object3ds, bench_3ds, box_object, chunk, cstr, file_3ds, material_chunk, node_chunk,
    };

    fn bounds(m: &Mesh) -> ([f32; 3], [f32; 3]) {
        m.bounds().unwrap()
    }

    fn close(a: [f32; 3], b: [f32; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
    }

    /// One triangle, one material, written byte by byte (not through the fixture writer).
    fn hand_written() -> Vec<u8> {
        let mut f = Vec::new();
        let le16 = |v: u16| v.to_le_bytes();
        let le32 = |v: u32| v.to_le_bytes();
        // material: name "Red" (0xA000, 10 bytes), diffuse 0xA020 > 0x0011 (255, 0, 0),
        // shininess 0xA040 > 0x0030 50 %
        let mut mat = Vec::new();
        mat.extend(le16(0xA000));
        mat.extend(le32(10));
        mat.extend(b"Red\0");
        mat.extend(le16(0xA020));
        mat.extend(le32(15));
        mat.extend(le16(0x0011));
        mat.extend(le32(9));
        mat.extend([255, 0, 0]);
        mat.extend(le16(0xA040));
        mat.extend(le32(14));
        mat.extend(le16(0x0030));
        mat.extend(le32(8));
        mat.extend(le16(50));
        // vertices: 3 × 12 bytes + count = 38 + 6
        let mut verts = Vec::new();
        verts.extend(le16(0x4110));
        verts.extend(le32(44));
        verts.extend(le16(3));
        for v in [1.0f32, 2.0, 3.0, 4.0, 2.0, 3.0, 1.0, 5.0, 3.0] {
            verts.extend(v.to_le_bytes());
        }
        // faces: count + 1 face (8 bytes) + face material list "Red" 1 face
        let mut fm = Vec::new();
        fm.extend(le16(0x4130));
        fm.extend(le32(6 + 4 + 2 + 2));
        fm.extend(b"Red\0");
        fm.extend(le16(1));
        fm.extend(le16(0));
        let mut faces = Vec::new();
        faces.extend(le16(0x4120));
        faces.extend(le32((6 + 2 + 8 + fm.len()) as u32));
        faces.extend(le16(1));
        faces.extend([0, 0, 1, 0, 2, 0, 0, 0]);
        faces.extend(&fm);
        let mut tri = Vec::new();
        tri.extend(le16(0x4100));
        tri.extend(le32((6 + verts.len() + faces.len()) as u32));
        tri.extend(&verts);
        tri.extend(&faces);
        let mut obj = Vec::new();
        obj.extend(le16(0x4000));
        obj.extend(le32((6 + 4 + tri.len()) as u32));
        obj.extend(b"Tri\0");
        obj.extend(&tri);
        let mut afff = Vec::new();
        afff.extend(le16(0xAFFF));
        afff.extend(le32((6 + mat.len()) as u32));
        afff.extend(&mat);
        let mut editor = Vec::new();
        editor.extend(le16(0x3D3D));
        editor.extend(le32((6 + afff.len() + obj.len()) as u32));
        editor.extend(&afff);
        editor.extend(&obj);
        f.extend(le16(0x4D4D));
        f.extend(le32((6 + editor.len()) as u32));
        f.extend(&editor);
        f
    }

    #[test]
    fn hand_written_triangle_has_known_values() {
        let m = parse(&hand_written()).unwrap();
        assert_eq!(m.indices.len(), 1);
        assert_eq!(m.objects, vec!["Tri".to_string()]);
        let tri = m.indices[0].map(|i| m.positions[i as usize]);
        assert_eq!(tri, [[1.0, 2.0, 3.0], [4.0, 2.0, 3.0], [1.0, 5.0, 3.0]]);
        // (3,0,0) × (0,3,0) points along +z.
        assert!(m.normals.iter().all(|n| close(*n, [0.0, 0.0, 1.0])));
        assert_eq!(m.materials.len(), 1, "no default material needed");
        assert_eq!(m.materials[0].name, "Red");
        assert_eq!(m.materials[0].diffuse, [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(m.materials[0].shininess, 64.0, "50 % of 128");
        assert_eq!(m.triangle_materials, vec![0]);
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        assert_eq!(m.validate(), Ok(()));
    }

    #[test]
    fn bench_fixture_reads_back_with_materials_and_texture() {
        let m = parse(&bench_3ds()).unwrap();
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        assert_eq!(m.objects, vec!["Seat".to_string(), "Legs".to_string()]);
        assert_eq!(m.indices.len(), 12 + 24);
        let names: Vec<_> = m.materials.iter().map(|x| x.name.as_str()).collect();
        assert_eq!(names, ["Wood", "Iron"]);
        assert_eq!(m.textures.len(), 1);
        assert_eq!(m.textures[0].name, "OBJWOOD.PNG");
        assert_eq!(m.materials[0].color_map, Some(0));
        assert_eq!(m.materials[1].color_map, None);
        assert!((m.materials[1].shininess - 0.6 * 128.0).abs() < 1e-4);
        assert_eq!(m.triangle_materials[..12], [0; 12]);
        assert_eq!(m.triangle_materials[12..], [1; 24]);
        // The keyframer placement equals the mesh matrix: the stored vertices come back.
        let (lo, hi) = bounds(&m);
        assert!(close(lo, [-0.8, -0.2, 0.0]), "{lo:?}");
        assert!(close(hi, [0.8, 0.2, 0.45]), "{hi:?}");
        // Box sides are flat: every normal is a unit axis vector.
        for n in &m.normals {
            let ones = n.iter().filter(|c| (c.abs() - 1.0).abs() < 1e-5).count();
            assert_eq!(ones, 1, "{n:?}");
        }
        // 24 vertices per box (4 per side, smoothing groups per side keep them apart).
        assert_eq!(m.positions.len(), 24 * 3);
        // v is flipped: stored uvs are 0/1 corners, so still 0/1 values.
        assert!(m.uvs.iter().flatten().all(|&c| c == 0.0 || c == 1.0));
        assert_eq!(m.validate(), Ok(()));
    }

    #[test]
    fn load_resolves_texture_case_insensitively() {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in crate::fixtures::object3ds::object_files() {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let m = load(&dir.path().join("object.3ds")).unwrap();
        assert_eq!(m.textures[0].path, dir.path().join("objwood.png"));
    }

    /// Regression: with a model named by a bare relative path (`bake ingest scene.eco` run in
    /// the scene's folder) the texture's folder was "", `read_dir("")` failed, and the
    /// case-insensitive match was skipped ("OBJWOOD.PNG: No such file or directory").
    #[test]
    fn bare_relative_texture_name_resolves_case_insensitively() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("objwood.png"), b"x").unwrap();
        let here = std::env::current_dir().unwrap();
        let rel = pathdiff(dir.path(), &here);
        let found = resolve_texture(&rel, "OBJWOOD.PNG");
        assert_eq!(found, rel.join("objwood.png"));
        assert_eq!(
            resolve_texture(Path::new(""), "Cargo.TOML"),
            PathBuf::from("Cargo.toml")
        );
    }

    /// `to` relative to `from` through `..` (both absolute).
    fn pathdiff(to: &Path, from: &Path) -> PathBuf {
        let mut p = PathBuf::new();
        for _ in from.components().skip(1) {
            p.push("..");
        }
        p.join(to.strip_prefix("/").unwrap())
    }

    fn one_box(matrix: Option<[f32; 12]>) -> Object3ds {
        let mut o = box_object("B", [0.0; 3], [1.0; 3]);
        o.matrix = matrix;
        o
    }

    #[test]
    fn keyframer_position_moves_the_object_like_assimp() {
        // Identity mesh matrix, node at (1, 2, 3): vertices move by (1, 2, 3).
        let kf = node_chunk(0, "B", [1.0, 2.0, 3.0], (0.0, [0.0, 0.0, 1.0]), [1.0; 3]);
        let m = parse(&file_3ds(&[], &[one_box(None)], Some(&kf))).unwrap();
        let (lo, hi) = bounds(&m);
        assert!(
            close(lo, [1.0, 2.0, 3.0]) && close(hi, [2.0, 3.0, 4.0]),
            "{lo:?} {hi:?}"
        );
    }

    #[test]
    fn mesh_matrix_is_undone_then_node_applied() {
        // Mesh matrix: translate by (10, 0, 0); node: rotation key +90° about z, which assimp
        // applies as a rotation by -90°: local (x, y, z) -> (y, -x, z), then scale 2.
        let mut mat = [0.0; 12];
        mat[0] = 1.0;
        mat[4] = 1.0;
        mat[8] = 1.0;
        mat[9] = 10.0;
        let o = Object3ds {
            name: "T".into(),
            positions: vec![[11.0, 0.0, 0.0], [10.0, 1.0, 0.0], [10.0, 0.0, 1.0]],
            faces: vec![[0, 1, 2]],
            matrix: Some(mat),
            ..Object3ds::default()
        };
        let kf = node_chunk(
            0,
            "T",
            [0.0; 3],
            (std::f32::consts::FRAC_PI_2, [0.0, 0.0, 1.0]),
            [2.0; 3],
        );
        let m = parse(&file_3ds(&[], &[o], Some(&kf))).unwrap();
        let tri = m.indices[0].map(|i| m.positions[i as usize]);
        assert!(close(tri[0], [0.0, -2.0, 0.0]), "{tri:?}");
        assert!(close(tri[1], [2.0, 0.0, 0.0]), "{tri:?}");
        assert!(close(tri[2], [0.0, 0.0, 2.0]), "{tri:?}");
    }

    #[test]
    fn negative_determinant_mirrors_local_x() {
        // Mesh matrix mirrors x; node identity: local = flip(inverse(M) v) = v again in x.
        let mut mat = [0.0; 12];
        mat[0] = -1.0;
        mat[4] = 1.0;
        mat[8] = 1.0;
        mat[9] = 5.0;
        let kf = node_chunk(0, "B", [0.0; 3], (0.0, [0.0, 0.0, 1.0]), [1.0; 3]);
        let m = parse(&file_3ds(&[], &[one_box(Some(mat))], Some(&kf))).unwrap();
        // inverse(M) v = (5 - x, y, z), mirrored: (x - 5, y, z).
        let (lo, hi) = bounds(&m);
        assert!(
            close(lo, [-5.0, 0.0, 0.0]) && close(hi, [-4.0, 1.0, 1.0]),
            "{lo:?} {hi:?}"
        );
    }

    #[test]
    fn without_keyframer_matrix_is_ignored() {
        let mut mat = [0.0; 12];
        mat[0] = 2.0;
        mat[4] = 2.0;
        mat[8] = 2.0;
        let m = parse(&file_3ds(&[], &[one_box(Some(mat))], None)).unwrap();
        assert_eq!(bounds(&m), ([0.0; 3], [1.0; 3]));
    }

    #[test]
    fn smoothing_groups_average_normals_across_seams() {
        // A roof: two faces meeting at the ridge x = 0, z = 1; the ridge vertices are stored
        // twice (a texture seam), so only positions can tell they are shared.
        let roof = |groups: Vec<u32>| Object3ds {
            name: "R".into(),
            positions: vec![
                [-1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, 1.0, 1.0],
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 1.0],
            ],
            faces: vec![[0, 1, 2], [3, 4, 5]],
            smoothing: groups,
            ..Object3ds::default()
        };
        let ridge = |m: &Mesh| -> Vec<[f32; 3]> {
            (0..m.positions.len())
                .filter(|&i| m.positions[i][0] == 0.0)
                .map(|i| m.normals[i])
                .collect()
        };
        let smooth = parse(&file_3ds(&[], &[roof(vec![1, 1])], None)).unwrap();
        let r = ridge(&smooth);
        assert_eq!(r.len(), 4);
        assert!(
            r.iter()
                .all(|n| close(*n, [0.0, 0.0, -1.0]) || close(*n, [0.0, 0.0, 1.0]))
        );
        let n0 = r[0];
        assert!(
            r.iter().all(|n| *n == n0),
            "one averaged normal on the ridge: {r:?}"
        );
        let flat = parse(&file_3ds(&[], &[roof(vec![1, 2])], None)).unwrap();
        let h = std::f32::consts::FRAC_1_SQRT_2;
        assert!(
            ridge(&flat)
                .iter()
                .all(|n| (n[0].abs() - h).abs() < 1e-5 && (n[2].abs() - h).abs() < 1e-5)
        );
    }

    #[test]
    fn rock_has_its_analytic_counts() {
        // Two rocks of 250 × 125 quads: 2 · 62500 triangles.
        let m = parse(&crate::fixtures::object3ds::rock_3ds(250, 2)).unwrap();
        assert_eq!(m.indices.len(), 2 * 2 * 250 * 125);
        assert_eq!(m.objects, ["Rock0", "Rock1"]);
        assert_eq!(m.validate(), Ok(()));
        let (lo, hi) = bounds(&m);
        assert!(lo.iter().all(|c| (-1.11..-0.85).contains(c)), "{lo:?}");
        assert!(
            (3.35..3.61).contains(&hi[0]) && (0.85..1.11).contains(&hi[2]),
            "{hi:?}"
        );
    }

    #[test]
    fn out_of_range_faces_are_dropped_with_a_warning() {
        let mut o = one_box(None);
        o.faces.push([0, 1, 99]);
        let m = parse(&file_3ds(&[], &[o], None)).unwrap();
        assert_eq!(m.indices.len(), 12);
        assert!(
            m.warnings.iter().any(|w| w.contains("1 of 13 faces")),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn faces_without_material_get_the_default_and_unknown_names_warn() {
        let mut o = one_box(None);
        o.face_materials = vec![("Nope".into(), vec![0, 1])];
        let mats = [material_chunk("Tex", [9, 9, 9], 0, 50, Some("T.PNG"))];
        let m = parse(&file_3ds(&mats, &[o], None)).unwrap();
        assert_eq!(m.materials.len(), 2);
        assert_eq!(m.materials[1].name, "default");
        assert_eq!(m.materials[0].transparency, 0.5);
        assert!(m.triangle_materials.iter().all(|&t| t == 1));
        assert!(
            m.warnings
                .iter()
                .any(|w| w.contains("unknown material \"Nope\""))
        );
    }

    #[test]
    fn missing_uvs_on_a_textured_object_warn() {
        let mut o = one_box(None);
        o.uvs.clear();
        o.face_materials = vec![("Tex".into(), (0..12).collect())];
        let mats = [material_chunk("Tex", [9, 9, 9], 0, 0, Some("T.PNG"))];
        let m = parse(&file_3ds(&mats, &[o], None)).unwrap();
        assert!(m.uvs.iter().all(|uv| *uv == [0.0, 0.0]));
        assert!(
            m.warnings.iter().any(|w| w.contains("0x4140")),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn truncation_at_every_length_is_an_error_not_a_panic() {
        let bytes = bench_3ds();
        for n in 0..bytes.len() {
            let e = parse(&bytes[..n]).expect_err("a truncated file must fail");
            assert!(e.place.starts_with("byte"), "{n}: {e}");
        }
    }

    #[test]
    fn zero_length_chunk_is_skipped_with_a_warning() {
        let mut o = Vec::new();
        o.extend(chunk(0x1234, &[])[..2].iter()); // id only ...
        o.extend(0u32.to_le_bytes()); // ... with length 0
        let obj = crate::fixtures::object3ds::object_chunk(&one_box(None));
        let editor = chunk(0x3D3D, &[&o, &obj]);
        let m = parse(&chunk(0x4D4D, &[&editor])).unwrap();
        assert_eq!(m.indices.len(), 12);
        assert!(
            m.warnings.iter().any(|w| w.contains("length 0")),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn chunk_past_its_parent_is_clamped_and_past_the_file_is_an_error() {
        let obj = crate::fixtures::object3ds::object_chunk(&one_box(None));
        let mut editor = chunk(0x3D3D, &[&obj]);
        // Editor claims 4 more bytes than the main chunk holds; the file has them (padding).
        let len = editor.len() as u32 + 4;
        editor[2..6].copy_from_slice(&len.to_le_bytes());
        let mut file = chunk(0x4D4D, &[&editor]);
        file.extend([0; 4]);
        let m = parse(&file).unwrap();
        assert!(
            m.warnings.iter().any(|w| w.contains("past its parent")),
            "{:?}",
            m.warnings
        );
        // The same without the padding runs past the end of the file.
        file.truncate(file.len() - 4);
        let e = parse(&file).unwrap_err();
        assert!(
            e.place.contains("chunk 0x3D3D") && e.message.contains("truncated"),
            "{e}"
        );
    }

    #[test]
    fn vertex_count_larger_than_its_chunk_names_chunk_and_offset() {
        let mut verts = 60000u16.to_le_bytes().to_vec();
        verts.extend([0u8; 12]);
        let tri = chunk(0x4100, &[&chunk(0x4110, &[&verts])]);
        let obj = chunk(0x4000, &[&cstr("X"), &tri]);
        let file = chunk(0x4D4D, &[&chunk(0x3D3D, &[&obj])]);
        let e = parse(&file).unwrap_err();
        assert!(e.place.contains("chunk 0x4110"), "{e}");
        assert!(
            e.message.contains("60000 vertices needs 720000 bytes"),
            "{e}"
        );
    }

    #[test]
    fn not_a_3ds_file_and_no_triangles_are_errors() {
        assert!(
            parse(b"hello world")
                .unwrap_err()
                .message
                .contains("0x4D4D")
        );
        let e = parse(&file_3ds(&[], &[], None)).unwrap_err();
        assert!(e.message.contains("no triangles"), "{e}");
    }

    #[test]
    fn random_mutations_never_panic() {
        let base = bench_3ds();
        let mut rng = crate::fixtures::Rng::new(7);
        for _ in 0..3000 {
            let mut b = base.clone();
            for _ in 0..1 + rng.next_u64() % 4 {
                let k = (rng.next_u64() % b.len() as u64) as usize;
                b[k] = rng.next_u64() as u8;
            }
            if let Ok(m) = parse(&b) {
                assert_eq!(m.validate(), Ok(()));
            }
        }
    }
}
