//! `bake plan`: the stage graph of one scene as a list of actions for an existing build engine
//! (Ninja, Bazel) instead of our own scheduler.
//!
//! Each action is one `bake unit ...` command ([`actions`]) with every file it reads and writes
//! declared: the scene's files as [`crate::graph::build`] resolves them (the same resolution as
//! `--depfile`), the packs of the units it reads, its own pack. All paths are relative to the
//! folder the engine runs the actions in, so an action run in a folder holding only its declared
//! inputs succeeds. The last action, `bake merge`, joins the units' packs in the graph's order
//! into a pack byte-identical to `bake SCENE.eco` run with the same arguments in that folder.

pub mod actions;
pub mod bazel;
pub mod ninja;

use crate::error::{Error, Result};
use crate::ingest::{self, IngestOptions};
use std::path::{Component, Path, PathBuf};

/// What `bake plan` was asked for (paths as the user wrote them, relative to the working
/// directory).
#[derive(Debug, Clone, Default)]
pub struct PlanOptions {
    pub scenes: Vec<PathBuf>,
    pub sky: Option<PathBuf>,
    pub model_dirs: Vec<PathBuf>,
    pub color_map: Option<PathBuf>,
    pub allow_paths: Vec<PathBuf>,
    /// `--max-memory` (bytes), passed to every action and used to resolve the scene.
    pub max_memory: Option<u64>,
    /// `--pipeline` as given (a preset name or a file).
    pub pipeline: Option<String>,
    pub preview: bool,
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
    pub args: Vec<String>,
    pub inputs: Vec<PathBuf>,
    /// Inputs that must exist but whose contents the action does not read (the scene's model
    /// files, which resolving the scene only looks up). Part of the hermetic input set.
    pub lookups: Vec<PathBuf>,
    pub outputs: Vec<PathBuf>,
}

/// The whole plan.
#[derive(Debug, Clone)]
pub struct Plan {
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
    let s = &pipeline.stages;
    let mut actions = Vec::new();
    let unit = |name: &str, extra: &[String]| -> Vec<String> {
        let mut a = vec!["unit".to_string(), name.to_string()];
        a.extend(common.iter().cloned());
        a.extend(extra.iter().cloned());
        a
    };
    let o = |p: &str| vec!["-o".to_string(), p.to_string()];
    let ins = |packs: &[&PathBuf]| -> Vec<String> {
        let mut v = Vec::new();
        for p in packs {
            v.extend(["--in".to_string(), arg(p)]);
        }
        v
    };

    // Units that resolve the scene (they look the model files up, reading none of them).
    let scene_action = |id: &str, out: &str| Action {
        id: id.into(),
        args: unit(id, &o(out)),
        inputs: Vec::new(),
        lookups: model_files.clone(),
        outputs: vec![out.into()],
    };
    let mut terrain = scene_action("terrain", "terrain.bake");
    terrain.inputs = with_pipeline(scene_files.clone());
    actions.push(terrain);
    let mut merged: Vec<PathBuf> = vec!["terrain.bake".into()];
    let mut model_packs = Vec::new();
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
        if s.prt {
            let prt = PathBuf::from(format!("prt/prt-{k:03}.bake"));
            let mut a = vec!["--name".to_string(), name.clone()];
            a.extend(ins(&[&pack]));
            a.extend(o(&arg(&prt)));
            actions.push(Action {
                id: format!("prt-{k:03}"),
                args: unit("prt", &a),
                inputs: with_pipeline(vec![pack.clone()]),
                lookups: Vec::new(),
                outputs: vec![prt.clone()],
            });
            merged.push(prt);
        }
        if s.lod {
            let lod = PathBuf::from(format!("lod/lod-{k:03}.bake"));
            let mut a = vec!["--name".to_string(), name.clone()];
            a.extend(ins(&[&pack]));
            a.extend(o(&arg(&lod)));
            actions.push(Action {
                id: format!("lod-{k:03}"),
                args: unit("lod", &a),
                inputs: with_pipeline(vec![pack.clone()]),
                lookups: Vec::new(),
                outputs: vec![lod.clone()],
            });
            merged.push(lod);
        }
        model_packs.push(pack);
        model_deps.push(deps);
    }
    let mut inst = scene_action("instances", "instances.bake");
    inst.inputs = with_pipeline(scene_files.clone());
    actions.push(inst);
    merged.push("instances.bake".into());
    let mut geometry: Vec<PathBuf> = vec!["terrain.bake".into()];
    geometry.extend(model_packs.iter().cloned());
    geometry.push("instances.bake".into());
    let mut trace = geometry.clone();
    if s.sky {
        actions.push(Action {
            id: "sky".into(),
            args: unit("sky", &o("sky.bake")),
            inputs: with_pipeline(sky_rel.iter().cloned().collect()),
            lookups: Vec::new(),
            outputs: vec!["sky.bake".into()],
        });
        merged.push("sky.bake".into());
        trace.push("sky.bake".into());
    }
    let trace_refs: Vec<&PathBuf> = trace.iter().collect();
    let over = |id: &str, packs: &[&PathBuf], out: &str, extra: &[String]| -> Action {
        let mut a = extra.to_vec();
        a.extend(ins(packs));
        a.extend(o(out));
        Action {
            id: id.into(),
            args: unit(id, &a),
            inputs: {
                let mut v: Vec<PathBuf> = packs.iter().map(|p| (*p).clone()).collect();
                v.extend(pipeline_rel.iter().cloned());
                v
            },
            lookups: Vec::new(),
            outputs: vec![out.into()],
        }
    };
    // `shards` actions of `unit` over the traced packs, shard I/N in `flag`, writing
    // `<stem>-I-of-N.bake`, named `<unit>-I-of-N`; returns their packs in shard order.
    let sharded = |unit: &str, flag: &str, stem: &str, shards: usize, actions: &mut Vec<Action>| {
        let mut packs = Vec::new();
        for i in 1..=shards {
            let out = format!("{stem}-{i}-of-{shards}.bake");
            let mut a = over(
                unit,
                &trace_refs,
                &out,
                &[flag.into(), format!("{i}/{shards}")],
            );
            a.id = format!("{unit}-{i}-of-{shards}");
            actions.push(a);
            packs.push(PathBuf::from(out));
        }
        packs
    };
    if s.lightmap {
        let shards = opts.lightmap_shards.unwrap_or(1).max(1);
        if shards == 1 {
            actions.push(over("lightmap", &trace_refs, "lightmap.bake", &[]));
        } else {
            let rows = sharded("lightmap", "--rows", "lightmap/rows", shards, &mut actions);
            let refs: Vec<&PathBuf> = rows.iter().collect();
            actions.push(over("lightmap-join", &refs, "lightmap.bake", &[]));
        }
        merged.push("lightmap.bake".into());
    }
    if s.atlas {
        actions.push(over("atlas", &trace_refs, "atlas.bake", &[]));
        merged.push("atlas.bake".into());
    }
    if s.envmaps {
        let n = plan.scene.instances.items.len();
        let per = pipeline.units.envmap_shard_instances.max(1) as usize;
        let shards = opts.shards.unwrap_or(n.max(1).div_ceil(per)).max(1);
        let shard_packs = sharded(
            "envmaps",
            "--shard",
            "envmaps/envmaps",
            shards,
            &mut actions,
        );
        let refs: Vec<&PathBuf> = shard_packs.iter().collect();
        let mut join = over("envmaps-join", &refs, "envmaps.bake", &[]);
        join.id = "envmaps-join".into();
        actions.push(join);
        merged.push("envmaps.bake".into());
    }
    if s.cluster {
        let i: PathBuf = "instances.bake".into();
        let e: PathBuf = "envmaps.bake".into();
        actions.push(over("cluster", &[&i, &e], "cluster.bake", &[]));
        merged.push("cluster.bake".into());
    }
    if s.bittree {
        let mut b = scene_action("bittree", "bittree.bake");
        b.inputs = with_pipeline(scene_files.clone());
        actions.push(b);
        merged.push("bittree.bake".into());
    }
    let geo_refs: Vec<&PathBuf> = geometry.iter().collect();
    if s.svo {
        actions.push(over("svo", &geo_refs, "svo.bake", &[]));
        merged.push("svo.bake".into());
    }
    if s.linespace {
        actions.push(over("linespace", &geo_refs, "linespace.bake", &[]));
        merged.push("linespace.bake".into());
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
