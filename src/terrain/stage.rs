//! The `terrain` stage: the prepared terrain over the terrain's sections from the scene (its
//! registry line is in `crate::graph::stage::REGISTRY`).

use crate::diag::Diagnostic;
use crate::error::ParseError;
use crate::error::Result;
use crate::pack::section::ArrayFormat::{F32, U8, U32};
use crate::pack::section::SectionView;
use crate::stage::kind::{Findings, Naming, SectionKind};
use crate::stage::{
    Output, Per, Phase, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs, report_of,
};

/// 1: the terrain's four-tap heights, normal map and min/max quadtree.
pub const VERSION: u32 = 1;

/// The prepared terrain (`terrain`) over the terrain's sections from the scene.
pub struct Terrain;
impl Stage for Terrain {
    type Options = ();
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    fn options_in(&self, _: Preset) {}
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "terrain",
            version: VERSION,
            per: Per::Terrain,
            writes: &["terrain", "texture"],
            actions: &["terrain"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: &["texture", "terrain"],
            ..Reads::default()
        }
    }
    fn phase(&self) -> Phase {
        Phase::Source
    }
    /// No options: its sections only.
    fn key(&self, _: &UnitInputs, _: &(), k: &mut StageKey) -> Result<()> {
        k.inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, _: &()) -> Result<Output> {
        let (s, r) = crate::terrain::bake_terrain(cx.view())?;
        Ok(Output {
            sections: s,
            report: report_of(&r),
            ..Default::default()
        })
    }
}

/// The section kinds the `terrain` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::terrain::source_section::KIND,
    naming: Naming::Kind,
    arrays: &[
        ("heights", &[F32], 1),
        ("four_tap", &[F32], 4),
        ("normals", &[U8], 4),
        ("quadtree", &[F32], 2),
        ("quadtree_levels", &[U32], 4),
    ],
    decode: decode_terrain,
    views: Some((
        crate::terrain::source_section::summary,
        crate::terrain::source_section::data,
    )),
    check: Some(check_terrain),
}];

fn decode_terrain(v: &SectionView) -> Result<(), ParseError> {
    if crate::terrain::section::is_prepared(v) {
        crate::terrain::section::from_section(v).map(drop)
    } else {
        crate::terrain::source_section::from_section(v).map(drop)
    }
}

fn check_terrain(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::terrain::source_section::TerrainMeta>() else {
        return;
    };
    if let Some(s) = &meta.color_section {
        f.reference("color_section", s, "texture");
    }
}

/// `terrain.none`.
pub const TERRAIN_NONE: Diagnostic = Diagnostic::warning(
    "terrain.none",
    "`bake terrain`: the input has no terrain section to prepare",
);

/// The warnings of the `terrain` stage and its command (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[TERRAIN_NONE];
