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
pub(crate) struct SkyArgs {
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

pub(crate) fn run(args: &SkyArgs, g: &Global) -> Result<Outcome> {
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
        // Named relative to the first input's folder (docs/FORMAT.md, "Source names").
        let roots = crate::ingest::confine::SourceNames::around(&args.inputs[0]);
        let names: Vec<_> = args.inputs.iter().map(|p| roots.name(p)).collect();
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
pub(crate) fn report_json(b: &SkyBake) -> Value {
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

fn warnings(b: &SkyBake) -> Vec<crate::diag::Warning> {
    let mut w = Vec::new();
    if b.sun.clipped {
        w.push(crate::diag::Warning::new(
            &crate::sky::stage::SKY_SUN_CLIPPED,
            "",
            format!(
                "the sun looks clipped ({} texels at the maximum): its irradiance is a lower bound",
                b.sun.plateau_texels
            ),
        ));
    }
    let big = b.cube.texels.iter().flatten().any(|v| v.abs() > 65504.0);
    if big {
        w.push(crate::diag::Warning::new(
            &crate::sky::stage::SKY_RADIANCE_CLAMPED,
            "",
            "sky radiance above 65504 was clamped to the half-float range",
        ));
    }
    w
}

/// `bake bench sky`: the sky stage's timings, and its SH accuracy against the exact projection.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct SkyBenchArgs {
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
    /// Instead, time the steps of `bake sky INPUT --face-size N` one by one (pack written to
    /// INPUT with the extension .profile.bake).
    #[arg(long, value_name = "N")]
    pub profile: Option<u32>,
}

pub(crate) fn bench(a: &SkyBenchArgs, _g: &Global) -> Result<Outcome> {
    let r = match a.write_sample {
        Some((w, h)) => crate::bench::sky::write_sample(&a.input, w, h)?,
        None if a.profile.is_some() => {
            let n = a.profile.unwrap_or(256).clamp(1, crate::sky::MAX_FACE_SIZE);
            let out = a.input.with_extension("profile.bake");
            crate::bench::sky::profile_sky(&a.input, n, a.repeat, &out)?
        }
        None => crate::bench::sky::bench_sky(&a.input, a.repeat, a.cmgen_sh.as_deref())?,
    };
    Ok(r.into())
}
