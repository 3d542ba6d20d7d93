//! The sky stage: HDR sky images to a float cube map, the sun extracted from it, the sun-free sky
//! projected to spherical harmonics; and a built-in analytic clear sky for scenes without one.
//!
//! ```text
//! .hdr/.exr lat-long | cross | 6 faces ──source_to_cube──▶ CubeMap ──extract_sun──▶ sun-free CubeMap + Sun
//!                                                                        └─project_cube─▶ ShRadiance
//! ```
//!
//! # Input layouts
//! - Lat-long (aspect 2:1): the project's convention (docs/CONVENTIONS.md), Z up.
//! - Cube crosses, horizontal (4:3) or vertical (3:4), and six face files: authored **Y up** in the
//!   GPU face convention (OpenGL table 8.19), as HDRShop, cmgen and most tools write them:
//!
//! ```text
//!  horizontal          vertical
//!      +Y                +Y
//!  −X  +Z  +X  −Z     −X +Z +X
//!      −Y                −Y
//!                        −Z   (turned 180°)
//! ```
//!   A Y-up direction (x', y', z') is the world direction (x, y, z) = (x', −z', y'): Y-up +Y (the
//!   sky) becomes world +Z.
//!
//! `rotate_deg` turns the sky about +Z (counter-clockwise seen from above): what the file shows at
//! azimuth φ ends up at φ + rotate_deg.

pub mod builtin;
pub use crate::cube;
mod resample;
pub mod section;
pub mod source_section;
pub mod stage;
pub mod sun;

use crate::error::{Error, ParseError, Result};
use crate::ingest::rgbe::RgbeImage;
use crate::ingest::skyimage::SkyImage;
use crate::model::FloatImage;
use crate::sh::{self, ShRadiance};
use cube::{CubeMap, Face};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use sun::{SkyIrradiance, Sun, SunOptions};

/// A sky as read from disk, before resampling.
#[derive(Debug, Clone, PartialEq)]
pub enum SkySource {
    /// A lat-long image in the project's convention (Z up).
    LatLong(FloatImage),
    /// The same from a Radiance file, kept as its RGBE quadruples: the resampling decodes the
    /// pixels it reads (to the bits of the float image), so the float image is never built.
    LatLongRgbe(RgbeImage),
    /// Six faces in the GPU face convention, **Y up** (from a cross or face files).
    CubeYUp(CubeMap),
    /// A cube map already in world axes (Z up), e.g. the built-in sky.
    Cube(CubeMap),
}

/// Options of [`bake_sky`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SkyOptions {
    /// Texels per cube face edge; `None` picks one matching the source's resolution.
    pub face_size: Option<u32>,
    /// Turn the sky about +Z, degrees.
    pub rotate_deg: f64,
    pub sun: SunOptions,
}

impl SkyOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: SkyOptions = SkyOptions {
        face_size: None,
        rotate_deg: 0.0,
        sun: SunOptions::DEFAULT,
    };
}

impl Default for SkyOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What the sky stage produces.
#[derive(Debug, Clone, PartialEq)]
pub struct SkyBake {
    /// The sky without the sun, world axes.
    pub cube: CubeMap,
    pub sun: Sun,
    /// Irradiance of the sun-free sky.
    pub sky: SkyIrradiance,
    /// The sun-free sky projected to order 4.
    pub sh: ShRadiance,
}

/// Largest face size accepted.
pub const MAX_FACE_SIZE: u32 = 4096;

/// Reads a sky: one image (lat-long or cross, told apart by the aspect ratio) or six face files
/// in the order +X, −X, +Y, −Y, +Z, −Z.
pub fn load_sky(paths: &[PathBuf]) -> Result<SkySource> {
    match paths {
        [one] => {
            let img = crate::ingest::skyimage::load_keeping_rgbe(one)?;
            match img {
                SkyImage::Rgbe(img) if img.width == 2 * img.height => {
                    Ok(SkySource::LatLongRgbe(img))
                }
                img => image_to_source(img.into_float()).map_err(|e| Error::invalid(one, e)),
            }
        }
        [..] if paths.len() == 6 => {
            let mut faces = Vec::with_capacity(6);
            for p in paths {
                faces.push((p.as_path(), crate::ingest::skyimage::load(p)?));
            }
            faces_to_source(&faces)
        }
        _ => Err(Error::usage(format!(
            "a sky is one image (lat-long or cube cross) or six face files, got {} files",
            paths.len()
        ))),
    }
}

/// Tells the layout of one image by its aspect ratio.
pub fn image_to_source(img: FloatImage) -> Result<SkySource, ParseError> {
    let (w, h) = (img.width, img.height);
    if w == 2 * h {
        Ok(SkySource::LatLong(img))
    } else if 3 * w == 4 * h {
        Ok(SkySource::CubeYUp(cross_to_cube(&img, false)))
    } else if 4 * w == 3 * h {
        Ok(SkySource::CubeYUp(cross_to_cube(&img, true)))
    } else {
        Err(ParseError::new(
            "image size",
            format!(
                "{w}×{h}: expected a lat-long image (2:1), a horizontal cube cross (4:3) or a vertical cross (3:4)"
            ),
        ))
    }
}

/// Cuts a cube cross (horizontal 4×3 or vertical 3×4 faces) into a Y-up cube map.
pub fn cross_to_cube(img: &FloatImage, vertical: bool) -> CubeMap {
    let n = if vertical {
        img.width / 3
    } else {
        img.width / 4
    };
    // (face, cell column, cell row, turned 180°)
    let cells: [(Face, u32, u32, bool); 6] = if vertical {
        [
            (Face::PosX, 2, 1, false),
            (Face::NegX, 0, 1, false),
            (Face::PosY, 1, 0, false),
            (Face::NegY, 1, 2, false),
            (Face::PosZ, 1, 1, false),
            (Face::NegZ, 1, 3, true),
        ]
    } else {
        [
            (Face::PosX, 2, 1, false),
            (Face::NegX, 0, 1, false),
            (Face::PosY, 1, 0, false),
            (Face::NegY, 1, 2, false),
            (Face::PosZ, 1, 1, false),
            (Face::NegZ, 3, 1, false),
        ]
    };
    let mut cube = CubeMap::filled(n, [0.0; 3]);
    for (face, cx, cy, turned) in cells {
        for row in 0..n {
            for col in 0..n {
                let (c, r) = if turned {
                    (n - 1 - col, n - 1 - row)
                } else {
                    (col, row)
                };
                let src = ((cy * n + r) * img.width + cx * n + c) as usize;
                let dst = cube.index(face, col, row);
                cube.texels[dst] = img.pixels[src];
            }
        }
    }
    cube
}

/// Six square face images of equal size into a Y-up cube map.
fn faces_to_source(faces: &[(&Path, FloatImage)]) -> Result<SkySource> {
    let n = faces[0].1.width;
    let mut cube = CubeMap::filled(n, [0.0; 3]);
    for (k, (path, img)) in faces.iter().enumerate() {
        if img.width != n || img.height != n {
            return Err(Error::invalid_at(
                path,
                "image size",
                format!(
                    "face {} is {}×{}; every face must be square and {n}×{n} like the first",
                    Face::ALL[k].name(),
                    img.width,
                    img.height
                ),
            ));
        }
        let len = (n * n) as usize;
        cube.texels[k * len..(k + 1) * len].copy_from_slice(&img.pixels);
    }
    Ok(SkySource::CubeYUp(cube))
}

/// A face size matching the source's resolution (a lat-long W wide has W/4 texels per 90°).
pub fn default_face_size(src: &SkySource) -> u32 {
    match src {
        SkySource::LatLong(FloatImage { width, .. })
        | SkySource::LatLongRgbe(RgbeImage { width, .. }) => (width / 4).clamp(1, 1024),
        SkySource::CubeYUp(c) | SkySource::Cube(c) => c.size,
    }
}

/// Reads the source in a world direction (Z up, need not be normalized), bilinear.
fn sample_source(src: &SkySource, d: [f64; 3]) -> [f32; 3] {
    match src {
        SkySource::LatLong(img) => {
            let (x, y) = cube::latlong_coords_fast(d, img.width, img.height);
            cube::sample_latlong(img, x, y)
        }
        SkySource::LatLongRgbe(img) => {
            let (x, y) = cube::latlong_coords_fast(d, img.width, img.height);
            cube::sample_latlong(img, x, y)
        }
        SkySource::CubeYUp(c) => c.sample([d[0], d[2], -d[1]]),
        SkySource::Cube(c) => c.sample(d),
    }
}

/// Source pixels per cube texel edge at a face's centre.
fn source_per_texel(src: &SkySource, face_size: u32) -> f64 {
    let source_texels_per_face = match src {
        SkySource::LatLong(FloatImage { width, .. })
        | SkySource::LatLongRgbe(RgbeImage { width, .. }) => *width as f64 / 4.0,
        SkySource::CubeYUp(c) | SkySource::Cube(c) => c.size as f64,
    };
    source_texels_per_face / face_size as f64
}

/// Subsamples per texel edge so that subsamples are no farther apart than source pixels.
fn supersampling(src: &SkySource, face_size: u32) -> u32 {
    (source_per_texel(src, face_size).ceil() as u32).clamp(1, 8)
}

/// Subsamples per texel edge where the source has contrast within the texel: a quarter of a
/// source pixel apart. At one sample per source pixel a small bright feature (the sun, a few
/// pixels wide) is point-sampled, and its energy in the cube came out −5 … +15 % off on a
/// 2048-wide lat-long (see `tests::sun_irradiance_survives_resampling`).
fn fine_supersampling(src: &SkySource, face_size: u32) -> u32 {
    ((4.0 * source_per_texel(src, face_size)).ceil() as u32)
        .clamp(supersampling(src, face_size), 16)
}

/// A texel is resampled with [`fine_supersampling`] where its samples and corners differ by
/// more than this factor in luminance …
const CONTRAST_REFINE: f32 = 1.05;
/// … and its brightest one is this many times the sky's median (the sun and its edge: the
/// sun is ~10⁵ times the sky; ordinary sky detail keeps the cheap sampling).
const HOT_REFINE: f32 = 8.0;

/// Median luminance of the source over a 128 × 64 lat-long grid of directions.
fn coarse_median_luminance(src: &SkySource) -> f32 {
    let (w, h) = (128, 64);
    let mut lum: Vec<f32> = (0..w * h)
        .map(|i| {
            let d = cube::latlong_direction((i % w) as f64 + 0.5, (i / w) as f64 + 0.5, w, h);
            sun::luminance(sample_source(src, d))
        })
        .collect();
    let mid = lum.len() / 2;
    *lum.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Resamples a sky into a world-axis cube map: each texel is the solid-angle-weighted mean of
/// `k × k` bilinear samples of the source, with k chosen so no source pixel is skipped (an area
/// average when downsampling, bilinear when upsampling). A bright texel (over [`HOT_REFINE`]×
/// the median sky) whose samples and corners differ by more than [`CONTRAST_REFINE`]× (in and
/// around the sun) is averaged again over 4× finer samples, so the energy of features a few
/// source pixels wide is kept: within 0.1 % for the true-size sun on a 2048-wide lat-long,
/// against −5 … +15 % with one point sample per texel. Tiles of texels are the units of work
/// (`resample`); a lat-long source shares its angle tables between faces there.
pub fn source_to_cube(src: &SkySource, face_size: u32, rotate_deg: f64) -> CubeMap {
    resample_to_cube(src, face_size, rotate_deg, true)
}

/// [`source_to_cube`]; `skip_cold`: tiles of a lat-long source that read only rows darker than
/// the refinement threshold skip the refinement test (`resample::ColdRows`; the same cube, as
/// `tests::skipping_cold_tiles_changes_no_texel` checks).
fn resample_to_cube(src: &SkySource, face_size: u32, rotate_deg: f64, skip_cold: bool) -> CubeMap {
    let params = resample::TileParams {
        n: face_size as usize,
        k: supersampling(src, face_size) as usize,
        k_fine: fine_supersampling(src, face_size) as usize,
        hot: HOT_REFINE * coarse_median_luminance(src),
        contrast: CONTRAST_REFINE,
    };
    let n = params.n;
    let (s_rot, c_rot) = (-rotate_deg.to_radians()).sin_cos();
    // The source is read where the rotation came from: R_z(−angle)·d.
    let read = move |face: Face, s: f64, t: f64| {
        let d = face.direction(s, t);
        let d = [
            c_rot * d[0] - s_rot * d[1],
            s_rot * d[0] + c_rot * d[1],
            d[2],
        ];
        sample_source(src, d)
    };
    // The solid-angle-weighted mean of k × k samples of texel (col, row), sample by sample.
    let fine = move |face: Face, col: usize, row: usize, k: usize| {
        let mut acc = [0.0f64; 3];
        let mut wsum = 0.0;
        for a in 0..k {
            for b in 0..k {
                let s = 2.0 * (col as f64 + (a as f64 + 0.5) / k as f64) / n as f64 - 1.0;
                let t = 2.0 * (row as f64 + (b as f64 + 0.5) / k as f64) / n as f64 - 1.0;
                let w = cube::solid_angle_density(s, t);
                let v = read(face, s, t);
                for c in 0..3 {
                    acc[c] += w * v[c] as f64;
                }
                wsum += w;
            }
        }
        acc.map(|v| (v / wsum) as f32)
    };
    let grids = resample::LatLongGrids::new(n, params.k);
    let generic = resample::Generic {
        read: &read,
        grids: &grids,
    };
    let rot = rotate_deg.to_radians();
    // (Written in place by the units: a fresh buffer is zeroed by the kernel, page by page, in
    // the threads that first write it.)
    let mut texels = vec![[0.0f32; 3]; 6 * n * n];
    let out = texels.as_mut_slice();
    match src {
        SkySource::LatLong(img) => {
            resample::latlong_units(&params, img, &grids, (rot, skip_cold), &fine, out)
        }
        SkySource::LatLongRgbe(img) => {
            resample::latlong_units(&params, &img.view(), &grids, (rot, skip_cold), &fine, out)
        }
        SkySource::CubeYUp(_) | SkySource::Cube(_) => {
            resample::units(out, &params, |_| generic, &fine)
        }
    }
    CubeMap {
        size: face_size,
        texels,
    }
}

/// Resamples a world-axis cube map to a lat-long image (bilinear, seamless across faces).
pub fn cube_to_latlong(cube: &CubeMap, width: u32, height: u32) -> FloatImage {
    let pixels = (0..height)
        .into_par_iter()
        .flat_map_iter(|row| {
            (0..width).map(move |col| {
                let d = cube::latlong_direction(col as f64 + 0.5, row as f64 + 0.5, width, height);
                cube.sample(d)
            })
        })
        .collect();
    FloatImage {
        width,
        height,
        pixels,
    }
}

/// The sky stage: resample to a cube map, extract the sun, measure the sky, project to SH.
pub fn bake_sky(src: &SkySource, opts: &SkyOptions) -> Result<SkyBake> {
    let size = opts.face_size.unwrap_or_else(|| default_face_size(src));
    if size == 0 || size > MAX_FACE_SIZE {
        return Err(Error::usage(format!(
            "face size {size}: expected 1 to {MAX_FACE_SIZE}"
        )));
    }
    if !(opts.sun.enlargement.is_finite() && opts.sun.enlargement > 0.0) {
        return Err(Error::usage(format!(
            "sun scale {}: expected a positive number",
            opts.sun.enlargement
        )));
    }
    // One table of exact texel solid angles serves the three sums over texels below.
    let (mut cube, omega) = rayon::join(
        || source_to_cube(src, size, opts.rotate_deg),
        || cube::solid_angle_table(size),
    );
    // The sun goes first: SH of a sky with its sun would ring (seed 000, 4.3).
    let sun = sun::extract_sun_in_place(&mut cube, &omega, &opts.sun);
    let (sky, sh) = rayon::join(
        || sun::sky_irradiance_with(&cube, &omega),
        || sh::project_cube_with(&cube, &omega),
    );
    Ok(SkyBake { cube, sun, sky, sh })
}

/// Names of the sections the sky stage writes.
pub const SKY_SECTION: &str = "sky";
pub const SUN_SECTION: &str = "sun";
pub const SH_SECTION: &str = "sh";

/// The pack sections of a baked sky: the sun-free cube map (`sky`), the sun (`sun`) and the
/// sun-free sky's SH (`sh`).
pub fn sky_sections(b: &SkyBake, source: &str) -> Vec<crate::pack::Section> {
    vec![
        section::cube_to_section(SKY_SECTION, source, &b.cube, &b.sky),
        section::sun_to_section(SUN_SECTION, &b.sun),
        section::sh_to_section(SH_SECTION, "sky radiance without the sun", &b.sh),
    ]
}

/// The sky sections of a scene: its sky if it has one, else the built-in clear sky, so every
/// scene bakes (for `graph::build`).
pub fn scene_sky_sections(
    sky: Option<&FloatImage>,
    builtin: &builtin::BuiltinSky,
    opts: &SkyOptions,
) -> Result<Vec<crate::pack::Section>> {
    let (src, name) = match sky {
        Some(img) => (
            image_to_source(img.clone()).map_err(|e| Error::invalid("sky", e))?,
            "scene sky",
        ),
        None => (
            SkySource::Cube(builtin::builtin_sky(builtin)),
            "builtin:preetham",
        ),
    };
    Ok(sky_sections(&bake_sky(&src, opts)?, name))
}

#[cfg(test)]
mod tests;
