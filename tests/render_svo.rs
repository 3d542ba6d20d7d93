//! Black-box tests of `bake render --view svo`: a model through `bake svo`, then the compute-shader
//! ray march against the CPU traversal on the same rays (`--reference`), the level chosen by
//! distance (coarser levels farther away, more of them at a larger lod scale), the negative
//! control of a lod scale so large that every ray stops at the root (of a solid box; a sparse
//! root is below the coverage floor), and the error for a pack without an `svo` section.

use serde_json::Value;
use std::collections::HashSet;
use std::path::Path;

mod common;
use common::{bake, json};

/// A 40 m ground strip along +y with three 2 m cubes on it, left and right, as OBJ text.
fn strip_obj() -> String {
    let mut s = String::from("v -4 0 0\nv 4 0 0\nv 4 40 0\nv -4 40 0\nf 1 2 3\nf 1 3 4\n");
    for (i, &(cx, y)) in [(-2.5f32, 4.0f32), (2.0, 14.0), (-1.0, 30.0)]
        .iter()
        .enumerate()
    {
        s += &common::box_obj(
            [cx - 1.0, y, 0.0],
            [cx + 1.0, y + 2.0, 2.0],
            5 + 8 * i as u32,
        );
    }
    s
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_str().unwrap().to_string()
}

/// `bake svo` of the strip at 128 voxels (4 levels: root 256, 64, 16, bricks 4, voxels).
fn strip_pack(dir: &Path) -> String {
    let obj = path(dir, "strip.obj");
    std::fs::write(&obj, strip_obj()).unwrap();
    let pack = path(dir, "strip.bake");
    let s = json(&bake(&[
        "svo",
        &obj,
        "-o",
        &pack,
        "--resolution",
        "128",
        "--json",
    ]));
    assert_eq!(s["levels"], 4, "{s}");
    pack
}

/// Renders the svo view down the strip (200×120) with the CPU reference beside it.
fn render(pack: &str, dir: &Path, tag: &str, show: &str, lod_scale: &str) -> Value {
    render_from(pack, dir, tag, show, lod_scale, ("0,-1,3", "0,30,0"))
}

/// As [`render`] from another eye and target.
fn render_from(
    pack: &str,
    dir: &Path,
    tag: &str,
    show: &str,
    lod_scale: &str,
    (eye, target): (&str, &str),
) -> Value {
    let (gpu, cpu) = (
        path(dir, &format!("{tag}.png")),
        path(dir, &format!("{tag}_cpu.png")),
    );
    let r = json(&bake(&[
        "render",
        pack,
        "-o",
        &gpu,
        "--view",
        "svo",
        "--svo-show",
        show,
        "--svo-lod-scale",
        lod_scale,
        "--width",
        "200",
        "--height",
        "120",
        "--eye",
        eye,
        "--target",
        target,
        "--reference",
        &cpu,
        "--json",
    ]));
    // GPU and CPU traced the same rays: the images and the answers agree.
    let reference = &r["reference"];
    let a = &reference["agreement"];
    assert_eq!(a["rays"], 200 * 120, "{r}");
    let mismatches = [
        "hit_mismatches",
        "cell_mismatches",
        "attribute_mismatches",
        "t_mismatches",
    ]
    .iter()
    .map(|k| a[k].as_u64().unwrap())
    .sum::<u64>();
    // At most 0.1 % of the rays (cell-edge ties); lavapipe measures 0.
    assert!(mismatches <= 24, "{tag}: {a}");
    assert!(
        reference["mad"].as_f64().unwrap() <= 0.5,
        "{tag}: {reference}"
    );
    assert!(
        reference["pixels_over"].as_f64().unwrap() <= 0.001,
        "{tag}: {reference}"
    );
    r
}

fn per_level(r: &Value) -> Vec<u64> {
    r["svo"]["pixels_per_level"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect()
}

fn rgba(p: &str) -> image::RgbaImage {
    image::open(p).unwrap().to_rgba8()
}

#[test]
fn the_svo_view_matches_the_cpu_traversal_and_coarsens_with_distance() {
    let dir = tempfile::tempdir().unwrap();
    let pack = strip_pack(dir.path());
    let r = render(&pack, dir.path(), "level", "level", "32");
    let counts = per_level(&r);
    assert_eq!(counts.len(), 5, "{r}");
    let hits: u64 = counts.iter().sum();
    assert!(hits > 200 * 120 / 3, "{r}");
    // At scale 32 the near strip shows voxels and the far end coarser cells.
    let shown: Vec<usize> = (0..5).filter(|&l| counts[l] > 20).collect();
    assert!(shown.len() >= 3, "{counts:?}");
    // Coarser levels lie farther away: the mean distance falls as the level index rises.
    let dist = r["svo"]["mean_distance_per_level"].as_array().unwrap();
    let d: Vec<f64> = shown.iter().map(|&l| dist[l].as_f64().unwrap()).collect();
    assert!(d.windows(2).all(|w| w[0] > w[1]), "levels {shown:?}: {d:?}");
    // The level image holds each level's palette colour on exactly that many pixels.
    let img = rgba(&path(dir.path(), "level.png"));
    let palette = [
        [230, 25, 75],
        [245, 130, 48],
        [255, 225, 25],
        [60, 180, 75],
        [70, 240, 240],
    ];
    for (l, c) in palette.iter().enumerate() {
        let n = img.pixels().filter(|p| p.0[..3] == c[..]).count() as u64;
        assert_eq!(n, counts[l], "level {l}");
    }

    // A finer scale reaches the voxels more often; scale 0 shows nothing but voxels.
    let fine = per_level(&render(&pack, dir.path(), "fine", "level", "4"));
    assert!(fine[4] > counts[4], "{fine:?} vs {counts:?}");
    let zero = per_level(&render(&pack, dir.path(), "zero", "level", "0"));
    assert_eq!(zero[..4], [0, 0, 0, 0], "{zero:?}");
    assert!(zero[4] > 0);

    // Colour and normal views of the same rays agree with the CPU too (checked in `render`).
    let c = render(&pack, dir.path(), "colour", "colour", "32");
    assert_eq!(per_level(&c), counts);
    render(&pack, dir.path(), "normal", "normal", "32");
}

#[test]
fn a_huge_lod_scale_collapses_every_hit_to_the_root_colour() {
    // A solid box fills half its 64³ root: coverage above the floor, so the root may answer.
    let dir = tempfile::tempdir().unwrap();
    let obj = path(dir.path(), "block.obj");
    // A closed 4 × 4 × 2 m box.
    std::fs::write(&obj, common::box_obj([0.0; 3], [4.0, 4.0, 2.0], 1)).unwrap();
    let pack = path(dir.path(), "block.bake");
    let s = json(&bake(&[
        "svo",
        &obj,
        "-o",
        &pack,
        "--resolution",
        "64",
        "--solid",
        "--json",
    ]));
    assert_eq!(s["levels"], 3, "{s}");
    let view = ("6,-7,5", "2,2,1");
    let r = render_from(&pack, dir.path(), "root", "level", "1e6", view);
    let counts = per_level(&r);
    let hits: u64 = counts.iter().sum();
    assert_eq!(counts[0], hits, "{counts:?}");
    assert!(hits > 2000, "{counts:?}");
    // Every hit pixel is the root's palette colour, the rest the background.
    let img = rgba(&path(dir.path(), "root.png"));
    let colours: HashSet<[u8; 4]> = img.pixels().map(|p| p.0).collect();
    assert_eq!(colours.len(), 2, "{colours:?}");
    assert!(colours.contains(&[230, 25, 75, 255]), "{colours:?}");
    // In colour, the root's one colour and normal (lit facing either way) on every hit.
    render_from(&pack, dir.path(), "root_colour", "colour", "1e6", view);
    let img = rgba(&path(dir.path(), "root_colour.png"));
    let colours: HashSet<[u8; 4]> = img.pixels().map(|p| p.0).collect();
    assert!(colours.len() <= 3, "{colours:?}");
    // The same view at scale 1 shows the voxels and their lit faces.
    let fine = render_from(&pack, dir.path(), "detail", "colour", "1", view);
    assert_eq!(
        per_level(&fine)[3],
        per_level(&fine).iter().sum::<u64>(),
        "{fine}"
    );
    let img = rgba(&path(dir.path(), "detail.png"));
    let colours: HashSet<[u8; 4]> = img.pixels().map(|p| p.0).collect();
    assert!(colours.len() >= 4, "{}", colours.len());

    // On the sparse strip the root is below the coverage floor: a huge scale stops at the
    // first cell dense enough, never the root, and almost never a voxel.
    let strip = strip_pack(dir.path());
    let c = per_level(&render(&strip, dir.path(), "sparse", "level", "1e6"));
    let hits: u64 = c.iter().sum();
    assert_eq!(c[0], 0, "{c:?}");
    assert!(c[4] * 50 < hits, "{c:?}");
}

#[test]
fn a_pack_without_an_svo_section_is_an_invalid_input_and_a_bad_scale_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let pack = strip_pack(dir.path());
    let bare = path(dir.path(), "bare.bake");
    let mut w =
        bake::pack::PackWriter::from_pack(&bake::pack::Pack::open(Path::new(&pack)).unwrap());
    w.remove_kind("svo");
    w.write(Path::new(&bare)).unwrap();
    let png = path(dir.path(), "none.png");
    let o = bake(&["render", &bare, "-o", &png, "--view", "svo"]);
    assert_eq!(o.status.code(), Some(4), "{o:?}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no svo section"), "{err}");
    assert!(!Path::new(&png).exists());
    // A lod scale that is not a number is a usage error (exit 2) before any work.
    let o = bake(&[
        "render",
        &pack,
        "-o",
        &png,
        "--view",
        "svo",
        "--svo-lod-scale",
        "NaN",
    ]);
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("lod scale"),
        "{o:?}"
    );
    assert!(!Path::new(&png).exists());
    // An option of the mesh view is refused, not silently ignored.
    for extra in [&["--parallax"][..], &["--msaa", "1"], &["--soft-shadows"]] {
        let mut args = vec!["render", &pack, "-o", &png, "--view", "svo"];
        args.extend_from_slice(extra);
        let o = bake(&args);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {o:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("no effect with --view svo"), "{err}");
        assert!(!Path::new(&png).exists());
    }
}
