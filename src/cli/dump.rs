//! `bake dump FILE`: what a pack holds.

use super::{Global, Outcome};
use crate::dump::{DumpOptions, dump_json, dump_text};
use crate::error::Result;
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct DumpArgs {
    /// A .bake pack.
    pub file: PathBuf,
    /// Include every section's full data.
    #[arg(long)]
    pub full: bool,
    /// Only this section.
    #[arg(long)]
    pub section: Option<String>,
}

pub fn run(args: &DumpArgs, _g: &Global) -> Result<Outcome> {
    let pack = Pack::open(&args.file)?;
    let doc = dump_json(
        &pack,
        &DumpOptions {
            full: args.full,
            section: args.section.clone(),
        },
    )?;
    let text = dump_text(&doc);
    Ok(Outcome {
        json: doc,
        text,
        warnings: Vec::new(),
    })
}
