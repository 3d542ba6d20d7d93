//! Wavefront OBJ reader with MTL materials, through the `tobj` crate.
//!
//! Polygons are triangulated (as fans, by tobj) and vertices get a single index (position,
//! normal and texture coordinate together); points and lines are skipped. All objects and groups
//! are merged into one mesh; their names go to `mesh.objects`. Axes are kept as written: OBJ
//! has no up axis, and files made for bake are expected to be Z-up like TXF. Texture v is flipped
//! (OBJ has v = 0 at the bottom of the image, the model has it at the top). UTF-16 files with a
//! byte-order mark are converted to UTF-8 first.
//!
//! MTL → [`Material`]: `Kd`/`Ka`/`Ks` → diffuse/ambient/specular (alpha 1), `Ns` (0..1000) →
//! shininess clamped to OpenGL's 0..128, `d` → transparency = 1 − d (or `Tr` directly),
//! `map_Kd` → colour map, `map_Bump`/`bump`/`norm` → normal map (texture options such as
//! `-bm 1` before the file name are dropped). Faces without a known material get the OpenGL
//! default material. A missing or broken MTL file is a warning, not an error.
//!
//! Missing normals become face normals (vertices unshared per triangle); missing texture
//! coordinates become (0, 0) with a warning when a textured material uses them.

use crate::error::{Error, ParseError, Result};
use crate::model::{Material, Mesh, TextureRef};
use glam::Vec3;
use std::io::BufRead;
use std::path::{Path, PathBuf};

/// Reads an `.obj` file and the MTL files it names (relative to the OBJ's folder, which they
/// must not leave).
pub fn load(path: &Path) -> Result<Mesh> {
    load_in(path, &super::confine::Roots::around(path, &[]))
}

/// Reads an `.obj` file; its MTL libraries must lie inside `roots` (a library outside is
/// refused before it is opened).
pub fn load_in(path: &Path, roots: &super::confine::Roots) -> Result<Mesh> {
    let bytes = crate::error::read_file(path)?;
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let refused = std::cell::RefCell::new(None);
    let loader = |mtl: &Path| {
        let p = dir.join(mtl);
        if refused.borrow().is_none()
            && let Err(e) = roots.check(path, "MTL library", &mtl.to_string_lossy(), &p)
        {
            *refused.borrow_mut() = Some(e);
        }
        if refused.borrow().is_some() {
            return Err(tobj::LoadError::OpenFileFailed);
        }
        let bytes = std::fs::read(&p).map_err(|_| tobj::LoadError::OpenFileFailed)?;
        load_mtl(&bytes)
    };
    let parsed = parse_with(&bytes, loader).map_err(|e| Error::invalid(path, e));
    if let Some(e) = refused.into_inner() {
        return Err(e);
    }
    let mut mesh = parsed?;
    for t in &mut mesh.textures {
        t.path = super::max3ds::resolve_texture(&dir, &t.name);
    }
    Ok(mesh)
}

/// The names after `mtllib` in an OBJ file's text.
pub fn mtl_names(bytes: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(bytes);
    text.lines()
        .filter_map(|l| l.trim_start().strip_prefix("mtllib"))
        .flat_map(|rest| rest.split_whitespace().map(str::to_string))
        .collect()
}

/// Parses an OBJ held in memory; `mtllib` lines cannot be followed (no folder), so faces get
/// default materials.
pub fn parse(bytes: &[u8]) -> Result<Mesh, ParseError> {
    parse_with(bytes, |_| Err(tobj::LoadError::OpenFileFailed))
}

/// Parses an OBJ held in memory with `mtl` as the text of every MTL file it names (fuzzing,
/// tests).
pub fn parse_with_mtl(obj: &[u8], mtl: &[u8]) -> Result<Mesh, ParseError> {
    parse_with(obj, |_| load_mtl(mtl))
}

/// Reads MTL text through tobj, after the checks tobj lacks: `tobj` 4.0 panics (an `unwrap` in
/// `parse_float3`) on a colour line (`Ka`/`Kd`/`Ks`/`Ke`) with fewer than three numbers, so such
/// a file is refused here as a broken MTL (a warning, like any other broken MTL).
fn load_mtl(mtl: &[u8]) -> tobj::MTLLoadResult {
    let text = String::from_utf8_lossy(mtl);
    let short_colour = text.lines().any(|l| {
        let mut w = l.split_whitespace();
        matches!(w.next(), Some("Ka" | "Kd" | "Ks" | "Ke")) && w.count() < 3
    });
    if short_colour {
        return Err(tobj::LoadError::MaterialParseError);
    }
    tobj::load_mtl_buf(&mut std::io::BufReader::new(mtl))
}

fn parse_with(
    bytes: &[u8],
    loader: impl Fn(&Path) -> tobj::MTLLoadResult,
) -> Result<Mesh, ParseError> {
    let text = to_utf8(bytes);
    check_face_indices(&text)?;
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let mut reader = LineCounter {
        data: &text,
        pos: 0,
        line: 0,
    };
    let (models, materials) = tobj::load_obj_buf(&mut reader, &opts, loader).map_err(|e| {
        // The failing line has been consumed; without a final newline it is not counted yet.
        let line = reader.line + usize::from(reader.pos == 0 || text[reader.pos - 1] != b'\n');
        ParseError::at_line(line.max(1), format!("OBJ: {e}"))
    })?;
    let mut mesh = Mesh::default();
    let materials = materials.unwrap_or_else(|e| {
        mesh.warnings
            .push(format!("MTL not loaded ({e}); default materials used"));
        Vec::new()
    });
    convert_materials(&materials, &mut mesh);
    let default = mesh.materials.len() as u32;
    let mut used_default = false;
    let mut no_uvs = 0;
    for m in &models {
        let mat = match m.mesh.material_id {
            Some(i) if i < materials.len() => i as u32,
            _ => {
                used_default = true;
                default
            }
        };
        if m.mesh.indices.is_empty() {
            continue;
        }
        let textured = mesh
            .materials
            .get(mat as usize)
            .is_some_and(|x| x.color_map.is_some());
        if textured && m.mesh.texcoords.is_empty() {
            no_uvs += 1;
        }
        let part = model_mesh(&m.mesh, mat)?;
        let keep = (
            std::mem::take(&mut mesh.materials),
            std::mem::take(&mut mesh.textures),
        );
        mesh.append(part);
        (mesh.materials, mesh.textures) = keep;
        mesh.objects.push(m.name.clone());
    }
    if used_default {
        mesh.materials.push(Material {
            name: "default".into(),
            ..Material::default()
        });
    }
    if no_uvs > 0 {
        mesh.warnings.push(format!(
            "{no_uvs} objects with a textured material have no texture coordinates; set to (0, 0)"
        ));
    }
    if mesh.indices.is_empty() {
        return Err(ParseError::new(
            "file",
            "no faces (points and lines are skipped)",
        ));
    }
    Ok(mesh)
}

/// Refuses face, line and point indices that resolve outside the file's vertex lists, naming
/// the line: `tobj` 4.0 resolves a relative index past the start (`-12` with one normal) or the
/// index 0 to a huge `usize` and then multiplies it (`vn * 3`), which overflows (a panic with
/// overflow checks, silently wrong data without). A positive index is checked against the whole
/// file's count (tobj allows references forward within a group), a negative one against the
/// vertices read so far, as tobj resolves it. Components that are not integers are left to
/// tobj, which reports them.
fn check_face_indices(text: &[u8]) -> Result<(), ParseError> {
    const KINDS: [&str; 3] = ["position", "texture coordinate", "normal"];
    let lines = || text.split(|&b| b == b'\n').map(String::from_utf8_lossy);
    let kind_of = |l: &str| match l.split_whitespace().next() {
        Some("v") => Some(0),
        Some("vt") => Some(1),
        Some("vn") => Some(2),
        _ => None,
    };
    let mut total = [0i64; 3];
    for l in lines() {
        if let Some(k) = kind_of(&l) {
            total[k] += 1;
        }
    }
    let mut so_far = [0i64; 3];
    for (n, l) in lines().enumerate() {
        if let Some(k) = kind_of(&l) {
            so_far[k] += 1;
            continue;
        }
        let mut words = l.split_whitespace();
        if !matches!(words.next(), Some("f" | "l" | "p")) {
            continue;
        }
        for vertex in words {
            for (k, part) in vertex.split('/').take(3).enumerate() {
                let Ok(x) = part.parse::<i64>() else { continue };
                if k > 0 && total[k] == 0 {
                    continue; // tobj ignores texture and normal indices when there are none
                }
                let ok = if x < 0 {
                    so_far[k].checked_add(x).is_some_and(|i| i >= 0)
                } else {
                    x >= 1 && x <= total[k]
                };
                if !ok {
                    let count = if x < 0 { so_far[k] } else { total[k] };
                    return Err(ParseError::at_line(
                        n + 1,
                        format!(
                            "OBJ: {} index {x} in `{vertex}` is outside the {count} {}s {}",
                            KINDS[k],
                            KINDS[k],
                            if x < 0 { "read so far" } else { "of the file" }
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// One tobj model as a mesh (materials index into the file's list).
fn model_mesh(m: &tobj::Mesh, mat: u32) -> Result<Mesh, ParseError> {
    let n = m.positions.len() / 3;
    let positions: Vec<[f32; 3]> = m
        .positions
        .chunks_exact(3)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    let uvs: Vec<[f32; 2]> = if m.texcoords.len() / 2 == n {
        m.texcoords
            .chunks_exact(2)
            .map(|t| [t[0], 1.0 - t[1]])
            .collect()
    } else {
        vec![[0.0, 0.0]; n]
    };
    let tris: Vec<[u32; 3]> = m
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    if let Some(bad) = tris.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(ParseError::new(
            "faces",
            format!("vertex index {bad} out of range ({n} vertices)"),
        ));
    }
    if m.normals.len() / 3 == n {
        let normals = m
            .normals
            .chunks_exact(3)
            .map(|v| Vec3::new(v[0], v[1], v[2]).normalize_or(Vec3::Z).to_array())
            .collect();
        Ok(Mesh {
            positions,
            normals,
            uvs,
            triangle_materials: vec![mat; tris.len()],
            indices: tris,
            ..Mesh::default()
        })
    } else {
        Ok(flat_mesh(&positions, &uvs, &tris, mat))
    }
}

/// A mesh with face normals: every triangle gets its own three vertices. Degenerate triangles
/// get (0, 0, 1). Shared by the glTF reader.
pub(crate) fn flat_mesh(
    positions: &[[f32; 3]],
    uvs: &[[f32; 2]],
    tris: &[[u32; 3]],
    material: u32,
) -> Mesh {
    let mut mesh = Mesh {
        triangle_materials: vec![material; tris.len()],
        ..Mesh::default()
    };
    mesh.positions.reserve(tris.len() * 3);
    for (k, t) in tris.iter().enumerate() {
        let [a, b, c] = t.map(|i| Vec3::from_array(positions[i as usize]));
        let n = (b - a).cross(c - a).normalize_or(Vec3::Z).to_array();
        for &i in t {
            mesh.positions.push(positions[i as usize]);
            mesh.normals.push(n);
            mesh.uvs.push(uvs[i as usize]);
        }
        let v = 3 * k as u32;
        mesh.indices.push([v, v + 1, v + 2]);
    }
    mesh
}

fn convert_materials(materials: &[tobj::Material], mesh: &mut Mesh) {
    for m in materials {
        let d = Material::default();
        let rgba = |c: Option<[f32; 3]>, def: [f32; 4]| c.map_or(def, |c| [c[0], c[1], c[2], 1.0]);
        let transparency = match (m.dissolve, m.unknown_param.get("Tr")) {
            (Some(d), _) => 1.0 - d,
            (None, Some(tr)) => tr.trim().parse().unwrap_or(0.0),
            _ => 0.0,
        };
        let normal = m
            .normal_texture
            .clone()
            .or_else(|| m.unknown_param.get("norm").cloned());
        let color_map = m.diffuse_texture.as_deref().map(|t| texture(mesh, t));
        let normal_map = normal.as_deref().map(|t| texture(mesh, t));
        mesh.materials.push(Material {
            name: m.name.clone(),
            diffuse: rgba(m.diffuse, d.diffuse),
            ambient: rgba(m.ambient, d.ambient),
            specular: rgba(m.specular, d.specular),
            emission: rgba(m.emissive, d.emission),
            shininess: m.shininess.unwrap_or(0.0).clamp(0.0, 128.0),
            transparency: transparency.clamp(0.0, 1.0),
            color_map,
            normal_map,
            ..d
        });
    }
}

/// The index of a texture by its MTL statement's file name (options like `-bm 1` dropped).
fn texture(mesh: &mut Mesh, statement: &str) -> u32 {
    let name = strip_options(statement);
    if let Some(i) = mesh.textures.iter().position(|t| t.name == name) {
        return i as u32;
    }
    mesh.textures.push(TextureRef {
        name: name.clone(),
        path: PathBuf::from(&name),
    });
    mesh.textures.len() as u32 - 1
}

/// MTL texture statements may start with options (`-bm 0.5 -clamp on file.png`): the file name
/// is what follows the last option and its arguments.
fn strip_options(s: &str) -> String {
    let words: Vec<&str> = s.split_whitespace().collect();
    if !words.first().is_some_and(|w| w.starts_with('-')) {
        return s.trim().to_string();
    }
    let args = |opt: &str| match opt {
        "-o" | "-s" | "-t" => 3,
        "-mm" => 2,
        _ => 1,
    };
    let mut k = 0;
    while k < words.len() && words[k].starts_with('-') {
        k += 1 + args(words[k]);
    }
    words.get(k..).map(|w| w.join(" ")).unwrap_or_default()
}

/// UTF-16 (with a byte-order mark) to UTF-8, invalid UTF-8 replaced (tobj needs valid lines),
/// and lines tobj would misread turned into comments, keeping the line numbers: `l` and `p`
/// statements (tobj reads an `l` with more than two indices as a polygon) and `usemtl` without a
/// name (tobj rejects it; its faces keep the current material).
fn to_utf8(bytes: &[u8]) -> Vec<u8> {
    let utf16 = |be: bool| {
        let units = bytes[2..].chunks_exact(2).map(|c| {
            if be {
                u16::from_be_bytes([c[0], c[1]])
            } else {
                u16::from_le_bytes([c[0], c[1]])
            }
        });
        char::decode_utf16(units)
            .map(|c| c.unwrap_or(char::REPLACEMENT_CHARACTER))
            .collect::<String>()
    };
    let text = match bytes {
        [0xFE, 0xFF, ..] => utf16(true),
        [0xFF, 0xFE, ..] => utf16(false),
        [0xEF, 0xBB, 0xBF, rest @ ..] => String::from_utf8_lossy(rest).into_owned(),
        _ => String::from_utf8_lossy(bytes).into_owned(),
    };
    let mut out = Vec::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        let mut words = line.split_whitespace();
        let first = words.next();
        let skip =
            matches!(first, Some("l" | "p")) || (first == Some("usemtl") && words.next().is_none());
        if skip {
            out.push(b'#');
        }
        out.extend_from_slice(line.as_bytes());
    }
    out
}

/// A `BufRead` over a byte slice that hands out one line at a time and counts the lines
/// consumed, so a tobj error can name its line.
struct LineCounter<'a> {
    data: &'a [u8],
    pos: usize,
    line: usize,
}

impl std::io::Read for LineCounter<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let avail = self.fill_buf()?;
        let n = avail.len().min(buf.len());
        buf[..n].copy_from_slice(&avail[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl BufRead for LineCounter<'_> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        let rest = &self.data[self.pos..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .map_or(rest.len(), |k| k + 1);
        Ok(&rest[..end])
    }
    fn consume(&mut self, n: usize) {
        let n = n.min(self.data.len() - self.pos);
        self.line += self.data[self.pos..self.pos + n]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        self.pos += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression (found by tests/fuzz_smoke.rs): `Kd 0.4` made tobj panic in `parse_float3`.
    #[test]
    fn mtl_colour_with_fewer_than_three_numbers_is_a_broken_mtl_not_a_panic() {
        let obj = b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n";
        for line in ["Kd 0.4", "Ka", "Ks 1 2", "Ke 0.1 x"] {
            let mtl = format!("newmtl a\n{line}\n");
            let m = parse_with_mtl(obj, mtl.as_bytes()).unwrap();
            assert_eq!(m.indices.len(), 1);
            assert!(
                m.warnings.iter().any(|w| w.contains("MTL")),
                "{line}: {:?}",
                m.warnings
            );
        }
    }

    const OBJ: &str = "# a quad and a triangle, two materials\n\
mtllib two.mtl\n\
o Quad\n\
v 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\n\
vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
usemtl Leaf\n\
f 1/1 2/2 3/3 4/4\n\
l 1 2 3 4\n\
o Tri\n\
v 0 0 1\nv 1 0 1\nv 0 0 2\n\
usemtl Stone\n\
f 5 6 7\n";

    const MTL: &str = "newmtl Leaf\nKd 0.1 0.6 0.2\nKa 0 0 0\nKs 0.5 0.5 0.5\nNs 400\nd 0.25\n\
map_Kd -bm 1 LEAF.png\nmap_Bump leaf_n.png\n\nnewmtl Stone\nKd 0.5 0.5 0.5\nTr 0.1\n";

    fn write(dir: &Path) -> PathBuf {
        std::fs::write(dir.join("two.obj"), OBJ).unwrap();
        std::fs::write(dir.join("two.mtl"), MTL).unwrap();
        std::fs::write(dir.join("leaf.png"), b"not decoded here").unwrap();
        dir.join("two.obj")
    }

    #[test]
    fn quad_and_triangle_with_mtl_materials() {
        let dir = tempfile::tempdir().unwrap();
        let m = load(&write(dir.path())).unwrap();
        assert_eq!(
            m.indices.len(),
            3,
            "quad → 2 triangles, line skipped, + 1 triangle"
        );
        assert_eq!(m.objects, vec!["Quad".to_string(), "Tri".to_string()]);
        assert_eq!(m.triangle_materials, vec![0, 0, 1]);
        let leaf = &m.materials[0];
        assert_eq!(leaf.name, "Leaf");
        assert_eq!(leaf.diffuse, [0.1, 0.6, 0.2, 1.0]);
        assert_eq!(leaf.specular, [0.5, 0.5, 0.5, 1.0]);
        assert_eq!(leaf.shininess, 128.0, "Ns 400 clamped to OpenGL's 128");
        assert_eq!(leaf.transparency, 0.75);
        let tex = &m.textures[leaf.color_map.unwrap() as usize];
        assert_eq!(tex.name, "LEAF.png");
        assert_eq!(
            tex.path,
            dir.path().join("leaf.png"),
            "case-insensitive fallback"
        );
        assert_eq!(
            m.textures[leaf.normal_map.unwrap() as usize].name,
            "leaf_n.png"
        );
        assert!((m.materials[1].transparency - 0.1).abs() < 1e-6);
        // No normals in the file: face normals, +z for the quad, -y for the triangle.
        for (t, tri) in m.indices.iter().enumerate() {
            let want = if t < 2 {
                [0.0, 0.0, 1.0]
            } else {
                [0.0, -1.0, 0.0]
            };
            for &v in tri {
                assert_eq!(m.normals[v as usize], want);
            }
        }
        // v flipped: the corner with vt (1, 1) at (2, 1, 0) gets uv (1, 0).
        let k = m
            .positions
            .iter()
            .position(|p| *p == [2.0, 1.0, 0.0])
            .unwrap();
        assert_eq!(m.uvs[k], [1.0, 0.0]);
        assert_eq!(m.validate(), Ok(()));
    }

    #[test]
    fn parse_without_folder_uses_default_materials() {
        let m = parse(OBJ.as_bytes()).unwrap();
        assert_eq!(m.indices.len(), 3);
        assert!(m.materials.iter().any(|x| x.name == "default"));
        assert!(
            m.warnings.iter().any(|w| w.contains("MTL")),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn face_indices_outside_the_vertex_lists_name_the_line_instead_of_overflowing() {
        // The fuzzer's find (tests/data/fuzz/obj/): `3/3/-12` with one normal made tobj 4.0.5
        // multiply a wrapped index (lib.rs:860).
        let crash = include_bytes!(
            "../../tests/data/fuzz/obj/crash-2673e795bd24076f3ffd99bffedba6733414d8f7"
        );
        let e = parse(crash).unwrap_err().to_string();
        assert!(
            e.contains("line 13") && e.contains("normal index -12"),
            "{e}"
        );
        let quad = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        for (face, what) in [
            ("f 1 2 0", "position index 0"),
            ("f 1 2 4", "position index 4"),
            ("f 1 2 -4", "position index -4"),
            ("vt 0 0\nf 1/1 2/1 3/2", "texture coordinate index 2"),
            (
                "f 1 2 9223372036854775807",
                "position index 9223372036854775807",
            ),
        ] {
            let e = parse(format!("{quad}{face}\n").as_bytes())
                .unwrap_err()
                .to_string();
            let line = 4 + face.matches('\n').count();
            assert!(
                e.contains(&format!("line {line}")) && e.contains(what),
                "{face}: {e}"
            );
        }
        // In range, relative and forward references (within the file) still read.
        let m = parse(format!("{quad}f -3 -2 -1\nf 1 2 4\nv 1 1 0\n").as_bytes()).unwrap();
        assert_eq!(m.indices.len(), 2, "two triangles");
        // Texture indices with no texture coordinates are ignored, as before.
        assert!(parse(format!("{quad}f 1/1 2/1 3/1\n").as_bytes()).is_ok());
    }

    #[test]
    fn errors_name_the_line() {
        let e = parse(b"v 0 0 0\nv 1 0 0\nv 1 x 0\nf 1 2 3\n").unwrap_err();
        assert_eq!(e.place, "line 3", "{e}");
        let e = parse(b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9").unwrap_err();
        assert_eq!(e.place, "line 4", "{e}");
        let e = parse(b"v 0 0 0\np 1\n").unwrap_err();
        assert!(e.message.contains("no faces"), "{e}");
    }

    #[test]
    fn utf16_with_bom_is_read() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let mut bytes = vec![0xFE, 0xFF];
        bytes.extend(text.encode_utf16().flat_map(|u| u.to_be_bytes()));
        assert_eq!(parse(&bytes).unwrap().indices.len(), 1);
    }

    #[test]
    fn texture_options_are_stripped() {
        assert_eq!(strip_options("-bm 0.5 -clamp on a b.png"), "a b.png");
        assert_eq!(strip_options("-o 1 2 3 tex.png"), "tex.png");
        assert_eq!(strip_options("plain.png"), "plain.png");
    }
}
