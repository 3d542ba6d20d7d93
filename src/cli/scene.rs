//! The scene's arguments of `bake SCENE.eco`, shared by `bake build`, `bake plan` and every
//! `bake unit`, so that an action's options are the graph's.

use super::Global;
use crate::error::Result;
use crate::graph::Pipeline;
use crate::ingest::IngestOptions;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct SceneFlags {
    /// One or more ECO files of one scene.
    #[arg(required = true)]
    pub scenes: Vec<PathBuf>,
    /// HDR sky (.hdr or .exr, lat-long).
    #[arg(long)]
    pub sky: Option<PathBuf>,
    /// Extra folders searched for model files (after the ECO file's folder).
    #[arg(long = "models", value_name = "DIR")]
    pub models: Vec<PathBuf>,
    /// Colour map of the terrain (default: beside the RAW file).
    #[arg(long)]
    pub color_map: Option<PathBuf>,
    /// The stages and their options: a TOML file (see pipelines/) or a preset name
    /// (default, preview, final, ci). Default: the `default` preset.
    #[arg(long, value_name = "FILE|PRESET")]
    pub pipeline: Option<String>,
    /// Override one pipeline option, e.g. `--set prt.samples=256` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Short for `--pipeline preview` (quick, noisy lighting).
    #[arg(long, conflicts_with = "pipeline")]
    pub preview: bool,
}

impl SceneFlags {
    /// The pipeline of `--pipeline`/`--preview`/`--set`, and the file it came from.
    pub(crate) fn pipeline(&self) -> Result<(Pipeline, Option<PathBuf>)> {
        crate::graph::preset::resolve(self.pipeline.as_deref(), self.preview, &self.set)
    }

    /// Ingest options: `--models`, `--color-map` and the global `--allow-path`/`--max-memory`.
    pub(crate) fn ingest(&self, g: &Global) -> IngestOptions {
        IngestOptions {
            model_dirs: self.models.clone(),
            color_map: self.color_map.clone(),
            ..g.ingest_defaults()
        }
    }
}
