//! The cached stage graph (`bake SCENE.eco`): which units a change re-runs, byte-identical
//! cached and uncached bakes, damaged cache entries, concurrent bakes sharing one cache, the
//! depfile against the files the process really opened (strace), pipeline files on the CLI.

mod common;

use bake::graph::{BuildOptions, BuildReport, CacheMode, Pipeline, build, progress::Silent};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A fixture scene in its own folder.
fn scene() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    bake::fixtures::write_all(dir.path()).unwrap();
    dir
}

fn opts(dir: &Path, out: &str, cache: &Path) -> BuildOptions {
    BuildOptions {
        scenes: vec![dir.join("scene.eco")],
        output: Some(dir.join(out)),
        sky: Some(dir.join("sky.hdr")),
        pipeline: Pipeline::preview(),
        cache: CacheMode::Dir(cache.to_path_buf()),
        ..Default::default()
    }
}

fn run(o: &BuildOptions) -> BuildReport {
    build(o, &Silent).unwrap()
}

/// "stage unit" → cache status.
fn statuses(r: &BuildReport) -> BTreeMap<String, &'static str> {
    r.stages
        .iter()
        .map(|s| (format!("{} {}", s.stage, s.unit), s.cache))
        .collect()
}

/// The units that ran (missed the cache).
fn missed(r: &BuildReport) -> BTreeSet<String> {
    statuses(r)
        .into_iter()
        .filter(|(_, c)| *c == "miss")
        .map(|(k, _)| k)
        .collect()
}

fn set(items: &[&str]) -> BTreeSet<String> {
    items.iter().map(|s| s.to_string()).collect()
}

const SCENE_UNITS: [&str; 4] = [
    "lightmap terrain",
    "atlas objects",
    "envmaps instances 0..100",
    "cluster scene",
];

#[test]
fn unchanged_inputs_hit_every_unit_and_leave_an_up_to_date_output_alone() {
    let dir = scene();
    let cache = dir.path().join("cache");
    let first = run(&opts(dir.path(), "a.bake", &cache));
    assert!(
        first.stages.iter().all(|s| s.cache == "miss"),
        "{:?}",
        statuses(&first)
    );
    assert!(first.stages.len() >= 13);
    // Same inputs, another output: every unit is a hit and the bytes are the same.
    let second = run(&opts(dir.path(), "b.bake", &cache));
    assert!(
        second.stages.iter().all(|s| s.cache == "hit"),
        "{:?}",
        statuses(&second)
    );
    let a = std::fs::read(dir.path().join("a.bake")).unwrap();
    assert_eq!(a, std::fs::read(dir.path().join("b.bake")).unwrap());
    // The same output again: up to date, not rewritten (its inode and mtime stay).
    let meta = std::fs::metadata(dir.path().join("a.bake")).unwrap();
    let third = run(&opts(dir.path(), "a.bake", &cache));
    assert!(third.up_to_date && third.stages.is_empty());
    assert_eq!(
        (third.models, third.instances),
        (first.models, first.instances)
    );
    let after = std::fs::metadata(dir.path().join("a.bake")).unwrap();
    assert_eq!(meta.modified().unwrap(), after.modified().unwrap());
    // Touching a file without changing its bytes keeps it up to date; changing a byte does not.
    let eco = dir.path().join("scene.eco");
    let text = std::fs::read(&eco).unwrap();
    std::fs::write(&eco, &text).unwrap();
    assert!(run(&opts(dir.path(), "a.bake", &cache)).up_to_date);
    let mut changed = text.clone();
    changed.extend_from_slice(b"\n");
    std::fs::write(&eco, &changed).unwrap();
    assert!(!run(&opts(dir.path(), "a.bake", &cache)).up_to_date);
}

#[test]
fn a_cached_rebuild_is_byte_identical_to_an_uncached_bake() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "warm.bake", &cache));
    let hit = run(&opts(dir.path(), "hit.bake", &cache));
    assert!(hit.stages.iter().all(|s| s.cache == "hit"));
    let mut o = opts(dir.path(), "cold.bake", &cache);
    o.cache = CacheMode::Off;
    let cold = run(&o);
    assert!(cold.stages.iter().all(|s| s.cache == "off"));
    let hit_bytes = std::fs::read(dir.path().join("hit.bake")).unwrap();
    assert_eq!(
        hit_bytes,
        std::fs::read(dir.path().join("cold.bake")).unwrap()
    );
    // The pack is whole: every checksum holds and every section kind decodes for dump.
    let pack = bake::pack::Pack::open(&dir.path().join("hit.bake")).unwrap();
    assert!(pack.sections().iter().all(|e| pack.checksum_ok(e)));
    bake::dump::dump_json(&pack, &Default::default()).unwrap();
    // `bake verify` finds nothing wrong with a graph-built pack, its build record included.
    let v = bake::verify::verify_file(&dir.path().join("hit.bake")).unwrap();
    assert!(v.violations.is_empty(), "{:?}", v.violations);
    assert_eq!(v.decoded, pack.sections().len());
}

#[test]
fn one_changed_model_reruns_its_units_and_the_scene_units_only() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "a.bake", &cache));
    // Change one byte of a vertex coordinate's text in the 3DS object... it is binary, so
    // move one vertex instead: rewrite the object with its first float nudged.
    let path = dir.path().join("object.3ds");
    let mut bytes = std::fs::read(&path).unwrap();
    nudge_first_vertex(&mut bytes);
    std::fs::write(&path, &bytes).unwrap();
    let r = run(&opts(dir.path(), "b.bake", &cache));
    let mut expect = set(&[
        "ingest object.3ds",
        "material object.3ds",
        "prt object.3ds",
        "lod object.3ds",
    ]);
    expect.extend(set(&SCENE_UNITS[..3]));
    // The clustering reads the instances and the env maps only: it re-runs exactly when the
    // maps came out different (content addressing cuts the rebuild off where outputs repeat).
    if section_hash(&dir.path().join("a.bake"), "envmaps")
        != section_hash(&dir.path().join("b.bake"), "envmaps")
    {
        expect.insert("cluster scene".into());
    }
    // The BitTree reads only the instances, which do not depend on the model's vertices.
    assert_eq!(missed(&r), expect);
    let s = statuses(&r);
    for unit in [
        "ingest plant.txf",
        "material plant.txf",
        "prt plant.txf",
        "lod plant.txf",
        "sky sky",
        "terrain terrain",
        "bittree scene",
    ] {
        assert_eq!(s[unit], "hit", "{unit}");
    }
}

fn section_hash(pack: &Path, name: &str) -> [u8; 32] {
    let p = bake::pack::Pack::open(pack).unwrap();
    p.find(name).unwrap().checksum
}

/// Adds a small offset to the first vertex of the first 0x4110 (vertex list) chunk.
fn nudge_first_vertex(b: &mut [u8]) {
    let at = b
        .windows(2)
        .position(|w| w == [0x10, 0x41])
        .expect("a vertex list chunk");
    // chunk id (2) + length (4) + count (2), then x as f32.
    let x = at + 8;
    let v = f32::from_le_bytes(b[x..x + 4].try_into().unwrap()) + 0.01;
    b[x..x + 4].copy_from_slice(&v.to_le_bytes());
}

#[test]
fn a_changed_sky_does_not_rerun_the_transfer() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "a.bake", &cache));
    let mut o = opts(dir.path(), "b.bake", &cache);
    o.sky = None; // the built-in clear sky instead of the HDR file
    let r = run(&o);
    let mut expect = set(&["sky sky"]);
    expect.extend(set(&SCENE_UNITS));
    assert_eq!(missed(&r), expect);
    assert_eq!(statuses(&r)["prt plant.txf"], "hit");
    assert_eq!(statuses(&r)["lod plant.txf"], "hit");
}

#[test]
fn one_option_of_one_stage_reruns_that_unit_only() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "a.bake", &cache));
    let mut o = opts(dir.path(), "b.bake", &cache);
    o.pipeline.set("lightmap.resolution=33").unwrap();
    assert_eq!(missed(&run(&o)), set(&["lightmap terrain"]));
    let mut o = opts(dir.path(), "c.bake", &cache);
    o.pipeline.set("prt.samples=32").unwrap();
    assert_eq!(missed(&run(&o)), set(&["prt object.3ds", "prt plant.txf"]));
    let mut o = opts(dir.path(), "d.bake", &cache);
    o.pipeline.set("cluster.error=0.05").unwrap();
    assert_eq!(missed(&run(&o)), set(&["cluster scene"]));
    let mut o = opts(dir.path(), "e.bake", &cache);
    o.pipeline.set("lod.levels=2").unwrap();
    assert_eq!(missed(&run(&o)), set(&["lod object.3ds", "lod plant.txf"]));
}

#[test]
fn a_new_bake_version_misses_every_unit() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "a.bake", &cache));
    let mut o = opts(dir.path(), "b.bake", &cache);
    o.bake_version = Some("999.0.0".into());
    let r = run(&o);
    assert!(
        r.stages.iter().all(|s| s.cache == "miss"),
        "{:?}",
        statuses(&r)
    );
    // ...and gives the same sections: the version enters only the keys and the build record.
    let (a, b) = (
        bake::pack::Pack::open(&dir.path().join("a.bake")).unwrap(),
        bake::pack::Pack::open(&dir.path().join("b.bake")).unwrap(),
    );
    assert_eq!(a.sections().len(), b.sections().len());
    for (x, y) in a.sections().iter().zip(b.sections()) {
        assert_eq!(x.name, y.name);
        if x.kind != "build" {
            assert_eq!(x.checksum, y.checksum, "{}", x.name);
        }
    }
}

#[test]
fn a_damaged_cache_entry_is_detected_and_recomputed() {
    let dir = scene();
    let cache = dir.path().join("cache");
    run(&opts(dir.path(), "a.bake", &cache));
    // Damage every entry differently: flip a byte in the middle of each.
    let mut entries = Vec::new();
    for d in std::fs::read_dir(cache.join("v1")).unwrap() {
        for f in std::fs::read_dir(d.unwrap().path()).unwrap() {
            entries.push(f.unwrap().path());
        }
    }
    assert!(entries.len() >= 13);
    for e in &entries {
        let mut b = std::fs::read(e).unwrap();
        let mid = 256 + (b.len() - 256) / 3;
        b[mid] ^= 0x55;
        std::fs::write(e, &b).unwrap();
    }
    let r = run(&opts(dir.path(), "b.bake", &cache));
    assert!(
        r.stages.iter().all(|s| s.cache == "miss"),
        "{:?}",
        statuses(&r)
    );
    let damaged = r
        .warnings
        .iter()
        .filter(|w| w.id == "cache.corrupt-entry")
        .count();
    assert_eq!(damaged, r.stages.len());
    assert_eq!(
        std::fs::read(dir.path().join("a.bake")).unwrap(),
        std::fs::read(dir.path().join("b.bake")).unwrap()
    );
    // The recomputed entries are good again.
    let r = run(&opts(dir.path(), "c.bake", &cache));
    assert!(r.stages.iter().all(|s| s.cache == "hit"));
}

#[test]
fn two_concurrent_bakes_into_one_cache_both_succeed() {
    let dir = scene();
    let cache = dir.path().join("cache");
    let mut reference = opts(dir.path(), "ref.bake", &cache);
    reference.cache = CacheMode::Off;
    run(&reference);
    let want = std::fs::read(dir.path().join("ref.bake")).unwrap();
    for round in 0..2 {
        let bin = common::bake_bin();
        let children: Vec<_> = ["x", "y"]
            .iter()
            .map(|n| {
                std::process::Command::new(&bin)
                    .arg(dir.path().join("scene.eco"))
                    .arg("--sky")
                    .arg(dir.path().join("sky.hdr"))
                    .args(["--preview", "--quiet", "--cache"])
                    .arg(&cache)
                    .arg("-o")
                    .arg(dir.path().join(format!("{n}{round}.bake")))
                    .spawn()
                    .unwrap()
            })
            .collect();
        for mut c in children {
            assert!(c.wait().unwrap().success(), "round {round}");
        }
        for n in ["x", "y"] {
            let got = std::fs::read(dir.path().join(format!("{n}{round}.bake"))).unwrap();
            assert!(
                got == want,
                "round {round}: {n} differs from the uncached bake"
            );
        }
    }
    let stats = bake::graph::cache::Cache::new(&cache).stats();
    assert_eq!(stats.stale_temporaries, 0);
}

/// Every regular file under `roots` that the process opened for reading, from strace.
fn opened_under(log: &Path, roots: &[PathBuf]) -> BTreeSet<PathBuf> {
    let text = std::fs::read_to_string(log).unwrap();
    let mut out = BTreeSet::new();
    for line in text.lines() {
        if !line.contains("openat(") || line.contains("O_DIRECTORY") || line.contains("= -1") {
            continue;
        }
        if line.contains("O_WRONLY") || line.contains("O_RDWR") {
            continue;
        }
        let Some(start) = line.find('"') else {
            continue;
        };
        let Some(len) = line[start + 1..].find('"') else {
            continue;
        };
        let p = PathBuf::from(&line[start + 1..start + 1 + len]);
        if roots.iter().any(|r| p.starts_with(r)) && p.is_file() {
            out.insert(p);
        }
    }
    out
}

#[test]
fn the_depfile_lists_exactly_the_files_read() {
    if !common::tool_available("strace", "peer tool for the depfile oracle") {
        return;
    }
    // The scene in one folder, the plant and its texture in a --models folder.
    let dir = scene();
    let scene_dir = dir.path().join("scene");
    let models = dir.path().join("models");
    std::fs::create_dir_all(&scene_dir).unwrap();
    std::fs::create_dir_all(&models).unwrap();
    for f in std::fs::read_dir(dir.path()).unwrap() {
        let p = f.unwrap().path();
        if p.is_file() {
            let name = p.file_name().unwrap().to_owned();
            let to = if name == "plant.txf" || name == "leaf.rgb" {
                models.join(&name)
            } else {
                scene_dir.join(&name)
            };
            std::fs::rename(&p, to).unwrap();
        }
    }
    let scene_dir = scene_dir.canonicalize().unwrap();
    let models = models.canonicalize().unwrap();
    let log = dir.path().join("strace.log");
    let dep = dir.path().join("out.d");
    let out = dir.path().join("out.bake");
    let status = std::process::Command::new("strace")
        .args(["-f", "-qq", "-e", "trace=openat", "-o"])
        .arg(&log)
        .arg(common::bake_bin())
        .arg(scene_dir.join("scene.eco"))
        .arg("--sky")
        .arg(scene_dir.join("sky.hdr"))
        .arg("--models")
        .arg(&models)
        .args(["--preview", "--quiet", "--no-cache", "--depfile"])
        .arg(&dep)
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let opened = opened_under(&log, &[scene_dir.clone(), models.clone()]);
    let text = std::fs::read_to_string(&dep).unwrap();
    let (target, deps) = text.split_once(':').unwrap();
    assert_eq!(Path::new(target), out);
    let listed: BTreeSet<PathBuf> = deps
        .split_whitespace()
        .filter(|w| *w != "\\")
        .map(PathBuf::from)
        .collect();
    assert_eq!(listed, opened, "depfile vs. files opened (strace)");
    // The textures of both folders are there, and the plant came from the --models folder.
    for f in [
        models.join("leaf.rgb"),
        models.join("plant.txf"),
        scene_dir.join("objwood.png"),
    ] {
        assert!(listed.contains(&f), "{}", f.display());
    }
    assert_eq!(listed.len(), 8, "{listed:?}");
}

#[test]
fn pipeline_files_and_overrides_on_the_command_line() {
    let dir = scene();
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[stages]\nprt = true\n\n[prt]\nsamples = 64\nbounce = 2\n",
    )
    .unwrap();
    let out = common::bake(&[
        dir.path().join("scene.eco").to_str().unwrap(),
        "--pipeline",
        bad.to_str().unwrap(),
        "--no-cache",
    ]);
    assert_eq!(out.status.code(), Some(4));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("line 6") && err.contains("bounce"),
        "{err}"
    );
    let out = common::bake(&[
        dir.path().join("scene.eco").to_str().unwrap(),
        "--set",
        "prt.samples=lots",
    ]);
    assert_eq!(out.status.code(), Some(2));
    // A good file with an override: the report shows the override took effect.
    let good = dir.path().join("good.toml");
    std::fs::write(&good, "[stages]\nlightmap = false\natlas = false\n").unwrap();
    let out = common::bake(&[
        dir.path().join("scene.eco").to_str().unwrap(),
        "--pipeline",
        good.to_str().unwrap(),
        "--set",
        "envmaps.samples=16",
        "--set",
        "prt.samples=16",
        "--no-cache",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let stages: BTreeSet<&str> = r["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["stage"].as_str().unwrap())
        .collect();
    assert!(!stages.contains("lightmap") && !stages.contains("atlas"));
    assert!(stages.contains("prt") && stages.contains("cluster"));
    for key in [
        "output",
        "bytes",
        "sections",
        "models",
        "instances",
        "triangles",
        "warnings",
        "wall_seconds",
        "peak_rss_bytes",
    ] {
        assert!(r.get(key).is_some(), "{key}");
    }
    let files: Vec<&str> = r["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(
        files.iter().any(|f| f.ends_with("good.toml")),
        "the pipeline file is a dependency"
    );
}

/// Bakes the fixture scene without a cache on a pool of `threads` threads.
fn bake_on_threads(
    dir: &Path,
    threads: usize,
    out: &str,
    observer: &dyn bake::graph::progress::Observer,
) -> BuildReport {
    let mut o = opts(dir, out, &dir.join("unused-cache"));
    o.cache = CacheMode::Off;
    o.pipeline = Pipeline::default_pipeline();
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| build(&o, observer).unwrap())
}

/// Units run side by side on two threads (the models' PRT and LOD units beside the sky and the
/// lighting; issue 37, item 3): the pack is the same bytes as on one thread, where they run in
/// turn, and the report lists the same units in the same order (each model's ingest,
/// material, prt, lod together, then the scene's units) with the same warnings.
#[test]
fn one_and_two_threads_bake_the_same_pack_and_report() {
    let dir = scene();
    let one = bake_on_threads(dir.path(), 1, "one.bake", &Silent);
    let two = bake_on_threads(dir.path(), 2, "two.bake", &Silent);
    let a = std::fs::read(dir.path().join("one.bake")).unwrap();
    assert_eq!(a, std::fs::read(dir.path().join("two.bake")).unwrap());
    assert_eq!(one.pack_blake3, two.pack_blake3);
    assert_eq!(one.sections, two.sections);
    let units = |r: &BuildReport| -> Vec<String> {
        r.stages
            .iter()
            .map(|s| format!("{} {}", s.stage, s.unit))
            .collect()
    };
    assert_eq!(units(&one), units(&two));
    assert_eq!(
        serde_json::to_value(&one.warnings).unwrap(),
        serde_json::to_value(&two.warnings).unwrap()
    );
    // The serial order: per model its four units in a row; the sky after every model.
    let u = units(&one);
    let sky = u.iter().position(|x| x == "sky sky").unwrap();
    for (i, x) in u.iter().enumerate() {
        if let Some(model) = x.strip_prefix("ingest ") {
            let want: Vec<String> = ["ingest", "material", "prt", "lod"]
                .iter()
                .map(|s| format!("{s} {model}"))
                .collect();
            assert_eq!(&u[i..i + 4], &want[..], "{u:?}");
            assert!(i + 4 <= sky, "{u:?}");
        }
    }
    assert!(u[sky..].iter().any(|x| x == "lightmap terrain"), "{u:?}");
    // The sections in the pack keep that order: each model's PRT and LOD right after its mesh.
    let pack = bake::pack::Pack::open(&dir.path().join("two.bake")).unwrap();
    let names: Vec<&str> = pack.sections().iter().map(|e| e.name.as_str()).collect();
    for (i, n) in names.iter().enumerate() {
        if let Some(model) = n.strip_prefix("prt:") {
            assert_eq!(names[i + 1], format!("lod:{model}"), "{names:?}");
            let mesh = names
                .iter()
                .position(|m| *m == format!("mesh:{model}"))
                .unwrap();
            assert!(
                names[mesh + 1..i]
                    .iter()
                    .all(|m| !m.starts_with("mesh:") && !m.starts_with("prt:")),
                "{names:?}"
            );
        }
    }
    // Every unit's busy cores is its CPU over its wall time.
    for s in &two.stages {
        if s.wall_seconds > 0.01 {
            let want = s.cpu_seconds / s.wall_seconds;
            assert!((s.busy_cores - want).abs() <= 0.006, "{s:?}");
        }
    }
}

/// Progress events of units that run at the same time stay well formed: every unit starts
/// once, reports progress only between its start and its end, and ends once (the terminal
/// view keeps one line per running unit, keyed the same way).
#[test]
fn progress_events_of_concurrent_units_stay_well_formed() {
    use std::sync::Mutex;
    #[derive(Default)]
    struct Events(Mutex<Vec<(char, String)>>);
    impl bake::graph::progress::Observer for Events {
        fn start(&self, stage: &str, unit: &str, _total: Option<u64>) {
            self.0
                .lock()
                .unwrap()
                .push(('s', format!("{stage} {unit}")));
        }
        fn progress(&self, stage: &str, unit: &str, _n: u64) {
            self.0
                .lock()
                .unwrap()
                .push(('p', format!("{stage} {unit}")));
        }
        fn end(&self, r: &bake::graph::StageRecord) {
            self.0
                .lock()
                .unwrap()
                .push(('e', format!("{} {}", r.stage, r.unit)));
        }
    }
    let dir = scene();
    let events = Events::default();
    let report = bake_on_threads(dir.path(), 2, "p.bake", &events);
    let events = events.0.into_inner().unwrap();
    let mut running: BTreeSet<String> = BTreeSet::new();
    let mut ended: BTreeSet<String> = BTreeSet::new();
    let mut progressed = 0;
    for (what, unit) in &events {
        match what {
            's' => assert!(
                running.insert(unit.clone()) && !ended.contains(unit),
                "{unit}"
            ),
            'p' => {
                assert!(running.contains(unit), "progress outside its unit: {unit}");
                progressed += 1;
            }
            _ => {
                assert!(running.remove(unit), "{unit}");
                ended.insert(unit.clone());
            }
        }
    }
    assert!(running.is_empty() && progressed > 0);
    let recorded: BTreeSet<String> = report
        .stages
        .iter()
        .map(|s| format!("{} {}", s.stage, s.unit))
        .collect();
    assert_eq!(ended, recorded);
}
