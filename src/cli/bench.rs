//! `bake bench WHAT`: benchmarks that report ratios against a baseline run in the same process.
//! Results are recorded in docs/PERFORMANCE.md.

use super::{Global, Outcome};
use crate::error::{Error, Result};

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub(crate) enum BenchWhat {
    /// Ingest throughput in MB/s per input file.
    Ingest(IngestBenchArgs),
    /// Voxelization and octree build time, bytes per voxel.
    Svo(crate::cli::svo::SvoBenchArgs),
    /// The `lod` stage over every mesh of a pack: simplification and impostors timed apart.
    Lod(crate::cli::lod::LodBenchArgs),
    /// Line-space shadow queries against exact BVH shadow rays.
    Linespace(crate::cli::linespace::LinespaceBenchArgs),
    /// Raw obvhs rays/s against PRT rays/s on one model (default: a procedural plant).
    Rays(super::prt::RaysBenchArgs),
    /// PRT transfer error against a converged reference, against wall time, per sampler.
    PrtError(super::prt::PrtErrorBenchArgs),
    /// Environment-map clustering and interpolation weights on a generated scene.
    Cluster(super::cluster::ClusterBenchArgs),
    /// The env-map tracer's error against a high-ray reference on a pack, per estimator variant.
    EnvmapError(EnvmapErrorBenchArgs),
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
pub(crate) struct AmbientBenchArgs {
    /// Instances on a 1024 m square (random positions and rotations).
    #[arg(long, default_value_t = 200_000)]
    pub instances: usize,
    /// Clustering error bound (relative RMS).
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct EnvmapErrorBenchArgs {
    /// A pack with the scene (instances, meshes, terrain, sky and sun).
    #[arg(long)]
    pub pack: std::path::PathBuf,
    /// Random instances in the subset (`bench cluster`'s subset for the same count).
    #[arg(long, default_value_t = 1000)]
    pub instances: usize,
    /// Rays of the reference maps (two independent halves).
    #[arg(long, default_value_t = 4096)]
    pub reference_samples: u32,
    /// Estimator variants: comma-separated key=value overrides of the env-map options
    /// (e.g. `samples=512,noise_estimate=false`); the empty string is the default.
    #[arg(long = "variant", default_value = "")]
    pub variants: Vec<String>,
    /// Independent runs (other seeds) of each variant.
    #[arg(long, default_value_t = 1)]
    pub seeds: u32,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct TerrainRaysBenchArgs {
    /// Grid size in samples (square, 1 m apart).
    #[arg(long, default_value_t = 1024)]
    pub size: u32,
    /// Rays per set.
    #[arg(long, default_value_t = 200_000)]
    pub rays: usize,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct IncrementalBenchArgs {
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
pub(crate) struct TexturesBenchArgs {
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
pub(crate) struct TerrainBenchArgs {
    /// Grid size in samples (square).
    #[arg(long, default_value_t = 4096)]
    pub size: u32,
    /// Repetitions.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct IngestBenchArgs {
    /// Model files to read (TXF, 3DS, OBJ, glTF).
    #[arg(required = true)]
    pub files: Vec<std::path::PathBuf>,
    /// Repetitions per file.
    #[arg(long, default_value_t = 5)]
    pub repeat: u32,
}

pub(crate) fn run(args: &BenchArgs, g: &Global) -> Result<Outcome> {
    match &args.what {
        BenchWhat::Ingest(a) => Ok(crate::bench::ingest::bench_ingest(&a.files, a.repeat)?.into()),
        BenchWhat::Rays(a) => super::prt::bench(a, g),
        BenchWhat::PrtError(a) => super::prt::bench_error(a, g),
        BenchWhat::Cluster(a) => super::cluster::bench(a, g),
        BenchWhat::Render(a) => super::render::bench(a, g),
        BenchWhat::Svo(a) => crate::cli::svo::bench(a, g),
        BenchWhat::Lod(a) => crate::cli::lod::bench(a, g),
        BenchWhat::Linespace(a) => crate::cli::linespace::bench(a, g),
        BenchWhat::Sky(a) => super::sky::bench(a, g),
        BenchWhat::Textures(a) => {
            Ok(crate::bench::textures::bench_textures(&a.files, a.size, a.repeat)?.into())
        }
        BenchWhat::Terrain(a) => Ok(crate::bench::terrain::bench_terrain(a.size, a.repeat)?.into()),
        BenchWhat::Ambient(a) => {
            Ok(crate::bench::ambient::bench_ambient(a.instances, a.error)?.into())
        }
        BenchWhat::TerrainRays(a) => {
            Ok(crate::bench::terrain_rays::bench_terrain_rays(a.size, a.rays)?.into())
        }
        BenchWhat::Lightmap(a) => super::lightmap::bench(a, g),
        BenchWhat::EnvmapError(a) => Ok(crate::bench::envmap_error::bench_envmap_error(
            &crate::bench::envmap_error::EnvmapErrorBench {
                pack: a.pack.clone(),
                instances: a.instances,
                reference_samples: a.reference_samples,
                variants: a.variants.clone(),
                seeds: a.seeds,
            },
        )?
        .into()),
        BenchWhat::Incremental(a) => {
            let bake = std::env::current_exe().map_err(|e| Error::runtime(e.to_string()))?;
            let b = crate::bench::incremental::IncrementalBench {
                dir: a.dir.clone(),
                instances: a.instances,
                models: a.models,
                terrain: a.terrain,
                pipeline: a.pipeline.clone(),
            };
            Ok(crate::bench::incremental::bench_incremental(&bake, &b)?.into())
        }
    }
}
