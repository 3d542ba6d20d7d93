//! Kind `instances`: every placed model of a scene as a 32-byte POD record.

use crate::error::ParseError;
use crate::model::{Instance, Instances};
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "instances";

/// One instance as stored: repr(C), Pod, 32 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct InstanceRecord {
    pub position: [f32; 3],
    pub scale: f32,
    pub rotation_deg: f32,
    /// Index into the metadata's model list.
    pub model: u32,
    pub layer: i32,
    pub reserved: u32,
}
const _: () = assert!(size_of::<InstanceRecord>() == 32);

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InstancesMeta {
    /// Model names; `mesh_sections[i]` is the section holding model i.
    pub models: Vec<String>,
    pub mesh_sections: Vec<String>,
}

pub fn to_section(name: &str, inst: &Instances, mesh_sections: Vec<String>) -> Section {
    let recs: Vec<InstanceRecord> = inst
        .items
        .iter()
        .map(|i| InstanceRecord {
            position: i.position,
            scale: i.scale,
            rotation_deg: i.rotation_deg,
            model: i.model,
            layer: i.layer,
            reserved: 0,
        })
        .collect();
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(&InstancesMeta {
        models: inst.models.clone(),
        mesh_sections,
    })
    .array("instances", ArrayFormat::U32, 8, &recs);
    b.finish()
}

pub fn from_section(v: &SectionView) -> Result<(InstancesMeta, Instances), ParseError> {
    let meta: InstancesMeta = v.meta()?;
    let recs: Vec<InstanceRecord> = v.array_vec("instances")?;
    let mut items = Vec::with_capacity(recs.len());
    for (k, r) in recs.iter().enumerate() {
        if r.model as usize >= meta.models.len() {
            return Err(ParseError::new(
                format!("instance {k}"),
                format!("model index {} past {}", r.model, meta.models.len()),
            ));
        }
        items.push(Instance {
            model: r.model,
            position: r.position,
            scale: r.scale,
            rotation_deg: r.rotation_deg,
            layer: r.layer,
        });
    }
    Ok((
        meta.clone(),
        Instances {
            models: meta.models,
            items,
        },
    ))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let (_, inst) = from_section(v)?;
    let mut layers: Vec<i32> = inst.items.iter().map(|i| i.layer).collect();
    layers.sort_unstable();
    layers.dedup();
    Ok(json!({ "count": inst.items.len(), "models": inst.models, "layers": layers }))
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, inst) = from_section(v)?;
    let list: Vec<Value> = inst
        .items
        .iter()
        .map(|i| {
            json!({"model": inst.models[i.model as usize], "position": i.position, "scale": i.scale,
                   "rotation_deg": i.rotation_deg, "layer": i.layer})
        })
        .collect();
    Ok(json!({ "instances": list }))
}
