//! `bake fixtures DIR`: writes the project's generated fixture scene.

use super::{Global, Outcome};
use crate::error::Result;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct FixturesArgs {
    /// Output folder (created if missing).
    #[arg(default_value = "fixtures/scene")]
    pub dir: PathBuf,
}

pub fn run(args: &FixturesArgs, _g: &Global) -> Result<Outcome> {
    let names = crate::fixtures::write_all(&args.dir)?;
    Ok(Outcome {
        json: serde_json::json!({"dir": args.dir, "files": names}),
        text: format!(
            "{}: {} files ({})\n",
            args.dir.display(),
            names.len(),
            names.join(", ")
        ),
        warnings: Vec::new(),
    })
}
