//! The `bake` command line: its clap arguments, the dispatch to the subcommands' `run`, and
//! printing the [`Outcome`] (`src/main.rs` only calls [`main`]).

use crate::cli::{self, Global, Outcome};
use crate::error::{Error, exit};
use clap::{Parser, Subcommand};

/// Asset-baking pipeline for interactive landscape rendering.
///
/// `bake SCENE.eco` is short for `bake build SCENE.eco`.
#[derive(Debug, Parser)]
#[command(name = "bake", version, about, long_about = None, after_help = EXIT_CODES)]
struct Cli {
    #[command(flatten)]
    global: Global,
    #[command(subcommand)]
    command: Command,
}

const EXIT_CODES: &str =
    "Exit codes: 0 ok, 2 usage, 3 I/O error, 4 invalid input, 5 runtime failure.";

#[derive(Debug, Subcommand)]
enum Command {
    /// Ingest a whole ECO scene into one pack (the default command).
    Build(cli::build::BuildArgs),
    /// The stage cache: `stats`, `gc --max-size SIZE`.
    Cache(cli::cache::CacheArgs),
    /// The pipeline presets and files: `list`, `show PRESET`, `check FILE`.
    Pipeline(cli::pipeline::PipelineArgs),
    /// Ingest any single input file into a pack.
    Ingest(cli::ingest::IngestArgs),
    /// Per-vertex PRT (SH transfer) for every mesh of a pack or model file.
    Prt(cli::prt::PrtArgs),
    /// Levels of detail and impostor atlases for every mesh of a pack.
    Lod(cli::lod::LodArgs),
    /// Show what a pack holds.
    Dump(cli::dump::DumpArgs),
    /// One self-contained HTML page of a pack: sections, images, the bake's timeline, a render.
    Report(cli::report::ReportArgs),
    /// Export a pack as a glTF 2.0 scene (GLB): models, materials, instances, terrain, sun.
    Export(cli::export::ExportArgs),
    /// Write the generated fixture scene into a folder.
    Fixtures(cli::fixtures::FixturesArgs),
    /// Encode the instances of a scene pack as a BitTree.
    Bittree(cli::bittree::BitTreeArgs),
    /// Cluster per-instance environment maps and set up multiquadric interpolation.
    Cluster(cli::cluster::ClusterArgs),
    /// An HDR sky (or the built-in one) to a cube map, the sun and the sky's SH.
    Sky(cli::sky::SkyArgs),
    /// Bake the light maps of the terrain and of the placed objects (atlases).
    Lightmap(cli::lightmap::LightmapArgs),
    /// Bake per-instance SH environment maps.
    Envmaps(cli::envmaps::EnvmapsArgs),
    /// Render a pack offscreen to a PNG (wgpu; runs on Mesa's lavapipe or llvmpipe without a GPU).
    Render(cli::render::RenderArgs),
    /// Write the placed scene as a Mitsuba 3 scene (the ground-truth harness, docs/VALIDATION.md).
    Mitsuba(cli::mitsuba::MitsubaArgs),
    /// Convert materials to two-layer Schlick, process textures, add tangents.
    Material(cli::material::MaterialArgs),
    /// Prepare terrains: four-tap height texture, normal map, min/max quadtree.
    Terrain(cli::terrain::TerrainArgs),
    /// Benchmarks (see docs/PERFORMANCE.md).
    Bench(cli::bench::BenchArgs),
    /// Voxelize a model or pack into a sparse voxel octree section.
    Svo(cli::svo::SvoArgs),
    /// Build the N-tree with line spaces (soft-shadow acceleration) of a model or pack.
    Linespace(cli::linespace::LinespaceArgs),
    /// Check the GPU traversal of a pack's svo and linespace sections against the CPU.
    Validate(cli::validate::ValidateArgs),
    /// Check a pack against docs/FORMAT.md: container, checksums, every section's invariants.
    Verify(cli::verify::VerifyArgs),
    /// Run any registered stage over a pack with a pipeline's options (`--list` names them).
    Stage(cli::stage::StageArgs),
    /// One unit of the stage graph as a build-engine action (what `bake plan` writes).
    Unit(cli::unit::UnitArgs),
    /// Join packs into one (the union of sections; a name with two payloads is an error).
    Merge(cli::unit::MergeArgs),
    /// The stage graph as actions of Ninja or Bazel: `--emit ninja|bazel -o DIR`.
    Plan(cli::plan::PlanArgs),
}

fn run(cli: &Cli) -> Result<Outcome, Error> {
    let g = &cli.global;
    match &cli.command {
        Command::Build(a) => cli::build::run(a, g),
        Command::Ingest(a) => cli::ingest::run(a, g),
        Command::Cache(a) => cli::cache::run(a, g),
        Command::Pipeline(a) => cli::pipeline::run(a, g),
        Command::Prt(a) => cli::prt::run(a, g),
        Command::Lod(a) => cli::lod::run(a, g),
        Command::Dump(a) => cli::dump::run(a, g),
        Command::Report(a) => cli::report::run(a, g),
        Command::Export(a) => cli::export::run(a, g),
        Command::Sky(a) => cli::sky::run(a, g),
        Command::Bench(a) => cli::bench::run(a, g),
        Command::Material(a) => cli::material::run(a, g),
        Command::Terrain(a) => cli::terrain::run(a, g),
        Command::Bittree(a) => cli::bittree::run(a, g),
        Command::Cluster(a) => cli::cluster::run(a, g),
        Command::Lightmap(a) => cli::lightmap::run(a, g),
        Command::Envmaps(a) => cli::envmaps::run(a, g),
        Command::Fixtures(a) => cli::fixtures::run(a, g),
        Command::Render(a) => cli::render::run(a, g),
        Command::Mitsuba(a) => cli::mitsuba::run(a, g),
        Command::Svo(a) => cli::svo::run(a, g),
        Command::Linespace(a) => cli::linespace::run(a, g),
        Command::Validate(a) => cli::validate::run(a, g),
        Command::Verify(a) => cli::verify::run(a, g),
        Command::Stage(a) => cli::stage::run(a, g),
        Command::Unit(a) => cli::unit::run(a, g),
        Command::Merge(a) => cli::unit::run_merge(a, g),
        Command::Plan(a) => cli::plan::run(a, g),
    }
}

/// `bake scene.eco ...` becomes `bake build scene.eco ...`.
fn with_default_command(mut args: Vec<std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let first = args
        .iter()
        .skip(1)
        .find(|a| !a.to_string_lossy().starts_with('-'));
    if let Some(first) = first {
        let f = first.to_string_lossy().to_ascii_lowercase();
        if f.ends_with(".eco") {
            args.insert(1, "build".into());
        }
    }
    args
}

/// The `bake` binary's whole work: parses the process's arguments, runs the command, prints its
/// outcome (text, or JSON with `--json`; warnings on stderr) and exits with the documented code
/// (docs/CONVENTIONS.md: 0 ok, 2 usage, 3 I/O, 4 invalid input, 5 runtime).
pub fn main() {
    cli::render::quiet_mesa_layer();
    let cli = match Cli::try_parse_from(with_default_command(std::env::args_os().collect())) {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() {
                exit::USAGE
            } else {
                exit::OK
            };
            let _ = e.print();
            std::process::exit(code);
        }
    };
    let filter = if cli.global.quiet { "error" } else { "warn" };
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("BAKE_LOG")
                .unwrap_or_else(|_| filter.into()),
        )
        .with_writer(std::io::stderr)
        .try_init();
    match run(&cli) {
        Ok(out) => {
            for w in &out.warnings {
                if w.place.is_empty() {
                    eprintln!("warning: {}", w.line());
                } else {
                    eprintln!("warning: {}: {}", w.place, w.line());
                }
            }
            if cli.global.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&out.json).unwrap_or_default()
                );
            } else if !cli.global.quiet {
                print!("{}", out.text);
            }
            let fatal = cli.global.fatal_warnings(&out.warnings);
            if !fatal.is_empty() {
                eprintln!("error: {} warning(s) and --warnings-as-errors", fatal.len());
                std::process::exit(exit::INVALID_INPUT);
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(e.exit_code());
        }
    }
}
