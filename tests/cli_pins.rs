//! Black-box pins of the `bake` binary (issue 13, item 7; KTX-Software's tool tests are the
//! model): for each case, the exact stdout, stderr and exit code of a main command on a good
//! or a bad input, kept in `tests/pins/<case>.txt`, so an error message cannot silently
//! degrade. The cases run in order in a temporary copy of the fixture scene, with relative
//! paths; the temporary folder's path is written `$DIR` in the pins.
//!
//! **Regenerating** after a deliberate change of a message or a report (review the diff):
//!
//! ```sh
//! BAKE_BLESS=1 cargo test --test cli_pins
//! ```

use std::path::{Path, PathBuf};
use std::process::Command;

/// (case name, arguments), run in this order in `$DIR/scene`.
const CASES: &[(&str, &[&str])] = &[
    ("no_arguments", &[]),
    ("unknown_command", &["frobnicate"]),
    ("ingest_scene", &["ingest", "scene.eco", "-o", "scene.bake"]),
    (
        "ingest_scene_json",
        &["--json", "ingest", "scene.eco", "-o", "scene.bake"],
    ),
    ("dump_scene", &["dump", "scene.bake"]),
    (
        "dump_no_such_section",
        &["dump", "scene.bake", "--section", "nope"],
    ),
    ("dump_missing_file", &["dump", "missing.bake"]),
    ("dump_not_a_pack", &["dump", "scene.eco"]),
    ("dump_future_version", &["dump", "future.bake"]),
    ("verify_scene", &["verify", "scene.bake"]),
    ("verify_scene_json", &["verify", "--json", "scene.bake"]),
    ("verify_flipped_bit", &["verify", "flipped.bake"]),
    (
        "verify_flipped_bit_json",
        &["--json", "verify", "flipped.bake"],
    ),
    ("verify_future_version", &["verify", "future.bake"]),
    ("verify_missing_file", &["verify", "missing.bake"]),
    ("verify_no_file", &["verify"]),
    (
        "ingest_bad_eco_line",
        &["ingest", "bad.eco", "-o", "bad.bake"],
    ),
    (
        "ingest_model_outside",
        &["ingest", "escape.eco", "-o", "escape.bake"],
    ),
    (
        "ingest_model_outside_allowed",
        &[
            "ingest",
            "escape.eco",
            "-o",
            "escape.bake",
            "--allow-path",
            "../outside",
        ],
    ),
    (
        "ingest_over_budget",
        &[
            "ingest",
            "scene.eco",
            "-o",
            "budget.bake",
            "--max-memory",
            "16K",
        ],
    ),
    (
        "ingest_bad_budget",
        &["ingest", "scene.eco", "--max-memory", "lots"],
    ),
    ("ingest_raw_without_size", &["ingest", "terrain.raw"]),
    (
        "ingest_raw_wrong_size",
        &["ingest", "terrain.raw", "--size", "3x3"],
    ),
    ("ingest_unknown_kind", &["ingest", "notes.txt"]),
];

fn pins_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pins")
}

/// The fixture scene in `$DIR/scene`, a copy of the plant in `$DIR/outside`, and the bad
/// inputs the cases use (made from the scene pack once `ingest_scene` has written it).
fn setup(root: &Path) -> PathBuf {
    let scene = root.join("scene");
    bake::fixtures::write_all(&scene).unwrap();
    std::fs::create_dir_all(root.join("outside")).unwrap();
    std::fs::copy(scene.join("plant.txf"), root.join("outside/plant.txf")).unwrap();
    std::fs::copy(scene.join("leaf.rgb"), root.join("outside/leaf.rgb")).unwrap();
    let eco = std::fs::read_to_string(scene.join("scene.eco")).unwrap();
    std::fs::write(
        scene.join("escape.eco"),
        eco.replacen("\nplant ", "\n../outside/plant.txf ", 1),
    )
    .unwrap();
    std::fs::write(
        scene.join("bad.eco"),
        "terrain.raw 65 65 1 0.05\n<GEOREF> 0 0 100 100 0 0 100 100\n<ECO>\nplant 0.5 half 1 0\n",
    )
    .unwrap();
    std::fs::write(scene.join("notes.txt"), "not an input\n").unwrap();
    scene
}

/// Packs made from `scene.bake`: one bit flipped in a payload, and a future format version.
fn derive_bad_packs(scene: &Path) {
    let b = std::fs::read(scene.join("scene.bake")).unwrap();
    let mut flipped = b.clone();
    flipped[4096 + 100] ^= 0x10;
    std::fs::write(scene.join("flipped.bake"), flipped).unwrap();
    let mut future = b;
    future[8..12].copy_from_slice(&(bake::pack::VERSION + 1).to_le_bytes());
    std::fs::write(scene.join("future.bake"), future).unwrap();
}

fn run(scene: &Path, root: &Path, args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_bake"))
        .args(args)
        .current_dir(scene)
        .env("NODEVICE_SELECT", "1")
        .env_remove("BAKE_LOG")
        .output()
        .unwrap();
    let text = format!(
        "$ bake {}\nexit: {}\n--- stdout\n{}--- stderr\n{}",
        args.join(" "),
        o.status.code().map_or("signal".into(), |c| c.to_string()),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let canonical = std::fs::canonicalize(root).unwrap();
    text.replace(&canonical.display().to_string(), "$DIR")
        .replace(&root.display().to_string(), "$DIR")
}

#[test]
fn stdout_stderr_and_exit_codes_are_pinned() {
    let dir = tempfile::tempdir().unwrap();
    let scene = setup(dir.path());
    let bless = std::env::var_os("BAKE_BLESS").is_some();
    let mut failed = Vec::new();
    for (name, args) in CASES {
        let got = run(&scene, dir.path(), args);
        if *name == "ingest_scene" {
            derive_bad_packs(&scene);
        }
        let path = pins_dir().join(format!("{name}.txt"));
        if bless {
            std::fs::create_dir_all(pins_dir()).unwrap();
            std::fs::write(&path, &got).unwrap();
            continue;
        }
        let want = std::fs::read_to_string(&path).unwrap_or_default();
        if want != got {
            failed.push(format!(
                "{}:\n--- pinned\n{want}--- now\n{got}",
                path.display()
            ));
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {} pins differ (if deliberate: BAKE_BLESS=1 cargo test --test cli_pins):\n{}",
        failed.len(),
        CASES.len(),
        failed.join("\n")
    );
}

#[test]
fn every_pin_file_belongs_to_a_case() {
    for e in std::fs::read_dir(pins_dir()).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        let stem = name.strip_suffix(".txt").unwrap_or(&name);
        assert!(
            CASES.iter().any(|(c, _)| *c == stem),
            "tests/pins/{name} has no case"
        );
    }
}
