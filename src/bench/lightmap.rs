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

/// One estimator of `bake bench lightmap --rows`:
/// `VISIBILITY:SAMPLES:SUN_SAMPLES[:LATTICE[:RES[:STEP]]]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimator {
    pub visibility: crate::lightmap::LightmapVisibility,
    pub samples: u32,
    pub sun_samples: u32,
    pub lattice: u32,
    /// Texels per side of its map (`lightmap.max_resolution`); `None`: the reference's.
    pub resolution: Option<u32>,
    /// `lightmap.trace_step` (1: hemisphere rays at every texel).
    pub trace_step: u32,
}

impl Estimator {
    /// Parses `VISIBILITY:SAMPLES:SUN_SAMPLES[:LATTICE[:RES[:STEP]]]` (defaults 64, 16, 3,
    /// full, 1; an empty RES: full).
    pub fn parse(c: &str) -> std::result::Result<Estimator, String> {
        let f: Vec<&str> = c.trim().split(':').collect();
        let visibility = match f.first().copied() {
            Some("horizons") => crate::lightmap::LightmapVisibility::Horizons,
            Some("rays") => crate::lightmap::LightmapVisibility::Rays,
            _ => return Err(format!("--compare {c}: horizons or rays first")),
        };
        if f.len() > 6 {
            return Err(format!(
                "--compare {c}: VISIBILITY:SAMPLES:SUN_SAMPLES[:LATTICE[:RES[:STEP]]]"
            ));
        }
        let num = |k: usize| -> std::result::Result<Option<u32>, String> {
            f.get(k)
                .filter(|v| !v.is_empty())
                .map(|v| v.parse().map_err(|e| format!("--compare {c}: {e}")))
                .transpose()
        };
        let resolution = num(4)?;
        if resolution == Some(0) {
            return Err(format!("--compare {c}: a resolution of at least 1 texel"));
        }
        Ok(Estimator {
            visibility,
            samples: num(1)?.unwrap_or(64),
            sun_samples: num(2)?.unwrap_or(16),
            lattice: num(3)?.unwrap_or(3),
            resolution,
            trace_step: num(5)?.unwrap_or(1),
        })
    }
}

/// The rows `c0..c1` of a coarse `cw × ch` map (texel-centred, as the light map places its
/// texels) sampled bilinearly, clamped at the map's edges as the renderer's sampler is, at the
/// texel centres of rows `rows` of a `w × h` map.
pub fn upsample_rows(
    coarse: &[[f32; 3]],
    (cw, ch): (u32, u32),
    c0: u32,
    (w, h): (u32, u32),
    rows: std::ops::Range<u32>,
) -> Vec<[f32; 3]> {
    let c1 = c0 + (coarse.len() / cw.max(1) as usize) as u32;
    let axis = |i: u32, n: u32, cn: u32| {
        let u = (i as f32 + 0.5) / n as f32 * cn as f32 - 0.5;
        let u = u.clamp(0.0, (cn - 1) as f32);
        let a = (u.floor() as u32).min(cn - 1);
        (a, (a + 1).min(cn - 1), u - a as f32)
    };
    let mut out = Vec::with_capacity((rows.len()) * w as usize);
    for j in rows {
        let (r0, r1, fy) = axis(j, h, ch);
        let (r0, r1) = (r0.clamp(c0, c1 - 1), r1.clamp(c0, c1 - 1));
        for i in 0..w {
            let (q0, q1, fx) = axis(i, w, cw);
            let t = |r: u32, q: u32| coarse[((r - c0) * cw + q) as usize];
            let (a, b, c, d) = (t(r0, q0), t(r0, q1), t(r1, q0), t(r1, q1));
            out.push(std::array::from_fn(|k| {
                let top = a[k] + (b[k] - a[k]) * fx;
                let bot = c[k] + (d[k] - c[k]) * fx;
                top + (bot - top) * fy
            }));
        }
    }
    out
}

/// `bake bench lightmap --rows A..B` (issue 37): rows `rows` of the terrain light map by every
/// estimator of `configs` (visibility, samples, sun samples, horizon lattice, resolution), timed
/// (wall and CPU seconds of this process), against the ray estimator at `reference` hemisphere
/// and `reference / 4` sun rays at the terrain's full resolution. Errors per texel of the
/// reference, relative to the mean irradiance of the rows: RMS, 90th percentile and largest of
/// |E − E_ref| over the texels (RGB mean), for the total and for the part without the direct
/// sun. An estimator at a lower resolution bakes the coarse rows under the reference's (plus a
/// margin for the bilinear taps and the filters), is filtered there, and is sampled bilinearly at
/// the reference's texel centres ([`upsample_rows`]); its CPU seconds are scaled to the coarse
/// rows that cover the same ground (the margin's share taken out).
pub fn bench_lightmap_error(
    input: Option<&Path>,
    rows: std::ops::Range<u32>,
    configs: &[Estimator],
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
    let want_noise = filters.iter().any(|f| f.noise);
    let run = |opts: &LightmapOptions,
               rows: std::ops::Range<u32>|
     -> Result<(f64, f64, crate::lightmap::TexelRows, Vec<f32>)> {
        let (t0, c0) = (
            std::time::Instant::now(),
            super::cpu_seconds().unwrap_or(0.0),
        );
        let none = || crate::error::Error::usage("the pack has no terrain".to_string());
        let noise_too = want_noise
            && opts.visibility == crate::lightmap::LightmapVisibility::Horizons
            && opts.mode == crate::lightmap::LightmapMode::Physical;
        let ((e, d), noise) = if noise_too {
            crate::lightmap::bake_terrain_lightmap_rows_noise(&scene, &light, opts, rows.clone())?
                .ok_or_else(none)?
        } else {
            (
                crate::lightmap::bake_terrain_lightmap_rows(&scene, &light, opts, rows.clone())?
                    .ok_or_else(none)?,
                Vec::new(),
            )
        };
        let cpu = super::cpu_seconds().unwrap_or(0.0) - c0;
        Ok((t0.elapsed().as_secs_f64(), cpu, (e, d), noise))
    };
    let ref_opts = LightmapOptions {
        samples: reference,
        sun_samples: (reference / 4).max(1),
        visibility: crate::lightmap::LightmapVisibility::Rays,
        ..Default::default()
    };
    let full = crate::lightmap::terrain_lightmap_size(&scene, &ref_opts)
        .ok_or_else(|| crate::error::Error::usage("the pack has no terrain".to_string()))?;
    let rows = rows.start.min(full.1)..rows.end.min(full.1);
    let (rw, rc, (re, rd), _) = run(&ref_opts, rows.clone())?;
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
    let margin = 1 + filters.iter().map(|f| f.radius as u32).max().unwrap_or(0);
    for &Estimator {
        visibility,
        samples,
        sun_samples,
        lattice,
        resolution,
        trace_step,
    } in configs
    {
        let opts = LightmapOptions {
            samples,
            sun_samples,
            visibility,
            horizon_lattice: lattice,
            max_resolution: resolution,
            trace_step,
            // STEP is the step (no bound in metres widens it).
            trace_spacing: 0.0,
            ..Default::default()
        };
        opts.check().map_err(crate::error::Error::usage)?;
        let size = crate::lightmap::terrain_lightmap_size(&scene, &opts).unwrap_or(full);
        // The coarse rows under the reference's, with a margin (none at full resolution).
        let (cr, share) = if size == full {
            (rows.clone(), 1.0)
        } else {
            let at = |j: f32| j / full.1 as f32 * size.1 as f32 - 0.5;
            let lo = at(rows.start as f32 + 0.5).floor().max(0.0) as u32;
            let hi = (at(rows.end as f32 - 0.5).floor() as u32 + 2).min(size.1);
            let cr = lo.saturating_sub(margin)..(hi + margin).min(size.1);
            let ground = rows.len() as f64 * size.1 as f64 / full.1 as f64;
            (cr.clone(), ground / cr.len().max(1) as f64)
        };
        let (w, c, (e, d), noise) = run(&opts, cr.clone())?;
        let (w, c) = (w * share, c * share);
        let width = size.0 as usize;
        let up = |v: &[[f32; 3]]| {
            if size == full {
                v.to_vec()
            } else {
                upsample_rows(v, size, cr.start, full, rows.clone())
            }
        };
        let ind_c: Vec<[f32; 3]> = e
            .iter()
            .zip(&d)
            .map(|(e, d)| std::array::from_fn(|c| e[c] - d[c]))
            .collect();
        let (e_c, d_c) = (e, d);
        let (e, d) = (up(&e_c), up(&d_c));
        let ind: Vec<[f32; 3]> = e
            .iter()
            .zip(&d)
            .map(|(e, d)| std::array::from_fn(|c| e[c] - d[c]))
            .collect();
        let (tot, sky) = (stats(&e, &re, m_tot), stats(&ind, &r_ind, m_ind));
        text += &format!(
            "{visibility:?}:{samples}:{sun_samples}:{lattice}:{}{}: {w:.2} s wall, {c:.2} CPU s; total rms {:.2} % p90 {:.2} % max {:.2} % bias {:.3} %; without direct sun rms {:.2} % p90 {:.2} % max {:.2} % bias {:.3} %\n",
            size.0,
            match trace_step {
                1 => String::new(),
                s => format!(":step {s}"),
            },
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
        // the rows' strip, clamped at its edges; the direct sun kept), on the estimator's own
        // texels before any upsampling: their error against the reference includes their bias.
        let mut filtered = Vec::new();
        for &TexelFilter {
            total,
            guided,
            noise: noise_kind,
            radius: r,
            range: t,
        } in filters
        {
            if noise_kind && noise.is_empty() {
                continue; // the ray estimator has no noise estimate
            }
            let filt = |v: &[[f32; 3]]| {
                if noise_kind {
                    crate::lightmap::filter::noise_bilateral(v, &noise, width, r, t)
                } else if guided {
                    crate::lightmap::filter::guided_bilateral(v, width, r, t)
                } else if t > 0.0 {
                    crate::lightmap::filter::bilateral(v, width, r, t)
                } else {
                    crate::lightmap::filter::box_filter(v, width, r)
                }
            };
            let (f, tot_f): (Vec<[f32; 3]>, Vec<[f32; 3]>) = if total {
                let tf = filt(&e_c);
                let f = tf
                    .iter()
                    .zip(&d_c)
                    .map(|(a, b)| std::array::from_fn(|c| a[c] - b[c]))
                    .collect();
                (f, tf)
            } else {
                let f = filt(&ind_c);
                let tf = f
                    .iter()
                    .zip(&d_c)
                    .map(|(a, b)| std::array::from_fn(|c| a[c] + b[c]))
                    .collect();
                (f, tf)
            };
            let (f, tot_f) = (up(&f), up(&tot_f));
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
                if noise_kind {
                    format!("noise-aware bilateral (k {t})")
                } else if guided {
                    format!("guided bilateral (range {t})")
                } else if t > 0.0 {
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
            filtered.push(serde_json::json!({"radius": r, "range": t, "guided": guided, "noise": noise_kind, "whole": total, "total": tf, "without_direct_sun": sf}));
        }
        rowsj.push(serde_json::json!({"visibility": visibility, "samples": samples, "sun_samples": sun_samples,
            "horizon_lattice": lattice, "resolution": size.0, "trace_step": trace_step, "wall_seconds": w, "cpu_seconds": c, "total": tot, "without_direct_sun": sky,
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
    /// A bilateral whose range weights follow the values' 3×3 box
    /// ([`crate::lightmap::filter::guided_bilateral`]).
    pub guided: bool,
    /// A bilateral whose range follows each texel's noise estimate, `range` its k
    /// ([`crate::lightmap::filter::noise_bilateral`]; horizon estimators only).
    pub noise: bool,
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
            let (total, bilateral, guided, noise) = match p[0] {
                "box" => (false, false, false, false),
                "bilateral" => (false, true, false, false),
                "guided" => (false, true, true, false),
                "noise" => (false, true, false, true),
                "bilateral-total" => (true, true, false, false),
                k => {
                    return Err(format!(
                        "filter `{f}`: kind `{k}` (box, bilateral, guided, noise, bilateral-total)"
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
                guided,
                noise,
                radius,
                range,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn upsampling_reproduces_a_linear_field_and_the_same_size() {
        // A coarse map of a linear field f(x, y) = 2x − 3y + 1 (texel centres); inside the
        // coarse centres' hull bilinear sampling is exact, at the edges it clamps.
        let (cw, ch, w, h) = (9u32, 7u32, 36u32, 28u32);
        let f = |x: f32, y: f32| 2.0 * x - 3.0 * y + 1.0;
        let coarse: Vec<[f32; 3]> = (0..ch)
            .flat_map(|j| (0..cw).map(move |i| (i, j)))
            .map(|(i, j)| {
                let v = f((i as f32 + 0.5) / cw as f32, (j as f32 + 0.5) / ch as f32);
                [v, v, v]
            })
            .collect();
        // Coarse rows 1..6 only, fine rows 8..20 (inside them).
        let part = &coarse[cw as usize..6 * cw as usize];
        let up = super::upsample_rows(part, (cw, ch), 1, (w, h), 8..20);
        assert_eq!(up.len(), 12 * w as usize);
        for (k, t) in up.iter().enumerate() {
            let (i, j) = (k as u32 % w, 8 + k as u32 / w);
            let (x, y) = ((i as f32 + 0.5) / w as f32, (j as f32 + 0.5) / h as f32);
            let xc = x.clamp(0.5 / cw as f32, 1.0 - 0.5 / cw as f32);
            assert!(
                (t[0] - f(xc, y)).abs() < 1e-4,
                "{i},{j}: {} vs {}",
                t[0],
                f(xc, y)
            );
        }
        // The same size is the identity.
        let same = super::upsample_rows(&coarse, (cw, ch), 0, (cw, ch), 0..ch);
        assert_eq!(same, coarse);
    }

    #[test]
    fn estimators_parse_with_a_resolution_and_refuse_bad_ones() {
        let e = super::Estimator::parse("horizons:32:16:3:2049").unwrap();
        assert_eq!((e.samples, e.sun_samples, e.lattice), (32, 16, 3));
        assert_eq!(e.resolution, Some(2049));
        assert_eq!(super::Estimator::parse("rays").unwrap().resolution, None);
        let e = super::Estimator::parse("horizons:64:16:3::2").unwrap();
        assert_eq!((e.resolution, e.trace_step), (None, 2));
        assert_eq!(super::Estimator::parse("rays").unwrap().trace_step, 1);
        for bad in [
            "sky:1",
            "horizons:x",
            "horizons:1:1:1:0",
            "horizons:1:1:1:1:1:1",
        ] {
            assert!(super::Estimator::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn filters_parse_and_refuse_bad_ones() {
        let f = super::parse_filters(
            "box:1, bilateral:2:0.2,bilateral-total:3:0.1,guided:2:0.5,noise:2:2",
        )
        .unwrap();
        assert_eq!(f.len(), 5);
        assert!(f[4].noise && !f[4].guided);
        assert_eq!(
            f[1],
            super::TexelFilter {
                total: false,
                guided: false,
                noise: false,
                radius: 2,
                range: 0.2
            }
        );
        assert!(f[2].total);
        assert!(f[3].guided && !f[3].total);
        assert!(super::parse_filters("").unwrap().is_empty());
        for bad in [
            "box",
            "box:x",
            "bilateral:2",
            "box:1:0.2",
            "gauss:1",
            "guided:2",
        ] {
            assert!(super::parse_filters(bad).is_err(), "{bad}");
        }
    }
}
