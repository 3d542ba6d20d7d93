//! Bakes `fixtures/scene` into `$OUT_DIR/scene.bake` with the preview pipeline and prints
//! `cargo:rerun-if-changed` for every file the bake read (the same list `--depfile` writes); reads
//! the pack back with the pack reader and passes the kinds it holds to the program.

use bake::graph::{BuildOptions, CacheMode, Pipeline, build, progress::Silent};
use bake::pack::Pack;
use std::path::PathBuf;

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("../..");
    let scene = root.join("fixtures/scene");
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("scene.bake");
    let report = build(
        &BuildOptions {
            scenes: vec![scene.join("scene.eco")],
            sky: Some(scene.join("sky.hdr")),
            output: Some(out.clone()),
            pipeline: Pipeline::preview(),
            cache: CacheMode::Dir(PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("cache")),
            ..Default::default()
        },
        &Silent,
    )
    .unwrap_or_else(|e| panic!("bake failed: {e}"));
    for f in &report.files {
        println!("cargo:rerun-if-changed={}", f.display());
    }
    // The pack reader: the section kinds the bake wrote (each section's checksum checked).
    let pack = Pack::open(&out).unwrap_or_else(|e| panic!("reading the pack: {e}"));
    let mut kinds: Vec<&str> = Vec::new();
    for e in pack.sections() {
        assert!(pack.checksum_ok(e), "section {} is damaged", e.name);
        kinds.push(&e.kind);
    }
    kinds.sort_unstable();
    kinds.dedup();
    println!("cargo:rustc-env=SCENE_KINDS={}", kinds.join(","));
    println!("cargo:rustc-env=SCENE_PACK={}", out.display());
    println!("cargo:rustc-env=SCENE_SECTIONS={}", report.sections);
}
