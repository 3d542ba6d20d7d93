//! `bake bench lightmap`: the scene's trace structure, the terrain light map and the placed
//! objects' atlases, timed separately (best of `repeat`).

use super::{Report, time_min};
use crate::error::Result;
use crate::lightmap::LightmapOptions;
use crate::pack::Pack;
use crate::trace::Tracer;
use std::path::Path;

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

/// `bake bench lightmap`: scene build (the BVH, and Embree's twin for `tracer` embree), terrain
/// light map and placed-object atlases on `tracer`, timed separately (best of `repeat`).
pub fn bench_lightmap(
    input: Option<&Path>,
    samples: u32,
    repeat: u32,
    tracer: Tracer,
) -> Result<Report> {
    let dir = tempfile::tempdir().map_err(|e| crate::error::Error::io("temporary folder", e))?;
    let pack = match input {
        Some(p) => Pack::open(p)?,
        None => fixture_pack(dir.path())?,
    };
    let opts = LightmapOptions {
        samples,
        tracer,
        ..Default::default()
    };
    let light = crate::lightmap::scene_lighting(&pack)?;
    let best = |f: &mut dyn FnMut() -> Result<()>| time_min(repeat, f).map(|(t, ())| t);
    let scene_s = best(&mut || {
        let scene = crate::trace::pack_scene::trace_scene(&pack)?;
        scene.tracer(tracer).map(|_| ())
    })?;
    let scene = crate::trace::pack_scene::trace_scene(&pack)?;
    // (Embree's scene is built on first use: before the timed light maps.)
    scene.tracer(tracer)?;
    let terrain_s = best(&mut || {
        crate::lightmap::bake_terrain_lightmap(&scene, &light, &opts)?;
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
        "samples": samples, "sun_samples": opts.sun_samples, "threads": threads,
        "tracer": tracer.name()});
    Ok(Report {
        text: format!(
            "scene ({}) {scene_s:.3} s, terrain light map {terrain_s:.3} s, {} object atlas(es) \
             ({covered} covered texels) {objects_s:.3} s; {} samples, {threads} threads\n",
            tracer.name(),
            sections.len(),
            samples
        ),
        json,
    })
}
