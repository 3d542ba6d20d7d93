//! Golden bytes (issue 13, item 6): the exact bytes of the fixture packs are pinned per pack
//! format version, as BLAKE3 hashes of the whole file and of every section's payload, in
//! `tests/golden/v<VERSION>.txt`. A change to any section's encoding, however small, fails here
//! and names the sections that changed.
//!
//! Three packs are pinned, each made by the `bake` binary from the generated fixture scene
//! (`bake fixtures`) with relative paths, so no host path enters the bytes:
//! `ingest` (`bake ingest scene.eco`), `terrain` (`bake terrain` over it: the prepared terrain)
//! and `build` (`bake scene.eco --sky sky.hdr --preview`: every stage).
//!
//! **Regenerating** after a deliberate change of the bytes (review the diff of the .txt; if
//! readers of the old bytes can no longer read the new ones, bump `pack::VERSION`, which starts
//! a new `v<N>.txt`, and update docs/FORMAT.md):
//!
//! ```sh
//! BAKE_BLESS=1 cargo test --test golden
//! ```

use std::path::{Path, PathBuf};
use std::process::Command;

fn bake_in(dir: &Path, args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_bake"))
        .args(args)
        .current_dir(dir)
        .env("NODEVICE_SELECT", "1")
        // A stage cache of this test's own: a shared one could serve units computed by an older
        // build of the same stage version and hide a changed encoding.
        .env("BAKE_CACHE", dir.join(".bake-cache"))
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "bake {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn golden_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/golden/v{}.txt", bake::pack::VERSION))
}

/// `label  <blake3 of the file>` then `label section-name  <blake3 of its payload>` lines.
fn hashes(label: &str, bytes: &[u8]) -> Vec<String> {
    let pack = bake::pack::Pack::from_bytes(bytes, label).unwrap();
    let mut out = vec![format!("{label} {}", blake3::hash(bytes).to_hex())];
    for e in pack.sections() {
        let h = blake3::hash(pack.payload(e)).to_hex();
        out.push(format!("{label} {} {h}", e.name));
    }
    out
}

fn fixture_packs() -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    bake_in(d, &["-q", "ingest", "scene.eco", "-o", "ingest.bake"]);
    bake_in(d, &["-q", "terrain", "ingest.bake", "-o", "terrain.bake"]);
    bake_in(
        d,
        &[
            "-q",
            "scene.eco",
            "--sky",
            "sky.hdr",
            "-o",
            "build.bake",
            "--preview",
        ],
    );
    let mut lines = Vec::new();
    for label in ["ingest", "terrain", "build"] {
        lines.extend(hashes(
            label,
            &std::fs::read(d.join(format!("{label}.bake"))).unwrap(),
        ));
    }
    lines
}

#[test]
fn fixture_pack_bytes_are_pinned_for_this_format_version() {
    let got = fixture_packs();
    let path = golden_file();
    if std::env::var_os("BAKE_BLESS").is_some() {
        let head = format!(
            "# BLAKE3 of the fixture packs, pack format version {} (tests/golden.rs).\n# Regenerate after a deliberate change: BAKE_BLESS=1 cargo test --test golden\n",
            bake::pack::VERSION
        );
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, head + &got.join("\n") + "\n").unwrap();
    }
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; a new format version needs: BAKE_BLESS=1 cargo test --test golden",
            path.display()
        )
    });
    let want: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    let changed: Vec<&str> = want
        .iter()
        .copied()
        .filter(|l| !got.iter().any(|g| g == l))
        .chain(got.iter().map(String::as_str).filter(|g| !want.contains(g)))
        .collect();
    assert!(
        changed.is_empty(),
        "the fixture packs' bytes changed (pinned in {}):\n{}\nIf the change is deliberate: BAKE_BLESS=1 cargo test --test golden, and review the diff",
        path.display(),
        changed.join("\n")
    );
}

#[test]
fn the_build_is_byte_identical_when_repeated() {
    assert_eq!(fixture_packs(), fixture_packs());
}

#[test]
fn a_pack_of_a_future_version_is_refused_naming_the_version_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    bake_in(d, &["-q", "ingest", "scene.eco", "-o", "ingest.bake"]);
    let mut b = std::fs::read(d.join("ingest.bake")).unwrap();
    let next = bake::pack::VERSION + 1;
    b[8..12].copy_from_slice(&next.to_le_bytes());
    std::fs::write(d.join("future.bake"), &b).unwrap();
    let want = format!(
        "pack format version {next}, this bake reads versions {} to {}",
        bake::pack::READ_VERSIONS[0],
        bake::pack::VERSION
    );
    for cmd in ["dump", "verify", "terrain"] {
        let o = Command::new(env!("CARGO_BIN_EXE_bake"))
            .args([cmd, "future.bake"])
            .current_dir(d)
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(4), "{cmd}: {e}");
        assert!(
            e.contains(&format!("future.bake: byte 8: {want}")),
            "{cmd}: {e}"
        );
    }
}
