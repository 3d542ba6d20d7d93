//! Black-box tests of `bake prt` and the `prt` section's dump view, on the committed fixture
//! plant (TXF with an alpha-tested SGI leaf texture).

use serde_json::Value;
use std::path::Path;

mod common;
use common::{bake, json};

fn fixture(name: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/scene")
        .join(name);
    p.to_str().unwrap().to_string()
}

fn prt_section(doc: &Value) -> Value {
    doc["sections"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["kind"] == "prt")
        .cloned()
        .expect("a prt section")
}

#[test]
fn prt_of_a_txf_plant_dumps_its_summary_and_transfer() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("plant.bake");
    let out = out.to_str().unwrap();
    let run = json(&bake(&[
        "prt",
        &fixture("plant.txf"),
        "-o",
        out,
        "--samples",
        "16",
        "--json",
    ]));
    assert_eq!(run["meshes"][0]["section"], "prt:plant.txf");
    let vertices = run["meshes"][0]["vertices"].as_u64().unwrap();
    assert!(vertices > 0);
    let doc = json(&bake(&["dump", out, "--json", "--full"]));
    let s = prt_section(&doc);
    let summary = &s["summary"];
    assert_eq!(summary["vertices"], vertices);
    assert_eq!(summary["order"], 4);
    assert_eq!(summary["samples"], 16);
    assert_eq!(summary["sides"], 2);
    assert_eq!(summary["sets"], 2);
    let transfer = s["data"]["transfer"].as_array().unwrap();
    assert_eq!(transfer.len() as u64, vertices);
    let v0 = &transfer[0];
    assert_eq!(v0.as_array().unwrap().len(), 2, "two sides");
    assert_eq!(v0[0].as_array().unwrap().len(), 2, "two sets");
    assert_eq!(v0[0][0].as_array().unwrap().len(), 16, "16 coefficients");
    assert_eq!(v0[0][0][0].as_array().unwrap().len(), 3, "RGB");
    // Some vertex sees the sky: the DC term of its front or back side is positive.
    assert!(transfer.iter().any(|v| v[0][0][0][1].as_f64().unwrap() > 0.0
        || v[1][0][0][1].as_f64().unwrap() > 0.0));

    // A pack input is updated in place, replacing the section.
    json(&bake(&[
        "prt",
        out,
        "--samples",
        "4",
        "--bounces",
        "1",
        "--json",
    ]));
    let doc = json(&bake(&["dump", out, "--json"]));
    assert_eq!(prt_section(&doc)["summary"]["samples"], 4);
    assert_eq!(prt_section(&doc)["summary"]["bounces"], 1);
}

#[test]
fn prt_rejects_bad_options_and_inputs_without_meshes() {
    let o = bake(&["prt", &fixture("plant.txf"), "--samples", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--samples 0"));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sky.bake");
    let o = bake(&["prt", &fixture("sky.hdr"), "-o", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(4));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no mesh section"));
    assert!(!out.exists(), "a failed bake writes nothing");
}

#[test]
fn bench_rays_reports_the_documented_keys() {
    let doc = json(&bake(&[
        "bench",
        "rays",
        "--triangles",
        "300",
        "--vertices",
        "20",
        "--samples",
        "4",
        "--json",
    ]));
    for key in [
        "triangles",
        "raw_rays_per_second",
        "prt_rays_per_second",
        "efficiency",
    ] {
        assert!(doc[key].is_number(), "{key}: {doc}");
    }
}

#[test]
fn bench_prt_error_reports_the_documented_keys() {
    let doc = json(&bake(&[
        "bench",
        "prt-error",
        "--triangles",
        "300",
        "--vertices",
        "20",
        "--reference-samples",
        "128",
        "--samples",
        "8,32",
        "--no-cache",
        "--json",
    ]));
    for key in ["triangles", "vertices", "reference_samples"] {
        assert!(doc[key].is_number(), "{key}: {doc}");
    }
    assert!(doc["model"].is_string(), "{doc}");
    let runs = doc["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 4, "2 methods × 2 sample counts: {doc}");
    for r in runs {
        assert!(r["method"].is_string() && r["samples"].is_number(), "{r}");
        for key in ["wall_seconds", "rms_error"] {
            assert!(r[key].as_f64().is_some_and(|v| v >= 0.0), "{key}: {r}");
        }
        assert!(r.get("cpu_seconds").is_some(), "{r}");
    }
    // More paths, less error (the metric subtracts the reference's own noise).
    let fixed: Vec<f64> = runs
        .iter()
        .filter(|r| r["method"] == "fixed")
        .map(|r| r["rms_error"].as_f64().unwrap())
        .collect();
    assert!(fixed[1] < fixed[0], "{fixed:?}");
}

#[test]
fn prt_tracer_gpu_without_an_adapter_fails_with_exit_5_and_says_why() {
    // Every Vulkan ICD and EGL vendor hidden: no adapter on a Mesa machine (CI's lavapipe).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.bake");
    let o = std::process::Command::new(common::bake_bin())
        .args([
            "prt",
            &fixture("plant.txf"),
            "--tracer",
            "gpu",
            "--samples",
            "4",
        ])
        .arg("-o")
        .arg(&out)
        .env("VK_ICD_FILENAMES", dir.path().join("none.json"))
        .env(
            "__EGL_VENDOR_LIBRARY_FILENAMES",
            dir.path().join("none.json"),
        )
        .env("LIBGL_DRIVERS_PATH", dir.path())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    if o.status.success() {
        eprintln!("SKIPPED: an adapter was found with the drivers hidden (not Mesa)");
        return;
    }
    assert_eq!(o.status.code(), Some(5), "{stderr}");
    assert!(
        stderr.contains("prt.tracer = \"gpu\"") && stderr.contains("no usable GPU adapter"),
        "{stderr}"
    );
    assert!(!out.exists(), "no pack written");
}

#[test]
fn bench_prt_error_measures_the_gpu_method_beside_fixed() {
    let o = std::process::Command::new(common::bake_bin())
        .args([
            "bench",
            "prt-error",
            "--triangles",
            "300",
            "--vertices",
            "40",
        ])
        .args(["--reference-samples", "256", "--samples", "64", "--methods"])
        .args(["fixed,gpu", "--no-cache", "--json"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    if o.status.code() == Some(5) && stderr.contains("no usable GPU adapter") {
        assert!(
            std::env::var_os("CI").is_none(),
            "no GPU adapter under CI: {stderr}"
        );
        eprintln!("SKIPPED: no GPU adapter");
        return;
    }
    assert!(o.status.success(), "{stderr}");
    let doc: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(doc["adapter"].is_string(), "{doc}");
    let runs = doc["runs"].as_array().expect("runs");
    let error = |m: &str| {
        runs.iter()
            .find(|r| r["method"] == m)
            .and_then(|r| r["rms_difference"].as_f64())
            .unwrap_or_else(|| panic!("{m}: {doc}"))
    };
    // The same estimator and seed: the same difference from the reference.
    let (f, g) = (error("fixed"), error("gpu"));
    assert!((g / f - 1.0).abs() < 0.05, "fixed {f}, gpu {g}");
}
