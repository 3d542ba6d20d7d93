//! The `material` stage: a model's materials, tangents and converted textures, one unit per
//! model inside the scene's own units (its registry line is in `crate::graph::stage::REGISTRY`).

use crate::diag;
use crate::error::Result;
use crate::stage::{Output, Per, Phase, Preset, Reads, Stage, StageDef, UnitCtx, report_of};

/// 2: Xfrog's default material gets the thesis' leaf (issue 16).
pub const VERSION: u32 = 2;

/// A model's materials, tangents and converted textures (`material`).
pub struct Material;
impl Stage for Material {
    type Options = crate::material::MaterialOptions;
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
        let warnings = diag::tagged(
            &diag::MATERIAL_TEXTURE_MISSING,
            std::mem::take(&mut r.warnings),
        );
        Ok(Output {
            sections: s,
            report: report_of(&r),
            warnings,
            ..Default::default()
        })
    }
}
