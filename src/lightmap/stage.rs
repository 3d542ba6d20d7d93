//! The `lightmap` stage (the terrain's light map) and the `atlas` stage (the object light maps
//! in atlases), and the trace structures every lighting unit of a bake shares ([`TraceCell`]).
//! Their registry lines are in `crate::graph::stage::REGISTRY`.

use crate::error::ParseError;
use crate::error::Result;
use crate::pack::section::ArrayFormat::{F32, U8, U32};
use crate::pack::section::SectionView;
use crate::pack::{Pack, Section};
use crate::stage::kind::{Findings, Naming, SectionKind};
use crate::stage::{
    LIGHTING, Output, Per, Preset, Reads, Shard, SharedTrace, Stage, StageDef, StageKey, UnitCtx,
    UnitInputs,
};
use serde_json::json;

/// 2: texels sampled on the drawn two-triangle surface; the linear albedo; a terrain
/// without colour map has albedo 0.216 as drawn (issue 35).
/// 3: the terrain's self-occlusion by horizon sweeps, the sky above the horizons exact and
/// rays only for the instances and the bounce (`visibility`, issue 37).
pub const LIGHTMAP_VERSION: u32 = 3;
/// 2: the linear albedo (issue 35).
pub const ATLAS_VERSION: u32 = 2;

/// The scene's trace structures and lighting (what the lighting units trace against).
pub type Traced = (
    crate::trace::pack_scene::TraceScene,
    crate::lightmap::BakeLight,
);

/// The trace structures over one view, built once by the first unit that asks.
pub struct TraceCell {
    view: Pack,
    cell: std::sync::OnceLock<Traced>,
}

impl TraceCell {
    /// The structures of the sections of a lighting unit's inputs.
    pub fn new(inputs: &UnitInputs) -> TraceCell {
        TraceCell {
            view: Pack::from_sections(inputs.sections(), inputs.scope.view_name),
            cell: std::sync::OnceLock::new(),
        }
    }

    /// Builds them if not built yet. No lock is held while building: a thread waiting on the
    /// build's own parallel jobs may take up another unit's queued job (rayon runs queued jobs
    /// while it waits) and ask again from within the build; such a nested request builds its
    /// own (same) structures and the first kept wins.
    pub fn get(&self) -> Result<&Traced> {
        if let Some(t) = self.cell.get() {
            return Ok(t);
        }
        let light = super::scene_lighting(&self.view)?;
        let ts = crate::trace::pack_scene::trace_scene(&self.view)?;
        let _ = self.cell.set((ts, light));
        Ok(self.cell.get().expect("set above"))
    }
}

impl SharedTrace for TraceCell {
    fn get(&self) -> Result<&(dyn std::any::Any + Send + Sync)> {
        Ok(TraceCell::get(self)?)
    }
}

/// The terrain's light map (`lightmap`).
pub struct Lightmap;
impl Stage for Lightmap {
    type Options = crate::lightmap::LightmapOptions;
    fn kinds(&self) -> &'static [SectionKind] {
        KINDS
    }
    /// The preview: 16 rays with 4 sun rays, at most 1025² texels, 16 horizon directions. The
    /// final pipeline: 256 rays with 32 sun rays at every texel.
    fn options_in(&self, preset: Preset) -> Self::Options {
        use crate::lightmap::LightmapOptions;
        let d = LightmapOptions::DEFAULT;
        match preset {
            Preset::Default => d,
            Preset::Preview | Preset::Ci => LightmapOptions {
                max_resolution: Some(1025),
                samples: 16,
                sun_samples: 4,
                // 16 horizon directions: the sweeps cost a third of 32's (1.3 against 4.5 CPU s
                // at 1025²), the error is the instances' (docs/PERFORMANCE.md, issue 37).
                horizon_lattice: 2,
                ..d
            },
            Preset::Final => LightmapOptions {
                samples: 256,
                sun_samples: 32,
                trace_step: 1,
                trace_spacing: 0.0,
                ..d
            },
        }
    }
    fn needs(&self) -> &'static [&'static str] {
        &["sky"]
    }
    fn check(&self, o: &Self::Options) -> std::result::Result<(), String> {
        o.check()
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "lightmap",
            version: LIGHTMAP_VERSION,
            per: Per::Terrain,
            writes: &["lightmap"],
            actions: &["lightmap", "lightmap-join"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    /// The options the terrain's map reads (the tracer only when not `cpu`).
    fn key(&self, _: &UnitInputs, lm: &Self::Options, k: &mut StageKey) -> Result<()> {
        let mut o = json!({"resolution": lm.resolution, "max_resolution": lm.max_resolution, "samples": lm.samples, "sun_samples": lm.sun_samples, "mode": lm.mode,
            "visibility": lm.visibility, "horizon_lattice": lm.horizon_lattice});
        if lm.filter_range > 0.0 && lm.filter_radius > 0 {
            o["filter"] = json!({"radius": lm.filter_radius, "range": lm.filter_range});
        }
        if lm.trace_step > 1 {
            o["trace_step"] = lm.trace_step.into();
        }
        if lm.trace_spacing > 0.0 {
            o["trace_spacing"] = lm.trace_spacing.into();
        }
        crate::trace::keyed_tracer(&mut o, lm.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced::<Traced>()?;
        let s = crate::lightmap::terrain_sections(ts, light, o)?;
        Ok(Output {
            report: json!({"texels": texels(&s)}),
            sections: s,
            ..Default::default()
        })
    }
}

/// The object light maps in atlases (`atlas`).
pub struct Atlas;
impl Stage for Atlas {
    type Options = crate::lightmap::LightmapOptions;
    /// The light map's options (the registry's line gives it the `lightmap` table).
    fn options_in(&self, preset: Preset) -> Self::Options {
        Lightmap.options_in(preset)
    }
    fn needs(&self) -> &'static [&'static str] {
        &["sky"]
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "atlas",
            version: ATLAS_VERSION,
            per: Per::Scene,
            writes: &["lightmap"],
            actions: &["atlas"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    fn unit_name(&self, _: Option<&str>, _: Option<&Shard>) -> String {
        "objects".into()
    }
    fn key(&self, _: &UnitInputs, lm: &Self::Options, k: &mut StageKey) -> Result<()> {
        let mut o = json!({"samples": lm.samples, "sun_samples": lm.sun_samples, "mode": lm.mode, "max_instances": lm.max_instances, "atlas": lm.atlas});
        crate::trace::keyed_tracer(&mut o, lm.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced::<Traced>()?;
        let s = crate::lightmap::object_sections(cx.view(), ts, light, o)?;
        Ok(Output {
            report: json!({"atlases": s.len()}),
            sections: s,
            ..Default::default()
        })
    }
}

/// The texels of light-map sections (their first arrays).
fn texels(sections: &[Section]) -> u64 {
    sections
        .iter()
        .filter_map(|s| crate::pack::section::SectionView::parse(&s.payload, 0).ok())
        .filter_map(|v| v.arrays.first().map(|a| a.count))
        .sum()
}

/// The section kinds the `lightmap` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::lightmap::section::KIND,
    naming: Naming::Prefixed,
    arrays: &[
        ("irradiance", &[F32], 4),
        ("indirect", &[F32], 4),
        ("coverage", &[U8], 1),
        ("tiles", &[F32], 4),
        ("atlas_uv", &[F32], 2),
        ("vertex_source", &[U32], 1),
        ("indices", &[U32], 3),
        ("triangle_chart", &[U32], 1),
        ("charts", &[U32], 4),
        ("lightmap_uv", &[F32], 2),
    ],
    decode: decode_lightmap,
    views: Some((
        crate::lightmap::section::summary,
        crate::lightmap::section::data,
    )),
    check: Some(check_lightmap),
}];

/// The terrain's light map, or an object atlas (told apart by its `vertex_source` array).
fn decode_lightmap(v: &SectionView) -> Result<(), ParseError> {
    if v.info("vertex_source").is_some() {
        crate::lightmap::atlas_section::from_section(v).map(drop)
    } else {
        crate::lightmap::section::from_section(v).map(drop)
    }
}

fn check_lightmap(v: &SectionView, f: &mut Findings) {
    let Ok(meta) = v.meta::<crate::lightmap::section::LightmapMeta>() else {
        return;
    };
    if meta.surface != "terrain" {
        f.reference("surface", &meta.surface, "mesh");
    } else {
        f.reference("surface", "terrain", "terrain");
    }
}
