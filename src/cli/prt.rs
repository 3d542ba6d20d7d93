//! `bake prt INPUT`: per-vertex PRT for every mesh of a pack or model file, and
//! `bake bench rays`: raw obvhs traversal against PRT ray throughput, and `bake bench prt-error`:
//! the transfer's error against time (docs/PERFORMANCE.md).

use super::{Global, Outcome};
use crate::bench::rays::{RaysBenchOptions, bench_rays};
use crate::error::{Error, Result};
use crate::ingest::{IngestOptions, InputKind};
use crate::pack::Pack;
use crate::prt::pack::{mesh_textures, mesh_vertex_count};
use crate::prt::transfer::{self as prt, PrtOptions};
use crate::trace::BuildPreset;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct PrtArgs {
    /// A pack with mesh sections (.bake), or a model or scene file (.txf .3ds .obj .gltf .glb
    /// .eco), which is ingested first.
    pub input: PathBuf,
    /// Output pack (default: the input pack itself, or <input stem>.bake for a model file).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Monte-Carlo paths per vertex side.
    #[arg(long, default_value_t = 256)]
    pub samples: u32,
    /// Scattering events a path may take inside the model (0: visibility only).
    #[arg(long, default_value_t = 3)]
    pub bounces: u32,
    /// Translucence of TXF materials that carry none.
    #[arg(long, default_value_t = 0.3)]
    pub translucence: f32,
    /// BVH build preset.
    #[arg(long, value_enum, default_value_t = BuildPreset::default())]
    pub preset: BuildPreset,
    /// Seed of the sample scrambles.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Which tracer follows the paths (gpu: fails with exit 5 where no GPU adapter exists).
    #[arg(long, value_enum, default_value_t = prt::PrtTracer::Cpu)]
    pub tracer: prt::PrtTracer,
    /// Which vertex sides are traced; a side not traced has a zero transfer.
    #[arg(long, value_enum, default_value_t = prt::PrtSides::Auto)]
    pub sides: prt::PrtSides,
}

fn check_sampling(samples: u32, bounces: u32) -> Result<()> {
    if samples == 0 || samples > 1 << 20 {
        return Err(Error::usage(format!(
            "--samples {samples}: expected 1 to {}",
            1 << 20
        )));
    }
    if bounces > 64 {
        return Err(Error::usage(format!(
            "--bounces {bounces}: expected 0 to 64"
        )));
    }
    Ok(())
}

/// A pack file as it is, or any other input ingested into a pack in memory.
fn open_or_ingest(input: &Path) -> Result<(Pack, Vec<String>)> {
    if InputKind::of(input).is_none() {
        return Ok((Pack::open(input)?, Vec::new()));
    }
    let (w, warnings) = crate::pipeline::ingest_to_pack(input, &IngestOptions::default())?;
    let pack = Pack::from_bytes(&w.to_bytes()?, &input.display().to_string())?;
    Ok((pack, warnings))
}

pub(crate) fn run(args: &PrtArgs, g: &Global) -> Result<Outcome> {
    check_sampling(args.samples, args.bounces)?;
    if !(0.0..=1.0).contains(&args.translucence) {
        return Err(Error::usage("--translucence: expected 0 to 1"));
    }
    let opts = PrtOptions {
        samples: args.samples,
        bounces: args.bounces,
        preset: args.preset,
        default_translucence: args.translucence,
        seed: args.seed,
        tracer: args.tracer,
        sides: args.sides,
        ..PrtOptions::default()
    };
    opts.check()
        .map_err(|m| Error::usage(format!("--tracer {}: {m}", args.tracer.name())))?;
    let is_pack = InputKind::of(&args.input).is_none();
    let (pack, read) = open_or_ingest(&args.input)?;
    let mut warnings = crate::diag::tagged(&crate::diag::INGEST_READER, read);
    let total = mesh_vertex_count(&pack);
    if total == 0 && pack.of_kind(crate::mesh::section::KIND).next().is_none() {
        return Err(Error::invalid_at(
            &args.input,
            "section table",
            "no mesh section: nothing to bake PRT for",
        ));
    }
    let bar = g.progress(total, "prt");
    // Every mesh through the registry's `prt` unit (the graph's and `bake unit prt`'s).
    let pipeline = crate::graph::Pipeline {
        prt: opts,
        ..crate::graph::Pipeline::default()
    };
    let candidates = crate::graph::stage::pack_sections(&pack, "prt")?;
    let mut w = crate::pack::PackWriter::from_pack(&pack);
    let mut reports = Vec::new();
    for e in pack.of_kind(crate::mesh::section::KIND) {
        let o = crate::graph::stage::pack_unit(
            "prt",
            &args.input,
            &candidates,
            &pipeline,
            Some(&e.name),
            None,
            &|n| bar.inc(n),
        )?;
        for s in o.sections {
            w.insert(s);
        }
        reports.push(o.report);
        warnings.extend(o.warnings);
    }
    bar.finish_and_clear();
    let output = match &args.output {
        Some(o) => o.clone(),
        None if is_pack => args.input.clone(),
        None => args.input.with_extension("bake"),
    };
    let bytes = w.to_bytes()?;
    drop((pack, candidates)); // release the input's memory map before replacing the file
    crate::pack::write_atomic(&output, &bytes)?;
    let mut text = String::new();
    for r in &reports {
        let (rays, seconds) = (
            r["rays"].as_u64().unwrap_or(0),
            r["seconds"].as_f64().unwrap_or(0.0),
        );
        text.push_str(&format!(
            "{}: {} vertices, {} triangles, {rays} rays in {seconds:.2} s ({:.2} M rays/s)\n",
            r["section"].as_str().unwrap_or_default(),
            r["vertices"],
            r["triangles"],
            rays as f64 / seconds.max(1e-9) / 1e6
        ));
    }
    text.push_str(&format!("{}: {} bytes\n", output.display(), bytes.len()));
    Ok(Outcome {
        json: serde_json::json!({"output": output, "bytes": bytes.len(), "samples": args.samples,
            "bounces": args.bounces, "tracer": args.tracer, "sides": args.sides,
            "meshes": reports}),
        text,
        warnings,
    })
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct RaysBenchArgs {
    /// A model file or pack (its first mesh); default: a procedural alpha-tested plant.
    pub model: Option<PathBuf>,
    /// Triangles of the procedural plant.
    #[arg(long, default_value_t = 100_000)]
    pub triangles: usize,
    /// Vertices traced (strided over the model).
    #[arg(long, default_value_t = 2000)]
    pub vertices: usize,
    /// Paths per vertex side for the measured PRT rays.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    #[arg(long, default_value_t = 3)]
    pub bounces: u32,
    /// Preset of the BVH the PRT rays use.
    #[arg(long, value_enum, default_value_t = BuildPreset::default())]
    pub preset: BuildPreset,
    /// Measure build time and raw rate of every preset.
    #[arg(long)]
    pub all_presets: bool,
    /// Subdivision depth of the alpha-aware BVH build (0: one box per triangle).
    #[arg(long, default_value_t = crate::trace::bvh::ALPHA_SPLIT_DEPTH)]
    pub alpha_split: u32,
    /// Also bake every vertex with this many samples per side and report the time.
    #[arg(long)]
    pub bake_samples: Option<u32>,
    /// Also trace the raw rays through Embree with the same alpha test (cargo feature `embree`).
    #[arg(long)]
    pub embree: bool,
}

pub(crate) fn bench(a: &RaysBenchArgs, _g: &Global) -> Result<Outcome> {
    check_sampling(a.samples, a.bounces)?;
    let (mesh, textures, source, warnings) = load_model(a.model.as_deref(), a.triangles)?;
    let mats = prt::prt_materials(&mesh, &textures, 0.3);
    let masks = prt::alpha_masks(&mesh, &textures);
    let opts = RaysBenchOptions {
        vertices: a.vertices,
        prt: PrtOptions {
            samples: a.samples,
            bounces: a.bounces,
            preset: a.preset,
            alpha_split: a.alpha_split,
            ..PrtOptions::default()
        },
        presets: if a.all_presets {
            BuildPreset::ALL.to_vec()
        } else {
            vec![a.preset]
        },
        full_bake_samples: a.bake_samples,
        embree: a.embree,
    };
    let r = bench_rays(&mesh, &mats, &masks, &opts)?;
    let cpu = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.3}", v / 1e6));
    let mut text = format!(
        "{source}: {} triangles, {} vertices traced, {} threads, preset {}\n\
         M rays/s         wall     per CPU-s\n\
         raw obvhs   {:>8.3}  {:>8}   ({} rays)\n\
         PRT         {:>8.3}  {:>8}   ({} rays)\n\
         PRT opaque  {:>8.3}  {:>8}   (no alpha test)\n\
         raw alpha   {:>8.3}  {:>8}   (raw rays, alpha-tested BVH)\n\
         efficiency  {:>8.3}  {:>8.3}\n\
         efficiency vs raw alpha     {:>8.3}\n",
        r.triangles,
        r.vertices_traced,
        r.threads,
        r.preset,
        r.raw_rays_per_second / 1e6,
        cpu(r.raw_rays_per_cpu_second),
        r.raw_rays,
        r.prt_rays_per_second / 1e6,
        cpu(r.prt_rays_per_cpu_second),
        r.prt_rays,
        r.prt_opaque_rays_per_second / 1e6,
        cpu(r.prt_opaque_rays_per_cpu_second),
        r.raw_alpha_rays_per_second / 1e6,
        cpu(r.raw_alpha_rays_per_cpu_second),
        r.efficiency_wall,
        r.efficiency,
        r.efficiency_alpha,
    );
    for p in &r.presets {
        text.push_str(&format!(
            "  preset {:<10} build {:>7.3} s, raw {:>7.3} M rays/s, {:>7} per CPU-s\n",
            p.preset,
            p.build_seconds,
            p.raw_rays_per_second / 1e6,
            cpu(p.raw_rays_per_cpu_second)
        ));
    }
    if let (Some(e), Some(b)) = (r.embree_rays_per_second, r.embree_build_seconds) {
        text.push_str(&format!(
            "raw Embree  {:>8.3}  {:>8}   (raw rays, Embree BVH, alpha filter; build {:.3} s)\n\
             PRT / Embree {:>7.3}\n\
             PRT Embree  {:>8.3}  {:>8}   (PRT loop on the Embree backend)\n\
             PRT Embree / raw Embree {:>7.3} wall, {} per CPU-s\n",
            e / 1e6,
            cpu(r.embree_rays_per_cpu_second),
            b,
            r.prt_over_embree.unwrap_or(0.0),
            r.prt_embree_rays_per_second.unwrap_or(0.0) / 1e6,
            cpu(r.prt_embree_rays_per_cpu_second),
            r.prt_embree_over_embree.unwrap_or(0.0),
            r.prt_embree_over_embree_cpu
                .map_or("-".into(), |v| format!("{v:.3}")),
        ));
    }
    if let Some(b) = &r.full_bake {
        text.push_str(&format!(
            "full bake: {} vertices × 2 sides × {} samples, {} bounces: {:.2} s, {} CPU-s \
             (BVH {:.2} s, {:.3} M rays/s)\n",
            b.vertices,
            b.samples,
            b.bounces,
            b.seconds,
            b.cpu_seconds.map_or("-".into(), |c| format!("{c:.1}")),
            b.build_seconds,
            b.rays_per_second / 1e6
        ));
    }
    let mut json = serde_json::to_value(&r).unwrap_or_default();
    json["source"] = source.into();
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}

/// The benchmarks' model: the first mesh of a model file or pack with its textures, or the
/// procedural plant of `triangles` triangles; and its name and warnings.
type BenchModel = (
    crate::model::Mesh,
    Vec<Option<crate::model::Rgba8Image>>,
    String,
    Vec<crate::diag::Warning>,
);

fn load_model(model: Option<&Path>, triangles: usize) -> Result<BenchModel> {
    let Some(path) = model else {
        let (mesh, tex) = crate::prt::plant::procedural_plant(triangles, 1);
        let name = "procedural plant, seed 1".to_string();
        return Ok((mesh, vec![Some(tex)], name, Vec::new()));
    };
    let (pack, read) = open_or_ingest(path)?;
    let mut warnings = crate::diag::tagged(&crate::diag::INGEST_READER, read);
    let e = pack
        .of_kind(crate::mesh::section::KIND)
        .next()
        .cloned()
        .ok_or_else(|| Error::invalid_at(path, "section table", "no mesh section"))?;
    let view = pack.view(&e)?;
    let (meta, mesh) =
        crate::mesh::section::from_section(&view).map_err(|err| Error::invalid(path, err))?;
    let textures = mesh_textures(&pack, &e.name, &meta, &mut warnings);
    Ok((mesh, textures, path.display().to_string(), warnings))
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct PrtErrorBenchArgs {
    /// A model file or pack (its first mesh); default: a procedural alpha-tested plant.
    pub model: Option<PathBuf>,
    /// Triangles of the procedural plant.
    #[arg(long, default_value_t = 100_000)]
    pub triangles: usize,
    /// Vertices measured (an even stride over the model; 0: all).
    #[arg(long, default_value_t = 1000)]
    pub vertices: usize,
    /// Paths per side of the reference (two independent halves of half as many).
    #[arg(long, default_value_t = 16_384)]
    pub reference_samples: u32,
    /// Paths per side of the measured runs (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "64,256,1024,4096")]
    pub samples: Vec<u32>,
    /// Samplers to compare (comma-separated: fixed, adaptive, filtered, embree, gpu; embree is
    /// fixed on the Embree backend and needs the cargo feature `embree`, gpu the same sampler
    /// as a wgpu compute shader).
    #[arg(long, value_delimiter = ',', default_value = "fixed,adaptive")]
    pub methods: Vec<String>,
    /// Radius of the filtered method, relative to the model's bounding-box diagonal.
    #[arg(long, default_value_t = 0.015)]
    pub filter_radius: f32,
    /// Least cosine between the normals the filtered method averages.
    #[arg(long, default_value_t = 0.9)]
    pub filter_min_cos: f32,
    #[arg(long, default_value_t = 4)]
    pub bounces: u32,
    /// BVH build preset.
    #[arg(long, value_enum, default_value_t = BuildPreset::default())]
    pub preset: BuildPreset,
    /// Which vertex sides are traced, by the runs and the reference alike (a side not traced
    /// is zero in both; the reference's cache key includes it).
    #[arg(long, value_enum, default_value_t = prt::PrtSides::Auto)]
    pub sides: prt::PrtSides,
    /// Folder of the cached references.
    #[arg(long, default_value = "target/prt-error")]
    pub cache: PathBuf,
    /// Bake the reference again and cache nothing.
    #[arg(long)]
    pub no_cache: bool,
}

pub(crate) fn bench_error(a: &PrtErrorBenchArgs, _g: &Global) -> Result<Outcome> {
    use crate::bench::prt_error::{Method, PrtErrorOptions, bench_prt_error, report_text};
    for &s in &a.samples {
        check_sampling(s, a.bounces)?;
    }
    check_sampling(a.reference_samples, a.bounces)?;
    let methods = a
        .methods
        .iter()
        .map(|m| {
            Method::ALL
                .into_iter()
                .find(|k| k.name() == m)
                .ok_or_else(|| {
                    Error::usage(format!(
                        "--methods {m}: expected fixed, adaptive, filtered, embree or gpu"
                    ))
                })
        })
        .collect::<Result<Vec<_>>>()?;
    let (mesh, textures, source, warnings) = load_model(a.model.as_deref(), a.triangles)?;
    let mats = prt::prt_materials(&mesh, &textures, 0.3);
    let masks = prt::alpha_masks(&mesh, &textures);
    let opts = PrtErrorOptions {
        vertices: a.vertices,
        reference_samples: a.reference_samples,
        samples: a.samples.clone(),
        methods,
        prt: PrtOptions {
            bounces: a.bounces,
            preset: a.preset,
            sides: a.sides,
            ..PrtOptions::default()
        },
        cache: (!a.no_cache).then(|| a.cache.clone()),
        filter_radius: a.filter_radius,
        filter_min_cos: a.filter_min_cos,
    };
    let r = bench_prt_error(&source, &mesh, &mats, &masks, &opts)?;
    Ok(Outcome {
        json: serde_json::to_value(&r).unwrap_or_default(),
        text: report_text(&r),
        warnings,
    })
}
