//! `bake bench sky`: the sky stage's timings (decode, SH from the lat-long image, the whole sky
//! bake) and its SH accuracy against the exact pixel integrals, optionally beside cmgen's.

use super::{Report, time_median};
use crate::error::{Error, Result};
use crate::sky::builtin::BuiltinSky;
use crate::sky::{self, SkyOptions};
use serde_json::json;
use std::path::Path;

/// Writes the built-in sky as a `w`×`h` lat-long .hdr to `path` (the benchmark's sample input).
pub fn write_sample(path: &Path, w: u32, h: u32) -> Result<Report> {
    // Sun off the diagonals, so the x and y axes are told apart in comparisons.
    let params = BuiltinSky {
        sun_elevation_deg: 35.0,
        sun_azimuth_deg: 160.0,
        ..BuiltinSky::default()
    };
    let img = sky::builtin::builtin_sky_latlong(&params, w, h);
    crate::pack::write_atomic(path, &crate::ingest::skyimage::write_hdr(&img))?;
    Ok(Report {
        json: json!({"written": path, "width": w, "height": h}),
        text: format!("{}: built-in sky, {w}×{h}\n", path.display()),
    })
}

/// Largest coefficient difference relative to |L00| (per channel, over all 16 coefficients).
fn sh_error(a: &crate::sh::ShRadiance, exact: &crate::sh::ShRadiance) -> f64 {
    let mut worst = 0.0f64;
    for k in 0..3 {
        let scale = (exact.coeffs[0][k] as f64).abs().max(1e-30);
        for i in 0..16 {
            worst = worst.max((a.coeffs[i][k] as f64 - exact.coeffs[i][k] as f64).abs() / scale);
        }
    }
    worst
}

/// The sky benchmark of `input` (`repeat` runs per timed step, the median reported).
pub fn bench_sky(input: &Path, repeat: u32, cmgen_sh: Option<&Path>) -> Result<Report> {
    let (t_decode, img) = time_median(repeat, || crate::ingest::skyimage::load(input))?;
    let (t_sh, sh) = time_median(repeat, || Ok(crate::sh::project_latlong(&img)))?;
    let src = sky::image_to_source(img.clone()).map_err(|e| Error::invalid(input, e))?;
    let (t_bake, bake) = time_median(repeat, || sky::bake_sky(&src, &SkyOptions::default()))?;
    let exact = crate::sh::project_latlong_exact(&img);
    let full_cube = sky::source_to_cube(&src, bake.cube.size, 0.0);
    let cube_sh = crate::sh::project_cube(&full_cube);
    let mut json = json!({
        "input": input, "width": img.width, "height": img.height, "threads": rayon::current_num_threads(),
        "seconds": {"decode": t_decode, "sh_latlong": t_sh, "bake_sky": t_bake},
        "sh_error_vs_exact": {"latlong": sh_error(&sh, &exact), "cube": sh_error(&cube_sh, &exact)},
        "face_size": bake.cube.size,
        "sh_exact": exact.coeffs, "sh_latlong": sh.coeffs,
    });
    let mut text = format!(
        "{} ({}×{}, {} threads): decode {:.1} ms, SH from lat-long {:.1} ms, bake sky (cube {}, sun, SH) {:.1} ms\n  SH error vs exact pixel integrals (max |Δ|/|L00|): lat-long {:.2e}, cube {:.2e}\n",
        input.display(),
        img.width,
        img.height,
        rayon::current_num_threads(),
        t_decode * 1e3,
        t_sh * 1e3,
        bake.cube.size,
        t_bake * 1e3,
        sh_error(&sh, &exact),
        sh_error(&cube_sh, &exact),
    );
    if let Some(path) = cmgen_sh {
        let theirs = read_cmgen_sh(path)?;
        let err = sh_error(&theirs, &exact);
        json["sh_error_vs_exact"]["cmgen"] = json!(err);
        json["sh_cmgen_aligned"] = json!(theirs.coeffs);
        text.push_str(&format!("  cmgen (aligned): {err:.2e}\n"));
    }
    Ok(Report { json, text })
}

/// Reads cmgen's `--sh-output` text (`( r, g, b ); // L00 ...` lines, 16 of them) and maps it to
/// bake's convention (see docs/PERFORMANCE.md, "Sky", for how the conventions were aligned).
fn read_cmgen_sh(path: &std::path::Path) -> Result<crate::sh::ShRadiance> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut coeffs = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let Some(open) = line.find('(') else { continue };
        let Some(close) = line[open..].find(')') else {
            continue;
        };
        let nums: Vec<f32> = line[open + 1..open + close]
            .split(',')
            .map(|s| s.trim().parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| {
                Error::invalid_at(path, format!("line {}", n + 1), "expected ( r, g, b )")
            })?;
        if nums.len() != 3 {
            return Err(Error::invalid_at(
                path,
                format!("line {}", n + 1),
                "expected 3 numbers",
            ));
        }
        coeffs.push([nums[0], nums[1], nums[2]]);
    }
    let coeffs: [[f32; 3]; 16] = coeffs.try_into().map_err(|c: Vec<_>| {
        Error::invalid_at(
            path,
            "file",
            format!("{} coefficients, expected 16", c.len()),
        )
    })?;
    Ok(cmgen_to_bake(coeffs))
}

/// cmgen's coefficients in bake's convention. cmgen (Filament `libs/ibl`) uses the same real
/// basis with the Condon–Shortley phase, but its axes are Y up and its cube maps mirrored (its
/// default): a world direction (x, y, z) is cmgen's (x', y', z') = (y, z, −x), found by matching
/// the band-1 dipole of a sky whose sun is off the diagonals (an improper map, det −1). bake's
/// function at ω is cmgen's at M·ω, i.e. cmgen's rotated by Mᵀ.
fn cmgen_to_bake(c: [[f32; 3]; 16]) -> crate::sh::ShRadiance {
    let mt = [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    crate::sh::ShRadiance { coeffs: c }.rotated(&crate::sh::ShRotation::new(4, mt))
}

/// The steps of `bake sky FILE --face-size N` timed one by one (median of `repeat` runs each, in
/// seconds): read and decode, resampling into the cube, sun extraction, sky irradiance, SH,
/// the pack's bytes (sections, compression, checksums) and the file write.
pub fn profile_sky(input: &Path, face_size: u32, repeat: u32, out: &Path) -> Result<Report> {
    // The steps of `sky::bake_sky` after `sky::load_sky` (a Radiance lat-long stays RGBE).
    let input_list = [input.to_path_buf()];
    let (t_decode, src) = time_median(repeat, || sky::load_sky(&input_list))?;
    let (t_cube, full) = time_median(repeat, || Ok(sky::source_to_cube(&src, face_size, 0.0)))?;
    let (t_omega, omega) = time_median(repeat, || Ok(crate::cube::solid_angle_table(face_size)))?;
    let sun_opts = SkyOptions::default().sun;
    // (Each repetition extracts from a fresh copy of the cube; the copy is timed too.)
    let (t_sun, (cube, sun)) = time_median(repeat, || {
        let mut cube = full.clone();
        let sun = sky::sun::extract_sun_in_place(&mut cube, &omega, &sun_opts);
        Ok((cube, sun))
    })?;
    let (t_irr, irr) = time_median(repeat, || Ok(sky::sun::sky_irradiance_with(&cube, &omega)))?;
    let (t_sh, sh) = time_median(repeat, || Ok(crate::sh::project_cube_with(&cube, &omega)))?;
    let bake = sky::SkyBake {
        cube,
        sun,
        sky: irr,
        sh,
    };
    let (t_bytes, bytes) = time_median(repeat, || {
        let mut w = crate::pack::PackWriter::new();
        for s in sky::sky_sections(&bake, "profile") {
            w.insert(s);
        }
        w.to_bytes()
    })?;
    let (t_write, ()) = time_median(repeat, || crate::pack::write_atomic(out, &bytes))?;
    let steps = [
        ("decode", t_decode),
        ("cube", t_cube),
        ("solid_angles", t_omega),
        ("sun", t_sun),
        ("irradiance", t_irr),
        ("sh", t_sh),
        ("pack_bytes", t_bytes),
        ("write", t_write),
    ];
    let total: f64 = steps.iter().map(|s| s.1).sum();
    let mut text = format!(
        "{} → cube {face_size}², {} threads, {} bytes: {:.1} ms in all\n",
        input.display(),
        rayon::current_num_threads(),
        bytes.len(),
        total * 1e3
    );
    for (name, t) in steps {
        text.push_str(&format!("  {name:<11} {:>7.1} ms\n", t * 1e3));
    }
    let seconds: serde_json::Map<String, serde_json::Value> = steps
        .iter()
        .map(|(k, t)| (k.to_string(), json!(t)))
        .collect();
    Ok(Report {
        json: json!({"input": input, "face_size": face_size, "bytes": bytes.len(),
            "threads": rayon::current_num_threads(), "seconds": seconds, "total_seconds": total}),
        text,
    })
}
