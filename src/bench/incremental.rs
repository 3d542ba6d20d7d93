//! `bake bench incremental`: the stage graph on a generated scene (`fixtures::large`): a full
//! bake, a no-op, one model touched and the sky changed, each its own `bake build` process (so
//! each peak memory is its own), with per-stage wall and CPU seconds of the full bake.

use super::Report;
use crate::error::{Error, Result};
use std::ffi::OsString;
use std::path::{Path, PathBuf};

/// The generated scene and the pipeline of [`bench_incremental`].
#[derive(Debug, Clone)]
pub struct IncrementalBench {
    /// Folder of the generated scene (made if it lacks scene.eco) and of the bench's outputs.
    pub dir: PathBuf,
    pub instances: u32,
    pub models: u32,
    pub terrain: u32,
    /// Pipeline preset or file of every bake.
    pub pipeline: String,
}

/// One child `bake` run's report (each scenario is its own process, so peak memory is its own).
fn bake_child(bake: &Path, args: &[OsString]) -> Result<serde_json::Value> {
    let out = std::process::Command::new(bake)
        .args(args)
        .args(["--json", "--quiet"])
        .output()
        .map_err(|e| Error::io(bake, e))?;
    if !out.status.success() {
        return Err(Error::runtime(format!(
            "bench bake failed: {}",
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| Error::runtime(format!("bench bake report: {e}")))
}

/// Seconds of the units whose stage and unit match `pick` in a report.
fn unit_seconds(r: &serde_json::Value, pick: &dyn Fn(&str, &str) -> bool) -> f64 {
    r["stages"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter(|s| {
                    pick(
                        s["stage"].as_str().unwrap_or(""),
                        s["unit"].as_str().unwrap_or(""),
                    )
                })
                .map(|s| s["wall_seconds"].as_f64().unwrap_or(0.0))
                .sum()
        })
        .unwrap_or(0.0)
}

/// Runs the four bakes with the `bake` binary at `bake`.
pub fn bench_incremental(bake: &Path, a: &IncrementalBench) -> Result<Report> {
    let dir = &a.dir;
    let scene = dir.join("scene").join("scene.eco");
    let p = crate::fixtures::large::LargeScene {
        instances: a.instances,
        models: a.models,
        terrain: a.terrain,
    };
    let files = crate::fixtures::large::large_files(&p);
    let scene_dir = dir.join("scene");
    std::fs::create_dir_all(&scene_dir).map_err(|e| Error::io(&scene_dir, e))?;
    for (name, bytes) in &files {
        let path = scene_dir.join(name);
        if std::fs::read(&path).ok().as_deref() != Some(bytes.as_slice()) {
            crate::pack::write_atomic(&path, bytes)?;
        }
    }
    let cache = dir.join("cache");
    let _ = std::fs::remove_dir_all(&cache);
    let out = dir.join("scene.bake");
    let _ = std::fs::remove_file(&out);
    let base = |sky: bool| -> Vec<OsString> {
        let mut v: Vec<OsString> = vec![
            "build".into(),
            scene.clone().into(),
            "-o".into(),
            out.clone().into(),
            "--pipeline".into(),
            a.pipeline.clone().into(),
            "--cache".into(),
            cache.clone().into(),
        ];
        if sky {
            v.push("--sky".into());
            v.push(scene_dir.join("sky.hdr").into());
        }
        v
    };
    let full = bake_child(bake, &base(true))?;
    let noop = bake_child(bake, &base(true))?;
    // One model touched: tree000 becomes another tree (new geometry, same name).
    let touched_name = crate::fixtures::large::model_name(0);
    let touched_path = scene_dir.join(format!("{touched_name}.txf"));
    crate::pack::write_atomic(
        &touched_path,
        &crate::fixtures::plant::write_txf(&crate::fixtures::large::tree(a.models + 7)),
    )?;
    let touched = bake_child(bake, &base(true))?;
    // The sky changed: the built-in clear sky instead of the HDR file.
    let sky = bake_child(bake, &base(false))?;
    // Put the scene back as generated.
    let original = files
        .iter()
        .find(|(n, _)| *n == format!("{touched_name}.txf"))
        .map(|(_, b)| b.clone())
        .unwrap_or_default();
    crate::pack::write_atomic(&touched_path, &original)?;
    let model_file = format!("{touched_name}.txf");
    let own_units = unit_seconds(&full, &|stage, unit| {
        unit == model_file || matches!(stage, "lightmap" | "atlas" | "envmaps" | "cluster")
    });
    let row = |name: &str, r: &serde_json::Value| {
        serde_json::json!({
            "run": name,
            "wall_seconds": r["wall_seconds"],
            "cpu_seconds": r["cpu_seconds"],
            "peak_rss_bytes": r["peak_rss_bytes"],
            "cache_hits": r["cache_hits"],
            "cache_misses": r["cache_misses"],
            "up_to_date": r["up_to_date"],
        })
    };
    let wall = |r: &serde_json::Value| r["wall_seconds"].as_f64().unwrap_or(0.0);
    let full_wall = wall(&full).max(1e-9);
    let mut slowest: Vec<(String, f64, f64)> = full["stages"]
        .as_array()
        .map(|v| {
            v.iter()
                .map(|s| {
                    (
                        format!(
                            "{} {}",
                            s["stage"].as_str().unwrap_or(""),
                            s["unit"].as_str().unwrap_or("")
                        ),
                        s["wall_seconds"].as_f64().unwrap_or(0.0),
                        s["cpu_seconds"].as_f64().unwrap_or(0.0),
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    slowest.sort_by(|x, y| y.1.total_cmp(&x.1));
    slowest.truncate(8);
    let mut by_stage: std::collections::BTreeMap<String, (f64, f64, u32)> = Default::default();
    for s in full["stages"].as_array().into_iter().flatten() {
        let e = by_stage
            .entry(s["stage"].as_str().unwrap_or("").to_string())
            .or_default();
        e.0 += s["wall_seconds"].as_f64().unwrap_or(0.0);
        e.1 += s["cpu_seconds"].as_f64().unwrap_or(0.0);
        e.2 += 1;
    }
    let json = serde_json::json!({
        "scene": {"instances": a.instances, "models": a.models, "terrain": a.terrain, "pipeline": a.pipeline},
        "bytes": full["bytes"],
        "runs": [row("full", &full), row("noop", &noop), row("one model touched", &touched), row("sky changed", &sky)],
        "noop_over_full": wall(&noop) / full_wall,
        "touched_over_full": wall(&touched) / full_wall,
        "touched_own_units_seconds": own_units,
        "sky_over_full": wall(&sky) / full_wall,
        "stages": by_stage.iter().map(|(k, v)| serde_json::json!({"stage": k, "wall_seconds": v.0, "cpu_seconds": v.1, "units": v.2})).collect::<Vec<_>>(),
        "slowest_units": slowest.iter().map(|(n, w, c)| serde_json::json!({"unit": n, "wall_seconds": w, "cpu_seconds": c})).collect::<Vec<_>>(),
    });
    let mut text = format!(
        "generated scene: {} instances, {} models, {}² terrain, pipeline {}; pack {} bytes\n",
        a.instances, a.models, a.terrain, a.pipeline, full["bytes"]
    );
    for (name, r) in [
        ("full", &full),
        ("no-op", &noop),
        ("one model touched", &touched),
        ("sky changed", &sky),
    ] {
        text.push_str(&format!(
            "  {name:18} {:>8.2} s wall {:>8.2} CPU s {:>7.0} MB peak  {} hits {} misses\n",
            wall(r),
            r["cpu_seconds"].as_f64().unwrap_or(0.0),
            r["peak_rss_bytes"].as_f64().unwrap_or(0.0) / 1e6,
            r["cache_hits"],
            r["cache_misses"]
        ));
    }
    text.push_str(&format!(
        "  no-op / full {:.4}; touched / full {:.3} (its own and the scene units took {:.2} s in the full bake)\n  by stage (full bake):\n",
        wall(&noop) / full_wall,
        wall(&touched) / full_wall,
        own_units
    ));
    for (k, v) in &by_stage {
        text.push_str(&format!(
            "    {k:10} {:>8.2} s wall {:>8.2} CPU s  {} units\n",
            v.0, v.1, v.2
        ));
    }
    Ok(Report { json, text })
}
