//! The stage graph's units as separate actions (`bake unit ...`): each reads only the files
//! and packs it is given and writes one small pack (plus, for a model, a JSON list of the
//! files it read). A registered stage's unit runs through [`stage_unit`]: the same
//! [`crate::graph::stage::Stage::run`] as [`crate::graph::build`] over the same declared inputs
//! (the sections of the declared kinds in the packs given), so that `bake merge` of their packs
//! in the plan's order is byte-identical to `bake SCENE.eco` run with the same arguments from
//! the same folder.

use crate::diag::{self, Warning};
use crate::error::{Error, Result};
use crate::graph::cache::{self, FileDep};
use crate::graph::stage::{self, AnyStage, Scope, Shard};
use crate::graph::{BAKE_VERSION, BuildOptions, Pipeline};
use crate::ingest::{self, IngestOptions};
use crate::pack::fit_name;
use crate::pack::{Pack, Section, StreamWriter, hex};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// What every unit knows of the scene: the arguments of `bake SCENE.eco`.
#[derive(Debug, Clone, Default)]
pub struct SceneArgs {
    /// The ECO scene files.
    pub scenes: Vec<PathBuf>,
    /// `--sky`.
    pub sky: Option<PathBuf>,
    /// How inputs are read (models folders, allowed paths, budget).
    pub ingest: IngestOptions,
    /// The pipeline.
    pub pipeline: Pipeline,
    /// The pipeline file given, if any (an input of every action).
    pub pipeline_file: Option<PathBuf>,
}

impl SceneArgs {
    fn first(&self) -> Result<&Path> {
        self.scenes
            .first()
            .map(PathBuf::as_path)
            .ok_or_else(|| Error::usage("no scene given"))
    }

    /// The name the graph gives its in-memory views (the first scene as written).
    fn view_name(&self) -> Result<String> {
        Ok(self.first()?.display().to_string())
    }

    /// The location-independent names of the scene's files.
    fn names(&self) -> Result<ingest::confine::SourceNames> {
        Ok(ingest::eco::scene_names(self.first()?, &self.ingest))
    }

    /// What the sections record as the scene's source: the first ECO file by name.
    fn source(&self) -> Result<String> {
        Ok(ingest::confine::SourceNames::first_name(self.first()?))
    }

    fn policy(&self) -> Result<ingest::ReadPolicy> {
        Ok(ingest::eco::scene_policy(self.first()?, &self.ingest))
    }

    fn plan(&self) -> Result<ingest::eco::ScenePlan> {
        self.pipeline
            .check()
            .map_err(|m| Error::usage(format!("pipeline: {m}")))?;
        ingest::eco::scene_plan(&self.scenes, &self.ingest)
    }

    /// One unit of the registered stage `st` over `candidates` (its scope: the sections of the
    /// packs it is given), as the graph runs it: its declared inputs only, the scene's plan
    /// resolved only where declared.
    fn run_over(
        &self,
        st: &dyn AnyStage,
        candidates: &[Section],
        model: Option<(&str, &Path)>,
        shard: Option<Shard>,
    ) -> Result<crate::graph::Output> {
        let reads = st.reads();
        let plan = if reads.scene {
            Some(self.plan()?)
        } else {
            None
        };
        let (names, policy) = if reads.model_file {
            (Some(self.names()?), Some(self.policy()?))
        } else {
            (None, None)
        };
        let (view_name, source) = (self.view_name()?, self.source()?);
        let scope = Scope {
            view_name: &view_name,
            source: &source,
            limits: &self.ingest.limits,
            first: self.first()?,
            sky: self.sky.as_deref(),
            plan: plan.as_ref(),
            names: names.as_ref(),
            policy: policy.as_ref(),
        };
        stage::run_unit(
            st,
            &scope,
            candidates,
            model,
            shard,
            &|_| {},
            &self.pipeline,
        )
    }
}

/// One unit of a registered stage (`bake unit ACTION`), over the sections of the packs
/// `inputs` (for a per-model stage, the model `model`'s), writing `out`: an empty pack where
/// the pipeline turns the stage off. `shard` is I of N (0-based) for a sharded stage.
pub fn stage_unit(
    st: &dyn AnyStage,
    s: &SceneArgs,
    model: Option<&str>,
    inputs: &[PathBuf],
    shard: Option<(usize, usize)>,
    out: &Path,
) -> Result<UnitReport> {
    let d = st.def();
    let label = match shard {
        Some(_) => format!("{}-shard", d.name),
        None => d.name.to_string(),
    };
    if !st.on(&s.pipeline) {
        return finish(&label, out, Vec::new(), Vec::new());
    }
    let sections = read_packs(inputs)?;
    let model = model.map(|m| (m, Path::new(m)));
    let o = s.run_over(st, &sections, model, shard.map(|(i, n)| Shard::Of(i, n)))?;
    finish(&label, out, o.sections, o.warnings)
}

/// The registered stage whose `bake unit` action is `action` (its first).
pub fn stage_of_action(action: &str) -> Result<&'static dyn AnyStage> {
    stage::REGISTRY
        .iter()
        .copied()
        .find(|s| s.def().actions.first() == Some(&action))
        .ok_or_else(|| Error::usage(format!("no stage runs the unit {action:?}")))
}

/// What a unit did: sections written and warnings raised.
#[derive(Debug, Clone, Default, Serialize)]
pub struct UnitReport {
    /// The unit's name.
    pub unit: String,
    /// The pack it wrote.
    pub output: PathBuf,
    /// The names of the sections written, in order.
    pub sections: Vec<String>,
    /// The warnings raised.
    pub warnings: Vec<Warning>,
}

/// Writes `sections` in order as a pack at `out` (atomically; nothing is left on failure).
pub fn write_sections(out: &Path, sections: &[Section]) -> Result<()> {
    let mut w = StreamWriter::create(out)?;
    for s in sections {
        w.push(s)?;
    }
    w.finish()
}

fn report(unit: &str, out: &Path, sections: &[Section], warnings: Vec<Warning>) -> UnitReport {
    UnitReport {
        unit: unit.into(),
        output: out.to_path_buf(),
        sections: sections.iter().map(|s| s.name.clone()).collect(),
        warnings,
    }
}

fn finish(unit: &str, out: &Path, sections: Vec<Section>, w: Vec<Warning>) -> Result<UnitReport> {
    write_sections(out, &sections)?;
    Ok(report(unit, out, &sections, w))
}

/// Every section of the given packs, in order (checksums checked).
pub fn read_packs(inputs: &[PathBuf]) -> Result<Vec<Section>> {
    let mut all = Vec::new();
    for p in inputs {
        all.extend(Pack::open(p)?.checked_sections()?);
    }
    Ok(all)
}

/// The terrain's sections from the plan, then the prepared terrain (`stages.terrain`).
pub fn terrain(s: &SceneArgs, out: &Path) -> Result<UnitReport> {
    let plan = s.plan()?;
    let mut sections = Vec::new();
    if let Some(t) = &plan.scene.terrain {
        sections = crate::pipeline::terrain_sections(&s.source()?, t);
        let st = stage::terrain();
        if st.on(&s.pipeline) {
            let o = s.run_over(st, &sections, None, None)?;
            crate::graph::merge(&mut sections, o.sections);
        }
    }
    let w = diag::tagged(&diag::INGEST_ECO_OUTSIDE_AREA, plan.scene.warnings.clone());
    finish("terrain", out, sections, w)
}

/// What a model unit read, beside its pack: the files (with hashes; the model file first) and
/// the model's triangle count, for the build record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelDeps {
    /// The model's name in the scene.
    pub model: String,
    /// The files read, with their hashes (the model file first).
    pub files: Vec<FileDep>,
    /// Triangles of the model.
    pub triangles: u64,
}

/// One model: ingest, then materials (`stages.material`). Writes the pack and `deps`.
pub fn model(
    s: &SceneArgs,
    name: &str,
    path: &Path,
    out: &Path,
    deps: &Path,
) -> Result<UnitReport> {
    s.pipeline
        .check()
        .map_err(|m| Error::usage(format!("pipeline: {m}")))?;
    let model_hash = cache::hash_file(path)?;
    let model = Some((name, path));
    let o = s.run_over(stage::ingest(), &[], model, None)?;
    let mut sections = o.sections;
    let mut warnings = o.warnings;
    let st = stage::material();
    if st.on(&s.pipeline) {
        let m = s.run_over(st, &sections, model, None)?;
        warnings.extend(m.warnings);
        crate::graph::merge(&mut sections, m.sections);
    }
    let mesh_name = fit_name(crate::mesh::section::mesh_section_name(name));
    let view = Pack::from_sections(&sections, &s.view_name()?);
    let triangles = view
        .find(&mesh_name)
        .and_then(|e| view.view(e).ok())
        .and_then(|v| v.info("indices").map(|a| a.count))
        .unwrap_or(0);
    let mut files = vec![FileDep {
        path: path.to_path_buf(),
        blake3: Some(hex(&model_hash)),
    }];
    files.extend(o.files);
    let d = ModelDeps {
        model: name.into(),
        files,
        triangles,
    };
    let json =
        serde_json::to_vec_pretty(&d).map_err(|e| Error::runtime(format!("model record: {e}")))?;
    write_sections(out, &sections)?;
    crate::pack::write_atomic(deps, &json)?;
    Ok(report("model", out, &sections, warnings))
}

/// The `instances` section of the scene.
pub fn instances(s: &SceneArgs, out: &Path) -> Result<UnitReport> {
    let sec = stage::instances_section(&s.plan()?);
    finish("instances", out, vec![sec], Vec::new())
}

/// The packs' sections a lighting unit traces (the declared kinds of the light maps).
fn traced_packs(s: &SceneArgs, inputs: &[PathBuf]) -> Result<stage::Traced> {
    let sections: Vec<Section> = read_packs(inputs)?
        .into_iter()
        .filter(|x| stage::TRACED.contains(&x.kind.as_str()))
        .collect();
    let view = Pack::from_sections(&sections, &s.view_name()?);
    let light = crate::lightmap::scene_lighting(&view)?;
    let ts = crate::trace::pack_scene::trace_scene(&view)?;
    Ok((ts, light))
}

/// Kind (and name) of the section holding one row shard of the terrain light map.
pub const LIGHTMAP_ROWS_KIND: &str = "lightmap-rows";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RowsMeta {
    width: u32,
    height: u32,
    start: u32,
    end: u32,
    /// The step the map is traced at (`lightmap::terrain_trace_step`), stated in the joined
    /// section's metadata.
    trace_step: u32,
}

/// Rows `shard.0` of `shard.1` of the terrain light map ([`shard_range`] over the rows), over
/// the same packs as [`lightmap`]; joined by [`lightmap_join`].
pub(crate) fn lightmap_rows(
    s: &SceneArgs,
    inputs: &[PathBuf],
    shard: (usize, usize),
    out: &Path,
) -> Result<UnitReport> {
    let (ts, light) = traced_packs(s, inputs)?;
    let lm = &s.pipeline.lightmap;
    let mut outs = Vec::new();
    if let Some((w, h)) = crate::lightmap::terrain_lightmap_size(&ts, lm) {
        let r = shard_range(shard.0, shard.1, h as usize);
        let rows = r.start as u32..r.end as u32;
        let (texels, direct) =
            crate::lightmap::bake_terrain_lightmap_rows(&ts, &light, lm, rows.clone())?
                .unwrap_or_default();
        let mut b = crate::pack::SectionBuilder::new(LIGHTMAP_ROWS_KIND, LIGHTMAP_ROWS_KIND);
        b.meta(&RowsMeta {
            width: w,
            height: h,
            start: rows.start,
            end: rows.end,
            trace_step: crate::lightmap::terrain_trace_step(&ts, lm),
        });
        b.array("texels", crate::pack::ArrayFormat::F32, 3, &texels);
        b.array("direct", crate::pack::ArrayFormat::F32, 3, &direct);
        outs.push(b.finish());
    }
    finish("lightmap-rows", out, outs, Vec::new())
}

/// The terrain light map from its row shards' packs (in shard order): the same section as
/// [`lightmap`] computes in one piece.
pub fn lightmap_join(s: &SceneArgs, shards: &[PathBuf], out: &Path) -> Result<UnitReport> {
    let mut texels: Vec<[f32; 3]> = Vec::new();
    let mut direct: Vec<[f32; 3]> = Vec::new();
    let mut size = None;
    let mut step = None;
    let mut next = 0u32;
    for p in shards {
        let pack = Pack::open(p)?;
        let Some(e) = pack.find(LIGHTMAP_ROWS_KIND) else {
            continue; // no terrain: every shard is empty
        };
        let bad = |m: String| Error::invalid_at(p, "lightmap-rows section", m);
        let v = pack.view(e)?;
        let m: RowsMeta = v.meta().map_err(|e| bad(e.to_string()))?;
        if size.is_some_and(|s| s != (m.width, m.height))
            || step.is_some_and(|s| s != m.trace_step)
            || m.start != next
            || m.end < m.start
        {
            return Err(bad(format!(
                "rows {}..{} of a {}×{} map do not continue the shards before it (row {next})",
                m.start, m.end, m.width, m.height
            )));
        }
        size = Some((m.width, m.height));
        step = Some(m.trace_step);
        next = m.end;
        let t: &[[f32; 3]] = v.array("texels").map_err(|e| bad(e.to_string()))?;
        let d: &[[f32; 3]] = v.array("direct").map_err(|e| bad(e.to_string()))?;
        let want = ((m.end - m.start) * m.width) as usize;
        if t.len() != want || d.len() != want {
            return Err(bad(format!("{} texels, expected {want}", t.len())));
        }
        texels.extend_from_slice(t);
        direct.extend_from_slice(d);
    }
    let mut outs = Vec::new();
    if let Some((width, height)) = size {
        if next != height {
            return Err(Error::usage(format!(
                "the light map's row shards end at row {next} of {height}: a shard is missing"
            )));
        }
        let map = crate::lightmap::Lightmap {
            width,
            height,
            texels,
        };
        outs = crate::lightmap::terrain_sections_of(
            &map,
            &direct,
            &s.pipeline.lightmap,
            step.unwrap_or(1),
        );
    }
    finish("lightmap", out, outs, Vec::new())
}

/// The instances of shard `i` of `n` (0-based): `i*len/n .. (i+1)*len/n`.
pub fn shard_range(i: usize, n: usize, len: usize) -> std::ops::Range<usize> {
    Shard::Of(i, n).range(len)
}

/// Parses `I/N` (1-based I, as written on the command line) into a 0-based shard and count.
pub fn parse_shard(text: &str) -> std::result::Result<(usize, usize), String> {
    let bad = || format!("{text:?} is not I/N with 1 <= I <= N, e.g. 3/8");
    let (i, n) = text.split_once('/').ok_or_else(bad)?;
    let i: usize = i.trim().parse().map_err(|_| bad())?;
    let n: usize = n.trim().parse().map_err(|_| bad())?;
    if i == 0 || n == 0 || i > n {
        return Err(bad());
    }
    Ok((i - 1, n))
}

/// A sharded stage's join (its second action): its sections from the shards' packs, in shard
/// order, through [`AnyStage::join`] as the graph joins its shards (each part's size from
/// [`AnyStage::shard_size`]).
pub fn stage_join(
    st: &dyn AnyStage,
    s: &SceneArgs,
    shards: &[PathBuf],
    out: &Path,
) -> Result<UnitReport> {
    let d = st.def();
    let mut parts = Vec::new();
    for p in shards {
        let sections = read_packs(std::slice::from_ref(p))?;
        let n = st.shard_size(&sections).map_err(|e| {
            Error::invalid_at(p, format!("{}-shard section", d.name), e.to_string())
        })?;
        parts.push((n, sections));
    }
    let sections = st.join(parts, &s.pipeline)?;
    finish(d.name, out, sections, Vec::new())
}

/// The files a whole bake reads, as [`crate::graph::build`] records them: the scene's ECO,
/// RAW and colour-map files, the pipeline file, every model with the files it read, the sky.
pub fn scene_files(
    s: &SceneArgs,
    plan: &ingest::eco::ScenePlan,
    models: &[ModelDeps],
) -> BTreeSet<PathBuf> {
    let mut files: BTreeSet<PathBuf> = plan.files.iter().cloned().collect();
    files.extend(s.pipeline_file.iter().cloned());
    for m in models {
        files.extend(
            m.files
                .iter()
                .filter(|f| f.blake3.is_some())
                .map(|f| f.path.clone()),
        );
    }
    files.extend(s.sky.iter().cloned());
    files
}

/// The `build` record: its key over every file the bake read (the models' files as their
/// units hashed them) and the counts.
pub fn record(s: &SceneArgs, deps: &[PathBuf], out: &Path) -> Result<UnitReport> {
    let plan = s.plan()?;
    let mut models = Vec::new();
    for d in deps {
        let bytes = crate::error::read_file(d)?;
        let m: ModelDeps = serde_json::from_slice(&bytes).map_err(|e| {
            Error::invalid_at(
                d,
                format!("line {}", e.line()),
                format!("not a model record of `bake unit model`: {e}"),
            )
        })?;
        models.push(m);
    }
    let known: std::collections::BTreeMap<&Path, &FileDep> = models
        .iter()
        .flat_map(|m| m.files.iter())
        .filter(|f| f.blake3.is_some())
        .map(|f| (f.path.as_path(), f))
        .collect();
    let files = scene_files(s, &plan, &models);
    let mut file_deps = Vec::with_capacity(files.len());
    for f in &files {
        file_deps.push(match known.get(f.as_path()) {
            Some(d) => (*d).clone(),
            None => FileDep {
                path: f.clone(),
                blake3: Some(hex(&cache::hash_file(f)?)),
            },
        });
    }
    let file_deps = crate::graph::record_files(&s.names()?, &file_deps);
    let opts = BuildOptions {
        scenes: s.scenes.clone(),
        sky: s.sky.clone(),
        ingest: s.ingest.clone(),
        pipeline: s.pipeline.clone(),
        pipeline_file: s.pipeline_file.clone(),
        ..Default::default()
    };
    let key = crate::graph::build_key(&opts, BAKE_VERSION, &file_deps);
    let sec = crate::graph::build_section(&crate::graph::BuildMeta {
        key: key.hex(),
        files: file_deps,
        models: plan.models.len() as u64,
        instances: plan.scene.instances.items.len() as u64,
        triangles: models.iter().map(|m| m.triangles).sum(),
    });
    finish("record", out, vec![sec], Vec::new())
}

/// `bake merge`: the union of the packs' sections in argument order. A name seen again with
/// the same payload is kept once; with a different payload it is an error naming both files.
pub fn merge(inputs: &[PathBuf], out: &Path) -> Result<UnitReport> {
    let mut seen: std::collections::HashMap<String, (usize, [u8; 32], String)> =
        std::collections::HashMap::new();
    let mut sections = Vec::new();
    for (k, p) in inputs.iter().enumerate() {
        for sec in Pack::open(p)?.checked_sections()? {
            match seen.get(&sec.name) {
                Some((j, h, kind)) => {
                    if h != sec.payload.hash() || *kind != sec.kind {
                        return Err(Error::invalid_at(
                            p,
                            format!("section {:?}", sec.name),
                            format!(
                                "differs from the section of the same name in {}; \
                                 a merge takes each section from one place",
                                inputs[*j].display()
                            ),
                        ));
                    }
                }
                None => {
                    seen.insert(sec.name.clone(), (k, *sec.payload.hash(), sec.kind.clone()));
                    sections.push(sec);
                }
            }
        }
    }
    finish("merge", out, sections, Vec::new())
}
