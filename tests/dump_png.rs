//! `bake dump PACK --png DIR` (issue 16, item 6): every image-like section of the fixture's
//! pack is written, every file decodes, and the files hold the sections' values: the leaf
//! texture's level 0 is the source SGI file's pixels again, the EXR files are the light map's
//! and the sky cube's texels exactly, the terrain heights map linearly onto 16 bits, north up.

mod common;

use bake::pack::Pack;
use std::path::Path;

fn read_exr(path: &Path) -> (usize, usize, Vec<[f32; 3]>) {
    use exr::prelude::*;
    let img = read_first_rgba_layer_from_file(
        path,
        |res, _| {
            (
                res.width(),
                res.height(),
                vec![[0f32; 3]; res.width() * res.height()],
            )
        },
        |(w, _, px), p, (r, g, b, _a): (f32, f32, f32, f32)| px[p.y() * *w + p.x()] = [r, g, b],
    )
    .unwrap();
    img.layer_data.channel_data.pixels
}

#[test]
fn dump_png_writes_every_image_section_with_its_values() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    common::json(&common::bake(&[
        "fixtures",
        scene.to_str().unwrap(),
        "--json",
    ]));
    let pack_path = dir.path().join("scene.bake");
    common::json(&common::bake(&[
        scene.join("scene.eco").to_str().unwrap(),
        "--preview",
        "--no-cache",
        "-o",
        pack_path.to_str().unwrap(),
        "--json",
        "--quiet",
    ]));
    let out = dir.path().join("png");
    let doc = common::json(&common::bake(&[
        "dump",
        pack_path.to_str().unwrap(),
        "--png",
        out.to_str().unwrap(),
        "--json",
    ]));
    let files = doc["png"].as_array().unwrap();
    let names: Vec<&str> = files
        .iter()
        .map(|f| {
            Path::new(f["file"].as_str().unwrap())
                .file_name()
                .unwrap()
                .to_str()
                .unwrap()
        })
        .collect();
    // Every listed file exists and decodes at its listed size.
    for f in files {
        let path = Path::new(f["file"].as_str().unwrap());
        let (w, h) = (f["width"].as_u64().unwrap(), f["height"].as_u64().unwrap());
        if path.extension().unwrap() == "png" {
            let img = image::open(path).unwrap();
            assert_eq!(
                (img.width() as u64, img.height() as u64),
                (w, h),
                "{path:?}"
            );
        } else {
            let (ew, eh, _) = read_exr(path);
            assert_eq!((ew as u64, eh as u64), (w, h), "{path:?}");
        }
    }
    let pack = Pack::open(&pack_path).unwrap();

    // The leaf texture: one file per colour, normal and height mip; level 0 is the source file.
    let view = pack.view_named("texture:plant.txf/leaf.rgb").unwrap();
    let (_, tex) = bake::texture::section::from_section(&view).unwrap();
    let mips = tex.color.as_ref().unwrap().levels.len();
    for k in 0..mips {
        for what in ["color", "normal", "height"] {
            let name = format!("texture_plant.txf_leaf.rgb.{what}.mip{k}.png");
            assert!(names.contains(&name.as_str()), "{name} missing");
        }
    }
    let source =
        bake::ingest::sgi::decode(&std::fs::read(scene.join("leaf.rgb")).unwrap()).unwrap();
    let level0 = image::open(out.join("texture_plant.txf_leaf.rgb.color.mip0.png"))
        .unwrap()
        .to_rgba8();
    assert_eq!(
        (level0.width(), level0.height()),
        (source.width, source.height)
    );
    let worst = level0
        .pixels()
        .zip(&source.pixels)
        .flat_map(|(a, b)| (0..4).map(move |c| (a.0[c] as i32 - b[c] as i32).abs()))
        .max()
        .unwrap();
    assert!(worst <= 1, "level 0 differs from the source by {worst}");

    // The impostor atlas of the plant: colour and normal PNGs are the section's texels exactly.
    let view = pack.view_named("lod:plant.txf").unwrap();
    let lod = bake::lod::section::from_view(&view, None).unwrap();
    let imp = lod.impostor.as_ref().unwrap();
    for (file, texels) in [
        ("lod_plant.txf.impostor-color.png", imp.color),
        ("lod_plant.txf.impostor-normal.png", imp.normal),
    ] {
        let png = image::open(out.join(file)).unwrap().to_rgba8();
        let side = lod.meta.impostor.as_ref().unwrap().side() as u32;
        assert_eq!((png.width(), png.height()), (side, side), "{file}");
        assert!(png.pixels().zip(texels).all(|(a, b)| a.0 == *b), "{file}");
    }

    // The terrain light map's EXR is its texels exactly; its PNG maps the mean to mid-grey.
    let view = pack.view_named("lightmap:terrain").unwrap();
    let (_, lm) = bake::lightmap::section::from_section(&view).unwrap();
    let (w, h, px) = read_exr(&out.join("lightmap_terrain.exr"));
    assert_eq!((w as u32, h as u32), (lm.width, lm.height));
    assert_eq!(px, lm.texels);
    let s = bake::dump::images::exposure(&lm.texels);
    let mean = lm.texels.iter().map(bake::color::luminance).sum::<f32>() / lm.texels.len() as f32;
    assert!(((1.0 - (-mean * s).exp()) - 0.5).abs() < 1e-4);

    // The sky: six faces in storage order and a lat-long; each face's EXR is the cube's face.
    let view = pack.view_named("sky").unwrap();
    let (_, cube) = bake::sky::section::cube_from_section(&view).unwrap();
    for face in bake::cube::Face::ALL {
        let (_, _, px) = read_exr(&out.join(format!("sky.face{}.exr", face.name())));
        assert_eq!(px, cube.face(face), "face {}", face.name());
    }
    assert!(names.contains(&"sky.latlong.png") && names.contains(&"sky.latlong.exr"));

    // Terrain heights: lowest sample black, highest white, linear between, north (last row of
    // the grid) at the top of the image.
    let view = pack.view_named("terrain").unwrap();
    let (_, t) = bake::terrain::source_section::from_section(&view).unwrap();
    let grey = image::open(out.join("terrain.height.png"))
        .unwrap()
        .to_luma16();
    let lo = t.heights.iter().cloned().fold(f32::INFINITY, f32::min);
    let hi = t.heights.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    for j in 0..t.height {
        for i in 0..t.width {
            let h = t.heights[(j * t.width + i) as usize];
            let expect = ((h - lo) / (hi - lo) * 65535.0).round() as u16;
            let got = grey.get_pixel(i, t.height - 1 - j).0[0];
            assert_eq!(got, expect, "sample ({i}, {j})");
        }
    }
}
