//! Relocatable packs (issue 36, item 5): a pack does not depend on where its scene lies or how
//! its paths were written. Sections, the build record and the cache keys name files relative to
//! the scene's roots (`scene:`, `models/<i>:`, `allow/<i>:`; docs/FORMAT.md, "Source names").
//!
//! The fixture scene is laid out twice, in two folders of different depth, each as a scene
//! folder `fx/` and a `--models` folder `lib/` holding the plant and its texture. Each copy is
//! baked by absolute paths, by relative paths and from another working directory: every pack is
//! the same bytes, section by section; no payload holds a host path. A second checkout sharing
//! the first's stage cache gets hits only; `bake plan --emit ninja` with paths written one way
//! gives the pack of a direct bake with paths written another; the depfile lists the real,
//! absolute paths of the checkout that was baked.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Every stage, the SVO and the line space included (their sections record the scene's source).
const PIPELINE: [&str; 6] = [
    "--pipeline",
    "ci",
    "--set",
    "stages.svo=true",
    "--set",
    "stages.linespace=true",
];

/// The fixture scene in `top/fx`, its plant and the plant's texture moved to `top/lib`.
fn checkout(top: &Path) {
    let fx = top.join("fx");
    let lib = top.join("lib");
    bake::fixtures::write_all(&fx).unwrap();
    std::fs::create_dir_all(&lib).unwrap();
    for f in ["plant.txf", "leaf.rgb"] {
        std::fs::rename(fx.join(f), lib.join(f)).unwrap();
    }
    std::fs::create_dir_all(top.join("work")).unwrap();
}

fn run_in(dir: &Path, program: &Path, args: &[String]) -> Output {
    let o = Command::new(program)
        .args(args)
        .current_dir(dir)
        .env("NODEVICE_SELECT", "1")
        .env_remove("BAKE_CACHE")
        .output()
        .expect("run");
    assert!(
        o.status.success(),
        "{} {args:?} in {}: {}\n{}",
        program.display(),
        dir.display(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// How the paths of one bake are written.
#[derive(Debug, Clone, Copy)]
enum Style {
    /// Absolute paths, run from the temporary folder's root.
    Absolute,
    /// Relative to the working directory, run from the temporary folder's root.
    Relative,
    /// Run in the checkout's `work` folder, paths through `..` and `.`.
    OtherDir,
}

/// (working directory, scene, sky, models folder) of a bake of the checkout `top` in `style`.
fn spelled(root: &Path, top: &Path, style: Style) -> (PathBuf, [String; 3]) {
    let s = |p: PathBuf| p.display().to_string();
    match style {
        Style::Absolute => (
            root.to_path_buf(),
            [
                s(top.join("fx/scene.eco")),
                s(top.join("fx/sky.hdr")),
                s(top.join("lib")),
            ],
        ),
        Style::Relative => {
            let rel = top.strip_prefix(root).unwrap();
            (
                root.to_path_buf(),
                [
                    s(rel.join("fx/scene.eco")),
                    s(rel.join("fx/sky.hdr")),
                    s(rel.join("lib")),
                ],
            )
        }
        Style::OtherDir => (
            top.join("work"),
            [
                "../fx/./scene.eco".into(),
                "./../fx/sky.hdr".into(),
                "../lib/".into(),
            ],
        ),
    }
}

/// `bake SCENE --sky SKY --models LIB -o OUT` of `top` in `style`, plus `extra`; the process'
/// output.
fn bake(root: &Path, top: &Path, style: Style, out: &Path, extra: &[&str]) -> Output {
    let (cwd, [scene, sky, lib]) = spelled(root, top, style);
    let mut args: Vec<String> = vec![
        scene,
        "--sky".into(),
        sky,
        "--models".into(),
        lib,
        "-o".into(),
        out.display().to_string(),
    ];
    args.extend(PIPELINE.iter().chain(extra).map(|a| a.to_string()));
    run_in(&cwd, &common::bake_bin(), &args)
}

/// (name, kind, payload) of every section, in order.
fn sections(bytes: &[u8]) -> Vec<(String, String, Vec<u8>)> {
    let pack = bake::pack::Pack::from_bytes(bytes, "pack").unwrap();
    pack.sections()
        .iter()
        .map(|e| (e.name.clone(), e.kind.clone(), pack.payload(e).to_vec()))
        .collect()
}

/// The names of the sections of `b` whose payload differs from `a`'s (or that only one has).
fn differing(a: &[u8], b: &[u8]) -> Vec<String> {
    let (a, b) = (sections(a), sections(b));
    let mut out: Vec<String> = a
        .iter()
        .filter(|s| !b.contains(s))
        .chain(b.iter().filter(|s| !a.contains(s)))
        .map(|s| s.0.clone())
        .collect();
    out.dedup();
    out
}

fn contains(hay: &[u8], needle: &[u8]) -> bool {
    hay.windows(needle.len()).any(|w| w == needle)
}

/// The section's `source` as `bake dump --json` shows it.
fn dumped_sources(pack: &Path) -> Vec<(String, String)> {
    let o = common::bake(&["dump", "--json", pack.to_str().unwrap()]);
    let v = common::json(&o);
    v["sections"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|s| {
            let src = s["summary"]["source"].as_str()?;
            Some((s["name"].as_str()?.to_string(), src.to_string()))
        })
        .collect()
}

#[test]
fn two_folders_baked_three_ways_give_the_same_bytes_in_every_section() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let tops = [root.join("a"), root.join("b/deeper/still")];
    for t in &tops {
        checkout(t);
    }
    let styles = [Style::Absolute, Style::Relative, Style::OtherDir];
    let mut packs: Vec<(String, Vec<u8>)> = Vec::new();
    for (i, top) in tops.iter().enumerate() {
        for style in styles {
            let out = root.join(format!("out-{i}-{style:?}.bake"));
            bake(root, top, style, &out, &["--no-cache", "-q"]);
            packs.push((
                format!("{} {style:?}", top.display()),
                std::fs::read(&out).unwrap(),
            ));
        }
    }
    let (first, reference) = &packs[0];
    assert!(sections(reference).len() >= 20, "every stage ran");
    for (what, bytes) in &packs[1..] {
        assert!(
            differing(reference, bytes).is_empty(),
            "{what} vs {first}: sections {:?} differ",
            differing(reference, bytes)
        );
        assert!(bytes == reference, "{what} vs {first}: the files differ");
    }
    // No payload holds a host path (the temporary folder, as given or canonical).
    let canonical = std::fs::canonicalize(root).unwrap();
    for (name, _, payload) in sections(reference) {
        for p in [root, canonical.as_path()] {
            assert!(
                !contains(&payload, p.display().to_string().as_bytes()),
                "section {name} holds the path {}",
                p.display()
            );
        }
        assert!(
            !contains(&payload, b"../"),
            "section {name} holds a `../` path"
        );
    }
    // The sources by root: the scene's folder, the --models folder.
    let sources = dumped_sources(&root.join("out-0-Absolute.bake"));
    let source = |name: &str| {
        sources
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("{name} in {sources:?}"))
            .1
            .as_str()
    };
    assert_eq!(source("mesh:plant.txf"), "models/0:plant.txf");
    assert_eq!(source("texture:plant.txf/leaf.rgb"), "models/0:leaf.rgb");
    assert_eq!(source("mesh:object.3ds"), "scene:object.3ds");
    assert_eq!(
        source("texture:object.3ds/OBJWOOD.PNG"),
        "scene:objwood.png"
    );
    assert_eq!(source("terrain"), "scene:scene.eco");
    assert_eq!(source("svo"), "scene:scene.eco");
    assert_eq!(source("linespace"), "scene:scene.eco");
}

#[test]
fn a_second_checkout_sharing_the_stage_cache_gets_only_hits_and_its_own_depfile() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let (a, b) = (root.join("one"), root.join("two/checkouts/deep"));
    checkout(&a);
    checkout(&b);
    let cache = root.join("shared-cache");
    let cache_arg = cache.to_str().unwrap();
    let report = |o: &Output| -> serde_json::Value { serde_json::from_slice(&o.stdout).unwrap() };
    let first = report(&bake(
        root,
        &a,
        Style::Absolute,
        &root.join("one.bake"),
        &["--cache", cache_arg, "--json"],
    ));
    assert_eq!(first["cache_hits"], 0, "{first}");
    let misses = first["cache_misses"].as_u64().unwrap();
    assert!(misses >= 10, "{first}");
    // The second checkout, its paths written another way, in another working directory.
    let dep = root.join("two.d");
    let second = report(&bake(
        root,
        &b,
        Style::OtherDir,
        &root.join("two.bake"),
        &[
            "--cache",
            cache_arg,
            "--json",
            "--depfile",
            dep.to_str().unwrap(),
        ],
    ));
    assert_eq!(second["cache_misses"], 0, "{second}");
    assert_eq!(second["cache_hits"].as_u64(), Some(misses), "{second}");
    for s in second["stages"].as_array().unwrap() {
        assert_eq!(s["cache"], "hit", "{s}");
    }
    let (one, two) = (
        std::fs::read(root.join("one.bake")).unwrap(),
        std::fs::read(root.join("two.bake")).unwrap(),
    );
    assert!(
        differing(&one, &two).is_empty(),
        "{:?}",
        differing(&one, &two)
    );
    assert!(one == two);
    // The entries name no host path.
    let canonical = std::fs::canonicalize(root).unwrap();
    for e in walk(&cache) {
        let bytes = std::fs::read(&e).unwrap();
        assert!(
            !contains(&bytes, canonical.display().to_string().as_bytes()),
            "cache entry {} holds a host path",
            e.display()
        );
    }
    // The depfile lists the second checkout's files (the hits' files placed in its roots), by
    // their real absolute paths, and the report the same list.
    let b_real = std::fs::canonicalize(&b).unwrap();
    let listed = depfile_entries(&dep);
    let expected: Vec<PathBuf> = [
        "fx/object.3ds",
        "fx/objwood.png",
        "fx/scene.eco",
        "fx/sky.hdr",
        "fx/terrain.png",
        "fx/terrain.raw",
        "lib/leaf.rgb",
        "lib/plant.txf",
    ]
    .iter()
    .map(|f| b_real.join(f))
    .collect();
    assert_eq!(listed, expected);
    let files: Vec<PathBuf> = second["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| PathBuf::from(f.as_str().unwrap()))
        .collect();
    assert_eq!(files, expected);
    // Up to date now: the same depfile again, without reading anything else.
    let dep2 = root.join("again.d");
    let third = report(&bake(
        root,
        &b,
        Style::Relative,
        &root.join("two.bake"),
        &[
            "--cache",
            cache_arg,
            "--json",
            "--depfile",
            dep2.to_str().unwrap(),
        ],
    ));
    assert_eq!(third["up_to_date"], true, "{third}");
    assert_eq!(depfile_entries(&dep2), expected);
}

/// The dependencies of a Makefile rule written by `--depfile` (no escaped spaces in these).
fn depfile_entries(dep: &Path) -> Vec<PathBuf> {
    let text = std::fs::read_to_string(dep).unwrap();
    let (_, deps) = text.split_once(':').unwrap();
    let listed: Vec<PathBuf> = deps
        .split_whitespace()
        .filter(|w| *w != "\\")
        .map(PathBuf::from)
        .collect();
    for p in &listed {
        assert!(p.is_absolute() && p.is_file(), "{}", p.display());
        assert_eq!(&std::fs::canonicalize(p).unwrap(), p, "real path");
    }
    listed
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn the_ninja_plan_gives_the_direct_bakes_pack_however_the_paths_were_written() {
    if !common::tool_available("ninja", "the Ninja build of the plan") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let (a, b) = (root.join("a"), root.join("b/elsewhere"));
    checkout(&a);
    checkout(&b);
    // The plan of the first checkout, by relative paths from the temporary root.
    let mut args: Vec<String> = [
        "-q",
        "plan",
        "a/fx/scene.eco",
        "--sky",
        "a/fx/sky.hdr",
        "--models",
        "a/lib",
        "--emit",
        "ninja",
        "-o",
        "build",
        "--lightmap-shards",
        "2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.extend(PIPELINE.iter().map(|s| s.to_string()));
    run_in(root, &common::bake_bin(), &args);
    run_in(&root.join("build"), Path::new("ninja"), &[]);
    let built = std::fs::read(root.join("build/scene.bake")).unwrap();
    // Direct bakes: the same checkout by absolute paths, the other one from its work folder.
    for (top, style) in [(&a, Style::Absolute), (&b, Style::OtherDir)] {
        let out = root.join(format!("direct-{style:?}.bake"));
        bake(root, top, style, &out, &["--no-cache", "-q"]);
        let direct = std::fs::read(&out).unwrap();
        assert!(
            differing(&built, &direct).is_empty(),
            "{style:?}: sections {:?} differ from the Ninja build's",
            differing(&built, &direct)
        );
        assert!(built == direct, "{style:?}: the files differ");
    }
}

#[test]
fn an_entry_of_the_first_checkout_never_skips_a_refusal_in_the_second() {
    // The second checkout's leaf texture is a symlink out of its roots, to the same bytes: the
    // ingest unit's key is the first checkout's (same model, name and layout), but the entry's
    // `models/0:leaf.rgb` does not place inside the second checkout's roots, so the unit runs
    // and the confinement refuses the texture.
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let (a, b) = (root.join("a"), root.join("b"));
    checkout(&a);
    checkout(&b);
    let cache = root.join("cache");
    let cache_arg = cache.to_str().unwrap();
    bake(
        root,
        &a,
        Style::Absolute,
        &root.join("a.bake"),
        &["--cache", cache_arg, "-q"],
    );
    std::fs::create_dir_all(root.join("elsewhere")).unwrap();
    std::fs::rename(b.join("lib/leaf.rgb"), root.join("elsewhere/leaf.rgb")).unwrap();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(root.join("elsewhere/leaf.rgb"), b.join("lib/leaf.rgb"))
            .unwrap();
        let (cwd, [scene, sky, lib]) = spelled(root, &b, Style::Absolute);
        let mut args: Vec<String> = vec![
            scene,
            "--sky".into(),
            sky,
            "--models".into(),
            lib,
            "--cache".into(),
            cache_arg.into(),
            "-o".into(),
            root.join("b.bake").display().to_string(),
        ];
        args.extend(PIPELINE.iter().map(|a| a.to_string()));
        let o = Command::new(common::bake_bin())
            .args(&args)
            .current_dir(cwd)
            .env("NODEVICE_SELECT", "1")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(4), "{err}");
        assert!(
            err.contains("leaf.rgb") && err.contains("--allow-path"),
            "{err}"
        );
    }
}
