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
    b.finish()
}

/// Decodes a mesh section back into the model.
pub fn from_section(v: &SectionView) -> Result<(MeshMeta, Mesh), ParseError> {
    let meta: MeshMeta = v.meta()?;
    let mesh = Mesh {
        positions: v.array_vec("positions")?,
        normals: v.array_vec("normals")?,
        uvs: v.array_vec("uvs")?,
        indices: v.array_vec("indices")?,
        triangle_materials: v.array_vec("triangle_materials")?,
        materials: meta.materials.clone(),
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
    Ok(json!({
        "vertices": positions.len(),
        "triangles": tris,
        "materials": meta.materials.len(),
        "bounds": {"min": lo, "max": hi},
        "objects": meta.objects,
        "textures": meta.textures.iter().map(|t| t.name.clone()).collect::<Vec<_>>(),
        "source": meta.source,
    }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, m) = from_section(v)?;
    Ok(json!({
        "positions": m.positions,
        "normals": m.normals,
        "uvs": m.uvs,
        "indices": m.indices,
        "triangle_materials": m.triangle_materials,
        "materials": m.materials,
    }))
}
