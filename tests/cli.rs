//! Black-box tests of the `bake` binary: exit codes, error messages, `dump --json` shape.

use std::path::Path;
use std::process::Output;

mod common;
use common::{bake, json};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn usage_errors_exit_2() {
    assert_eq!(bake(&[]).status.code(), Some(2));
    assert_eq!(bake(&["frobnicate"]).status.code(), Some(2));
    let o = bake(&["ingest", "x.raw"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("needs --size"), "{}", stderr(&o));
    let o = bake(&["ingest", "/nonexistent/x.raw", "--size", "2x2"]);
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
}

#[test]
fn a_scene_where_a_model_is_read_is_named_as_such_with_the_way_round() {
    let dir = tempfile::tempdir().unwrap();
    let eco = write(dir.path(), "scene.eco", b"");
    let out = dir.path().join("s.bake");
    for cmd in ["svo", "linespace"] {
        let o = bake(&[cmd, &eco, "-o", out.to_str().unwrap()]);
        assert_eq!(o.status.code(), Some(4), "{cmd}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(
            e.contains("scene.eco: file name: a scene, not a model"),
            "{e}"
        );
        assert!(e.contains("bake SCENE.eco -o S.bake"), "{e}");
        assert!(!out.exists());
    }
    // An unknown extension keeps the message of every input kind.
    let txt = write(dir.path(), "notes.txt", b"x");
    let e = stderr(&bake(&["svo", &txt]));
    assert!(e.contains("unknown input type"), "{e}");
}

#[test]
fn missing_file_is_an_io_error_naming_the_file() {
    let o = bake(&["dump", "/nonexistent/pack.bake"]);
    assert_eq!(o.status.code(), Some(3));
    assert!(
        stderr(&o).contains("/nonexistent/pack.bake"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn garbage_pack_is_invalid_input() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "x.bake",
        b"this is not a pack, just some text that is long enough to hold a header..",
    );
    let o = bake(&["dump", &p]);
    assert_eq!(o.status.code(), Some(4));
    assert!(stderr(&o).contains("not a bake pack"), "{}", stderr(&o));
    assert!(stderr(&o).contains("x.bake: byte 0"), "{}", stderr(&o));
}

#[test]
fn raw_terrain_round_trips_through_dump() {
    let dir = tempfile::tempdir().unwrap();
    let samples: Vec<u8> = (0..12u8).map(|v| v * 20).collect();
    let raw = write(dir.path(), "t.raw", &samples);
    let out = dir.path().join("t.bake");
    let o = bake(&[
        "ingest",
        &raw,
        "--size",
        "4x3",
        "--scale",
        "0.5",
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc = json(&bake(&["dump", out.to_str().unwrap(), "--json", "--full"]));
    assert_eq!(doc["version"], bake::pack::VERSION);
    let s = &doc["sections"][0];
    assert_eq!(s["kind"], "terrain");
    assert_eq!(s["checksum_ok"], true);
    assert!(s["bytes"].as_u64().unwrap() > 0);
    let sum = &s["summary"];
    assert_eq!(
        (sum["width"].as_u64(), sum["height"].as_u64()),
        (Some(4), Some(3))
    );
    assert_eq!(sum["min_height"].as_f64(), Some(0.0));
    assert_eq!(sum["max_height"].as_f64(), Some(110.0));
    for key in ["origin", "extent"] {
        assert_eq!(sum[key].as_array().map(Vec::len), Some(2), "{key}");
    }
    let heights: Vec<f64> = s["data"]["heights"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let expected: Vec<f64> = samples.iter().map(|&v| v as f64 * 0.5).collect();
    assert_eq!(heights, expected);
    // Without --full there is no data.
    let doc = json(&bake(&["dump", out.to_str().unwrap(), "--json"]));
    assert!(doc["sections"][0].get("data").is_none());
}

#[test]
fn eco_errors_name_file_and_line_and_keep_previous_output() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "t.raw", &[10u8; 16]);
    let good = "t.raw 4 4 1 0.1\n<GEOREF> 0 0 10 10 0 0 10 10\n<ECO>\n<LAYER> 1\n";
    let eco = write(dir.path(), "s.eco", good.as_bytes());
    let out = dir.path().join("s.bake");
    let o = bake(&[&eco, "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = std::fs::read(&out).unwrap();

    write(
        dir.path(),
        "s.eco",
        format!("{good}missing_plant 0.5 0.5 1 0\n").as_bytes(),
    );
    let o = bake(&[&eco]);
    assert_eq!(o.status.code(), Some(4));
    let err = stderr(&o);
    assert!(err.contains("s.eco: line 5"), "{err}");
    assert!(err.contains("missing_plant.txf"), "{err}");
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "a failed run must not touch the previous pack"
    );
    let leftovers = std::fs::read_dir(dir.path())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with(".bake-tmp")
        })
        .count();
    assert_eq!(leftovers, 0);

    write(
        dir.path(),
        "s.eco",
        b"t.raw 4 4 1 0.1\n<GEOREF> 0 0 10 10 0 0 10 10\n<ECO>\nplant 0.5 zero 1 0\n",
    );
    let o = bake(&[&eco]);
    assert_eq!(o.status.code(), Some(4));
    assert!(
        stderr(&o).contains("s.eco: line 4: v position"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn wrong_raw_size_is_reported_with_the_expected_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let raw = write(dir.path(), "t.raw", &[0u8; 10]);
    let o = bake(&["ingest", &raw, "--size", "4x4"]);
    assert_eq!(o.status.code(), Some(4));
    assert!(
        stderr(&o).contains("expected 16 (8-bit) or 32 (16-bit)"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn dump_of_unknown_section_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let raw = write(dir.path(), "t.raw", &[0u8; 4]);
    let out = dir.path().join("t.bake");
    assert!(
        bake(&["ingest", &raw, "--size", "2x2", "-o", out.to_str().unwrap()])
            .status
            .success()
    );
    let o = bake(&["dump", out.to_str().unwrap(), "--section", "nope"]);
    assert_eq!(o.status.code(), Some(2));
    let o = bake(&[
        "dump",
        out.to_str().unwrap(),
        "--section",
        "terrain",
        "--json",
    ]);
    assert_eq!(json(&o)["sections"].as_array().unwrap().len(), 1);
}

#[test]
fn committed_fixtures_match_the_generator() {
    let dir = tempfile::tempdir().unwrap();
    let o = bake(&["fixtures", dir.path().to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scene");
    let mut n = 0;
    for e in std::fs::read_dir(dir.path()).unwrap() {
        let e = e.unwrap();
        let mine = std::fs::read(e.path()).unwrap();
        let theirs = std::fs::read(committed.join(e.file_name())).unwrap_or_default();
        assert!(
            mine == theirs,
            "fixtures/scene/{} differs from `bake fixtures`: regenerate with `cargo run -- fixtures`",
            e.file_name().to_string_lossy()
        );
        n += 1;
    }
    assert!(n >= 8, "{n} fixture files");
}

#[test]
fn fixture_scene_bakes_and_dumps_every_kind() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scene");
    let out = dir.path().join("scene.bake");
    let o = bake(&[
        scene.join("scene.eco").to_str().unwrap(),
        "--sky",
        scene.join("sky.hdr").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let doc = json(&bake(&["dump", out.to_str().unwrap(), "--json"]));
    let sections = doc["sections"].as_array().unwrap();
    let kind = |k: &str| {
        sections
            .iter()
            .filter(|s| s["kind"] == k)
            .collect::<Vec<_>>()
    };
    assert!(sections.iter().all(|s| s["checksum_ok"] == true));
    let inst = &kind("instances")[0]["summary"];
    assert_eq!(inst["count"], 100);
    assert_eq!(inst["layers"], serde_json::json!([1, 2]));
    assert_eq!(
        inst["models"],
        serde_json::json!(["plant.txf", "object.3ds"])
    );
    let meshes = kind("mesh");
    assert_eq!(meshes.len(), 2);
    for m in &meshes {
        let s = &m["summary"];
        assert!(s["vertices"].as_u64().unwrap() > 0 && s["triangles"].as_u64().unwrap() > 0);
        assert!(s["materials"].as_u64().unwrap() >= 1);
        assert_eq!(s["bounds"]["min"].as_array().unwrap().len(), 3);
    }
    let t = &kind("terrain")[0]["summary"];
    assert_eq!(
        (t["width"].as_u64(), t["height"].as_u64()),
        (Some(65), Some(65))
    );
    assert!(kind("texture").len() >= 3);
    for t in kind("texture") {
        assert!(t["summary"]["width"].as_u64().unwrap() > 0 && t["summary"]["format"].is_string());
    }
    assert_eq!(kind("sky").len(), 1);
    // Instances stand on the terrain: z equals the terrain height at (x, y) within the 8-bit step.
    let full = json(&bake(&[
        "dump",
        out.to_str().unwrap(),
        "--json",
        "--full",
        "--section",
        "instances",
    ]));
    for i in full["sections"][0]["data"]["instances"].as_array().unwrap() {
        let z = i["position"][2].as_f64().unwrap();
        assert!((0.0..=12.75).contains(&z), "{z}");
    }
}

/// `dump --json` shape for packs made from every single-file input kind (OBJ, glTF, GLB written
/// here; EXR written with the `exr` crate; TXF and 3DS from the fixtures).
#[test]
fn dump_json_shape_for_every_input_kind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    bake::fixtures::write_all(d).unwrap();
    write(
        d,
        "quad.obj",
        b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n",
    );
    // A glTF triangle with an embedded base64 buffer: 3 positions (36 bytes) + 3 u16 indices.
    let mut buf: Vec<u8> = [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]]
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    buf.extend([0u16, 1, 2].iter().flat_map(|v| v.to_le_bytes()));
    buf.extend([0u8, 0]);
    let b64 = base64_encode(&buf);
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"translation":[0,2,0]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}]}}"#,
        buf.len()
    );
    write(d, "tri.gltf", gltf.as_bytes());
    exr::prelude::write_rgb_file(d.join("sky.exr"), 16, 8, |x, y| {
        (x as f32 * 0.1, y as f32 * 0.1, 1.0f32)
    })
    .unwrap();
    let cases: [(&str, &[&str], &str, u64); 7] = [
        ("plant.txf", &[], "mesh", 268),
        ("object.3ds", &[], "mesh", 36),
        ("quad.obj", &[], "mesh", 2),
        ("tri.gltf", &[], "mesh", 1),
        (
            "terrain.raw",
            &["--size", "65x65", "--scale", "0.05"],
            "terrain",
            0,
        ),
        ("sky.hdr", &[], "sky", 0),
        ("sky.exr", &[], "sky", 0),
    ];
    for (file, extra, kind, tris) in cases {
        let out = d.join(format!("{file}.bake"));
        let input = d.join(file);
        let mut args = vec![
            "ingest",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--quiet",
        ];
        args.extend_from_slice(extra);
        let o = bake(&args);
        assert!(o.status.success(), "{file}: {}", stderr(&o));
        let doc = json(&bake(&["dump", out.to_str().unwrap(), "--json", "--full"]));
        assert!(doc["file"].is_string() && doc["version"].is_u64(), "{file}");
        let s = doc["sections"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["kind"] == kind)
            .unwrap_or_else(|| panic!("{file}: no {kind} section"));
        for key in ["name", "kind", "bytes", "checksum_ok", "summary", "data"] {
            assert!(s.get(key).is_some(), "{file}: section lacks {key}");
        }
        let sum = &s["summary"];
        match kind {
            "mesh" => {
                assert_eq!(sum["triangles"].as_u64(), Some(tris), "{file}");
                for key in ["vertices", "materials"] {
                    assert!(sum[key].is_u64(), "{file}: {key}");
                }
                assert_eq!(sum["bounds"]["max"].as_array().map(Vec::len), Some(3));
                let data = &s["data"];
                assert_eq!(
                    data["indices"].as_array().map(Vec::len),
                    Some(tris as usize)
                );
                assert_eq!(
                    data["triangle_materials"].as_array().map(Vec::len),
                    Some(tris as usize)
                );
                let n = sum["vertices"].as_u64().unwrap() as usize;
                for key in ["positions", "normals", "uvs"] {
                    assert_eq!(data[key].as_array().map(Vec::len), Some(n), "{file}: {key}");
                }
            }
            "terrain" => {
                for key in [
                    "width",
                    "height",
                    "origin",
                    "extent",
                    "min_height",
                    "max_height",
                ] {
                    assert!(!sum[key].is_null(), "{file}: {key}");
                }
                assert_eq!(s["data"]["heights"].as_array().map(Vec::len), Some(65 * 65));
            }
            _ => assert!(
                sum["width"].as_u64().unwrap() > 0 && sum["height"].as_u64().unwrap() > 0,
                "{file}"
            ),
        }
    }
    // glTF node translation (0, 2, 0) in Y-up is (0, 0, 2) in bake's Z-up.
    let doc = json(&bake(&[
        "dump",
        d.join("tri.gltf.bake").to_str().unwrap(),
        "--json",
    ]));
    let min = &doc["sections"][0]["summary"]["bounds"]["min"];
    assert_eq!(min[2].as_f64(), Some(2.0), "{min}");
}

fn base64_encode(data: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in data.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// `tracer = "embree"` in a binary built without the cargo feature is refused before any work,
/// naming the feature and how to build it (never a silent fallback to the CPU tracer).
#[cfg(not(feature = "embree"))]
#[test]
fn embree_tracer_without_the_feature_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.bake");
    let out = out.to_str().unwrap();
    let names_the_feature = |o: &Output| {
        let e = stderr(o);
        assert!(
            e.contains("embree") && e.contains("--features embree"),
            "{e}"
        );
    };
    // --set on the build command: a usage error.
    let o = bake(&[
        "fixtures/scene/scene.eco",
        "--set",
        "prt.tracer=embree",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    names_the_feature(&o);
    assert!(!Path::new(out).exists());
    // `bake prt --tracer embree`: a usage error too.
    let o = bake(&[
        "prt",
        "fixtures/scene/plant.txf",
        "--tracer",
        "embree",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    names_the_feature(&o);
    // The light-map and env-map stages: the same refusal, naming their option.
    for key in ["lightmap.tracer", "envmaps.tracer"] {
        let o = bake(&[
            "fixtures/scene/scene.eco",
            "--set",
            &format!("{key}=embree"),
            "-o",
            out,
        ]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        names_the_feature(&o);
        assert!(stderr(&o).contains(key), "{}", stderr(&o));
        assert!(!Path::new(out).exists());
    }
    for cmd in ["lightmap", "envmaps"] {
        let o = bake(&[
            cmd,
            "fixtures/scene/scene.eco",
            "--tracer",
            "embree",
            "-o",
            out,
        ]);
        assert_eq!(o.status.code(), Some(2), "{cmd}: {}", stderr(&o));
        names_the_feature(&o);
        assert!(!Path::new(out).exists());
    }
    // `bake bench lightmap --tracer embree`: refused before the fixture scene is built.
    let o = bake(&["bench", "lightmap", "--tracer", "embree"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    names_the_feature(&o);
    // A pipeline file asking for it: invalid input naming the file.
    let text = std::fs::read_to_string("pipelines/default.toml")
        .unwrap()
        .replace("tracer = \"cpu\"", "tracer = \"embree\"");
    let pipeline = write(dir.path(), "embree.toml", text.as_bytes());
    let o = bake(&[
        "fixtures/scene/scene.eco",
        "--pipeline",
        &pipeline,
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(4), "{}", stderr(&o));
    names_the_feature(&o);
    assert!(stderr(&o).contains("embree.toml"), "{}", stderr(&o));
    // An unknown tracer is a usage error listing the known ones.
    let o = bake(&[
        "prt",
        "fixtures/scene/plant.txf",
        "--tracer",
        "optix",
        "-o",
        out,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("cpu"), "{}", stderr(&o));
}

/// Warnings carry their id on stderr and in the build report (schema `bake.build/2`), and
/// `--warnings-as-errors` makes all of them fatal alone, or only those of the ids it is given.
#[test]
fn warnings_carry_stable_ids_and_warnings_as_errors_takes_them() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "t.raw", &[10u8; 16]);
    write(
        dir.path(),
        "box.obj",
        common::box_obj([-1.0; 3], [1.0; 3], 1).as_bytes(),
    );
    let text =
        "t.raw 4 4 1 0.1\n<GEOREF> 0 0 10 10 0 0 10 10\n<ECO>\n<LAYER> 1\nbox.obj 1.5 0.5 1 0\n";
    let eco = write(dir.path(), "s.eco", text.as_bytes());
    let o = bake(&[&eco, "--preview", "--no-cache", "--json"]);
    let report = json(&o);
    assert_eq!(report["schema"], "bake.build/2");
    // The placement outside the area, and one instance is too few to cluster.
    let w = &report["warnings"];
    let ids: Vec<&str> = w
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["id"].as_str().unwrap())
        .collect();
    assert_eq!(
        ids,
        ["ingest.eco-outside-area", "cluster.compression-low"],
        "{w}"
    );
    assert_eq!(w[0]["severity"], "warning");
    assert!(w[0]["message"].as_str().unwrap().contains("line 5"), "{w}");
    assert_eq!(w[1]["place"], "scene");
    assert!(
        stderr(&o).contains("lies outside the area of interest [0,1]² [ingest.eco-outside-area]"),
        "{}",
        stderr(&o)
    );

    // Each run its own output: a second run into one output is up to date and runs nothing.
    let code = |flag: &str| {
        let out = dir.path().join(format!("{}.bake", flag.len()));
        let out = out.to_str().unwrap();
        let o = bake(&[&eco, "--preview", "--no-cache", "--quiet", "-o", out, flag]);
        (o.status.code(), stderr(&o))
    };
    let (all, err) = code("--warnings-as-errors");
    assert_eq!(all, Some(4), "{err}");
    assert!(
        err.contains("2 warning(s) and --warnings-as-errors"),
        "{err}"
    );
    let (some, err) = code("--warnings-as-errors=ingest.eco-outside-area,cache.write-failed");
    assert_eq!(some, Some(4), "{err}");
    assert!(
        err.contains("1 warning(s) and --warnings-as-errors"),
        "{err}"
    );
    assert_eq!(code("--warnings-as-errors=prt.texture-missing").0, Some(0));
    let (unknown, err) = code("--warnings-as-errors=no.such-id");
    assert_eq!(unknown, Some(2), "{err}");
    assert!(err.contains("docs/DIAGNOSTICS.md"), "{err}");
}
