//! Path confinement (issue 13, item 2): a scene reads only inside its folder, the `--models`
//! folders and the `--allow-path` folders. Each test writes the fixture scene into a temporary
//! `scene/` folder beside an `outside/` folder holding a copy of every file, points one
//! reference at `outside/` (by `..`, by an absolute path, or through a symlink), and checks that
//! `bake ingest` refuses with exit 4 naming the referring file, the line (or byte) and the
//! resolved path, and that `--allow-path outside` makes the same scene ingest. The refusal
//! happens before the referenced file is opened (src/ingest/confine.rs), so nothing outside the
//! roots is read.

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::bake;

struct Scene {
    _dir: tempfile::TempDir,
    scene: PathBuf,
    outside: PathBuf,
}

fn scene() -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let outside = dir.path().join("outside");
    bake::fixtures::write_all(&scene).unwrap();
    bake::fixtures::write_all(&outside).unwrap();
    Scene {
        _dir: dir,
        scene,
        outside,
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ingest(s: &Scene, extra: &[&str]) -> Output {
    let eco = s.scene.join("scene.eco");
    let out = s.scene.join("out.bake");
    let mut args = vec!["ingest", eco.to_str().unwrap(), "-o", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    bake(&args)
}

/// Replaces `from` by `to` in a scene file (the first occurrence).
fn edit(path: &Path, from: &[u8], to: &[u8]) {
    let b = std::fs::read(path).unwrap();
    let at = b
        .windows(from.len())
        .position(|w| w == from)
        .unwrap_or_else(|| {
            panic!(
                "{} has no {:?}",
                path.display(),
                String::from_utf8_lossy(from)
            )
        });
    let mut out = b[..at].to_vec();
    out.extend_from_slice(to);
    out.extend_from_slice(&b[at + from.len()..]);
    std::fs::write(path, out).unwrap();
}

fn line_of(path: &Path, needle: &str) -> usize {
    let text = std::fs::read(path).unwrap();
    let at = text
        .windows(needle.len())
        .position(|w| w == needle.as_bytes())
        .unwrap();
    text[..at].iter().filter(|&&c| c == b'\n').count() + 1
}

/// Exit 4, and the message names the referring file, the place and the resolved path.
fn assert_refused(o: &Output, referrer: &Path, place: &str, resolved: &Path) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(4), "{e}");
    let head = format!("error: {}: {place}: ", referrer.display());
    assert!(e.starts_with(&head), "expected {head:?} in {e}");
    let resolved = std::fs::canonicalize(resolved).unwrap_or(resolved.to_path_buf());
    assert!(
        e.contains(&format!("resolves to {},", resolved.display())),
        "{e}"
    );
    assert!(e.contains("--allow-path"), "{e}");
}

#[test]
fn the_fixture_scene_reads_only_inside_its_folder() {
    let s = scene();
    let o = ingest(&s, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn a_model_name_with_dotdot_is_refused_and_allow_path_admits_it() {
    let s = scene();
    let eco = s.scene.join("scene.eco");
    edit(&eco, b"\nobject.3ds ", b"\n../outside/object.3ds ");
    let line = line_of(&eco, "../outside/object.3ds");
    let o = ingest(&s, &[]);
    assert_refused(
        &o,
        &eco,
        &format!("line {line}"),
        &s.outside.join("object.3ds"),
    );
    let o = ingest(&s, &["--allow-path", s.outside.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn an_absolute_model_path_is_refused() {
    let s = scene();
    let eco = s.scene.join("scene.eco");
    let abs = s.outside.join("object.3ds");
    let name = abs.to_str().unwrap().to_string();
    edit(&eco, b"\nobject.3ds ", format!("\n{name} ").as_bytes());
    let o = ingest(&s, &[]);
    assert_refused(&o, &eco, &format!("line {}", line_of(&eco, &name)), &abs);
    assert!(stderr(&o).contains("an absolute path"), "{}", stderr(&o));
}

#[cfg(unix)]
#[test]
fn a_symlink_out_of_the_scene_is_refused() {
    let s = scene();
    std::fs::remove_file(s.scene.join("object.3ds")).unwrap();
    std::os::unix::fs::symlink(s.outside.join("object.3ds"), s.scene.join("object.3ds")).unwrap();
    let eco = s.scene.join("scene.eco");
    let o = ingest(&s, &[]);
    assert_refused(
        &o,
        &eco,
        &format!("line {}", line_of(&eco, "\nobject.3ds") + 1),
        &s.outside.join("object.3ds"),
    );
}

#[test]
fn the_terrain_may_not_leave_the_scene() {
    let s = scene();
    let eco = s.scene.join("scene.eco");
    edit(&eco, b"terrain.raw", b"../outside/terrain.raw");
    let o = ingest(&s, &[]);
    assert_refused(&o, &eco, "line 1", &s.outside.join("terrain.raw"));
}

#[test]
fn a_txf_texture_with_dotdot_is_refused_naming_the_txf_line() {
    let s = scene();
    let txf = s.scene.join("plant.txf");
    edit(
        &txf,
        b"<tex_name>leaf.rgb",
        b"<tex_name>../outside/leaf.rgb",
    );
    let o = ingest(&s, &[]);
    let line = line_of(&txf, "../outside/leaf.rgb");
    assert_refused(
        &o,
        &txf,
        &format!("line {line}"),
        &s.outside.join("leaf.rgb"),
    );
}

#[test]
fn a_3ds_texture_outside_is_refused_naming_the_byte() {
    let s = scene();
    let max = s.scene.join("object.3ds");
    // Names of the same length keep the chunk lengths right. `../a/WD.PNG` leaves the scene
    // by `..`; `a/objwd.png` through a symlinked folder `a` -> outside.
    edit(&max, b"OBJWOOD.PNG", b"../a/WD.PNG");
    let at = |b: &[u8], n: &[u8]| b.windows(n.len()).position(|w| w == n).unwrap();
    let o = ingest(&s, &[]);
    let place = format!("byte {}", at(&std::fs::read(&max).unwrap(), b"../a/WD.PNG"));
    let root = std::fs::canonicalize(s.scene.parent().unwrap()).unwrap();
    assert_refused(&o, &max, &place, &root.join("a/WD.PNG"));
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&s.outside, s.scene.join("a")).unwrap();
        std::fs::copy(s.outside.join("objwood.png"), s.outside.join("objwd.png")).unwrap();
        edit(&max, b"../a/WD.PNG", b"a/objwd.png");
        let o = ingest(&s, &[]);
        let place = format!("byte {}", at(&std::fs::read(&max).unwrap(), b"a/objwd.png"));
        assert_refused(&o, &max, &place, &s.outside.join("objwd.png"));
    }
}

#[test]
fn obj_mtl_libraries_and_their_textures_stay_inside() {
    let s = scene();
    std::fs::write(s.outside.join("m.mtl"), "newmtl a\nKd 1 0 0\n").unwrap();
    let obj = s.scene.join("quad.obj");
    std::fs::write(
        &obj,
        "mtllib ../outside/m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n",
    )
    .unwrap();
    let out = s.scene.join("q.bake");
    let o = bake(&["ingest", obj.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_refused(&o, &obj, "line 1", &s.outside.join("m.mtl"));

    std::fs::write(
        s.scene.join("m.mtl"),
        "newmtl a\nKd 1 0 0\nmap_Kd ../outside/objwood.png\n",
    )
    .unwrap();
    std::fs::write(
        &obj,
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl a\nf 1/1 2/1 3/1\n",
    )
    .unwrap();
    let o = bake(&["ingest", obj.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_refused(
        &o,
        &s.scene.join("m.mtl"),
        "line 3",
        &s.outside.join("objwood.png"),
    );
    let o = bake(&[
        "ingest",
        obj.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--allow-path",
        s.outside.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn gltf_external_buffers_stay_inside_and_data_uris_need_no_file() {
    let s = scene();
    std::fs::write(s.outside.join("b.bin"), [0u8; 36]).unwrap();
    let doc = |uri: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
"buffers":[{{"byteLength":36,"uri":"{uri}"}}],
"bufferViews":[{{"buffer":0,"byteLength":36}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}}]}}"#
        )
    };
    let gltf = s.scene.join("m.gltf");
    let out = s.scene.join("m.bake");
    std::fs::write(&gltf, doc("../outside/b.bin")).unwrap();
    let o = bake(&[
        "ingest",
        gltf.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_refused(&o, &gltf, "line 3", &s.outside.join("b.bin"));
    let zeros = "data:application/octet-stream;base64,".to_string() + &"A".repeat(48);
    std::fs::write(&gltf, doc(&zeros)).unwrap();
    let o = bake(&[
        "ingest",
        gltf.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn further_eco_files_stay_inside() {
    let s = scene();
    let out = s.scene.join("out.bake");
    let first = s.scene.join("scene.eco");
    let further = s.outside.join("scene.eco");
    let o = bake(&[
        "build",
        first.to_str().unwrap(),
        further.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--preview",
    ]);
    assert_refused(&o, &further, "command line", &further);
}
