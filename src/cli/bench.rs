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
    /// Environment-map clustering and interpolation weights on a generated scene.
    Cluster(ClusterBenchArgs),
    /// Offscreen render of a pack: device setup, upload and draw times.
    Render(super::render::RenderBenchArgs),
    /// The sky stage on a lat-long sky: decode, SH, full bake; SH accuracy against exact integrals.
    Sky(super::sky::SkyBenchArgs),
    /// Texture processing in MB/s of source texels: decode, linearize, mips, normal map.
    Textures(TexturesBenchArgs),
    /// Terrain preparation (four-tap texture, normals, min/max quadtree) of a generated grid.
    Terrain(TerrainBenchArgs),
    /// The renderer's ambient term at load time: cluster maps per instance, eq. 4.8 per vertex.
    Ambient(crate::render::ambient_bench::AmbientBenchArgs),
    /// Terrain rays/s: heightfield (min/max quadtree) against the triangle-mesh BVH.
    TerrainRays(crate::rt::bench::TerrainRaysBenchArgs),
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
    /// Use the synthetic field instead of traced environment maps.
    #[arg(long)]
    pub synthetic: bool,
    /// Rays per instance for the traced environment maps.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// Terrain samples per side (1 m apart).
    #[arg(long, default_value_t = 1024)]
    pub terrain: u32,
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
        BenchWhat::Render(a) => super::render::bench(a, g),
        BenchWhat::Svo(a) => crate::cli::svo::bench(a, g),
        BenchWhat::Linespace(a) => crate::cli::linespace::bench(a, g),
        BenchWhat::Sky(a) => super::sky::bench(a, g),
        BenchWhat::Textures(a) => crate::texture::bench::bench_textures(a),
        BenchWhat::Terrain(a) => crate::terrain::bench::bench_terrain(a),
        BenchWhat::Ambient(a) => crate::render::ambient_bench::bench_ambient(a),
        BenchWhat::TerrainRays(a) => crate::rt::bench::bench_terrain_rays(a),
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
    let t_envmaps = std::time::Instant::now();
    let (positions, values) = if a.synthetic {
        synthetic_scene(a)
    } else {
        traced_scene(a)?
    };
    let envmap_seconds = t_envmaps.elapsed().as_secs_f64();
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
        "rounds": c.rounds, "seconds": t_cluster, "envmap_seconds": envmap_seconds, "synthetic": a.synthetic, "weights_seconds": t_weights,
        "weights_bytes": (nb.len() * 4 + w.len() * 4) as u64, "ill_conditioned": meta.ill_conditioned,
    });
    Ok(Outcome {
        text: format!("{doc:#}\n"),
        json: doc,
        warnings: Vec::new(),
    })
}

/// Instance positions on a hilly terrain, with synthetic maps.
fn synthetic_scene(a: &ClusterBenchArgs) -> (Vec<[f32; 3]>, Vec<f32>) {
    let mut rng = crate::fixtures::Rng::new(2005);
    let positions: Vec<[f32; 3]> = (0..a.instances)
        .map(|_| {
            let (x, y) = (rng.f32() * 1024.0, rng.f32() * 1024.0);
            [x, y, 20.0 * (x * 0.01).sin() * (y * 0.013).cos()]
        })
        .collect();
    let values = crate::envmap::synthetic_envmaps(&positions);
    (positions, values)
}

/// A generated scene (procedural alpha-tested plant on a hilly terrain, built-in sky) and its
/// traced environment maps.
fn traced_scene(a: &ClusterBenchArgs) -> Result<(Vec<[f32; 3]>, Vec<f32>)> {
    use crate::rt::{AlphaMask, BuildPreset, InstanceTransform, ModelBvh, SceneBvh};
    use std::sync::Arc;
    let n = a.terrain.max(2);
    let extent = (n - 1) as f32;
    let heights = (0..n * n)
        .map(|k| {
            let (x, y) = ((k % n) as f32, (k / n) as f32);
            20.0 * (x * 0.01).sin() * (y * 0.013).cos() + 3.0 * (x * 0.07 + y * 0.05).sin()
        })
        .collect();
    let terrain = crate::model::Terrain {
        width: n,
        height: n,
        heights,
        origin: [0.0, 0.0],
        extent: [extent; 2],
        color: None,
    };
    let (plant, leaf) = crate::light::plant::procedural_plant(300, 7);
    let masks = vec![Some(AlphaMask::from_rgba8(&leaf)); plant.materials.len()];
    let plant_bvh = Arc::new(ModelBvh::build(&plant, &masks, BuildPreset::Medium)?);
    let ground = Arc::new(ModelBvh::build(
        &crate::tracescene::terrain_mesh(&terrain),
        &[],
        BuildPreset::Fast,
    )?);
    let mut rng = crate::fixtures::Rng::new(2005);
    let mut transforms = Vec::with_capacity(a.instances + 1);
    for _ in 0..a.instances {
        let (x, y) = (rng.f32() * extent, rng.f32() * extent);
        transforms.push(InstanceTransform {
            model: 0,
            translation: [x, y, terrain.height_at(x, y)],
            scale: 0.8 + 0.6 * rng.f32(),
            rotation_deg: rng.f32() * 360.0,
        });
    }
    transforms.push(InstanceTransform {
        model: 1,
        translation: [0.0; 3],
        scale: 1.0,
        rotation_deg: 0.0,
    });
    let positions: Vec<[f32; 3]> = transforms[..a.instances]
        .iter()
        .map(|t| t.translation)
        .collect();
    let height = plant.bounds().map_or(1.0, |(lo, hi)| hi[2] - lo[2]);
    let probe_height = transforms[..a.instances]
        .iter()
        .map(|t| 0.5 * height * t.scale)
        .collect();
    let bvh = SceneBvh::build(vec![plant_bvh, ground], transforms)?;
    let sky = crate::sky::builtin::BuiltinSky::default();
    let cube = crate::sky::builtin::builtin_sky(&sky);
    let (cube, sun) = crate::sky::sun::extract_sun(&cube, &Default::default());
    let mut albedo = vec![[0.25, 0.4, 0.15]; a.instances];
    albedo.push([0.2, 0.25, 0.15]);
    let scene = crate::envmap::bake::EnvmapScene {
        bvh: &bvh,
        count: a.instances,
        probe_height,
        albedo,
        sky: crate::sh::project_cube(&cube),
        sun: Some(crate::envmap::bake::SunLight {
            direction: sun.direction,
            irradiance: sun.irradiance,
        }),
    };
    let maps = crate::envmap::bake::bake_envmaps(
        &scene,
        &crate::envmap::bake::EnvmapOptions {
            samples: a.samples,
            seed: 1,
        },
    );
    let sky_maps: Vec<_> = maps.iter().map(|m| m.0).collect();
    let sun_maps: Vec<_> = maps.iter().map(|m| m.1).collect();
    Ok((
        positions,
        crate::envmap::section::flatten(&sky_maps, &sun_maps),
    ))
}
