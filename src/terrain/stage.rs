//! The `terrain` stage: the prepared terrain over the terrain's sections from the scene (its
//! registry line is in `crate::graph::stage::REGISTRY`).

use crate::error::Result;
use crate::stage::{
    Output, Per, Phase, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs, report_of,
};

/// 1: the terrain's four-tap heights, normal map and min/max quadtree.
pub const VERSION: u32 = 1;

/// The prepared terrain (`terrain`) over the terrain's sections from the scene.
pub struct Terrain;
impl Stage for Terrain {
    type Options = ();
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
