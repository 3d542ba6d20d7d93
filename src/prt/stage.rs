//! The `prt` stage: a model's precomputed radiance transfer, one unit per model (its registry
//! line is in `crate::graph::stage::REGISTRY`).

use crate::error::Result;
use crate::stage::{
    MODEL_SURFACE, Output, Per, Preset, Reads, Stage, StageDef, UnitCtx, UnitInputs, report_of,
};

/// 2: duplicate vertices (position, normal, material) welded, sharing one transfer (issue 19).
/// 3: no Russian roulette at the first hit (issue 19).
/// 4: `prt.sides` (default `auto`): the back side of one-sided materials is not traced
/// (zero transfer; issue 19).
/// 5: one linear albedo and translucence for every stage (`material::convert::diffuse_albedo`,
/// `translucence`): authored colours no longer sRGB-decoded, authored materials opaque
/// (issue 35).
pub const VERSION: u32 = 5;

/// A model's precomputed radiance transfer (`prt`).
pub struct Prt;
impl Stage for Prt {
    type Options = crate::prt::transfer::PrtOptions;
    /// PRT 64 paths in the preview, 1,024 paths and 4 bounces in the final pipeline.
    fn options_in(&self, preset: Preset) -> Self::Options {
        use crate::prt::transfer::PrtOptions;
        match preset {
            Preset::Default => PrtOptions::standard(),
            Preset::Preview | Preset::Ci => PrtOptions::preview(),
            Preset::Final => PrtOptions::final_quality(),
        }
    }
    fn check(&self, o: &Self::Options) -> std::result::Result<(), String> {
        o.check()
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "prt",
            version: VERSION,
            per: Per::Model,
            writes: &["prt"],
            actions: &["prt"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: MODEL_SURFACE,
            ..Reads::default()
        }
    }
    /// The mesh's vertices.
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        let view = u.view();
        let mesh = crate::mesh::section::unit_mesh_name(u).ok()?;
        view.find(&mesh)
            .and_then(|e| view.view(e).ok())
            .and_then(|v| v.info("positions").map(|a| a.count))
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let mut warnings = Vec::new();
        let (s, r) = crate::prt::pack::prt_mesh(
            cx.view(),
            &crate::mesh::section::unit_mesh_name(cx)?,
            o,
            cx.progress,
            &mut warnings,
        )?;
        Ok(Output {
            sections: vec![s],
            report: report_of(&r),
            warnings,
            ..Default::default()
        })
    }
}
