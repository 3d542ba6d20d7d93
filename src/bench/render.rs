//! `bake bench render PACK`: median seconds of device setup, upload and draw (with readback) of
//! an offscreen render, and optionally of the CPU reference of the same view.

use super::Report;
use crate::error::Result;
use crate::pack::Pack;
use crate::render::{RenderOptions, render_pack};
use std::path::Path;

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
    for _ in 0..repeat.max(1) {
        let out = render_pack(&pack, opts)?;
        let s = out.stats;
        runs.push([s.seconds_setup, s.seconds_upload, s.seconds_draw]);
        adapter = Some((out.adapter, s.triangles, s.instances, s.uploaded_bytes));
    }
    let column = |k: usize| median(runs.iter().map(|r| r[k]).collect());
    let (setup, upload, draw) = (column(0), column(1), column(2));
    let (adapter, triangles, instances, bytes) = adapter.expect("at least one run");
    let reference = if reference {
        Some(bench_reference(&pack, opts, repeat)?)
    } else {
        None
    };
    let mut text = format!(
        "{}: {}×{} on {adapter}: {triangles} triangles, {instances} instances, {bytes} bytes uploaded; \
         median of {}: setup {:.1} ms, upload {:.1} ms, draw+readback {:.1} ms ({:.1} Mtri/s)\n",
        path.display(),
        opts.width,
        opts.height,
        runs.len(),
        setup * 1e3,
        upload * 1e3,
        draw * 1e3,
        triangles as f64 / draw / 1e6
    );
    if let Some(r) = reference {
        text += &format!("CPU reference: median {:.1} ms\n", r * 1e3);
    }
    Ok(Report {
        json: serde_json::json!({
            "pack": path, "adapter": adapter, "width": opts.width, "height": opts.height,
            "runs": runs.len(), "triangles": triangles, "instances": instances, "uploaded_bytes": bytes,
            "seconds_setup": setup, "seconds_upload": upload, "seconds_draw": draw,
            "seconds_reference": reference,
        }),
        text,
    })
}
