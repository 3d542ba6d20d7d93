//! The bake as a flat graph of cached stage units (`bake SCENE.eco`).
//!
//! Units run in data-flow order: the scene plan (ECO files, terrain, model names; always read),
//! then per model `ingest` → `material` → `prt`, the `terrain` preparation, the `sky`, and the
//! per-scene units `lightmap`, `atlas`, `envmaps` (in shards of instances), `cluster`,
//! `bittree`, `svo` and `linespace`. Units that do not read each other's sections run side by
//! side on the rayon pool (the models' `prt` and `lod` beside the scene's units, the terrain
//! `lightmap` beside `atlas` and `envmaps`), their sections, records and warnings put in the
//! serial order's places, so the pack and the report do not depend on the thread count. Each
//! unit is a pure function of the sections (or files) it reads and its options, computed by its
//! stage's `run` of the stage registry ([`stage::REGISTRY`], which also declares what it reads);
//! its key ([`cache::KeyBuilder`], made by [`stage::StageKey`]) hashes exactly those, so a hit in the stage cache
//! ([`cache::Cache`]) maps the stored sections instead of computing them. Stages
//! share one in-memory view of the sections produced so far ([`crate::pack::Pack::from_sections`],
//! no encoding), the scene's trace structures are built once per bake and only if a lighting
//! unit misses, and finished sections stream to the output's temporary file
//! ([`crate::pack::StreamWriter`]) and are read back through its memory map; the per-model
//! units' sections, which go before the scene's and so wait for them, wait on disk
//! ([`crate::pack::Spool`]): the bake never holds the pack in memory. The output also records a `build` section (the build key and every
//! file read with its hash): a run whose inputs and options hash the same leaves the output
//! alone without reading anything else.
//!
//! Nothing location-dependent enters a section or a key: sources, the build record and the
//! ingest keys name files relative to the scene's roots ([`SourceNames`]), cache entries record
//! the files they read by those names, so the same scene baked from another folder, or by
//! another spelling of its path, gives the same bytes and hits the same entries.
#![warn(missing_docs)]

pub mod cache;
pub mod preset;
pub mod progress;
pub mod stage;
pub mod stages;

use crate::diag;
use crate::error::{Error, Result};
use crate::ingest::confine::{self, SourceNames};
use crate::ingest::{self, IngestOptions};
use crate::pack::fit_name;
use crate::pack::{Pack, Section, Spool, StreamWriter, hex};
pub use crate::report::record::{BUILD_KIND, check_build_section};
pub(crate) use crate::report::record::{BuildMeta, build_section};
use cache::{Cache, EntryMeta, FileDep, Key, KeyBuilder, Lookup, Warning};
pub use preset::Pipeline;
use progress::Observer;
use serde::Serialize;
use serde_json::{Value, json};
use stage::{AnyStage, Phase, Scope, Shard, TraceCell, UnitCtx, UnitInputs};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The bake version that enters every cache key (the crate version).
pub const BAKE_VERSION: &str = env!("CARGO_PKG_VERSION");
/// Version of the `--json` build report (docs/REPORT.md).
pub const REPORT_SCHEMA: &str = "bake.build/2";

pub mod versions {
    //! The stages' versions: each stage's constant lives beside its implementation (its
    //! folder's `stage.rs`, with the history of its changes) and reaches the build key through
    //! its registry entry.

    /// Every stage's name and version, in registry order ([`super::stages::all`]). The whole
    /// build's key includes them, so an output written by a build whose stages had other
    /// versions is not taken as up to date.
    pub fn all() -> Vec<(&'static str, u32)> {
        super::stages::all().map(|s| (s.name, s.version)).collect()
    }
}

/// Where stage units are cached.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum CacheMode {
    /// [`cache::default_dir`].
    #[default]
    Default,
    /// This folder.
    Dir(PathBuf),
    /// Compute everything (and do not skip an up-to-date output).
    Off,
}

/// Options of [`build`].
#[derive(Debug, Clone, Default)]
pub struct BuildOptions {
    /// The ECO scene files (the first names the scene; the others add placements).
    pub scenes: Vec<PathBuf>,
    /// The pack to write (default: the first scene with the extension `.bake`).
    pub output: Option<PathBuf>,
    /// An HDR sky image (`--sky`; the built-in clear sky without it).
    pub sky: Option<PathBuf>,
    /// How inputs are read: `--models` folders, allowed paths, the memory budget.
    pub ingest: IngestOptions,
    /// What every stage computes and with which options.
    pub pipeline: Pipeline,
    /// The pipeline file the options came from (a dependency of the output).
    pub pipeline_file: Option<PathBuf>,
    /// Where units are cached.
    pub cache: CacheMode,
    /// Write the files read as a Makefile rule here.
    pub depfile: Option<PathBuf>,
    /// Overrides [`BAKE_VERSION`] in the keys (tests of key invalidation).
    pub bake_version: Option<String>,
}

impl BuildOptions {
    /// The options of `bake SCENE... ` with the preview pipeline.
    pub fn preview(mut self) -> Self {
        self.pipeline = Pipeline::preview();
        self
    }
}

/// One stage unit's record in the report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageRecord {
    /// The stage's name.
    pub stage: String,
    /// The unit's name (a model's, `terrain`, `scene`, a shard's instances).
    pub unit: String,
    /// "hit", "miss" or "off".
    pub cache: &'static str,
    /// Seconds from the start of the bake to the start of this unit (the timeline of
    /// `bake report`).
    pub start_seconds: f64,
    /// Seconds the unit ran (0 for a hit).
    pub wall_seconds: f64,
    /// The process's CPU time (all threads) while the unit ran: units that run at the same
    /// time each count their overlap.
    pub cpu_seconds: f64,
    /// `cpu_seconds / wall_seconds`: how many cores were busy while the unit ran.
    pub busy_cores: f64,
    /// The names of the sections the unit wrote.
    pub outputs: Vec<String>,
    /// The stage's own report (counts).
    pub report: Value,
}

/// What a build did (`--json`; docs/REPORT.md).
#[derive(Debug, Clone, Default, Serialize)]
pub struct BuildReport {
    /// The report's schema name and version (docs/REPORT.md).
    pub schema: &'static str,
    /// The pack written.
    pub output: PathBuf,
    /// The output was up to date and left as it was.
    pub up_to_date: bool,
    /// Sections in the pack.
    pub sections: usize,
    /// Bytes of the pack file.
    pub bytes: u64,
    /// BLAKE3 of the pack file as written (hex); `None` when the output was up to date.
    pub pack_blake3: Option<String>,
    /// Models placed by the scene.
    pub models: usize,
    /// Instances placed.
    pub instances: usize,
    /// Triangles of the models (level 0).
    pub triangles: u64,
    /// Every warning of the bake, with its id (docs/DIAGNOSTICS.md).
    pub warnings: Vec<Warning>,
    /// Seconds of the whole bake.
    pub wall_seconds: f64,
    /// CPU seconds of the whole bake (all threads).
    pub cpu_seconds: f64,
    /// Peak resident memory of the process.
    pub peak_rss_bytes: u64,
    /// The cache folder used (`None` with the cache off).
    pub cache: Option<PathBuf>,
    /// Units served from the cache.
    pub cache_hits: usize,
    /// Units computed.
    pub cache_misses: usize,
    /// Every unit's record, in the order they finished.
    pub stages: Vec<StageRecord>,
    /// Every file the bake read (what `--depfile` writes).
    pub files: Vec<PathBuf>,
}

/// CPU seconds (user + system, all threads) of this process so far, and its peak resident set.
pub fn process_usage() -> (f64, u64) {
    // SAFETY: getrusage fills the struct it is given.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return (0.0, 0);
    }
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    (tv(u.ru_utime) + tv(u.ru_stime), u.ru_maxrss as u64 * 1024)
}

pub use crate::stage::Output;

/// What every unit reads and nothing changes while units run: units of different threads run
/// against it at once.
struct Ctx<'a> {
    /// The registered stages ([`stage::REGISTRY`]; a test adds one).
    stages: &'a [&'a dyn AnyStage],
    cache: Option<Cache>,
    version: String,
    observer: &'a dyn Observer,
    /// The location-independent names of the scene's files.
    names: SourceNames,
    name: String,
    /// When the bake started.
    t0: Instant,
}

/// What units leave beside their sections: their records, warnings and the files they read.
/// Units that run at the same time each fill their own, merged at fixed places afterwards, so
/// the report's order never depends on which unit finished first.
#[derive(Default)]
struct Recorder {
    records: Vec<StageRecord>,
    warnings: Vec<Warning>,
    /// Every file read, by its real (canonical) path.
    files: BTreeSet<PathBuf>,
}

/// The running bake.
struct Graph<'a> {
    ctx: &'a Ctx<'a>,
    rec: Recorder,
    /// Every finished section in pack order (mapped from the output once written).
    done: Vec<Section>,
    /// Sections `done[..written]` are in the output.
    written: usize,
    /// Units that run beside the scene's units and whose sections go before sections that
    /// are finished already: while set, finished sections wait in `done`.
    deferred: Option<Deferred>,
    out: StreamWriter,
}

/// The per-model units (PRT, LOD) run beside the scene's units ([`build`]): where their
/// sections, records and warnings go, and where they arrive.
struct Deferred {
    /// Per model: its sections', records' and warnings' places (before the model's PRT).
    places: Vec<Place>,
    /// The per-model units' results, in model order, once all have run.
    slot: std::sync::Arc<std::sync::Mutex<Option<ModelResults>>>,
}

impl Deferred {
    /// Whether one of the per-model units has failed.
    fn failed(&self) -> bool {
        self.slot
            .lock()
            .is_ok_and(|s| s.as_ref().is_some_and(|r| r.iter().any(|x| x.is_err())))
    }
}

/// Indices into `done`, `rec.records` and `rec.warnings`.
#[derive(Debug, Clone, Copy)]
struct Place {
    section: usize,
    record: usize,
    warning: usize,
}

/// Every model's PRT and LOD units: their sections and what they recorded, in model order.
type ModelResults = Vec<Result<(Vec<Section>, Recorder)>>;

impl Ctx<'_> {
    /// Whether `key`'s unit has a cache entry (a hit unless the entry is damaged or its files
    /// changed; nothing is read or removed).
    fn has_entry(&self, key: &Key) -> bool {
        self.cache
            .as_ref()
            .is_some_and(|c| c.entry_path(key).is_file())
    }

    fn key(&self, stage: &str, version: u32, unit: &str) -> KeyBuilder {
        KeyBuilder::new(&self.version, stage, version, unit)
    }

    /// The key of a registered stage's unit over its declared inputs.
    fn stage_key(&self, st: &dyn AnyStage, p: &Pipeline, u: &UnitInputs) -> Result<Key> {
        let d = st.def();
        st.key(u, p, self.key(d.name, d.version, &u.unit))
    }

    /// Runs a registered stage's unit over its declared inputs ([`Ctx::unit`]).
    fn run_stage(
        &self,
        rec: &mut Recorder,
        st: &dyn AnyStage,
        p: &Pipeline,
        u: &UnitInputs,
        trace: Option<&TraceCell>,
    ) -> Result<Vec<Section>> {
        let key = self.stage_key(st, p, u)?;
        self.run_keyed(rec, st, p, u, trace, key)
    }

    /// [`Ctx::run_stage`] with its key made already. The files a unit declares (the sky, the
    /// model) are among the bake's files.
    fn run_keyed(
        &self,
        rec: &mut Recorder,
        st: &dyn AnyStage,
        p: &Pipeline,
        u: &UnitInputs,
        trace: Option<&TraceCell>,
        key: Key,
    ) -> Result<Vec<Section>> {
        let reads = st.reads();
        if reads.sky
            && let Some(s) = u.scope.sky
        {
            rec.files.insert(confine::resolve(s));
        }
        if reads.model_file
            && let Some((_, path)) = u.model
        {
            rec.files.insert(confine::resolve(path));
        }
        self.unit(rec, st.def().name, &u.unit, key, st.total(u), |progress| {
            let shared = trace.map(|t| t as &dyn crate::stage::SharedTrace);
            st.run(&UnitCtx::new(u, progress, shared), p)
        })
    }

    /// Runs one unit: a cache hit (its files still hashing as recorded) maps the stored
    /// sections; a miss computes them and stores them. Its record, warnings and files go to
    /// `rec`. `cpu_seconds` is the process's CPU time while the unit ran: where units run at
    /// the same time each counts their overlap (`busy_cores` reads as the cores busy then).
    fn unit(
        &self,
        rec: &mut Recorder,
        stage: &str,
        unit: &str,
        key: Key,
        total: Option<u64>,
        compute: impl FnOnce(&(dyn Fn(u64) + Sync)) -> Result<Output>,
    ) -> Result<Vec<Section>> {
        let t0 = Instant::now();
        let start_seconds = t0.duration_since(self.t0).as_secs_f64();
        let (c0, _) = process_usage();
        self.observer.start(stage, unit, total);
        let mut status = "off";
        let mut hit = None;
        if let Some(cache) = &self.cache {
            status = "miss";
            match cache.get(&key) {
                Lookup::Hit(e) => {
                    // The entry's files by name, placed in this bake's roots.
                    if let Some(files) = placed_files(&self.names, &e.meta.files)
                        && files_unchanged(&files)
                    {
                        hit = Some((e, files));
                    }
                }
                Lookup::Miss => {}
                Lookup::Corrupt(why) => rec.warnings.push(Warning::new(
                    &diag::CACHE_CORRUPT_ENTRY,
                    format!("{stage} {unit}"),
                    why,
                )),
            }
        }
        let (sections, report, warnings, files) = match hit {
            Some((e, files)) => {
                status = "hit";
                (e.sections, e.meta.report, e.meta.warnings, files)
            }
            None => {
                let obs = self.observer;
                let progress = |n: u64| obs.progress(stage, unit, n);
                let o = compute(&progress)?;
                let warnings: Vec<Warning> = o
                    .warnings
                    .into_iter()
                    .map(|w| Warning {
                        place: if w.place.is_empty() {
                            unit.to_string()
                        } else {
                            w.place
                        },
                        ..w
                    })
                    .collect();
                if let Some(cache) = &self.cache {
                    let meta = EntryMeta {
                        stage: stage.into(),
                        unit: unit.into(),
                        report: o.report.clone(),
                        warnings: warnings.clone(),
                        files: named_files(&self.names, &o.files),
                        sections: o.sections.iter().map(|s| s.name.clone()).collect(),
                    };
                    if let Err(e) = cache.put(&key, &o.sections, &meta) {
                        rec.warnings.push(Warning::new(
                            &diag::CACHE_WRITE_FAILED,
                            format!("{stage} {unit}"),
                            e.to_string(),
                        ));
                    }
                }
                (o.sections, o.report, warnings, o.files)
            }
        };
        rec.files.extend(
            files
                .iter()
                .filter(|f| f.blake3.is_some())
                .map(|f| confine::resolve(&f.path)),
        );
        rec.warnings.extend(warnings);
        let (c1, _) = process_usage();
        let wall_seconds = t0.elapsed().as_secs_f64();
        let cpu_seconds = c1 - c0;
        let record = StageRecord {
            stage: stage.into(),
            unit: unit.into(),
            cache: status,
            start_seconds,
            wall_seconds,
            cpu_seconds,
            busy_cores: busy_cores(cpu_seconds, wall_seconds),
            outputs: sections.iter().map(|s| s.name.clone()).collect(),
            report,
        };
        self.observer.end(&record);
        rec.records.push(record);
        Ok(sections)
    }
}

/// CPU seconds per wall second, rounded to 0.01 (0 for a unit too short to tell).
fn busy_cores(cpu: f64, wall: f64) -> f64 {
    if wall < 1e-3 {
        0.0
    } else {
        (cpu / wall * 100.0).round() / 100.0
    }
}

impl Recorder {
    /// Appends another recorder's records and warnings after this one's.
    fn append(&mut self, other: Recorder) {
        self.records.extend(other.records);
        self.warnings.extend(other.warnings);
        self.files.extend(other.files);
    }
}

impl Graph<'_> {
    /// [`Ctx::run_stage`], recorded in this graph's order.
    fn run_stage(
        &mut self,
        st: &dyn AnyStage,
        p: &Pipeline,
        u: &UnitInputs,
    ) -> Result<Vec<Section>> {
        self.ctx.run_stage(&mut self.rec, st, p, u, None)
    }

    /// Keeps finished sections (in the view) and writes them to the output, unless units
    /// whose sections go before them still run.
    fn finish_sections(&mut self, sections: Vec<Section>) -> Result<()> {
        self.done.extend(sections);
        if self.deferred.as_ref().is_some_and(Deferred::failed) {
            // A model's unit failed: stop here; `build` returns that unit's error.
            return Err(Error::runtime("a model's PRT or LOD unit failed"));
        }
        self.take_deferred();
        if self.deferred.is_none() {
            self.flush()?;
        }
        Ok(())
    }

    /// Puts the deferred units' sections, records and warnings in their places once they have
    /// all run without error (an error stays for [`build`] to return).
    fn take_deferred(&mut self) {
        let Some(d) = &self.deferred else {
            return;
        };
        let results = {
            let Ok(mut slot) = d.slot.lock() else {
                return;
            };
            match slot.as_ref() {
                Some(r) if r.iter().all(|x| x.is_ok()) => slot.take(),
                _ => None,
            }
        };
        let Some(results) = results else {
            return;
        };
        let places = self.deferred.take().map(|d| d.places).unwrap_or_default();
        // From the last model back, so that earlier places stay valid.
        for (place, r) in places.iter().zip(results).rev() {
            let Ok((sections, rec)) = r else {
                continue;
            };
            self.done.splice(place.section..place.section, sections);
            self.rec
                .records
                .splice(place.record..place.record, rec.records);
            self.rec
                .warnings
                .splice(place.warning..place.warning, rec.warnings);
            self.rec.files.extend(rec.files);
        }
    }

    /// Writes the sections not written yet, in order, keeping their mapped copies in the view.
    fn flush(&mut self) -> Result<()> {
        for i in self.written..self.done.len() {
            let s = self.done[i].clone();
            self.done[i] = self.out.push_mapped(s)?;
        }
        self.written = self.done.len();
        Ok(())
    }
}

/// Replaces sections of the same name (keeping their place) and appends the rest.
pub(crate) fn merge(into: &mut Vec<Section>, new: Vec<Section>) {
    for s in new {
        match into.iter_mut().find(|t| t.name == s.name) {
            Some(t) => *t = s,
            None => into.push(s),
        }
    }
}

/// Whether every recorded file still hashes as recorded (or is still absent).
fn files_unchanged(files: &[FileDep]) -> bool {
    files
        .iter()
        .all(|f| match (&f.blake3, cache::hash_file(&f.path)) {
            (Some(h), Ok(now)) => *h == hex(&now),
            (None, Err(_)) => !f.path.exists(),
            _ => false,
        })
}

/// A unit's files as its cache entry records them: by name ([`SourceNames`]), so that the entry
/// serves the same scene in another folder. (A unit's files lie inside the roots: models and
/// what they reference are confined.)
fn named_files(names: &SourceNames, files: &[FileDep]) -> Vec<FileDep> {
    files
        .iter()
        .map(|f| FileDep {
            path: PathBuf::from(names.inside(&f.path).unwrap_or_else(|| names.name(&f.path))),
            blake3: f.blake3.clone(),
        })
        .collect()
}

/// A cache entry's named files as real paths in this bake's roots; `None` where a name does
/// not place (an `outside:` name, a label this bake does not have) or where the placed path
/// has another name here (a symlink out of its root: the confinement would refuse it): the
/// entry is then a miss, so a hit never skips a refusal.
fn placed_files(names: &SourceNames, files: &[FileDep]) -> Option<Vec<FileDep>> {
    files
        .iter()
        .map(|f| {
            let name = f.path.to_string_lossy();
            let path = names.path_of(&name)?;
            (names.inside(&path).as_deref() == Some(&*name)).then(|| FileDep {
                path,
                blake3: f.blake3.clone(),
            })
        })
        .collect()
}

/// The build record's files: each real file by its name, with its hash, sorted by name.
pub(crate) fn record_files(names: &SourceNames, files: &[FileDep]) -> Vec<FileDep> {
    let mut out: Vec<FileDep> = files
        .iter()
        .map(|f| {
            let name = match &f.blake3 {
                Some(h) => names.name_hex(&f.path, h),
                None => names.name(&f.path),
            };
            FileDep {
                path: PathBuf::from(name),
                blake3: f.blake3.clone(),
            }
        })
        .collect();
    out.sort_by(|a, b| a.path.cmp(&b.path));
    out.dedup();
    out
}

fn file_dep(path: &Path) -> FileDep {
    FileDep {
        path: path.to_path_buf(),
        blake3: cache::hash_file(path).ok().map(|h| hex(&h)),
    }
}

/// `bake SCENE.eco`: every unit of the pipeline, cached, streamed into one pack.
pub fn build(opts: &BuildOptions, observer: &dyn Observer) -> Result<BuildReport> {
    build_with(opts, observer, stage::REGISTRY)
}

/// [`build`] with the stages of `registry` (a test adds a stage).
pub(crate) fn build_with(
    opts: &BuildOptions,
    observer: &dyn Observer,
    registry: &[&dyn AnyStage],
) -> Result<BuildReport> {
    let t0 = Instant::now();
    let (c0, _) = process_usage();
    let first = opts
        .scenes
        .first()
        .ok_or_else(|| Error::usage("no scene given"))?;
    opts.pipeline
        .check()
        .map_err(|m| Error::usage(format!("pipeline: {m}")))?;
    let output = opts
        .output
        .clone()
        .unwrap_or_else(|| first.with_extension("bake"));
    let version = opts
        .bake_version
        .clone()
        .unwrap_or_else(|| BAKE_VERSION.to_string());
    let cache_dir = match &opts.cache {
        CacheMode::Default => Some(cache::default_dir(&output)),
        CacheMode::Dir(d) => Some(d.clone()),
        CacheMode::Off => None,
    };
    let finish = |mut r: BuildReport| {
        let (c1, rss) = process_usage();
        r.schema = REPORT_SCHEMA;
        r.wall_seconds = t0.elapsed().as_secs_f64();
        r.cpu_seconds = c1 - c0;
        r.peak_rss_bytes = rss;
        r.cache = cache_dir.clone();
        r.cache_hits = r.stages.iter().filter(|s| s.cache == "hit").count();
        r.cache_misses = r.stages.iter().filter(|s| s.cache == "miss").count();
        r
    };
    if opts.cache != CacheMode::Off
        && let Some(r) = up_to_date(opts, &output, &version)
    {
        // A bake killed after its pack's rename (while it wrote the report beside the pack)
        // left its temporary file there: removed here, as each writer removes them when it
        // starts.
        crate::pack::remove_stale_temporaries(&crate::pack::parent_dir(&output));
        if let Some(d) = &opts.depfile {
            write_depfile(d, &output, &r.files)?;
        }
        return Ok(finish(r));
    }

    let plan = ingest::eco::scene_plan(&opts.scenes, &opts.ingest)?;
    let names = ingest::eco::scene_names(first, &opts.ingest);
    // What the sections record as the scene's source: the first ECO file by name.
    let scene_source = SourceNames::first_name(first);
    let ctx = Ctx {
        stages: registry,
        cache: cache_dir.clone().map(Cache::new),
        version,
        observer,
        names,
        name: first.display().to_string(),
        t0,
    };
    let mut g = Graph {
        ctx: &ctx,
        rec: Recorder::default(),
        done: Vec::new(),
        written: 0,
        deferred: None,
        out: StreamWriter::create(&output)?,
    };
    g.rec
        .files
        .extend(plan.files.iter().map(|f| confine::resolve(f)));
    g.rec
        .files
        .extend(opts.pipeline_file.iter().map(|f| confine::resolve(f)));
    g.rec.warnings.extend(plan.scene.warnings.iter().map(|m| {
        Warning::new(
            &diag::INGEST_ECO_OUTSIDE_AREA,
            first.display().to_string(),
            m.clone(),
        )
    }));
    let p = &opts.pipeline;
    // Models read under the scene's policy (roots and limits), which enters the ingest keys
    // so that a hit never skips a refusal: the roots by their places relative to each other
    // (what decides whether a reference from one reaches another), not where they lie, so
    // that the same tree elsewhere hits the same entries.
    let policy = ingest::eco::scene_policy(first, &opts.ingest);
    // What the units are given: the registered stages' declared inputs come from here.
    let scope = Scope {
        view_name: &ctx.name,
        source: &scene_source,
        limits: &opts.ingest.limits,
        first,
        sky: opts.sky.as_deref(),
        plan: Some(&plan),
        names: Some(&ctx.names),
        policy: Some(&policy),
    };

    // The terrain: its sections from the plan, then the prepared terrain.
    if let Some(t) = &plan.scene.terrain {
        let mut sections = crate::pipeline::terrain_sections(&scene_source, t);
        let st = stage::terrain();
        if st.on(p) {
            let u = stage::unit_inputs(st, &scope, &sections, None, None);
            let out = g.run_stage(st, p, &u)?;
            merge(&mut sections, out);
        }
        g.finish_sections(sections)?;
    }

    // Per model: ingest, material, then (below) the per-model stages (PRT, LOD).
    let mut triangles = 0u64;
    // Each model's (vertices, triangles), for the placed scene's size.
    let mut model_sizes = Vec::with_capacity(plan.models.len());
    // The svo and line-space units read the placed scene as one mesh (200,000 trees are ~10⁹
    // triangles): refused as soon as the models ingested so far (a lower bound of the scene)
    // cannot fit the memory budget, before their PRT and the lighting.
    let check_placed = |model_sizes: &[Option<(u64, u64)>]| -> Result<()> {
        use crate::voxel::geometry::{PlacedSize, SceneStage};
        let placed = PlacedSize::of_scene(
            plan.scene.terrain.as_ref().map(|t| (t.width, t.height)),
            model_sizes,
            &plan.scene.instances.items,
        );
        for (on, stage) in [
            (p.stages.svo, SceneStage::Svo),
            (p.stages.linespace, SceneStage::Linespace),
        ] {
            if on {
                placed.check(stage, &opts.ingest.limits, first)?;
            }
        }
        Ok(())
    };
    // What each model's per-model units read, and where their sections, records and
    // warnings go (right after the model's own, as when every unit ran in turn).
    let mut jobs = Vec::with_capacity(plan.models.len());
    let mut places = Vec::with_capacity(plan.models.len());
    for (name, path) in &plan.models {
        let model = Some((name.as_str(), path.as_path()));
        let st = stage::ingest();
        let u = stage::unit_inputs(st, &scope, &[], model, None);
        let mut sections = g.run_stage(st, p, &u)?;
        let st = stage::material();
        if st.on(p) {
            let u = stage::unit_inputs(st, &scope, &sections, model, None);
            let out = g.run_stage(st, p, &u)?;
            merge(&mut sections, out);
        }
        // The mesh and its textures are final now (only the material stage replaces them).
        let mesh_name = fit_name(crate::mesh::section::mesh_section_name(name));
        let view = Pack::from_sections(&sections, &ctx.name);
        let mesh_view = view.find(&mesh_name).and_then(|e| view.view(e).ok());
        let count = |array: &str| {
            mesh_view
                .as_ref()
                .and_then(|v| v.info(array))
                .map(|a| a.count)
        };
        triangles += count("indices").unwrap_or(0);
        model_sizes.push(count("positions").zip(count("indices")));
        check_placed(&model_sizes)?;
        // Written once the per-model sections of the models before it are.
        jobs.push(ModelJob {
            name,
            path,
            sections: sections.clone(),
        });
        g.done.extend(sections);
        places.push(Place {
            section: g.done.len(),
            record: g.rec.records.len(),
            warning: g.rec.warnings.len(),
        });
    }
    let instances = plan.scene.instances.items.len();
    check_placed(&model_sizes)?;

    // The per-model units run beside the scene's units (the instances, the sky, the lighting:
    // none reads them), on the same thread pool, so both cores stay busy through the serial
    // parts of either. Their sections, records and warnings go to their places, so the pack
    // and the report are the same whichever finishes first (and on one thread).
    let slot = std::sync::Arc::new(std::sync::Mutex::new(None));
    g.deferred = Some(Deferred {
        places,
        slot: slot.clone(),
    });
    // The per-model units' sections wait for the scene's units (the light map, last of all at
    // the theses' scale) before they go into the output: meanwhile they wait on disk beside
    // it ([`Spool`]; docs/PERFORMANCE.md, "The default's peak at 200,000 instances"), not in
    // memory. Dropped after the output holds them.
    let mut spool = Spool::beside(&output)?;
    let ctxr = g.ctx;
    let scope_r = &scope;
    let spool_r = &mut spool;
    let ((), scene_done) = rayon::join(
        || {
            // Up to the first failure (the scene's units then stop at their next section).
            let mut r: ModelResults = Vec::with_capacity(jobs.len());
            for j in &jobs {
                let one = model_units(ctxr, scope_r, p, j).and_then(|(sections, rec)| {
                    let sections = sections
                        .into_iter()
                        .map(|s| spool_r.park(s))
                        .collect::<Result<Vec<_>>>()?;
                    Ok((sections, rec))
                });
                let failed = one.is_err();
                r.push(one);
                if failed {
                    break;
                }
            }
            if let Ok(mut s) = slot.lock() {
                *s = Some(r);
            }
        },
        || -> Result<()> {
            g.finish_sections(vec![stage::instances_section(&plan)])?;
            scene_units(&mut g, p, scope_r)
        },
    );
    if g.deferred.is_some() {
        // The scene's units ended first, or a model's unit failed (its error first).
        let results = slot.lock().ok().and_then(|mut s| s.take());
        let mut ok: ModelResults = Vec::new();
        for r in results.unwrap_or_default() {
            ok.push(Ok(r?));
        }
        if let Ok(mut s) = slot.lock() {
            *s = Some(ok);
        }
        g.take_deferred();
    }
    scene_done?;
    g.flush()?;
    drop(spool);
    // The record of this build: its key and every file read (by name).
    let files: Vec<PathBuf> = g.rec.files.iter().cloned().collect();
    let deps: Vec<FileDep> = files.iter().map(|f| file_dep(f)).collect();
    let deps = record_files(&ctx.names, &deps);
    let build_key = build_key(opts, &ctx.version, &deps);
    g.finish_sections(vec![build_section(&BuildMeta {
        key: build_key.hex(),
        files: deps,
        models: plan.models.len() as u64,
        instances: instances as u64,
        triangles,
    })])?;
    let sections = g.done.len();
    let bytes = g.out.file_size();
    drop(g.done);
    g.out.finish()?;
    if let Some(d) = &opts.depfile {
        write_depfile(d, &output, &files)?;
    }
    let pack_blake3 = Some(hex(&cache::hash_file(&output)?));
    Ok(finish(BuildReport {
        output,
        sections,
        bytes,
        pack_blake3,
        models: plan.models.len(),
        instances,
        triangles,
        warnings: g.rec.warnings,
        stages: g.rec.records,
        files,
        ..Default::default()
    }))
}

/// What a model's per-model units read.
struct ModelJob<'a> {
    name: &'a str,
    path: &'a Path,
    /// The model's own sections (mesh, textures, materials).
    sections: Vec<Section>,
}

/// A model's per-model units ([`Phase::Model`], as the pipeline turns them on, in registry
/// order): their sections in pack order and what they recorded.
fn model_units(
    ctx: &Ctx,
    scope: &Scope,
    p: &Pipeline,
    j: &ModelJob,
) -> Result<(Vec<Section>, Recorder)> {
    let mut rec = Recorder::default();
    let mut sections = Vec::new();
    for st in ctx.stages.iter().copied() {
        if st.phase() == Phase::Model && st.on(p) {
            let u = stage::unit_inputs(st, scope, &j.sections, Some((j.name, j.path)), None);
            sections.extend(ctx.run_stage(&mut rec, st, p, &u, None)?);
        }
    }
    Ok((sections, rec))
}

/// The per-scene units ([`Phase::Scene`], in registry order): the sky, the lighting units,
/// clustering, BitTree, SVO, line space. Consecutive units that read the trace structures run
/// as a group ([`lighting_units`]); the others one after the other.
fn scene_units(g: &mut Graph, p: &Pipeline, scope: &Scope) -> Result<()> {
    let on: Vec<&dyn AnyStage> = g
        .ctx
        .stages
        .iter()
        .copied()
        .filter(|s| s.phase() == Phase::Scene && s.on(p))
        .collect();
    let mut i = 0;
    while i < on.len() {
        if on[i].reads().trace {
            let end = (i..on.len())
                .find(|&j| !on[j].reads().trace)
                .unwrap_or(on.len());
            lighting_units(g, p, scope, &on[i..end])?;
            i = end;
        } else {
            let u = stage::unit_inputs(on[i], scope, &g.done, None, None);
            let out = g.run_stage(on[i], p, &u)?;
            g.finish_sections(out)?;
            i += 1;
        }
    }
    Ok(())
}

/// Units that trace the scene (light maps, environment maps): the trace structures are built
/// once, here, before the units run side by side, when one of them has no cache entry. (Built
/// inside a unit, an entry found damaged or stale, see [`TraceCell::get`].) The first stage's
/// units (the terrain light map) run beside the others' (object light maps, environment-map
/// shards; none reads another's output); their records and sections go in registry order
/// whichever finishes first.
fn lighting_units(
    g: &mut Graph,
    p: &Pipeline,
    scope: &Scope,
    stages: &[&dyn AnyStage],
) -> Result<()> {
    let ctx = g.ctx;
    let n = scope.plan.map_or(0, |pl| pl.scene.instances.items.len());
    let mut units: Vec<Vec<(UnitInputs, Key)>> = Vec::with_capacity(stages.len());
    for st in stages {
        let shards: Vec<Option<Shard>> = if st.def().per == stages::Per::Shards {
            stage::envmap_shards(n, p.units.envmap_shard_instances as usize)
                .into_iter()
                .map(|r| Some(Shard::Range(r)))
                .collect()
        } else {
            vec![None]
        };
        let mut us = Vec::with_capacity(shards.len());
        for shard in shards {
            let u = stage::unit_inputs(*st, scope, &g.done, None, shard);
            let key = ctx.stage_key(*st, p, &u)?;
            us.push((u, key));
        }
        units.push(us);
    }
    let Some((first, _)) = units.first().and_then(|u| u.first()) else {
        return Ok(());
    };
    let trace = TraceCell::new(first);
    if units.iter().flatten().any(|(_, k)| !ctx.has_entry(k)) {
        trace.get()?;
    }
    let run = |rec: &mut Recorder, k: usize| -> Result<Vec<Section>> {
        let st = stages[k];
        let mut parts = Vec::with_capacity(units[k].len());
        for (u, key) in &units[k] {
            let out = ctx.run_keyed(rec, st, p, u, Some(&trace), *key)?;
            let len = u.shard.as_ref().map_or(0, |s| s.range(n).len());
            parts.push((len, out));
        }
        st.join(parts, p)
    };
    let (mut rec_l, mut rec_r) = (Recorder::default(), Recorder::default());
    let (first_out, rest_out) = rayon::join(
        || run(&mut rec_l, 0),
        || -> Result<Vec<Section>> {
            let mut out = Vec::new();
            for k in 1..stages.len() {
                out.extend(run(&mut rec_r, k)?);
            }
            Ok(out)
        },
    );
    g.rec.append(rec_l);
    let first_out = first_out?;
    g.rec.append(rec_r);
    let rest_out = rest_out?;
    g.finish_sections(first_out)?;
    g.finish_sections(rest_out)?;
    Ok(())
}

/// Reads one model and its textures into `texture:<model>/...` and `mesh:<model>` sections,
/// their sources named by `names`.
pub(crate) fn ingest_model(
    name: &str,
    path: &Path,
    policy: &ingest::ReadPolicy,
    names: &SourceNames,
) -> Result<Output> {
    let mesh = ingest::load_mesh_in(path, policy)?;
    let mut warnings: Vec<String> = mesh.warnings.clone();
    let mut w = crate::pack::PackWriter::new();
    crate::pipeline::add_mesh(&mut w, name, path, names, &mesh, &mut warnings);
    let mut files: Vec<FileDep> = ingest::mesh_side_files(path)
        .iter()
        .map(|p| file_dep(p))
        .collect();
    for t in &mesh.textures {
        files.push(file_dep(&t.path));
    }
    files.sort_by(|a, b| a.path.cmp(&b.path));
    files.dedup();
    Ok(Output {
        report: json!({
            "vertices": mesh.positions.len(),
            "triangles": mesh.indices.len(),
            "materials": mesh.materials.len(),
            "textures": mesh.textures.len(),
        }),
        sections: w.sections().to_vec(),
        warnings: diag::tagged(&diag::INGEST_READER, warnings),
        files,
    })
}

/// The key of a whole build: version, the stages' versions, pipeline, command-line inputs and
/// every file's content. `files` are named ([`record_files`]), and the command line enters by
/// names and counts, so the key does not depend on where the scene lies or how its path was
/// written (the files say which sky, colour map and models were read).
pub(crate) fn build_key(opts: &BuildOptions, version: &str, files: &[FileDep]) -> Key {
    build_key_with(opts, version, &versions::all(), files)
}

/// [`build_key`] with the stages' versions given.
fn build_key_with(
    opts: &BuildOptions,
    version: &str,
    stages: &[(&str, u32)],
    files: &[FileDep],
) -> Key {
    let mut k = KeyBuilder::new(version, "build", 1, "");
    k.options(&stages);
    k.options(&opts.pipeline);
    let names = opts
        .scenes
        .first()
        .map(|f| ingest::eco::scene_names(f, &opts.ingest))
        .unwrap_or_default();
    let scenes: Vec<String> = opts
        .scenes
        .iter()
        .enumerate()
        .map(|(i, p)| match i {
            0 => SourceNames::first_name(p),
            _ => names.inside(p).unwrap_or_else(|| names.name(p)),
        })
        .collect();
    k.options(&(
        &scenes,
        opts.sky.is_some(),
        opts.ingest.model_dirs.len(),
        opts.ingest.allow_paths.len(),
        opts.ingest.color_map.is_some(),
    ));
    for f in files {
        let h = f.blake3.as_deref().unwrap_or("absent");
        k.input(
            &f.path.display().to_string(),
            blake3::hash(h.as_bytes()).as_bytes(),
        );
    }
    k.finish()
}

/// The report of a build whose output is up to date: its recorded key equals the key of the
/// files it lists as they are now. `None` when anything differs or cannot be read.
fn up_to_date(opts: &BuildOptions, output: &Path, version: &str) -> Option<BuildReport> {
    let pack = Pack::open(output).ok()?;
    let e = pack.of_kind(BUILD_KIND).next()?;
    let meta: BuildMeta = pack.view(e).ok()?.meta().ok()?;
    // The recorded files by name, placed in this build's roots; an `outside:` name is one of
    // the files given on the command line (its name holds its hash: a changed file is not
    // found, and the output is stale).
    let first = opts.scenes.first()?;
    let names = ingest::eco::scene_names(first, &opts.ingest);
    let given: Vec<&PathBuf> = [&opts.sky, &opts.ingest.color_map, &opts.pipeline_file]
        .into_iter()
        .flatten()
        .collect();
    let placed: Vec<PathBuf> = meta
        .files
        .iter()
        .map(|f| {
            let name = f.path.to_string_lossy();
            names.path_of(&name).or_else(|| {
                given
                    .iter()
                    .find(|g| names.name(g.as_path()) == name)
                    .map(|g| confine::resolve(g))
            })
        })
        .collect::<Option<_>>()?;
    let now: Vec<FileDep> = {
        use rayon::prelude::*;
        placed.par_iter().map(|f| file_dep(f)).collect()
    };
    let now = record_files(&names, &now);
    if now != meta.files || build_key(opts, version, &now).hex() != meta.key {
        return None;
    }
    let bytes = std::fs::metadata(output).ok()?.len();
    Some(BuildReport {
        output: output.to_path_buf(),
        up_to_date: true,
        sections: pack.sections().len(),
        bytes,
        models: meta.models as usize,
        instances: meta.instances as usize,
        triangles: meta.triangles,
        files: {
            let mut files = placed;
            files.sort();
            files
        },
        ..Default::default()
    })
}

/// Writes `target: dep dep ...` (Makefile syntax; spaces, `#` and `$` escaped) atomically.
pub fn write_depfile(path: &Path, target: &Path, files: &[PathBuf]) -> Result<()> {
    let esc = |p: &Path| {
        p.display()
            .to_string()
            .replace('\\', "\\\\")
            .replace(' ', "\\ ")
            .replace('#', "\\#")
            .replace('$', "$$")
    };
    let mut text = format!("{}:", esc(target));
    for f in files {
        text.push_str(" \\\n  ");
        text.push_str(&esc(f));
    }
    text.push('\n');
    crate::pack::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stage_version_enters_the_build_key() {
        // An output baked before a stage's version changed must not count as up to date (it
        // did: the key held only the crate version, and `bake SCENE.eco` kept a stale pack).
        let opts = BuildOptions::default();
        let now = build_key(&opts, "0.1.0", &[]).hex();
        assert_eq!(
            now,
            build_key_with(&opts, "0.1.0", &versions::all(), &[]).hex()
        );
        let all = versions::all();
        let mut names: Vec<&str> = all.iter().map(|s| s.0).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), all.len());
        for i in 0..all.len() {
            let mut bumped = all.clone();
            bumped[i].1 += 1;
            let key = build_key_with(&opts, "0.1.0", &bumped, &[]).hex();
            assert_ne!(key, now, "{}", bumped[i].0);
        }
    }
}
