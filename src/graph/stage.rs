//! The [`Stage`] trait and its registry, [`REGISTRY`] (issue 36, item 1): each stage declares
//! what its units read ([`Reads`]), how a unit's key is made from its options and those inputs,
//! and computes its sections as one function, [`Stage::run`], of a unit context
//! ([`UnitCtx`]) and its options. The context hands out only the declared inputs: its view
//! holds only the sections of the declared kinds, [`UnitInputs::section`] and
//! [`UnitInputs::of_kind`] refuse an undeclared one with an error naming it, and the scene, the
//! sky file and the model file are given only to the stages that declare them. A unit's key
//! hashes every declared section ([`StageKey::finish`] refuses a key that skipped them), so the
//! key covers what the unit reads by construction.
//!
//! The same `run` serves both runners: the graph ([`super::build`], which keeps the sections in
//! memory, caches the units and runs independent ones side by side) and the actions of a
//! build-engine plan (`crate::plan::actions`, `bake unit`, which read the inputs from packs).
//! The plan ([`crate::plan`]) loops over the registry too: a stage's actions read the packs of
//! the units that write the kinds it declares.
//!
//! Not driven by the registry (still written once by hand): the scene's own units (the
//! terrain's and the models' sections from the scene plan, then [`Phase::Source`] stages
//! `ingest`, `material`, `terrain`, which the graph and the `terrain` and `model` actions call
//! through the registry at fixed places), the instances and the build record; the sharding of
//! `envmaps` (by instances) and of the terrain light map (by rows, plans only).
//! `bake unit`'s subcommands of the registered stages are made from the registry
//! (`cli::unit::StageUnit`) and run through [`crate::plan::actions::stage_unit`].
//!
//! One entry runs a unit outside the graph, [`run_unit`]: the plan's actions call it, and so do
//! the per-stage subcommands through [`pack_unit`] (`bake prt` and `bake lod` per mesh,
//! `bake material`, `bake terrain`, `bake lightmap` (the `lightmap` and `atlas` units),
//! `bake envmaps` (one shard of every instance, then [`join_units`]), `bake cluster`
//! (`--weights` is the option `cluster.weights`)) or [`scene_unit`] (whole-scene stages given
//! the command's memory budget and, for an ECO input, the scene's plan: `bake bittree`, and
//! `bake svo` and `bake linespace` over a pack). Still calling their stage's functions, because
//! they do more than the registered unit: `bake sky` (several input files, the built-in sky's
//! parameters, `--sh-only`), and `bake svo` and `bake linespace` over a model file (voxelized in
//! its own frame, its textures read from files).

use super::cache::{self, Key, KeyBuilder};
use super::stages::{Per, StageDef};
use super::{Output, Pipeline, keyed_tracer, report_of, texels, versions};
use crate::diag::{self, Warning};
use crate::error::{Error, Result};
use crate::ingest::confine::SourceNames;
use crate::ingest::eco::ScenePlan;
use crate::ingest::limits::Limits;
use crate::pack::{Pack, Section, fit_name};
use serde::Serialize;
use serde_json::json;
use std::ops::Range;
use std::path::Path;

/// The section kinds the lighting units trace: the placed models with their textures, the
/// terrain, the sky's sun and SH (not the PRT, materials or tangents).
pub const TRACED: &[&str] = &["instances", "mesh", "texture", "terrain", "sun", "sh"];
/// The placed scene's geometry (the SVO and line-space units).
pub const GEOMETRY: &[&str] = &["instances", "mesh", "texture", "terrain"];

/// What the units of a stage read besides their options.
#[derive(Debug, Clone, Copy, Default)]
pub struct Reads {
    /// Sections by kind: every section of these kinds in the unit's scope (a model's own
    /// sections for a per-model unit, the terrain's for the terrain, the scene's otherwise), in
    /// pack order.
    pub kinds: &'static [&'static str],
    /// The scene's plan: what its ECO files place (instances, terrain) and the models' names.
    pub scene: bool,
    /// The `--sky` image (the built-in sky without it).
    pub sky: bool,
    /// The model file and the files it references (a model's ingest).
    pub model_file: bool,
    /// The scene's trace structures, built from the declared sections (which must include
    /// [`TRACED`]).
    pub trace: bool,
}

/// Where a stage runs in the graph and the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Inside the scene's own units: the terrain unit (after the terrain's sections from the
    /// plan) and each model's unit (ingest, then materials).
    Source,
    /// Once per model, over the model's sections, beside the scene's units.
    Model,
    /// Once (or in shards) over the scene's sections, after the instances, in registry order.
    Scene,
}

/// Which part of a sharded stage's work a unit does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Shard {
    /// These instances (the graph's shards).
    Range(Range<usize>),
    /// Shard `.0` (0-based) of `.1` equal parts (a plan's `--shard I/N`).
    Of(usize, usize),
}

impl Shard {
    /// The instances of this shard among `len`.
    pub fn range(&self, len: usize) -> Range<usize> {
        match self {
            Shard::Range(r) => r.clone(),
            Shard::Of(i, n) => (i * len / n)..((i + 1) * len / n),
        }
    }
}

/// What every unit of a bake knows of it, whatever it reads: its arguments.
pub struct Scope<'a> {
    /// The name of the in-memory views (the first scene file as written).
    pub view_name: &'a str,
    /// The scene's source, as sections record it (the first ECO file by name).
    pub source: &'a str,
    /// The memory budget the stages check sizes against.
    pub limits: &'a Limits,
    /// The first scene file (for errors).
    pub first: &'a Path,
    /// `--sky` (given to the stages that declare [`Reads::sky`]).
    pub sky: Option<&'a Path>,
    /// The scene's plan (given to the stages that declare [`Reads::scene`]; a runner that has
    /// none gives `None`, and such a stage fails with an error).
    pub plan: Option<&'a ScenePlan>,
    /// The names of the scene's files and the policy models are read under (a model's ingest).
    pub names: Option<&'a SourceNames>,
    /// The policy models are read under (a model's ingest).
    pub policy: Option<&'a crate::ingest::ReadPolicy>,
}

/// A unit's declared inputs: its sections (only those of declared kinds), the scope's
/// arguments, and the scene, sky and model where declared.
pub struct UnitInputs<'a> {
    stage: &'static str,
    /// The unit's name (a model's name, `terrain`, `scene`, `instances 0..40`, ...).
    pub unit: String,
    reads: Reads,
    sections: Vec<Section>,
    /// The sections in scope that the stage does not declare: (name, kind).
    undeclared: Vec<(String, String)>,
    view: Pack,
    /// The bake's arguments.
    pub scope: &'a Scope<'a>,
    /// The model of a per-model unit: its name in the scene and its file.
    pub model: Option<(&'a str, &'a Path)>,
    /// The shard of a sharded stage's unit.
    pub shard: Option<Shard>,
}

impl<'a> UnitInputs<'a> {
    /// The inputs of `stage`'s unit among `candidates` (the sections in the unit's scope).
    pub fn new(
        stage: &dyn AnyStage,
        scope: &'a Scope<'a>,
        candidates: &[Section],
        model: Option<(&'a str, &'a Path)>,
        shard: Option<Shard>,
    ) -> UnitInputs<'a> {
        let reads = stage.reads();
        let (mut sections, mut undeclared) = (Vec::new(), Vec::new());
        for s in candidates {
            if reads.kinds.contains(&s.kind.as_str()) {
                sections.push(s.clone());
            } else {
                undeclared.push((s.name.clone(), s.kind.clone()));
            }
        }
        let unit = stage.unit_name(model.map(|m| m.0), shard.as_ref());
        let view = Pack::from_sections(&sections, scope.view_name);
        UnitInputs {
            stage: stage.def().name,
            unit,
            reads,
            sections,
            undeclared,
            view,
            scope,
            model,
            shard,
        }
    }

    fn undeclared_error(&self, what: String) -> Error {
        Error::runtime(format!(
            "stage {}, unit {}: reads {what}, which the stage does not declare \
             (it declares the kinds {:?}); a unit's key covers only its declared inputs",
            self.stage, self.unit, self.reads.kinds
        ))
    }

    /// The declared sections, in pack order (what the key hashes).
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// A view of the declared sections only.
    pub fn view(&self) -> &Pack {
        &self.view
    }

    /// The section named `name`: an error if it is in scope but of an undeclared kind, or
    /// not in scope.
    pub fn section(&self, name: &str) -> Result<&Section> {
        if let Some(s) = self.sections.iter().find(|s| s.name == name) {
            return Ok(s);
        }
        match self.undeclared.iter().find(|(n, _)| n == name) {
            Some((n, k)) => Err(self.undeclared_error(format!("section {n:?} of kind {k:?}"))),
            None => Err(Error::runtime(format!(
                "stage {}, unit {}: no section {name:?} among its inputs",
                self.stage, self.unit
            ))),
        }
    }

    /// The sections of kind `kind` (an error if the kind is not declared).
    pub fn of_kind(&self, kind: &str) -> Result<Vec<&Section>> {
        if !self.reads.kinds.contains(&kind) {
            return Err(self.undeclared_error(format!("the sections of kind {kind:?}")));
        }
        Ok(self.sections.iter().filter(|s| s.kind == kind).collect())
    }

    /// The scene's plan (declared by [`Reads::scene`]).
    pub fn scene(&self) -> Result<&'a ScenePlan> {
        if !self.reads.scene {
            return Err(self.undeclared_error("the scene's plan".into()));
        }
        self.scope
            .plan
            .ok_or_else(|| Error::usage(format!("stage {}: no scene given", self.stage)))
    }

    /// The scene's plan where the runner has one (declared by [`Reads::scene`]): a stage
    /// command over a pack has none.
    pub fn scene_if_given(&self) -> Result<Option<&'a ScenePlan>> {
        if !self.reads.scene {
            return Err(self.undeclared_error("the scene's plan".into()));
        }
        Ok(self.scope.plan)
    }

    /// `--sky` (declared by [`Reads::sky`]).
    pub fn sky(&self) -> Result<Option<&'a Path>> {
        if !self.reads.sky {
            return Err(self.undeclared_error("the sky file".into()));
        }
        Ok(self.scope.sky)
    }

    /// The model's name and file (declared by [`Reads::model_file`]).
    pub fn model_file(&self) -> Result<(&'a str, &'a Path)> {
        if !self.reads.model_file {
            return Err(self.undeclared_error("the model file".into()));
        }
        self.model
            .ok_or_else(|| Error::usage(format!("stage {}: no model given", self.stage)))
    }

    /// The mesh section's name of a per-model unit.
    pub fn mesh_name(&self) -> Result<String> {
        let (name, _) = self
            .model
            .ok_or_else(|| Error::usage(format!("stage {}: no model given", self.stage)))?;
        Ok(fit_name(crate::mesh::section::mesh_section_name(name)))
    }
}

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
        let light = crate::lightmap::scene_lighting(&self.view)?;
        let ts = crate::trace::pack_scene::trace_scene(&self.view)?;
        let _ = self.cell.set((ts, light));
        Ok(self.cell.get().expect("set above"))
    }
}

/// What a unit's `run` is given: its inputs, a progress callback, the trace structures.
pub struct UnitCtx<'a> {
    /// The unit's declared inputs.
    pub inputs: &'a UnitInputs<'a>,
    /// Reports work done (for the progress bar).
    pub progress: &'a (dyn Fn(u64) + Sync),
    trace: Option<&'a TraceCell>,
}

impl<'a> std::ops::Deref for UnitCtx<'a> {
    type Target = UnitInputs<'a>;
    fn deref(&self) -> &UnitInputs<'a> {
        self.inputs
    }
}

impl<'a> UnitCtx<'a> {
    /// A context over `inputs`, with `trace` for the stages that trace.
    pub fn new(
        inputs: &'a UnitInputs<'a>,
        progress: &'a (dyn Fn(u64) + Sync),
        trace: Option<&'a TraceCell>,
    ) -> UnitCtx<'a> {
        UnitCtx {
            inputs,
            progress,
            trace,
        }
    }

    /// The trace structures (declared by [`Reads::trace`]).
    pub fn traced(&self) -> Result<&'a Traced> {
        if !self.reads.trace {
            return Err(self.undeclared_error("the scene's trace structures".into()));
        }
        match self.trace {
            Some(t) => t.get(),
            None => Err(Error::runtime(format!(
                "stage {}: no trace structures given",
                self.stage
            ))),
        }
    }
}

/// A unit's cache key under construction: the options first, then (by [`StageKey::inputs`])
/// every declared section; [`StageKey::finish`] refuses a key that did not hash them.
pub struct StageKey<'u> {
    k: KeyBuilder,
    u: &'u UnitInputs<'u>,
    hashed: bool,
}

impl<'u> StageKey<'u> {
    /// A key begun by `k` over the unit `u`'s inputs.
    pub fn new(k: KeyBuilder, u: &'u UnitInputs<'u>) -> StageKey<'u> {
        StageKey {
            k,
            u,
            hashed: false,
        }
    }

    /// Hashes the options (serialized).
    pub fn options(&mut self, o: &impl Serialize) -> &mut Self {
        self.k.options(o);
        self
    }

    /// Every declared section, by name and hash, in pack order.
    pub fn inputs(&mut self) -> &mut Self {
        for s in &self.u.sections {
            self.k.input(&s.name, s.payload.hash());
        }
        self.hashed = true;
        self
    }

    /// One further input (a file by its name, a section derived from the scene).
    pub fn input(&mut self, name: &str, hash: &[u8; 32]) -> &mut Self {
        self.k.input(name, hash);
        self
    }

    /// The key, or an error if it skipped the declared sections.
    pub fn finish(&self) -> Result<Key> {
        if !self.hashed && !self.u.reads.kinds.is_empty() {
            return Err(Error::runtime(format!(
                "stage {}: its key does not hash its declared sections",
                self.u.stage
            )));
        }
        Ok(self.k.finish())
    }
}

/// One stage: what it reads, its options, its key and its computation.
pub trait Stage: Sync {
    /// The part of the pipeline the stage reads.
    type Options: Serialize + Sync;
    /// Its name, version, what a unit covers, the kinds it writes and its `bake unit` actions
    /// (a `static` in the impl).
    fn def(&self) -> &'static StageDef;
    /// What its units read.
    fn reads(&self) -> Reads;
    /// Whether the pipeline turns it on.
    fn on(&self, p: &Pipeline) -> bool;
    /// Its options in the pipeline.
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options;
    /// Where it runs: by default a per-model stage beside the scene's units, others once over the scene.
    fn phase(&self) -> Phase {
        match self.def().per {
            Per::Model => Phase::Model,
            _ => Phase::Scene,
        }
    }
    /// A unit's name: the model's for a per-model unit, the shard's instances for a shard,
    /// `terrain`, `sky` or `scene` otherwise.
    fn unit_name(&self, model: Option<&str>, shard: Option<&Shard>) -> String {
        match (model, shard) {
            (Some(m), _) => m.to_string(),
            (None, Some(s)) => {
                let r = s.range(0);
                format!("instances {}..{}", r.start, r.end)
            }
            (None, None) => match self.def().per {
                Per::Terrain => "terrain".into(),
                Per::Sky => "sky".into(),
                _ => "scene".into(),
            },
        }
    }
    /// The unit's progress total (for the progress bar), if known.
    fn total(&self, _u: &UnitInputs) -> Option<u64> {
        None
    }
    /// The unit's key: by default its options, then its declared sections.
    fn key(&self, _u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o).inputs();
        Ok(())
    }
    /// The unit's sections, report and warnings.
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output>;
    /// The stage's sections from its units' (with each unit's number of instances, for a
    /// sharded stage), in unit order: by default all of them.
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, _o: &Self::Options) -> Result<Vec<Section>> {
        Ok(parts.into_iter().flat_map(|(_, s)| s).collect())
    }
}

/// [`Stage`] without its options type: what the registry holds.
pub trait AnyStage: Sync {
    /// [`Stage::def`].
    fn def(&self) -> &'static StageDef;
    /// [`Stage::reads`].
    fn reads(&self) -> Reads;
    /// [`Stage::on`].
    fn on(&self, p: &Pipeline) -> bool;
    /// [`Stage::phase`].
    fn phase(&self) -> Phase;
    /// [`Stage::unit_name`].
    fn unit_name(&self, model: Option<&str>, shard: Option<&Shard>) -> String;
    /// [`Stage::total`].
    fn total(&self, u: &UnitInputs) -> Option<u64>;
    /// The unit's key, begun by `k` (the bake version, stage, version and unit).
    fn key(&self, u: &UnitInputs, p: &Pipeline, k: KeyBuilder) -> Result<Key>;
    /// [`Stage::run`] with the pipeline's options for the stage.
    fn run(&self, cx: &UnitCtx, p: &Pipeline) -> Result<Output>;
    /// [`Stage::join`] with the pipeline's options for the stage.
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, p: &Pipeline) -> Result<Vec<Section>>;
}

impl<S: Stage> AnyStage for S {
    fn def(&self) -> &'static StageDef {
        Stage::def(self)
    }
    fn reads(&self) -> Reads {
        Stage::reads(self)
    }
    fn on(&self, p: &Pipeline) -> bool {
        Stage::on(self, p)
    }
    fn phase(&self) -> Phase {
        Stage::phase(self)
    }
    fn unit_name(&self, model: Option<&str>, shard: Option<&Shard>) -> String {
        Stage::unit_name(self, model, shard)
    }
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        Stage::total(self, u)
    }
    fn key(&self, u: &UnitInputs, p: &Pipeline, k: KeyBuilder) -> Result<Key> {
        let mut sk = StageKey::new(k, u);
        Stage::key(self, u, self.options(p), &mut sk)?;
        sk.finish()
    }
    fn run(&self, cx: &UnitCtx, p: &Pipeline) -> Result<Output> {
        Stage::run(self, cx, self.options(p))
    }
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, p: &Pipeline) -> Result<Vec<Section>> {
        Stage::join(self, parts, self.options(p))
    }
}

/// One unit of the registered stage `st` outside the graph: its declared inputs among
/// `candidates` (the sections in the unit's scope), the trace structures built over them where
/// declared, no cache. The one entry by which a stage runs besides [`super::build`]: the
/// actions of a plan (`bake unit`, `crate::plan::actions::stage_unit`) and the per-stage
/// subcommands (`bake prt`, `bake lod`, ...: [`pack_unit`]) call it.
pub fn run_unit(
    st: &dyn AnyStage,
    scope: &Scope,
    candidates: &[Section],
    model: Option<(&str, &Path)>,
    shard: Option<Shard>,
    progress: &(dyn Fn(u64) + Sync),
    p: &Pipeline,
) -> Result<Output> {
    let u = UnitInputs::new(st, scope, candidates, model, shard);
    let trace = st.reads().trace.then(|| TraceCell::new(&u));
    st.run(&UnitCtx::new(&u, progress, trace.as_ref()), p)
}

/// One unit of the registered stage `stage` for a stage command (`bake prt`, `bake lod`, ...),
/// through the registry's one entry ([`run_unit`]), as `bake unit` and the
/// graph run it: over `sections` (the command's pack; the unit reads those of its declared
/// kinds), named after `input` (in errors, and as the scene's source the sections record), with
/// the options of `p`. `mesh`: the mesh section (`mesh:<model>`) of a per-model unit.
pub fn pack_unit(
    stage: &str,
    input: &Path,
    sections: &[Section],
    p: &Pipeline,
    mesh: Option<&str>,
    shard: Option<Shard>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Output> {
    let limits = Limits::DEFAULT;
    let at = CommandScope {
        input,
        limits: &limits,
        plan: None,
    };
    pack_unit_of(find_or_err(stage)?, &at, sections, p, mesh, shard, progress)
}

/// What a stage command gives a unit besides its sections: the input it names (in errors, and
/// as the scene's source the sections record), the memory budget (`--max-memory`), and the
/// scene's plan where its input is a scene (read for what no section records: the area of
/// interest of `bittree`).
pub struct CommandScope<'a> {
    /// The command's input.
    pub input: &'a Path,
    /// The memory budget the stages check sizes against.
    pub limits: &'a Limits,
    /// The scene's plan, for an ECO input.
    pub plan: Option<&'a ScenePlan>,
}

/// One unit of the registered whole-scene stage `stage` (`bake bittree`, `bake svo` and `bake
/// linespace` on a pack) through [`run_unit`], over `sections`, as [`pack_unit`] but with the
/// command's budget and, for a scene input, its plan.
pub fn scene_unit(
    stage: &str,
    at: &CommandScope,
    sections: &[Section],
    p: &Pipeline,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Output> {
    pack_unit_of(find_or_err(stage)?, at, sections, p, None, None, progress)
}

/// The registered stage named `stage`, or an error.
fn find_or_err(stage: &str) -> Result<&'static dyn AnyStage> {
    find(stage).ok_or_else(|| Error::runtime(format!("no registered stage {stage:?}")))
}

/// [`pack_unit`] of the stage `st` (a test's toy stage too).
fn pack_unit_of(
    st: &dyn AnyStage,
    at: &CommandScope,
    sections: &[Section],
    p: &Pipeline,
    mesh: Option<&str>,
    shard: Option<Shard>,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Output> {
    let input = at.input;
    let model = match mesh {
        Some(m) => Some(
            m.strip_prefix("mesh:")
                .filter(|n| !n.is_empty())
                .ok_or_else(|| {
                    Error::invalid_at(
                        input,
                        format!("section {m:?}"),
                        "a mesh section's name is mesh:<model>",
                    )
                })?,
        ),
        None => None,
    };
    let view_name = input.display().to_string();
    let source = crate::ingest::confine::SourceNames::first_name(input);
    let scope = Scope {
        view_name: &view_name,
        source: &source,
        limits: at.limits,
        first: input,
        sky: None,
        plan: at.plan,
        names: None,
        policy: None,
    };
    run_unit(
        st,
        &scope,
        sections,
        model.map(|m| (m, input)),
        shard,
        progress,
        p,
    )
}

/// The sections of `pack` of the kinds the registered stage `stage` declares (checksums
/// checked), sharing its memory: a stage command's candidates for [`pack_unit`].
pub fn pack_sections(pack: &Pack, stage: &str) -> Result<Vec<Section>> {
    let kinds = find_or_err(stage)?.reads().kinds;
    let mut out = Vec::new();
    for e in pack.sections() {
        if !kinds.contains(&e.kind.as_str()) {
            continue;
        }
        if !pack.checksum_ok(e) {
            return Err(Error::invalid_at(
                pack.path(),
                format!("section {:?} at byte {}", e.name, e.offset),
                "checksum mismatch: the pack is corrupt",
            ));
        }
        out.push(Section {
            kind: e.kind.clone(),
            name: e.name.clone(),
            payload: pack.shared_payload(e),
        });
    }
    Ok(out)
}

/// The registered per-model stage `stage` over every mesh section of `pack` (read as `input`)
/// through [`pack_unit`], the meshes side by side: each unit's output, in the pack's order.
pub fn pack_mesh_units(
    stage: &str,
    pack: &Pack,
    input: &Path,
    p: &Pipeline,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<Output>> {
    use rayon::prelude::*;
    let candidates = pack_sections(pack, stage)?;
    let meshes: Vec<&str> = pack
        .of_kind(crate::mesh::section::KIND)
        .map(|e| e.name.as_str())
        .collect();
    meshes
        .par_iter()
        .map(|m| pack_unit(stage, input, &candidates, p, Some(m), None, progress))
        .collect()
}

/// The registered stage `stage`'s sections from its units' ([`AnyStage::join`]: each unit's
/// number of instances and sections, in unit order), for a stage command.
pub fn join_units(
    stage: &str,
    parts: Vec<(usize, Vec<Section>)>,
    p: &Pipeline,
) -> Result<Vec<Section>> {
    find_or_err(stage)?.join(parts, p)
}

/// Every stage, in the order of the build key (do not reorder: the key hashes this order; a
/// new stage goes where its inputs are written before it).
pub static REGISTRY: &[&dyn AnyStage] = &[
    &Ingest, &Material, &Terrain, &Sky, &Prt, &Lod, &Lightmap, &Atlas, &Envmaps, &Cluster,
    &Bittree, &Svo, &Linespace,
];

/// The registered stage named `name`.
pub fn find(name: &str) -> Option<&'static dyn AnyStage> {
    REGISTRY.iter().copied().find(|s| s.def().name == name)
}

/// The registered stage named `name` (a stage of this module: present by a test).
fn registered(name: &str) -> &'static dyn AnyStage {
    find(name).unwrap_or_else(|| panic!("stage {name} is not registered"))
}

pub(crate) fn ingest() -> &'static dyn AnyStage {
    registered("ingest")
}
pub(crate) fn material() -> &'static dyn AnyStage {
    registered("material")
}
pub(crate) fn terrain() -> &'static dyn AnyStage {
    registered("terrain")
}

/// Reads one model and its textures (`ingest`).
pub struct Ingest;
impl Stage for Ingest {
    type Options = ();
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "ingest",
            version: versions::INGEST,
            per: Per::Model,
            writes: &["mesh", "texture"],
            actions: &["model"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            model_file: true,
            ..Reads::default()
        }
    }
    fn on(&self, _: &Pipeline) -> bool {
        true
    }
    fn options<'p>(&'p self, _: &'p Pipeline) -> &'p () {
        &()
    }
    fn phase(&self) -> Phase {
        Phase::Source
    }
    /// The scene's policy (roots by their places relative to each other, limits), so that a
    /// hit never skips a refusal, and the model file's contents by its source name.
    fn key(&self, u: &UnitInputs, _: &(), k: &mut StageKey) -> Result<()> {
        let (_, path) = u.model_file()?;
        let (names, policy) = names_policy(u)?;
        k.options(&format!("{:?} {:?}", names.layout(), policy.limits));
        k.input(&names.name(path), &cache::hash_file(path)?);
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, _: &()) -> Result<Output> {
        let (name, path) = cx.model_file()?;
        let (names, policy) = names_policy(cx)?;
        super::ingest_model(name, path, policy, names)
    }
}

fn names_policy<'a>(
    u: &UnitInputs<'a>,
) -> Result<(&'a SourceNames, &'a crate::ingest::ReadPolicy)> {
    u.scope
        .names
        .zip(u.scope.policy)
        .ok_or_else(|| Error::usage("ingest: no read policy given"))
}

/// A model's materials, tangents and converted textures (`material`).
pub struct Material;
impl Stage for Material {
    type Options = crate::material::MaterialOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "material",
            version: versions::MATERIAL,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.material
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.material
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

/// The prepared terrain (`terrain`) over the terrain's sections from the scene.
pub struct Terrain;
impl Stage for Terrain {
    type Options = ();
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "terrain",
            version: versions::TERRAIN,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.terrain
    }
    fn options<'p>(&'p self, _: &'p Pipeline) -> &'p () {
        &()
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

/// The sky's cube map, sun and SH (`sky`): `--sky`, or the built-in clear sky.
pub struct Sky;
impl Stage for Sky {
    type Options = crate::sky::SkyOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "sky",
            version: versions::SKY,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.sky
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.sky
    }
    /// The options, then the sky's contents only (its output does not depend on where it
    /// lies), or the built-in sky's parameters.
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o);
        match u.sky()? {
            Some(path) => {
                k.input("--sky", &cache::hash_file(path)?);
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

/// The mesh and texture sections of a model, final after its materials.
const MODEL_SURFACE: &[&str] = &["mesh", "texture"];

/// A model's precomputed radiance transfer (`prt`).
pub struct Prt;
impl Stage for Prt {
    type Options = crate::prt::transfer::PrtOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "prt",
            version: versions::PRT,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.prt
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.prt
    }
    /// The mesh's vertices.
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        let view = u.view();
        let mesh = u.mesh_name().ok()?;
        view.find(&mesh)
            .and_then(|e| view.view(e).ok())
            .and_then(|v| v.info("positions").map(|a| a.count))
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let mut warnings = Vec::new();
        let (s, r) =
            crate::prt::pack::prt_mesh(cx.view(), &cx.mesh_name()?, o, cx.progress, &mut warnings)?;
        Ok(Output {
            sections: vec![s],
            report: report_of(&r),
            warnings,
            ..Default::default()
        })
    }
}

/// A model's levels of detail (`lod`).
pub struct Lod;
impl Stage for Lod {
    type Options = crate::lod::LodOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "lod",
            version: versions::LOD,
            per: Per::Model,
            writes: &["lod"],
            actions: &["lod"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: MODEL_SURFACE,
            ..Reads::default()
        }
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.lod
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.lod
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (s, r) = crate::lod::bake_lod(cx.view(), &cx.mesh_name()?, o)?;
        Ok(Output {
            sections: vec![s],
            report: report_of(&r),
            ..Default::default()
        })
    }
}

const LIGHTING: Reads = Reads {
    kinds: TRACED,
    scene: false,
    sky: false,
    model_file: false,
    trace: true,
};

/// The terrain's light map (`lightmap`).
pub struct Lightmap;
impl Stage for Lightmap {
    type Options = crate::lightmap::LightmapOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "lightmap",
            version: versions::LIGHTMAP,
            per: Per::Terrain,
            writes: &["lightmap"],
            actions: &["lightmap", "lightmap-join"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.lightmap
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.lightmap
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
        keyed_tracer(&mut o, lm.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced()?;
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
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "atlas",
            version: versions::ATLAS,
            per: Per::Scene,
            writes: &["lightmap"],
            actions: &["atlas"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.atlas
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.lightmap
    }
    fn unit_name(&self, _: Option<&str>, _: Option<&Shard>) -> String {
        "objects".into()
    }
    fn key(&self, _: &UnitInputs, lm: &Self::Options, k: &mut StageKey) -> Result<()> {
        let mut o = json!({"samples": lm.samples, "sun_samples": lm.sun_samples, "mode": lm.mode, "max_instances": lm.max_instances, "atlas": lm.atlas});
        keyed_tracer(&mut o, lm.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced()?;
        let s = crate::lightmap::object_sections(cx.view(), ts, light, o)?;
        Ok(Output {
            report: json!({"atlases": s.len()}),
            sections: s,
            ..Default::default()
        })
    }
}

/// The instances' environment maps (`envmaps`), in shards of instances: each unit writes a
/// cache-only `envmaps-shard` section, joined into `envmaps` ([`join_envmaps`]).
pub struct Envmaps;
impl Stage for Envmaps {
    type Options = crate::envmap::bake::EnvmapOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "envmaps",
            version: versions::ENVMAPS,
            per: Per::Shards,
            writes: &["envmaps"],
            actions: &["envmaps", "envmaps-join"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.envmaps
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.envmaps
    }
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        match &u.shard {
            Some(Shard::Range(r)) => Some(r.len() as u64),
            _ => None,
        }
    }
    /// The options without the tracer, then the tracer only when not `cpu`.
    fn key(&self, _: &UnitInputs, e: &Self::Options, k: &mut StageKey) -> Result<()> {
        let mut o = report_of(e);
        if let Some(m) = o.as_object_mut() {
            m.remove("tracer");
        }
        keyed_tracer(&mut o, e.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced()?;
        let shard = cx
            .shard
            .as_ref()
            .ok_or_else(|| Error::usage("envmaps: a unit covers one shard of instances"))?;
        let range = shard.range(ts.instances.items.len());
        let m = crate::envmap::instance_traced(ts, light, o, range)?;
        Ok(Output {
            report: json!({"instances": m.maps.len(), "rays": m.maps.len() as u64 * o.samples as u64}),
            sections: vec![super::shard_section(&m)],
            ..Default::default()
        })
    }
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, o: &Self::Options) -> Result<Vec<Section>> {
        Ok(vec![join_envmaps(&parts, o)?])
    }
}

/// The graph's shards of `n` instances: `per` instances each (one empty shard for none).
pub fn envmap_shards(n: usize, per: usize) -> Vec<Range<usize>> {
    let per = per.max(1);
    (0..n.max(1))
        .step_by(per)
        .map(|start| start..(start + per).min(n))
        .collect()
}

/// The `envmaps` section from its shards' sections, in shard order (each with its number of
/// instances).
pub fn join_envmaps(
    shards: &[(usize, Vec<Section>)],
    o: &crate::envmap::bake::EnvmapOptions,
) -> Result<Section> {
    let mut maps = crate::envmap::bake::Traced::default();
    for (n, s) in shards {
        maps.extend(super::shard_maps(s, *n)?);
    }
    Ok(crate::envmap::envmaps_section(&maps, o))
}

/// The instances' clustering (`cluster`) over their environment maps.
pub struct Cluster;
impl Stage for Cluster {
    type Options = crate::envmap::cluster::ClusterOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "cluster",
            version: versions::CLUSTER,
            per: Per::Scene,
            writes: &["clusters"],
            actions: &["cluster"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: &["instances", "envmaps"],
            ..Reads::default()
        }
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.cluster
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.cluster
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (s, c, w) = crate::envmap::cluster_sections_warned(cx.view(), o, o.weights)?;
        Ok(Output {
            report: json!({"clusters": c.clustering.samples.len(), "rms_error": c.rms_error(), "max_error": c.max_error(),
                "shared_rms_error": c.clustering.rms_error(),
                "rounds": c.clustering.rounds, "noise_relative": c.clustering.noise,
                "local_components": c.local.as_ref().map_or(0, |l| l.components),
                "compression": crate::envmap::compression(&c, crate::envmap::section::DIM)}),
            sections: s,
            warnings: diag::tagged(&diag::CLUSTER_COMPRESSION_LOW, w),
            ..Default::default()
        })
    }
}

/// The scene's `instances` section, as the graph writes it from the scene's plan.
pub fn instances_section(plan: &ScenePlan) -> Section {
    let meshes = plan
        .models
        .iter()
        .map(|(n, _)| fit_name(crate::mesh::section::mesh_section_name(n)))
        .collect();
    crate::ingest::instances_section::to_section("instances", &plan.scene.instances, meshes)
}

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
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "bittree",
            version: versions::BITTREE,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.bittree
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.bittree
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
                        &diag::BITTREE_NOT_ENCODED,
                        "",
                        format!("no BitTree: {e}"),
                    )],
                    ..Default::default()
                },
            },
        )
    }
}

/// The sparse voxel octree of the placed scene (`svo`): the flattened `svo` where the placed
/// scene fits the memory budget, else the two-level `svo-scene` (one octree per model).
pub struct Svo;
impl Stage for Svo {
    type Options = crate::voxel::voxelize::VoxelizeOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "svo",
            version: versions::SVO,
            per: Per::Scene,
            writes: &["svo", "svo-scene"],
            actions: &["svo"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: GEOMETRY,
            ..Reads::default()
        }
    }
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.svo
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.svo
    }
    /// The options and the scene's source (the section records it), the sections, and the
    /// two-level choice (only when two-level, so the flattened units' keys are as before).
    fn key(&self, u: &UnitInputs, o: &Self::Options, k: &mut StageKey) -> Result<()> {
        k.options(o).options(&u.scope.source).inputs();
        if crate::voxel::geometry::placed_size(u.view())?.svo_two_level(u.scope.limits) {
            k.options(&"two-level");
        }
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let s = cx.scope;
        let (sec, report, left) =
            crate::voxel::geometry::pack_svo_section(cx.view(), o, s.limits, s.first, s.source)?;
        let mut warnings = Vec::new();
        if left.skipped_triangles > 0 {
            warnings.push(Warning::new(
                &diag::SVO_TRIANGLES_WITHOUT_VOXEL,
                "",
                format!(
                    "{} triangles left no voxel (outside the grid or alpha-tested away)",
                    left.skipped_triangles
                ),
            ));
        }
        if left.open_columns > 0 {
            warnings.push(Warning::new(
                &diag::SVO_MESH_NOT_CLOSED,
                "",
                format!(
                    "solid fill: {} columns crossed the surface an odd number of times \
                     (mesh not closed)",
                    left.open_columns
                ),
            ));
        }
        Ok(Output {
            report,
            sections: vec![sec],
            warnings,
            ..Default::default()
        })
    }
}

/// The N-tree with line spaces of the placed scene (`linespace`): the flattened `linespace`
/// where the placed scene fits the memory budget, else the two-level `linespace-scene`.
pub struct Linespace;
impl Stage for Linespace {
    type Options = crate::linespace::ntree::NTreeOptions;
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "linespace",
            version: versions::LINESPACE,
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
    fn on(&self, p: &Pipeline) -> bool {
        p.stages.linespace
    }
    fn options<'p>(&'p self, p: &'p Pipeline) -> &'p Self::Options {
        &p.linespace
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

/// A toy stage for tests: registered beside [`REGISTRY`], it must appear in the graph, the
/// plan and `bake unit`-style execution without any of them naming it.
#[cfg(test)]
pub(crate) mod toy {
    use super::*;
    use crate::pack::{SectionBuilder, hex};

    /// Writes one `toy` section recording the hash of the `instances` section it read, its
    /// option, and how many sections its view held.
    pub(crate) struct Toy {
        /// Also asks for the `sun` section, which it does not declare.
        pub(crate) greedy: bool,
        /// Makes its key without hashing its declared sections.
        pub(crate) lazy_key: bool,
    }

    pub(crate) static DEF: StageDef = StageDef {
        name: "toy",
        version: 1,
        per: Per::Scene,
        writes: &["toy"],
        actions: &["toy"],
    };
    pub(crate) static TOY: Toy = Toy {
        greedy: false,
        lazy_key: false,
    };
    pub(crate) static GREEDY: Toy = Toy {
        greedy: true,
        lazy_key: false,
    };
    pub(crate) static LAZY: Toy = Toy {
        greedy: false,
        lazy_key: true,
    };
    const OPTION: u32 = 7;

    /// The `toy` section's metadata.
    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    pub(crate) struct ToyMeta {
        /// The hash of the `instances` section read (hex).
        pub(crate) instances: String,
        pub(crate) option: u32,
        /// How many sections the unit's view held.
        pub(crate) sections: u64,
    }

    impl Stage for Toy {
        type Options = u32;
        fn def(&self) -> &'static StageDef {
            &DEF
        }
        fn reads(&self) -> Reads {
            Reads {
                kinds: &["instances"],
                ..Reads::default()
            }
        }
        fn on(&self, _: &Pipeline) -> bool {
            true
        }
        fn options<'p>(&'p self, _: &'p Pipeline) -> &'p u32 {
            &OPTION
        }
        fn key(&self, _: &UnitInputs, o: &u32, k: &mut StageKey) -> Result<()> {
            k.options(o);
            if !self.lazy_key {
                k.inputs();
            }
            Ok(())
        }
        fn run(&self, cx: &UnitCtx, o: &u32) -> Result<Output> {
            if self.greedy {
                cx.section(crate::sky::SUN_SECTION)?;
            }
            let inst = cx.section("instances")?;
            let mut b = SectionBuilder::new("toy", "toy");
            b.meta(&ToyMeta {
                instances: hex(inst.payload.hash()),
                option: *o,
                sections: cx.view().sections().len() as u64,
            });
            Ok(Output {
                sections: vec![b.finish()],
                report: json!({"sections": cx.sections().len()}),
                ..Default::default()
            })
        }
    }

    /// The registry with `toy` added at the end.
    pub(crate) fn with(toy: &'static Toy) -> Vec<&'static dyn AnyStage> {
        let mut r: Vec<&'static dyn AnyStage> = REGISTRY.to_vec();
        r.push(toy);
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_registry_declares_its_phases_and_reads_what_earlier_stages_write() {
        let source: Vec<&str> = REGISTRY
            .iter()
            .filter(|s| s.phase() == Phase::Source)
            .map(|s| s.def().name)
            .collect();
        assert_eq!(source, ["ingest", "material", "terrain"]);
        // A stage that traces reads what the trace structures are built from.
        for s in REGISTRY.iter().filter(|s| s.reads().trace) {
            for k in TRACED {
                assert!(s.reads().kinds.contains(k), "{}: {k}", s.def().name);
            }
        }
        // Every kind a stage reads is written by a stage before it or by the graph itself
        // (the source stages read the scene's own sections).
        for (i, s) in REGISTRY.iter().enumerate() {
            if s.phase() == Phase::Source {
                continue;
            }
            for k in s.reads().kinds {
                let written = REGISTRY[..i].iter().any(|w| w.def().writes.contains(k))
                    || crate::graph::stages::GRAPH_WRITES.contains(k);
                assert!(
                    written,
                    "{} reads {k}, which no stage before it writes",
                    s.def().name
                );
            }
        }
    }

    /// A pack with an `instances` section (of no instance) and a `sun` section.
    fn instances_and_sun() -> Vec<Section> {
        let inst = crate::ingest::instances_section::to_section(
            "instances",
            &crate::model::Instances::default(),
            Vec::new(),
        );
        let mut b = crate::pack::SectionBuilder::new("sun", crate::sky::SUN_SECTION);
        b.meta(&0u32);
        vec![inst, b.finish()]
    }

    #[test]
    fn a_stage_command_s_unit_sees_only_its_declared_kinds() {
        let sections = instances_and_sun();
        let limits = Limits::DEFAULT;
        let input = &CommandScope {
            input: Path::new("in.bake"),
            limits: &limits,
            plan: None,
        };
        let p = Pipeline::default();
        let o = pack_unit_of(&toy::TOY, input, &sections, &p, None, None, &|_| {}).unwrap();
        // The toy declares `instances` only: its view held that one section.
        let v = crate::pack::section::SectionView::parse(&o.sections[0].payload, 0).unwrap();
        let meta: toy::ToyMeta = v.meta().unwrap();
        assert_eq!(meta.sections, 1);
        assert_eq!(meta.instances, crate::pack::hex(sections[0].payload.hash()));
        // Asking for the undeclared `sun` section is refused, naming it.
        let e = pack_unit_of(&toy::GREEDY, input, &sections, &p, None, None, &|_| {})
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("\"sun\"") && e.contains("does not declare"),
            "{e}"
        );
    }

    #[test]
    fn a_stage_command_refuses_a_mesh_section_not_named_after_its_model() {
        let p = Pipeline::default();
        for bad in ["box", "mesh:"] {
            let e = pack_unit(
                "lod",
                Path::new("in.bake"),
                &[],
                &p,
                Some(bad),
                None,
                &|_| {},
            )
            .unwrap_err()
            .to_string();
            assert!(e.contains("mesh:<model>") && e.contains("in.bake"), "{e}");
        }
        let e = pack_unit("nope", Path::new("in.bake"), &[], &p, None, None, &|_| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("no registered stage \"nope\""), "{e}");
    }

    #[test]
    fn shards_cover_the_instances_once() {
        for n in [0usize, 1, 5, 40, 41] {
            let s = envmap_shards(n, 20);
            assert_eq!(s.first().map(|r| r.start), Some(0));
            assert_eq!(s.last().map(|r| r.end), Some(n));
            assert!(s.windows(2).all(|w| w[0].end == w[1].start));
            assert_eq!(s.len(), n.max(1).div_ceil(20));
        }
    }
}
