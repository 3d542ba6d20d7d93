//! Benchmarks (`bake bench WHAT`; results recorded in docs/PERFORMANCE.md): each module measures
//! one stage or kernel and returns its report; `cli::bench` parses the arguments and prints.
//! One timing helper for all of them: [`time_best`] (fastest of three runs, wall and CPU time)
//! and [`cpu_seconds`] (this process' CPU time, from Linux' schedstat).

pub mod ambient;
pub mod cluster;
pub mod cluster_cause;
pub mod envmap_error;
pub mod incremental;
pub mod ingest;
pub mod lightmap;
pub mod linespace;
pub mod lod;
pub mod prt_error;
pub mod rays;
pub mod render;
pub mod sky;
pub mod svo;
pub mod terrain;
pub mod terrain_rays;
pub mod textures;

use crate::error::Result;
use std::time::Instant;

/// What a benchmark reports: its JSON document and the text `bake bench` prints.
#[derive(Debug, Clone)]
pub struct Report {
    pub json: serde_json::Value,
    pub text: String,
}

/// CPU time of this process (all threads), from Linux' per-thread schedstat (nanoseconds);
/// `None` elsewhere. On a shared machine, rays per CPU-second compare two runs far more stably
/// than wall time.
pub fn cpu_seconds() -> Option<f64> {
    let mut total = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let stat = std::fs::read_to_string(task.ok()?.path().join("schedstat")).ok()?;
        total += stat.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total as f64 * 1e-9)
}

/// A measurement: the fastest of three runs, in wall and CPU seconds.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    pub wall: f64,
    pub cpu: Option<f64>,
}

pub fn time_best(mut f: impl FnMut()) -> Timing {
    let mut best = Timing {
        wall: f64::INFINITY,
        cpu: None,
    };
    for _ in 0..3 {
        let (start, cpu0) = (Instant::now(), cpu_seconds());
        f();
        let wall = start.elapsed().as_secs_f64();
        // schedstat advances in scheduler ticks: a run too short to register has no CPU time.
        let cpu = cpu0
            .zip(cpu_seconds())
            .map(|(a, b)| b - a)
            .filter(|&c| c > 1e-3);
        best.wall = best.wall.min(wall);
        best.cpu = match (best.cpu, cpu) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
    }
    best
}

/// One run of `f`, in wall and CPU seconds, and its result (for runs too long to repeat).
pub fn time_once<T>(f: impl FnOnce() -> T) -> (Timing, T) {
    let (start, cpu0) = (Instant::now(), cpu_seconds());
    let out = f();
    let wall = start.elapsed().as_secs_f64();
    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
    (Timing { wall, cpu }, out)
}

/// Median wall time of `repeat` runs of `f`, in seconds.
pub fn time_median<T>(repeat: u32, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        last = Some(f()?);
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    Ok((times[times.len() / 2], last.expect("at least one run")))
}

/// Mean wall time of `repeat` runs of `f`, in seconds, and the last run's result.
pub fn time_mean<T>(repeat: u32, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let start = Instant::now();
    let mut last = None;
    for _ in 0..repeat.max(1) {
        last = Some(f()?);
    }
    let secs = start.elapsed().as_secs_f64() / repeat.max(1) as f64;
    Ok((secs, last.expect("at least one run")))
}

/// Best (smallest) wall time of `repeat` runs of `f`, in seconds, and the last run's result.
pub fn time_min<T>(repeat: u32, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        last = Some(f()?);
        best = best.min(t.elapsed().as_secs_f64());
    }
    Ok((best, last.expect("at least one run")))
}
