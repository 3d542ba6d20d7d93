//! The `bittree` stage: the BitTree of the scene's instances (its registry line is in
//! `crate::graph::stage::REGISTRY`).

use crate::diag::Diagnostic;
use crate::error::{Error, Result};
use crate::pack::section::ArrayFormat::{F32, U8, U16, U32};
use crate::stage::kind::{Naming, SectionKind};
use crate::stage::{
    Output, Per, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs, Warning,
};
use serde_json::json;

/// 2: instances within 1 mm of each other share a leaf (the `shared` array) instead of
/// forcing deeper levels or failing (issue 16).
/// 3: per-instance residuals within the leaf cell (`residual`, issue 35).
pub const VERSION: u32 = 3;

/// The BitTree of the scene's instances (`bittree`): the instances of the `instances` section
/// (the graph's, from the scene's plan; a pack's for `bake bittree`), over the area
/// [`crate::bittree::section::area_of`] makes of them and the scene's area of interest (from
/// the scene's plan where the unit is given one: the graph, `bake unit bittree`, `bake bittree
/// SCENE.eco`; no section records it, so over a pack alone the instances' bounds).
pub struct Bittree;
impl Bittree {
    /// The instances and the area of the unit's inputs.
    fn instances(u: &UnitInputs) -> Result<(crate::model::Instances, crate::model::Rect)> {
        let first = u.scope.first;
        let e = match u
            .of_kind(crate::ingest::instances_section::KIND)?
            .as_slice()
        {
            [e] => *e,
            [] => {
                return Err(Error::invalid_at(
                    first,
                    "sections",
                    "no `instances` section: nothing for the BitTree to encode",
                ));
            }
            more => {
                return Err(Error::invalid_at(
                    first,
                    "sections",
                    format!("{} `instances` sections; a scene has one", more.len()),
                ));
            }
        };
        let v = crate::pack::section::SectionView::parse(&e.payload, 0)
            .map_err(|err| Error::invalid(first, err))?;
        let (_, inst) = crate::ingest::instances_section::from_section(&v)
            .map_err(|err| Error::invalid(first, err))?;
        let aoi = u.scene_if_given()?.map(|p| p.scene.aoi);
        let area = crate::bittree::section::area_of(&inst, aoi);
        Ok((inst, area))
    }
}
impl Stage for Bittree {
    type Options = crate::bittree::BitTreeOptions;
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    fn options_in(&self, _: Preset) -> Self::Options {
        crate::bittree::BitTreeOptions::DEFAULT
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "bittree",
            version: VERSION,
            per: Per::Scene,
            writes: &["bittree"],
            actions: &["bittree"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: &["instances"],
            scene: true,
            ..Reads::default()
        }
    }
    /// The options, the area, then the `instances` section.
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        let (_, area) = Self::instances(u)?;
        k.options(o).options(&(area.origin, area.extent)).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (inst, area) = Self::instances(cx)?;
        let report = json!({"instances": inst.items.len()});
        Ok(
            match crate::bittree::section::to_section("bittree", &inst, area, o) {
                Ok(s) => Output {
                    report,
                    sections: vec![s],
                    ..Default::default()
                },
                Err(e) => Output {
                    report,
                    warnings: vec![Warning::new(
                        &BITTREE_NOT_ENCODED,
                        "",
                        format!("no BitTree: {e}"),
                    )],
                    ..Default::default()
                },
            },
        )
    }
}

/// The section kinds the `bittree` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::bittree::section::KIND,
    naming: Naming::Kind,
    arrays: &[
        ("bits", &[U8], 1),
        ("scale", &[F32], 1),
        ("rotation", &[U16], 1),
        ("model", &[U16], 1),
        ("layer", &[U16], 1),
        ("residual", &[U16], 2),
        ("shared", &[U32], 1),
    ],
    decode: |v| crate::bittree::section::from_section(v).map(drop),
    views: Some((
        crate::bittree::section::summary,
        crate::bittree::section::data,
    )),
    check: None,
}];

/// `bittree.not-encoded`.
pub const BITTREE_NOT_ENCODED: Diagnostic = Diagnostic::warning(
    "bittree.not-encoded",
    "the instances could not be encoded as a BitTree; the pack has no bittree section",
);

/// The warnings the `bittree` stage gives (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[BITTREE_NOT_ENCODED];
