//! `bake bench ingest FILES`: reader throughput in MB/s of file bytes, per input file (mean of
//! the repetitions; docs/PERFORMANCE.md compares it with assimp, scripts/bench-ingest-vs-assimp.sh).

use super::{Report, time_mean};
use crate::error::{Error, Result};
use std::path::PathBuf;

/// Reads each file `repeat` times with [`crate::ingest::load_mesh`] and reports its mean time.
pub fn bench_ingest(files: &[PathBuf], repeat: u32) -> Result<Report> {
    let mut rows = Vec::new();
    let mut text = String::new();
    for f in files {
        let bytes = std::fs::metadata(f).map_err(|e| Error::io(f, e))?.len();
        let (secs, tris) = time_mean(repeat, || Ok(crate::ingest::load_mesh(f)?.indices.len()))?;
        let mbps = bytes as f64 / 1e6 / secs;
        text.push_str(&format!(
            "{}: {bytes} bytes, {tris} triangles, {:.3} ms, {mbps:.1} MB/s\n",
            f.display(),
            secs * 1e3
        ));
        rows.push(serde_json::json!({"file": f, "bytes": bytes, "triangles": tris, "seconds": secs, "mb_per_second": mbps}));
    }
    Ok(Report {
        json: serde_json::json!({"ingest": rows}),
        text,
    })
}
