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
    /// Voxelization and octree build time, bytes per voxel.
    Svo(crate::cli::svo::SvoBenchArgs),
    /// Line-space shadow queries against exact BVH shadow rays.
    Linespace(crate::cli::linespace::LinespaceBenchArgs),
    /// Raw obvhs rays/s against PRT rays/s on one model (default: a procedural plant).
    Rays(super::prt::RaysBenchArgs),
    /// PRT transfer error against a converged reference, against wall time, per sampler.
    PrtError(super::prt::PrtErrorBenchArgs),
    /// Environment-map clustering and interpolation weights on a generated scene.
    Cluster(super::cluster::ClusterBenchArgs),
    /// Offscreen render of a pack: device setup, upload and draw times.
    Render(super::render::RenderBenchArgs),
    /// The sky stage on a lat-long sky: decode, SH, full bake; SH accuracy against exact integrals.
    Sky(super::sky::SkyBenchArgs),
    /// Texture processing in MB/s of source texels: decode, linearize, mips, normal map.
    Textures(TexturesBenchArgs),
    /// Terrain preparation (four-tap texture, normals, min/max quadtree) of a generated grid.
    Terrain(TerrainBenchArgs),
    /// The renderer's ambient term at load time: cluster maps per instance, eq. 4.8 per vertex.
    Ambient(AmbientBenchArgs),
    /// Terrain rays/s: heightfield (min/max quadtree) against the triangle-mesh BVH.
    TerrainRays(TerrainRaysBenchArgs),
    /// Light maps of the fixture scene (or a pack): terrain and placed-object atlases.
    Lightmap(super::lightmap::LightmapBenchArgs),
    /// The stage graph on a generated scene: full bake, no-op, one model touched, sky changed.
    Incremental(IncrementalBenchArgs),
}

/// Options of [`crate::bench::ambient::bench_ambient`].
#[derive(Debug, Clone, clap::Args)]
pub struct AmbientBenchArgs {
    /// Instances on a 1024 m square (random positions and rotations).
    #[arg(long, default_value_t = 200_000)]
    pub instances: usize,
    /// Clustering error bound (relative RMS).
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
}

#[derive(Debug, Clone, clap::Args)]
pub struct TerrainRaysBenchArgs {
    /// Grid size in samples (square, 1 m apart).
    #[arg(long, default_value_t = 1024)]
    pub size: u32,
    /// Rays per set.
    #[arg(long, default_value_t = 200_000)]
    pub rays: usize,
}

#[derive(Debug, Clone, clap::Args)]
pub struct IncrementalBenchArgs {
    /// Folder of the generated scene (made if it lacks scene.eco) and of the bench's outputs.
    #[arg(long, default_value = "target/bench-incremental")]
    pub dir: std::path::PathBuf,
    #[arg(long, default_value_t = 200_000)]
    pub instances: u32,
    #[arg(long, default_value_t = 30)]
    pub models: u32,
    #[arg(long, default_value_t = 4097)]
    pub terrain: u32,
    /// Pipeline preset or file of every bake.
    #[arg(long, default_value = "preview")]
    pub pipeline: String,
}

#[derive(Debug, Clone, clap::Args)]
pub struct TexturesBenchArgs {
    /// Image files to process (default: a generated leaf texture encoded as PNG).
    pub files: Vec<std::path::PathBuf>,
    /// Size of the generated texture (square).
    #[arg(long, default_value_t = 1024)]
    pub size: u32,
    /// Repetitions per file.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
}

#[derive(Debug, Clone, clap::Args)]
pub struct TerrainBenchArgs {
    /// Grid size in samples (square).
    #[arg(long, default_value_t = 4096)]
    pub size: u32,
    /// Repetitions.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
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
        BenchWhat::PrtError(a) => super::prt::bench_error(a, g),
        BenchWhat::Cluster(a) => super::cluster::bench(a, g),
        BenchWhat::Render(a) => super::render::bench(a, g),
        BenchWhat::Svo(a) => crate::cli::svo::bench(a, g),
        BenchWhat::Linespace(a) => crate::cli::linespace::bench(a, g),
        BenchWhat::Sky(a) => super::sky::bench(a, g),
        BenchWhat::Textures(a) => report(crate::bench::textures::bench_textures(
            &a.files, a.size, a.repeat,
        )?),
        BenchWhat::Terrain(a) => report(crate::bench::terrain::bench_terrain(a.size, a.repeat)?),
        BenchWhat::Ambient(a) => {
            report(crate::bench::ambient::bench_ambient(a.instances, a.error)?)
        }
        BenchWhat::TerrainRays(a) => report(crate::bench::terrain_rays::bench_terrain_rays(
            a.size, a.rays,
        )?),
        BenchWhat::Lightmap(a) => super::lightmap::bench(a, g),
        BenchWhat::Incremental(a) => incremental(a, g),
    }
}

/// A benchmark's report as the command's outcome.
fn report(r: crate::bench::Report) -> Result<Outcome> {
    Ok(Outcome {
        json: r.json,
        text: r.text,
        warnings: Vec::new(),
    })
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

/// One child `bake` run's report (each scenario is its own process, so peak memory is its own).
fn bake_child(args: &[std::ffi::OsString]) -> Result<serde_json::Value> {
    let exe = std::env::current_exe().map_err(|e| crate::error::Error::runtime(e.to_string()))?;
    let out = std::process::Command::new(&exe)
        .args(args)
        .args(["--json", "--quiet"])
        .output()
        .map_err(|e| crate::error::Error::io(&exe, e))?;
    if !out.status.success() {
        return Err(crate::error::Error::runtime(format!(
            "bench bake failed: {}",
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| crate::error::Error::runtime(format!("bench bake report: {e}")))
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

fn incremental(a: &IncrementalBenchArgs, _g: &Global) -> Result<Outcome> {
    use crate::error::Error;
    use std::ffi::OsString;
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
    let full = bake_child(&base(true))?;
    let noop = bake_child(&base(true))?;
    // One model touched: tree000 becomes another tree (new geometry, same name).
    let touched_name = crate::fixtures::large::model_name(0);
    let touched_path = scene_dir.join(format!("{touched_name}.txf"));
    crate::pack::write_atomic(
        &touched_path,
        &crate::fixtures::plant::write_txf(&crate::fixtures::large::tree(a.models + 7)),
    )?;
    let touched = bake_child(&base(true))?;
    // The sky changed: the built-in clear sky instead of the HDR file.
    let sky = bake_child(&base(false))?;
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
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
}
