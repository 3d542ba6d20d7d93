//! `bake dump FILE`: what a pack holds.

use super::{Global, Outcome};
use crate::dump::{DumpOptions, dump_json, dump_text};
use crate::error::{Error, Result};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct DumpArgs {
    /// A .bake pack.
    pub file: PathBuf,
    /// Include every section's full data.
    #[arg(long)]
    pub full: bool,
    /// Only this section.
    #[arg(long)]
    pub section: Option<String>,
    /// Also write every image-like section (texture mips, normal and height maps, light maps,
    /// sky cube faces and lat-long, terrain heights) into this folder: PNG, and OpenEXR beside
    /// the tone-mapped PNG of HDR ones.
    #[arg(long, value_name = "DIR")]
    pub png: Option<PathBuf>,
}

pub(crate) fn run(args: &DumpArgs, _g: &Global) -> Result<Outcome> {
    let pack = Pack::open(&args.file)?;
    let doc = dump_json(
        &pack,
        &DumpOptions {
            full: args.full,
            section: args.section.clone(),
        },
    )?;
    let mut doc = doc;
    let mut text = dump_text(&doc);
    if let Some(dir) = &args.png {
        let mut files = crate::dump::images::section_images(&pack)?;
        if let Some(only) = &args.section {
            files.retain(|f| &f.section == only);
        }
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        text.push_str(&format!(
            "\n{} image files in {}:\n",
            files.len(),
            dir.display()
        ));
        let mut list = Vec::new();
        for f in &files {
            let path = dir.join(&f.file);
            crate::pack::write_atomic(&path, &f.bytes)?;
            text.push_str(&format!(
                "  {}  {}×{}  {}\n",
                f.file, f.width, f.height, f.what
            ));
            list.push(serde_json::json!({
                "file": path, "section": f.section, "what": f.what,
                "width": f.width, "height": f.height, "bytes": f.bytes.len(),
            }));
        }
        doc["png"] = list.into();
    }
    Ok(Outcome {
        json: doc,
        text,
        warnings: Vec::new(),
    })
}
