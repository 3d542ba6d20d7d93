//! `bake lightmap INPUT`: the terrain's light map (section `lightmap:terrain`) and atlas light
//! maps of the meshes placed at most `--lightmap-max-instances` times (`lightmap:<mesh>`).

use super::{Global, Outcome};
use crate::error::Result;
use crate::lightmap::{LightmapMode, LightmapOptions};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct LightmapArgs {
    /// A scene pack (with `sh`/`sun` sections from `bake sky` or `bake build`).
    pub input: PathBuf,
    /// Output pack (default: the input pack).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Texels per side (default: the terrain grid size).
    #[arg(long)]
    pub resolution: Option<u32>,
    /// Hemisphere samples per texel.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// `physical` (visibility, true sun disc, one bounce) or `thesis` (seed 001's estimator).
    #[arg(long, value_enum, default_value_t = LightmapMode::Physical)]
    pub mode: LightmapMode,
    /// Models placed at most this many times (the 3DS objects) get an atlas light map.
    #[arg(long, default_value_t = 16)]
    pub lightmap_max_instances: u32,
    /// Texels per side of one instance's atlas tile (doubled while the charts do not fit).
    #[arg(long, default_value_t = 64)]
    pub atlas_tile: u32,
    /// Gutter texels around every chart.
    #[arg(long, default_value_t = 2)]
    pub gutter: u32,
}

pub fn run(args: &LightmapArgs, _g: &Global) -> Result<Outcome> {
    let (mut w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let pack = Pack::from_bytes(&w.to_bytes()?, &args.input.display().to_string())?;
    let opts = LightmapOptions {
        resolution: args.resolution,
        samples: args.samples,
        mode: args.mode,
        max_instances: args.lightmap_max_instances,
        atlas: crate::lightmap::atlas::AtlasOptions {
            tile: args.atlas_tile,
            gutter: args.gutter.max(1),
            ..Default::default()
        },
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let mut sections = crate::lightmap::lightmap_sections(&pack, &opts)?;
    sections.extend(crate::lightmap::atlas_sections(&pack, &opts)?);
    let seconds = start.elapsed().as_secs_f64();
    let mut summaries = Vec::new();
    for s in sections {
        let v = crate::pack::section::SectionView::parse(&s.payload, 0)
            .map_err(|e| crate::error::Error::invalid(&output, e))?;
        summaries.push(
            crate::lightmap::section::summary(&v)
                .map_err(|e| crate::error::Error::invalid(&output, e))?,
        );
        w.insert(s);
    }
    w.write(&output)?;
    let doc = serde_json::json!({"output": output, "lightmaps": summaries, "seconds": seconds});
    Ok(Outcome {
        text: format!(
            "{}: {} light map(s) in {seconds:.2} s\n",
            output.display(),
            summaries.len()
        ),
        json: doc,
        warnings: Vec::new(),
    })
}

#[derive(Debug, Clone, clap::Args)]
pub struct LightmapBenchArgs {
    /// A scene pack with `sh`/`sun` sections (default: the generated fixture scene with its sky).
    pub input: Option<PathBuf>,
    /// Hemisphere samples per texel.
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// Repetitions (the best time is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
}

/// The fixture scene (`bake fixtures`) ingested with its HDR sky's `sky`/`sun`/`sh` sections.
pub fn fixture_pack(dir: &std::path::Path) -> Result<Pack> {
    crate::fixtures::write_all(dir)?;
    let (mut w, _) = crate::pipeline::ingest_to_pack(
        &dir.join("scene.eco"),
        &crate::ingest::IngestOptions::default(),
    )?;
    let sky = crate::ingest::skyimage::load(&dir.join("sky.hdr"))?;
    for s in crate::sky::scene_sky_sections(
        Some(&sky),
        &Default::default(),
        &crate::sky::SkyOptions::default(),
    )? {
        w.insert(s);
    }
    Pack::from_bytes(&w.to_bytes()?, "fixture scene")
}

/// `bake bench lightmap`: scene BVH build, terrain light map and placed-object atlases, timed
/// separately (best of `repeat`).
pub fn bench(a: &LightmapBenchArgs, _g: &Global) -> Result<Outcome> {
    let dir = tempfile::tempdir().map_err(|e| crate::error::Error::io("temporary folder", e))?;
    let pack = match &a.input {
        Some(p) => Pack::open(p)?,
        None => fixture_pack(dir.path())?,
    };
    let opts = LightmapOptions {
        samples: a.samples,
        ..Default::default()
    };
    let light = crate::lightmap::scene_lighting(&pack)?;
    let best = |f: &mut dyn FnMut() -> Result<()>| -> Result<f64> {
        let mut best = f64::INFINITY;
        for _ in 0..a.repeat.max(1) {
            let t = std::time::Instant::now();
            f()?;
            best = best.min(t.elapsed().as_secs_f64());
        }
        Ok(best)
    };
    let scene_s = best(&mut || crate::trace::pack_scene::trace_scene(&pack).map(|_| ()))?;
    let scene = crate::trace::pack_scene::trace_scene(&pack)?;
    let terrain_s = best(&mut || {
        crate::lightmap::bake_terrain_lightmap(&scene, &light, &opts);
        Ok(())
    })?;
    let mut sections = Vec::new();
    let objects_s = best(&mut || {
        sections = crate::lightmap::object_sections(&pack, &scene, &light, &opts)?;
        Ok(())
    })?;
    let mut covered = 0u64;
    for s in &sections {
        let v = crate::pack::section::SectionView::parse(&s.payload, 0)
            .map_err(|e| crate::error::Error::invalid("bench", e))?;
        let (m, _) = crate::lightmap::atlas_section::from_section(&v)
            .map_err(|e| crate::error::Error::invalid("bench", e))?;
        covered += m.texels_covered;
    }
    let threads = rayon::current_num_threads();
    let json = serde_json::json!({"scene_seconds": scene_s, "terrain_seconds": terrain_s,
        "objects_seconds": objects_s, "object_atlases": sections.len(), "object_texels_covered": covered,
        "samples": a.samples, "sun_samples": opts.sun_samples, "threads": threads});
    Ok(Outcome {
        text: format!(
            "scene BVH {scene_s:.3} s, terrain light map {terrain_s:.3} s, {} object atlas(es) \
             ({covered} covered texels) {objects_s:.3} s; {} samples, {threads} threads\n",
            sections.len(),
            a.samples
        ),
        json,
        warnings: Vec::new(),
    })
}
