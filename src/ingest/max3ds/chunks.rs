//! The chunk reader: chunk ids, the bounds-checked cursor over one chunk, capped warnings,
//! and the parser that walks the chunk tree into a [`File3ds`] (objects, materials, nodes).

use super::*;

pub(super) const MAIN: u16 = 0x4D4D;
pub(super) const EDITOR: u16 = 0x3D3D;
pub(super) const MASTER_SCALE: u16 = 0x0100;
pub(super) const OBJECT: u16 = 0x4000;
pub(super) const TRIMESH: u16 = 0x4100;
pub(super) const VERTICES: u16 = 0x4110;
pub(super) const FACES: u16 = 0x4120;
pub(super) const FACE_MATERIALS: u16 = 0x4130;
pub(super) const UVS: u16 = 0x4140;
pub(super) const SMOOTHING: u16 = 0x4150;
pub(super) const MESH_MATRIX: u16 = 0x4160;
pub(super) const MATERIAL: u16 = 0xAFFF;
pub(super) const MAT_NAME: u16 = 0xA000;
pub(super) const MAT_AMBIENT: u16 = 0xA010;
pub(super) const MAT_DIFFUSE: u16 = 0xA020;
pub(super) const MAT_SPECULAR: u16 = 0xA030;
pub(super) const MAT_SHININESS: u16 = 0xA040;
pub(super) const MAT_SHIN_STRENGTH: u16 = 0xA041;
pub(super) const MAT_TRANSPARENCY: u16 = 0xA050;
pub(super) const MAT_TEXTURE: u16 = 0xA200;
pub(super) const MAP_FILE: u16 = 0xA300;
pub(super) const RGB_F32: u16 = 0x0010;
pub(super) const RGB_U8: u16 = 0x0011;
pub(super) const LIN_RGB_U8: u16 = 0x0012;
pub(super) const LIN_RGB_F32: u16 = 0x0013;
pub(super) const PERCENT_U16: u16 = 0x0030;
pub(super) const PERCENT_F32: u16 = 0x0031;
pub(super) const KEYFRAMER: u16 = 0xB000;
pub(super) const KF_OBJECT: u16 = 0xB002;
pub(super) const KF_CAMERA: u16 = 0xB003;
pub(super) const KF_CAM_TARGET: u16 = 0xB004;
pub(super) const KF_LIGHT_TARGET: u16 = 0xB006;
pub(super) const KF_SPOT: u16 = 0xB007;
pub(super) const KF_NAME: u16 = 0xB010;
pub(super) const KF_DUMMY_NAME: u16 = 0xB011;
pub(super) const KF_PIVOT: u16 = 0xB013;
pub(super) const KF_POS: u16 = 0xB020;
pub(super) const KF_ROT: u16 = 0xB021;
pub(super) const KF_SCALE: u16 = 0xB022;
pub(super) const KF_ROLL: u16 = 0xB024;

/// Warnings, capped so a file of a million zero-length chunks does not make a million strings.
#[derive(Default)]
pub(super) struct Warnings {
    pub(super) list: Vec<String>,
    pub(super) dropped: usize,
}

impl Warnings {
    pub(super) fn push(&mut self, w: String) {
        if self.list.len() < MAX_WARNINGS {
            self.list.push(w);
        } else {
            self.dropped += 1;
        }
    }
    pub(super) fn finish(mut self) -> Vec<String> {
        if self.dropped > 0 {
            self.list
                .push(format!("... and {} more warnings", self.dropped));
        }
        self.list
    }
}

/// One chunk: id, header offset, body range.
#[derive(Debug, Clone, Copy)]
pub(super) struct Chunk {
    pub(super) id: u16,
    pub(super) at: usize,
    pub(super) body: usize,
    pub(super) end: usize,
}

impl Chunk {
    pub(super) fn place(&self) -> String {
        format!("byte {} (chunk 0x{:04X})", self.at, self.id)
    }
    pub(super) fn err(&self, message: impl Into<String>) -> ParseError {
        ParseError::new(self.place(), message)
    }
}

/// A bounds-checked reader over one chunk's body.
pub(super) struct Cur<'a> {
    pub(super) data: &'a [u8],
    pub(super) pos: usize,
    pub(super) chunk: Chunk,
}

impl<'a> Cur<'a> {
    pub(super) fn new(data: &'a [u8], chunk: Chunk) -> Self {
        Cur {
            data,
            pos: chunk.body,
            chunk,
        }
    }
    pub(super) fn left(&self) -> usize {
        self.chunk.end.saturating_sub(self.pos)
    }
    /// Checks that `n` more bytes are in the chunk before anything is read or allocated.
    pub(super) fn need(&self, n: usize, what: &str) -> Result<(), ParseError> {
        if n > self.left() {
            return Err(self.chunk.err(format!(
                "{what} needs {n} bytes at byte {}, but the chunk has only {} left",
                self.pos,
                self.left()
            )));
        }
        Ok(())
    }
    pub(super) fn bytes<const N: usize>(&mut self, what: &str) -> Result<[u8; N], ParseError> {
        self.need(N, what)?;
        let mut b = [0; N];
        b.copy_from_slice(&self.data[self.pos..self.pos + N]);
        self.pos += N;
        Ok(b)
    }
    pub(super) fn u16(&mut self, what: &str) -> Result<u16, ParseError> {
        self.bytes::<2>(what).map(u16::from_le_bytes)
    }
    pub(super) fn u32(&mut self, what: &str) -> Result<u32, ParseError> {
        self.bytes::<4>(what).map(u32::from_le_bytes)
    }
    pub(super) fn f32(&mut self, what: &str) -> Result<f32, ParseError> {
        self.bytes::<4>(what).map(f32::from_le_bytes)
    }
    pub(super) fn vec3(&mut self, what: &str) -> Result<Vec3, ParseError> {
        Ok(Vec3::new(self.f32(what)?, self.f32(what)?, self.f32(what)?))
    }
    pub(super) fn skip(&mut self, n: usize, what: &str) -> Result<(), ParseError> {
        self.need(n, what)?;
        self.pos += n;
        Ok(())
    }
    /// A NUL-terminated string; one that runs to the chunk's end without a NUL is accepted.
    pub(super) fn cstr(&mut self) -> String {
        let end = self.chunk.end.min(self.data.len());
        let body = &self.data[self.pos.min(end)..end];
        let n = body.iter().position(|&b| b == 0).unwrap_or(body.len());
        let s = String::from_utf8_lossy(&body[..n]).into_owned();
        self.pos = (self.pos + n + 1).min(end);
        s
    }
}

/// A raw 3DS material: the model material plus its texture file name.
pub(super) struct RawMaterial {
    pub(super) material: Material,
    pub(super) texture: Option<String>,
}

/// One triangle-mesh object as stored.
#[derive(Default)]
pub(super) struct Object {
    pub(super) name: String,
    pub(super) positions: Vec<[f32; 3]>,
    pub(super) uvs: Vec<[f32; 2]>,
    pub(super) faces: Vec<[u16; 3]>,
    pub(super) smoothing: Vec<u32>,
    /// Per face: index into the file's materials, or `None` for the default material.
    pub(super) face_materials: Vec<Option<u32>>,
    pub(super) matrix: Option<Mat4>,
}

/// A keyframer node, as assimp's hierarchy builder makes it.
#[derive(Debug, Default, Clone)]
pub(super) struct Node {
    pub(super) name: String,
    pub(super) parent: Option<usize>,
    pub(super) children: Vec<usize>,
    pub(super) hierarchy_pos: i32,
    pub(super) pivot: Vec3,
    /// First key of each track: (frame, value).
    pub(super) pos: Option<(u32, Vec3)>,
    pub(super) rot: Option<(u32, f32, Vec3)>,
    pub(super) scale: Option<(u32, Vec3)>,
    pub(super) roll: Option<(u32, f32)>,
}

/// Everything read from the file.
pub(super) struct File3ds {
    pub(super) master_scale: f32,
    pub(super) materials: Vec<RawMaterial>,
    pub(super) objects: Vec<Object>,
    /// Node 0 is the root.
    pub(super) nodes: Vec<Node>,
    pub(super) current: usize,
    pub(super) last_index: i32,
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

pub(super) struct Parser<'a> {
    pub(super) data: &'a [u8],
    pub(super) file: File3ds,
    pub(super) warn: Warnings,
}

impl<'a> Parser<'a> {
    /// The next chunk in `pos..end`, or `None` when fewer than 6 bytes are left.
    pub(super) fn next_chunk(
        &mut self,
        pos: &mut usize,
        end: usize,
    ) -> Result<Option<Chunk>, ParseError> {
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
    pub(super) fn each(
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

    pub(super) fn main(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| match sub.id {
            EDITOR => p.editor(&sub),
            KEYFRAMER => p.keyframer(&sub),
            _ => Ok(()),
        })
    }

    pub(super) fn editor(&mut self, c: &Chunk) -> Result<(), ParseError> {
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

    pub(super) fn object(&mut self, c: &Chunk) -> Result<(), ParseError> {
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

    pub(super) fn object_mut(&mut self) -> &mut Object {
        self.file
            .objects
            .last_mut()
            .expect("trimesh pushes an object first")
    }

    pub(super) fn trimesh(&mut self, c: &Chunk) -> Result<(), ParseError> {
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

    pub(super) fn faces(&mut self, c: &Chunk, cur: &mut Cur) -> Result<(), ParseError> {
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

    pub(super) fn face_materials(&mut self, c: &Chunk, cur: &mut Cur) -> Result<(), ParseError> {
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

    pub(super) fn material(&mut self, c: &Chunk) -> Result<(), ParseError> {
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
    pub(super) fn color(&mut self, c: &Chunk) -> Result<Option<[f32; 4]>, ParseError> {
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
    pub(super) fn percent(&mut self, c: &Chunk) -> Result<Option<f32>, ParseError> {
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

    pub(super) fn keyframer(&mut self, c: &Chunk) -> Result<(), ParseError> {
        self.each(c.body, c.end, |p, sub| {
            if (KF_OBJECT..=KF_SPOT).contains(&sub.id) {
                let kind = sub.id;
                p.each(sub.body, sub.end, |p, t| p.track_chunk(kind, &t))?;
            }
            Ok(())
        })
    }

    /// One sub-chunk of a keyframer node chunk of type `kind` (0xB002..0xB007).
    pub(super) fn track_chunk(&mut self, kind: u16, c: &Chunk) -> Result<(), ParseError> {
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
