//! The blocks: `<Textures>`, `<Colors>` and the sets with their binary vertex, index and LOD
//! arrays, read into a [`TxfFile`].

use super::*;

/// A material from `<Colors>`.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Color {
    pub(super) name: String,
    pub(super) material: Material,
}

/// One binary vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Vertex {
    pub(super) tc: [f32; 2],
    pub(super) normal: [f32; 3],
    pub(super) position: [f32; 3],
}

#[derive(Debug, Default)]
pub(super) struct SetData {
    pub(super) number: Option<i64>,
    /// Byte offset of `<Set>`, to name unnumbered sets.
    pub(super) offset: usize,
    pub(super) tex: Option<i64>,
    pub(super) mat: Option<i64>,
    pub(super) translucence: Option<f32>,
    pub(super) vertices: Vec<Vertex>,
    pub(super) triangles: Vec<[u32; 3]>,
    /// Segments of the set's `<line_array>`s and points of its `<point_array>`s.
    pub(super) lines: Vec<[[f32; 3]; 2]>,
    pub(super) points: Vec<[f32; 3]>,
}

#[derive(Debug, Default)]
pub(super) struct TxfFile {
    pub(super) textures: HashMap<i64, String>,
    pub(super) colors: HashMap<i64, Color>,
    pub(super) sets: Vec<SetData>,
    pub(super) warnings: Vec<String>,
}

pub(super) fn read_version(c: &mut Cursor, warnings: &mut Vec<String>) -> Result<(), ParseError> {
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

pub(super) fn parse_num<T: std::str::FromStr>(
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
pub(super) fn parse_floats<const N: usize>(
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

pub(super) fn read_textures(c: &mut Cursor, f: &mut TxfFile) -> Result<(), ParseError> {
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

pub(super) fn read_colors(c: &mut Cursor, f: &mut TxfFile) -> Result<(), ParseError> {
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

pub(super) fn read_set(c: &mut Cursor, offset: usize) -> Result<SetData, ParseError> {
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
            (Tok::Open(n @ ("line_array" | "point_array")), _) => read_lod_array(c, n, &mut set)?,
            (Tok::Open(n), _) => c.skip_element(n)?, // references and anything unknown
            (t, at) => return Err(c.unexpected(at, &t, "a set element or </Set>")),
        }
    }
}

pub(super) fn read_set_header(c: &mut Cursor, set: &mut SetData) -> Result<(), ParseError> {
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
pub(super) fn read_count(c: &mut Cursor, name: &str) -> Result<u64, ParseError> {
    let (t, at) = c.text_element(name)?;
    parse_num(c, at, t, name)
}

/// Reads `<header>` of a geometry array, returning the sum of the counts named in `fields`.
pub(super) fn read_array_header(c: &mut Cursor, fields: &[&str]) -> Result<u64, ParseError> {
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

pub(super) fn bytes_for(count: u64, size: usize) -> Option<usize> {
    usize::try_from(count).ok()?.checked_mul(size)
}

/// How plausible a vertex payload is: per vertex, one point each for normal (not subnormal), bounded values,
/// a zero third texcoord and a unit (or zero) normal. A payload read one byte off scores low.
pub(super) fn vertex_score(p: &[u8]) -> usize {
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
pub(super) fn index_score(n: usize) -> impl Fn(&[u8]) -> usize {
    move |p| {
        p.chunks_exact(4)
            .filter(|i| (u32::from_le_bytes((*i).try_into().unwrap()) as usize) < n)
            .count()
    }
}

/// After `<index>`: `<number_of_index_values>` and the binary indices, then `</index>`.
pub(super) fn read_index_block<'a>(
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

pub(super) fn read_vertex_array(c: &mut Cursor, set: &mut SetData) -> Result<(), ParseError> {
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

/// Reads a `line_array` or `point_array` (Xfrog's LOD data) into the set: the line array's
/// vertices joined by its index pairs as segments, the point array's vertices as points
/// (positions only, model space, as the triangles' vertices).
pub(super) fn read_lod_array(
    c: &mut Cursor,
    name: &str,
    set: &mut SetData,
) -> Result<(), ParseError> {
    let lines = name == "line_array";
    let fields: &[&str] = if lines {
        &["number_of_line_vertices"]
    } else {
        &[
            "number_of_subpoints",
            "number_of_regpoints",
            "number_of_suppoints",
        ]
    };
    let mut count: Option<u64> = None;
    let mut vertices: Vec<[f32; 3]> = Vec::new();
    loop {
        match c.next()? {
            (Tok::Close(n), _) if n == name => {
                if !lines {
                    set.points.extend(vertices);
                }
                return Ok(());
            }
            (Tok::Open("header"), _) => count = Some(read_array_header(c, fields)?),
            (Tok::Open("data"), at) => {
                let n = count.ok_or_else(|| {
                    c.err(at, format!("<data> of {name} before its vertex count"))
                })?;
                let p = c.payload(
                    bytes_for(n, VERTEX_BYTES),
                    &format!("{name} payload of {n} vertices"),
                    "data",
                    vertex_score,
                )?;
                let offset = c.pos - p.len();
                vertices.extend(decode_vertices(p, offset)?.iter().map(|v| v.position));
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
                let idx = |k: usize| u32::from_le_bytes(p[4 * k..4 * k + 4].try_into().unwrap());
                for k in 0..p.len() / 8 {
                    let (a, b) = (idx(2 * k) as usize, idx(2 * k + 1) as usize);
                    match (vertices.get(a), vertices.get(b)) {
                        (Some(&pa), Some(&pb)) if lines => set.lines.push([pa, pb]),
                        (Some(_), Some(_)) => {}
                        _ => {
                            return Err(c.err(
                                at,
                                format!(
                                    "{name}: segment {k} joins vertices {a} and {b}, \
                                     but the array has {} vertices",
                                    vertices.len()
                                ),
                            ));
                        }
                    }
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

pub(super) fn decode_vertices(p: &[u8], offset: usize) -> Result<Vec<Vertex>, ParseError> {
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

pub(super) fn decode_triangles(
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
