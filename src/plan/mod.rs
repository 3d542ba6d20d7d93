//! `bake plan`: the stage graph of one scene as a list of actions for an existing build engine
//! (Ninja, Bazel) instead of our own scheduler.
//!
//! Each action is one `bake unit ...` command ([`actions`]) with every file it reads and writes
//! declared: the scene's files as [`crate::graph::build`] resolves them (the same resolution as
//! `--depfile`), the packs of the units it reads, its own pack. All paths are relative to the
//! folder the engine runs the actions in, so an action run in a folder holding only its declared
//! inputs succeeds. The last action, `bake merge`, joins the units' packs in the graph's order
//! into a pack byte-identical to `bake SCENE.eco` run with the same arguments in that folder.
//!
//! The stages' actions come from the stage registry ([`crate::graph::stage::REGISTRY`]), in
//! its order: per model its per-model stages over the model's packs, then the scene's stages,
//! each over the packs made before it that hold a kind it declares. The terrain, model,
//! instances, record and merge actions and the shards (env maps by instances, the light map by
//! rows) with their joins are written here by hand.
#![warn(missing_docs)]

pub mod actions;
pub mod bazel;
pub mod ninja;

use crate::error::{Error, Result};
use crate::graph::stage::{AnyStage, Phase};
use crate::graph::stages::Per;
use crate::ingest::{self, IngestOptions};
use std::path::{Component, Path, PathBuf};

/// What `bake plan` was asked for (paths as the user wrote them, relative to the working
/// directory).
#[derive(Debug, Clone, Default)]
pub struct PlanOptions {
    /// The ECO scene files.
    pub scenes: Vec<PathBuf>,
    /// `--sky`.
    pub sky: Option<PathBuf>,
    /// `--models` folders.
    pub model_dirs: Vec<PathBuf>,
    /// `--color-map`.
    pub color_map: Option<PathBuf>,
    /// `--allow-path` folders.
    pub allow_paths: Vec<PathBuf>,
    /// `--max-memory` (bytes), passed to every action and used to resolve the scene.
    pub max_memory: Option<u64>,
    /// `--pipeline` as given (a preset name or a file).
    pub pipeline: Option<String>,
    /// `--preview`.
    pub preview: bool,
    /// `--set KEY=VALUE` overrides, in order.
    pub set: Vec<String>,
    /// Environment-map shards (default: the pipeline's `units.envmap_shard_instances`).
    pub shards: Option<usize>,
    /// Row shards of the terrain light map (default 1: one action).
    pub lightmap_shards: Option<usize>,
    /// Where the final pack goes (default: `<dir>/<scene stem>.bake`).
    pub output: Option<PathBuf>,
}

/// One action: the `bake` arguments and the files it reads and writes, relative to the folder
/// the actions run in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Action {
    /// A short unique name (`model-003`, `envmaps-2-of-8`).
    pub id: String,
    /// The `bake` arguments (after the program).
    pub args: Vec<String>,
    /// The files it reads.
    pub inputs: Vec<PathBuf>,
    /// Inputs that must exist but whose contents the action does not read (the scene's model
    /// files, which resolving the scene only looks up). Part of the hermetic input set.
    pub lookups: Vec<PathBuf>,
    /// The files it writes.
    pub outputs: Vec<PathBuf>,
}

/// The whole plan.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The actions (the build engine orders them by their inputs and outputs).
    pub actions: Vec<Action>,
    /// The final pack (the merge's output).
    pub output: PathBuf,
    /// Every source file (not made by an action) some action reads.
    pub sources: Vec<PathBuf>,
    /// The `bake plan` arguments that make this plan again when run in its folder (paths relative
    /// to it; without the engine, `-o` and `--bake`, which the emitter adds).
    pub replan_args: Vec<String>,
    /// The files whose change makes the plan itself stale: the scene files given and the pipeline
    /// file (a model's contents only change its actions' outputs).
    pub replan_inputs: Vec<PathBuf>,
}

/// `path` (absolute or relative to the working directory) made absolute without touching the
/// file system: `.` dropped, `..` applied.
pub fn absolute(path: &Path) -> Result<PathBuf> {
    let cwd = std::env::current_dir().map_err(|e| Error::io(".", e))?;
    Ok(normalize(&cwd.join(path)))
}

fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c.as_os_str()),
        }
    }
    out
}

/// `path` relative to `base` (both absolute and normalized).
pub fn relative(path: &Path, base: &Path) -> PathBuf {
    let p: Vec<Component> = path.components().collect();
    let b: Vec<Component> = base.components().collect();
    let common = p.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..b.len() {
        out.push("..");
    }
    for c in &p[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// Computes the plan of a scene whose actions run in `dir` (created if missing, and removed
/// again when the scene cannot be planned).
pub fn make_plan(opts: &PlanOptions, dir: &Path) -> Result<Plan> {
    let created = !dir.exists();
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let plan = plan_in(opts, dir);
    if plan.is_err() && created {
        let _ = std::fs::remove_dir(dir);
    }
    plan
}

fn plan_in(opts: &PlanOptions, dir: &Path) -> Result<Plan> {
    plan_with(opts, dir, crate::graph::stage::REGISTRY)
}

/// [`plan_in`] over the stages of `registry` (a test adds a stage).
fn plan_with(opts: &PlanOptions, dir: &Path, registry: &[&dyn AnyStage]) -> Result<Plan> {
    let base = absolute(dir)?;
    let rel = |p: &Path| -> Result<PathBuf> { Ok(relative(&absolute(p)?, &base)) };
    let first = opts
        .scenes
        .first()
        .ok_or_else(|| Error::usage("no scene given"))?;
    let (pipeline, pipeline_file) =
        crate::graph::preset::resolve(opts.pipeline.as_deref(), opts.preview, &opts.set)?;
    // The arguments every action shares, with paths as the actions see them.
    let mut common: Vec<String> = Vec::new();
    for s in &opts.scenes {
        common.push(arg(&rel(s)?));
    }
    let scenes_rel: Vec<PathBuf> = opts.scenes.iter().map(|p| rel(p)).collect::<Result<_>>()?;
    let sky_rel = opts.sky.as_deref().map(rel).transpose()?;
    let models_rel: Vec<PathBuf> = opts
        .model_dirs
        .iter()
        .map(|p| rel(p))
        .collect::<Result<_>>()?;
    let color_rel = opts.color_map.as_deref().map(rel).transpose()?;
    let allow_rel: Vec<PathBuf> = opts
        .allow_paths
        .iter()
        .map(|p| rel(p))
        .collect::<Result<_>>()?;
    let pipeline_rel = pipeline_file.as_deref().map(rel).transpose()?;
    if let Some(s) = &sky_rel {
        common.extend(["--sky".into(), arg(s)]);
    }
    for m in &models_rel {
        common.extend(["--models".into(), arg(m)]);
    }
    if let Some(c) = &color_rel {
        common.extend(["--color-map".into(), arg(c)]);
    }
    for a in &allow_rel {
        common.extend(["--allow-path".into(), arg(a)]);
    }
    if let Some(m) = opts.max_memory {
        common.extend(["--max-memory".into(), m.to_string()]);
    }
    match (&pipeline_rel, &opts.pipeline, opts.preview) {
        (_, _, true) => common.push("--preview".into()),
        (Some(f), _, false) => common.extend(["--pipeline".into(), arg(f)]),
        (None, Some(name), false) => common.extend(["--pipeline".into(), name.clone()]),
        (None, None, false) => {}
    }
    for s in &opts.set {
        common.extend(["--set".into(), s.clone()]);
    }

    // Resolve the scene as the actions will (paths relative to `base`), reading through `base`.
    let at = |p: &Path| base.join(p);
    let back = |p: &Path| -> PathBuf {
        p.strip_prefix(&base)
            .map(Path::to_path_buf)
            .unwrap_or_else(|_| p.to_path_buf())
    };
    let ingest_opts = IngestOptions {
        model_dirs: models_rel.iter().map(|p| at(p)).collect(),
        color_map: color_rel.as_deref().map(at),
        allow_paths: allow_rel.iter().map(|p| at(p)).collect(),
        limits: opts.max_memory.map_or(
            crate::ingest::limits::Limits::DEFAULT,
            crate::ingest::limits::Limits::with_memory,
        ),
        ..Default::default()
    };
    let abs_scenes: Vec<PathBuf> = scenes_rel.iter().map(|p| at(p)).collect();
    let plan = ingest::eco::scene_plan(&abs_scenes, &ingest_opts)?;
    let policy = ingest::eco::scene_policy(&abs_scenes[0], &ingest_opts);
    let scene_files: Vec<PathBuf> = plan.files.iter().map(|p| back(p)).collect();
    let model_files: Vec<PathBuf> = plan.models.iter().map(|(_, p)| back(p)).collect();
    let with_pipeline = |mut v: Vec<PathBuf>| {
        v.extend(pipeline_rel.iter().cloned());
        v
    };
    let mut actions = Vec::new();
    let unit = |name: &str, extra: &[String]| -> Vec<String> {
        let mut a = vec!["unit".to_string(), name.to_string()];
        a.extend(common.iter().cloned());
        a.extend(extra.iter().cloned());
        a
    };
    let o = |p: &str| vec!["-o".to_string(), p.to_string()];
    let ins = |packs: &[PathBuf]| -> Vec<String> {
        let mut v = Vec::new();
        for p in packs {
            v.extend(["--in".to_string(), arg(p)]);
        }
        v
    };
    // The kinds the listed stages write (what their packs hold).
    let writes = |names: &[&str]| -> Vec<&'static str> {
        names
            .iter()
            .filter_map(|n| registry.iter().find(|s| s.def().name == *n))
            .flat_map(|s| s.def().writes.iter().copied())
            .collect()
    };
    // The packs among `made` that hold a kind `st` declares, in order: what its actions read.
    let reading = |st: &dyn AnyStage, made: &[(PathBuf, Vec<&str>)]| -> Vec<PathBuf> {
        let kinds = st.reads().kinds;
        made.iter()
            .filter(|(_, k)| k.iter().any(|k| kinds.contains(k)))
            .map(|(p, _)| p.clone())
            .collect()
    };

    // The terrain unit resolves the scene (it looks the model files up, reading none of them).
    actions.push(Action {
        id: "terrain".into(),
        args: unit("terrain", &o("terrain.bake")),
        inputs: with_pipeline(scene_files.clone()),
        lookups: model_files.clone(),
        outputs: vec!["terrain.bake".into()],
    });
    let mut merged: Vec<PathBuf> = vec!["terrain.bake".into()];
    // Every pack made so far in merge order, with the kinds it holds.
    let mut made: Vec<(PathBuf, Vec<&str>)> = vec![("terrain.bake".into(), writes(&["terrain"]))];
    let model_stages: Vec<&dyn AnyStage> = registry
        .iter()
        .copied()
        .filter(|s| s.phase() == Phase::Model && s.on(&pipeline))
        .collect();
    let mut model_deps = Vec::new();
    for (k, (name, path)) in plan.models.iter().enumerate() {
        let id = format!("model-{k:03}");
        let pack = PathBuf::from(format!("models/{id}.bake"));
        let deps = PathBuf::from(format!("models/{id}.json"));
        let mesh = ingest::load_mesh_in(path, &policy)?;
        let mut reads = vec![back(path)];
        reads.extend(
            ingest::mesh_side_files(path)
                .into_iter()
                .chain(mesh.textures.iter().map(|t| t.path.clone()))
                .filter(|p| p.is_file())
                .map(|p| back(&p)),
        );
        reads.sort();
        reads.dedup();
        let rel_model = back(path);
        actions.push(Action {
            id: id.clone(),
            args: unit(
                "model",
                &[
                    "--name".into(),
                    name.clone(),
                    "--path".into(),
                    arg(&rel_model),
                    "--deps".into(),
                    arg(&deps),
                    "-o".into(),
                    arg(&pack),
                ],
            ),
            inputs: with_pipeline(reads),
            lookups: Vec::new(),
            outputs: vec![pack.clone(), deps.clone()],
        });
        merged.push(pack.clone());
        // The model's packs: its per-model stages read among them.
        let mut own: Vec<(PathBuf, Vec<&str>)> = vec![(pack, writes(&["ingest", "material"]))];
        for st in &model_stages {
            let act = st.def().actions[0];
            let out = PathBuf::from(format!("{act}/{act}-{k:03}.bake"));
            let packs = reading(*st, &own);
            let mut a = vec!["--name".to_string(), name.clone()];
            a.extend(ins(&packs));
            a.extend(o(&arg(&out)));
            actions.push(Action {
                id: format!("{act}-{k:03}"),
                args: unit(act, &a),
                inputs: with_pipeline(packs),
                lookups: Vec::new(),
                outputs: vec![out.clone()],
            });
            merged.push(out.clone());
            own.push((out, st.def().writes.to_vec()));
        }
        made.extend(own);
        model_deps.push(deps);
    }
    actions.push(Action {
        id: "instances".into(),
        args: unit("instances", &o("instances.bake")),
        inputs: with_pipeline(scene_files.clone()),
        lookups: model_files.clone(),
        outputs: vec!["instances.bake".into()],
    });
    merged.push("instances.bake".into());
    made.push(("instances.bake".into(), vec!["instances"]));

    // One action of a scene stage: `extra` flags, the packs it reads, its pack; its inputs
    // the scene's files (and lookups its models) where it reads the scene, the sky where it
    // reads the sky, its packs, the pipeline file.
    let action = |st: &dyn AnyStage, act: &str, extra: &[String], packs: &[PathBuf], out: &str| {
        let r = st.reads();
        let mut a = extra.to_vec();
        a.extend(ins(packs));
        a.extend(o(out));
        let mut inputs = Vec::new();
        if r.scene {
            inputs.extend(scene_files.iter().cloned());
        }
        if r.sky {
            inputs.extend(sky_rel.iter().cloned());
        }
        inputs.extend(packs.iter().cloned());
        Action {
            id: act.into(),
            args: unit(act, &a),
            inputs: with_pipeline(inputs),
            lookups: if r.scene {
                model_files.clone()
            } else {
                Vec::new()
            },
            outputs: vec![out.into()],
        }
    };
    // `shards` actions of `st`'s first action over `packs`, shard I/N in `flag`, writing
    // `<stem>-I-of-N.bake`, named `<action>-I-of-N`, then its second action joining them.
    let sharded = |st: &dyn AnyStage,
                   flag: &str,
                   stem: &str,
                   shards: usize,
                   packs: &[PathBuf],
                   out: &str,
                   actions: &mut Vec<Action>| {
        let acts = st.def().actions;
        let mut parts = Vec::new();
        for i in 1..=shards {
            let part = format!("{stem}-{i}-of-{shards}.bake");
            let extra = [flag.to_string(), format!("{i}/{shards}")];
            let mut a = action(st, acts[0], &extra, packs, &part);
            a.id = format!("{}-{i}-of-{shards}", acts[0]);
            actions.push(a);
            parts.push(PathBuf::from(part));
        }
        actions.push(action(st, acts[1], &[], &parts, out));
    };
    // The scene's stages in registry order, each over the packs that hold the kinds it reads.
    for st in registry.iter().copied() {
        if st.phase() != Phase::Scene || !st.on(&pipeline) {
            continue;
        }
        let d = st.def();
        let act = d.actions[0];
        let out = format!("{act}.bake");
        let packs = reading(st, &made);
        let lightmap_rows = opts.lightmap_shards.unwrap_or(1).max(1);
        if d.per == Per::Shards {
            // Shards of instances (default: the pipeline's `units.envmap_shard_instances`).
            let n = plan.scene.instances.items.len();
            let per = pipeline.units.envmap_shard_instances.max(1) as usize;
            let shards = opts.shards.unwrap_or(n.max(1).div_ceil(per)).max(1);
            let stem = format!("{act}/{act}");
            sharded(st, "--shard", &stem, shards, &packs, &out, &mut actions);
        } else if d.name == "lightmap" && lightmap_rows > 1 {
            // The terrain light map in shards of rows.
            let stem = "lightmap/rows";
            sharded(
                st,
                "--rows",
                stem,
                lightmap_rows,
                &packs,
                &out,
                &mut actions,
            );
        } else {
            actions.push(action(st, act, &[], &packs, &out));
        }
        merged.push(out.clone().into());
        made.push((out.into(), d.writes.to_vec()));
    }
    // The build record reads the scene, the sky, the pipeline file and the models' records.
    let mut rec_args = Vec::new();
    for d in &model_deps {
        rec_args.extend(["--deps".to_string(), arg(d)]);
    }
    rec_args.extend(o("record.bake"));
    let mut rec_inputs = scene_files.clone();
    rec_inputs.extend(sky_rel.iter().cloned());
    rec_inputs.extend(model_deps.iter().cloned());
    actions.push(Action {
        id: "record".into(),
        args: unit("record", &rec_args),
        inputs: with_pipeline(rec_inputs),
        lookups: model_files.clone(),
        outputs: vec!["record.bake".into()],
    });
    merged.push("record.bake".into());

    let output = match &opts.output {
        Some(p) => rel(p)?,
        None => PathBuf::from(format!(
            "{}.bake",
            first
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scene".into())
        )),
    };
    let mut margs = vec!["merge".to_string()];
    margs.extend(merged.iter().map(|p| arg(p)));
    margs.extend(["-o".to_string(), arg(&output)]);
    actions.push(Action {
        id: "merge".into(),
        args: margs,
        inputs: merged,
        lookups: Vec::new(),
        outputs: vec![output.clone()],
    });

    let made: std::collections::BTreeSet<&PathBuf> =
        actions.iter().flat_map(|a| a.outputs.iter()).collect();
    let mut sources: Vec<PathBuf> = actions
        .iter()
        .flat_map(|a| a.inputs.iter().chain(&a.lookups))
        .filter(|p| !made.contains(p))
        .cloned()
        .collect();
    sources.sort();
    sources.dedup();
    let mut replan_args = common.clone();
    if let Some(n) = opts.shards {
        replan_args.extend(["--shards".into(), n.to_string()]);
    }
    if let Some(n) = opts.lightmap_shards {
        replan_args.extend(["--lightmap-shards".into(), n.to_string()]);
    }
    if opts.output.is_some() {
        replan_args.extend(["--output".into(), arg(&output)]);
    }
    Ok(Plan {
        actions,
        output,
        sources,
        replan_args,
        replan_inputs: with_pipeline(scenes_rel),
    })
}

fn arg(p: &Path) -> String {
    p.display().to_string()
}

/// Quotes one argument for a POSIX shell (only where needed).
pub fn shell_quote(s: &str) -> String {
    let plain = !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./=:,+@%".contains(&b));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_walk_up_and_down() {
        let r = |p: &str, b: &str| relative(Path::new(p), Path::new(b));
        assert_eq!(r("/a/b/c.eco", "/a/d"), PathBuf::from("../b/c.eco"));
        assert_eq!(r("/a/b/c.eco", "/a/b"), PathBuf::from("c.eco"));
        assert_eq!(r("/a", "/a"), PathBuf::from("."));
        assert_eq!(r("/x/y", "/a/b"), PathBuf::from("../../x/y"));
        assert_eq!(normalize(Path::new("/a/./b/../c")), PathBuf::from("/a/c"));
    }

    #[test]
    fn shards_cover_every_instance_once() {
        for len in [0usize, 1, 7, 100, 25_001] {
            for n in [1usize, 2, 3, 8, 50] {
                let mut next = 0;
                for i in 0..n {
                    let r = actions::shard_range(i, n, len);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, len, "{len} in {n}");
            }
        }
        assert_eq!(actions::parse_shard("3/8"), Ok((2, 8)));
        for bad in ["0/3", "4/3", "x/2", "3", "1/0"] {
            assert!(actions::parse_shard(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn shell_quoting() {
        assert_eq!(shell_quote("a/b.eco"), "a/b.eco");
        assert_eq!(shell_quote("prt.samples=64"), "prt.samples=64");
        assert_eq!(shell_quote("a b"), "'a b'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert_eq!(shell_quote(""), "''");
    }
}

/// The registry drives the graph, the plan and the units: a toy stage registered here (and
/// named nowhere else) runs in `graph::build`, gets its action in the plan over the packs
/// that hold the kind it declares, runs as a unit over packs, and gives the same bytes
/// each way; a unit that reads an undeclared section, or a key that skips the declared
/// sections, fails with an error naming them.
#[cfg(test)]
mod registry_tests {
    use super::*;
    use crate::graph::stage::toy;
    use crate::graph::{BuildOptions, CacheMode};
    use crate::pack::{Pack, hex};

    fn fixture() -> (tempfile::TempDir, BuildOptions) {
        let dir = tempfile::tempdir().unwrap();
        crate::fixtures::write_all(dir.path()).unwrap();
        let mut opts = BuildOptions {
            scenes: vec![dir.path().join("scene.eco")],
            output: Some(dir.path().join("scene.bake")),
            sky: Some(dir.path().join("sky.hdr")),
            cache: CacheMode::Off,
            ..Default::default()
        };
        // Only what the toy needs, and the sky (whose `sun` it must not see).
        let st = &mut opts.pipeline.stages;
        (
            st.prt,
            st.lod,
            st.lightmap,
            st.atlas,
            st.envmaps,
            st.cluster,
        ) = (false, false, false, false, false, false);
        (dir, opts)
    }

    fn meta(pack: &Pack, name: &str) -> toy::ToyMeta {
        let e = pack.find(name).expect("section");
        pack.view(e).unwrap().meta().unwrap()
    }

    #[test]
    fn a_registered_toy_stage_runs_in_the_graph_the_plan_as_a_unit_and_as_a_command() {
        let (dir, mut opts) = fixture();
        let registry = toy::with(&toy::TOY);
        let cache = dir.path().join("cache");
        opts.cache = CacheMode::Dir(cache);
        let silent = crate::graph::progress::Silent;

        // The graph: its unit recorded, its section after the other stages' (before `build`),
        // over the pack's own `instances` section, its view holding that section only.
        let r = crate::graph::build_with(&opts, &silent, &registry).unwrap();
        let rec: Vec<_> = r.stages.iter().filter(|s| s.stage == "toy").collect();
        assert_eq!(rec.len(), 1);
        assert_eq!((rec[0].unit.as_str(), rec[0].cache), ("scene", "miss"));
        let out = opts.output.clone().unwrap();
        let pack = Pack::open(&out).unwrap();
        let names: Vec<&str> = pack.sections().iter().map(|s| s.name.as_str()).collect();
        assert_eq!(&names[names.len() - 2..], ["toy", "build"]);
        let inst = pack.find("instances").unwrap().checksum;
        let m = meta(&pack, "toy");
        let want = toy::ToyMeta {
            instances: hex(&inst),
            option: 7,
            sections: 1,
        };
        assert_eq!(m, want);
        let graph_toy = pack.payload(pack.find("toy").unwrap()).to_vec();
        // Its key is the graph's: the same bake again is a hit.
        std::fs::remove_file(&out).unwrap();
        let r = crate::graph::build_with(&opts, &silent, &registry).unwrap();
        let rec = r.stages.iter().find(|s| s.stage == "toy").unwrap();
        assert_eq!(rec.cache, "hit");

        // The plan: one action `bake unit toy` over the packs holding `instances`, merged
        // before the build record.
        let popts = PlanOptions {
            scenes: opts.scenes.clone(),
            sky: opts.sky.clone(),
            pipeline: Some("default".into()),
            set: ["prt", "lod", "atlas", "lightmap", "cluster", "envmaps"]
                .iter()
                .map(|s| format!("stages.{s}=false"))
                .collect(),
            ..Default::default()
        };
        let build = dir.path().join("build");
        std::fs::create_dir_all(&build).unwrap();
        let plan = plan_with(&popts, &build, &registry).unwrap();
        let a = plan
            .actions
            .iter()
            .find(|a| a.id == "toy")
            .expect("toy action");
        assert_eq!(a.inputs, [PathBuf::from("instances.bake")]);
        assert_eq!(&a.args[..2], ["unit", "toy"]);
        assert!(a.args.ends_with(&[
            "--in".into(),
            "instances.bake".into(),
            "-o".into(),
            "toy.bake".into()
        ]));
        let merge = plan.actions.last().unwrap();
        let n = merge.inputs.len();
        assert_eq!(
            &merge.inputs[n - 2..],
            [PathBuf::from("toy.bake"), "record.bake".into()]
        );
        // Both build engines' files carry its action: Ninja's `build` edge and Bazel's rule.
        let ninja = ninja::build_ninja(&plan, Path::new("bake"));
        assert!(
            ninja.contains("build toy.bake: bake instances.bake")
                && ninja.contains("args = unit toy ")
                && ninja.contains("--in instances.bake -o toy.bake\n  desc = toy\n"),
            "{ninja}"
        );
        let bazel = bazel::build_bazel(&plan);
        assert!(
            bazel.contains("name = \"toy\",")
                && bazel.contains("outs = [\"toy.bake\"]")
                && bazel.contains("args = [\"unit\", \"toy\", ")
                && bazel.contains("\"--in\", \"@IN:instances.bake\", \"-o\", \"@OUT:toy.bake\"]"),
            "{bazel}"
        );
        // Without the toy, the plan is the registry's (the same actions less the toy's).
        let plain = plan_in(&popts, &build).unwrap();
        let ids = |p: &Plan| -> Vec<String> {
            p.actions
                .iter()
                .map(|a| a.id.clone())
                .filter(|i| i != "toy")
                .collect()
        };
        assert_eq!(ids(&plain), ids(&plan));

        // As a unit over packs (more than it declares): the graph's bytes.
        let s = scene_args(&opts);
        let [ip, tp, sp, up] = ["instances", "terrain", "sky", "toy"]
            .map(|n| dir.path().join(format!("{n}.unit.bake")));
        actions::instances(&s, &ip).unwrap();
        actions::terrain(&s, &tp).unwrap();
        sky_unit(&s, &sp);
        let rep =
            actions::stage_unit(&toy::TOY, &s, None, &[tp, ip, sp.clone()], None, &up).unwrap();
        assert_eq!(rep.sections, ["toy"]);
        let unit = Pack::open(&up).unwrap();
        let unit_toy = unit.payload(unit.find("toy").unwrap()).to_vec();
        assert_eq!(unit_toy, graph_toy);

        // The command line: `bake stage toy PACK` (made from the registry, as `bake stage
        // --list` shows it) over the graph's pack, which holds far more than the toy declares:
        // the graph's bytes again.
        let g = crate::cli::Global {
            quiet: true,
            ..Default::default()
        };
        let args = |stage: Option<&str>, list: bool| crate::cli::stage::StageArgs {
            stage: stage.map(str::to_string),
            input: Some(out.clone()),
            output: Some(dir.path().join("cli-toy.bake")),
            pipeline: None,
            set: Vec::new(),
            list,
        };
        let listed = crate::cli::stage::run_in(&registry, &args(None, true), &g).unwrap();
        assert!(
            listed.text.lines().any(|l| l.starts_with("toy ")),
            "{}",
            listed.text
        );
        let plain = crate::cli::stage::run(&args(None, true), &g).unwrap();
        assert!(!plain.text.contains("toy "), "{}", plain.text);
        let o = crate::cli::stage::run_in(&registry, &args(Some("toy"), false), &g).unwrap();
        assert_eq!(o.json["sections"], serde_json::json!(["toy"]));
        assert_eq!(o.json["units"], serde_json::json!(["scene"]));
        let cli = Pack::open(&dir.path().join("cli-toy.bake")).unwrap();
        let cli_toy = cli.payload(cli.find("toy").unwrap()).to_vec();
        assert_eq!(cli_toy, graph_toy);
        // Without the toy registered, the command does not know it.
        let e = crate::cli::stage::run(&args(Some("toy"), false), &g)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no registered stage \"toy\""), "{e}");
    }

    /// The fixture's scene as `bake unit` arguments.
    fn scene_args(opts: &crate::graph::BuildOptions) -> actions::SceneArgs {
        actions::SceneArgs {
            scenes: opts.scenes.clone(),
            sky: opts.sky.clone(),
            pipeline: opts.pipeline.clone(),
            ..Default::default()
        }
    }

    /// The sky stage's unit into `out`.
    fn sky_unit(s: &actions::SceneArgs, out: &std::path::Path) {
        actions::stage_unit(
            actions::stage_of_action("sky").unwrap(),
            s,
            None,
            &[],
            None,
            out,
        )
        .unwrap();
    }

    #[test]
    fn a_unit_that_reads_an_undeclared_section_fails_naming_it() {
        let (dir, opts) = fixture();
        let silent = crate::graph::progress::Silent;
        let e = crate::graph::build_with(&opts, &silent, &toy::with(&toy::GREEDY))
            .expect_err("the greedy toy reads `sun`")
            .to_string();
        assert!(
            e.contains("stage toy") && e.contains("\"sun\"") && e.contains("does not declare"),
            "{e}"
        );
        // The same as a unit over packs holding the section.
        let s = scene_args(&opts);
        let (ip, sp) = (dir.path().join("i.bake"), dir.path().join("s.bake"));
        actions::instances(&s, &ip).unwrap();
        sky_unit(&s, &sp);
        let e = actions::stage_unit(
            &toy::GREEDY,
            &s,
            None,
            &[ip, sp],
            None,
            &dir.path().join("t.bake"),
        )
        .expect_err("refused")
        .to_string();
        assert!(
            e.contains("\"sun\"") && e.contains("does not declare"),
            "{e}"
        );
        // A key that skips the declared sections is refused before the unit runs.
        let mut cached = opts.clone();
        cached.cache = CacheMode::Dir(dir.path().join("cache"));
        let e = crate::graph::build_with(&cached, &silent, &toy::with(&toy::LAZY))
            .expect_err("the lazy key is refused")
            .to_string();
        assert!(
            e.contains("stage toy") && e.contains("does not hash its declared sections"),
            "{e}"
        );
    }
}
