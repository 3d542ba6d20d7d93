//! `bake lod PACK` as a user runs it (issue 14, item 1): the fixture scene ingested, levels and
//! impostors added, the pack valid for `bake verify`, the dump view's levels and switch
//! distances, the same bytes whatever the thread count, and a clear error for a pack without
//! meshes.

mod common;

use bake::pack::Pack;

fn ingest(dir: &std::path::Path) -> std::path::PathBuf {
    let scene = dir.join("scene");
    common::json(&common::bake(&[
        "fixtures",
        scene.to_str().unwrap(),
        "--json",
    ]));
    let pack = dir.join("ingest.bake");
    common::json(&common::bake(&[
        "ingest",
        scene.join("scene.eco").to_str().unwrap(),
        "-o",
        pack.to_str().unwrap(),
        "--json",
    ]));
    pack
}

#[test]
fn bake_lod_adds_checked_sections_and_the_dump_shows_switch_distances() {
    let dir = tempfile::tempdir().unwrap();
    let input = ingest(dir.path());
    let out = dir.path().join("lod.bake");
    let doc = common::json(&common::bake(&[
        "lod",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]));
    let meshes = doc["meshes"].as_array().unwrap();
    assert_eq!(meshes.len(), 2, "{doc}");
    common::json(&common::bake(&["verify", out.to_str().unwrap(), "--json"]));
    let pack = Pack::open(&out).unwrap();
    let lod = bake::lod::section::read(&pack, "mesh:plant.txf")
        .unwrap()
        .unwrap();
    assert!(lod.meta.levels.len() >= 2 && lod.impostor.is_some());
    // The dump view: levels with their switch distance at 1280×720, 45°, tau 1.
    let dump = common::json(&common::bake(&["dump", out.to_str().unwrap(), "--json"]));
    let s = dump["sections"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "lod:plant.txf")
        .unwrap();
    let k = bake::lod::select::reference_k();
    for (l, level) in lod.meta.levels.iter().enumerate() {
        let d = s["summary"]["levels"][l]["switch_distance"]
            .as_f64()
            .unwrap();
        assert!(
            (d - (level.error * k) as f64).abs() < 1e-3 * (1.0 + d),
            "level {l}: {d}"
        );
    }

    // Same bytes with one thread and with four.
    let again = dir.path().join("lod1.bake");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_bake"))
        .args([
            "lod",
            input.to_str().unwrap(),
            "-o",
            again.to_str().unwrap(),
            "--quiet",
        ])
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .unwrap();
    assert!(o.status.success());
    let four = dir.path().join("lod4.bake");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_bake"))
        .args([
            "lod",
            input.to_str().unwrap(),
            "-o",
            four.to_str().unwrap(),
            "--quiet",
        ])
        .env("RAYON_NUM_THREADS", "4")
        .output()
        .unwrap();
    assert!(o.status.success());
    let a = std::fs::read(&out).unwrap();
    assert!(a == std::fs::read(&again).unwrap() && a == std::fs::read(&four).unwrap());
}

#[test]
fn a_pack_without_meshes_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let input = ingest(dir.path());
    // Keep the terrain only.
    let pack = Pack::open(&input).unwrap();
    let mut w = bake::pack::PackWriter::new();
    for s in pack.checked_sections().unwrap() {
        if s.kind == "terrain" {
            w.insert(s);
        }
    }
    let bare = dir.path().join("bare.bake");
    w.write(&bare).unwrap();
    let o = common::bake(&["lod", bare.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(4));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bare.bake") && err.contains("no mesh section"),
        "{err}"
    );
}
