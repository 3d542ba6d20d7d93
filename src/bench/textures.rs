//! `bake bench textures`: texture processing throughput (decode, linearize, mips with coverage,
//! height and normal maps, section encoding), in MB/s of source RGBA8 texels.

use super::Report;
use crate::error::{Error, Result};
use crate::texture::{TextureOptions, TextureRole, process_texture};
use std::time::Instant;

/// A generated leaf-like texture: alpha-tested leaf shapes with veins and noise, as PNG bytes.
pub fn generated_png(size: u32) -> Result<Vec<u8>> {
    let mut rng = crate::rng::Rng::new(31);
    let s = size as f32;
    let mut img = image::RgbaImage::new(size, size);
    for (x, y, p) in img.enumerate_pixels_mut() {
        let (u, v) = (
            2.0 * (x as f32 + 0.5) / s - 1.0,
            2.0 * (y as f32 + 0.5) / s - 1.0,
        );
        let t = (v / 0.9).clamp(-1.0, 1.0);
        let half = 0.42 * (1.0 - t * t).powf(0.8) * (1.0 + 0.08 * (t * 40.0).sin());
        let a = ((half - u.abs()) * s / 2.0 + 0.5).clamp(0.0, 1.0);
        let vein = if u.abs() < 0.01 || ((u.abs() - 0.3 * (v + 1.0)).abs() < 0.01) {
            60.0
        } else {
            0.0
        };
        let n = rng.f32() * 30.0;
        *p = image::Rgba([
            (40.0 + n) as u8,
            (120.0 + n + vein) as u8,
            (30.0 + n) as u8,
            (a * 255.0) as u8,
        ]);
    }
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| Error::runtime(format!("encoding the generated texture: {e}")))?;
    Ok(out.into_inner())
}

/// Runs the benchmark over `files`, or a generated `size`² texture when there are none, each
/// `repeat` times.
pub fn bench_textures(files: &[std::path::PathBuf], size: u32, repeat: u32) -> Result<Report> {
    let mut inputs: Vec<(String, Vec<u8>)> = Vec::new();
    for f in files {
        inputs.push((f.display().to_string(), crate::error::read_file(f)?));
    }
    if inputs.is_empty() {
        inputs.push((
            format!("generated {0}×{0} leaf (PNG)", size),
            generated_png(size)?,
        ));
    }
    let (mut rows, mut text) = (Vec::new(), String::new());
    for (name, bytes) in &inputs {
        let reps = repeat.max(1);
        let (mut t_decode, mut t_process, mut t_encode) = (0.0, 0.0, 0.0);
        let mut texels = 0u64;
        for _ in 0..reps {
            let t0 = Instant::now();
            let img = crate::ingest::texture::decode(bytes).map_err(|e| Error::invalid(name, e))?;
            let t1 = Instant::now();
            let p = process_texture(
                &img,
                TextureRole::Color,
                &TextureOptions::for_size(img.width, img.height),
            );
            let t2 = Instant::now();
            let s = crate::texture::section::to_section("texture:bench", name, &img, &p);
            let t3 = Instant::now();
            std::hint::black_box(s);
            t_decode += (t1 - t0).as_secs_f64();
            t_process += (t2 - t1).as_secs_f64();
            t_encode += (t3 - t2).as_secs_f64();
            texels = img.pixels.len() as u64;
        }
        let r = reps as f64;
        let (td, tp, te) = (t_decode / r, t_process / r, t_encode / r);
        let mb = texels as f64 * 4.0 / 1e6;
        let mbps = mb / (td + tp + te);
        text.push_str(&format!(
            "{name}: {texels} texels ({mb:.1} MB RGBA8): decode {:.1} ms, process {:.1} ms, encode {:.1} ms; {mbps:.1} MB/s ({:.1} MB/s without decode)\n",
            td * 1e3, tp * 1e3, te * 1e3, mb / (tp + te)
        ));
        rows.push(serde_json::json!({"input": name, "texels": texels, "decode_seconds": td, "process_seconds": tp,
            "encode_seconds": te, "mb_per_second": mbps, "threads": rayon::current_num_threads()}));
    }
    Ok(Report {
        json: serde_json::json!({"textures": rows}),
        text,
    })
}
