//! Black-box tests of `bake sky`: the `--json` shape, the pack it writes, exit codes.

use bake::ingest::skyimage::write_hdr;
use bake::model::FloatImage;
use serde_json::Value;
use std::path::Path;

mod common;
use common::{bake, json};

/// A 512×256 lat-long sky with a bright 3×3-pixel sun at row 64 (θ = 45°), column 0 (φ ≈ 0).
fn sky_file(dir: &Path) -> String {
    let (w, h) = (512u32, 256u32);
    let mut pixels = Vec::new();
    for j in 0..h {
        for i in 0..w {
            let sun = (j as i32 - 64).abs() <= 1 && (i as i32 - 1).abs() <= 1;
            pixels.push(if sun {
                [3000.0, 2900.0, 2800.0]
            } else if j < h / 2 {
                [0.3, 0.5, 1.0]
            } else {
                [0.1, 0.1, 0.1]
            });
        }
    }
    let p = dir.join("sky.hdr");
    std::fs::write(
        &p,
        write_hdr(&FloatImage {
            width: w,
            height: h,
            pixels,
        }),
    )
    .unwrap();
    p.to_str().unwrap().to_string()
}

fn vec3(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("array");
    assert_eq!(a.len(), 3);
    [0, 1, 2].map(|k| a[k].as_f64().expect("number"))
}

#[test]
fn json_report_has_the_documented_shape() {
    let dir = tempfile::tempdir().unwrap();
    let input = sky_file(dir.path());
    let out = dir.path().join("out.bake");
    let doc = json(&bake(&[
        "sky",
        &input,
        "-o",
        out.to_str().unwrap(),
        "--face-size",
        "64",
        "--json",
    ]));
    let d = vec3(&doc["sun"]["direction"]);
    // θ = 45° (row 64.5 of 256), φ ≈ 0: (0.707, 0.0, 0.707) within a few texels.
    assert!(
        (d[0] - 0.707).abs() < 0.05 && d[1].abs() < 0.05 && (d[2] - 0.707).abs() < 0.05,
        "{d:?}"
    );
    assert!(vec3(&doc["sun"]["irradiance"])[0] > 0.0);
    vec3(&doc["sun"]["irradiance_thesis"]);
    assert!(doc["sun"]["texels"].as_u64().unwrap() >= 1);
    assert!(doc["sun"]["clipped"].is_boolean());
    // Sky above: (0.3, 0.5, 1.0) on the upper hemisphere, so π·L on the ground.
    let e = vec3(&doc["sky"]["irradiance_horizontal"]);
    assert!((e[2] - std::f64::consts::PI).abs() < 0.05, "{e:?}");
    vec3(&doc["sky"]["I_H_thesis"]);
    assert_eq!(doc["sh"]["order"], 4);
    let c = doc["sh"]["coefficients"].as_array().unwrap();
    assert_eq!(c.len(), 16);
    c.iter().for_each(|v| {
        vec3(v);
    });
    assert_eq!(doc["cube"]["face_size"], 64);

    let dump = json(&bake(&["dump", out.to_str().unwrap(), "--json"]));
    let kinds: Vec<_> = dump["sections"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["kind"].as_str().unwrap().to_string(),
                s["summary"].clone(),
            )
        })
        .collect();
    assert_eq!(kinds.len(), 3);
    assert_eq!(kinds[0].0, "sky");
    assert_eq!(kinds[0].1["layout"], "cube");
    assert_eq!(kinds[0].1["width"], 64);
    assert_eq!(kinds[0].1["faces"], 6);
    assert_eq!(kinds[1].0, "sun");
    assert_eq!(kinds[2].0, "sh");
}

#[test]
fn builtin_sky_bakes_without_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("b.bake");
    let doc = json(&bake(&[
        "sky",
        "-o",
        out.to_str().unwrap(),
        "--face-size",
        "32",
        "--sun-elevation",
        "30",
        "--sun-azimuth",
        "90",
        "--json",
    ]));
    let d = vec3(&doc["sun"]["direction"]);
    // Elevation 30°, azimuth 90°: (0, cos 30°, sin 30°).
    assert!(d[0].abs() < 0.03 && (d[1] - 0.866).abs() < 0.03 && (d[2] - 0.5).abs() < 0.03);
}

#[test]
fn errors_exit_with_documented_codes() {
    let dir = tempfile::tempdir().unwrap();
    let input = sky_file(dir.path());
    let o = bake(&["sky", &input, "--face-size", "0"]);
    assert_eq!(o.status.code(), Some(2));
    let bad = dir.path().join("bad.hdr");
    std::fs::write(&bad, b"#?RADIANCE\n\n-Y 2 +X 2\n").unwrap();
    let o = bake(&["sky", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(4));
    let msg = String::from_utf8_lossy(&o.stderr);
    assert!(msg.contains("bad.hdr"), "{msg}");
    let o = bake(&["sky", dir.path().join("none.exr").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(3));
}
