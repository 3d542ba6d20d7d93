//! The `linespace` stage: the N-tree with line spaces of the placed scene (its registry line is
//! in `crate::graph::stage::REGISTRY`).

use crate::pack::section::ArrayFormat::{F32, U32, U64};
use crate::stage::kind::{Naming, SectionKind};

use crate::error::Result;
use crate::stage::{
    GEOMETRY, Output, Per, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs,
};

/// 2: the compact section layout (issue 15).
pub const VERSION: u32 = 2;

/// The N-tree with line spaces of the placed scene (`linespace`): the flattened `linespace`
/// where the placed scene fits the memory budget, else the two-level `linespace-scene`.
pub struct Linespace;
impl Stage for Linespace {
    type Options = crate::linespace::ntree::NTreeOptions;
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    /// On in the final pipeline only (the whole placed scene: large scenes make it large).
    fn on_in(&self, preset: Preset) -> bool {
        preset == Preset::Final
    }
    fn options_in(&self, _: Preset) -> Self::Options {
        crate::linespace::ntree::NTreeOptions::thesis()
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "linespace",
            version: VERSION,
            per: Per::Scene,
            writes: &["linespace", "linespace-scene"],
            actions: &["linespace"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: GEOMETRY,
            ..Reads::default()
        }
    }
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o).options(&u.scope.source).inputs();
        if crate::voxel::geometry::placed_size(u.view())?.linespace_two_level(u.scope.limits) {
            k.options(&"two-level");
        }
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let s = cx.scope;
        let (sec, report) = crate::linespace::scene::pack_linespace_section(
            cx.view(),
            o,
            s.limits,
            s.first,
            s.source,
        )?;
        Ok(Output {
            report,
            sections: vec![sec],
            ..Default::default()
        })
    }
}

/// The section kinds the `linespace` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[
    SectionKind {
        kind: crate::linespace::section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("occupancy", &[U64], 1),
            ("first_child", &[U32], 1),
            ("leaf_tris", &[U32], 1),
            ("tri_indices", &[U32], 1),
            ("triangles", &[F32], 9),
            ("shaft_cells", &[U64], 1),
        ],
        decode: |v| crate::linespace::section::from_section(v).map(drop),
        views: Some((
            crate::linespace::section::summary,
            crate::linespace::section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::linespace::instanced_section::KIND,
        naming: Naming::Kind,
        arrays: &[
            ("occupancy", &[U64], 1),
            ("first_child", &[U32], 1),
            ("leaf_items", &[U32], 1),
            ("item_indices", &[U32], 1),
            ("triangles", &[F32], 9),
            ("instances", &[U32], 8),
            ("heights", &[F32], 1),
            ("shaft_cells", &[U64], 1),
        ],
        decode: |v| crate::linespace::instanced_section::from_section(v).map(drop),
        views: Some((
            crate::linespace::instanced_section::summary,
            crate::linespace::instanced_section::data,
        )),
        check: None,
    },
];
