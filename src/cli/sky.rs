//! `bake sky [INPUT...]`: an HDR sky (lat-long, cube cross or six faces; .hdr or .exr), or the
//! built-in clear sky, to a float cube map, the extracted sun and the sky's SH, written to a pack.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::pack::{Pack, PackWriter};
use crate::sky::builtin::BuiltinSky;
use crate::sky::sun::SunOptions;
use crate::sky::{self, SkyBake, SkyOptions, SkySource};
use serde_json::{Value, json};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct SkyArgs {
    /// A lat-long (2:1) or cube-cross (4:3, 3:4) .hdr/.exr image, or six face files in the order
    /// +X −X +Y −Y +Z −Z (crosses and faces Y up). None: the built-in clear sky.
    pub inputs: Vec<PathBuf>,
    /// Output pack (default: <input stem>.bake beside the input, or sky.bake). An existing pack is
    /// updated: its sky, sun and sh sections are replaced, the rest is kept.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Texels per cube face edge (default: a quarter of a lat-long's width, max 1024).
    #[arg(long)]
    pub face_size: Option<u32>,
    /// Enlargement of the sun's area π r² for extraction (the thesis' 4.0).
    #[arg(long, default_value_t = sky::sun::DEFAULT_ENLARGEMENT)]
    pub sun_scale: f64,
    /// Turn the sky about +Z by DEG (counter-clockwise from above), for skies shot with another north.
    #[arg(
        long,
        value_name = "DEG",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub rotate: f64,
    /// Only project the input to SH (with the sun, no cube, no pack) and report it, like
    /// `cmgen --sh=4`; the input must be a lat-long image.
    #[arg(long)]
    pub sh_only: bool,
    /// Built-in sky: sun elevation in degrees (0..90).
    #[arg(long, default_value_t = 40.0)]
    pub sun_elevation: f64,
    /// Built-in sky: sun azimuth in degrees, counter-clockwise from +X (east).
    #[arg(long, default_value_t = 225.0, allow_negative_numbers = true)]
    pub sun_azimuth: f64,
    /// Built-in sky: atmospheric turbidity (2 clear .. 10 hazy).
    #[arg(long, default_value_t = 3.0)]
    pub turbidity: f64,
}

/// Resolves the built-in sky's parameters, rejecting values outside the model's range.
fn builtin_params(a: &SkyArgs) -> Result<BuiltinSky> {
    if !(0.0..=90.0).contains(&a.sun_elevation) {
        return Err(Error::usage(format!(
            "--sun-elevation {}: expected 0 to 90 degrees",
            a.sun_elevation
        )));
    }
    if !(1.7..=10.0).contains(&a.turbidity) {
        return Err(Error::usage(format!(
            "--turbidity {}: expected 1.7 to 10 (Preetham's fits)",
            a.turbidity
        )));
    }
    Ok(BuiltinSky {
        sun_elevation_deg: a.sun_elevation,
        sun_azimuth_deg: a.sun_azimuth,
        turbidity: a.turbidity,
        face_size: a.face_size.unwrap_or(256),
        ..BuiltinSky::default()
    })
}

pub fn run(args: &SkyArgs, g: &Global) -> Result<Outcome> {
    if args.sh_only {
        return sh_only(args, g);
    }
    let (src, source_name) = if args.inputs.is_empty() {
        let p = builtin_params(args)?;
        let name = format!(
            "builtin:preetham elevation={} azimuth={} turbidity={}",
            p.sun_elevation_deg, p.sun_azimuth_deg, p.turbidity
        );
        (SkySource::Cube(sky::builtin::builtin_sky(&p)), name)
    } else {
        let names: Vec<_> = args
            .inputs
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        (sky::load_sky(&args.inputs)?, names.join(" "))
    };
    let opts = SkyOptions {
        face_size: args.face_size,
        rotate_deg: args.rotate,
        sun: SunOptions {
            enlargement: args.sun_scale,
        },
    };
    let bake = sky::bake_sky(&src, &opts)?;
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| match args.inputs.first() {
            Some(p) => p.with_extension("bake"),
            None => PathBuf::from("sky.bake"),
        });
    let w = if output.exists() {
        PackWriter::from_pack(&Pack::open(&output)?)
    } else {
        PackWriter::new()
    };
    let bytes = super::write_pack(w, sky::sky_sections(&bake, &source_name), &output)?;
    let mut json = report_json(&bake);
    json["output"] = json!(output);
    json["bytes"] = json!(bytes.len());
    Ok(Outcome {
        text: report_text(&bake, &output),
        json,
        warnings: warnings(&bake),
    })
}

/// `--sh-only`: the SH of a lat-long input as it is (sun included), exact solid angles.
fn sh_only(args: &SkyArgs, _g: &Global) -> Result<Outcome> {
    let [input] = args.inputs.as_slice() else {
        return Err(Error::usage("--sh-only takes exactly one lat-long image"));
    };
    let img = crate::ingest::skyimage::load(input)?;
    let img = match sky::image_to_source(img).map_err(|e| Error::invalid(input, e))? {
        SkySource::LatLong(img) => img,
        _ => return Err(Error::usage("--sh-only takes a lat-long (2:1) image")),
    };
    let sh = crate::sh::project_latlong(&img);
    let sh = sh.rotated_z(args.rotate.to_radians());
    let text = sh
        .coeffs
        .iter()
        .map(|c| format!("{:.6} {:.6} {:.6}\n", c[0], c[1], c[2]))
        .collect();
    Ok(Outcome {
        json: json!({"sh": {"order": crate::sh::ORDER, "coefficients": sh.coeffs}}),
        text,
        warnings: Vec::new(),
    })
}

/// The `--json` document (stable keys: sun, sky, sh, cube).
pub fn report_json(b: &SkyBake) -> Value {
    let s = &b.sun;
    json!({
        "sun": {
            "direction": s.direction, "direction_brightest": s.direction_brightest,
            "irradiance": s.irradiance, "irradiance_thesis": s.irradiance_thesis,
            "texels": s.texels, "solid_angle": s.solid_angle, "replacement": s.replacement,
            "clipped": s.clipped, "plateau_texels": s.plateau_texels,
            "enlargement": s.enlargement, "angular_radius": s.angular_radius,
        },
        "sky": {"irradiance_horizontal": b.sky.horizontal, "I_H_thesis": b.sky.thesis},
        "sh": {"order": crate::sh::ORDER, "coefficients": b.sh.coeffs},
        "cube": {"face_size": b.cube.size, "faces": 6},
    })
}

fn report_text(b: &SkyBake, output: &std::path::Path) -> String {
    let s = &b.sun;
    let f = |v: [f32; 3]| format!("({:.4}, {:.4}, {:.4})", v[0], v[1], v[2]);
    format!(
        "{}: cube {}² × 6\n  sun direction {}, irradiance {} (thesis eq. 3.2: {}), {} texels{}\n  sky irradiance on the ground {} (thesis eq. 3.3: {})\n",
        output.display(),
        b.cube.size,
        f(s.direction),
        f(s.irradiance),
        f(s.irradiance_thesis),
        s.texels,
        if s.clipped { ", CLIPPED" } else { "" },
        f(b.sky.horizontal),
        f(b.sky.thesis),
    )
}

fn warnings(b: &SkyBake) -> Vec<String> {
    let mut w = Vec::new();
    if b.sun.clipped {
        w.push(format!(
            "the sun looks clipped ({} texels at the maximum): its irradiance is a lower bound",
            b.sun.plateau_texels
        ));
    }
    let big = b.cube.texels.iter().flatten().any(|v| v.abs() > 65504.0);
    if big {
        w.push("sky radiance above 65504 was clamped to the half-float range".into());
    }
    w
}

/// `bake bench sky`: the sky stage's timings, and its SH accuracy against the exact projection.
#[derive(Debug, Clone, clap::Args)]
pub struct SkyBenchArgs {
    /// A lat-long .hdr/.exr sky.
    pub input: PathBuf,
    /// Repetitions of each timed step (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeat: u32,
    /// Instead of benchmarking, write the built-in sky as a W×H lat-long .hdr to INPUT.
    #[arg(long, value_parser = super::parse_size, value_name = "WxH")]
    pub write_sample: Option<(u32, u32)>,
    /// cmgen's `--sh-output` text file for the same input, compared after aligning conventions.
    #[arg(long)]
    pub cmgen_sh: Option<PathBuf>,
}

/// Median wall time of `repeat` runs of `f`, in seconds.
fn time_median<T>(repeat: u32, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t = std::time::Instant::now();
        last = Some(f()?);
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    Ok((times[times.len() / 2], last.expect("at least one run")))
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

pub fn bench(a: &SkyBenchArgs, _g: &Global) -> Result<Outcome> {
    if let Some((w, h)) = a.write_sample {
        // Sun off the diagonals, so the x and y axes are told apart in comparisons.
        let params = BuiltinSky {
            sun_elevation_deg: 35.0,
            sun_azimuth_deg: 160.0,
            ..BuiltinSky::default()
        };
        let img = sky::builtin::builtin_sky_latlong(&params, w, h);
        crate::pack::write_atomic(&a.input, &crate::ingest::skyimage::write_hdr(&img))?;
        return Ok(Outcome {
            json: json!({"written": a.input, "width": w, "height": h}),
            text: format!("{}: built-in sky, {w}×{h}\n", a.input.display()),
            warnings: Vec::new(),
        });
    }
    let (t_decode, img) = time_median(a.repeat, || crate::ingest::skyimage::load(&a.input))?;
    let (t_sh, sh) = time_median(a.repeat, || Ok(crate::sh::project_latlong(&img)))?;
    let src = sky::image_to_source(img.clone()).map_err(|e| Error::invalid(&a.input, e))?;
    let (t_bake, bake) = time_median(a.repeat, || sky::bake_sky(&src, &SkyOptions::default()))?;
    let exact = crate::sh::project_latlong_exact(&img);
    let full_cube = sky::source_to_cube(&src, bake.cube.size, 0.0);
    let cube_sh = crate::sh::project_cube(&full_cube);
    let mut json = json!({
        "input": a.input, "width": img.width, "height": img.height, "threads": rayon::current_num_threads(),
        "seconds": {"decode": t_decode, "sh_latlong": t_sh, "bake_sky": t_bake},
        "sh_error_vs_exact": {"latlong": sh_error(&sh, &exact), "cube": sh_error(&cube_sh, &exact)},
        "face_size": bake.cube.size,
        "sh_exact": exact.coeffs, "sh_latlong": sh.coeffs,
    });
    let mut text = format!(
        "{} ({}×{}, {} threads): decode {:.1} ms, SH from lat-long {:.1} ms, bake sky (cube {}, sun, SH) {:.1} ms\n  SH error vs exact pixel integrals (max |Δ|/|L00|): lat-long {:.2e}, cube {:.2e}\n",
        a.input.display(),
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
    if let Some(path) = &a.cmgen_sh {
        let theirs = read_cmgen_sh(path)?;
        let err = sh_error(&theirs, &exact);
        json["sh_error_vs_exact"]["cmgen"] = json!(err);
        json["sh_cmgen_aligned"] = json!(theirs.coeffs);
        text.push_str(&format!("  cmgen (aligned): {err:.2e}\n"));
    }
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
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
