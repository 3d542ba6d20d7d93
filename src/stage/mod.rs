//! The stage interface (issue 36, item 1): what a stage implements in its own folder
//! (`src/<module>/stage.rs`), below the graph that runs it. A [`Stage`] declares its entry
//! ([`StageDef`]: name, version, what a unit covers, the kinds it writes, its `bake unit`
//! actions), what its units read ([`Reads`]), how a unit's key is made from its options and
//! those inputs ([`StageKey`]), and computes its sections as one function, [`Stage::run`], of a
//! unit context ([`UnitCtx`]) and its options. The context hands out only the declared inputs:
//! its view holds only the sections of the declared kinds, [`UnitInputs::section`] and
//! [`UnitInputs::of_kind`] refuse an undeclared one with an error naming it, and the scene, the
//! sky file, the model file and the trace structures are given only to the stages that declare
//! them. A unit's key hashes every declared section ([`StageKey::finish`] refuses a key that
//! skipped them), so the key covers what the unit reads by construction.
//!
//! A stage also declares, in its folder, what the rest of the bake needs of it besides its
//! units: its options type and its switch and options in each [`Preset`] ([`Stage::on_in`],
//! [`Stage::options_in`]), the stages it needs and its options' check, the section kinds it
//! defines ([`Stage::kinds`], [`SectionKind`] rows) and the warnings it gives
//! ([`Stage::diagnostics`]).
//!
//! This module lies below the stages' modules (docs/ARCHITECTURE.md, "Layers"), so a stage's
//! folder can implement it without importing the orchestration layer. It therefore knows no
//! pipeline: the registry's line of a stage (`crate::graph::stage::REGISTRY`, written by the
//! `registry!` macro there) makes the pipeline's switch and table of the stage from what it
//! declares. The runners (the graph, `bake
//! unit`, the stage commands) and the registry are in `crate::graph::stage`.

#![warn(missing_docs)]

pub mod kind;

use crate::error::{Error, Result};
use crate::ingest::confine::SourceNames;
use crate::ingest::eco::ScenePlan;
use crate::ingest::limits::Limits;
use crate::pack::{Pack, Section, hex};
use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::ops::Range;
use std::path::{Path, PathBuf};

pub use crate::diag::Warning;
pub use kind::SectionKind;

/// A file a unit read, with its content hash (`None`: it was looked for and did not exist,
/// so that its appearing later invalidates the entry). In memory `path` is the real path; in a
/// cache entry and the `build` record it is the file's source name
/// ([`crate::ingest::confine::SourceNames`]), placed again in the roots of the bake that reads it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileDep {
    /// The file, placed again in the roots of the bake that reads the record.
    pub path: PathBuf,
    /// BLAKE3 of its contents (hex); `None` where it could not be read.
    pub blake3: Option<String>,
}

/// What a unit computed: sections, the stage's report, warnings, files read beyond its key.
#[derive(Debug, Default)]
pub struct Output {
    /// The unit's sections.
    pub sections: Vec<Section>,
    /// The stage's report (counts).
    pub report: Value,
    /// The unit's warnings.
    pub warnings: Vec<Warning>,
    /// Files read beyond the unit's key (a model's textures).
    pub files: Vec<FileDep>,
}

/// A report's JSON value of `r` (`null` if it does not serialize).
pub fn report_of(r: &impl Serialize) -> Value {
    serde_json::to_value(r).unwrap_or(Value::Null)
}

/// A unit's cache key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Key(pub [u8; 32]);

impl Key {
    /// The key in lower-case hex (the entry's file name).
    pub fn hex(&self) -> String {
        hex(&self.0)
    }
}

/// Builds a [`Key`] from the parts the module doc lists, each length-prefixed so that no two
/// different part lists hash alike.
pub struct KeyBuilder(blake3::Hasher);

impl KeyBuilder {
    /// A key begun with the bake's version, the stage, its version and the unit.
    pub fn new(bake_version: &str, stage: &str, stage_version: u32, unit: &str) -> KeyBuilder {
        let mut k = KeyBuilder(blake3::Hasher::new());
        k.part(b"bake-stage-key");
        k.part(bake_version.as_bytes());
        k.part(stage.as_bytes());
        k.part(&stage_version.to_le_bytes());
        k.part(unit.as_bytes());
        k
    }

    fn part(&mut self, bytes: &[u8]) {
        self.0.update(&(bytes.len() as u64).to_le_bytes());
        self.0.update(bytes);
    }

    /// The options the unit reads, in canonical form (serde JSON of the option struct).
    pub fn options(&mut self, opts: &impl Serialize) -> &mut Self {
        let json = serde_json::to_vec(opts).expect("options serialize to JSON");
        self.part(b"options");
        self.part(&json);
        self
    }

    /// One input: a name (a section name or a file's source name, never a path:
    /// [`crate::ingest::confine::SourceNames`]) and its hash.
    pub fn input(&mut self, name: &str, hash: &[u8; 32]) -> &mut Self {
        self.part(b"input");
        self.part(name.as_bytes());
        self.part(hash);
        self
    }

    /// The key of the parts added.
    pub fn finish(&self) -> Key {
        Key(*self.0.finalize().as_bytes())
    }
}

/// What one unit of a stage covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Per {
    /// One unit per model file of the scene.
    Model,
    /// The scene's terrain.
    Terrain,
    /// The scene's sky.
    Sky,
    /// The whole scene (its instances, the terrain and the models together).
    Scene,
    /// The scene's instances in shards, joined into one section.
    Shards,
}

/// One stage of the graph.
#[derive(Debug, Clone, Copy)]
pub struct StageDef {
    /// The name of its units in the build report, the cache and `--set stages.NAME`.
    pub name: &'static str,
    /// Bumped when its output changes for the same inputs (a constant beside the stage, with its history).
    pub version: u32,
    /// What one unit covers.
    pub per: Per,
    /// The section kinds its units write.
    pub writes: &'static [&'static str],
    /// The `bake unit` subcommands that run it in a plan (a model's ingest and materials are
    /// one action, `model`).
    pub actions: &'static [&'static str],
}

/// The mesh and texture sections of a model, final after its materials.
pub const MODEL_SURFACE: &[&str] = &["mesh", "texture"];

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

/// What the lighting units (`lightmap`, `atlas`, `envmaps`) read: the traced kinds and the
/// trace structures built over them.
pub const LIGHTING: Reads = Reads {
    kinds: TRACED,
    scene: false,
    sky: false,
    model_file: false,
    trace: true,
};

/// The trace structures a runner shares between the lighting units of one bake: built once,
/// by the first unit that asks ([`UnitCtx::traced`] downcasts them to the type their builder
/// makes).
pub trait SharedTrace: Sync {
    /// The structures, built if not built yet.
    fn get(&self) -> Result<&(dyn std::any::Any + Send + Sync)>;
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
    /// The inputs of the unit `unit` of the stage `def` (which reads `reads`) among
    /// `candidates` (the sections in the unit's scope).
    pub fn new(
        def: &'static StageDef,
        reads: Reads,
        unit: String,
        scope: &'a Scope<'a>,
        candidates: &[Section],
        model: Option<(&'a str, &'a Path)>,
        shard: Option<Shard>,
    ) -> UnitInputs<'a> {
        let (mut sections, mut undeclared) = (Vec::new(), Vec::new());
        for s in candidates {
            if reads.kinds.contains(&s.kind.as_str()) {
                sections.push(s.clone());
            } else {
                undeclared.push((s.name.clone(), s.kind.clone()));
            }
        }
        let view = Pack::from_sections(&sections, scope.view_name);
        UnitInputs {
            stage: def.name,
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

    /// The model's name of a per-model unit.
    pub fn model_name(&self) -> Result<&'a str> {
        self.model
            .map(|m| m.0)
            .ok_or_else(|| Error::usage(format!("stage {}: no model given", self.stage)))
    }
}
/// What a unit's `run` is given: its inputs, a progress callback, the trace structures.
pub struct UnitCtx<'a> {
    /// The unit's declared inputs.
    pub inputs: &'a UnitInputs<'a>,
    /// Reports work done (for the progress bar).
    pub progress: &'a (dyn Fn(u64) + Sync),
    trace: Option<&'a dyn SharedTrace>,
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
        trace: Option<&'a dyn SharedTrace>,
    ) -> UnitCtx<'a> {
        UnitCtx {
            inputs,
            progress,
            trace,
        }
    }

    /// The trace structures (declared by [`Reads::trace`]), of the type `T` their builder
    /// makes (`crate::lightmap::stage::Traced`).
    pub fn traced<T: std::any::Any>(&self) -> Result<&'a T> {
        if !self.reads.trace {
            return Err(self.undeclared_error("the scene's trace structures".into()));
        }
        let t = match self.trace {
            Some(t) => t.get()?,
            None => {
                return Err(Error::runtime(format!(
                    "stage {}: no trace structures given",
                    self.stage
                )));
            }
        };
        t.downcast_ref::<T>().ok_or_else(|| {
            Error::runtime(format!(
                "stage {}: the trace structures are not of the type it reads",
                self.stage
            ))
        })
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

/// The pipeline presets (`pipelines/*.toml`, `--pipeline NAME`), in the order `bake pipeline
/// list` shows them. Each stage says its switch and options in each ([`Stage::on_in`],
/// [`Stage::options_in`]); the graph's own settings (the env-map shards) are central.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preset {
    /// `default`: every lighting stage at its default quality.
    Default,
    /// `preview` (`--preview`): quick, noisy lighting.
    Preview,
    /// `final`: converged lighting, the optional stages on.
    Final,
    /// `ci`: the preview's quality (a stage gives it the preview's options), small shards.
    Ci,
}

impl Preset {
    /// Every preset, in `bake pipeline list`'s order.
    pub const ALL: [Preset; 4] = [Preset::Default, Preset::Preview, Preset::Final, Preset::Ci];

    /// Its name (`--pipeline NAME`, `pipelines/NAME.toml`).
    pub fn name(self) -> &'static str {
        match self {
            Preset::Default => "default",
            Preset::Preview => "preview",
            Preset::Final => "final",
            Preset::Ci => "ci",
        }
    }

    /// The preset named `name`.
    pub fn named(name: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.name() == name)
    }
}

/// One stage: what it reads, its options, its key and its computation.
pub trait Stage: Sync {
    /// The stage's options: its table of the pipeline (`[<name>]` in `pipelines/*.toml`, its
    /// serde form hashed into every unit's key). `()` for a stage without options.
    type Options: Serialize
        + serde::de::DeserializeOwned
        + Clone
        + PartialEq
        + std::fmt::Debug
        + Send
        + Sync
        + 'static;
    /// Whether the preset turns the stage on (by default: in every preset).
    fn on_in(&self, _preset: Preset) -> bool {
        true
    }
    /// The stage's options in the preset (`pipelines/<preset>.toml` spells them out).
    fn options_in(&self, preset: Preset) -> Self::Options;
    /// The stages whose output it reads that must be on when it is (by name; the pipeline
    /// refuses a switch that breaks this).
    fn needs(&self) -> &'static [&'static str] {
        &[]
    }
    /// Checks its options beyond their types (the pipeline's parse and `--set` refuse them
    /// with this message).
    fn check(&self, _o: &Self::Options) -> std::result::Result<(), String> {
        Ok(())
    }
    /// The section kinds this stage defines (docs/FORMAT.md; `bake dump` and `bake verify`
    /// walk them through the registry). A kind written by several stages is defined by one.
    fn kinds(&self) -> &'static [SectionKind] {
        &[]
    }
    /// The warnings this stage gives, with their stable ids (docs/DIAGNOSTICS.md).
    fn diagnostics(&self) -> &'static [crate::diag::Diagnostic] {
        &[]
    }
    /// Its name, version, what a unit covers, the kinds it writes and its `bake unit` actions
    /// (a `static` in the impl).
    fn def(&self) -> &'static StageDef;
    /// What its units read.
    fn reads(&self) -> Reads;
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
    /// A sharded stage's number of instances in one shard's sections, checked as [`Self::join`]
    /// reads them: what a plan's join action (its second action, over the shards' packs) gives
    /// `join` with each part. An error for a stage that is not sharded.
    fn shard_size(&self, _shard: &[Section]) -> Result<usize> {
        Err(Error::usage(format!(
            "the {} stage is not sharded",
            self.def().name
        )))
    }
}
