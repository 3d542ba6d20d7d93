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
    /// Environment-map clustering and interpolation weights on a generated scene.
    Cluster(ClusterBenchArgs),
}

#[derive(Debug, Clone, clap::Args)]
pub struct ClusterBenchArgs {
    /// Number of instances, scattered over a 1024 m × 1024 m terrain.
    #[arg(long, default_value_t = 200_000)]
    pub instances: usize,
    /// Per-instance error bound (relative RMS).
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
    /// Fraction of the violating clusters split per round.
    #[arg(long, default_value_t = 0.5)]
    pub split_fraction: f32,
    /// Write positions and values as little-endian f32 files into this folder (for a peer tool).
    #[arg(long)]
    pub export: Option<std::path::PathBuf>,
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
        BenchWhat::Cluster(a) => cluster(a, g),
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

fn cluster(a: &ClusterBenchArgs, _g: &Global) -> Result<Outcome> {
    use crate::envmap::section::DIM;
    let mut rng = crate::fixtures::Rng::new(2005);
    let positions: Vec<[f32; 3]> = (0..a.instances)
        .map(|_| {
            let (x, y) = (rng.f32() * 1024.0, rng.f32() * 1024.0);
            [x, y, 20.0 * (x * 0.01).sin() * (y * 0.013).cos()]
        })
        .collect();
    let values = crate::envmap::synthetic_envmaps(&positions);
    let opts = crate::envmap::cluster::ClusterOptions {
        error: a.error,
        split_fraction: a.split_fraction,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let (meta, c, _) = crate::envmap::cluster_and_weigh(&positions, &values, DIM, &opts, false);
    let t_cluster = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let (nb, w) = crate::envmap::instance_weights(&positions, &values, DIM, &c);
    let t_weights = t1.elapsed().as_secs_f64();
    let raw = (a.instances * DIM * 4) as u64;
    let packed = meta.clusters * (12 + 4 + DIM as u64 * 4);
    if let Some(dir) = &a.export {
        let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let flat: Vec<f32> = positions.iter().flatten().copied().collect();
        let samples: Vec<f32> = c.samples.iter().map(|&s| s as f32).collect();
        std::fs::create_dir_all(dir).map_err(|e| crate::error::Error::io(dir, e))?;
        for (name, data) in [
            ("positions.f32", f32s(&flat)),
            ("values.f32", f32s(&values)),
            ("samples.f32", f32s(&samples)),
        ] {
            crate::pack::write_atomic(&dir.join(name), &data)?;
        }
    }
    let doc = serde_json::json!({
        "instances": a.instances, "clusters": meta.clusters, "k": meta.k, "radius": meta.radius,
        "raw_bytes": raw, "packed_bytes": packed, "compression": raw as f64 / packed as f64,
        "rms_error_relative": meta.rms_error_relative, "max_error_relative": meta.max_error_relative,
        "rounds": c.rounds, "seconds": t_cluster, "weights_seconds": t_weights,
        "weights_bytes": (nb.len() * 4 + w.len() * 4) as u64, "ill_conditioned": meta.ill_conditioned,
    });
    Ok(Outcome {
        text: format!("{doc:#}\n"),
        json: doc,
        warnings: Vec::new(),
    })
}
