//! The stage registry, [`REGISTRY`] (issue 36, item 1): one line per stage in the `registry!`
//! invocation, naming the stage's [`Stage`] implementation in its own folder
//! (`src/<module>/stage.rs`, through the interface of [`crate::stage`]) and what of the
//! pipeline it has (a switch, its own options table, another stage's table). The macro writes
//! [`REGISTRY`] ([`Registered`] lines), the pipeline's [`Stages`] and [`Pipeline`] structs and
//! the presets ([`Pipeline::of_preset`]) from those lines and what each stage declares in its
//! folder (its options type, `on_in`, `options_in`). Everything else the graph, the plans,
//! `bake unit`, `bake stage` and the stage commands need of a stage comes from that line: its
//! name, version (the build key), units, the kinds it reads and writes, its `bake unit`
//! actions, its options' check and the stages it needs ([`Pipeline::check`]), the section
//! kinds it defines (`crate::kinds::all`) and its warnings ([`diagnostics`]).
//!
//! The same [`Stage::run`] serves both runners: the graph ([`super::build`], which keeps the
//! sections in memory, caches the units and runs independent ones side by side) and the
//! actions of a build-engine plan (`crate::plan::actions`, `bake unit`, which read the inputs
//! from packs). The plan ([`crate::plan`]) loops over the registry too: a stage's actions read
//! the packs of the units that write the kinds it declares.
//!
//! Not driven by the registry (still written once by hand): the scene's own units (the
//! terrain's and the models' sections from the scene plan, then [`Phase::Source`] stages
//! `ingest`, `material`, `terrain`, which the graph and the `terrain` and `model` actions call
//! through the registry at fixed places), the instances and the build record; the sharding of
//! `envmaps` (by instances) and of the terrain light map (by rows, plans only). The `ingest`
//! stage's implementation stays here ([`Ingest`]): it writes a model's sections through
//! [`crate::pipeline::add_mesh`] (the orchestration layer), and its module, `ingest`, lies
//! below the stage interface. `bake unit`'s subcommands of the registered stages are made from
//! the registry (`cli::unit::StageUnit`) and run through [`crate::plan::actions::stage_unit`].
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
use crate::error::{Error, Result};
use crate::ingest::confine::SourceNames;
use crate::ingest::eco::ScenePlan;
use crate::ingest::limits::Limits;
use crate::pack::{Pack, Section, fit_name};
use std::path::Path;

pub use crate::envmap::stage::{envmap_shards, join_envmaps};
pub use crate::lightmap::stage::{TraceCell, Traced};
pub use crate::stage::{
    GEOMETRY, Output, Phase, Preset, Reads, Scope, Shard, Stage, StageKey, TRACED, UnitCtx,
    UnitInputs,
};

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
    /// [`Stage::shard_size`].
    fn shard_size(&self, shard: &[Section]) -> Result<usize>;
    /// [`Stage::needs`].
    fn needs(&self) -> &'static [&'static str];
    /// [`Stage::check`] of the pipeline's options for the stage.
    fn check(&self, p: &Pipeline) -> std::result::Result<(), String>;
    /// [`Stage::kinds`].
    fn kinds(&self) -> &'static [crate::stage::SectionKind];
    /// [`Stage::diagnostics`].
    fn diagnostics(&self) -> &'static [crate::diag::Diagnostic];
}

/// A registry line: the stage `stage` (implemented in its own folder), what turns it on, and
/// where its options lie in the pipeline.
pub struct Registered<S: Stage + 'static> {
    /// The stage.
    pub stage: S,
    /// Whether the pipeline turns it on.
    pub on: fn(&Pipeline) -> bool,
    /// Its options in the pipeline.
    pub options: for<'p> fn(&'p Pipeline) -> &'p S::Options,
}

impl<S: Stage + 'static> AnyStage for Registered<S> {
    fn def(&self) -> &'static StageDef {
        self.stage.def()
    }
    fn reads(&self) -> Reads {
        self.stage.reads()
    }
    fn on(&self, p: &Pipeline) -> bool {
        (self.on)(p)
    }
    fn phase(&self) -> Phase {
        self.stage.phase()
    }
    fn unit_name(&self, model: Option<&str>, shard: Option<&Shard>) -> String {
        self.stage.unit_name(model, shard)
    }
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        self.stage.total(u)
    }
    fn key(&self, u: &UnitInputs, p: &Pipeline, k: KeyBuilder) -> Result<Key> {
        let mut sk = StageKey::new(k, u);
        self.stage.key(u, (self.options)(p), &mut sk)?;
        sk.finish()
    }
    fn run(&self, cx: &UnitCtx, p: &Pipeline) -> Result<Output> {
        self.stage.run(cx, (self.options)(p))
    }
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, p: &Pipeline) -> Result<Vec<Section>> {
        self.stage.join(parts, (self.options)(p))
    }
    fn shard_size(&self, shard: &[Section]) -> Result<usize> {
        self.stage.shard_size(shard)
    }
    fn needs(&self) -> &'static [&'static str] {
        self.stage.needs()
    }
    fn check(&self, p: &Pipeline) -> std::result::Result<(), String> {
        self.stage.check((self.options)(p))
    }
    fn kinds(&self) -> &'static [crate::stage::SectionKind] {
        self.stage.kinds()
    }
    fn diagnostics(&self) -> &'static [crate::diag::Diagnostic] {
        self.stage.diagnostics()
    }
}

/// The inputs of `st`'s unit among `candidates` (the sections in the unit's scope).
pub fn unit_inputs<'a>(
    st: &dyn AnyStage,
    scope: &'a Scope<'a>,
    candidates: &[Section],
    model: Option<(&'a str, &'a Path)>,
    shard: Option<Shard>,
) -> UnitInputs<'a> {
    let unit = st.unit_name(model.map(|m| m.0), shard.as_ref());
    UnitInputs::new(st.def(), st.reads(), unit, scope, candidates, model, shard)
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
    let u = unit_inputs(st, scope, candidates, model, shard);
    let trace = st.reads().trace.then(|| TraceCell::new(&u));
    let shared = trace.as_ref().map(|t| t as &dyn crate::stage::SharedTrace);
    st.run(&UnitCtx::new(&u, progress, shared), p)
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

/// [`pack_unit`] of the stage `st` (a test's toy stage too; `bake stage`).
pub(crate) fn pack_unit_of(
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

/// Writes the registry from its lines: [`REGISTRY`], and the pipeline's structs that the
/// lines imply (its `[stages]` switches, [`Stages`], and one options table per stage that has
/// its own, [`Pipeline`]; both in registry order, which is their serde order and therefore the
/// build key's and `pipelines/*.toml`'s) with their presets ([`Pipeline::of_preset`], from each
/// stage's [`Stage::on_in`] and [`Stage::options_in`]). A line is `name: path::To::Stage
/// [what]`, `what` one of `always` (no switch, no options), `switch` (a switch, no options),
/// `switch, options` (a switch and its own `[name]` table) or `switch, options = other` (a
/// switch, and the table of the stage `other`).
macro_rules! registry {
    ($($name:ident : $stage:path [$($what:tt)*];)*) => {
        registry!(@acc [] [] []; $($name : $stage [$($what)*];)*);
    };
    (@acc [$($sw:tt)*] [$($opt:tt)*] [$($line:tt)*]; $name:ident : $stage:path [always]; $($rest:tt)*) => {
        registry!(@acc [$($sw)*] [$($opt)*]
            [$($line)* &Registered { stage: $stage, on: |_| true, options: |_| &() },]; $($rest)*);
    };
    (@acc [$($sw:tt)*] [$($opt:tt)*] [$($line:tt)*]; $name:ident : $stage:path [switch]; $($rest:tt)*) => {
        registry!(@acc [$($sw)* ($name, $stage)] [$($opt)*]
            [$($line)* &Registered { stage: $stage, on: |p| p.stages.$name, options: |_| &() },]; $($rest)*);
    };
    (@acc [$($sw:tt)*] [$($opt:tt)*] [$($line:tt)*]; $name:ident : $stage:path [switch, options]; $($rest:tt)*) => {
        registry!(@acc [$($sw)* ($name, $stage)] [$($opt)* ($name, $stage)]
            [$($line)* &Registered { stage: $stage, on: |p| p.stages.$name, options: |p| &p.$name },]; $($rest)*);
    };
    (@acc [$($sw:tt)*] [$($opt:tt)*] [$($line:tt)*]; $name:ident : $stage:path [switch, options = $other:ident]; $($rest:tt)*) => {
        registry!(@acc [$($sw)* ($name, $stage)] [$($opt)*]
            [$($line)* &Registered { stage: $stage, on: |p| p.stages.$name, options: |p| &p.$other },]; $($rest)*);
    };
    (@acc [$(($sw:ident, $sw_stage:path))*] [$(($opt:ident, $opt_stage:path))*] [$($line:tt)*];) => {
        /// Which stages run, one switch per registered stage that has one (`[stages]`; ingest
        /// always runs). A stage whose input is switched off is an error ([`Pipeline::check`]).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
        #[serde(default, deny_unknown_fields)]
        pub struct Stages {
            $(
                #[doc = concat!("Runs the `", stringify!($sw), "` stage.")]
                pub $sw: bool,
            )*
        }

        /// A whole bake: the stages' switches, the graph's units and each stage's options (its
        /// table, declared by its [`Stage::Options`]). Its serde form is `pipelines/*.toml`'s and
        /// the build key's.
        #[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
        #[serde(default, deny_unknown_fields)]
        pub struct Pipeline {
            /// Which stages run.
            pub stages: Stages,
            /// How the graph splits stages into units (the env-map shards).
            pub units: super::preset::Units,
            $(
                #[doc = concat!("The `", stringify!($opt), "` stage's options.")]
                pub $opt: <$opt_stage as Stage>::Options,
            )*
        }

        impl Pipeline {
            /// The preset `preset`: each stage's switch and options as the stage declares them
            /// ([`Stage::on_in`], [`Stage::options_in`]), the graph's units as
            /// [`super::preset::Units::of_preset`] gives them.
            pub fn of_preset(preset: Preset) -> Pipeline {
                Pipeline {
                    stages: Stages {
                        $($sw: Stage::on_in(&$sw_stage, preset),)*
                    },
                    units: super::preset::Units::of_preset(preset),
                    $($opt: Stage::options_in(&$opt_stage, preset),)*
                }
            }
        }

        /// Every stage, one line each, in the order of the build key (do not reorder: the key
        /// hashes this order; a new stage goes where its inputs are written before it). A line
        /// names the stage's implementation in its own folder and what of the pipeline it has
        /// ([`registry!`]): adding a stage is its folder's `stage.rs` and one line here
        /// (docs/ARCHITECTURE.md, "Adding a stage"; `tests/registry.rs` checks it).
        pub static REGISTRY: &[&dyn AnyStage] = &[$($line)*];
    };
}

registry! {
    ingest: Ingest [always];
    material: crate::material::stage::Material [switch, options];
    terrain: crate::terrain::stage::Terrain [switch];
    sky: crate::sky::stage::Sky [switch, options];
    prt: crate::prt::stage::Prt [switch, options];
    lod: crate::lod::stage::Lod [switch, options];
    lightmap: crate::lightmap::stage::Lightmap [switch, options];
    atlas: crate::lightmap::stage::Atlas [switch, options = lightmap];
    envmaps: crate::envmap::stage::Envmaps [switch, options];
    cluster: crate::envmap::stage::Cluster [switch, options];
    bittree: crate::bittree::stage::Bittree [switch, options];
    svo: crate::voxel::stage::Svo [switch, options];
    linespace: crate::linespace::stage::Linespace [switch, options];
}

/// Every diagnostic: those no stage gives ([`crate::diag::DIAGNOSTICS`]), then each registered
/// stage's ([`Stage::diagnostics`], declared in its folder), in registry order: the order of
/// docs/DIAGNOSTICS.md.
pub fn diagnostics() -> impl Iterator<Item = &'static crate::diag::Diagnostic> {
    crate::diag::DIAGNOSTICS
        .iter()
        .chain(REGISTRY.iter().flat_map(|s| s.diagnostics().iter()))
}

/// The diagnostic of `id` (central or a stage's), or `None` for an id bake does not have.
pub fn find_diagnostic(id: &str) -> Option<&'static crate::diag::Diagnostic> {
    diagnostics().find(|d| d.id == id)
}

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

/// The `ingest` stage's version. 2: TXF line and point arrays kept as the mesh's skeleton
/// (issue 14). 3: glTF materials keep `doubleSided` (`Material::double_sided`; issue 19).
/// 4: sources recorded by source name (`scene:plant.txf`), not as typed (issue 36).
pub const INGEST_VERSION: u32 = 4;

/// Reads one model and its textures (`ingest`).
pub struct Ingest;
impl Stage for Ingest {
    type Options = ();
    fn options_in(&self, _: Preset) {}
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "ingest",
            version: INGEST_VERSION,
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

/// The scene's `instances` section, as the graph writes it from the scene's plan.
pub fn instances_section(plan: &ScenePlan) -> Section {
    let meshes = plan
        .models
        .iter()
        .map(|(n, _)| fit_name(crate::mesh::section::mesh_section_name(n)))
        .collect();
    crate::ingest::instances_section::to_section("instances", &plan.scene.instances, meshes)
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
    pub(crate) static TOY: Registered<Toy> = registered_toy(false, false);
    pub(crate) static GREEDY: Registered<Toy> = registered_toy(true, false);
    pub(crate) static LAZY: Registered<Toy> = registered_toy(false, true);

    /// The toy's registry line: always on, its option a constant.
    const fn registered_toy(greedy: bool, lazy_key: bool) -> Registered<Toy> {
        Registered {
            stage: Toy { greedy, lazy_key },
            on: |_| true,
            options: |_| &OPTION,
        }
    }
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
        fn options_in(&self, _: Preset) -> u32 {
            OPTION
        }
        fn def(&self) -> &'static StageDef {
            &DEF
        }
        fn reads(&self) -> Reads {
            Reads {
                kinds: &["instances"],
                ..Reads::default()
            }
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
                report: serde_json::json!({"sections": cx.sections().len()}),
                ..Default::default()
            })
        }
    }

    /// The registry with `toy` added at the end.
    pub(crate) fn with(toy: &'static Registered<Toy>) -> Vec<&'static dyn AnyStage> {
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
