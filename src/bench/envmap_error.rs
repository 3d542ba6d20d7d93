//! `bake bench envmap-error --pack P`: the env-map tracer's error against a high-ray reference on
//! a random subset of a baked pack's instances (issue 37, item 2), per estimator variant, with
//! the CPU time of each variant's trace.
//!
//! The subset and the reference are `bench cluster --pack`'s (the same 1,000 instances, seeds
//! and two independent halves, whose difference is the reference's own noise), so "the input
//! maps vs the reference" there equals the default variant's error here: the stored maps of an
//! instance depend only on its index, the scene and the options. Errors are RMS over all 96
//! coefficients of the subset relative to the RMS of all the pack's stored coefficients (the
//! cluster bench's denominator; the subset's reference RMS when the pack has no `envmaps`), raw
//! and with the reference's noise removed in quadrature.
//!
//! A variant is a list of `key=value` overrides of [`EnvmapOptions`] (`samples=512`,
//! `noise_estimate=false`, …), applied to the defaults.

use super::{Report, time_once};
use crate::envmap::bake::EnvmapOptions;
use crate::envmap::section::{self, DIM};
use crate::error::{Error, Result};
use serde_json::json;
use std::path::PathBuf;

/// Options of [`bench_envmap_error`].
#[derive(Debug, Clone)]
pub struct EnvmapErrorBench {
    pub pack: PathBuf,
    /// Instances in the subset.
    pub instances: usize,
    /// Rays of the reference (two independent halves).
    pub reference_samples: u32,
    /// Variants: comma-separated `key=value` overrides of the default options.
    pub variants: Vec<String>,
    /// Independent repetitions of each variant (other seeds): their mean's error and the
    /// spread of their means (bias check).
    pub seeds: u32,
}

/// The default options with a variant's overrides.
pub fn variant_options(spec: &str) -> Result<EnvmapOptions> {
    let mut v = serde_json::to_value(EnvmapOptions::DEFAULT).expect("options serialize");
    for kv in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (k, val) = kv
            .split_once('=')
            .ok_or_else(|| Error::usage(format!("variant `{kv}`: expected key=value")))?;
        if v.get(k).is_none() {
            return Err(Error::usage(format!("variant `{kv}`: no option `{k}`")));
        }
        let parsed: serde_json::Value =
            serde_json::from_str(val).unwrap_or_else(|_| serde_json::Value::String(val.into()));
        v[k] = parsed;
    }
    serde_json::from_value(v).map_err(|e| Error::usage(format!("variant `{spec}`: {e}")))
}

/// The benchmark (see the module doc).
pub fn bench_envmap_error(a: &EnvmapErrorBench) -> Result<Report> {
    let path = &a.pack;
    let pack = crate::pack::Pack::open(path)?;
    let bad = |e| Error::invalid(path, e);
    let (_, inst) = crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
        .map_err(bad)?;
    let rotations: Vec<f32> = inst.items.iter().map(|i| i.rotation_deg).collect();
    let stored_rms = match pack.view_named("envmaps") {
        Ok(v) => {
            let (_, sky, sun) = section::envmaps_from_section(&v).map_err(bad)?;
            Some(crate::envmap::cluster::rms_of(&section::flatten(
                &sky, &sun,
            )))
        }
        Err(_) => None,
    };
    let light = crate::lightmap::scene_lighting(&pack)?;
    let ts = crate::trace::pack_scene::trace_scene(&pack)?;
    let subset = super::cluster::random_subset(rotations.len(), a.instances, 4096);
    let rot: Vec<f32> = subset.iter().map(|&i| rotations[i]).collect();
    // World-frame maps (flattened) and the half differences (world frame, empty without).
    let trace_with_diffs = |o: &EnvmapOptions| -> Result<(Vec<f32>, Vec<f32>)> {
        let t = crate::envmap::instance_traced_subset(&ts, &light, o, &subset)?;
        let (mut sky, mut sun): (Vec<_>, Vec<_>) = t.maps.into_iter().unzip();
        crate::envmap::to_world_frame(&mut sky, &mut sun, &rot);
        Ok((
            section::flatten(&sky, &sun),
            t.diffs.iter().flatten().copied().collect(),
        ))
    };
    let trace = |o: &EnvmapOptions| trace_with_diffs(o).map(|(m, _)| m);
    // The reference: `bench cluster`'s seeds, one N/2-point set per half.
    let half = |seed: u64| {
        trace(&EnvmapOptions {
            samples: (a.reference_samples / 2).max(1),
            seed,
            noise_estimate: false,
            ..EnvmapOptions::DEFAULT
        })
    };
    let (t_ref, (ra, rb)) = time_once(|| (half(0x0072_ef00), half(0x0072_ef01)));
    let (ra, rb) = (ra?, rb?);
    let var = super::cluster_cause::noise_variance(&ra, &rb, DIM);
    let ref_noise_var = var.iter().sum::<f64>() / var.len().max(1) as f64;
    let reference: Vec<f32> = ra.iter().zip(&rb).map(|(x, y)| 0.5 * (x + y)).collect();
    let rms = stored_rms.unwrap_or_else(|| crate::envmap::cluster::rms_of(&reference));
    let sigma = ref_noise_var.max(0.0).sqrt() / rms.max(f32::MIN_POSITIVE) as f64;
    let removed = |x: f64| (x * x - sigma * sigma).max(0.0).sqrt();
    let mut rows = Vec::new();
    let mut text = format!(
        "{}: {} instances, reference {} rays ({:.1} s wall, {:.1} CPU s), its noise {:.3} %, denominator {rms:.5} ({})\n",
        path.display(),
        subset.len(),
        a.reference_samples,
        t_ref.wall,
        t_ref.cpu.unwrap_or(f64::NAN),
        100.0 * sigma,
        if stored_rms.is_some() {
            "the stored maps' RMS"
        } else {
            "the reference's RMS"
        }
    );
    for spec in &a.variants {
        let base = variant_options(spec)?;
        let mut runs = Vec::new();
        let mut diffs = Vec::new();
        let mut cpu = 0.0;
        let mut wall = 0.0;
        for s in 0..a.seeds.max(1) {
            let o = EnvmapOptions {
                seed: base.seed.wrapping_add(s as u64 * 0x1_0000_0001),
                ..base
            };
            let (t, m) = time_once(|| trace_with_diffs(&o));
            cpu += t.cpu.unwrap_or(f64::NAN);
            wall += t.wall;
            let (m, d) = m?;
            runs.push(m);
            diffs.push(d);
        }
        // Filters of the first run, honest: their error against the reference includes their
        // bias. Wiener per coefficient: each coefficient's deviation from the subset's mean
        // shrunk by max(0, 1 − ν/T) (ν the noise variance from the run's own half differences,
        // T the coefficient's variance over the subset). Band-limited: band 3 dropped.
        let filtered = |x: &[f32], d: &[f32]| -> Option<Vec<f32>> {
            if d.len() != x.len() {
                return None;
            }
            let n = (x.len() / DIM) as f64;
            let mut out = x.to_vec();
            for j in 0..DIM {
                let col = |v: &[f32]| -> Vec<f64> {
                    v.iter().skip(j).step_by(DIM).map(|&q| q as f64).collect()
                };
                let (xs, ds) = (col(x), col(d));
                let mu = xs.iter().sum::<f64>() / n;
                let t = xs.iter().map(|q| (q - mu).powi(2)).sum::<f64>() / n;
                let nu = ds.iter().map(|q| q * q).sum::<f64>() / (4.0 * n);
                let s = if t > 0.0 {
                    (1.0 - nu / t).max(0.0)
                } else {
                    0.0
                };
                for (k, q) in xs.iter().enumerate() {
                    out[k * DIM + j] = (mu + s * (q - mu)) as f32;
                }
            }
            Some(out)
        };
        let wiener = filtered(&runs[0], &diffs[0])
            .map(|w| super::cluster::relative_rms(&w, &reference, rms));
        let band3: Vec<f32> = runs[0]
            .iter()
            .enumerate()
            .map(|(j, &q)| if (j % 48) / 3 >= 9 { 0.0 } else { q })
            .collect();
        let e_band3 = super::cluster::relative_rms(&band3, &reference, rms);
        // The irradiance's error (a diffuse receiver's view: band l weighted by Â_l, band 3's
        // Â is 0), relative to the reference's irradiance RMS.
        let a_hat = [
            std::f32::consts::PI,
            2.0 * std::f32::consts::PI / 3.0,
            std::f32::consts::FRAC_PI_4,
            0.0,
        ];
        let irr = |v: &[f32]| -> Vec<f32> {
            v.iter()
                .enumerate()
                .map(|(j, &q)| q * a_hat[(((j % 48) / 3) as f64).sqrt() as usize])
                .collect()
        };
        let ref_irr = irr(&reference);
        let e_irr = super::cluster::relative_rms(
            &irr(&runs[0]),
            &ref_irr,
            crate::envmap::cluster::rms_of(&ref_irr),
        );
        let k = runs.len() as f64;
        let errs: Vec<f64> = runs
            .iter()
            .map(|m| super::cluster::relative_rms(m, &reference, rms))
            .collect();
        let e = (errs.iter().map(|x| x * x).sum::<f64>() / k).sqrt();
        let mean: Vec<f32> = (0..reference.len())
            .map(|j| (runs.iter().map(|m| m[j] as f64).sum::<f64>() / k) as f32)
            .collect();
        let e_mean = super::cluster::relative_rms(&mean, &reference, rms);
        // Split of the squared error: C_H / C_S and SH bands.
        let mut parts = [0.0f64; 2];
        let mut bands = [0.0f64; 4];
        for m in &runs {
            for (j, (x, y)) in m.iter().zip(&reference).enumerate() {
                let d = ((x - y) as f64).powi(2);
                let c = j % DIM;
                parts[c / 48] += d;
                let coeff = (c % 48) / 3;
                bands[(coeff as f64).sqrt() as usize] += d;
            }
        }
        let tot: f64 = parts.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        // Spread of the per-instance errors (first run): mean(e²) / mean(e)², the variance an
        // ideal per-instance ray allocation (n_i ∝ e_i, same total) would save at 1/√n.
        let per: Vec<f64> = runs[0]
            .chunks(DIM)
            .zip(reference.chunks(DIM))
            .map(|(x, y)| {
                x.iter()
                    .zip(y)
                    .map(|(p, q)| ((p - q) as f64).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .collect();
        let np = per.len().max(1) as f64;
        let spread = (per.iter().map(|e| e * e).sum::<f64>() / np)
            / (per.iter().sum::<f64>() / np)
                .powi(2)
                .max(f64::MIN_POSITIVE);
        text.push_str(&format!(
            "  {spec:<40} error {:.3} % ({:.3} % noise removed), mean of {} runs {:.3} %; {:.2} CPU s per run ({:.2} s wall); C_H {:.1} %, bands {:.1}/{:.1}/{:.1}/{:.1} %; spread {spread:.2}; Wiener {}, band 3 dropped {:.3} %, irradiance {:.3} %\n",
            100.0 * e,
            100.0 * removed(e),
            runs.len(),
            100.0 * e_mean,
            cpu / k,
            wall / k,
            100.0 * parts[0] / tot,
            100.0 * bands[0] / tot,
            100.0 * bands[1] / tot,
            100.0 * bands[2] / tot,
            100.0 * bands[3] / tot,
            wiener.map_or("–".to_string(), |w| format!("{:.3} %", 100.0 * w)),
            100.0 * e_band3,
            100.0 * e_irr,
        ));
        rows.push(json!({
            "variant": spec,
            "options": serde_json::to_value(base).expect("options serialize"),
            "runs": runs.len(),
            "rms_error_relative": e,
            "rms_error_relative_noise_removed": removed(e),
            "run_errors": errs,
            "mean_rms_error_relative": e_mean,
            "cpu_seconds_per_run": cpu / k,
            "wall_seconds_per_run": wall / k,
            "sky_fraction": parts[0] / tot,
            "band_fractions": bands.map(|b| b / tot),
            "allocation_spread": spread,
            "wiener_rms_error_relative": wiener,
            "band3_dropped_rms_error_relative": e_band3,
            "irradiance_rms_error_relative": e_irr,
        }));
    }
    Ok(Report {
        json: json!({
            "pack": path.display().to_string(),
            "instances": subset.len(),
            "reference": {
                "samples": a.reference_samples,
                "noise_relative": sigma,
                "wall_seconds": t_ref.wall,
                "cpu_seconds": t_ref.cpu,
            },
            "denominator": rms,
            "denominator_is_stored_maps": stored_rms.is_some(),
            "variants": rows,
        }),
        text,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_variant_overrides_the_named_options_and_refuses_unknown_ones() {
        let o = variant_options("samples=512, noise_estimate=false").unwrap();
        assert_eq!(o.samples, 512);
        assert!(!o.noise_estimate);
        assert_eq!(o.seed, EnvmapOptions::DEFAULT.seed);
        assert_eq!(variant_options("").unwrap(), EnvmapOptions::DEFAULT);
        assert!(variant_options("tracer=embree").is_ok_and(|o| o.tracer.name() == "embree"));
        for bad in ["samples", "rays=4", "samples=many"] {
            let e = variant_options(bad).unwrap_err().to_string();
            assert!(e.contains("variant"), "{bad}: {e}");
        }
    }
}
