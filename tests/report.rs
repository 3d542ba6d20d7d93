//! The record of a bake and `bake report` (issue 16, item 7): every bake leaves its report beside
//! the pack naming the pack's BLAKE3 (or, with `--embed-report`, inside it); the report's
//! timeline is the order the units ran in; `bake report` writes one self-contained page that
//! headless Chromium (Debian's `chromium`) loads with every image decoded, and whose top-left
//! corner on a screenshot is the render `bake render` makes of the same default view.

mod common;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The fixture scene in `dir/sc`, baked with the preview pipeline to `dir/NAME` (extra args
/// appended); returns the pack's path and `--json`'s report.
fn bake_fixture(dir: &Path, name: &str, extra: &[&str]) -> (PathBuf, Value) {
    let scene = dir.join("sc");
    if !scene.join("scene.eco").exists() {
        common::json(&common::bake(&[
            "fixtures",
            scene.to_str().unwrap(),
            "--json",
        ]));
    }
    let pack = dir.join(name);
    let mut args = vec![
        scene.join("scene.eco").to_str().unwrap().to_string(),
        "--preview".into(),
        "-o".into(),
        pack.to_str().unwrap().to_string(),
        "--json".into(),
        "--quiet".into(),
    ];
    args.extend(extra.iter().map(|s| s.to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let report = common::json(&common::bake(&args));
    (pack, report)
}

fn blake3_hex(path: &Path) -> String {
    blake3::hash(&std::fs::read(path).unwrap())
        .to_hex()
        .to_string()
}

fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// `bake report PACK -o PAGE --no-render --json`.
fn report_without_render(pack: &Path, page: &Path) -> Value {
    common::json(&common::bake(&[
        "report",
        pack.to_str().unwrap(),
        "-o",
        page.to_str().unwrap(),
        "--no-render",
        "--json",
    ]))
}

#[test]
fn every_bake_writes_a_sidecar_report_that_names_its_pack() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let (pack, report) = bake_fixture(dir.path(), "a.bake", &["--cache", cache.to_str().unwrap()]);
    let sidecar = dir.path().join("a.bake.report.json");
    let side = read_json(&sidecar);
    assert_eq!(side, report, "the sidecar is the --json report");
    assert_eq!(side["pack_blake3"].as_str().unwrap(), blake3_hex(&pack));
    // The timeline: units of different stages may run side by side (issue 37), the units of
    // one stage (its lane in the page) one after another, all inside the bake's wall time.
    let stages = side["stages"].as_array().unwrap();
    assert!(stages.len() >= 10, "{}", stages.len());
    let wall = side["wall_seconds"].as_f64().unwrap();
    let mut lane_end: std::collections::BTreeMap<&str, f64> = Default::default();
    for s in stages {
        let t0 = s["start_seconds"].as_f64().unwrap();
        let w = s["wall_seconds"].as_f64().unwrap();
        let end = lane_end.entry(s["stage"].as_str().unwrap()).or_insert(0.0);
        assert!(
            t0 >= *end - 1e-9,
            "{s} starts before the previous unit of its stage ended ({end})"
        );
        *end = t0 + w;
        assert!(
            t0 + w <= wall + 1e-9,
            "{s} ends at {} after the bake's {wall}",
            t0 + w
        );
    }

    // Up to date: nothing is written, the sidecar still describes the pack.
    let again = common::json(&common::bake(&[
        dir.path().join("sc/scene.eco").to_str().unwrap(),
        "--preview",
        "-o",
        pack.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
        "--json",
        "--quiet",
    ]));
    assert_eq!(again["up_to_date"], true);
    assert_eq!(read_json(&sidecar), side);

    // A sidecar of other bytes is recognized as stale by `bake report`.
    let other = dir.path().join("b.bake");
    common::json(&common::bake(&[
        "bittree",
        pack.to_str().unwrap(),
        "--children",
        "4",
        "-o",
        other.to_str().unwrap(),
        "--json",
    ]));
    assert_ne!(blake3_hex(&other), blake3_hex(&pack));
    std::fs::copy(&sidecar, dir.path().join("b.bake.report.json")).unwrap();
    let page = dir.path().join("b.html");
    let r = report_without_render(&other, &page);
    assert_eq!(r["build_report"], Value::Null);
    let notes = r["notes"].to_string();
    assert!(notes.contains("stale"), "{notes}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(!html.contains("The bake that wrote it") && html.contains("stale"));
}

#[test]
fn embed_report_keeps_the_report_in_the_pack() {
    let dir = tempfile::tempdir().unwrap();
    let (pack, report) = bake_fixture(dir.path(), "e.bake", &["--no-cache", "--embed-report"]);
    assert!(!dir.path().join("e.bake.report.json").exists());
    let verify = common::bake(&["verify", pack.to_str().unwrap()]);
    assert!(
        verify.status.success(),
        "{}",
        String::from_utf8_lossy(&verify.stdout)
    );
    let doc = common::json(&common::bake(&[
        "dump",
        pack.to_str().unwrap(),
        "--section",
        "build_report",
        "--full",
        "--json",
    ]));
    let s = &doc["sections"][0];
    assert_eq!(s["kind"], "build_report");
    assert_eq!(s["data"], report);
    // The embedded report names the pack as the stage graph wrote it, before the report went in.
    assert_ne!(report["pack_blake3"].as_str().unwrap(), blake3_hex(&pack));
    let page = dir.path().join("e.html");
    let r = report_without_render(&pack, &page);
    assert_eq!(r["build_report"], "the pack's build_report section");
}

/// Headless Chromium with its own profile; returns stdout.
fn chromium(profile: &Path, args: &[&str], url: &str) -> Vec<u8> {
    let out = Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--force-device-scale-factor=1",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(url)
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

fn attribute(tag: &str, name: &str) -> Option<usize> {
    let at = tag.find(&format!("{name}=\""))? + name.len() + 2;
    tag[at..].split('"').next()?.parse().ok()
}

#[test]
fn the_report_page_shows_its_images_in_headless_chromium() {
    if !common::tool_available("chromium", "loads bake report's page") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (pack, report) = bake_fixture(dir.path(), "s.bake", &["--no-cache"]);
    let page = dir.path().join("report.html");
    let r = common::json(&common::bake(&[
        "report",
        pack.to_str().unwrap(),
        "-o",
        page.to_str().unwrap(),
        "--width",
        "320",
        "--height",
        "180",
        "--json",
    ]));
    // As many thumbnails as `bake dump --png` writes PNG files.
    let pngs = dir.path().join("png");
    let d = common::json(&common::bake(&[
        "dump",
        pack.to_str().unwrap(),
        "--png",
        pngs.to_str().unwrap(),
        "--json",
    ]));
    let png_files = d["png"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["file"].as_str().unwrap().ends_with(".png"))
        .count();
    assert!(png_files > 10, "{png_files}");
    assert_eq!(r["images"].as_u64().unwrap() as usize, png_files);
    assert!(
        r["build_report"]
            .as_str()
            .unwrap()
            .ends_with("s.bake.report.json")
    );

    // Self-contained: nothing is fetched from elsewhere.
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(!html.contains("http://") && !html.contains("https://"));
    assert_eq!(
        html.matches(" src=\"").count(),
        html.matches(" src=\"data:image/png;base64,").count()
    );
    // The timeline has a bar per unit of the report, every section a row.
    let units = report["stages"].as_array().unwrap().len();
    assert_eq!(html.matches("<rect ").count(), units);
    let sections = d["sections"].as_array().unwrap().len();
    let stage_names: std::collections::BTreeSet<&str> = report["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        html.matches("<tr><td>").count(),
        sections + stage_names.len()
    );

    // Chromium decodes every image: the thumbnails and the render.
    let url = format!("file://{}", page.display());
    let profile = dir.path().join("profile");
    let dom = chromium(
        &profile,
        &["--virtual-time-budget=5000", "--dump-dom"],
        &url,
    );
    let dom = String::from_utf8_lossy(&dom);
    let body = &dom[dom.find("<body").expect("a body")..];
    let body = &body[..body.find('>').unwrap()];
    assert_eq!(
        attribute(body, "data-images"),
        Some(png_files + 1),
        "{body}"
    );
    assert_eq!(
        attribute(body, "data-decoded"),
        Some(png_files + 1),
        "{body}"
    );

    // On a screenshot, the page's top-left 320×180 pixels are `bake render`'s image.
    let shot = dir.path().join("shot.png");
    chromium(
        &profile,
        &[
            "--window-size=1000,900",
            &format!("--screenshot={}", shot.display()),
        ],
        &url,
    );
    let shot = image::open(&shot).unwrap().to_rgba8();
    let view = dir.path().join("view.png");
    common::json(&common::bake(&[
        "render",
        pack.to_str().unwrap(),
        "-o",
        view.to_str().unwrap(),
        "--width",
        "320",
        "--height",
        "180",
        "--json",
    ]));
    let view = image::open(&view).unwrap().to_rgba8();
    let mad = |x0: u32, y0: u32| {
        let mut sum = 0u64;
        for (x, y, p) in view.enumerate_pixels() {
            let q = shot.get_pixel(x0 + x, y0 + y);
            sum += (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>();
        }
        sum as f64 / (320.0 * 180.0 * 3.0)
    };
    let at_corner = mad(0, 0);
    assert!(at_corner < 2.0, "screenshot vs render: MAD {at_corner}");
    // A negative control: the same comparison one render to the right is far off.
    let beside = mad(320, 0);
    assert!(beside > 20.0, "the page beside the render: MAD {beside}");
}
