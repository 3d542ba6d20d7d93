//! Each kind's invariants past its decoder: unit vectors, reserved fields, index ranges, and the
//! references to other sections (which `bake verify` resolves against the whole table). A check
//! sees one section; it records [`Finding`]s in order, offsets relative to the payload's start.

use crate::pack::section::SectionView;
use crate::stage::kind::{Finding, Findings, at, f32s};

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

pub(super) fn terrain(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::terrain::source_section::TerrainMeta>() else {
        return;
    };
    if let Some(s) = &meta.color_section {
        f.reference("color_section", s, "texture");
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

pub(super) fn material(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = crate::material::section::from_section(v) else {
        return;
    };
    f.reference("mesh_section", &meta.mesh_section, "mesh");
    for m in [&meta.color_map, &meta.normal_map].into_iter().flatten() {
        f.reference("color_map/normal_map", m, "texture");
    }
}

pub(super) fn tangents(v: &SectionView, f: &mut Findings) {
    let Ok((meta, t)) = crate::mesh::tangents::from_section(v) else {
        return;
    };
    f.reference("mesh_section", &meta.mesh_section, "mesh");
    if let Some(a) = v.info("tangents") {
        f.unit_vectors(a, t.iter().map(|t| [t[0], t[1], t[2]]));
    }
    f.0.push(Finding::VertexCount {
        mesh: meta.mesh_section.clone(),
        count: t.len() as u64,
        array: "tangents",
    });
}

pub(super) fn prt(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::prt::pack::PrtMeta>() else {
        return;
    };
    f.reference("mesh", &meta.mesh, "mesh");
    f.0.push(Finding::VertexCount {
        mesh: meta.mesh.clone(),
        count: meta.vertices as u64,
        array: "transfer",
    });
}

pub(super) fn lod(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::lod::section::LodMeta>() else {
        return;
    };
    f.reference("mesh_section", &meta.mesh_section, "mesh");
    f.0.push(Finding::BakedFor {
        mesh: meta.mesh_section.clone(),
        vertices: meta.mesh_vertices as u64,
    });
}

pub(super) fn lightmap(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::lightmap::section::LightmapMeta>() else {
        return;
    };
    if meta.surface != "terrain" {
        f.reference("surface", &meta.surface, "mesh");
    } else {
        f.reference("surface", "terrain", "terrain");
    }
}
