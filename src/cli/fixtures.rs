//! `bake fixtures DIR`: writes the project's generated fixture scene, or with `--instances`
//! (and `--models`, `--terrain`) a generated scene at the theses' scale.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct FixturesArgs {
    /// Output folder (created if missing).
    #[arg(default_value = "fixtures/scene")]
    pub dir: PathBuf,
    /// A generated large scene with this many instances instead of the small fixture.
    #[arg(long)]
    pub instances: Option<u32>,
    /// Procedural tree models of the large scene.
    #[arg(long, default_value_t = 30, requires = "instances")]
    pub models: u32,
    /// Terrain samples per side of the large scene (16-bit RAW, 1 m per sample).
    #[arg(long, default_value_t = 4097, requires = "instances")]
    pub terrain: u32,
}

pub(crate) fn run(args: &FixturesArgs, _g: &Global) -> Result<Outcome> {
    let names = match args.instances {
        None => crate::fixtures::write_all(&args.dir)?,
        Some(instances) => {
            if args.models == 0 || args.terrain < 2 {
                return Err(Error::usage(
                    "--models must be at least 1 and --terrain at least 2",
                ));
            }
            let p = crate::fixtures::large::LargeScene {
                instances,
                models: args.models,
                terrain: args.terrain,
            };
            std::fs::create_dir_all(&args.dir).map_err(|e| Error::io(&args.dir, e))?;
            let mut names = Vec::new();
            for (name, bytes) in crate::fixtures::large::large_files(&p) {
                crate::pack::write_atomic(&args.dir.join(&name), &bytes)?;
                names.push(name);
            }
            names
        }
    };
    Ok(Outcome {
        json: serde_json::json!({"dir": args.dir, "files": names}),
        text: format!(
            "{}: {} files ({})\n",
            args.dir.display(),
            names.len(),
            if names.len() > 8 {
                format!("{}, ...", names[..8].join(", "))
            } else {
                names.join(", ")
            }
        ),
        warnings: Vec::new(),
    })
}
