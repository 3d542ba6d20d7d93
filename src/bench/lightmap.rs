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

/// `bake bench lightmap --rows A..B` (issue 37): rows `rows` of the terrain light map by every
/// estimator of `configs` (visibility, samples, sun samples, horizon lattice), timed (wall and
/// CPU seconds of this process), against the ray estimator at `reference` hemisphere and
/// `reference / 4` sun rays. Errors per texel, relative to the mean irradiance of the rows:
/// RMS, 90th percentile and largest of |E − E_ref| over the texels (RGB mean), for the total
/// and for the part without the direct sun.
pub fn bench_lightmap_error(
    input: Option<&Path>,
    rows: std::ops::Range<u32>,
    configs: &[(crate::lightmap::LightmapVisibility, u32, u32, u32)],
    reference: u32,
    filters: &[TexelFilter],
) -> Result<Report> {
    let dir = tempfile::tempdir().map_err(|e| crate::error::Error::io("temporary folder", e))?;
    let pack = match input {
        Some(p) => Pack::open(p)?,
        None => fixture_pack(dir.path())?,
    };
    let light = crate::lightmap::scene_lighting(&pack)?;
    let scene = crate::trace::pack_scene::trace_scene(&pack)?;
    let run = |opts: &LightmapOptions| -> Result<(f64, f64, crate::lightmap::TexelRows)> {
        let (t0, c0) = (
            std::time::Instant::now(),
            super::cpu_seconds().unwrap_or(0.0),
        );
        let (e, d) =
            crate::lightmap::bake_terrain_lightmap_rows(&scene, &light, opts, rows.clone())?
                .ok_or_else(|| crate::error::Error::usage("the pack has no terrain".to_string()))?;
        let cpu = super::cpu_seconds().unwrap_or(0.0) - c0;
        Ok((t0.elapsed().as_secs_f64(), cpu, (e, d)))
    };
    let ref_opts = LightmapOptions {
        samples: reference,
        sun_samples: (reference / 4).max(1),
        visibility: crate::lightmap::LightmapVisibility::Rays,
        ..Default::default()
    };
    let (rw, rc, (re, rd)) = run(&ref_opts)?;
    let mean = |v: &[[f32; 3]]| {
        v.iter()
            .map(|t| (t[0] + t[1] + t[2]) as f64 / 3.0)
            .sum::<f64>()
            / v.len().max(1) as f64
    };
    let r_ind: Vec<[f32; 3]> = re
        .iter()
        .zip(&rd)
        .map(|(e, d)| std::array::from_fn(|c| e[c] - d[c]))
        .collect();
    let (m_tot, m_ind) = (mean(&re), mean(&r_ind));
    let stats = |a: &[[f32; 3]], b: &[[f32; 3]], m: f64| {
        let mut err: Vec<f64> = a
            .iter()
            .zip(b)
            .map(|(x, y)| ((0..3).map(|c| (x[c] - y[c]) as f64).sum::<f64>() / 3.0).abs() / m)
            .collect();
        let rms = (err.iter().map(|e| e * e).sum::<f64>() / err.len().max(1) as f64).sqrt();
        let bias = a
            .iter()
            .zip(b)
            .map(|(x, y)| (0..3).map(|c| (x[c] - y[c]) as f64).sum::<f64>() / 3.0)
            .sum::<f64>()
            / a.len().max(1) as f64
            / m;
        err.sort_by(f64::total_cmp);
        let p90 = err.get(err.len() * 9 / 10).copied().unwrap_or(0.0);
        let max = err.last().copied().unwrap_or(0.0);
        serde_json::json!({"rms": rms, "p90": p90, "max": max, "bias": bias})
    };
    let mut rowsj = Vec::new();
    let mut text = format!(
        "rows {}..{} ({} texels), reference rays:{reference}:{}: {rw:.2} s wall, {rc:.2} CPU s\n",
        rows.start,
        rows.end,
        re.len(),
        ref_opts.sun_samples
    );
    for &(visibility, samples, sun_samples, lattice) in configs {
        let opts = LightmapOptions {
            samples,
            sun_samples,
            visibility,
            horizon_lattice: lattice,
            ..Default::default()
        };
        opts.check().map_err(crate::error::Error::usage)?;
        let (w, c, (e, d)) = run(&opts)?;
        let ind: Vec<[f32; 3]> = e
            .iter()
            .zip(&d)
            .map(|(e, d)| std::array::from_fn(|c| e[c] - d[c]))
            .collect();
        let (tot, sky) = (stats(&e, &re, m_tot), stats(&ind, &r_ind, m_ind));
        text += &format!(
            "{visibility:?}:{samples}:{sun_samples}:{lattice}: {w:.2} s wall, {c:.2} CPU s; total rms {:.2} % p90 {:.2} % max {:.2} % bias {:.3} %; without direct sun rms {:.2} % p90 {:.2} % max {:.2} % bias {:.3} %\n",
            tot["rms"].as_f64().unwrap_or(0.0) * 100.0,
            tot["p90"].as_f64().unwrap_or(0.0) * 100.0,
            tot["max"].as_f64().unwrap_or(0.0) * 100.0,
            tot["bias"].as_f64().unwrap_or(0.0) * 100.0,
            sky["rms"].as_f64().unwrap_or(0.0) * 100.0,
            sky["p90"].as_f64().unwrap_or(0.0) * 100.0,
            sky["max"].as_f64().unwrap_or(0.0) * 100.0,
            sky["bias"].as_f64().unwrap_or(0.0) * 100.0,
        );
        // Honest texel-space filters of the part without the direct sun (box of radius r over
        // the rows' strip, clamped at its edges; the direct sun kept): their error against the
        // reference includes their bias.
        let width = e.len() / (rows.end - rows.start).max(1) as usize;
        let mut filtered = Vec::new();
        for &TexelFilter {
            total,
            radius: r,
            range: t,
        } in filters
        {
            let filt = |v: &[[f32; 3]]| {
                if t > 0.0 {
                    crate::lightmap::filter::bilateral(v, width, r, t)
                } else {
                    crate::lightmap::filter::box_filter(v, width, r)
                }
            };
            let (f, tot_f): (Vec<[f32; 3]>, Vec<[f32; 3]>) = if total {
                let tf = filt(&e);
                let f = tf
                    .iter()
                    .zip(&d)
                    .map(|(a, b)| std::array::from_fn(|c| a[c] - b[c]))
                    .collect();
                (f, tf)
            } else {
                let f = filt(&ind);
                let tf = f
                    .iter()
                    .zip(&d)
                    .map(|(a, b)| std::array::from_fn(|c| a[c] + b[c]))
                    .collect();
                (f, tf)
            };
            let (tf, sf) = (stats(&tot_f, &re, m_tot), stats(&f, &r_ind, m_ind));
            text += &format!(
                "  + {8} {0}×{0} on {9}: total rms {1:.2} % p90 {2:.2} % max {3:.2} %; without direct sun rms {4:.2} % p90 {5:.2} % max {6:.2} % bias {7:.3} %\n",
                2 * r + 1,
                tf["rms"].as_f64().unwrap_or(0.0) * 100.0,
                tf["p90"].as_f64().unwrap_or(0.0) * 100.0,
                tf["max"].as_f64().unwrap_or(0.0) * 100.0,
                sf["rms"].as_f64().unwrap_or(0.0) * 100.0,
                sf["p90"].as_f64().unwrap_or(0.0) * 100.0,
                sf["max"].as_f64().unwrap_or(0.0) * 100.0,
                sf["bias"].as_f64().unwrap_or(0.0) * 100.0,
                if t > 0.0 {
                    format!("bilateral (range {t})")
                } else {
                    "box".to_string()
                },
                if total {
                    "the whole irradiance"
                } else {
                    "the part without direct sun"
                },
            );
            filtered.push(serde_json::json!({"radius": r, "range": t, "whole": total, "total": tf, "without_direct_sun": sf}));
        }
        rowsj.push(serde_json::json!({"visibility": visibility, "samples": samples, "sun_samples": sun_samples,
            "horizon_lattice": lattice, "wall_seconds": w, "cpu_seconds": c, "total": tot, "without_direct_sun": sky,
            "filtered": filtered}));
    }
    Ok(Report {
        json: serde_json::json!({"rows": [rows.start, rows.end], "texels": re.len(),
            "reference": {"samples": reference, "sun_samples": ref_opts.sun_samples, "wall_seconds": rw, "cpu_seconds": rc},
            "threads": rayon::current_num_threads(), "estimators": rowsj}),
        text,
    })
}

/// A texel-space filter of the error mode (`--filters`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelFilter {
    /// The whole irradiance filtered (else the part without the direct sun).
    pub total: bool,
    pub radius: usize,
    /// The bilateral's relative range; 0: a box.
    pub range: f32,
}

/// `KIND:RADIUS[:RANGE],…` (see `bake bench lightmap --filters`).
pub fn parse_filters(s: &str) -> std::result::Result<Vec<TexelFilter>, String> {
    s.split(',')
        .map(str::trim)
        .filter(|f| !f.is_empty())
        .map(|f| {
            let p: Vec<&str> = f.split(':').collect();
            let num = |i: usize| -> std::result::Result<&str, String> {
                p.get(i)
                    .copied()
                    .ok_or_else(|| format!("filter `{f}`: KIND:RADIUS[:RANGE]"))
            };
            let radius: usize = num(1)?.parse().map_err(|e| format!("filter `{f}`: {e}"))?;
            let range: f32 = match p.get(2) {
                Some(r) => r.parse().map_err(|e| format!("filter `{f}`: {e}"))?,
                None => 0.0,
            };
            let (total, bilateral) = match p[0] {
                "box" => (false, false),
                "bilateral" => (false, true),
                "bilateral-total" => (true, true),
                k => {
                    return Err(format!(
                        "filter `{f}`: kind `{k}` (box, bilateral, bilateral-total)"
                    ));
                }
            };
            if bilateral != (range > 0.0) || p.len() > 3 {
                return Err(format!(
                    "filter `{f}`: a bilateral needs a range > 0, a box none"
                ));
            }
            Ok(TexelFilter {
                total,
                radius,
                range,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn filters_parse_and_refuse_bad_ones() {
        let f = super::parse_filters("box:1, bilateral:2:0.2,bilateral-total:3:0.1").unwrap();
        assert_eq!(f.len(), 3);
        assert_eq!(
            f[1],
            super::TexelFilter {
                total: false,
                radius: 2,
                range: 0.2
            }
        );
        assert!(f[2].total);
        assert!(super::parse_filters("").unwrap().is_empty());
        for bad in ["box", "box:x", "bilateral:2", "box:1:0.2", "gauss:1"] {
            assert!(super::parse_filters(bad).is_err(), "{bad}");
        }
    }
}
