//! Black-box tests of `bake validate` and `bake render --soft-shadows`: a small OBJ through
//! `bake svo` and `bake linespace`, then the GPU/CPU comparison (exit 0, every answer equal) and
//! the error paths (exit 4 for a pack with nothing to validate or no line space to shade with);
//! `bake bench linespace --accuracy` on the same scene.

use std::path::Path;

mod common;
use common::{bake, json};

/// A unit cube over a ground quad, as OBJ text.
fn scene_obj() -> String {
    let mut s = common::box_obj([0.0, 0.0, 1.0], [1.0, 1.0, 2.0], 1);
    s += "v -3 -3 0\nv 4 -3 0\nv 4 4 0\nv -3 4 0\n";
    s += "f 9 10 11\nf 9 11 12\n";
    s
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_str().unwrap().to_string()
}

#[test]
fn validate_agrees_on_svo_and_linespace_of_a_model() {
    let dir = tempfile::tempdir().unwrap();
    let obj = path(dir.path(), "scene.obj");
    std::fs::write(&obj, scene_obj()).unwrap();
    let pack = path(dir.path(), "scene.bake");
    json(&bake(&[
        "svo",
        &obj,
        "-o",
        &pack,
        "--resolution",
        "64",
        "--json",
    ]));
    json(&bake(&[
        "linespace",
        &pack,
        "--n",
        "4",
        "--depth",
        "3",
        "--json",
    ]));
    let v = json(&bake(&[
        "validate",
        &pack,
        "--rays",
        "5000",
        "--receivers",
        "300",
        "--json",
    ]));
    assert_eq!(v["agree"], true, "{v}");
    assert_eq!(v["svo"]["rays"], 5000);
    assert_eq!(v["svo"]["voxel_mismatches"], 0);
    assert!(v["svo"]["hits"].as_u64().unwrap() > 500, "{v}");
    // The LOD kernel of `render --view svo` on the same rays at four cones: every answer equal.
    let lod = v["svo_lod"].as_array().unwrap();
    assert_eq!(lod.len(), 4, "{v}");
    for row in lod {
        let a = &row["agreement"];
        assert_eq!(row["agree"], true, "{row}");
        for k in [
            "hit_mismatches",
            "cell_mismatches",
            "attribute_mismatches",
            "t_mismatches",
        ] {
            assert_eq!(a[k], 0, "{row}");
        }
        assert!(a["hits"].as_u64().unwrap() > 500, "{row}");
    }
    assert_eq!(v["linespace"]["segments"], 300 * 16);
    assert_eq!(v["linespace"]["fraction_mismatches"], 0);
    assert!(v["linespace"]["occluded"].as_u64().unwrap() > 100, "{v}");

    // The cube shadows the ground under a light above it.
    let png = path(dir.path(), "soft.png");
    let r = json(&bake(&[
        "render",
        &pack,
        "-o",
        &png,
        "--width",
        "64",
        "--height",
        "48",
        "--eye",
        "0.5,-6,6",
        "--target",
        "0.5,0.5,0",
        "--soft-shadows",
        "--area-light",
        "0,0,6,1,0,0,0,1,0",
        "--json",
    ]));
    let s = &r["soft_shadows"];
    assert!(s["receivers"].as_u64().unwrap() > 1000, "{r}");
    assert!(s["shadowed_pixels"].as_u64().unwrap() > 0, "{r}");
    assert!(Path::new(&png).exists());
}

/// The thesis' default, n = 10 and depth 3, in the compact form: GPU = CPU in every
/// refinement, and the section and GPU pools a fraction of the dense pools.
#[test]
fn validate_agrees_at_n10_depth3_with_the_compact_form() {
    let dir = tempfile::tempdir().unwrap();
    let obj = path(dir.path(), "scene.obj");
    std::fs::write(&obj, scene_obj()).unwrap();
    let pack = path(dir.path(), "scene.bake");
    let l = json(&bake(&[
        "linespace",
        &obj,
        "-o",
        &pack,
        "--n",
        "10",
        "--depth",
        "3",
        "--json",
    ]));
    // A 7 × 7 m ground in 7 mm leaves: 2.1 million leaves, 30 MB (the dense pools: 305 MB).
    let bytes = l["bytes"].as_u64().unwrap();
    assert!(8 * bytes < l["dense_bytes"].as_u64().unwrap(), "{l}");
    let occupancy = l["occupancy_bytes"].as_u64().unwrap();
    assert_eq!(l["shaft_table_bytes"], 9 * 10_000 * 16 * 8);
    for refine in ["shaft", "cells", "exact"] {
        let v = json(&bake(&[
            "validate",
            &pack,
            "--receivers",
            "200",
            "--refine",
            refine,
            "--json",
        ]));
        assert_eq!(v["agree"], true, "{v}");
        let ls = &v["linespace"];
        assert_eq!(ls["segment_mismatches"], 0, "{v}");
        assert_eq!(ls["fraction_mismatches"], 0, "{v}");
        assert!(ls["occluded"].as_u64().unwrap() > 50, "{v}");
        // The section's arrays plus the reversed occupancy (buffers padded to 16 B at most).
        let pools = ls["gpu_pool_bytes"].as_u64().unwrap();
        assert!(
            pools >= bytes + occupancy && pools <= bytes + occupancy + 7 * 16,
            "{v}"
        );
    }
}

/// `bake bench linespace --accuracy --json`: the documented keys, never brighter than exact,
/// and the exact refinement without error against obvhs rays to the same light points.
#[test]
fn bench_accuracy_reports_one_sided_errors_with_stable_keys() {
    let dir = tempfile::tempdir().unwrap();
    let obj = path(dir.path(), "scene.obj");
    std::fs::write(&obj, scene_obj()).unwrap();
    let v = json(&bake(&[
        "bench",
        "linespace",
        &obj,
        "--accuracy",
        "--n",
        "4",
        "--depth",
        "3",
        "--receivers",
        "300",
        "--accuracy-samples",
        "16",
        "--area-light",
        "0,0,6,1,0,0,0,1,0",
        "--json",
    ]));
    for key in [
        "receivers",
        "light_samples",
        "mean_abs_error",
        "darker_share",
        "brighter_than_exact",
    ] {
        assert!(v.get(key).is_some(), "{key} missing: {v}");
    }
    assert_eq!(v["receivers"], 300);
    assert_eq!(v["light_samples"], 256);
    assert_eq!(v["refine"], "Exact");
    assert_eq!(v["brighter_than_exact"], 0, "{v}");
    let modes = v["modes"].as_array().unwrap();
    assert_eq!(modes.len(), 4);
    for m in modes {
        assert_eq!(m["brighter_than_exact"], 0, "{m}");
    }
    assert!(v["mean_abs_error"].as_f64().unwrap() < 1e-3, "{v}");
    assert!(modes[0]["mean_abs_error"].as_f64().unwrap() >= v["mean_abs_error"].as_f64().unwrap());
}

#[test]
fn validate_and_soft_shadows_need_their_sections() {
    let dir = tempfile::tempdir().unwrap();
    let obj = path(dir.path(), "scene.obj");
    std::fs::write(&obj, scene_obj()).unwrap();
    let pack = path(dir.path(), "mesh.bake");
    json(&bake(&["ingest", &obj, "-o", &pack, "--json"]));
    let o = bake(&["validate", &pack]);
    assert_eq!(o.status.code(), Some(4));
    assert!(
        String::from_utf8_lossy(&o.stderr)
            .contains("no svo, svo-scene, linespace or linespace-scene section")
    );
    let png = path(dir.path(), "x.png");
    let o = bake(&["render", &pack, "-o", &png, "--soft-shadows"]);
    assert_eq!(o.status.code(), Some(4));
    assert!(String::from_utf8_lossy(&o.stderr).contains("linespace"));
    let o = bake(&[
        "render",
        &pack,
        "-o",
        &png,
        "--soft-shadows",
        "--area-light",
        "1,2,3",
    ]);
    assert_eq!(o.status.code(), Some(2));
}
