//! The `lod` stage: a model's levels of detail, one unit per model (its registry line is in
//! `crate::graph::stage::REGISTRY`).

use crate::error::Result;
use crate::pack::section::ArrayFormat::{F32, U8, U32};
use crate::pack::section::SectionView;
use crate::stage::kind::{Finding, Findings, Naming, SectionKind};
use crate::stage::{
    MODEL_SURFACE, Output, Per, Preset, Reads, Stage, StageDef, UnitCtx, report_of,
};

/// 1: the `lod` stage (issue 14): meshopt levels, leaf-card thinning, impostor atlas.
/// 2: cards keep their triangles, a level's error counts the cards it removes (issue 14).
/// 3: the model's skeleton (TXF line and point arrays) kept as the farthest representation.
/// 4: impostor and skeleton colours from the linear albedo (issue 35).
/// 5: the impostor normal's alpha is the surface's material index (issue 35).
pub const VERSION: u32 = 5;

/// A model's levels of detail (`lod`).
pub struct Lod;
impl Stage for Lod {
    type Options = crate::lod::LodOptions;
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    fn options_in(&self, preset: Preset) -> Self::Options {
        use crate::lod::LodOptions;
        match preset {
            Preset::Default => LodOptions::DEFAULT,
            Preset::Preview | Preset::Ci => LodOptions::preview(),
            Preset::Final => LodOptions::final_quality(),
        }
    }
    fn check(&self, o: &Self::Options) -> std::result::Result<(), String> {
        o.check()
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "lod",
            version: VERSION,
            per: Per::Model,
            writes: &["lod"],
            actions: &["lod"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: MODEL_SURFACE,
            ..Reads::default()
        }
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (s, r) =
            crate::lod::bake_lod(cx.view(), &crate::mesh::section::unit_mesh_name(cx)?, o)?;
        Ok(Output {
            sections: vec![s],
            report: report_of(&r),
            ..Default::default()
        })
    }
}

/// The section kinds the `lod` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::lod::section::KIND,
    naming: Naming::Qualified,
    arrays: &[
        ("positions", &[F32], 3),
        ("vertex_source", &[U32], 1),
        ("indices", &[U32], 3),
        ("triangle_materials", &[U32], 1),
        ("impostor_color", &[U8], 4),
        ("impostor_normal", &[U8], 4),
        ("impostor_depth", &[U8], 1),
        ("skeleton_lines", &[F32], 3),
        ("skeleton_points", &[F32], 3),
    ],
    decode: |v| crate::lod::section::from_view(v, None).map(drop),
    views: Some((crate::lod::section::summary, crate::lod::section::data)),
    check: Some(check_lod),
}];

fn check_lod(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::lod::section::LodMeta>() else {
        return;
    };
    f.reference("mesh_section", &meta.mesh_section, "mesh");
    f.0.push(Finding::BakedFor {
        mesh: meta.mesh_section.clone(),
        vertices: meta.mesh_vertices as u64,
    });
}
