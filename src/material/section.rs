//! Kind `material`: one converted two-layer Schlick material per section, named
//! `material:<model>/<index>` after the mesh material it came from.
//!
//! Arrays: `params`, one 96-byte record ([`MaterialRecord`]) ready for a uniform buffer. The
//! metadata keeps the whole [`SchlickMaterial`] and the names of the sections holding its maps.

use super::schlick::{NormalMap, SchlickLayer, SchlickMaterial};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "material";

/// Section name of material `index` of `model`.
pub fn material_section_name(model: &str, index: usize) -> String {
    crate::pack::fit_name(format!("material:{model}/{index}"))
}

/// Metadata of a material section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialMeta {
    /// The input material's name.
    pub name: String,
    /// The mesh section whose `triangle_materials` refer to this material by `index`.
    pub mesh_section: String,
    pub index: u32,
    pub material: SchlickMaterial,
    /// Texture section of the colour map (processed: linear, mips).
    pub color_map: Option<String>,
    /// Texture section whose `normal` array is the normal map (the colour map's section when
    /// the normal map was derived from it).
    pub normal_map: Option<String>,
}

/// One layer as stored: repr(C), Pod, 32 bytes:
/// roughness, isotropy, diffuse, glossy, specular, colour r, g, b.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct LayerRecord {
    pub roughness: f32,
    pub isotropy: f32,
    pub diffuse: f32,
    pub glossy: f32,
    pub specular: f32,
    pub color: [f32; 3],
}
const _: () = assert!(size_of::<LayerRecord>() == 32);

/// The material as stored for the GPU: repr(C), Pod, 96 bytes (std140/std430 compatible: every
/// vec4 group starts on 16 bytes). `flags` bit 0: has colour map, bit 1: has normal map.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct MaterialRecord {
    pub top: LayerRecord,
    pub bottom: LayerRecord,
    pub bump_height: f32,
    pub translucence: f32,
    pub opacity: f32,
    pub flags: u32,
    pub emission: [f32; 3],
    pub reserved: f32,
}
const _: () = assert!(size_of::<MaterialRecord>() == 96);

fn layer_record(l: &SchlickLayer) -> LayerRecord {
    LayerRecord {
        roughness: l.roughness,
        isotropy: l.isotropy,
        diffuse: l.diffuse,
        glossy: l.glossy,
        specular: l.specular,
        color: l.color,
    }
}

/// The GPU record of a material.
pub fn material_record(m: &SchlickMaterial) -> MaterialRecord {
    let flags =
        u32::from(m.color_map.is_some()) | (u32::from(m.normal_map != NormalMap::None) << 1);
    MaterialRecord {
        top: layer_record(&m.layers[0]),
        bottom: layer_record(&m.layers[1]),
        bump_height: m.bump_height,
        translucence: m.translucence,
        opacity: m.opacity,
        flags,
        emission: m.emission,
        reserved: 0.0,
    }
}

pub fn to_section(name: &str, meta: &MaterialMeta) -> Section {
    let mut b = SectionBuilder::new(KIND, name);
    // 24 f32 per record: the format is f32 with 24 components.
    b.meta(meta).array(
        "params",
        ArrayFormat::F32,
        24,
        &[material_record(&meta.material)],
    );
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<MaterialMeta, ParseError> {
    let meta: MaterialMeta = v.meta()?;
    meta.material
        .validate()
        .map_err(|m| ParseError::new(format!("material {:?}", meta.name), m))?;
    Ok(meta)
}

fn layer_json(l: &SchlickLayer) -> Value {
    json!({"roughness": l.roughness, "isotropy": l.isotropy, "diffuse": l.diffuse,
           "glossy": l.glossy, "specular": l.specular, "color": l.color})
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let meta = from_section(v)?;
    let m = &meta.material;
    let normal_source = match m.normal_map {
        NormalMap::None => Value::Null,
        NormalMap::Explicit(_) => json!("explicit"),
        NormalMap::FromColor(_) => json!("from_color"),
    };
    Ok(json!({
        "name": meta.name,
        "mesh": meta.mesh_section,
        "index": meta.index,
        "layers": [layer_json(&m.layers[0]), layer_json(&m.layers[1])],
        "bump_height": m.bump_height,
        "translucence": m.translucence,
        "opacity": m.opacity,
        "emission": m.emission,
        "color_map": meta.color_map,
        "normal_map": meta.normal_map,
        "normal_map_source": normal_source,
    }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let rec: Vec<[f32; 24]> = v.array_vec("params")?;
    Ok(json!({ "params": rec.iter().map(|r| r.to_vec()).collect::<Vec<_>>() }))
}
