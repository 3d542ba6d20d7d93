//! `bake verify PACK`: checks a pack against docs/FORMAT.md (container, every checksum, each
//! section kind's invariants; see `crate::verify`).
//!
//! Exit 0 when the pack is valid; exit 4 with the first violation (section, array, byte offset)
//! on stderr otherwise. With `--json` the report, every violation included, goes to stdout in
//! both cases, so a script gets all of them and the exit code.

use super::{Global, Outcome};
use crate::error::Result;
use crate::verify::{VerifyReport, first_error, verify_file};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct VerifyArgs {
    /// A .bake pack.
    pub file: PathBuf,
}

pub(crate) fn run(args: &VerifyArgs, g: &Global) -> Result<Outcome> {
    let report = verify_file(&args.file)?;
    let json = report_json(&args.file, &report);
    if let Some(err) = first_error(&args.file, &report) {
        if g.json {
            // The one place a command prints: a failing verify still owes --json its report.
            println!(
                "{}",
                serde_json::to_string_pretty(&json).unwrap_or_default()
            );
        }
        return Err(err);
    }
    let text = format!(
        "{}: valid pack, format version {}, {} sections, {} bytes\n",
        args.file.display(),
        report.version.unwrap_or_default(),
        report.sections,
        report.bytes
    );
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
}

fn report_json(file: &std::path::Path, r: &VerifyReport) -> serde_json::Value {
    let mut json = serde_json::to_value(r).unwrap_or_default();
    json["file"] = serde_json::json!(file);
    json["ok"] = serde_json::json!(r.ok());
    json["reads_version"] = serde_json::json!(crate::pack::VERSION);
    json
}
