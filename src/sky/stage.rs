//! The `sky` stage: the sky's cube map, sun and SH from `--sky` or the built-in clear sky (its
//! registry line is in `crate::graph::stage::REGISTRY`).

use crate::error::Result;
use crate::stage::{Output, Per, Preset, Reads, Stage, StageDef, StageKey, UnitCtx, UnitInputs};
use serde_json::json;

/// 2: the sun's energy kept through resampling, the ring-mean replacement (issue 16).
/// 3: resampling angles from tables shared between faces and a polynomial atan2 (≤ 1.2e-8
/// rad), f32 bilinear taps; irradiance summed per row (issue 19: values move in the last bits).
pub const VERSION: u32 = 3;

/// The sky's cube map, sun and SH (`sky`): `--sky`, or the built-in clear sky.
pub struct Sky;
impl Stage for Sky {
    type Options = crate::sky::SkyOptions;
    fn options_in(&self, _: Preset) -> Self::Options {
        crate::sky::SkyOptions::DEFAULT
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "sky",
            version: VERSION,
            per: Per::Sky,
            writes: &["sky", "sun", "sh"],
            actions: &["sky"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            sky: true,
            ..Reads::default()
        }
    }
    /// The options, then the sky's contents only (its output does not depend on where it
    /// lies), or the built-in sky's parameters.
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o);
        match u.sky()? {
            Some(path) => {
                k.input("--sky", &crate::pack::hash_file(path)?);
            }
            None => {
                k.options(&format!("{:?}", crate::sky::builtin::BuiltinSky::default()));
            }
        }
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let img = cx.sky()?.map(crate::ingest::skyimage::load).transpose()?;
        let s = crate::sky::scene_sky_sections(
            img.as_ref(),
            &crate::sky::builtin::BuiltinSky::default(),
            o,
        )?;
        Ok(Output {
            report: json!({"sections": s.len()}),
            sections: s,
            ..Default::default()
        })
    }
}
