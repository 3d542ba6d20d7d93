//! `bake unit STAGE ...`: one unit of the stage graph as an action with explicit inputs and
//! outputs (what `bake plan` writes for Ninja and Bazel; [`crate::plan::actions`]). Every unit
//! takes the scene's arguments of `bake SCENE.eco` (scenes, `--sky`, `--models`, `--color-map`,
//! `--pipeline`/`--set`/`--preview`) so that its options are the graph's.

use super::{Global, Outcome};
use crate::error::Result;
use crate::plan::actions::{self, SceneArgs, UnitReport};
use std::path::PathBuf;

/// The arguments of `bake SCENE.eco` that every unit shares, and the unit's pack.
#[derive(Debug, Clone, clap::Args)]
pub struct UnitFlags {
    #[command(flatten)]
    pub flags: super::scene::SceneFlags,
    /// The unit's pack.
    #[arg(short, long, required = true)]
    pub output: PathBuf,
}

impl UnitFlags {
    fn scene(&self, g: &Global) -> Result<SceneArgs> {
        let (pipeline, pipeline_file) = self.flags.pipeline()?;
        Ok(SceneArgs {
            scenes: self.flags.scenes.clone(),
            sky: self.flags.sky.clone(),
            ingest: self.flags.ingest(g),
            pipeline,
            pipeline_file,
        })
    }
}

#[derive(Debug, Clone, clap::Args)]
pub struct UnitArgs {
    #[command(subcommand)]
    pub unit: Unit,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub enum Unit {
    /// The terrain's sections and the prepared terrain.
    Terrain(UnitFlags),
    /// One model: ingest and materials; also writes the files it read (`--deps`).
    Model {
        #[command(flatten)]
        scene: UnitFlags,
        /// The model's name in the scene (its file name).
        #[arg(long)]
        name: String,
        /// The model file, as the scene resolves it.
        #[arg(long)]
        path: PathBuf,
        /// JSON record of the files read and the triangle count (for `bake unit record`).
        #[arg(long, required = true)]
        deps: PathBuf,
    },
    /// One model's PRT over its model pack.
    Prt {
        #[command(flatten)]
        scene: UnitFlags,
        #[arg(long)]
        name: String,
        /// The model's pack (`bake unit model`).
        #[arg(long = "in", required = true)]
        input: PathBuf,
    },
    /// One model's levels of detail over its model pack.
    Lod {
        #[command(flatten)]
        scene: UnitFlags,
        #[arg(long)]
        name: String,
        /// The model's pack (`bake unit model`).
        #[arg(long = "in", required = true)]
        input: PathBuf,
    },
    /// The scene's `instances` section.
    Instances(UnitFlags),
    /// The sky's cube map, sun and SH.
    Sky(UnitFlags),
    /// The terrain light map over the packs of terrain, models, instances, sky (with `--rows
    /// I/N`: one shard of its rows, joined by `lightmap-join`).
    Lightmap {
        #[command(flatten)]
        packs: WithPacks,
        /// Which shard of the rows: I of N (1-based).
        #[arg(long, value_parser = actions::parse_shard)]
        rows: Option<(usize, usize)>,
    },
    /// The terrain light map from its row shards' packs (in shard order).
    LightmapJoin(WithPacks),
    /// The object atlases over the same packs.
    Atlas(WithPacks),
    /// One shard of the environment maps (`--shard I/N`), over the same packs.
    Envmaps {
        #[command(flatten)]
        packs: WithPacks,
        /// Which shard: I of N (1-based).
        #[arg(long, value_parser = actions::parse_shard, required = true)]
        shard: (usize, usize),
    },
    /// The `envmaps` section from the shards' packs (in shard order).
    EnvmapsJoin(WithPacks),
    /// Clustering over the packs of the instances and the environment maps.
    Cluster(WithPacks),
    /// The BitTree of the scene's instances.
    Bittree(UnitFlags),
    /// The SVO over the packs of terrain, models, instances.
    Svo(WithPacks),
    /// The N-tree with line spaces over the packs of terrain, models, instances.
    Linespace(WithPacks),
    /// The `build` record over the models' records (`--deps`).
    Record {
        #[command(flatten)]
        scene: UnitFlags,
        #[arg(long = "deps", value_name = "JSON")]
        deps: Vec<PathBuf>,
    },
}

#[derive(Debug, Clone, clap::Args)]
pub struct WithPacks {
    #[command(flatten)]
    pub scene: UnitFlags,
    /// The packs the unit reads, in the graph's order (repeatable).
    #[arg(long = "in", value_name = "PACK", required = true)]
    pub inputs: Vec<PathBuf>,
}

/// A registered stage's unit ([`actions::stage_unit`]): the stage whose first action is
/// `action`.
fn stage(
    action: &str,
    f: &UnitFlags,
    g: &Global,
    model: Option<&str>,
    inputs: &[PathBuf],
    shard: Option<(usize, usize)>,
) -> Result<UnitReport> {
    let st = actions::stage_of_action(action)?;
    actions::stage_unit(st, &f.scene(g)?, model, inputs, shard, &f.output)
}

pub fn run(args: &UnitArgs, g: &Global) -> Result<Outcome> {
    let r: UnitReport = match &args.unit {
        Unit::Terrain(f) => actions::terrain(&f.scene(g)?, &f.output)?,
        Unit::Model {
            scene,
            name,
            path,
            deps,
        } => actions::model(&scene.scene(g)?, name, path, &scene.output, deps)?,
        Unit::Prt { scene, name, input } => stage(
            "prt",
            scene,
            g,
            Some(name),
            std::slice::from_ref(input),
            None,
        )?,
        Unit::Lod { scene, name, input } => stage(
            "lod",
            scene,
            g,
            Some(name),
            std::slice::from_ref(input),
            None,
        )?,
        Unit::Instances(f) => actions::instances(&f.scene(g)?, &f.output)?,
        Unit::Sky(f) => stage("sky", f, g, None, &[], None)?,
        Unit::Lightmap { packs, rows } => match rows {
            Some(r) => actions::lightmap_rows(
                &packs.scene.scene(g)?,
                &packs.inputs,
                *r,
                &packs.scene.output,
            )?,
            None => stage("lightmap", &packs.scene, g, None, &packs.inputs, None)?,
        },
        Unit::LightmapJoin(w) => {
            actions::lightmap_join(&w.scene.scene(g)?, &w.inputs, &w.scene.output)?
        }
        Unit::Atlas(w) => stage("atlas", &w.scene, g, None, &w.inputs, None)?,
        Unit::Envmaps { packs, shard } => stage(
            "envmaps",
            &packs.scene,
            g,
            None,
            &packs.inputs,
            Some(*shard),
        )?,
        Unit::EnvmapsJoin(w) => {
            actions::envmaps_join(&w.scene.scene(g)?, &w.inputs, &w.scene.output)?
        }
        Unit::Cluster(w) => stage("cluster", &w.scene, g, None, &w.inputs, None)?,
        Unit::Bittree(f) => stage("bittree", f, g, None, &[], None)?,
        Unit::Svo(w) => stage("svo", &w.scene, g, None, &w.inputs, None)?,
        Unit::Linespace(w) => stage("linespace", &w.scene, g, None, &w.inputs, None)?,
        Unit::Record { scene, deps } => actions::record(&scene.scene(g)?, deps, &scene.output)?,
    };
    Ok(outcome(r))
}

pub(crate) fn outcome(r: UnitReport) -> Outcome {
    Outcome {
        json: serde_json::to_value(&r).unwrap_or_default(),
        text: format!(
            "{}: {} ({} sections)\n",
            r.output.display(),
            r.unit,
            r.sections.len()
        ),
        warnings: r.warnings,
    }
}

/// `bake merge A.bake B.bake ... -o OUT.bake`.
#[derive(Debug, Clone, clap::Args)]
pub struct MergeArgs {
    /// The packs, in the order their sections go into the output.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[arg(short, long, required = true)]
    pub output: PathBuf,
}

pub fn run_merge(args: &MergeArgs, _g: &Global) -> Result<Outcome> {
    Ok(outcome(actions::merge(&args.inputs, &args.output)?))
}
