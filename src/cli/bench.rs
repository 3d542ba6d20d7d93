//! `bake bench WHAT`: benchmarks that report ratios against a baseline run in the same process.
//! Results are recorded in docs/PERFORMANCE.md.

use super::{Global, Outcome};
use crate::error::Result;

#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub enum BenchWhat {
    /// Ingest throughput in MB/s per input file.
    Ingest(IngestBenchArgs),
    /// Raw obvhs rays/s against PRT rays/s on one model (default: a procedural plant).
    Rays(super::prt::RaysBenchArgs),
}

#[derive(Debug, Clone, clap::Args)]
pub struct IngestBenchArgs {
    /// Model files to read (TXF, 3DS, OBJ, glTF).
    #[arg(required = true)]
    pub files: Vec<std::path::PathBuf>,
    /// Repetitions per file.
    #[arg(long, default_value_t = 5)]
    pub repeat: u32,
}

pub fn run(args: &BenchArgs, g: &Global) -> Result<Outcome> {
    match &args.what {
        BenchWhat::Ingest(a) => ingest(a, g),
        BenchWhat::Rays(a) => super::prt::bench(a, g),
    }
}

fn ingest(a: &IngestBenchArgs, _g: &Global) -> Result<Outcome> {
    let mut rows = Vec::new();
    let mut text = String::new();
    for f in &a.files {
        let bytes = std::fs::metadata(f)
            .map_err(|e| crate::error::Error::io(f, e))?
            .len();
        let start = std::time::Instant::now();
        let mut tris = 0;
        for _ in 0..a.repeat.max(1) {
            tris = crate::ingest::load_mesh(f)?.indices.len();
        }
        let secs = start.elapsed().as_secs_f64() / a.repeat.max(1) as f64;
        let mbps = bytes as f64 / 1e6 / secs;
        text.push_str(&format!(
            "{}: {bytes} bytes, {tris} triangles, {:.3} ms, {mbps:.1} MB/s\n",
            f.display(),
            secs * 1e3
        ));
        rows.push(serde_json::json!({"file": f, "bytes": bytes, "triangles": tris, "seconds": secs, "mb_per_second": mbps}));
    }
    Ok(Outcome {
        json: serde_json::json!({"ingest": rows}),
        text,
        warnings: Vec::new(),
    })
}
