//! The placed scene that the svo and line-space stages read as one mesh is sized before it is
//! built, and refused (exit 4, naming the file and the budget) when it cannot fit --max-memory:
//! at the theses' scale (200,000 trees, ~10⁹ placed triangles) it used to be built and
//! killed by the kernel at 22 GB.

mod common;

use bake::pack::Pack;
use bake::voxel::geometry::{SceneStage, pack_geometry, placed_size};

#[test]
fn the_placed_size_is_the_mesh_that_pack_geometry_builds() {
    let dir = tempfile::tempdir().unwrap();
    let pack = Pack::open(&common::preview_fixture_pack(dir.path())).unwrap();
    let size = placed_size(&pack).unwrap();
    // Oracle: the mesh itself, built.
    let geo = pack_geometry(&pack).unwrap();
    let m = &geo.mesh;
    assert_eq!(size.vertices, m.positions.len() as u64);
    assert_eq!(size.triangles, m.indices.len() as u64);
    assert_eq!(size.instances, 100, "the fixture places 100 instances");
    // The estimate of the mesh's bytes is exactly what its per-vertex and per-triangle arrays
    // hold (so the budget check is a lower bound of the stage's memory, never above it).
    let arrays = 12 * m.positions.len()
        + 12 * m.normals.len()
        + 8 * m.uvs.len()
        + 12 * m.indices.len()
        + 4 * m.triangle_materials.len();
    assert_eq!(size.mesh_bytes(), arrays as u64);
    // The N-tree holds the voxelizer's set-up per triangle too, and the triangle itself.
    assert!(size.stage_bytes(SceneStage::Linespace) > size.stage_bytes(SceneStage::Svo));
    assert!(size.stage_bytes(SceneStage::Linespace) > size.mesh_bytes());
}

#[test]
fn a_placed_scene_over_the_budget_is_refused_before_it_is_built() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let size = placed_size(&Pack::open(&pack_path).unwrap()).unwrap();
    for (cmd, stage) in [
        ("svo", SceneStage::Svo),
        ("linespace", SceneStage::Linespace),
    ] {
        // Both stages fall back to their two-level forms where those need less (issue 39).
        let need = size.two_level_of(stage).min(size.stage_bytes(stage));
        let out = dir.path().join(format!("{cmd}.bake"));
        // One byte short: refused, nothing written.
        let o = common::bake(&[
            cmd,
            pack_path.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--max-memory",
            &(need - 1).to_string(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(4), "{cmd}: {err}");
        assert!(err.contains("scene.bake"), "{cmd}: names the pack: {err}");
        assert!(
            err.contains(&format!(
                "the {cmd} stage reads the placed scene as one mesh"
            )) && (cmd != "svo" || err.contains("its two-level form (one octree per model)"))
                && (cmd != "linespace"
                    || err.contains("its two-level form (one N-tree per model)"))
                && err.contains("100 instances")
                && err.contains(&format!("{} triangles", size.triangles))
                && err.contains("--max-memory"),
            "{cmd}: {err}"
        );
        assert!(!out.exists(), "{cmd}: no output after a refusal");
        // Exactly the estimate: accepted (the check is not a blanket refusal).
        let mut args = vec![
            cmd,
            pack_path.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ];
        let budget = need.to_string();
        args.extend(["--max-memory", &budget, "-q"]);
        if cmd == "svo" {
            args.extend(["--resolution", "32"]);
        } else {
            args.extend(["--depth", "1"]);
        }
        let o = common::bake(&args);
        assert!(
            o.status.success(),
            "{cmd}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(out.exists());
    }
}

#[test]
fn the_graph_refuses_the_placed_scene_before_the_lighting() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let size = placed_size(&Pack::open(&pack_path).unwrap()).unwrap();
    assert!(size.two_level_bytes < size.stage_bytes(SceneStage::Svo));
    let budget = (size.two_level_bytes - 1).to_string();
    let out = dir.path().join("svo-scene.bake");
    let scene = dir.path().join("scene.eco");
    let o = common::bake(&[
        scene.to_str().unwrap(),
        "--sky",
        dir.path().join("sky.hdr").to_str().unwrap(),
        "--preview",
        "--set",
        "stages.svo=true",
        "--no-cache",
        "--progress",
        "ndjson",
        "--max-memory",
        &budget,
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(4), "{err}");
    assert!(
        err.contains("scene.eco") && err.contains("the svo stage"),
        "{err}"
    );
    assert!(!out.exists(), "no pack after a refusal");
    // After the models' ingest (whose sizes it needs), before their PRT (which runs beside the
    // scene's units since issue 37), the sky and the scene's lighting: the progress events name
    // the stages that ran.
    let ran = |stage: &str| err.contains(&format!("\"stage\":\"{stage}\""));
    assert!(ran("ingest"), "{err}");
    for later in ["prt", "lod", "sky", "lightmap", "envmaps", "cluster", "svo"] {
        assert!(!ran(later), "{later} ran before the refusal: {err}");
    }
}

/// Between the two sizes the svo stage writes the two-level `svo-scene` section instead of
/// `svo`: from `bake svo` and from the graph, at the flattened scene's resolution, one octree
/// per model and every instance referenced (issue 39).
#[test]
fn over_the_flattened_budget_the_svo_stage_writes_the_two_level_svo() {
    use bake::voxel::instanced_section;
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let pack = Pack::open(&pack_path).unwrap();
    let size = placed_size(&pack).unwrap();
    let budget = (size.stage_bytes(SceneStage::Svo) - 1).to_string();
    assert!(size.two_level_bytes < size.stage_bytes(SceneStage::Svo));
    let flat_out = dir.path().join("flat.bake");
    let two_out = dir.path().join("two.bake");
    let p = pack_path.to_str().unwrap();
    let o = common::bake(&[
        "svo",
        p,
        "-o",
        flat_out.to_str().unwrap(),
        "--resolution",
        "64",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = common::bake(&[
        "svo",
        p,
        "-o",
        two_out.to_str().unwrap(),
        "--resolution",
        "64",
        "--max-memory",
        &budget,
        "--json",
    ]);
    let j = common::json(&o);
    assert_eq!(j["instances"], 100);
    let flat = Pack::open(&flat_out).unwrap();
    let two = Pack::open(&two_out).unwrap();
    assert!(flat.find("svo").is_some() && flat.find("svo-scene").is_none());
    assert!(two.find("svo-scene").is_some() && two.find("svo").is_none());
    let (_, fsvo) = bake::voxel::section::from_section(&flat.view_named("svo").unwrap()).unwrap();
    let (_, s) = instanced_section::from_section(&two.view_named("svo-scene").unwrap()).unwrap();
    assert_eq!(s.scene_grid, fsvo.grid, "the flattened SVO's resolution");
    let meshes = pack.of_kind("mesh").count();
    assert!(s.terrain, "the fixture has a terrain");
    assert!(
        s.models.len() <= meshes + 1,
        "one octree per model: {}",
        s.models.len()
    );
    assert_eq!(s.grid_instances(), 100);
    // The pack verifies (the kind is registered, its decoder accepts it).
    let o = common::bake(&["verify", two_out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // `bake validate`: the GPU traversal of both levels gives the CPU's answers.
    let v = common::json(&common::bake(&[
        "validate",
        two_out.to_str().unwrap(),
        "--rays",
        "3000",
        "--json",
    ]));
    assert_eq!(v["agree"], true, "{v}");
    assert_eq!(v["svo_scene"]["voxel_mismatches"], 0, "{v}");
    assert!(
        v["svo_scene"]["instance_hits"].as_u64().unwrap() > 30,
        "{v}"
    );
    // `bake render --view svo` draws it (GPU) beside the CPU's traversal of the same rays.
    let img = dir.path().join("svo.png");
    let reference = dir.path().join("svo-cpu.png");
    let svo_view = |extra: &[&str]| {
        let mut args = vec!["render", two_out.to_str().unwrap(), "--view", "svo"];
        args.extend_from_slice(extra);
        args.extend([
            "-o",
            img.to_str().unwrap(),
            "--reference",
            reference.to_str().unwrap(),
            "--width",
            "96",
            "--height",
            "64",
            "--json",
        ]);
        common::json(&common::bake(&args))
    };
    let r = svo_view(&[]);
    assert!(
        r["svo_scene"]["hits"].as_u64().unwrap() > 96 * 64 / 4,
        "{r}"
    );
    assert_eq!(r["reference"]["rays_disagree"], 0, "{r}");
    assert_eq!(r["reference"]["mad"], 0.0, "{r}");
    // The validation's LOD batch stops on the top level's aggregates and on the models' nodes
    // inside instances, GPU = CPU.
    assert!(
        v["svo_scene"]["lod"]["aggregate_hits"].as_u64().unwrap() > 30,
        "{v}"
    );
    assert!(
        v["svo_scene"]["lod"]["node_hits"].as_u64().unwrap() > 0,
        "{v}"
    );
    // With a wide cone the view reads the aggregates (top cells or sub-cells), with a middle
    // one the models' nodes as well, GPU = CPU; with cone 0 only voxels.
    for (scale, aggregates, nodes) in [
        ("40", Some(true), None),
        ("4", None, Some(true)),
        ("0", Some(false), Some(false)),
    ] {
        let r = svo_view(&["--svo-lod-scale", scale]);
        let on_aggregates = r["svo_scene"]["cell_hits"].as_u64().unwrap()
            + r["svo_scene"]["sub_cell_hits"].as_u64().unwrap();
        let on_nodes = r["svo_scene"]["node_hits"].as_u64().unwrap();
        if let Some(a) = aggregates {
            assert_eq!(on_aggregates > 20, a, "scale {scale}: {r}");
        }
        if let Some(n) = nodes {
            assert_eq!(on_nodes > 20, n, "scale {scale}: {r}");
        }
        assert_eq!(r["reference"]["rays_disagree"], 0, "{r}");
    }

    // The graph makes the same choice.
    let g = graph_bake(
        dir.path(),
        ["stages.svo=true", "svo.resolution=64"],
        &budget,
    );
    assert!(g.find("svo-scene").is_some() && g.find("svo").is_none());
    let (_, gs) = instanced_section::from_section(&g.view_named("svo-scene").unwrap()).unwrap();
    assert_eq!(gs.grid_instances(), 100);
    assert_eq!(gs.scene_grid, fsvo.grid);
}

/// Between the two sizes the linespace stage writes the two-level `linespace-scene` section
/// instead of `linespace`, from `bake linespace` and from the graph; its exact answers are the
/// flattened tree's (issue 39, item 2).
#[test]
fn over_the_flattened_budget_the_linespace_stage_writes_the_two_level_line_spaces() {
    use bake::linespace::instanced_section;
    use bake::linespace::query::{QueryStats, Segment};
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let size = placed_size(&Pack::open(&pack_path).unwrap()).unwrap();
    assert!(size.linespace_two_level_bytes < size.stage_bytes(SceneStage::Linespace));
    let budget = (size.stage_bytes(SceneStage::Linespace) - 1).to_string();
    let (flat_out, two_out) = (dir.path().join("flat.bake"), dir.path().join("two.bake"));
    let p = pack_path.to_str().unwrap();
    for (out, budget) in [(&flat_out, None), (&two_out, Some(&budget))] {
        let mut args = vec!["linespace", p, "-o", out.to_str().unwrap(), "--n", "4"];
        if let Some(b) = budget {
            args.extend(["--max-memory", b.as_str()]);
        }
        args.push("-q");
        let o = common::bake(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let flat = Pack::open(&flat_out).unwrap();
    let two = Pack::open(&two_out).unwrap();
    assert!(flat.find("linespace").is_some() && flat.find("linespace-scene").is_none());
    assert!(two.find("linespace-scene").is_some() && two.find("linespace").is_none());
    let (_, ft) =
        bake::linespace::section::from_section(&flat.view_named("linespace").unwrap()).unwrap();
    let (_, s) =
        instanced_section::from_section(&two.view_named("linespace-scene").unwrap()).unwrap();
    assert_eq!(s.instances.len(), 100);
    assert!(s.terrain.is_some(), "the fixture has a terrain");
    // Exact answers: the same as the flattened tree's on segments from the terrain up.
    let (lo, ext) = bake::linespace::gpu::root_box(&ft);
    let hi = [0, 1, 2].map(|k| lo[k] + ext[k]);
    let mut rng = bake::rng::Rng::new(3);
    let t = s.terrain.as_ref().unwrap();
    let (mut differ, mut blocked, total) = (0, 0, 4000);
    for _ in 0..total {
        let x = lo[0] + (hi[0] - lo[0]) * rng.f32();
        let y = lo[1] + (hi[1] - lo[1]) * rng.f32();
        let from = [x, y, t.terrain.mesh_height_at(x, y)];
        let to = [
            x + 20.0 * (rng.f32() - 0.5),
            y + 20.0 * (rng.f32() - 0.5),
            hi[2] + 5.0,
        ];
        let seg = Segment::between(from, to, 1e-3);
        let a = s.segment_occluded(&seg, &mut QueryStats::default());
        blocked += a as usize;
        differ += (a != ft.segment_occluded(&seg, &mut QueryStats::default())) as usize;
    }
    assert!(blocked > 0, "no segment blocked");
    assert_eq!(differ, 0, "{blocked} of {total} blocked");
    let o = common::bake(&["verify", two_out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    two_level_on_the_gpu(&flat, &two, &two_out, &ft, &s);
    two_level_on_the_gpu(&flat, &two, &two_out, &ft, &s);

    // The graph makes the same choice.
    let g = graph_bake(
        dir.path(),
        ["stages.linespace=true", "linespace.n=4"],
        &budget,
    );
    assert!(g.find("linespace-scene").is_some() && g.find("linespace").is_none());
    let (_, gs) =
        instanced_section::from_section(&g.view_named("linespace-scene").unwrap()).unwrap();
    assert_eq!(gs, s);
}

/// The two-level line spaces on the GPU: `bake validate` finds GPU = CPU in the `near` and
/// `exact` modes, and `--soft-shadows` over the `linespace-scene` pack answers every pixel as
/// the CPU's two-level query does and, in `exact` mode, as the flattened tree's pack does under
/// the same light (both are the placed scene's exact visibility of the same receivers).
fn two_level_on_the_gpu(
    flat: &Pack,
    two: &Pack,
    two_out: &std::path::Path,
    ft: &bake::linespace::ntree::NTree,
    s: &bake::linespace::instanced::SceneLinespace,
) {
    use bake::linespace::ntree::Refine;
    use bake::linespace::query::{AreaLight, QueryStats};
    use bake::render::soft_shadow::SoftShadows;
    use bake::render::{Lighting, RenderOptions, render_pack};
    for refine in ["near", "exact"] {
        let o = common::bake(&[
            "validate",
            two_out.to_str().unwrap(),
            "--receivers",
            "300",
            "--samples",
            "3",
            "--refine",
            refine,
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let j = common::json(&o);
        assert_eq!(j["linespace_scene"]["agree"], true, "{j}");
        assert_eq!(j["linespace_scene"]["segments"], 2700, "{j}");
        assert!(
            j["linespace_scene"]["occluded"].as_u64().unwrap() > 0,
            "{j}"
        );
    }
    // A view over the scene, a quad light above it at 45°.
    let (lo, ext) = bake::linespace::gpu::root_box(ft);
    let c = [0, 1, 2].map(|k| lo[k] + 0.5 * ext[k]);
    let light = AreaLight {
        corner: [c[0] + 20.0, c[1] - 4.0, lo[2] + ext[2] + 20.0],
        edge_u: [6.0, 0.0, 0.0],
        edge_v: [0.0, 6.0, 0.0],
        samples: 4,
    };
    let options = |refine| RenderOptions {
        width: 96,
        height: 72,
        eye: Some([c[0], c[1] - 0.3 * ext[1], c[2] + 0.25 * ext[0]]),
        target: Some([c[0], c[1], lo[2]]),
        fov_y_deg: 50.0,
        exposure: Some(1.0),
        lighting: Some(Lighting {
            sun_direction: [0.6, 0.0, 0.8],
            sun_irradiance: [3.0, 3.0, 3.0],
            ambient: [0.3, 0.3, 0.3],
            sun_solid_angle: 0.0,
        }),
        soft_shadows: Some(SoftShadows {
            area_light: Some(light),
            samples: 4,
            refine,
            compare_exact: true,
        }),
        ..RenderOptions::default()
    };
    let on_two = render_pack(two, &options(Refine::Exact)).unwrap();
    let on_flat = render_pack(flat, &options(Refine::Exact)).unwrap();
    let (a, b) = (
        on_two.soft_shadows.as_ref().unwrap(),
        on_flat.soft_shadows.as_ref().unwrap(),
    );
    assert_eq!(a.world, b.world, "the same receivers");
    let mut stats = QueryStats::default();
    let (mut shaded, mut differ) = (0, 0);
    for (p, (&v, &w)) in a.world.iter().zip(a.visibility.iter().zip(&b.visibility)) {
        if p[3] < 0.5 {
            continue;
        }
        let cpu = s.shadow([p[0], p[1], p[2]], &a.light, a.offset, &mut stats);
        assert!((v - cpu).abs() <= 1e-6, "at {p:?}: GPU {v}, CPU {cpu}");
        differ += (v != w) as usize;
        shaded += (v < 1.0) as usize;
    }
    assert_eq!(differ, 0, "two-level and flattened exact visibility differ");
    assert!(shaded > 20, "only {shaded} pixels in shadow");
    let cmp = a.comparison.as_ref().unwrap();
    assert_eq!(
        (cmp.brighter_pixels, cmp.mean_abs_error),
        (0, 0.0),
        "{cmp:?}"
    );
    // The thesis' refinement in the model trees: never brighter than exact visibility.
    let shaft = render_pack(two, &options(Refine::Shaft)).unwrap();
    let cmp = shaft.soft_shadows.unwrap().comparison.unwrap();
    assert_eq!(cmp.brighter_pixels, 0, "{cmp:?}");
}

/// The fixture scene baked by the graph (`--preview` with two `--set`s) under `budget` bytes.
fn graph_bake(dir: &std::path::Path, sets: [&str; 2], budget: &str) -> Pack {
    let out = dir.join("graph.bake");
    let o = common::bake(&[
        dir.join("scene.eco").to_str().unwrap(),
        "--sky",
        dir.join("sky.hdr").to_str().unwrap(),
        "--preview",
        "--set",
        sets[0],
        "--set",
        sets[1],
        "--no-cache",
        "-q",
        "--max-memory",
        budget,
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    Pack::open(&out).unwrap()
}
