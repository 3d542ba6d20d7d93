//! Per-vertex tangent frames by MikkTSpace (crate `bevy_mikktspace`, a safe port that gives the
//! reference C implementation's results), and their pack section.
//!
//! The tangent is `xyz` (unit, orthogonal to the vertex normal, along increasing u) and `w = ±1`
//! gives the bitangent `b = w · (n × t)`, along increasing v (v = 0 at the image's top row, so
//! the normal maps of src/texture/normalmap.rs use the same frame). MikkTSpace returns one frame
//! per triangle corner; where corners of one vertex disagree (UV mirroring, seams the input
//! shares a vertex across) the vertex is split, so a mesh may come back with more vertices.
//! Corners MikkTSpace leaves without a frame (degenerate UVs, no neighbour) get any unit
//! tangent orthogonal to the normal, and are counted.
//!
//! Section kind `tangents`, named `tangents:<model>`: array `tangents` f32×4 per vertex of the
//! mesh section named in the metadata.

use crate::error::ParseError;
use crate::model::Mesh;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "tangents";

/// A mesh with a tangent per vertex.
#[derive(Debug, Clone, PartialEq)]
pub struct TangentFrames {
    /// The input mesh, with vertices split where corners needed different frames.
    pub mesh: Mesh,
    /// One `[tx, ty, tz, w]` per vertex of `mesh`.
    pub tangents: Vec<[f32; 4]>,
    /// Vertices added by splitting.
    pub split_vertices: usize,
    /// Corners without a MikkTSpace frame (given an arbitrary orthogonal tangent).
    pub fallback_corners: usize,
}

struct Corners<'a> {
    mesh: &'a Mesh,
    out: Vec<Option<[f32; 4]>>,
}

impl bevy_mikktspace::Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.mesh.indices.len()
    }
    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }
    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.mesh.positions[self.mesh.indices[face][vert] as usize]
    }
    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.mesh.normals[self.mesh.indices[face][vert] as usize]
    }
    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        self.mesh.uvs[self.mesh.indices[face][vert] as usize]
    }
    fn set_tangent(&mut self, ts: Option<bevy_mikktspace::TangentSpace>, face: usize, vert: usize) {
        self.out[face * 3 + vert] = ts.map(|t| t.tangent_encoded());
    }
}

/// Any unit vector orthogonal to `n` (Frisvad's construction), as a tangent with w = +1.
fn any_tangent(n: [f32; 3]) -> [f32; 4] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = if l > 0.0 {
        n.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    };
    if n[2] < -0.999_999 {
        return [0.0, -1.0, 0.0, 1.0];
    }
    let a = 1.0 / (1.0 + n[2]);
    let b = -n[0] * n[1] * a;
    [1.0 - n[0] * n[0] * a, b, -n[0], 1.0]
}

/// Generates MikkTSpace tangents (a stage: pure, deterministic).
pub fn generate_tangents(mesh: &Mesh) -> TangentFrames {
    let mut corners = Corners {
        mesh,
        out: vec![None; mesh.indices.len() * 3],
    };
    // The error type has no variants: generation cannot fail.
    let _ = bevy_mikktspace::generate_tangents(&mut corners);
    let mut fallback_corners = 0;
    let frames: Vec<[f32; 4]> = corners
        .out
        .iter()
        .enumerate()
        .map(|(c, t)| {
            t.unwrap_or_else(|| {
                fallback_corners += 1;
                any_tangent(mesh.normals[mesh.indices[c / 3][c % 3] as usize])
            })
        })
        .collect();
    let (out, tangents) = split_disagreeing(mesh, &frames);
    TangentFrames {
        split_vertices: out.positions.len() - mesh.positions.len(),
        mesh: out,
        tangents,
        fallback_corners,
    }
}

/// Gives every vertex one frame: the first corner's keeps the vertex, each further distinct
/// frame gets a copy of the vertex appended (in corner order, so the result is deterministic).
fn split_disagreeing(mesh: &Mesh, frames: &[[f32; 4]]) -> (Mesh, Vec<[f32; 4]>) {
    let n = mesh.positions.len();
    let mut out = mesh.clone();
    let mut tangents: Vec<Option<[f32; 4]>> = vec![None; n];
    // Copies made of each vertex: (frame, new index).
    let mut copies: std::collections::HashMap<u32, Vec<([u32; 4], u32)>> = Default::default();
    for (c, f) in frames.iter().enumerate() {
        let v = mesh.indices[c / 3][c % 3];
        let bits = f.map(f32::to_bits);
        let slot = &mut tangents[v as usize];
        let target = match slot {
            None => {
                *slot = Some(*f);
                v
            }
            Some(t) if t.map(f32::to_bits) == bits => v,
            Some(_) => {
                let list = copies.entry(v).or_default();
                match list.iter().find(|(b, _)| *b == bits) {
                    Some(&(_, i)) => i,
                    None => {
                        let i = out.positions.len() as u32;
                        out.positions.push(mesh.positions[v as usize]);
                        out.normals.push(mesh.normals[v as usize]);
                        out.uvs.push(mesh.uvs[v as usize]);
                        tangents.push(Some(*f));
                        list.push((bits, i));
                        i
                    }
                }
            }
        };
        out.indices[c / 3][c % 3] = target;
    }
    // Vertices no triangle uses get a frame from their normal.
    let t = tangents
        .iter()
        .zip(&out.normals)
        .map(|(t, &nrm)| t.unwrap_or_else(|| any_tangent(nrm)))
        .collect();
    (out, t)
}

/// Metadata of a `tangents` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TangentsMeta {
    pub mesh_section: String,
    /// Corners that got an arbitrary orthogonal tangent.
    pub fallback_corners: u64,
}

/// Section name of a model's tangents.
pub fn tangents_section_name(model: &str) -> String {
    crate::pack::fit_name(format!("tangents:{model}"))
}

pub fn to_section(name: &str, mesh_section: &str, f: &TangentFrames) -> Section {
    let meta = TangentsMeta {
        mesh_section: mesh_section.into(),
        fallback_corners: f.fallback_corners as u64,
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("tangents", ArrayFormat::F32, 4, &f.tangents);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(TangentsMeta, Vec<[f32; 4]>), ParseError> {
    let meta: TangentsMeta = v.meta()?;
    let t: Vec<[f32; 4]> = v.array_vec("tangents")?;
    if let Some(k) = t
        .iter()
        .position(|t| t[3].abs() != 1.0 || t.iter().any(|c| !c.is_finite()))
    {
        return Err(ParseError::new(
            format!("tangents section, vertex {k}"),
            "w must be ±1 and every component finite",
        ));
    }
    Ok((meta, t))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (meta, t) = from_section(v)?;
    let mirrored = t.iter().filter(|t| t[3] < 0.0).count();
    Ok(
        json!({"mesh": meta.mesh_section, "vertices": t.len(), "mirrored": mirrored,
              "fallback_corners": meta.fallback_corners}),
    )
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, t) = from_section(v)?;
    Ok(json!({ "tangents": t }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }
    fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }
    fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    }

    /// A UV sphere (smooth normals) whose left half has mirrored u, as leaves often do.
    fn mirrored_sphere(rings: u32, segs: u32) -> Mesh {
        let mut m = Mesh::default();
        for r in 0..=rings {
            let th = std::f32::consts::PI * (0.1 + 0.8 * r as f32 / rings as f32);
            for s in 0..=segs {
                let ph = 2.0 * std::f32::consts::PI * s as f32 / segs as f32;
                let p = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
                let u = s as f32 / segs as f32;
                let u = if u < 0.5 { u } else { 1.0 - u };
                m.positions.push(p);
                m.normals.push(p);
                m.uvs.push([u, r as f32 / rings as f32]);
            }
        }
        for r in 0..rings {
            for s in 0..segs {
                let a = r * (segs + 1) + s;
                let (b, c, d) = (a + 1, a + segs + 1, a + segs + 2);
                m.indices.push([a, c, b]);
                m.indices.push([b, c, d]);
            }
        }
        m.triangle_materials = vec![0; m.indices.len()];
        m.materials = vec![Default::default()];
        m
    }

    #[test]
    fn frames_are_orthonormal_and_follow_the_uv_direction() {
        let f = generate_tangents(&mirrored_sphere(12, 24));
        f.mesh.validate().unwrap();
        assert_eq!(f.tangents.len(), f.mesh.positions.len());
        assert_eq!(f.fallback_corners, 0);
        let mut mirrored = 0;
        for (t, n) in f.tangents.iter().zip(&f.mesh.normals) {
            let t3 = [t[0], t[1], t[2]];
            assert!((dot(t3, t3) - 1.0).abs() < 1e-4, "tangent not unit");
            assert!(
                dot(t3, *n).abs() < 1e-4,
                "tangent not orthogonal to the normal"
            );
            assert!(t[3] == 1.0 || t[3] == -1.0);
            mirrored += usize::from(t[3] < 0.0);
        }
        assert!(mirrored > 0, "the mirrored half must flip the bitangent");
        // Independent oracle: each triangle's ∂p/∂u and ∂p/∂v from its positions and UVs.
        for tri in &f.mesh.indices {
            let [p0, p1, p2] = tri.map(|i| f.mesh.positions[i as usize]);
            let [t0, t1, t2] = tri.map(|i| f.mesh.uvs[i as usize]);
            let (e1, e2) = (sub(p1, p0), sub(p2, p0));
            let (du1, dv1, du2, dv2) = (t1[0] - t0[0], t1[1] - t0[1], t2[0] - t0[0], t2[1] - t0[1]);
            let det = du1 * dv2 - du2 * dv1;
            if det.abs() < 1e-9 {
                continue;
            }
            let dpdu = [0, 1, 2].map(|k| (e1[k] * dv2 - e2[k] * dv1) / det);
            let dpdv = [0, 1, 2].map(|k| (e2[k] * du1 - e1[k] * du2) / det);
            for &i in tri {
                let t = f.tangents[i as usize];
                let t3 = [t[0], t[1], t[2]];
                let n = f.mesh.normals[i as usize];
                let b = cross(n, t3).map(|c| c * t[3]);
                let cu = dot(t3, dpdu) / dot(dpdu, dpdu).sqrt();
                let cv = dot(b, dpdv) / dot(dpdv, dpdv).sqrt();
                assert!(cu > 0.7, "tangent against ∂p/∂u: cos {cu}");
                assert!(cv > 0.7, "bitangent against ∂p/∂v: cos {cv}");
            }
        }
    }

    #[test]
    fn a_shared_vertex_with_mirrored_uvs_is_split() {
        // Two triangles share the edge (1, 2); the second mirrors u, so vertices 1 and 2 need
        // two frames each.
        let mut m = Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [2.0, 1.0, 0.0],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            indices: vec![[0, 1, 2], [1, 3, 2]],
            ..Default::default()
        };
        m.triangle_materials = vec![0, 0];
        m.materials = vec![Default::default()];
        let f = generate_tangents(&m);
        f.mesh.validate().unwrap();
        assert!(f.split_vertices >= 1);
        assert!(f.tangents[f.mesh.indices[0][0] as usize][0] > 0.9);
        // The second triangle's u runs along −x.
        assert!(f.tangents[f.mesh.indices[1][1] as usize][0] < -0.9);
    }
}
