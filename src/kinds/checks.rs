//! Each kind's invariants past its decoder: unit vectors, reserved fields, index ranges, and the
//! references to other sections (which `bake verify` resolves against the whole table). A check
//! sees one section; it records [`Finding`]s in order, offsets relative to the payload's start.

use crate::pack::section::SectionView;
use crate::stage::kind::{Findings, at, f32s};

pub(super) fn mesh(v: &SectionView, f: &mut Findings) {
    let Ok((meta, _)) = crate::mesh::section::from_section(v) else {
        return;
    };
    if let Some((a, normals)) = f32s::<3>(v, "normals") {
        f.unit_vectors(&a, normals.iter().map(|n| [n[0], n[1], n[2]]));
    }
    for t in &meta.textures {
        if let Some(s) = &t.section {
            f.reference("textures[].section", s, "texture");
        }
    }
    for (k, m) in meta.materials.iter().enumerate() {
        let n = meta.textures.len() as u32;
        if m.color_map.is_some_and(|i| i >= n) || m.normal_map.is_some_and(|i| i >= n) {
            let msg = format!("material {k}'s map index is past the {n} textures");
            f.rule("mesh.texture_index", None, 0, msg);
        }
    }
}

pub(super) fn instances(v: &SectionView, f: &mut Findings) {
    let Ok((meta, _)) = crate::ingest::instances_section::from_section(v) else {
        return;
    };
    if meta.mesh_sections.len() != meta.models.len() {
        let msg = format!(
            "{} mesh_sections for {} models",
            meta.mesh_sections.len(),
            meta.models.len()
        );
        f.rule("instances.models", None, 0, msg);
    }
    for s in &meta.mesh_sections {
        f.reference("mesh_sections", s, "mesh");
    }
    type Rec = crate::ingest::instances_section::InstanceRecord;
    let (Some(a), Ok(recs)) = (v.info("instances"), v.array_vec::<Rec>("instances")) else {
        return;
    };
    if let Some(k) = recs.iter().position(|r| r.reserved != 0) {
        let msg = format!("record {k}: reserved field is not zero");
        f.rule(
            "instances.reserved",
            Some("instances"),
            at(a, k as u64) + 28,
            msg,
        );
    }
}
