//! The `prt` stage: a model's precomputed radiance transfer, one unit per model (its registry
//! line is in `crate::graph::stage::REGISTRY`).

use crate::diag::Diagnostic;
use crate::error::Result;
use crate::pack::section::ArrayFormat::F32;
use crate::pack::section::SectionView;
use crate::stage::kind::{Finding, Findings, Naming, SectionKind};
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
    fn diagnostics(&self) -> &'static [Diagnostic] {
        DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
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

/// The section kinds the `prt` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::prt::pack::KIND,
    naming: Naming::Qualified,
    arrays: &[("transfer", &[F32], 3), ("gpu", &[F32], 4)],
    decode: |v| crate::prt::pack::from_section(v).map(drop),
    views: Some((crate::prt::pack::summary, crate::prt::pack::data)),
    check: Some(check_prt),
}];

fn check_prt(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::prt::pack::PrtMeta>() else {
        return;
    };
    f.reference("mesh", &meta.mesh, "mesh");
    f.0.push(Finding::VertexCount {
        mesh: meta.mesh.clone(),
        count: meta.vertices as u64,
        array: "transfer",
    });
}

/// `prt.triangles-non-finite`.
pub const PRT_TRIANGLES_NON_FINITE: Diagnostic = Diagnostic::warning(
    "prt.triangles-non-finite",
    "triangles with non-finite positions; left out of the BVH",
);
/// `prt.texture-unreadable`.
pub const PRT_TEXTURE_UNREADABLE: Diagnostic = Diagnostic::warning(
    "prt.texture-unreadable",
    "a texture section the alpha test needs does not decode; treated as opaque",
);
/// `prt.texture-missing`.
pub const PRT_TEXTURE_MISSING: Diagnostic = Diagnostic::warning(
    "prt.texture-missing",
    "a texture was not decoded into the pack; treated as opaque and white",
);

/// The warnings the `prt` stage gives (docs/DIAGNOSTICS.md), reached through its registry line.
const DIAGNOSTICS: &[Diagnostic] = &[
    PRT_TRIANGLES_NON_FINITE,
    PRT_TEXTURE_UNREADABLE,
    PRT_TEXTURE_MISSING,
];
