//! Kind `mesh`: one model's triangles in model space, with its materials and texture references.

use crate::error::{ParseError, Result};
use crate::model::{Material, Mesh, TextureRef, bounds_of};
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// Section name of a model's mesh.
pub fn mesh_section_name(model: &str) -> String {
    format!("mesh:{model}")
}

/// The mesh section's name of a per-model stage unit (`mesh:<model>`, fitted to a name's
/// length).
pub fn unit_mesh_name(u: &crate::stage::UnitInputs) -> Result<String> {
    Ok(crate::pack::fit_name(mesh_section_name(u.model_name()?)))
}

pub const KIND: &str = "mesh";

/// Metadata of a mesh section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshMeta {
    /// The file the mesh was read from.
    pub source: String,
    pub objects: Vec<String>,
    pub materials: Vec<Material>,
    /// Texture references; `section` names the texture section holding the decoded image.
    pub textures: Vec<TextureEntry>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TextureEntry {
    pub name: String,
    pub section: Option<String>,
}

/// Encodes a mesh; `texture_sections[i]` is the section name of `mesh.textures[i]` if it was
/// decoded into the pack.
pub fn to_section(
    name: &str,
    source: &str,
    mesh: &Mesh,
    texture_sections: &[Option<String>],
) -> Section {
    let meta = MeshMeta {
        source: source.to_string(),
        objects: mesh.objects.clone(),
        materials: mesh.materials.clone(),
        textures: mesh
            .textures
            .iter()
            .enumerate()
            .map(|(i, t)| TextureEntry {
                name: t.name.clone(),
                section: texture_sections.get(i).cloned().flatten(),
            })
            .collect(),
    };
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&meta)
        .array("positions", ArrayFormat::F32, 3, &mesh.positions)
        .array("normals", ArrayFormat::F32, 3, &mesh.normals)
        .array("uvs", ArrayFormat::F32, 2, &mesh.uvs)
        .array("indices", ArrayFormat::U32, 3, &mesh.indices)
        .array(
            "triangle_materials",
            ArrayFormat::U32,
            1,
            &mesh.triangle_materials,
        );
    // The one-sided materials (glTF `doubleSided: false`) only where there are any (so other
    // models' bytes are unchanged; a pack without the array reads as all double-sided).
    let one_sided = one_sided_materials(mesh);
    if !one_sided.is_empty() {
        b.array("one_sided_materials", ArrayFormat::U32, 1, &one_sided);
    }
    // A skeleton's arrays only where the model has one (so other models' bytes are unchanged).
    if !mesh.skeleton.lines.is_empty() {
        b.array(
            "skeleton_lines",
            ArrayFormat::F32,
            3,
            &flat_lines(&mesh.skeleton.lines),
        );
    }
    if !mesh.skeleton.points.is_empty() {
        b.array(
            "skeleton_points",
            ArrayFormat::F32,
            3,
            &mesh.skeleton.points,
        );
    }
    b.finish()
}

/// Segments as a list of end points (two per segment).
fn flat_lines(lines: &[[[f32; 3]; 2]]) -> Vec<[f32; 3]> {
    lines.iter().flatten().copied().collect()
}

/// The section's skeleton (`skeleton_lines`: two end points per segment, `skeleton_points`),
/// empty where it has none.
pub fn skeleton_of(v: &SectionView) -> Result<crate::model::Skeleton, ParseError> {
    let mut sk = crate::model::Skeleton::default();
    if v.info("skeleton_lines").is_some() {
        let ends: Vec<[f32; 3]> = v.array_vec("skeleton_lines")?;
        if !ends.len().is_multiple_of(2) {
            return Err(ParseError::new(
                "mesh array \"skeleton_lines\"",
                format!("{} end points do not form segments", ends.len()),
            ));
        }
        sk.lines = ends.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    }
    if v.info("skeleton_points").is_some() {
        sk.points = v.array_vec("skeleton_points")?;
    }
    let finite = |p: &[f32; 3]| p.iter().all(|c| c.is_finite());
    if !sk.lines.iter().flatten().all(finite) || !sk.points.iter().all(finite) {
        return Err(ParseError::new("mesh skeleton", "a position is not finite"));
    }
    Ok(sk)
}

/// The indices of the mesh's one-sided materials ([`Material::double_sided`] false).
pub fn one_sided_materials(mesh: &Mesh) -> Vec<u32> {
    (0..mesh.materials.len() as u32)
        .filter(|&i| !mesh.materials[i as usize].double_sided)
        .collect()
}

/// The section's `one_sided_materials` array (empty where absent).
fn one_sided_of(v: &SectionView) -> Result<Vec<u32>, ParseError> {
    if v.info("one_sided_materials").is_none() {
        return Ok(Vec::new());
    }
    v.array_vec("one_sided_materials")
}

/// Decodes a mesh section back into the model.
pub fn from_section(v: &SectionView) -> Result<(MeshMeta, Mesh), ParseError> {
    let meta: MeshMeta = v.meta()?;
    let mut materials = meta.materials.clone();
    for i in one_sided_of(v)? {
        let m = materials.get_mut(i as usize).ok_or_else(|| {
            ParseError::new(
                "mesh array \"one_sided_materials\"",
                format!("material {i} of {}", meta.materials.len()),
            )
        })?;
        m.double_sided = false;
    }
    let mesh = Mesh {
        positions: v.array_vec("positions")?,
        normals: v.array_vec("normals")?,
        uvs: v.array_vec("uvs")?,
        indices: v.array_vec("indices")?,
        triangle_materials: v.array_vec("triangle_materials")?,
        materials,
        textures: meta
            .textures
            .iter()
            .map(|t| TextureRef {
                name: t.name.clone(),
                path: t.name.clone().into(),
            })
            .collect(),
        objects: meta.objects.clone(),
        warnings: Vec::new(),
        skeleton: skeleton_of(v)?,
    };
    mesh.validate()
        .map_err(|m| ParseError::new("mesh section", m))?;
    Ok((meta, mesh))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta: MeshMeta = v.meta()?;
    let positions: Vec<[f32; 3]> = v.array_vec("positions")?;
    let (lo, hi) = bounds_of(&positions).unwrap_or(([0.0; 3], [0.0; 3]));
    let tris = v.info("indices").map_or(0, |a| a.count);
    let mut out = json!({
        "vertices": positions.len(),
        "triangles": tris,
        "materials": meta.materials.len(),
        "bounds": {"min": lo, "max": hi},
        "objects": meta.objects,
        "textures": meta.textures.iter().map(|t| t.name.clone()).collect::<Vec<_>>(),
        "source": meta.source,
        "skeleton": {
            "segments": v.info("skeleton_lines").map_or(0, |a| a.count / 2),
            "points": v.info("skeleton_points").map_or(0, |a| a.count),
        },
    });
    // Only where there are any, so the summary of double-sided meshes reads as before.
    let one_sided = one_sided_of(v)?;
    if !one_sided.is_empty() {
        out["one_sided_materials"] = json!(one_sided);
    }
    Ok(out)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, m) = from_section(v)?;
    let mut out = json!({
        "positions": m.positions,
        "normals": m.normals,
        "uvs": m.uvs,
        "indices": m.indices,
        "triangle_materials": m.triangle_materials,
        "materials": m.materials,
    });
    let one_sided = one_sided_materials(&m);
    if !one_sided.is_empty() {
        out["one_sided_materials"] = json!(one_sided);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view_of(s: &Section) -> crate::pack::Pack {
        crate::pack::Pack::from_sections(std::slice::from_ref(s), "t.bake")
    }

    #[test]
    fn one_sided_materials_round_trip_and_double_sided_meshes_keep_their_bytes() {
        let mut mesh = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            uvs: vec![[0.0; 2]; 3],
            indices: vec![[0, 1, 2]],
            triangle_materials: vec![1],
            materials: vec![Material::default(); 3],
            ..Mesh::default()
        };
        let plain = to_section("mesh:m", "m.gltf", &mesh, &[]);
        let pack = view_of(&plain);
        let v = pack.view_named("mesh:m").unwrap();
        assert!(v.info("one_sided_materials").is_none());
        assert_eq!(from_section(&v).unwrap().1, mesh);
        mesh.materials[1].double_sided = false;
        let one = to_section("mesh:m", "m.gltf", &mesh, &[]);
        let pack = view_of(&one);
        let v = pack.view_named("mesh:m").unwrap();
        let back = from_section(&v).unwrap().1;
        assert_eq!(back, mesh);
        assert_eq!(
            back.materials
                .iter()
                .map(|m| m.double_sided)
                .collect::<Vec<_>>(),
            [true, false, true]
        );
        assert_eq!(summary(&v).unwrap()["one_sided_materials"], json!([1]));
    }

    #[test]
    fn a_skeleton_round_trips_and_a_mesh_without_one_has_no_arrays() {
        let mut mesh = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            uvs: vec![[0.0; 2]; 3],
            indices: vec![[0, 1, 2]],
            triangle_materials: vec![0],
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        let plain = to_section("mesh:m", "m.txf", &mesh, &[]);
        let pack = view_of(&plain);
        let v = pack.view_named("mesh:m").unwrap();
        assert!(v.info("skeleton_lines").is_none() && v.info("skeleton_points").is_none());
        assert_eq!(from_section(&v).unwrap().1, mesh);
        mesh.skeleton.lines = vec![
            [[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]],
            [[0.0, 0.0, 2.0], [1.0, 0.0, 3.0]],
        ];
        mesh.skeleton.points = vec![[0.5, 0.5, 2.5]];
        let s = to_section("mesh:m", "m.txf", &mesh, &[]);
        let pack = view_of(&s);
        let v = pack.view_named("mesh:m").unwrap();
        assert_eq!(from_section(&v).unwrap().1, mesh);
        let sum = summary(&v).unwrap();
        assert_eq!(sum["skeleton"]["segments"], 2);
        assert_eq!(sum["skeleton"]["points"], 1);
    }
}
