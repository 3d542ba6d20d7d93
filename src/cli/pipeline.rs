//! `bake pipeline list|show|check`: the pipeline presets and files.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::preset::{PRESETS, Pipeline};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct PipelineArgs {
    #[command(subcommand)]
    pub action: PipelineAction,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub(crate) enum PipelineAction {
    /// The preset names.
    List,
    /// A preset (or a file with --set applied) as complete TOML: a starting point for your own.
    Show {
        /// A preset name (default, preview, final, ci) or a pipeline file.
        #[arg(default_value = "default")]
        pipeline: String,
        /// Override one option (repeatable), e.g. `--set prt.samples=256`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Reads a pipeline file and reports the first error (file, line, key).
    Check { file: PathBuf },
}

pub(crate) fn run(args: &PipelineArgs, _g: &Global) -> Result<Outcome> {
    match &args.action {
        PipelineAction::List => Ok(Outcome {
            json: serde_json::json!({ "presets": PRESETS }),
            text: PRESETS.iter().map(|p| format!("{p}\n")).collect(),
            warnings: Vec::new(),
        }),
        PipelineAction::Show { pipeline, set } => {
            let (p, _) = super::build::resolve_pipeline(Some(pipeline), false, set)?;
            Ok(Outcome {
                json: serde_json::to_value(&p).unwrap_or_default(),
                text: p.to_toml(),
                warnings: Vec::new(),
            })
        }
        PipelineAction::Check { file } => {
            if !file.exists() {
                return Err(Error::io(file, std::io::ErrorKind::NotFound.into()));
            }
            let p = Pipeline::load(file)?;
            Ok(Outcome {
                json: serde_json::to_value(&p).unwrap_or_default(),
                text: format!("{}: ok\n", file.display()),
                warnings: Vec::new(),
            })
        }
    }
}
