//! The `sky` stage: the sky's cube map, sun and SH from `--sky` or the built-in clear sky (its
//! registry line is in `crate::graph::stage::REGISTRY`).

use crate::diag::Diagnostic;
use crate::error::ParseError;
use crate::error::Result;
use crate::pack::section::ArrayFormat::{F16, F32};
use crate::pack::section::SectionView;
use crate::stage::kind::{Naming, SectionKind};
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
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
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

/// The section kinds the `sky` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[
    SectionKind {
        kind: crate::sky::source_section::KIND,
        naming: Naming::Kind,
        arrays: &[("texels", &[F32, F16], 4)],
        decode: decode_sky,
        views: Some((
            crate::sky::source_section::summary,
            crate::sky::source_section::data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::sky::section::SUN_KIND,
        naming: Naming::Kind,
        arrays: &[],
        decode: |v| crate::sky::section::sun_from_section(v).map(drop),
        views: Some((
            crate::sky::section::sun_summary,
            crate::sky::section::sun_data,
        )),
        check: None,
    },
    SectionKind {
        kind: crate::sky::section::SH_KIND,
        naming: Naming::Kind,
        arrays: &[("radiance", &[F32], 3), ("irradiance", &[F32], 3)],
        decode: |v| crate::sky::section::sh_from_section(v).map(drop),
        views: Some((
            crate::sky::section::sh_summary,
            crate::sky::section::sh_data,
        )),
        check: None,
    },
];

fn decode_sky(v: &SectionView) -> Result<(), ParseError> {
    if crate::sky::source_section::is_cube(v)? {
        crate::sky::section::cube_from_section(v).map(drop)
    } else {
        crate::sky::source_section::from_section(v).map(drop)
    }
}

/// `sky.sun-clipped`.
pub const SKY_SUN_CLIPPED: Diagnostic = Diagnostic::warning(
    "sky.sun-clipped",
    "the sun looks clipped in the sky image; its irradiance is a lower bound",
);
/// `sky.radiance-clamped`.
pub const SKY_RADIANCE_CLAMPED: Diagnostic = Diagnostic::warning(
    "sky.radiance-clamped",
    "sky radiance above 65504 was clamped to the half-float range",
);

/// The warnings of the `sky` stage and its command (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[SKY_SUN_CLIPPED, SKY_RADIANCE_CLAMPED];
