//! The `linespace` stage: the N-tree with line spaces of the placed scene (its registry line is
//! in `crate::graph::stage::REGISTRY`).

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
