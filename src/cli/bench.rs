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
    Ambient(crate::render::ambient_bench::AmbientBenchArgs),
    /// Terrain rays/s: heightfield (min/max quadtree) against the triangle-mesh BVH.
    TerrainRays(crate::rt::bench::TerrainRaysBenchArgs),
    /// Light maps of the fixture scene (or a pack): terrain and placed-object atlases.
    Lightmap(super::lightmap::LightmapBenchArgs),
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
        BenchWhat::Cluster(a) => super::cluster::bench(a, g),
        BenchWhat::Render(a) => super::render::bench(a, g),
        BenchWhat::Svo(a) => crate::cli::svo::bench(a, g),
        BenchWhat::Linespace(a) => crate::cli::linespace::bench(a, g),
        BenchWhat::Sky(a) => super::sky::bench(a, g),
        BenchWhat::Textures(a) => crate::texture::bench::bench_textures(a),
        BenchWhat::Terrain(a) => crate::terrain::bench::bench_terrain(a),
        BenchWhat::Ambient(a) => crate::render::ambient_bench::bench_ambient(a),
        BenchWhat::TerrainRays(a) => crate::rt::bench::bench_terrain_rays(a),
        BenchWhat::Lightmap(a) => super::lightmap::bench(a, g),
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
