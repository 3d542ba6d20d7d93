//! TXF plant models (Xfrog via the University of Konstanz player; seed 000, 3.1.1).
//!
//! A TXF file is XML-like text with binary blocks. Line 1 is `<?txf_version='0.91'?>`, then
//! blocks `<Textures>`, `<Colors>`, `<Infos>` and `<Set>`. The format is not context-free:
//! `<tex_number>` and `<col_number>` set a current id that the following `<tex_name>`,
//! `<diff>`, `<ambi>`, `<spec>`, `<emis>`, `<shin>` refer to. Whitespace around tags is accepted.
//!
//! A `<Set>` has a `<header>` whose `<tc_combo> TEX MAT </tc_combo>` picks texture and material
//! (and `<translucence>`; a negative texture id means untextured, an id missing from
//! `<Textures>` or `<Colors>` gives a warning and no texture or the OpenGL default material),
//! `<references>` (skipped as text), and geometry: `<vertex_array>` with
//! `number_of_vertices` vertices of 36 bytes `{f32 texcoord[3]; f32 normal[3]; f32 position[3]}`
//! (little-endian) in `<data>`, then `<index>` with `number_of_index_values` u32 indices
//! (3 per triangle); `<line_array>` (`number_of_line_vertices`, index pairs) and `<point_array>`
//! (`number_of_subpoints + number_of_regpoints + number_of_suppoints` vertices) are read and
//! skipped (they are LOD representations).
//!
//! **Binary payloads.** The thesis does not say whether a payload starts right after its tag
//! (`<data>` or `</number_of_index_values>`) or after that tag's 0x0A. Both are accepted: the
//! payload length comes from the header counts (never from a search for the closing tag), and
//! a placement is valid when the closing tag follows the payload (after optional whitespace).
//! When both are valid (the payload starts with 0x0A and is followed by whitespace) the one
//! whose content is plausible wins (vertices with finite values and a third texcoord of 0,
//! indices in range), ties going to the after-newline placement.
//!
//! **Texture coordinates.** TXF coordinates are OpenGL's (t = 0 at the bottom row of the
//! image); the model has v = 0 at the top row, so `uv = (s, 1 − t)`.
//!
//! **Wrap-around fix.** On closed cylinders u rises around the model (0.0, 0.2, … 0.8) and the
//! closing triangles reuse the start vertices with u = 0.0; those triangles must see 1 + u.
//! Per set, a triangle is a *candidate* when its u span exceeds 0.5 and adding 1 to its low
//! vertices (u < u_max − 0.5) brings the span to at most 0.5. A candidate is fixed when its
//! shifted span is closer than its original span to the median span of the non-candidate
//! triangles that share a vertex with it (its neighbours along the cylinder have the segment
//! span). Leaf quads whose triangles span the whole texture have no such narrow neighbours
//! and are left alone. A fixed triangle gets duplicates of its low vertices with u + 1 (one
//! duplicate per original vertex, shared by the set's fixed triangles); the shared vertex is
//! never moved.
//!
//! **Normals.** Zero or non-finite normals are replaced by the area-weighted face normals of
//! the set's triangles, with a warning; the others are normalised.

use crate::error::{Error, ParseError, Result};
use crate::model::{Material, Mesh, TextureRef};
use std::collections::HashMap;
use std::path::Path;

/// Bytes of one binary vertex.
pub const VERTEX_BYTES: usize = 36;

/// Reads a TXF file; texture names are resolved against the file's folder.
pub fn load(path: &Path) -> Result<Mesh> {
    let bytes = crate::error::read_file(path)?;
    let mut mesh = parse(&bytes).map_err(|e| Error::invalid(path, e))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    for t in &mut mesh.textures {
        t.path = dir.join(&t.name);
    }
    Ok(mesh)
}

/// Parses TXF bytes into one mesh; texture paths are left as the names written.
pub fn parse(bytes: &[u8]) -> Result<Mesh, ParseError> {
    let mut c = Cursor { b: bytes, pos: 0 };
    let mut file = TxfFile::default();
    read_version(&mut c, &mut file.warnings)?;
    loop {
        let (tok, at) = c.next()?;
        match tok {
            Tok::Eof => break,
            Tok::Open("Textures") => read_textures(&mut c, &mut file)?,
            Tok::Open("Colors") => read_colors(&mut c, &mut file)?,
            Tok::Open("Infos") => c.skip_element("Infos")?,
            Tok::Open("Set") => {
                let set = read_set(&mut c, at)?;
                file.sets.push(set);
            }
            Tok::Open(other) => {
                file.warnings
                    .push(format!("{}: unknown block <{other}> skipped", c.place(at)));
                c.skip_element(other)?;
            }
            t => {
                return Err(c.unexpected(at, &t, "a block <Textures>, <Colors>, <Infos> or <Set>"));
            }
        }
    }
    build_mesh(file)
}

// ---------------------------------------------------------------------------------------------
// Lexer

/// A token of the text parts.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Tok<'a> {
    Open(&'a str),
    Close(&'a str),
    Text(&'a str),
    Eof,
}

struct Cursor<'a> {
    b: &'a [u8],
    pos: usize,
}

fn is_ws(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r' | b'\n')
}

impl<'a> Cursor<'a> {
    /// 1-based line of a byte offset (counting every 0x0A before it, binary ones included, so
    /// that it matches what an editor shows).
    fn line_of(&self, at: usize) -> usize {
        1 + self.b[..at.min(self.b.len())]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
    }

    fn place(&self, at: usize) -> String {
        format!("line {}", self.line_of(at))
    }

    fn err(&self, at: usize, msg: impl Into<String>) -> ParseError {
        ParseError::at_line(self.line_of(at), msg)
    }

    fn unexpected(&self, at: usize, tok: &Tok, expected: &str) -> ParseError {
        let found = match tok {
            Tok::Open(n) => format!("<{n}>"),
            Tok::Close(n) => format!("</{n}>"),
            Tok::Text(t) => format!("text {:?}", t.chars().take(40).collect::<String>()),
            Tok::Eof => "the end of the file".into(),
        };
        self.err(at, format!("expected {expected}, found {found}"))
    }

    fn skip_ws(&mut self) {
        while self.pos < self.b.len() && is_ws(self.b[self.pos]) {
            self.pos += 1;
        }
    }

    /// The next token and the byte offset where it starts.
    fn next(&mut self) -> Result<(Tok<'a>, usize), ParseError> {
        self.skip_ws();
        let at = self.pos;
        if at >= self.b.len() {
            return Ok((Tok::Eof, at));
        }
        if self.b[at] == b'<' {
            return self.tag(at).map(|t| (t, at));
        }
        let end = self.b[at..]
            .iter()
            .position(|&c| c == b'<')
            .map_or(self.b.len(), |k| at + k);
        let text = std::str::from_utf8(&self.b[at..end])
            .map_err(|_| self.err(at, "binary data where text was expected"))?;
        self.pos = end;
        Ok((Tok::Text(text.trim_end()), at))
    }

    fn tag(&mut self, at: usize) -> Result<Tok<'a>, ParseError> {
        const MAX_TAG: usize = 128;
        let rest = &self.b[at + 1..self.b.len().min(at + 1 + MAX_TAG)];
        let len = rest
            .iter()
            .position(|&c| c == b'>')
            .ok_or_else(|| self.err(at, "unterminated tag (no '>')"))?;
        let inner = std::str::from_utf8(&rest[..len])
            .map_err(|_| self.err(at, "tag name is not text"))?
            .trim();
        self.pos = at + 2 + len;
        let (close, name) = match inner.strip_prefix('/') {
            Some(n) => (true, n.trim()),
            None => (false, inner),
        };
        if name.is_empty() || !name.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_') {
            return Err(self.err(at, format!("bad tag <{inner}>")));
        }
        Ok(if close {
            Tok::Close(name)
        } else {
            Tok::Open(name)
        })
    }

    /// After `<name>`: the element's text up to `</name>` (empty if none).
    fn text_element(&mut self, name: &str) -> Result<(&'a str, usize), ParseError> {
        let (tok, at) = self.next()?;
        match tok {
            Tok::Close(n) if n == name => Ok(("", at)),
            Tok::Text(t) => {
                self.expect_close(name)?;
                Ok((t, at))
            }
            t => Err(self.unexpected(at, &t, &format!("the value of <{name}>"))),
        }
    }

    fn expect_close(&mut self, name: &str) -> Result<(), ParseError> {
        match self.next()? {
            (Tok::Close(n), _) if n == name => Ok(()),
            (t, at) => Err(self.unexpected(at, &t, &format!("</{name}>"))),
        }
    }

    /// After `<name>`: skips text and nested elements up to the matching `</name>`.
    fn skip_element(&mut self, name: &str) -> Result<(), ParseError> {
        let mut open: Vec<&str> = vec![name];
        while let Some(&top) = open.last() {
            match self.next()? {
                (Tok::Open(n), _) => open.push(n),
                (Tok::Close(n), _) if n == top => {
                    open.pop();
                }
                (Tok::Text(_), _) => {}
                (t, at) => return Err(self.unexpected(at, &t, &format!("</{top}>"))),
            }
        }
        Ok(())
    }

    /// Whether `</name>` follows byte `at` after optional whitespace.
    fn closes_at(&self, mut at: usize, name: &str) -> bool {
        while at < self.b.len() && is_ws(self.b[at]) {
            at += 1;
        }
        let rest = &self.b[at.min(self.b.len())..];
        let Some(r) = rest.strip_prefix(b"</") else {
            return false;
        };
        let Some(r) = r.strip_prefix(name.as_bytes()) else {
            return false;
        };
        r.iter().find(|&&c| !is_ws(c)) == Some(&b'>')
    }

    /// Reads a binary payload of `len` bytes that starts right after the tag just read or
    /// after that tag's 0x0A, and is followed by `</closing>` (see the module doc). `score`
    /// rates how plausible a candidate payload is. Leaves the cursor after the payload.
    fn payload(
        &mut self,
        len: Option<usize>,
        what: &str,
        closing: &str,
        score: impl Fn(&[u8]) -> usize,
    ) -> Result<&'a [u8], ParseError> {
        let start = self.pos;
        let remaining = self.b.len() - start;
        let len = match len {
            Some(l) if l <= remaining => l,
            _ => {
                return Err(ParseError::at_byte(
                    start,
                    format!(
                        "{what} needs {} bytes, only {remaining} remain",
                        len.map_or("more than 2^64".into(), |l| l.to_string())
                    ),
                ));
            }
        };
        let mut candidates = vec![start];
        let nl = self.b[start..]
            .iter()
            .take(8)
            .position(|&c| !matches!(c, b' ' | b'\t' | b'\r'));
        if let Some(k) = nl.filter(|&k| self.b.get(start + k) == Some(&b'\n')) {
            candidates.push(start + k + 1);
        }
        let valid: Vec<usize> = candidates
            .into_iter()
            .filter(|&s| s + len <= self.b.len() && self.closes_at(s + len, closing))
            .collect();
        // Ties go to the later (after-newline) candidate: `max_by_key` keeps the last maximum.
        let chosen = valid
            .iter()
            .copied()
            .max_by_key(|&s| score(&self.b[s..s + len]))
            .ok_or_else(|| {
                ParseError::at_byte(
                    start + len,
                    format!("expected </{closing}> after the {len}-byte {what} that starts at byte {start}"),
                )
            })?;
        self.pos = chosen + len;
        Ok(&self.b[chosen..chosen + len])
    }
}

// ---------------------------------------------------------------------------------------------
// Blocks

/// A material from `<Colors>`.
#[derive(Debug, Clone, PartialEq)]
struct Color {
    name: String,
    material: Material,
}

/// One binary vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Vertex {
    tc: [f32; 2],
    normal: [f32; 3],
    position: [f32; 3],
}

#[derive(Debug, Default)]
struct SetData {
    number: Option<i64>,
    /// Byte offset of `<Set>`, to name unnumbered sets.
    offset: usize,
    tex: Option<i64>,
    mat: Option<i64>,
    translucence: Option<f32>,
    vertices: Vec<Vertex>,
    triangles: Vec<[u32; 3]>,
}

#[derive(Debug, Default)]
struct TxfFile {
    textures: HashMap<i64, String>,
    colors: HashMap<i64, Color>,
    sets: Vec<SetData>,
    warnings: Vec<String>,
}

fn read_version(c: &mut Cursor, warnings: &mut Vec<String>) -> Result<(), ParseError> {
    c.skip_ws();
    let at = c.pos;
    let rest = &c.b[at..];
    let end = rest
        .iter()
        .take(256)
        .position(|&b| b == b'\n')
        .unwrap_or(rest.len().min(256));
    let line = std::str::from_utf8(&rest[..end]).unwrap_or("").trim();
    let version = line
        .strip_prefix("<?txf_version=")
        .and_then(|r| r.strip_suffix("?>"))
        .map(|v| v.trim().trim_matches(|q| q == '\'' || q == '"'))
        .ok_or_else(|| c.err(at, "not a TXF file: expected <?txf_version='0.91'?>"))?;
    if version != "0.91" {
        warnings.push(format!("TXF version {version:?}, read as 0.91"));
    }
    c.pos = at + end;
    Ok(())
}

fn parse_num<T: std::str::FromStr>(
    c: &Cursor,
    at: usize,
    text: &str,
    what: &str,
) -> Result<T, ParseError> {
    text.trim()
        .parse()
        .map_err(|_| c.err(at, format!("{what}: expected a number, found {text:?}")))
}

/// `n` whitespace-separated finite floats (`alpha_default` fills a missing fourth).
fn parse_floats<const N: usize>(
    c: &Cursor,
    at: usize,
    text: &str,
    what: &str,
    alpha_default: Option<f32>,
) -> Result<[f32; N], ParseError> {
    let vals: Vec<f32> = text
        .split_whitespace()
        .map(|t| t.parse::<f32>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| {
            c.err(
                at,
                format!("<{what}>: expected finite numbers, found {text:?}"),
            )
        })?;
    let mut out = [alpha_default.unwrap_or(0.0); N];
    let ok = vals.len() == N || (alpha_default.is_some() && vals.len() == N - 1);
    if !ok {
        return Err(c.err(
            at,
            format!("<{what}>: expected {N} numbers, found {}", vals.len()),
        ));
    }
    out[..vals.len()].copy_from_slice(&vals);
    Ok(out)
}

fn read_textures(c: &mut Cursor, f: &mut TxfFile) -> Result<(), ParseError> {
    let mut current = None;
    loop {
        match c.next()? {
            (Tok::Close("Textures"), _) => return Ok(()),
            (Tok::Open("tex_number"), _) => {
                let (t, at) = c.text_element("tex_number")?;
                current = Some(parse_num::<i64>(c, at, t, "tex_number")?);
            }
            (Tok::Open("tex_name"), at) => {
                let (t, _) = c.text_element("tex_name")?;
                let id = current.ok_or_else(|| c.err(at, "<tex_name> before any <tex_number>"))?;
                f.textures.insert(id, t.trim().to_string());
            }
            (Tok::Open(n), _) => c.skip_element(n)?,
            (t, at) => return Err(c.unexpected(at, &t, "<tex_number>, <tex_name> or </Textures>")),
        }
    }
}

fn read_colors(c: &mut Cursor, f: &mut TxfFile) -> Result<(), ParseError> {
    let mut current: Option<i64> = None;
    loop {
        let (tok, at) = c.next()?;
        let field = match tok {
            Tok::Close("Colors") => return Ok(()),
            Tok::Open("col_number") => {
                let (t, at) = c.text_element("col_number")?;
                let id = parse_num(c, at, t, "col_number")?;
                f.colors.entry(id).or_insert_with(|| Color {
                    name: format!("material {id}"),
                    material: Material::default(),
                });
                current = Some(id);
                continue;
            }
            Tok::Open(n @ ("col_name" | "diff" | "ambi" | "spec" | "emis" | "shin")) => n,
            Tok::Open(n) => {
                c.skip_element(n)?;
                continue;
            }
            t => return Err(c.unexpected(at, &t, "a material field or </Colors>")),
        };
        let (text, vat) = c.text_element(field)?;
        let id = current.ok_or_else(|| c.err(at, format!("<{field}> before any <col_number>")))?;
        let col = f.colors.get_mut(&id).expect("inserted at col_number");
        let m = &mut col.material;
        match field {
            "col_name" => col.name = text.trim().to_string(),
            "diff" => m.diffuse = parse_floats(c, vat, text, field, Some(1.0))?,
            "ambi" => m.ambient = parse_floats(c, vat, text, field, Some(1.0))?,
            "spec" => m.specular = parse_floats(c, vat, text, field, Some(1.0))?,
            "emis" => m.emission = parse_floats(c, vat, text, field, Some(1.0))?,
            _ => m.shininess = parse_floats::<1>(c, vat, text, field, None)?[0],
        }
    }
}

fn read_set(c: &mut Cursor, offset: usize) -> Result<SetData, ParseError> {
    let mut set = SetData {
        offset,
        ..SetData::default()
    };
    loop {
        match c.next()? {
            (Tok::Close("Set"), _) => return Ok(set),
            (Tok::Open("set_number"), _) => {
                let (t, at) = c.text_element("set_number")?;
                set.number = Some(parse_num(c, at, t, "set_number")?);
            }
            (Tok::Open("header"), _) => read_set_header(c, &mut set)?,
            (Tok::Open("vertex_array"), _) => read_vertex_array(c, &mut set)?,
            (Tok::Open(n @ ("line_array" | "point_array")), _) => read_lod_array(c, n)?,
            (Tok::Open(n), _) => c.skip_element(n)?, // references and anything unknown
            (t, at) => return Err(c.unexpected(at, &t, "a set element or </Set>")),
        }
    }
}

fn read_set_header(c: &mut Cursor, set: &mut SetData) -> Result<(), ParseError> {
    loop {
        match c.next()? {
            (Tok::Close("header"), _) => return Ok(()),
            (Tok::Open("tc_combo"), _) => {
                let (t, at) = c.text_element("tc_combo")?;
                let ids: Vec<i64> = t
                    .split_whitespace()
                    .map(|s| s.parse().ok())
                    .collect::<Option<_>>()
                    .filter(|v: &Vec<i64>| v.len() == 2)
                    .ok_or_else(|| {
                        c.err(
                            at,
                            format!("<tc_combo>: expected two ids (texture material), found {t:?}"),
                        )
                    })?;
                (set.tex, set.mat) = (Some(ids[0]), Some(ids[1]));
            }
            (Tok::Open("translucence"), _) => {
                let (t, at) = c.text_element("translucence")?;
                set.translucence = Some(parse_floats::<1>(c, at, t, "translucence", None)?[0]);
            }
            (Tok::Open(n), _) => c.skip_element(n)?,
            (t, at) => return Err(c.unexpected(at, &t, "a header field or </header>")),
        }
    }
}

/// A count from a header element (`<name> N </name>`).
fn read_count(c: &mut Cursor, name: &str) -> Result<u64, ParseError> {
    let (t, at) = c.text_element(name)?;
    parse_num(c, at, t, name)
}

/// Reads `<header>` of a geometry array, returning the sum of the counts named in `fields`.
fn read_array_header(c: &mut Cursor, fields: &[&str]) -> Result<u64, ParseError> {
    let mut total: u64 = 0;
    loop {
        match c.next()? {
            (Tok::Close("header"), _) => return Ok(total),
            (Tok::Open(n), at) if fields.contains(&n) => {
                total = total
                    .checked_add(read_count(c, n)?)
                    .ok_or_else(|| c.err(at, "vertex counts overflow"))?;
            }
            (Tok::Open(n), _) => c.skip_element(n)?,
            (t, at) => return Err(c.unexpected(at, &t, "a count or </header>")),
        }
    }
}

fn bytes_for(count: u64, size: usize) -> Option<usize> {
    usize::try_from(count).ok()?.checked_mul(size)
}

/// How plausible a vertex payload is: per vertex, one point each for normal (not subnormal), bounded values,
/// a zero third texcoord and a unit (or zero) normal. A payload read one byte off scores low.
fn vertex_score(p: &[u8]) -> usize {
    p.chunks_exact(VERTEX_BYTES)
        .map(|v| {
            let f = |k: usize| f32::from_le_bytes(v[4 * k..4 * k + 4].try_into().unwrap());
            // Subnormals: what round floats (zero low bytes) look like when read a byte off.
            let sane = |x: f32| x == 0.0 || (x.is_normal() && x.abs() < 1e9);
            let bounded = (0..9).all(|k| sane(f(k)));
            let n2 = f(3) * f(3) + f(4) * f(4) + f(5) * f(5);
            let unit = (3..6).all(|k| f(k) == 0.0) || (0.25..=2.25).contains(&n2);
            bounded as usize + (f(2) == 0.0) as usize + unit as usize
        })
        .sum()
}

/// Indices below `n`: how plausible an index payload is.
fn index_score(n: usize) -> impl Fn(&[u8]) -> usize {
    move |p| {
        p.chunks_exact(4)
            .filter(|i| (u32::from_le_bytes((*i).try_into().unwrap()) as usize) < n)
            .count()
    }
}

/// After `<index>`: `<number_of_index_values>` and the binary indices, then `</index>`.
fn read_index_block<'a>(
    c: &mut Cursor<'a>,
    what: &str,
    vertices: usize,
) -> Result<(&'a [u8], usize), ParseError> {
    match c.next()? {
        (Tok::Open("number_of_index_values"), _) => {}
        (t, at) => return Err(c.unexpected(at, &t, "<number_of_index_values>")),
    }
    let (t, at) = c.text_element("number_of_index_values")?;
    let count: u64 = parse_num(c, at, t, "number_of_index_values")?;
    let bytes = c.payload(
        bytes_for(count, 4),
        &format!("{what} index payload of {count} indices"),
        "index",
        index_score(vertices),
    )?;
    c.expect_close("index")?;
    Ok((bytes, at))
}

fn read_vertex_array(c: &mut Cursor, set: &mut SetData) -> Result<(), ParseError> {
    let base = set.vertices.len();
    let mut count: Option<u64> = None;
    loop {
        match c.next()? {
            (Tok::Close("vertex_array"), _) => return Ok(()),
            (Tok::Open("header"), _) => {
                count = Some(read_array_header(c, &["number_of_vertices"])?)
            }
            (Tok::Open("data"), at) => {
                let n = count.ok_or_else(|| c.err(at, "<data> before number_of_vertices"))?;
                let start = c.pos;
                let p = c.payload(
                    bytes_for(n, VERTEX_BYTES),
                    &format!("vertex payload of {n} vertices"),
                    "data",
                    vertex_score,
                )?;
                let offset = c.pos - p.len();
                debug_assert!(offset >= start);
                set.vertices.extend(decode_vertices(p, offset)?);
                c.expect_close("data")?;
            }
            (Tok::Open("index"), _) => {
                let n = set.vertices.len() - base;
                let (p, at) = read_index_block(c, "vertex_array", n)?;
                set.triangles
                    .extend(decode_triangles(c, p, at, n, base, set.number)?);
            }
            (Tok::Open(n), _) => c.skip_element(n)?,
            (t, at) => {
                return Err(c.unexpected(at, &t, "<header>, <data>, <index> or </vertex_array>"));
            }
        }
    }
}

/// Reads a `line_array` or `point_array` (LOD data) and drops it.
fn read_lod_array(c: &mut Cursor, name: &str) -> Result<(), ParseError> {
    let fields: &[&str] = if name == "line_array" {
        &["number_of_line_vertices"]
    } else {
        &[
            "number_of_subpoints",
            "number_of_regpoints",
            "number_of_suppoints",
        ]
    };
    let mut count: Option<u64> = None;
    loop {
        match c.next()? {
            (Tok::Close(n), _) if n == name => return Ok(()),
            (Tok::Open("header"), _) => count = Some(read_array_header(c, fields)?),
            (Tok::Open("data"), at) => {
                let n = count.ok_or_else(|| {
                    c.err(at, format!("<data> of {name} before its vertex count"))
                })?;
                c.payload(
                    bytes_for(n, VERTEX_BYTES),
                    &format!("{name} payload of {n} vertices"),
                    "data",
                    vertex_score,
                )?;
                c.expect_close("data")?;
            }
            (Tok::Open("index"), _) => {
                let n = count.unwrap_or(0) as usize;
                let (p, at) = read_index_block(c, name, n)?;
                if !p.len().is_multiple_of(8) {
                    return Err(c.err(
                        at,
                        format!("{name}: {} indices do not form pairs", p.len() / 4),
                    ));
                }
            }
            (Tok::Open(n), _) => c.skip_element(n)?,
            (t, at) => {
                return Err(c.unexpected(
                    at,
                    &t,
                    &format!("<header>, <data>, <index> or </{name}>"),
                ));
            }
        }
    }
}

fn decode_vertices(p: &[u8], offset: usize) -> Result<Vec<Vertex>, ParseError> {
    p.chunks_exact(VERTEX_BYTES)
        .enumerate()
        .map(|(k, v)| {
            let f = |i: usize| f32::from_le_bytes(v[4 * i..4 * i + 4].try_into().unwrap());
            let vert = Vertex {
                tc: [f(0), f(1)],
                normal: [f(3), f(4), f(5)],
                position: [f(6), f(7), f(8)],
            };
            if !vert.position.iter().chain(&vert.tc).all(|x| x.is_finite()) {
                return Err(ParseError::at_byte(
                    offset + k * VERTEX_BYTES,
                    format!("vertex {k}: position or texture coordinate is not finite"),
                ));
            }
            Ok(vert)
        })
        .collect()
}

fn decode_triangles(
    c: &Cursor,
    p: &[u8],
    at: usize,
    vertices: usize,
    base: usize,
    set: Option<i64>,
) -> Result<Vec<[u32; 3]>, ParseError> {
    let set_name = set.map_or("set (unnumbered)".into(), |n| format!("set {n}"));
    if !p.len().is_multiple_of(12) {
        return Err(c.err(
            at,
            format!(
                "{set_name}: {} indices are not a multiple of 3",
                p.len() / 4
            ),
        ));
    }
    let idx = |k: usize| u32::from_le_bytes(p[4 * k..4 * k + 4].try_into().unwrap());
    (0..p.len() / 12)
        .map(|t| {
            let tri = [idx(3 * t), idx(3 * t + 1), idx(3 * t + 2)];
            match tri.iter().find(|&&i| i as usize >= vertices) {
                Some(&i) => Err(c.err(
                    at,
                    format!("{set_name}: triangle {t} uses vertex {i}, but the set has {vertices}"),
                )),
                None => Ok(tri.map(|i| i + base as u32)),
            }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Mesh building

/// What makes a set's material distinct: material id, texture id, translucence bits.
type MaterialKey = (Option<i64>, Option<i64>, Option<u32>);

fn build_mesh(mut file: TxfFile) -> Result<Mesh, ParseError> {
    let mut mesh = Mesh {
        warnings: file.warnings.clone(),
        ..Mesh::default()
    };
    let mut materials: HashMap<MaterialKey, u32> = HashMap::new();
    let mut textures: HashMap<i64, u32> = HashMap::new();
    for mut set in std::mem::take(&mut file.sets) {
        let name = set
            .number
            .map_or(format!("set at byte {}", set.offset), |n| {
                format!("set {n}")
            });
        let key = (set.mat, set.tex, set.translucence.map(f32::to_bits));
        let m = match materials.get(&key) {
            Some(&m) => m,
            None => {
                let mat = set_material(&file, &set, &name, &mut textures, &mut mesh);
                mesh.materials.push(mat);
                let m = mesh.materials.len() as u32 - 1;
                materials.insert(key, m);
                m
            }
        };
        let repaired = repair_normals(&mut set.vertices, &set.triangles);
        if repaired > 0 {
            mesh.warnings.push(format!(
                "{name}: {repaired} zero or invalid normals replaced by face normals"
            ));
        }
        fix_wrap_around(&mut set.vertices, &mut set.triangles);
        append_set(&mut mesh, &set, m);
        mesh.objects.push(name);
    }
    Ok(mesh)
}

/// The material of a set: its `<Colors>` entry (or the OpenGL default), texture and translucence.
fn set_material(
    file: &TxfFile,
    set: &SetData,
    name: &str,
    textures: &mut HashMap<i64, u32>,
    mesh: &mut Mesh,
) -> Material {
    let mut mat = match set.mat.and_then(|id| file.colors.get(&id)) {
        Some(col) => {
            let mut m = col.material.clone();
            m.name = col.name.clone();
            m
        }
        None => {
            let why = set.mat.map_or("no tc_combo".into(), |id| {
                format!("material {id} is not in <Colors>")
            });
            mesh.warnings
                .push(format!("{name}: {why}; using the OpenGL default material"));
            Material {
                name: "default".into(),
                ..Material::default()
            }
        }
    };
    mat.translucence = set.translucence;
    mat.color_map = match set.tex.filter(|&t| t >= 0) {
        None => None,
        Some(t) => match (textures.get(&t), file.textures.get(&t)) {
            (Some(&i), _) => Some(i),
            (None, Some(tex_name)) => {
                mesh.textures.push(TextureRef {
                    name: tex_name.clone(),
                    path: tex_name.into(),
                });
                let i = mesh.textures.len() as u32 - 1;
                textures.insert(t, i);
                Some(i)
            }
            (None, None) => {
                mesh.warnings.push(format!(
                    "{name}: texture {t} is not in <Textures>; untextured"
                ));
                None
            }
        },
    };
    if let Some(i) = mat.color_map {
        mat.name = format!("{} + {}", mat.name, mesh.textures[i as usize].name);
    }
    mat
}

fn append_set(mesh: &mut Mesh, set: &SetData, material: u32) {
    let base = mesh.positions.len() as u32;
    for v in &set.vertices {
        mesh.positions.push(v.position);
        mesh.normals.push(v.normal);
        mesh.uvs.push([v.tc[0], 1.0 - v.tc[1]]);
    }
    mesh.indices
        .extend(set.triangles.iter().map(|t| t.map(|i| i + base)));
    mesh.triangle_materials
        .extend(std::iter::repeat_n(material, set.triangles.len()));
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalized(v: [f32; 3]) -> Option<[f32; 3]> {
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (len.is_finite() && len > 1e-12).then(|| v.map(|x| x / len))
}

/// Normalises the normals; replaces zero or non-finite ones by the area-weighted normals of the
/// adjacent triangles (+Z when there are none). Returns how many were replaced.
fn repair_normals(vertices: &mut [Vertex], triangles: &[[u32; 3]]) -> usize {
    let bad: Vec<bool> = vertices
        .iter()
        .map(|v| normalized(v.normal).is_none())
        .collect();
    let count = bad.iter().filter(|&&b| b).count();
    if count > 0 {
        let mut acc = vec![[0.0f32; 3]; vertices.len()];
        for t in triangles {
            let [a, b, c] = t.map(|i| vertices[i as usize].position);
            let n = cross(sub(b, a), sub(c, a)); // length = 2 × area: area weighting
            for &i in t {
                let s = &mut acc[i as usize];
                (0..3).for_each(|k| s[k] += n[k]);
            }
        }
        for (i, v) in vertices.iter_mut().enumerate().filter(|(i, _)| bad[*i]) {
            v.normal = normalized(acc[i]).unwrap_or([0.0, 0.0, 1.0]);
        }
    }
    for v in vertices.iter_mut() {
        v.normal = normalized(v.normal).unwrap_or(v.normal);
    }
    count
}

/// u span of a triangle.
fn u_span(us: [f32; 3]) -> f32 {
    us.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
        - us.iter().fold(f32::INFINITY, |a, &b| a.min(b))
}

/// The u values after adding 1 to the low ones (u < u_max − 0.5).
fn shifted(us: [f32; 3]) -> [f32; 3] {
    let max = us.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    us.map(|u| if u < max - 0.5 { u + 1.0 } else { u })
}

/// The texture-coordinate wrap-around fix (see the module doc). Returns the triangles fixed.
fn fix_wrap_around(vertices: &mut Vec<Vertex>, triangles: &mut [[u32; 3]]) -> usize {
    let us = |t: &[u32; 3], v: &[Vertex]| t.map(|i| v[i as usize].tc[0]);
    let spans: Vec<f32> = triangles.iter().map(|t| u_span(us(t, vertices))).collect();
    let candidate: Vec<bool> = triangles
        .iter()
        .zip(&spans)
        .map(|(t, &s)| s > 0.5 && u_span(shifted(us(t, vertices))) <= 0.5)
        .collect();
    if !candidate.iter().any(|&c| c) {
        return 0;
    }
    // Triangles around each vertex (only the narrow ones matter).
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); vertices.len()];
    for (ti, t) in triangles
        .iter()
        .enumerate()
        .filter(|(ti, _)| !candidate[*ti])
    {
        for &i in t {
            around[i as usize].push(ti as u32);
        }
    }
    let fix: Vec<usize> = (0..triangles.len())
        .filter(|&ti| candidate[ti])
        .filter(|&ti| {
            let mut near: Vec<f32> = triangles[ti]
                .iter()
                .flat_map(|&i| around[i as usize].iter().map(|&n| spans[n as usize]))
                .collect();
            if near.is_empty() {
                return false;
            }
            near.sort_by(f32::total_cmp);
            let median = near[near.len() / 2];
            let after = u_span(shifted(us(&triangles[ti], vertices)));
            (after - median).abs() < (spans[ti] - median).abs()
        })
        .collect();
    let mut duplicate: HashMap<u32, u32> = HashMap::new();
    for &ti in &fix {
        let tri = triangles[ti];
        let max = tri
            .iter()
            .map(|&i| vertices[i as usize].tc[0])
            .fold(f32::NEG_INFINITY, f32::max);
        for slot in 0..3 {
            let i = tri[slot];
            if vertices[i as usize].tc[0] < max - 0.5 {
                let d = *duplicate.entry(i).or_insert_with(|| {
                    let mut v = vertices[i as usize];
                    v.tc[0] += 1.0;
                    vertices.push(v);
                    vertices.len() as u32 - 1
                });
                triangles[ti][slot] = d;
            }
        }
    }
    fix.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One binary vertex written by hand: texcoord (s, t, 0), normal, position.
    fn vtx(st: [f32; 2], n: [f32; 3], p: [f32; 3]) -> Vec<u8> {
        [st[0], st[1], 0.0, n[0], n[1], n[2], p[0], p[1], p[2]]
            .iter()
            .flat_map(|f| f.to_le_bytes())
            .collect()
    }

    fn idx(ix: &[u32]) -> Vec<u8> {
        ix.iter().flat_map(|i| i.to_le_bytes()).collect()
    }

    /// Where a payload goes: right after its tag (`tight`) or after the tag's 0x0A.
    fn set_bytes(tc: &str, verts: &[Vec<u8>], ix: &[u32], tight: bool) -> Vec<u8> {
        let nl: &[u8] = if tight { b"" } else { b"\n" };
        let mut b = Vec::new();
        b.extend(format!("<Set>\n<set_number> 7 </set_number>\n<header>\n<tc_combo> {tc} </tc_combo>\n<importance> 1.0 </importance>\n<translucence> 0.25 </translucence>\n<p_min> 0 0 0 </p_min>\n</header>\n<references>\n<header>\n<number_of_references> 0 </number_of_references>\n</header>\n</references>\n").bytes());
        b.extend(format!("<vertex_array>\n<header>\n<number_of_vertices> {} </number_of_vertices>\n</header>\n<data>", verts.len()).bytes());
        b.extend(nl);
        verts.iter().for_each(|v| b.extend(v));
        b.extend(
            format!(
                "\n</data>\n<index>\n<number_of_index_values> {} </number_of_index_values>",
                ix.len()
            )
            .bytes(),
        );
        b.extend(nl);
        b.extend(idx(ix));
        b.extend(b"\n</index>\n</vertex_array>\n");
        // LOD arrays: 2 line vertices with one pair, 1 + 0 + 2 points.
        b.extend(b"<line_array>\n<header>\n<number_of_line_vertices> 2 </number_of_line_vertices>\n</header>\n<data>");
        b.extend(nl);
        b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [9.0, 9.0, 9.0]));
        b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [9.0, 9.0, 8.0]));
        b.extend(b"</data>\n<index>\n<number_of_index_values> 2 </number_of_index_values>");
        b.extend(nl);
        b.extend(idx(&[0, 1]));
        b.extend(b"</index>\n</line_array>\n");
        b.extend(b"<point_array>\n<header>\n<number_of_subpoints> 1 </number_of_subpoints>\n<number_of_regpoints> 0 </number_of_regpoints>\n<number_of_suppoints> 2 </number_of_suppoints>\n</header>\n<data>");
        b.extend(nl);
        for z in 0..3 {
            b.extend(vtx([0.0, 0.0], [0.0, 0.0, 1.0], [5.0, 5.0, z as f32]));
        }
        b.extend(b"\n</data>\n</point_array>\n</Set>\n");
        b
    }

    const HEAD: &str = "<?txf_version='0.91'?>\n<Textures>\n<tex_number>0</tex_number><tex_name>bark.png</tex_name>\n<tex_number>3</tex_number><tex_name>leaf.rgb</tex_name>\n</Textures>\n<Colors>\n<col_number> 0 </col_number> <col_name> Default </col_name>\n<diff> 0.70 0.70 0.70 1.00 </diff>\n<ambi> 0.10 0.10 0.10 1.00 </ambi>\n<spec> 0.00 0.00 0.00 1.00 </spec>\n<emis> 0.00 0.00 0.00 1.00 </emis>\n<shin> 0.00 </shin>\n<col_number> 5 </col_number> <col_name> Leaf </col_name>\n<diff> 0.1 0.5 0.2 0.9 </diff>\n<shin> 12.5 </shin>\n<col_number> 0 </col_number>\n<spec> 0.3 0.3 0.3 1 </spec>\n</Colors>\n<Infos>\n<author> someone </author>\n</Infos>\n";

    fn quad() -> Vec<Vec<u8>> {
        vec![
            vtx([0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.0]),
            vtx([1.0, 0.0], [0.0, -2.0, 0.0], [0.5, 0.0, 0.0]),
            vtx([1.0, 1.0], [0.0, -1.0, 0.0], [0.5, 0.0, 1.0]),
            vtx([0.0, 0.75], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]),
        ]
    }

    fn tiny(tight: bool) -> Vec<u8> {
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 0, 2, 3], tight));
        b
    }

    #[test]
    fn parses_a_tiny_file_value_by_value() {
        let m = parse(&tiny(true)).unwrap();
        assert_eq!(m.validate(), Ok(()));
        assert_eq!(
            m.positions,
            vec![
                [0.0, 0.0, 0.0],
                [0.5, 0.0, 0.0],
                [0.5, 0.0, 1.0],
                [0.0, 0.0, 1.0]
            ]
        );
        // Normals normalised; v = 1 − t.
        assert_eq!(m.normals, vec![[0.0, -1.0, 0.0]; 4]);
        assert_eq!(m.uvs, vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.25]]);
        assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.triangle_materials, vec![0, 0]);
        assert_eq!(m.objects, vec!["set 7".to_string()]);
        // tc_combo 3 5: texture 3 (leaf.rgb), material 5 (Leaf); only used textures are kept.
        assert_eq!(
            m.textures,
            vec![TextureRef {
                name: "leaf.rgb".into(),
                path: "leaf.rgb".into()
            }]
        );
        let mat = &m.materials[0];
        assert_eq!(mat.diffuse, [0.1, 0.5, 0.2, 0.9]);
        assert_eq!(mat.shininess, 12.5);
        assert_eq!(mat.ambient, Material::default().ambient); // not given: OpenGL default
        assert_eq!(mat.translucence, Some(0.25));
        assert_eq!(mat.color_map, Some(0));
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    }

    #[test]
    fn col_number_is_a_state_that_later_lines_refer_to() {
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("0 0", &quad(), &[0, 1, 2], true));
        let m = parse(&b).unwrap();
        let mat = &m.materials[0];
        // Material 0 was reopened after material 5: its spec changed, the rest stayed.
        assert_eq!(mat.diffuse, [0.7, 0.7, 0.7, 1.0]);
        assert_eq!(mat.ambient, [0.1, 0.1, 0.1, 1.0]);
        assert_eq!(mat.specular, [0.3, 0.3, 0.3, 1.0]);
        assert_eq!(mat.name, "Default + bark.png");
        assert_eq!(m.textures[0].name, "bark.png");
    }

    /// A TXF written like seed 000 3.1.1's listing (its `<Colors>` block verbatim, a set header
    /// with Xfrog's `translucence 0.000000`) maps to Table 3.1's leaf defaults.
    #[test]
    fn the_seeds_xfrog_default_maps_to_the_leaf_defaults() {
        use crate::material::convert::material_to_schlick;
        use crate::material::schlick::NormalMap;
        let head = "<?txf_version='0.91'?>\n<Textures>\n<tex_number>0</tex_number><tex_name>beispiel.rgb</tex_name>\n</Textures>\n<Colors>\n<col_number> 0 </col_number> <col_name> Default </col_name>\n<diff> 0.70 0.70 0.70 1.00 </diff>\n<ambi> 0.10 0.10 0.10 1.00 </ambi>\n<spec> 0.00 0.00 0.00 1.00 </spec>\n<emis> 0.00 0.00 0.00 1.00 </emis>\n<shin> 0.00 </shin>\n</Colors>\n<Infos>\n</Infos>\n";
        // The set header (text, before any binary payload) with Xfrog's unset translucence.
        let set = |tc: &str, ix: &[u32]| {
            let b = set_bytes(tc, &quad(), ix, false);
            let at = b.windows(5).position(|w| w == b"0.25 ").unwrap();
            [&b[..at], b"0.000000 ".as_slice(), &b[at + 5..]].concat()
        };
        let mut b = head.as_bytes().to_vec();
        b.extend(set("0 0", &[0, 1, 2]));
        b.extend(set("-1 0", &[0, 2, 3]));
        let m = parse(&b).unwrap();
        assert!(m.warnings.is_empty(), "{:?}", m.warnings);
        assert_eq!(m.materials.len(), 2, "{:?}", m.materials);
        let textured = m.materials.iter().find(|x| x.color_map.is_some()).unwrap();
        let s = material_to_schlick(textured);
        let [top, bottom] = s.layers;
        assert_eq!(
            (
                top.roughness,
                top.isotropy,
                top.diffuse,
                top.glossy,
                top.specular
            ),
            (0.1, 1.0, 0.0, 1.0, 0.0)
        );
        assert_eq!(top.color, [0.075; 3]);
        assert_eq!(
            (bottom.diffuse, bottom.glossy, bottom.specular),
            (1.0, 0.0, 0.0)
        );
        assert_eq!(bottom.color, [1.0; 3]);
        assert_eq!((s.bump_height, s.translucence), (0.001, 0.3));
        assert!(matches!(s.normal_map, NormalMap::FromColor(_)));
        // The untextured set: the stem rule on top (Xfrog's 0.7 grey, the set's τ of 0).
        let untextured = m.materials.iter().find(|x| x.color_map.is_none()).unwrap();
        let s = material_to_schlick(untextured);
        assert_eq!(s.layers[0], top);
        assert_eq!(s.layers[1].color, [0.7; 3]);
        assert_eq!((s.bump_height, s.translucence), (0.0, 0.0));
    }

    #[test]
    fn both_payload_placements_and_indentation_agree() {
        let tight = parse(&tiny(true)).unwrap();
        assert_eq!(parse(&tiny(false)).unwrap(), tight);
        // The thesis layout: indentation and blank lines around tags.
        let text = String::from_utf8(tiny(true)[..HEAD.len()].to_vec()).unwrap();
        let indented = text.replace("<", "\n   <").replacen("\n   <?", "<?", 1);
        let mut b = indented.into_bytes();
        b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 0, 2, 3], true));
        assert_eq!(parse(&b).unwrap(), tight);
    }

    #[test]
    fn payload_starting_with_a_newline_byte_is_placed_by_plausibility() {
        // u's first little-endian byte is 0x0A, and the payload is followed by "\n</data>":
        // both placements close properly; the content decides.
        let u = f32::from_bits(0x3E4C_CC0A);
        assert_eq!(u.to_le_bytes()[0], b'\n');
        let verts = vec![
            vtx([u, 0.5], [0.0, 0.0, 1.0], [1.0, 2.0, 3.0]),
            vtx([0.5, 0.5], [0.0, 0.0, 1.0], [4.0, 5.0, 6.0]),
            vtx([0.5, 1.0], [0.0, 0.0, 1.0], [7.0, 8.0, 9.0]),
        ];
        for tight in [true, false] {
            let mut b = HEAD.as_bytes().to_vec();
            b.extend(set_bytes("3 5", &verts, &[10 - 10, 1, 2], tight));
            let m = parse(&b).unwrap();
            assert_eq!(m.uvs[0], [u, 0.5], "tight={tight}");
            assert_eq!(m.positions[2], [7.0, 8.0, 9.0]);
        }
    }

    /// A closed ring of 5 segments: u = 0.0, 0.2, … 0.8, the closing quad reuses the u = 0
    /// vertices (bottom 0..5, top 5..10).
    fn ring() -> (Vec<Vec<u8>>, Vec<u32>) {
        let mut verts = Vec::new();
        for z in [0.0f32, 1.0] {
            for k in 0..5 {
                let a = k as f32 * std::f32::consts::TAU / 5.0;
                let n = [a.cos(), a.sin(), 0.0];
                verts.push(vtx(
                    [k as f32 * 0.2, z],
                    n,
                    [0.1 * a.cos(), 0.1 * a.sin(), z],
                ));
            }
        }
        let mut ix = Vec::new();
        for k in 0..5u32 {
            let k1 = (k + 1) % 5;
            ix.extend([k, k1, 5 + k1, k, 5 + k1, 5 + k]);
        }
        (verts, ix)
    }

    #[test]
    fn wrap_around_duplicates_the_start_vertices() {
        let (verts, ix) = ring();
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("0 0", &verts, &ix, true));
        let m = parse(&b).unwrap();
        assert_eq!(m.validate(), Ok(()));
        assert_eq!(
            m.positions.len(),
            12,
            "two duplicates (bottom and top start vertex)"
        );
        assert_eq!(m.indices.len(), 10);
        // The shared start vertices keep u = 0 and are still used by the first segment.
        assert_eq!(m.uvs[0][0], 0.0);
        assert_eq!(m.uvs[5][0], 0.0);
        assert_eq!(&m.indices[0..2], &[[0, 1, 6], [0, 6, 5]]);
        // The closing segment (k = 4): 4, 0→dup, 5→dup ; 4, 5→dup, 9.
        let (d0, d5) = (10u32, 11u32);
        assert_eq!(&m.indices[8..10], &[[4, d0, d5], [4, d5, 9]]);
        assert_eq!(m.uvs[d0 as usize], [1.0, 1.0]);
        assert_eq!(m.uvs[d5 as usize], [1.0, 0.0]);
        assert_eq!(m.positions[d0 as usize], m.positions[0]);
        assert_eq!(m.normals[d5 as usize], m.normals[5]);
        // Every triangle now spans u = 0.2.
        for t in &m.indices {
            let us = t.map(|i| m.uvs[i as usize][0]);
            assert!((u_span(us) - 0.2).abs() < 1e-6, "{us:?}");
        }
    }

    #[test]
    fn leaf_quads_spanning_the_texture_are_not_wrapped() {
        // Two triangles spanning u 0..1, and a fan around a centre with margins 0.05/0.95.
        let fan = vec![
            vtx([0.05, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
            vtx([0.95, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
            vtx([0.95, 1.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]),
            vtx([0.05, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            vtx([0.5, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0]),
        ];
        for (verts, ix) in [
            (quad(), vec![0, 1, 2, 0, 2, 3]),
            (fan.clone(), vec![0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4]),
            (fan, vec![0, 1, 2, 0, 2, 3]),
        ] {
            let mut b = HEAD.as_bytes().to_vec();
            b.extend(set_bytes("3 5", &verts, &ix, true));
            let m = parse(&b).unwrap();
            assert_eq!(m.positions.len(), verts.len());
        }
    }

    #[test]
    fn zero_normals_become_face_normals_with_a_warning() {
        let verts = vec![
            vtx([0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            vtx([0.0, 0.0], [f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0]),
            vtx([0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 1.0, 0.0]),
        ];
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &verts, &[0, 1, 2], true));
        let m = parse(&b).unwrap();
        assert_eq!(m.normals, vec![[0.0, 0.0, 1.0]; 3]);
        assert_eq!(m.warnings.len(), 1);
        assert!(
            m.warnings[0].contains("2 zero or invalid normals"),
            "{:?}",
            m.warnings
        );
    }

    fn err_of(b: &[u8]) -> ParseError {
        parse(b).expect_err("must fail")
    }

    #[test]
    fn bad_inputs_name_the_place() {
        let e = err_of(b"<Textures>\n</Textures>\n");
        assert_eq!(e.place, "line 1");
        // Index out of range names the set.
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &quad(), &[0, 1, 4], true));
        let e = err_of(&b);
        assert!(
            e.message.contains("set 7") && e.message.contains("vertex 4"),
            "{e}"
        );
        // Not a multiple of 3.
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &quad(), &[0, 1, 2, 3], true));
        assert!(err_of(&b).message.contains("multiple of 3"));
        // A bad number in the text, on its line.
        let text = HEAD.replace("<shin> 12.5 </shin>", "<shin> twelve </shin>");
        let e = err_of(text.as_bytes());
        assert_eq!(e.place, "line 15", "{e}");
        // Unterminated tag; stray closing tag; binary where text is expected.
        assert!(
            err_of(b"<?txf_version='0.91'?>\n<Set\n")
                .message
                .contains("unterminated")
        );
        assert!(
            err_of(b"<?txf_version='0.91'?>\n</Set>\n")
                .message
                .contains("expected a block")
        );
        assert!(
            err_of(b"<?txf_version='0.91'?>\n\xff\xfe\n")
                .message
                .contains("binary")
        );
    }

    /// Replaces the first `from` in binary-laden bytes.
    fn replace_once(b: &[u8], from: &str, to: &str) -> Vec<u8> {
        let at = b
            .windows(from.len())
            .position(|w| w == from.as_bytes())
            .expect("pattern present");
        [&b[..at], to.as_bytes(), &b[at + from.len()..]].concat()
    }

    #[test]
    fn huge_counts_fail_before_allocating() {
        let mut b = HEAD.as_bytes().to_vec();
        b.extend(set_bytes("3 5", &quad(), &[0, 1, 2], true));
        let tag = "<number_of_vertices> 4 ";
        for n in ["4000000000", "18446744073709551615"] {
            let e = err_of(&replace_once(
                &b,
                tag,
                &format!("<number_of_vertices> {n} "),
            ));
            assert!(
                e.place.starts_with("byte ") && e.message.contains("only"),
                "{n}: {e}"
            );
        }
        let e = err_of(&replace_once(
            &b,
            tag,
            "<number_of_vertices> 99999999999999999999999 ",
        ));
        assert!(e.message.contains("expected a number"), "{e}");
        // The same for indices: 10^9 indices need 4·10^9 bytes.
        let e = err_of(&replace_once(
            &b,
            "<number_of_index_values> 3 ",
            "<number_of_index_values> 1000000000 ",
        ));
        assert!(e.message.contains("needs 4000000000 bytes"), "{e}");
        // Point counts that overflow when summed.
        let e = err_of(&replace_once(
            &b,
            "<number_of_subpoints> 1 ",
            "<number_of_subpoints> 18446744073709551615 ",
        ));
        assert!(e.message.contains("overflow"), "{e}");
    }

    #[test]
    fn every_truncation_is_an_error_not_a_panic() {
        let b = tiny(false);
        let find = |p: &[u8]| b.windows(p.len()).position(|w| w == p).unwrap();
        let (set_start, set_end) = (find(b"<Set>"), find(b"</Set>") + 6);
        for n in 0..b.len() {
            // A prefix that ends between blocks is a valid (smaller) file; any cut inside
            // the set must fail.
            if let Ok(m) = parse(&b[..n]) {
                assert!(n <= set_start || n >= set_end, "cut at {n} parsed");
                assert!(m.indices.is_empty() || n >= set_end);
            }
        }
        // Garbled bytes: an error, or a mesh that satisfies the model's invariants.
        for at in 0..b.len() {
            for x in [0x5a, 0x01, 0x80] {
                let mut g = b.clone();
                g[at] ^= x;
                if let Ok(m) = parse(&g) {
                    assert_eq!(m.validate(), Ok(()), "flip {x:#x} at {at}");
                }
            }
        }
    }
}
