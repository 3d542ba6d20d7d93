//! Black-box tests of `bake material` and `bake terrain`: outputs, `dump --json` keys, errors.

use bake::model::{Material, MaterialSource, Mesh, Rgba8Image, TextureRef};
use bake::pack::PackWriter;
use serde_json::Value;
use std::path::Path;

mod common;
use common::{bake, json};

fn section<'a>(doc: &'a Value, name: &str) -> &'a Value {
    doc["sections"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .unwrap_or_else(|| panic!("no section {name}"))
}

/// A 32×32 leaf texture: an opaque disc on a transparent background.
fn leaf_image() -> Rgba8Image {
    let pixels = (0..32 * 32)
        .map(|i| {
            let (x, y) = ((i % 32) as f32 - 15.5, (i / 32) as f32 - 15.5);
            let a = if x * x + y * y < 12.0 * 12.0 { 255 } else { 0 };
            [40, 140, 30, a]
        })
        .collect();
    Rgba8Image {
        width: 32,
        height: 32,
        pixels,
    }
}

/// What `bake ingest plant.txf` would write: a quad with the default material and a texture,
/// plus a triangle with an authored (TXF `<Colors>`) material.
fn write_plant_pack(path: &Path) {
    let mesh = Mesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.1, 0.0, 0.1],
            [0.0, 0.0, 0.1],
        ],
        normals: vec![[0.0, -1.0, 0.0]; 4],
        uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        triangle_materials: vec![0, 1],
        materials: vec![
            Material {
                name: "leaf".into(),
                color_map: Some(0),
                ..Material::default()
            },
            Material {
                name: "stem".into(),
                diffuse: [0.4, 0.3, 0.1, 1.0],
                specular: [0.2, 0.2, 0.2, 1.0],
                shininess: 18.0,
                source: MaterialSource::FixedFunction,
                ..Material::default()
            },
        ],
        textures: vec![TextureRef {
            name: "leaf.png".into(),
            path: "leaf.png".into(),
        }],
        ..Default::default()
    };
    let mut w = PackWriter::new();
    let tex = bake::texture::source_section::texture_section_name("plant.txf", "leaf.png");
    w.insert(bake::texture::source_section::to_section(
        &tex,
        "leaf.png",
        &leaf_image(),
    ));
    w.insert(bake::mesh::section::to_section(
        "mesh:plant.txf",
        "plant.txf",
        &mesh,
        &[Some(tex)],
    ));
    w.write(path).unwrap();
}

#[test]
fn material_stage_adds_materials_mips_and_tangents() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("plant.bake");
    let output = dir.path().join("out.bake");
    write_plant_pack(&input);
    let report = json(&bake(&[
        "material",
        input.to_str().unwrap(),
        "-o",
        output.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(report["materials"], 2);
    assert_eq!(report["leaf_defaults"], 1);
    assert_eq!(report["textures"], 1);
    let doc = json(&bake(&["dump", output.to_str().unwrap(), "--json"]));
    let leaf = &section(&doc, "material:plant.txf/0")["summary"];
    assert_eq!(section(&doc, "material:plant.txf/0")["kind"], "material");
    for key in [
        "layers",
        "bump_height",
        "translucence",
        "color_map",
        "normal_map",
    ] {
        assert!(leaf.get(key).is_some(), "material summary lacks {key}");
    }
    for layer in leaf["layers"].as_array().unwrap() {
        let sum: f64 = ["diffuse", "glossy", "specular"]
            .iter()
            .map(|k| layer[k].as_f64().unwrap())
            .sum();
        assert!((sum - 1.0).abs() < 1e-6);
        assert_eq!(layer["color"].as_array().unwrap().len(), 3);
    }
    assert_eq!(leaf["layers"][0]["color"][0], 0.075f32 as f64);
    let stem = &section(&doc, "material:plant.txf/1")["summary"];
    assert_eq!(stem["layers"][0]["roughness"], 0.1f32 as f64); // 2/(18+2)
    let tex = &section(&doc, "texture:plant.txf/leaf.png");
    assert_eq!(tex["kind"], "texture");
    assert_eq!(tex["summary"]["mips"], 6);
    assert_eq!(tex["summary"]["coverage"].as_array().unwrap().len(), 6);
    assert_eq!(
        section(&doc, "tangents:plant.txf")["summary"]["vertices"],
        4
    );
}

#[test]
fn terrain_stage_reports_quadtree_levels() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("t.raw");
    std::fs::write(
        &raw,
        (0..33 * 17)
            .map(|k| (k * 7 % 251) as u8)
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let out = dir.path().join("t.bake");
    let r = json(&bake(&[
        "terrain",
        raw.to_str().unwrap(),
        "--size",
        "33x17",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(r["quadtree_levels"][0], 6);
    let doc = json(&bake(&["dump", out.to_str().unwrap(), "--json"]));
    let t = section(&doc, "terrain");
    assert_eq!(t["summary"]["quadtree_levels"], 6);
    let arrays: Vec<&str> = t["arrays"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["name"].as_str().unwrap())
        .collect();
    for a in ["heights", "normals", "quadtree", "quadtree_levels"] {
        assert!(arrays.contains(&a), "{arrays:?}");
    }
    // The four-tap texture repeats the heights four times: readers derive it (format 2).
    assert!(!arrays.contains(&"four_tap"), "{arrays:?}");
    // Running the stage on its own output changes nothing.
    let again = dir.path().join("t2.bake");
    json(&bake(&[
        "terrain",
        out.to_str().unwrap(),
        "-o",
        again.to_str().unwrap(),
        "--json",
    ]));
    assert!(std::fs::read(&out).unwrap() == std::fs::read(&again).unwrap());
}

#[test]
fn stage_errors_have_exit_codes() {
    let o = bake(&["material", "/nonexistent/x.bake"]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.bake");
    std::fs::write(
        &bad,
        b"not a pack at all, but long enough to be read as a header........",
    )
    .unwrap();
    let o = bake(&["terrain", bad.to_str().unwrap()]);
    assert_eq!(
        o.status.code(),
        Some(4),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("bad.bake"));
}
