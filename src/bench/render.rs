//! `bake bench render PACK`: median seconds of device setup, upload and draw (with readback) of
//! an offscreen render, and optionally of the CPU reference of the same view.

use super::Report;
use crate::error::Result;
use crate::pack::Pack;
use crate::render::{RenderOptions, render_pack};
use std::path::Path;

/// User + system CPU seconds of this process, exited threads included (the rasterizer's worker
/// threads end with each device, so `bench::cpu_seconds`, which sums the live threads, misses
/// them): fields 14 and 15 of /proc/self/stat, in clock ticks of 1/100 s (Linux' USER_HZ).
/// `None` elsewhere.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) is parenthesised and may hold spaces: count after it.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / 100.0)
}

/// Median of `v` (not empty).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median seconds of `repeat` CPU reference renders (BVH build included).
fn bench_reference(pack: &Pack, opts: &RenderOptions, repeat: u32) -> Result<f64> {
    let mut t = Vec::new();
    for _ in 0..repeat.max(1) {
        t.push(crate::render::reference::render_reference(pack, opts)?.seconds);
    }
    Ok(median(t))
}

/// Renders the pack at `path` `repeat` times (each opens its own device) with `opts`; with
/// `reference`, also times the CPU reference.
pub fn bench_render(
    path: &Path,
    opts: &RenderOptions,
    repeat: u32,
    reference: bool,
) -> Result<Report> {
    let pack = Pack::open(path)?;
    let mut runs = Vec::new();
    let mut adapter = None;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let cpu0 = process_cpu_seconds().unwrap_or(0.0);
        let out = render_pack(&pack, opts)?;
        let cpu = process_cpu_seconds().unwrap_or(0.0) - cpu0;
        let s = out.stats.clone();
        runs.push([
            s.seconds_setup,
            s.seconds_upload,
            s.seconds_draw,
            s.seconds_load,
            s.seconds_select,
            cpu,
        ]);
        adapter = Some((out.adapter, s.triangles, s.instances, s.uploaded_bytes));
        last = Some(out.stats);
    }
    let column = |k: usize| median(runs.iter().map(|r| r[k]).collect());
    let (setup, upload, draw) = (column(0), column(1), column(2));
    let (load, select, cpu) = (column(3), column(4), column(5));
    let (adapter, triangles, instances, bytes) = adapter.expect("at least one run");
    let stats = last.expect("at least one run");
    let reference = if reference {
        Some(bench_reference(&pack, opts, repeat)?)
    } else {
        None
    };
    let mut text = format!(
        "{}: {}×{} on {adapter}: {triangles} triangles ({} shadow), {instances} instances \
         ({} culled, per level {:?}, {} impostors, {} skeletons), {bytes} bytes uploaded; median of {}: load {:.1} ms, setup {:.1} ms, \
         upload {:.1} ms, LOD selection {:.1} ms, draw+readback {:.1} ms ({:.1} Mtri/s); \
         {:.1} CPU s per render\n",
        path.display(),
        opts.width,
        opts.height,
        stats.shadow_triangles,
        stats.instances_culled,
        stats.instances_per_level,
        stats.impostor_instances,
        stats.skeleton_instances,
        runs.len(),
        load * 1e3,
        setup * 1e3,
        upload * 1e3,
        select * 1e3,
        draw * 1e3,
        (triangles + stats.shadow_triangles) as f64 / draw / 1e6,
        cpu
    );
    if let Some(r) = reference {
        text += &format!("CPU reference: median {:.1} ms\n", r * 1e3);
    }
    Ok(Report {
        json: serde_json::json!({
            "pack": path, "adapter": adapter, "width": opts.width, "height": opts.height,
            "runs": runs.len(), "triangles": triangles, "instances": instances, "uploaded_bytes": bytes,
            "seconds_setup": setup, "seconds_upload": upload, "seconds_draw": draw,
            "seconds_load": load, "seconds_select": select, "cpu_seconds": cpu,
            "lod_tau": opts.lod_tau, "stats": stats,
            "seconds_reference": reference,
        }),
        text,
    })
}
