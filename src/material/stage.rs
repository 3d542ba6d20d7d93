//! The `material` stage: a model's materials, tangents and converted textures, one unit per
//! model inside the scene's own units (its registry line is in `crate::graph::stage::REGISTRY`).

use crate::diag;
use crate::diag::Diagnostic;
use crate::error::Result;
use crate::pack::section::ArrayFormat::F32;
use crate::pack::section::SectionView;
use crate::stage::kind::{Finding, Findings, Naming, SectionKind};
use crate::stage::{Output, Per, Phase, Preset, Reads, Stage, StageDef, UnitCtx, report_of};

/// 2: Xfrog's default material gets the thesis' leaf (issue 16).
pub const VERSION: u32 = 2;

/// A model's materials, tangents and converted textures (`material`).
pub struct Material;
impl Stage for Material {
    type Options = crate::material::MaterialOptions;
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    fn options_in(&self, _: Preset) -> Self::Options {
        crate::material::MaterialOptions::DEFAULT
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "material",
            version: VERSION,
            per: Per::Model,
            writes: &["material", "texture", "tangents"],
            actions: &["model"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: &["texture", "mesh"],
            ..Reads::default()
        }
    }
    fn phase(&self) -> Phase {
        Phase::Source
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (s, mut r) = crate::material::bake_materials(cx.view(), o)?;
        let warnings = diag::tagged(&MATERIAL_TEXTURE_MISSING, std::mem::take(&mut r.warnings));
        Ok(Output {
            sections: s,
            report: report_of(&r),
            warnings,
            ..Default::default()
        })
    }
}

/// The section kinds the `material` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[
    SectionKind {
        kind: crate::material::section::KIND,
        naming: Naming::Qualified,
        arrays: &[("params", &[F32], 24)],
        decode: |v| crate::material::section::from_section(v).map(drop),
        views: Some((
            crate::material::section::summary,
            crate::material::section::data,
        )),
        check: Some(check_material),
    },
    SectionKind {
        kind: crate::mesh::tangents::KIND,
        naming: Naming::Qualified,
        arrays: &[("tangents", &[F32], 4)],
        decode: |v| crate::mesh::tangents::from_section(v).map(drop),
        views: Some((crate::mesh::tangents::summary, crate::mesh::tangents::data)),
        check: Some(check_tangents),
    },
];

fn check_material(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = crate::material::section::from_section(v) else {
        return;
    };
    f.reference("mesh_section", &meta.mesh_section, "mesh");
    for m in [&meta.color_map, &meta.normal_map].into_iter().flatten() {
        f.reference("color_map/normal_map", m, "texture");
    }
}

fn check_tangents(v: &SectionView, f: &mut Findings) {
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

/// `material.texture-missing`.
pub const MATERIAL_TEXTURE_MISSING: Diagnostic = Diagnostic::warning(
    "material.texture-missing",
    "a texture the material names is not in the pack; the material renders untextured",
);

/// The warnings the `material` stage gives (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[MATERIAL_TEXTURE_MISSING];
