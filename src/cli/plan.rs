//! `bake plan SCENE.eco --emit ninja|bazel -o DIR`: the stage graph as actions of a build
//! engine ([`crate::plan`]).

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::plan::{PlanOptions, make_plan};
use std::path::PathBuf;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Emit {
    /// `DIR/build.ninja` (run `ninja -C DIR`).
    Ninja,
    /// A Bazel workspace in DIR (`BUILD.bazel`, `bake.bzl`, `WORKSPACE`; the inputs copied in).
    Bazel,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct PlanArgs {
    #[command(flatten)]
    pub scene: super::scene::SceneFlags,
    /// The build engine.
    #[arg(long, value_enum)]
    pub emit: Emit,
    /// The folder of the build file (and of the units' packs).
    #[arg(short = 'o', long = "dir", value_name = "DIR", required = true)]
    pub dir: PathBuf,
    /// Environment-map shards (default: the pipeline's units.envmap_shard_instances).
    #[arg(long)]
    pub shards: Option<usize>,
    /// Row shards of the terrain light map (default 1).
    #[arg(long, value_name = "N")]
    pub lightmap_shards: Option<usize>,
    /// The final pack (default: DIR/<scene stem>.bake).
    #[arg(long)]
    pub output: Option<PathBuf>,
    /// The `bake` binary the actions run. Ninja: a relative PATH (from the working directory)
    /// is written relative to DIR, so the build folder and the binary can move together to
    /// another machine; an absolute one as it is. Bazel copies it into the workspace.
    /// Default: this binary, by its absolute path.
    #[arg(long, value_name = "PATH")]
    pub bake: Option<PathBuf>,
}

pub(crate) fn run(args: &PlanArgs, g: &Global) -> Result<Outcome> {
    if args.shards == Some(0) || args.lightmap_shards == Some(0) {
        return Err(Error::usage(
            "--shards and --lightmap-shards must be at least 1",
        ));
    }
    let opts = PlanOptions {
        scenes: args.scene.scenes.clone(),
        sky: args.scene.sky.clone(),
        model_dirs: args.scene.models.clone(),
        color_map: args.scene.color_map.clone(),
        allow_paths: g.allow_paths.clone(),
        max_memory: g.max_memory,
        pipeline: args.scene.pipeline.clone(),
        preview: args.scene.preview,
        set: args.scene.set.clone(),
        shards: args.shards,
        lightmap_shards: args.lightmap_shards,
        output: args.output.clone(),
    };
    let bake = match &args.bake {
        Some(b) => b.clone(),
        None => std::env::current_exe().map_err(|e| Error::io("bake", e))?,
    };
    let (file, plan) = match args.emit {
        Emit::Ninja => {
            let plan = make_plan(&opts, &args.dir)?;
            let tool = if bake.is_relative() {
                let dir = crate::plan::absolute(&args.dir)?;
                crate::plan::relative(&crate::plan::absolute(&bake)?, &dir)
            } else {
                bake
            };
            (crate::plan::ninja::write(&plan, &args.dir, &tool)?, plan)
        }
        Emit::Bazel => crate::plan::bazel::write(&opts, &args.dir, &bake)?,
    };
    let json = serde_json::json!({
        "build_file": file,
        "actions": plan.actions.len(),
        "sources": plan.sources,
        "output": plan.output,
    });
    Ok(Outcome {
        json,
        text: format!(
            "{}: {} actions over {} source files; final pack {}\n",
            file.display(),
            plan.actions.len(),
            plan.sources.len(),
            plan.output.display()
        ),
        warnings: Vec::new(),
    })
}
