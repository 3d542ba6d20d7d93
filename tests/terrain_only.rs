//! A scene of a terrain alone (no instance line in its ECO file) through the default pipeline and
//! `bake render` (issue 35, items 3 and 7): it bakes, it renders, and no texel of its light map
//! is black under a sky that is black below the horizon. The terrain is rough (random heights on every sample), so about half of its cells
//! are concave, where the bilinear height lies below the two triangles that are drawn and traced:
//! a light-map sample taken at the bilinear height started under the surface and came out black.

mod common;
use common::bake;

const N: u32 = 129;
const EXTENT: f32 = 64.0;
const SCALE: f32 = 0.01;

/// 16-bit RAW heights: a gentle hill plus ±0.25 m of hashed noise on every sample.
fn rough_raw() -> Vec<u8> {
    let mut out = Vec::with_capacity((N * N * 2) as usize);
    for j in 0..N {
        for i in 0..N {
            let (x, y) = (i as f32 / N as f32, j as f32 / N as f32);
            let hill = 3.0 * (x * 3.1).sin() * (y * 2.3).cos() + 4.0;
            let h = bake::rng::mix64(((j as u64) << 32) | i as u64);
            let noise = ((h >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.5;
            let s = ((hill + noise) / SCALE).round() as u16;
            out.extend_from_slice(&s.to_le_bytes());
        }
    }
    out
}

/// A lat-long sky of uniform radiance 1 above the horizon and 0 below (no sun): a texel whose
/// sample point lay under the surface saw only the underside of the terrain, lit by the black
/// lower sky, and came out black.
fn write_sky(path: &std::path::Path) {
    let (w, h) = (64usize, 32usize);
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|k| image::Rgb([if k / w < h / 2 { 1.0 } else { 0.0 }; 3]))
        .collect();
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    image::codecs::hdr::HdrEncoder::new(f)
        .encode(&px, w, h)
        .unwrap();
}

fn write_scene(dir: &std::path::Path) -> std::path::PathBuf {
    write_sky(&dir.join("sky.hdr"));
    std::fs::write(dir.join("terrain.raw"), rough_raw()).unwrap();
    let eco = format!(
        "terrain.raw {N} {N} 1 {SCALE}\n<GEOREF> 0 0 {EXTENT} {EXTENT} 0 0 {EXTENT} {EXTENT}\n\
         <ECO>\n<TILING> 0\n<LAYER> 1\n"
    );
    let p = dir.join("scene.eco");
    std::fs::write(&p, eco).unwrap();
    p
}

#[test]
fn a_terrain_only_scene_bakes_renders_and_has_no_black_light_map_texel() {
    let dir = tempfile::tempdir().unwrap();
    let eco = write_scene(dir.path());
    let pack = dir.path().join("scene.bake");
    let (eco_s, pack_s) = (eco.to_str().unwrap(), pack.to_str().unwrap());
    let sky = dir.path().join("sky.hdr");
    let o = bake(&[
        eco_s,
        "--sky",
        sky.to_str().unwrap(),
        "-o",
        pack_s,
        "--no-cache",
        "--quiet",
    ]);
    assert!(
        o.status.success(),
        "bake failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );

    // The light map: every texel of an unoccluded rough terrain under an open sky sees some sky.
    let p = bake::pack::Pack::open(&pack).unwrap();
    let e = p
        .of_kind(bake::lightmap::section::KIND)
        .find(|e| e.name.contains("terrain"))
        .expect("a terrain light map");
    let (meta, map) = bake::lightmap::section::from_section(&p.view(e).unwrap()).unwrap();
    let lum: Vec<f32> = map
        .texels
        .iter()
        .map(|t| 0.2126 * t[0] + 0.7152 * t[1] + 0.0722 * t[2])
        .collect();
    let mut sorted = lum.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!(median > 0.0, "median texel {median}");
    let black = lum.iter().filter(|&&l| l < 0.01 * median).count();
    assert_eq!(
        black,
        0,
        "{black} of {} texels ({}×{}) below 1 % of the median {median}",
        lum.len(),
        meta.width,
        meta.height
    );

    // It renders (it used to stop at "clusters: 0 instances").
    let png = dir.path().join("view.png");
    let o = bake(&[
        "render",
        pack_s,
        "-o",
        png.to_str().unwrap(),
        "--width",
        "64",
        "--height",
        "48",
        "--quiet",
    ]);
    assert!(
        o.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let img = image::open(&png).unwrap().to_rgba8();
    assert_eq!((img.width(), img.height()), (64, 48));
    let lit = img.pixels().filter(|p| p[0] > 10 || p[1] > 10).count();
    assert!(lit > 64 * 48 / 4, "only {lit} lit pixels");
}
