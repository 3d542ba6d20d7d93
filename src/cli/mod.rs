//! Subcommands: each file holds one command's clap arguments and its `run`, which resolves the
//! arguments, calls the library and returns an [`Outcome`]; [`main`] (`app.rs`, the binary's
//! whole work) parses the arguments, dispatches and prints it. Only [`main`] is public.

mod app;
pub(crate) mod bench;
pub(crate) mod bittree;
pub(crate) mod build;
pub(crate) mod cache;
pub(crate) mod cluster;
pub(crate) mod dump;
pub(crate) mod envmaps;
pub(crate) mod export;
pub(crate) mod fixtures;
pub(crate) mod ingest;
pub(crate) mod lightmap;
pub(crate) mod linespace;
pub(crate) mod lod;
pub(crate) mod material;
pub(crate) mod mitsuba;
pub(crate) mod pipeline;
pub(crate) mod plan;
pub(crate) mod prt;
pub(crate) mod render;
pub(crate) mod report;
pub(crate) mod scene;
pub(crate) mod sky;
pub(crate) mod stage;
pub(crate) mod svo;
pub(crate) mod terrain;
pub(crate) mod unit;
pub(crate) mod validate;
pub(crate) mod values;
pub(crate) mod verify;

pub use app::main;
use serde_json::Value;

/// Flags shared by every subcommand.
#[derive(Debug, Clone, Default, clap::Args)]
pub(crate) struct Global {
    /// No progress bars, no summary text (errors still go to stderr).
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Print machine-readable results as JSON on stdout.
    #[arg(long, global = true)]
    pub json: bool,
    /// Treat warnings (dropped or repaired data) as errors: all of them, or those of the given
    /// ids (`--warnings-as-errors=prt.texture-missing,ingest.reader`; docs/DIAGNOSTICS.md).
    #[arg(long, global = true, value_name = "ID", num_args = 0..=1, require_equals = true,
          value_delimiter = ',', value_parser = parse_warning_id)]
    pub warnings_as_errors: Option<Vec<String>>,
    /// A further folder scenes may read files from (repeatable; by default only the scene's
    /// folder and the --models folders).
    #[arg(long = "allow-path", value_name = "DIR", global = true)]
    pub allow_paths: Vec<std::path::PathBuf>,
    /// Budget for the decoded size of one input file, e.g. 512M or 8G [default: 4G].
    #[arg(long, value_name = "BYTES", global = true, value_parser = crate::ingest::limits::parse_bytes)]
    pub max_memory: Option<u64>,
}

/// What a command produced: JSON for `--json`, text for people, warnings for stderr.
#[derive(Debug, Clone, Default)]
pub(crate) struct Outcome {
    pub json: Value,
    pub text: String,
    pub warnings: Vec<crate::diag::Warning>,
}

/// A warning id of `graph::stage::diagnostics` (`--warnings-as-errors=ID`).
fn parse_warning_id(s: &str) -> std::result::Result<String, String> {
    match crate::graph::stage::find_diagnostic(s) {
        Some(d) => Ok(d.id.to_string()),
        None => Err(format!(
            "no warning has the id {s:?} (docs/DIAGNOSTICS.md lists them)"
        )),
    }
}

impl Global {
    /// The warnings `--warnings-as-errors` makes fatal: none without the flag, all with it
    /// alone, those of the given ids otherwise.
    pub(crate) fn fatal_warnings<'a>(
        &self,
        warnings: &'a [crate::diag::Warning],
    ) -> Vec<&'a crate::diag::Warning> {
        match &self.warnings_as_errors {
            None => Vec::new(),
            Some(ids) => warnings
                .iter()
                .filter(|w| ids.is_empty() || ids.contains(&w.id))
                .collect(),
        }
    }
}

impl Outcome {
    /// The outcome of a stage that wrote a pack: its report as JSON plus `output` and `bytes`.
    pub(crate) fn written(
        report: &impl serde::Serialize,
        output: &std::path::Path,
        bytes: usize,
        text: String,
        warnings: Vec<crate::diag::Warning>,
    ) -> Outcome {
        let mut json = serde_json::to_value(report).unwrap_or_default();
        json["output"] = serde_json::json!(output);
        json["bytes"] = serde_json::json!(bytes);
        Outcome {
            json,
            text,
            warnings,
        }
    }
}

/// A benchmark's report as a command's outcome (no warnings).
impl From<crate::bench::Report> for Outcome {
    fn from(r: crate::bench::Report) -> Outcome {
        Outcome {
            json: r.json,
            text: r.text,
            warnings: Vec::new(),
        }
    }
}

impl Global {
    /// Ingest options carrying the global --allow-path and --max-memory.
    pub(crate) fn ingest_defaults(&self) -> crate::ingest::IngestOptions {
        crate::ingest::IngestOptions {
            allow_paths: self.allow_paths.clone(),
            limits: self.max_memory.map_or(
                crate::ingest::limits::Limits::DEFAULT,
                crate::ingest::limits::Limits::with_memory,
            ),
            ..Default::default()
        }
    }

    /// A progress bar on stderr, hidden with `--quiet`.
    pub(crate) fn progress(&self, len: u64, message: &str) -> indicatif::ProgressBar {
        if self.quiet {
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new(len);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{msg:>12} [{bar:30}] {pos}/{len} {elapsed_precise}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.set_message(message.to_string());
        bar
    }
}

/// Parses `WxH`.
pub(crate) fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{s:?} is not WxH"))?;
    let w = w
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: width is not a number"))?;
    let h = h
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: height is not a number"))?;
    Ok((w, h))
}

/// Parses `x,y,z`.
pub(crate) fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|c| c.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{s:?} is not x,y,z"))?;
    <[f32; 3]>::try_from(v).map_err(|_| format!("{s:?} is not x,y,z"))
}

/// The end of a stage command: adds `sections` to `w` (replacing sections of the same name) and
/// writes the pack to `output` atomically (the previous file survives a failure); returns the
/// bytes written.
pub(crate) fn write_pack(
    mut w: crate::pack::PackWriter,
    sections: impl IntoIterator<Item = crate::pack::Section>,
    output: &std::path::Path,
) -> crate::error::Result<Vec<u8>> {
    for s in sections {
        w.insert(s);
    }
    let bytes = w.to_bytes()?;
    crate::pack::write_atomic(output, &bytes)?;
    Ok(bytes)
}

/// The starting point of a stage command: an existing pack (kept whole, output defaults to the
/// pack itself) or any input file ingested first (output defaults to `<stem>.bake`).
pub(crate) fn open_or_ingest(
    input: &std::path::Path,
    output: Option<std::path::PathBuf>,
) -> crate::error::Result<(crate::pack::PackWriter, std::path::PathBuf)> {
    let is_pack = input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bake"));
    if is_pack {
        let pack = crate::pack::Pack::open(input)?;
        Ok((
            crate::pack::PackWriter::from_pack(&pack),
            output.unwrap_or_else(|| input.to_path_buf()),
        ))
    } else {
        let (w, _) =
            crate::pipeline::ingest_to_pack(input, &crate::ingest::IngestOptions::default())?;
        Ok((w, output.unwrap_or_else(|| input.with_extension("bake"))))
    }
}
