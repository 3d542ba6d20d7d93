//! The registry of section kinds (`bake::kinds::all`: the central list and each stage's) against a real bake: the fixture scene
//! through the graph with every stage on (svo and line space too, small) and its build report
//! embedded. Every section's kind is registered, `bake dump` shows it through the registry's
//! views, `bake verify` passes it, and the bake writes every registered kind. The graph's units
//! are those of the stage registry (`graph::stages::all`); `bake unit`'s subcommands are held to
//! them by `cli::unit::tests` (the command line is internal to the crate).

mod common;

use bake::graph::stages::all;
use bake::kinds::find;
use std::collections::BTreeSet;

/// The fixture scene, preview pipeline plus small svo and line-space stages, the build report
/// embedded as `--embed-report` does.
fn every_kind_pack(dir: &std::path::Path) -> std::path::PathBuf {
    bake::fixtures::write_all(dir).unwrap();
    let out = dir.join("scene.bake");
    let mut opts = bake::graph::BuildOptions {
        scenes: vec![dir.join("scene.eco")],
        output: Some(out.clone()),
        sky: Some(dir.join("sky.hdr")),
        cache: bake::graph::CacheMode::Off,
        ..Default::default()
    }
    .preview();
    opts.pipeline.stages.svo = true;
    opts.pipeline.stages.linespace = true;
    opts.pipeline.stages.atlas = true;
    opts.pipeline.svo.resolution = 32;
    opts.pipeline.linespace.n = 4;
    opts.pipeline.linespace.depth = 2;
    let report = bake::graph::build(&opts, &bake::graph::progress::Silent).unwrap();
    let json = serde_json::to_value(&report).unwrap();
    bake::report::embed(&json, &out).unwrap();
    // Every unit the graph ran is of a listed stage, and every listed stage ran.
    let ran: BTreeSet<&str> = report.stages.iter().map(|s| s.stage.as_str()).collect();
    let listed: BTreeSet<&str> = all().map(|s| s.name).collect();
    assert_eq!(ran, listed);
    out
}

/// The same scene with a memory budget under the flattened scene's, so that the svo stage
/// writes its two-level `svo-scene` section (issue 39).
fn two_level_pack(dir: &std::path::Path, flat: &std::path::Path) -> std::path::PathBuf {
    bake::fixtures::write_all(dir).unwrap();
    let size = bake::voxel::geometry::placed_size(&bake::pack::Pack::open(flat).unwrap()).unwrap();
    let out = dir.join("two.bake");
    let mut opts = bake::graph::BuildOptions {
        scenes: vec![dir.join("scene.eco")],
        output: Some(out.clone()),
        sky: Some(dir.join("sky.hdr")),
        cache: bake::graph::CacheMode::Off,
        ..Default::default()
    }
    .preview();
    opts.pipeline.stages.svo = true;
    opts.pipeline.svo.resolution = 32;
    // The line spaces too (`linespace-scene`): a budget both two-level forms fit and neither
    // flattened scene does.
    opts.pipeline.stages.linespace = true;
    opts.pipeline.linespace.n = 4;
    let budget = size.two_level_bytes.max(size.linespace_two_level_bytes);
    assert!(budget < size.stage_bytes(bake::voxel::geometry::SceneStage::Linespace));
    opts.ingest.limits.max_memory = budget;
    bake::graph::build(&opts, &bake::graph::progress::Silent).unwrap();
    out
}

#[test]
fn every_kind_of_a_real_bake_is_registered_dumped_and_verified() {
    let dir = tempfile::tempdir().unwrap();
    let path = every_kind_pack(dir.path());
    let two_dir = tempfile::tempdir().unwrap();
    let two = two_level_pack(two_dir.path(), &path);
    let mut seen = BTreeSet::new();
    for path in [path, two] {
        check_pack(&path, &mut seen);
    }
    let missing: Vec<_> = bake::kinds::all()
        .map(|k| k.kind)
        .filter(|k| !seen.contains(k))
        .collect();
    assert!(missing.is_empty(), "the bakes wrote no {missing:?} section");
}

fn check_pack(path: &std::path::Path, seen: &mut BTreeSet<&'static str>) {
    let pack = bake::pack::Pack::open(path).unwrap();

    let doc = bake::dump::dump_json(&pack, &bake::dump::DumpOptions::default()).unwrap();
    let dumped = doc["sections"].as_array().unwrap();
    assert_eq!(dumped.len(), pack.sections().len());
    for (e, d) in pack.sections().iter().zip(dumped) {
        let kind = find(&e.kind).unwrap_or_else(|| panic!("{:?}: kind not registered", e.name));
        seen.insert(kind.kind);
        assert!(
            kind.naming.accepts(kind.kind, &e.name),
            "{:?} of kind {}",
            e.name,
            e.kind
        );
        let view = pack.view(e).unwrap();
        (kind.decode)(&view).unwrap_or_else(|err| panic!("{:?}: {err}", e.name));
        // dump's summary is the registry's view of the section.
        match kind.views {
            Some((summary, _)) => {
                assert_eq!(d["summary"], summary(&view).unwrap(), "{}", e.name);
                assert_ne!(d["summary"], serde_json::json!({}), "{}", e.name);
            }
            None => assert_eq!(d["summary"], serde_json::json!({}), "{}", e.name),
        }
    }
    let v = bake::verify::verify_file(path).unwrap();
    assert!(v.ok(), "{:#?}", v.violations);
    assert_eq!(v.decoded, pack.sections().len());
}
