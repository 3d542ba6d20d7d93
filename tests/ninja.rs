//! The stage graph as Ninja actions (issue 17): `bake plan --emit ninja` of the fixture scene
//! (env maps in two shards, the terrain light map in two row shards),
//! built by the real `ninja`, against the single-process `bake SCENE.eco` (byte identity), ninja's
//! own `-n` output (no work after a build; after one model changes, only that model's actions
//! and the scene actions that read them), and every action run alone in a folder holding only
//! its declared inputs.

mod common;

use std::collections::BTreeSet;
use std::path::{Component, Path, PathBuf};
use std::process::{Command, Output};

/// The plan's pipeline: the CI preset (small env-map shards, so that there are several) with
/// every optional stage on, so that every kind of action is in the plan.
/// The ci preset with the optional stages, its light map traced at least 8 m apart (step 5 on
/// the fixture's 1.54 m texels, where the spacing's default keeps step 2): the row shards carry
/// the widened step to the join.
const PIPELINE: [&str; 8] = [
    "--pipeline",
    "ci",
    "--set",
    "stages.svo=true",
    "--set",
    "stages.linespace=true",
    "--set",
    "lightmap.trace_spacing=8",
];

fn run_in(dir: &Path, program: &Path, args: &[&str]) -> Output {
    Command::new(program)
        .args(args)
        .current_dir(dir)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("run")
}

fn ok(o: Output, what: &str) -> Output {
    assert!(
        o.status.success(),
        "{what}: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// `bake plan fx/scene.eco --sky fx/sky.hdr --emit ninja -o build` with the test pipeline and
/// `extra` arguments.
fn plan_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "-q",
        "plan",
        "fx/scene.eco",
        "--sky",
        "fx/sky.hdr",
        "--emit",
        "ninja",
        "-o",
        "build",
    ];
    args.extend(extra);
    args.extend(PIPELINE);
    args
}

/// A fixture scene in `root/fx` and its Ninja plan in `root/build`.
fn planned(root: &Path) -> PathBuf {
    let fx = root.join("fx");
    bake::fixtures::write_all(&fx).unwrap();
    let args = plan_args(&["--lightmap-shards", "2"]);
    ok(run_in(root, &common::bake_bin(), &args), "bake plan");
    root.join("build")
}

/// `bake ../fx/scene.eco` with the plan's arguments, run in the build folder (no cache).
fn reference(build: &Path, out: &str) -> Vec<u8> {
    let mut args = vec![
        "-q",
        "../fx/scene.eco",
        "--sky",
        "../fx/sky.hdr",
        "--no-cache",
        "-o",
        out,
    ];
    args.extend(PIPELINE);
    ok(run_in(build, &common::bake_bin(), &args), "bake SCENE.eco");
    std::fs::read(build.join(out)).unwrap()
}

fn ninja(build: &Path, args: &[&str]) -> String {
    let o = ok(
        run_in(build, Path::new("ninja"), args),
        &format!("ninja {args:?}"),
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The actions `ninja -n` would run, by their descriptions (`bake <id>`).
fn dry_run(build: &Path) -> BTreeSet<String> {
    ninja(build, &["-n"])
        .lines()
        .filter_map(|l| l.split_once("] bake ").map(|(_, id)| id.trim().to_string()))
        .collect()
}

#[test]
fn the_ninja_build_equals_the_single_process_bake_and_rebuilds_only_what_a_model_change_reaches() {
    if !common::tool_available("ninja", "the Ninja build of the plan") {
        return;
    }
    let root = tempfile::tempdir().unwrap();
    let build = planned(root.path());
    let all = dry_run(&build);
    assert!(
        all.contains("model-000") && all.contains("envmaps-2-of-2") && all.contains("merge"),
        "{all:?}"
    );
    ninja(&build, &[]);
    let built = std::fs::read(build.join("scene.bake")).unwrap();
    let expected = reference(&build, "reference.bake");
    assert!(
        built == expected,
        "the merged pack ({} bytes) differs from `bake SCENE.eco` ({} bytes)",
        built.len(),
        expected.len()
    );

    // Nothing to do after a build.
    let again = ninja(&build, &["-n"]);
    assert!(again.contains("no work to do"), "{again}");

    // One model file changes (rewritten, so newer): its model, PRT and LOD actions and the scene
    // actions that read its pack run again; the other model, the terrain, the sky, the
    // instances and the BitTree do not.
    let ids = |name: &str| -> (String, String, String) {
        let plan = std::fs::read_to_string(build.join("build.ninja")).unwrap();
        let line = plan
            .lines()
            .find(|l| l.contains("unit model") && l.contains(&format!("--name {name}")))
            .unwrap_or_else(|| panic!("no model action for {name}"))
            .to_string();
        let k = line
            .split("models/model-")
            .nth(1)
            .unwrap()
            .split('.')
            .next()
            .unwrap()
            .to_string();
        (format!("model-{k}"), format!("prt-{k}"), format!("lod-{k}"))
    };
    let (model, prt, lod) = ids("plant.txf");
    let (other_model, other_prt, other_lod) = ids("object.3ds");
    std::thread::sleep(std::time::Duration::from_millis(20));
    let plant = root.path().join("fx/plant.txf");
    std::fs::write(&plant, std::fs::read(&plant).unwrap()).unwrap();
    let dirty = dry_run(&build);
    let want: BTreeSet<String> = [
        model.as_str(),
        prt.as_str(),
        lod.as_str(),
        "lightmap-1-of-2",
        "lightmap-2-of-2",
        "lightmap-join",
        "atlas",
        "envmaps-1-of-2",
        "envmaps-2-of-2",
        "envmaps-join",
        "cluster",
        "svo",
        "linespace",
        "record",
        "merge",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    assert_eq!(dirty, want, "ninja -n after {} changed", plant.display());
    for clean in [
        other_model.as_str(),
        other_prt.as_str(),
        other_lod.as_str(),
        "terrain",
        "sky",
        "instances",
        "bittree",
    ] {
        assert!(!dirty.contains(clean), "{clean} would run again");
    }
    // The same bytes, so the rebuilt pack is the same.
    ninja(&build, &[]);
    assert!(std::fs::read(build.join("scene.bake")).unwrap() == expected);
    assert!(ninja(&build, &["-n"]).contains("no work to do"));
}

/// How many leading `..` a relative path has.
fn ups(p: &Path) -> usize {
    p.components()
        .take_while(|c| matches!(c, Component::ParentDir))
        .count()
}

#[test]
fn every_action_succeeds_in_a_folder_holding_only_its_declared_inputs() {
    if !common::tool_available("ninja", "the Ninja build of the plan") {
        return;
    }
    let root = tempfile::tempdir().unwrap();
    let build = planned(root.path());
    ninja(&build, &[]);
    let opts = bake::plan::PlanOptions {
        scenes: vec![root.path().join("fx/scene.eco")],
        sky: Some(root.path().join("fx/sky.hdr")),
        pipeline: Some("ci".into()),
        set: vec![
            "stages.svo=true".into(),
            "stages.linespace=true".into(),
            "lightmap.trace_spacing=8".into(),
        ],
        lightmap_shards: Some(2),
        ..Default::default()
    };
    let plan = bake::plan::make_plan(&opts, &build).unwrap();
    assert!(plan.actions.len() >= 14, "{}", plan.actions.len());
    for a in &plan.actions {
        let sandbox = tempfile::tempdir().unwrap();
        let depth = a
            .inputs
            .iter()
            .chain(&a.lookups)
            .map(|p| ups(p))
            .max()
            .unwrap_or(0);
        let mut run_dir = sandbox.path().to_path_buf();
        for k in 0..depth {
            run_dir.push(format!("d{k}"));
        }
        std::fs::create_dir_all(&run_dir).unwrap();
        for p in a.inputs.iter().chain(&a.lookups) {
            let to = run_dir.join(p);
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::copy(build.join(p), &to)
                .unwrap_or_else(|e| panic!("{}: copy {}: {e}", a.id, p.display()));
        }
        let mut args = vec!["-q".to_string()];
        args.extend(a.args.iter().cloned());
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        ok(
            run_in(&run_dir, &common::bake_bin(), &args),
            &format!("action {} alone", a.id),
        );
        for out in &a.outputs {
            let mine = std::fs::read(run_dir.join(out))
                .unwrap_or_else(|e| panic!("{}: output {}: {e}", a.id, out.display()));
            let theirs = std::fs::read(build.join(out)).unwrap();
            assert!(
                mine == theirs,
                "{}: {} differs from the Ninja build's",
                a.id,
                out.display()
            );
        }
    }
}

#[test]
fn merge_refuses_two_payloads_under_one_name_naming_both_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    let bake = common::bake_bin();
    ok(
        run_in(d, &bake, &["-q", "ingest", "scene.eco", "-o", "a.bake"]),
        "ingest",
    );
    ok(
        run_in(d, &bake, &["-q", "terrain", "a.bake", "-o", "b.bake"]),
        "terrain",
    );
    // The same pack twice is fine (every section kept once) and equals the pack.
    ok(
        run_in(
            d,
            &bake,
            &["-q", "merge", "a.bake", "a.bake", "-o", "aa.bake"],
        ),
        "merge a a",
    );
    assert!(std::fs::read(d.join("aa.bake")).unwrap() == std::fs::read(d.join("a.bake")).unwrap());
    // b's terrain section replaced a's: same name, other bytes.
    let o = run_in(
        d,
        &bake,
        &["-q", "merge", "a.bake", "b.bake", "-o", "ab.bake"],
    );
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("a.bake") && e.contains("b.bake"), "{e}");
    assert!(!d.join("ab.bake").exists(), "no partial output");
    // A unit given the wrong pack names it and writes nothing.
    let o = run_in(
        d,
        &bake,
        &[
            "-q",
            "unit",
            "envmaps-join",
            "scene.eco",
            "--in",
            "a.bake",
            "-o",
            "j.bake",
        ],
    );
    assert_eq!(o.status.code(), Some(4));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("a.bake") && e.contains("envmaps-shard"), "{e}");
    assert!(!d.join("j.bake").exists());
    // A file that is not a pack names itself.
    let o = run_in(
        d,
        &bake,
        &["-q", "merge", "a.bake", "scene.eco", "-o", "x.bake"],
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("scene.eco"));
    assert!(!d.join("x.bake").exists());
}

#[test]
fn a_plan_of_a_bad_scene_names_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    let bake = common::bake_bin();
    let o = run_in(
        d,
        &bake,
        &[
            "-q",
            "plan",
            "missing.eco",
            "--emit",
            "ninja",
            "-o",
            "build",
        ],
    );
    assert_eq!(o.status.code(), Some(3), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.eco"));
    assert!(!d.join("build").exists(), "no partial output");
    // A scene line naming a model that is not there: the ECO file and its line.
    let eco = std::fs::read_to_string(d.join("scene.eco")).unwrap();
    std::fs::write(d.join("bad.eco"), eco.replace("plant ", "nosuchplant ")).unwrap();
    let o = run_in(
        d,
        &bake,
        &["-q", "plan", "bad.eco", "--emit", "ninja", "-o", "build"],
    );
    assert_eq!(o.status.code(), Some(4), "{o:?}");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("bad.eco") && e.contains("line") && e.contains("nosuchplant"),
        "{e}"
    );
    assert!(!d.join("build").exists(), "no partial output");
}

#[test]
fn the_memory_budget_reaches_the_plan_and_every_action() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(&d.join("fx")).unwrap();
    let bake = common::bake_bin();
    let plan = |budget: &str| {
        run_in(
            d,
            &bake,
            &[
                "-q",
                "plan",
                "fx/scene.eco",
                "--emit",
                "ninja",
                "-o",
                "build",
                "--max-memory",
                budget,
            ],
        )
    };
    // The fixture's 128×128 colour map decodes to 64 KiB: a 40 KiB budget refuses it while
    // planning, naming the file, and writes nothing.
    let o = plan("40K");
    assert_eq!(o.status.code(), Some(4), "{o:?}");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("terrain.png") && e.contains("40.0 KiB budget"),
        "{e}"
    );
    assert!(!d.join("build").exists(), "no partial output");
    // 100 KiB is enough; every unit (each reads the scene; the merge reads only packs) carries
    // the budget.
    ok(plan("100K"), "bake plan --max-memory 100K");
    let text = std::fs::read_to_string(d.join("build/build.ninja")).unwrap();
    let actions: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("  args = unit "))
        .collect();
    assert!(actions.len() > 5, "{text}");
    for a in actions {
        assert!(a.contains("--max-memory 102400"), "{a}");
    }
}

#[test]
fn a_plan_with_a_relative_bake_moves_with_its_folder() {
    if !common::tool_available("ninja", "the Ninja build of a moved plan") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("here");
    bake::fixtures::write_all(&d.join("fx")).unwrap();
    std::fs::copy(common::bake_bin(), d.join("bake")).unwrap();
    let args = plan_args(&["--bake", "./bake"]);
    ok(
        run_in(&d, &common::bake_bin(), &args),
        "bake plan --bake ./bake",
    );
    let text = std::fs::read_to_string(d.join("build/build.ninja")).unwrap();
    assert!(text.contains("command = ../bake -q $args"), "{text}");
    assert!(
        !text.contains(dir.path().to_str().unwrap()),
        "no absolute path: {text}"
    );
    // The whole folder moves elsewhere; Ninja builds there the pack of a single-process bake.
    let moved = dir.path().join("elsewhere");
    std::fs::rename(&d, &moved).unwrap();
    ninja(&moved.join("build"), &[]);
    let built = std::fs::read(moved.join("build/scene.bake")).unwrap();
    assert_eq!(built, reference(&moved.join("build"), "ref.bake"));
}

#[test]
fn the_plan_remakes_itself_when_the_scene_changes() {
    if !common::tool_available("ninja", "the Ninja build of a changed scene") {
        return;
    }
    let root = tempfile::tempdir().unwrap();
    let build = planned(root.path());
    ninja(&build, &[]);
    assert!(ninja(&build, &["-n"]).contains("no work to do"));

    // The scene changes: one plant moves, another is removed (the file is rewritten, newer).
    let eco = root.path().join("fx/scene.eco");
    let text = std::fs::read_to_string(&eco).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let first = lines.iter().position(|l| l.starts_with("plant ")).unwrap();
    let mut changed: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    changed[first] = "plant 0.5000 0.5000 1.000 90.0".into();
    changed.remove(first + 1);
    std::fs::write(&eco, changed.join("\n") + "\n").unwrap();
    let mtime = |p: &Path| std::fs::metadata(p).unwrap().modified().unwrap();
    assert!(mtime(&eco) > mtime(&build.join("build.ninja")));

    // One `ninja` remakes build.ninja first, then builds the changed scene: the pack of a
    // single-process bake of the changed scene.
    let out = ninja(&build, &[]);
    assert!(
        out.contains("bake plan (the scene or the pipeline changed)"),
        "{out}"
    );
    let built = std::fs::read(build.join("scene.bake")).unwrap();
    assert!(
        built == reference(&build, "reference.bake"),
        "the rebuilt pack differs from `bake SCENE.eco` of the changed scene"
    );
    assert!(ninja(&build, &["-n"]).contains("no work to do"));

    // The remade build.ninja is the one `bake plan` writes from scratch with the same arguments.
    let args = plan_args(&["--lightmap-shards", "2"]);
    let mut fresh: Vec<&str> = args.clone();
    let o = fresh.iter().position(|a| *a == "-o").unwrap();
    fresh[o + 1] = "fresh";
    ok(
        run_in(root.path(), &common::bake_bin(), &fresh),
        "bake plan",
    );
    let remade = std::fs::read_to_string(build.join("build.ninja")).unwrap();
    let again = std::fs::read_to_string(root.path().join("fresh/build.ninja")).unwrap();
    assert_eq!(remade, again);
    assert!(remade.contains("generator = 1"), "{remade}");
}
