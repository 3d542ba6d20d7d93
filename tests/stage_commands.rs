//! The whole-scene stage commands run the registry's unit (issue 36): `bake bittree`, and `bake
//! svo` and `bake linespace` on a pack, give the section the graph's unit gives over the same
//! sections, checked here against the graph's own pack (the oracle) and, where the command's
//! input lacks what the graph reads (a pack records no area of interest), against the
//! instances it does read.

mod common;

use bake::graph::{BuildOptions, CacheMode, Pipeline};
use bake::pack::Pack;
use std::path::{Path, PathBuf};

/// The scene `dir/scene.eco` baked by the graph into `dir/<name>` with only the stages `on`
/// leaves on (of the lighting and whole-scene stages; material, terrain and sky stay).
fn graph_pack(dir: &Path, name: &str, on: impl FnOnce(&mut Pipeline)) -> PathBuf {
    let mut pipeline = Pipeline::default();
    let s = &mut pipeline.stages;
    (s.prt, s.lod, s.lightmap, s.atlas, s.envmaps, s.cluster) =
        (false, false, false, false, false, false);
    (s.bittree, s.svo, s.linespace) = (false, false, false);
    on(&mut pipeline);
    graph_bake(dir, name, pipeline)
}

/// The scene `dir/scene.eco` (with `dir/sky.hdr`) baked by the graph with `pipeline` into
/// `dir/<name>`, no cache.
fn graph_bake(dir: &Path, name: &str, pipeline: Pipeline) -> PathBuf {
    let out = dir.join(name);
    bake::graph::build(
        &BuildOptions {
            scenes: vec![dir.join("scene.eco")],
            output: Some(out.clone()),
            sky: Some(dir.join("sky.hdr")),
            cache: CacheMode::Off,
            pipeline,
            ..Default::default()
        },
        &bake::graph::progress::Silent,
    )
    .unwrap();
    out
}

/// The payload of section `name` of the pack at `path`.
fn payload(path: &Path, name: &str) -> Vec<u8> {
    let pack = Pack::open(path).unwrap();
    let e = pack
        .find(name)
        .unwrap_or_else(|| panic!("{}: no section {name}", path.display()));
    pack.payload(e).to_vec()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn bittree_of(path: &Path) -> bake::bittree::section::Decoded {
    let pack = Pack::open(path).unwrap();
    bake::bittree::section::from_section(&pack.view_named("bittree").unwrap()).unwrap()
}

#[test]
fn bake_bittree_encodes_the_instances_section_over_the_graph_s_area() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    let graph = graph_pack(d, "graph.bake", |p| p.stages.bittree = true);
    let want = payload(&graph, "bittree");

    // An ECO input: the scene's plan gives the area of interest, as in the graph.
    let eco = d.join("eco.bake");
    common::json(&common::bake(&[
        "bittree",
        s(&d.join("scene.eco")),
        "-o",
        s(&eco),
        "--json",
    ]));
    assert!(payload(&eco, "bittree") == want, "bake bittree SCENE.eco");

    // A pack without a BitTree: the instances of its `instances` section, over their bounds
    // (no section records the area of interest, which here is larger than the bounds).
    let plain = graph_pack(d, "plain.bake", |_| {});
    let out = d.join("pack.bake");
    common::json(&common::bake(&[
        "bittree",
        s(&plain),
        "-o",
        s(&out),
        "--json",
    ]));
    let pack = Pack::open(&plain).unwrap();
    let (_, inst) =
        bake::ingest::instances_section::from_section(&pack.view_named("instances").unwrap())
            .unwrap();
    let got = bittree_of(&out);
    let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
    for i in &inst.items {
        for k in 0..2 {
            lo[k] = lo[k].min(i.position[k]);
            hi[k] = hi[k].max(i.position[k]);
        }
    }
    let a = got.meta.area;
    for k in 0..2 {
        assert!((a.origin[k] - (lo[k] - 1e-3)).abs() < 1e-5, "{a:?}");
        assert!(
            (a.origin[k] + a.extent[k] - (hi[k] + 1e-3)).abs() < 1e-4,
            "{a:?}"
        );
    }
    assert_ne!(
        a,
        bittree_of(&graph).meta.area,
        "the fixture's area of interest"
    );
    // Every instance of the section, in leaf order: matched by position to within a leaf
    // cell's 2^-17, with its scale and model.
    assert_eq!(got.positions.len(), inst.items.len());
    let cells = 4f32.powi(got.meta.levels as i32);
    for (k, p) in got.positions.iter().enumerate() {
        let tol = [0, 1].map(|j| a.extent[j] / cells / 65536.0 + 1e-5);
        let hit = inst.items.iter().find(|i| {
            (i.position[0] - p[0]).abs() <= tol[0]
                && (i.position[1] - p[1]).abs() <= tol[1]
                && i.scale == got.scale[k]
                && i.model == got.model[k] as u32
        });
        assert!(hit.is_some(), "decoded instance {k} at {p:?}");
    }

    // A scene whose area of interest lies within its instances' bounds (instances at two of
    // its corners): over the graph's own pack, the command gives the graph's section.
    let eco_text = std::fs::read_to_string(d.join("scene.eco")).unwrap();
    std::fs::write(
        d.join("scene.eco"),
        format!("{eco_text}\nplant 0.0 0.0 1.0 0.0\nplant 1.0 1.0 1.0 90.0\n"),
    )
    .unwrap();
    let corners = graph_pack(d, "corners.bake", |p| p.stages.bittree = true);
    let again = d.join("again.bake");
    common::json(&common::bake(&[
        "bittree",
        s(&corners),
        "-o",
        s(&again),
        "--json",
    ]));
    assert!(payload(&again, "bittree") == payload(&corners, "bittree"));
    // `--children` is the pipeline's option.
    let c64 = d.join("c64.bake");
    common::json(&common::bake(&[
        "bittree",
        s(&corners),
        "-o",
        s(&c64),
        "--children",
        "64",
        "--json",
    ]));
    assert_eq!(bittree_of(&c64).meta.children, 64);
}

#[test]
fn bake_bittree_refuses_a_pack_without_instances() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    let terrain = d.join("t.bake");
    common::json(&common::bake(&[
        "ingest",
        s(&d.join("terrain.raw")),
        "--size",
        "65x65",
        "-o",
        s(&terrain),
        "--json",
    ]));
    let o = common::bake(&["bittree", s(&terrain), "-o", s(&d.join("x.bake"))]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("instances") && e.contains("t.bake"), "{e}");
}

/// The section named `name` of `path` decoded and encoded again with the graph's source (the
/// scene's first ECO file; a command records its own input): the bytes the graph's unit would
/// have written over the same sections.
fn as_graph_source(path: &Path, name: &str) -> Vec<u8> {
    let pack = Pack::open(path).unwrap();
    let e = pack.find(name).unwrap();
    let v = pack.view(e).unwrap();
    let source = "scene:scene.eco";
    let s = match e.kind.as_str() {
        "svo" => {
            let (m, svo) = bake::voxel::section::from_section(&v).unwrap();
            bake::voxel::section::to_section(name, source, &svo, m.solid)
        }
        "svo-scene" => {
            let (m, two) = bake::voxel::instanced_section::from_section(&v).unwrap();
            bake::voxel::instanced_section::to_section(name, source, &two, m.solid)
        }
        "linespace" => {
            let (_, t) = bake::linespace::section::from_section(&v).unwrap();
            bake::linespace::section::to_section(name, source, &t)
        }
        "linespace-scene" => {
            let (_, t) = bake::linespace::instanced_section::from_section(&v).unwrap();
            bake::linespace::instanced_section::to_section(name, source, &t)
        }
        k => panic!("kind {k}"),
    };
    s.payload.to_vec()
}

#[test]
fn bake_svo_and_linespace_on_a_pack_give_the_graph_s_sections() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    // Flattened (the default budget) and two-level (a budget the placed scene exceeds as one
    // mesh), for each stage.
    let cases: [(&str, &str, &str, Option<&str>); 4] = [
        ("svo", "svo", "svo", None),
        ("linespace", "linespace", "linespace", None),
        ("svo", "svo-scene", "svo-scene", Some("4M")),
        (
            "linespace",
            "linespace-scene",
            "linespace-scene",
            Some("1M"),
        ),
    ];
    for (stage, kind, name, budget) in cases {
        let graph = {
            let mut pipeline = Pipeline::default();
            let s = &mut pipeline.stages;
            (
                s.prt, s.lod, s.lightmap, s.atlas, s.envmaps, s.cluster, s.bittree,
            ) = (false, false, false, false, false, false, false);
            (s.svo, s.linespace) = (stage == "svo", stage == "linespace");
            let mut ingest = bake::ingest::IngestOptions::default();
            if let Some(b) = budget {
                let bytes = b.trim_end_matches('M').parse::<u64>().unwrap() << 20;
                ingest.limits = bake::ingest::limits::Limits::with_memory(bytes);
            }
            let out = d.join(format!("graph-{kind}.bake"));
            bake::graph::build(
                &BuildOptions {
                    scenes: vec![d.join("scene.eco")],
                    output: Some(out.clone()),
                    sky: Some(d.join("sky.hdr")),
                    cache: CacheMode::Off,
                    pipeline,
                    ingest,
                    ..Default::default()
                },
                &bake::graph::progress::Silent,
            )
            .unwrap();
            out
        };
        let pack = Pack::open(&graph).unwrap();
        assert_eq!(pack.find(name).map(|e| e.kind.as_str()), Some(kind));
        drop(pack);
        let out = d.join(format!("cmd-{kind}.bake"));
        let mut args: Vec<&str> = Vec::new();
        if let Some(b) = budget {
            args.extend(["--max-memory", b]);
        }
        args.extend([stage, s(&graph), "-o", s(&out), "--json"]);
        let doc = common::json(&common::bake(&args));
        assert!(
            as_graph_source(&out, name) == payload(&graph, name),
            "bake {stage} ({kind}): {doc}"
        );
    }
}

#[test]
fn bake_cluster_gives_the_graph_s_clusters_with_and_without_weights() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    for weights in [false, true] {
        let name = format!("graph-{weights}.bake");
        let graph = graph_pack(d, &name, |p| {
            (p.stages.envmaps, p.stages.cluster) = (true, true);
            p.cluster.weights = weights;
        });
        let out = d.join(format!("cmd-{weights}.bake"));
        let mut args = vec!["cluster", s(&graph), "-o", s(&out), "--json"];
        if weights {
            args.push("--weights");
        }
        common::json(&common::bake(&args));
        assert!(
            payload(&out, "clusters") == payload(&graph, "clusters"),
            "weights {weights}"
        );
    }
    // The weights are stored only when asked for (a larger section).
    let [plain, weighed] =
        [false, true].map(|w| payload(&d.join(format!("graph-{w}.bake")), "clusters"));
    assert!(weighed.len() > plain.len());
}

/// `bake stage NAME PACK` (issue 36: the command made from the registry) runs any registered
/// stage's units with the pipeline's options. Oracle: the graph's own bake of the same
/// pipeline with the stage on. A pack baked by the graph with `prt`, `lod`, `envmaps` and
/// `cluster` off gets each of them by `bake stage`, and each section equals the full bake's.
#[test]
fn bake_stage_runs_any_registered_stage_as_the_graph_does() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    let full = graph_bake(d, "full.bake", Pipeline::preview());
    let mut without = Pipeline::preview();
    let st = &mut without.stages;
    (st.prt, st.lod, st.envmaps, st.cluster) = (false, false, false, false);
    let base = graph_bake(d, "base.bake", without);
    let sections_of = |path: &Path, kind: &str| -> Vec<(String, Vec<u8>)> {
        let pack = Pack::open(path).unwrap();
        pack.of_kind(kind)
            .map(|e| (e.name.clone(), pack.payload(e).to_vec()))
            .collect()
    };
    // prt and lod per mesh, envmaps as one shard joined, cluster over the env maps' pack.
    let mut input = base.clone();
    for (stage, kind, units) in [
        ("prt", "prt", None),
        ("lod", "lod", None),
        ("envmaps", "envmaps", Some(1)),
        ("cluster", "clusters", Some(1)),
    ] {
        let out = d.join(format!("stage-{stage}.bake"));
        let doc = common::json(&common::bake(&[
            "stage",
            stage,
            s(&input),
            "-o",
            s(&out),
            "--pipeline",
            "preview",
            "--json",
        ]));
        let want = sections_of(&full, kind);
        assert!(!want.is_empty(), "{kind}");
        assert!(sections_of(&out, kind) == want, "bake stage {stage}: {doc}");
        let n = doc["units"].as_array().unwrap().len();
        match units {
            Some(u) => assert_eq!(n, u, "{doc}"),
            None => assert_eq!(n, want.len(), "one unit per mesh: {doc}"),
        }
        assert_eq!(doc["stage"], stage);
        input = out;
    }
    // `--set` reaches the stage's options: other samples, other transfer.
    let out = d.join("stage-prt-64.bake");
    common::json(&common::bake(&[
        "stage",
        "prt",
        s(&base),
        "-o",
        s(&out),
        "--pipeline",
        "preview",
        "--set",
        "prt.samples=16",
        "--json",
    ]));
    assert!(sections_of(&out, "prt") != sections_of(&full, "prt"));

    // `--list` names every registered stage; an unknown stage, an unknown option and the
    // ingest stage (which reads a model file) are usage errors (exit 2) naming what is wrong.
    let doc = common::json(&common::bake(&["stage", "--list", "--json"]));
    let names: Vec<&str> = doc["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    let registry: Vec<&str> = bake::graph::stage::REGISTRY
        .iter()
        .map(|s| s.def().name)
        .collect();
    assert_eq!(names, registry);
    for (args, needle) in [
        (
            vec!["stage", "nope", s(&base)],
            "no registered stage \"nope\"",
        ),
        (
            vec!["stage", "prt", s(&base), "--set", "prt.sampels=3"],
            "sampels",
        ),
        (vec!["stage", "ingest", s(&base)], "bake ingest"),
    ] {
        let o = common::bake(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(needle), "{args:?}: {e}");
    }
}
