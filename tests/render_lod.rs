//! Drawing at scale (issue 14): the renderer's detail levels from `lod` sections, against
//! oracles that do not share its code paths.
//!
//! - A level that is the full mesh re-indexed through a vertex permutation (each LOD vertex a
//!   copy of another mesh vertex, named by `vertex_source`) must render exactly like full detail:
//!   positions come from the level, normals, UVs, tangents and the PRT transfer are gathered
//!   through `vertex_source`, so any gathering mistake changes pixels.
//! - The level each instance draws follows `lod::select::choose` (the stats count the instances
//!   per level; `--lod-tau 0` draws level 0 only).

mod common;

use bake::lod::section::{LodArrays, LodLevel, LodMeta, full_mesh_lod, material_ranges};
use bake::pack::{Pack, StreamWriter};
use bake::render::{RenderOptions, Terms, render_pack};

fn fixture_pack(dir: &std::path::Path) -> std::path::PathBuf {
    let out = common::preview_fixture_pack(dir);
    // The preview preset runs the `lod` stage; these tests add their own levels to a pack
    // without them.
    let pack = Pack::open(&out).unwrap();
    let sections: Vec<_> = pack
        .checked_sections()
        .unwrap()
        .into_iter()
        .filter(|s| s.kind != bake::lod::section::KIND)
        .collect();
    drop(pack);
    let bare = dir.join("scene-without-lod.bake");
    let mut w = StreamWriter::create(&bare).unwrap();
    for s in &sections {
        w.push(s).unwrap();
    }
    w.finish().unwrap();
    bare
}

/// The section's mesh as level 0 and, as level 1 of error `error`, the same triangles over a
/// reversed copy of the vertices (LOD vertex i copies mesh vertex n − 1 − i).
fn permuted_lod(mesh_section: &str, mesh: &bake::model::Mesh, error: f32) -> (LodMeta, LodArrays) {
    let (mut meta, mut a) = full_mesh_lod(mesh_section, mesh);
    let n = mesh.positions.len() as u32;
    let l0 = meta.levels[0].clone();
    let rev = |v: u32| n - 1 - v;
    let first_triangle = a.indices.len() as u32;
    let tris: Vec<[u32; 3]> = a.indices.iter().map(|t| t.map(rev)).collect();
    let mats = a.triangle_materials.clone();
    a.positions
        .extend((0..n).map(|i| mesh.positions[rev(i) as usize]));
    a.vertex_source.extend((0..n).map(rev));
    a.indices.extend(tris);
    a.triangle_materials.extend(mats.iter().copied());
    meta.levels.push(LodLevel {
        first_vertex: n,
        first_triangle,
        error,
        ranges: material_ranges(first_triangle, &mats),
        ..l0
    });
    (meta, a)
}

/// The fixture pack with a permuted level 1 for every mesh of the scene.
fn pack_with_lods(src: &std::path::Path, dst: &std::path::Path, error: f32) {
    let pack = Pack::open(src).unwrap();
    let mut sections = pack.checked_sections().unwrap();
    let meshes: Vec<String> = pack.of_kind("mesh").map(|e| e.name.clone()).collect();
    for name in meshes {
        let (_, mesh) =
            bake::mesh::section::from_section(&pack.view_named(&name).unwrap()).unwrap();
        let (meta, arrays) = permuted_lod(&name, &mesh, error);
        sections.push(bake::lod::section::to_section(
            &bake::lod::section::lod_section_name(&name),
            &meta,
            &arrays,
        ));
    }
    let mut w = StreamWriter::create(dst).unwrap();
    for s in &sections {
        w.push(s).unwrap();
    }
    w.finish().unwrap();
}

fn view(tau: f32) -> RenderOptions {
    RenderOptions {
        width: 192,
        height: 108,
        terms: Terms::All,
        lod_tau: tau,
        ..RenderOptions::default()
    }
}

#[test]
fn a_permuted_copy_as_level_one_renders_exactly_like_full_detail() {
    let dir = tempfile::tempdir().unwrap();
    let src = fixture_pack(dir.path());
    let dst = dir.path().join("lod.bake");
    // Error 1e-6 model units: level 1 passes wherever the instance is more than a
    // micro-metre away, so every instance draws it at τ = 1.
    pack_with_lods(&src, &dst, 1e-6);
    let pack = Pack::open(&dst).unwrap();
    let full = render_pack(&pack, &view(0.0)).unwrap();
    let lod = render_pack(&pack, &view(1.0)).unwrap();
    let (fs, ls) = (&full.stats, &lod.stats);
    assert_eq!(fs.instances_per_level[0], fs.instances, "{fs:?}");
    assert!(fs.instances_per_level.get(1).is_none_or(|&n| n == 0));
    assert_eq!(ls.instances_per_level[0], 0, "{ls:?}");
    assert_eq!(ls.instances_per_level[1], ls.instances);
    assert!(ls.instances > 0 && ls.instances == fs.instances);
    assert_eq!(ls.triangles, fs.triangles);
    assert!(
        ls.ambient.prt_models > 0,
        "the fixture's plants carry PRT: {:?}",
        ls.ambient
    );
    // The same image, bit for bit: the ambient (PRT) term and the direct term read the
    // gathered attributes of the permuted vertices.
    let diff = bake::render::reference::image_difference(&full.image, &lod.image, 0).unwrap();
    assert_eq!(diff.max, 0, "LOD level differs from full detail: {diff:?}");
    // The original pack (no lod sections) gives the same image too.
    let plain = render_pack(&Pack::open(&src).unwrap(), &view(1.0)).unwrap();
    assert_eq!(plain.image.pixels, full.image.pixels);
}

#[test]
fn each_instance_draws_the_level_the_selection_rule_chooses() {
    let dir = tempfile::tempdir().unwrap();
    let src = fixture_pack(dir.path());
    let dst = dir.path().join("lod.bake");
    let opts = view(1.0);
    // Level 1's error puts the switch distance e·s·k/τ at the median instance's distance, so
    // the default view draws both levels.
    let error = {
        let plain = Pack::open(&src).unwrap();
        let scene = bake::render::scene::load_scene(&plain).unwrap();
        let v = bake::render::resolve_view(&plain, &scene, &opts);
        let k = bake::lod::select::pixels_per_unit(opts.height, v.camera.fov_y_deg);
        let mut d: Vec<f32> = scene
            .models
            .iter()
            .flat_map(|m| m.instances.iter().map(move |r| (m, r)))
            .map(|(m, r)| (m.sphere.placed(r).0 - v.camera.eye).length() / (r.scale.abs() * k))
            .collect();
        d.sort_by(f32::total_cmp);
        d[d.len() / 2]
    };
    pack_with_lods(&src, &dst, error);
    let pack = Pack::open(&dst).unwrap();
    let out = render_pack(&pack, &opts).unwrap();
    let s = &out.stats;
    // The oracle: the rule applied to every instance, with the view's k and each culled-in
    // instance's sphere distance (the frustum test is the cull module's, checked there).
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let v = bake::render::resolve_view(&pack, &scene, &opts);
    let frustum = bake::render::cull::Frustum::from_view_proj(v.camera.view_proj(), false);
    let k = bake::lod::select::pixels_per_unit(opts.height, v.camera.fov_y_deg);
    let mut expect = [0u64; 2];
    for m in &scene.models {
        let meta = m.lod.as_ref().expect("every model has a lod section");
        for r in &m.instances {
            let (c, rad) = m.sphere.placed(r);
            if !frustum.meets_sphere(c, rad) {
                continue;
            }
            match bake::lod::select::choose(meta, r.scale, (c - v.camera.eye).length(), k, 1.0) {
                bake::lod::select::Choice::Mesh(l) => expect[l] += 1,
                bake::lod::select::Choice::Impostor => unreachable!("no impostor"),
                bake::lod::select::Choice::Skeleton => unreachable!("no skeleton"),
            }
        }
    }
    assert_eq!(s.instances_per_level, expect.to_vec(), "{s:?}");
    assert!(
        expect[0] > 0 && expect[1] > 0,
        "the view mixes both levels: {expect:?}"
    );
    assert_eq!(s.instances + s.instances_culled, 100);
}

/// A rugged 257² terrain (4×4 chunks of 64 cells), red, under the analytic sky; `with_terrain`
/// false leaves the terrain out (the sky alone).
fn terrain_pack(dir: &std::path::Path, with_terrain: bool) -> Pack {
    use bake::model::{Rgba8Image, Terrain};
    let n = 257u32;
    let heights = (0..n * n)
        .map(|k| {
            let (x, y) = ((k % n) as f32, (k / n) as f32);
            6.0 * (0.11 * x).sin() * (0.07 * y).cos() + 2.0 * (0.5 * x + 0.3 * y).sin()
        })
        .collect();
    let t = Terrain {
        width: n,
        height: n,
        heights,
        origin: [0.0, 0.0],
        extent: [256.0, 256.0],
        color: None,
    };
    let mut w = bake::pack::PackWriter::new();
    if with_terrain {
        let color = bake::texture::source_section::texture_section_name("terrain", "color");
        let red = Rgba8Image {
            width: 1,
            height: 1,
            pixels: vec![[200, 30, 30, 255]],
        };
        w.insert(bake::texture::source_section::to_section(
            &color, "test", &red,
        ));
        w.insert(bake::terrain::source_section::to_section(
            "terrain",
            "test",
            &t,
            Some(color),
        ));
    }
    let path = dir.join(if with_terrain { "t.bake" } else { "sky.bake" });
    w.write(&path).unwrap();
    Pack::open(&path).unwrap()
}

#[test]
fn the_chunked_terrain_has_no_cracks_where_neighbouring_steps_differ() {
    let dir = tempfile::tempdir().unwrap();
    let opts = RenderOptions {
        width: 200,
        height: 200,
        eye: Some([128.0, 20.0, 60.0]),
        target: Some([128.0, 90.0, 0.0]),
        lighting: Some(bake::render::Lighting {
            sun_direction: [0.3, -0.4, 0.866],
            sun_irradiance: [3.0, 3.0, 3.0],
            ambient: [0.5, 0.5, 0.5],
            sun_solid_angle: 0.0,
        }),
        exposure: Some(1.0),
        // A coarse threshold, so the view mixes steps.
        lod_tau: 6.0,
        ..RenderOptions::default()
    };
    let terrain = render_pack(&terrain_pack(dir.path(), true), &opts).unwrap();
    let sky = render_pack(&terrain_pack(dir.path(), false), &opts).unwrap();
    let steps = &terrain.stats.terrain_chunks_per_step;
    assert!(
        steps.iter().filter(|&&c| c > 0).count() >= 2,
        "the view mixes chunk steps: {steps:?}"
    );
    // The view looks down at the terrain everywhere (the top ray meets the ground at y ≈ 205 m),
    // so a pixel equal to the sky-only image's is the sky seen through a crack.
    let through = terrain
        .image
        .pixels
        .iter()
        .zip(&sky.image.pixels)
        .filter(|(a, b)| a == b)
        .count();
    assert_eq!(
        through, 0,
        "{through} pixels show the sky through the terrain"
    );
    // And the terrain is red everywhere (no sky-coloured pixel at all).
    assert!(terrain.image.pixels.iter().all(|p| p[0] > p[2]));
}

/// The generated 20,000-instance scene (src/fixtures/large.rs, 6 tree models, 257² terrain),
/// ingested, then with the `lod` stage's sections of every model added.
fn large_packs(dir: &std::path::Path) -> (Pack, Pack) {
    let p = bake::fixtures::large::LargeScene {
        instances: 20_000,
        models: 6,
        terrain: 257,
    };
    for (name, bytes) in bake::fixtures::large::large_files(&p) {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
    let (w, _) = bake::pipeline::ingest_to_pack(
        &dir.join("scene.eco"),
        &bake::ingest::IngestOptions::default(),
    )
    .unwrap();
    let full = dir.join("full.bake");
    w.write(&full).unwrap();
    let pack = Pack::open(&full).unwrap();
    let mut out = StreamWriter::create(&dir.join("lod.bake")).unwrap();
    for s in pack.checked_sections().unwrap() {
        out.push(&s).unwrap();
    }
    let meshes: Vec<String> = pack.of_kind("mesh").map(|e| e.name.clone()).collect();
    for m in &meshes {
        let (s, _) = bake::lod::bake_lod(&pack, m, &bake::lod::LodOptions::DEFAULT).unwrap();
        out.push(&s).unwrap();
    }
    out.finish().unwrap();
    (pack, Pack::open(&dir.join("lod.bake")).unwrap())
}

/// LOD against full detail on a view both can draw: the view looks over the forest from 30 m
/// up, so instances from a few metres to the far edge are in it and several levels are drawn.
///
/// Issue 14 asks for a mean absolute difference ≤ 2/255 at the default τ. Measured here
/// (llvmpipe, 320×180, 4× MSAA, 2026-12-03; the floor, two *full-detail* renders whose eyes are
/// 1 cm apart, is MAD 3.16, since leaves are smaller than a pixel), τ: MAD, triangles of 17.2 M:
/// 0.5 px: 0.00, 17.2 M; 1 (the default): 0.04, 15.6 M; 2: 0.68, 8.9 M. Before leaf cards kept
/// their triangles and a level's error counted the cards it removes (`lod` stage version 1):
/// τ 0.1: 0.50, 14.8 M; 0.25: 3.25, 8.3 M; 1: 10.33, 2.7 M. The test holds τ 1 and τ 2 to the
/// issue's 2 steps.
#[test]
fn lod_and_full_detail_of_a_20000_instance_view_differ_by_at_most_2_steps() {
    let dir = tempfile::tempdir().unwrap();
    let (full_pack, lod_pack) = large_packs(dir.path());
    let opts = RenderOptions {
        width: 320,
        height: 180,
        eye: Some([128.0, 30.0, 70.0]),
        target: Some([128.0, 140.0, 40.0]),
        ..RenderOptions::default()
    };
    assert_eq!(opts.lod_tau, bake::lod::select::DEFAULT_TAU);
    let full = render_pack(
        &full_pack,
        &RenderOptions {
            lod_tau: 0.0,
            ..opts.clone()
        },
    )
    .unwrap();
    let fs = &full.stats;
    for tau in [bake::lod::select::DEFAULT_TAU, 2.0] {
        let lod = render_pack(
            &lod_pack,
            &RenderOptions {
                lod_tau: tau,
                ..opts.clone()
            },
        )
        .unwrap();
        let ls = &lod.stats;
        let d = bake::render::reference::image_difference(&full.image, &lod.image, 24).unwrap();
        eprintln!(
            "τ {tau}: full {} triangles, LOD {} triangles, per level {:?}; MAD {:.3}, {:.3} % over 24, max {}",
            fs.triangles,
            ls.triangles,
            ls.instances_per_level,
            d.mad,
            d.fraction_over * 100.0,
            d.max
        );
        if let Some(out) = std::env::var_os("BAKE_LOD_TEST_PNG") {
            let out = std::path::PathBuf::from(out);
            for (name, img) in [
                ("full.png", &full.image),
                (&format!("lod-{tau}.png"), &lod.image),
            ] {
                std::fs::write(out.join(name), bake::render::encode_png(img).unwrap()).unwrap();
            }
        }
        assert_eq!(
            fs.instances, ls.instances,
            "the same instances pass the culling"
        );
        assert!(
            ls.instances_per_level.iter().skip(1).any(|&n| n > 0),
            "τ {tau} draws simplified levels: {:?}",
            ls.instances_per_level
        );
        assert!(ls.triangles < fs.triangles, "LOD draws fewer triangles");
        assert!(d.mad <= 2.0, "τ {tau}: MAD {:.3} > 2/255", d.mad);
        if tau >= 2.0 {
            assert!(
                (ls.triangles as f64) < 0.6 * fs.triangles as f64,
                "τ {tau}: {} of {} triangles",
                ls.triangles,
                fs.triangles
            );
        }
    }
}

/// The fixture scene ingested (no PRT: every model's ambient is the sky SH fallback, the
/// impostor's too), with the `lod` stage's default levels and impostor atlas for every mesh;
/// its sections, the name of the instances section and the ingested instances.
fn impostor_sections(
    dir: &std::path::Path,
) -> (
    Vec<bake::pack::Section>,
    String,
    bake::ingest::instances_section::InstancesMeta,
    bake::model::Instances,
) {
    bake::fixtures::write_all(dir).unwrap();
    let (w, _) = bake::pipeline::ingest_to_pack(
        &dir.join("scene.eco"),
        &bake::ingest::IngestOptions::default(),
    )
    .unwrap();
    let full = dir.join("ingested.bake");
    w.write(&full).unwrap();
    let pack = Pack::open(&full).unwrap();
    let mut sections = pack.checked_sections().unwrap();
    let meshes: Vec<String> = pack.of_kind("mesh").map(|e| e.name.clone()).collect();
    for m in &meshes {
        let (s, _) = bake::lod::bake_lod(&pack, m, &bake::lod::LodOptions::DEFAULT).unwrap();
        sections.push(s);
    }
    let name = pack
        .of_kind(bake::ingest::instances_section::KIND)
        .next()
        .unwrap()
        .name
        .clone();
    let (meta, inst) =
        bake::ingest::instances_section::from_section(&pack.view_named(&name).unwrap()).unwrap();
    (sections, name, meta, inst)
}

fn write_pack(path: &std::path::Path, sections: &[bake::pack::Section]) -> Pack {
    let mut w = StreamWriter::create(path).unwrap();
    for s in sections {
        w.push(s).unwrap();
    }
    w.finish().unwrap();
    Pack::open(path).unwrap()
}

/// (a) The tile the impostor pass draws is the one whose centre direction is nearest to the view
/// direction: `nearest_tile` against brute force over all 64 tiles, at random directions of the
/// upper hemisphere, near the horizon, at the zenith and below the horizon (clamped to it).
#[test]
fn the_impostor_tile_is_the_nearest_view_by_brute_force() {
    use bake::lod::octa::tile_direction;
    use bake::render::impostor::nearest_tile;
    use glam::Vec3;
    let n = 8;
    let mut r = bake::rng::Rng::new(14);
    let mut dirs: Vec<Vec3> = (0..20_000)
        .map(|_| {
            let z = r.f32();
            let phi = r.f32() * std::f32::consts::TAU;
            let s = (1.0 - z * z).max(0.0).sqrt();
            Vec3::new(s * phi.cos(), s * phi.sin(), z)
        })
        .collect();
    // Near and on the horizon, straight up, and below the horizon.
    dirs.extend((0..720).map(|k| {
        let phi = k as f32 * 0.5f32.to_radians();
        Vec3::new(phi.cos(), phi.sin(), 0.002 * (k % 3) as f32)
    }));
    dirs.push(Vec3::Z);
    dirs.extend((0..100).map(|k| Vec3::new((k as f32).cos(), (k as f32).sin(), -0.5)));
    let mut off_cell = 0;
    for w in dirs {
        let (i, j) = nearest_tile(w, n);
        let wc = Vec3::new(w.x, w.y, w.z.max(0.0)).normalize();
        let got = tile_direction(i, j, n).dot(wc);
        let best = (0..n * n)
            .map(|t| tile_direction(t % n, t / n, n).dot(wc))
            .fold(f32::MIN, f32::max);
        assert!(
            got >= best - 1e-6,
            "{w}: tile ({i}, {j}) at cos {got}, the nearest at cos {best}"
        );
        if (i, j) != bake::lod::octa::tile_of(wc, n) {
            off_cell += 1;
        }
    }
    // The check is not vacuous: the cell holding a direction's coordinates is not always the
    // nearest view (the octahedral map is not equal-angle).
    assert!(off_cell > 0);
}

/// The sections of `base` (without the terrain unless `terrain`) with `items` as the only
/// instances.
fn with_instances(
    terrain: bool,
    base: &[bake::pack::Section],
    name: &str,
    meta: &bake::ingest::instances_section::InstancesMeta,
    models: &[String],
    items: Vec<bake::model::Instance>,
) -> Vec<bake::pack::Section> {
    let inst = bake::model::Instances {
        models: models.to_vec(),
        items,
    };
    base.iter()
        .filter(|s| terrain || s.kind != "terrain")
        .map(|s| {
            if s.name == name {
                bake::ingest::instances_section::to_section(name, &inst, meta.mesh_sections.clone())
            } else {
                s.clone()
            }
        })
        .collect()
}

/// The fixture's plant alone: the sections of [`impostor_sections`] with the first plant
/// instance as the only instance (`at`: moved there, for a background), without or with terrain.
struct OnePlant {
    base: Vec<bake::pack::Section>,
    name: String,
    meta: bake::ingest::instances_section::InstancesMeta,
    models: Vec<String>,
    one: bake::model::Instance,
    terrain: bool,
}

impl OnePlant {
    fn new(
        base: Vec<bake::pack::Section>,
        name: String,
        meta: bake::ingest::instances_section::InstancesMeta,
        inst: &bake::model::Instances,
        terrain: bool,
    ) -> OnePlant {
        OnePlant::of_model(base, name, meta, inst, terrain, "plant.txf")
    }

    /// The first instance of the model whose mesh section ends with `model`.
    fn of_model(
        base: Vec<bake::pack::Section>,
        name: String,
        meta: bake::ingest::instances_section::InstancesMeta,
        inst: &bake::model::Instances,
        terrain: bool,
        model: &str,
    ) -> OnePlant {
        let plant = meta
            .mesh_sections
            .iter()
            .position(|m| m.ends_with(model))
            .expect("the fixture has the model");
        let one = inst
            .items
            .iter()
            .find(|i| i.model as usize == plant)
            .copied()
            .unwrap();
        OnePlant {
            base,
            name,
            meta,
            models: inst.models.clone(),
            one,
            terrain,
        }
    }

    fn pack(&self, path: &std::path::Path, at: Option<[f32; 3]>) -> Pack {
        let mut one = self.one;
        if let Some(p) = at {
            one.position = p;
        }
        let s = with_instances(
            self.terrain,
            &self.base,
            &self.name,
            &self.meta,
            &self.models,
            vec![one],
        );
        write_pack(path, &s)
    }
}

/// Pixels of `img` that differ from the background `bg` (more than 2 steps in a channel), and
/// their mean sRGB colour.
fn coverage(img: &bake::model::Rgba8Image, bg: &bake::model::Rgba8Image) -> (usize, [f64; 3]) {
    let mut n = 0;
    let mut sum = [0.0f64; 3];
    for (p, on) in img.pixels.iter().zip(mask(img, bg)) {
        if on {
            n += 1;
            for c in 0..3 {
                sum[c] += p[c] as f64;
            }
        }
    }
    (n, sum.map(|v| v / n.max(1) as f64))
}

/// (b) One plant far enough that its impostor is chosen, against the same view at full detail
/// (τ = 0): the pixels it covers and their mean colour. The background (the same view with the
/// plant behind the eye, culled) tells which pixels the plant covers; no terrain, so no shadow
/// on the ground enters the count.
///
/// Measured (lavapipe, 256², the plant's sphere 60 px in radius, 2026-12-02): the impostor
/// covers 1113 px, full detail 1053 (5.7 % apart); mean sRGB (53.0, 110.1, 49.8) against
/// (54.4, 120.6, 46.6), 10.5 steps apart at most (green: Lambert on the atlas albedo against the
/// material's Schlick lobes, and the texel size: 64 texels over 120 px). Bounds: 10 % and 16
/// steps. From a direction between tiles (16° up, 7° from the nearest view) the same plant
/// differs by 16 % and 22 steps: grazing leaves change with the view, which is the 8×8 grid's
/// error, not the drawing's. `BAKE_IMPOSTOR_PNG=DIR` writes the three images. On 2026-12-07
/// (lavapipe) full detail covered 1,234 px, the impostor 1,113 (0.098 apart, 9.5 steps), with
/// parallax 1,197 (0.030 apart) but 15.9 steps: at 60 px the perspective rays are up to 11° off
/// the tile's direction, and a ray through the gaps between the crown's front leaves meets leaves
/// deeper in it, darker in the crown's shadow (docs/VALIDATION.md, twelfth session).
#[test]
fn a_far_plant_drawn_as_impostor_covers_and_colours_like_full_detail() {
    let [far, full, bg] = far_plant_views(false, Terms::All);
    let (n_far, c_far) = coverage(&far.image, &bg.image);
    let (n_full, c_full) = coverage(&full.image, &bg.image);
    let area = (n_far as f64 - n_full as f64).abs() / n_full as f64;
    let colour = (0..3)
        .map(|i| (c_far[i] - c_full[i]).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "impostor {n_far} px mean {c_far:?}; full detail {n_full} px mean {c_full:?}; \
         area {area:.3}, colour {colour:.2}"
    );
    assert!(n_full > 500, "the plant covers {n_full} px");
    assert!(area < 0.10, "coverage {n_far} vs {n_full}");
    assert!(colour < 16.0, "mean colour {c_far:?} vs {c_full:?}");
}

/// The same views over the fixture's terrain: the pixels the plant changes now include its
/// shadow on the ground, cast by the impostor (a sun-facing quad at the depth atlas' depths) in
/// one render and by the full mesh in the other. A missing or misplaced impostor shadow would
/// change the count by about the shadow's area.
///
/// Measured (lavapipe, 2026-12-02): plant and shadow 3429 px as impostor, 3288 px at full detail
/// (4.3 % apart; the plant alone is about 1100 px, so without its shadow the impostor would be
/// about 66 % short). Bound: 15 %.
#[test]
fn a_far_plant_drawn_as_impostor_casts_a_shadow_like_full_detail() {
    let [far, full, bg] = far_plant_views(true, Terms::All);
    assert!(far.stats.terrain_triangles > 0);
    let (n_far, _) = coverage(&far.image, &bg.image);
    let (n_full, _) = coverage(&full.image, &bg.image);
    let area = (n_far as f64 - n_full as f64).abs() / n_full as f64;
    eprintln!("with terrain: impostor {n_far} px, full detail {n_full} px, {area:.3} apart");
    assert!(area < 0.15, "plant and shadow {n_far} vs {n_full} px");
}

/// A w × w view from `eye` towards `target`, 45° field of view, every term, LOD threshold τ.
fn square_view(eye: glam::Vec3, target: glam::Vec3, w: u32, tau: f32) -> RenderOptions {
    RenderOptions {
        width: w,
        height: w,
        eye: Some(eye.to_array()),
        target: Some(target.to_array()),
        fov_y_deg: 45.0,
        terms: Terms::All,
        lod_tau: tau,
        ..RenderOptions::default()
    }
}

/// Renders of one fixture plant far enough for its impostor (τ just above its projected error)
/// and at full detail (τ = 0), and the background (the plant behind the eye), from the centre
/// direction of tile (1, 2), without or with the terrain.
fn far_plant_views(terrain: bool, terms: Terms) -> [bake::render::RenderOutput; 3] {
    use glam::Vec3;
    let dir = tempfile::tempdir().unwrap();
    let (base, name, meta, inst) = impostor_sections(dir.path());
    let plant = OnePlant::new(base, name, meta, &inst, terrain);
    let one = plant.one;
    let pack = plant.pack(&dir.path().join("one.bake"), None);
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let m = scene
        .models
        .iter()
        .find(|m| m.instances.len() == 1)
        .unwrap();
    let lod = m.lod.as_ref().unwrap();
    let imp = lod
        .impostor
        .as_ref()
        .expect("the lod stage baked an impostor");
    let r = &m.instances[0];
    let (c, radius) = m.sphere.placed(r);
    let (w, h) = (256u32, 256u32);
    let k = bake::lod::select::pixels_per_unit(h, 45.0);
    // The plant's sphere 60 px in radius; τ just above the impostor's projected error there.
    let d = radius * k / 60.0;
    let tau = imp.error * r.scale.abs() * k / d * 1.01;
    // Looking along the centre direction of tile (1, 2) (35° above the horizon), turned by the
    // instance's rotation: the tile's view is then the one an orthographic camera would see, and
    // the difference measures the drawing (placement, axes, lookup, light), not the 8×8 views'
    // spacing.
    let wm = bake::lod::octa::tile_direction(1, 2, imp.grid);
    let (sn, cs) = r.rotation_deg.to_radians().sin_cos();
    let ww = Vec3::new(cs * wm.x - sn * wm.y, sn * wm.x + cs * wm.y, wm.z);
    let eye = c + ww * d;
    let wc = Vec3::from(imp.centre) * r.scale;
    let wc = Vec3::new(cs * wc.x - sn * wc.y, sn * wc.x + cs * wc.y, wc.z) + Vec3::from(r.position);
    let wv = bake::render::impostor::model_view_direction(eye, wc, r.rotation_deg);
    assert_eq!(bake::render::impostor::nearest_tile(wv, imp.grid), (1, 2));
    let opts = |tau: f32| RenderOptions {
        terms,
        linear: true,
        ..square_view(eye, c, w, tau)
    };
    let far = render_pack(&pack, &opts(tau)).unwrap();
    let full = render_pack(&pack, &opts(0.0)).unwrap();
    assert_eq!(far.stats.impostor_instances, 1, "{:?}", far.stats);
    assert_eq!(far.stats.instances, 1);
    assert_eq!(full.stats.impostor_instances, 0);
    assert_eq!(full.stats.instances_per_level[0], 1);
    // Two triangles for the impostor against the whole mesh.
    assert_eq!(far.stats.triangles, 2 + far.stats.terrain_triangles);
    assert!(full.stats.triangles > 100 + far.stats.triangles);
    // The background: the plant moved behind the eye and 1 km up (its shadow far out of view).
    let back = Vec3::from(one.position) + (eye - c) * 2.0 + Vec3::Z * 1000.0;
    let bg_pack = plant.pack(&dir.path().join("bg.bake"), Some(back.to_array()));
    let bg = render_pack(&bg_pack, &opts(0.0)).unwrap();
    assert_eq!(bg.stats.instances, 0);
    if let Ok(o) = std::env::var("BAKE_IMPOSTOR_PNG") {
        for (n, i) in [
            ("far", &far.image),
            ("full", &full.image),
            ("bg", &bg.image),
        ] {
            let t = if terrain { "-terrain" } else { "" };
            let png = bake::render::encode_png(i).unwrap();
            std::fs::write(format!("{o}/{n}{t}.png"), png).unwrap();
        }
    }
    [far, full, bg]
}

/// Pixels of `img` that differ from the background `bg` (as [`coverage`]), as a mask.
fn mask(img: &bake::model::Rgba8Image, bg: &bake::model::Rgba8Image) -> Vec<bool> {
    img.pixels
        .iter()
        .zip(&bg.pixels)
        .map(|(p, q)| (0..3).any(|c| p[c].abs_diff(q[c]) > 2))
        .collect()
}

/// The fixture's 3DS bench alone (no terrain), through the material stage: its two-layer
/// materials (wood top, metal legs).
fn one_bench(dir: &std::path::Path) -> (OnePlant, Pack) {
    let (base, name, meta, inst) = impostor_sections(dir);
    let one = OnePlant::of_model(base, name, meta, &inst, false, "object.3ds");
    let plain = one.pack(&dir.join("plain.bake"), None);
    let (materials, _) = bake::material::bake_materials(&plain, &Default::default()).unwrap();
    let mut wr = bake::pack::PackWriter::from_pack(&plain);
    for s in materials {
        wr.insert(s);
    }
    let pack = Pack::from_bytes(&wr.to_bytes().unwrap(), "one.bake").unwrap();
    (one, pack)
}

/// The model of a scene's only instance.
fn the_one_model<'a>(
    scene: &'a bake::render::scene::SceneData<'a>,
) -> &'a bake::render::scene::ModelData<'a> {
    scene
        .models
        .iter()
        .find(|m| m.instances.len() == 1)
        .unwrap()
}

/// The impostor's picture lies where the model does, from a view between tiles: the fixture's
/// 3DS bench (elongated, so a turned picture shows), seen from high above (75°) at an azimuth
/// between the tiles' (the nearest tile's direction 11° away from the view and 45° apart in
/// azimuth), drawn as impostor against full detail: the overlap of the pixels they cover
/// (intersection over union). The impostor's quad lies in its tile's image plane with the tile's
/// own axes; when it faced the eye with axes from the eye's direction, the picture turned by the
/// azimuth between the two directions (docs/VALIDATION.md: the fixture's far benches drawn
/// rotated and about a metre off).
///
/// Measured (lavapipe, 256², 2026-12-05): intersection over union 0.78 with the tile's axes,
/// 0.20 with the eye's (the bench turned by 45°). Bound: 0.7. And the light (the pack through the
/// material stage): the impostor's mean linear luminance over its pixels is 1.04 of full
/// detail's, each texel lit by its material's two layers (the atlas normal's alpha names it);
/// 0.75 when it was Lambertian on the atlas albedo (the bench top's gloss missing), and 0.60
/// (both Lambertian) while its shadow lookup stayed on the surface of the eye's tile, where the
/// impostor's own shadow from the sun's tile covered it. Bound: ±15 %. And its size (2026-12-07,
/// lavapipe): 0.855 of full detail's pixels with the tile's picture turned to face the eye, 0.842
/// when the quad lay in the tile's plane (foreshortened by the cosine of the angle between eye
/// and tile); bound 0.85. With parallax (2026-12-07, lavapipe): IoU 0.805 → 0.839, 3,911 of full
/// detail's 3,567 pixels (1.10: a slat's column in the depth atlas reaches 4 texels behind it;
/// 1.17 and IoU 0.764 when columns reached through the whole box), luminance 1.014. Bounds: IoU
/// 0.8, size below 1.15.
#[test]
fn an_impostor_seen_between_tiles_covers_the_models_pixels() {
    use glam::Vec3;
    let dir = tempfile::tempdir().unwrap();
    let (one, pack) = one_bench(dir.path());
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let m = the_one_model(&scene);
    let lod = m.lod.as_ref().unwrap();
    let imp = lod.impostor.as_ref().expect("the bench has an impostor");
    let r = &m.instances[0];
    let (c, radius) = m.sphere.placed(r);
    // In the model frame: 75° up, azimuth 45°.
    let (el, az) = (75f32.to_radians(), 45f32.to_radians());
    let wm = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    let (ti, tj) = bake::render::impostor::nearest_tile(wm, imp.grid);
    let wt = bake::lod::octa::tile_direction(ti, tj, imp.grid);
    let gap = wm.dot(wt).clamp(-1.0, 1.0).acos().to_degrees();
    let azimuth_gap = (wm.y.atan2(wm.x) - wt.y.atan2(wt.x)).to_degrees().abs();
    assert!(
        gap < 12.0 && azimuth_gap > 30.0,
        "view {gap}° from its tile, {azimuth_gap}° in azimuth"
    );
    let (sn, cs) = r.rotation_deg.to_radians().sin_cos();
    let ww = Vec3::new(cs * wm.x - sn * wm.y, sn * wm.x + cs * wm.y, wm.z);
    let (w, h) = (256u32, 256u32);
    let k = bake::lod::select::pixels_per_unit(h, 45.0);
    let d = radius * k / 60.0;
    let tau = imp.error * r.scale.abs() * k / d * 1.01;
    let eye = c + ww * d;
    let opts = |tau: f32| square_view(eye, c, w, tau);
    let far = render_pack(&pack, &opts(tau)).unwrap();
    let full = render_pack(&pack, &opts(0.0)).unwrap();
    assert_eq!(far.stats.impostor_instances, 1, "{:?}", far.stats);
    assert_eq!(full.stats.impostor_instances, 0);
    let back = Vec3::from(one.one.position) + (eye - c) * 2.0 + Vec3::Z * 1000.0;
    let bg = render_pack(
        &one.pack(&dir.path().join("bg.bake"), Some(back.to_array())),
        &opts(0.0),
    )
    .unwrap();
    let (a, b) = (mask(&far.image, &bg.image), mask(&full.image, &bg.image));
    let inter = a.iter().zip(&b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(&b).filter(|(x, y)| **x || **y).count();
    let iou = inter as f64 / union.max(1) as f64;
    eprintln!(
        "bench: impostor {} px, full detail {} px, intersection over union {iou:.3}",
        a.iter().filter(|x| **x).count(),
        b.iter().filter(|x| **x).count()
    );
    assert!(
        b.iter().filter(|x| **x).count() > 300,
        "the bench covers too few pixels"
    );
    assert!(iou > 0.8, "intersection over union {iou:.3}");
    // Its size: drawn in the tile's plane the picture was foreshortened by the cosine of the
    // angle between the eye and the tile (3,002 of full detail's 3,567 pixels, 0.842, IoU 0.795);
    // turned to face the eye, 3,050 (0.855, IoU 0.805); with parallax 3,911 (1.10, IoU 0.839).
    let size = a.iter().filter(|x| **x).count() as f64 / b.iter().filter(|x| **x).count() as f64;
    assert!(
        size > 0.85 && size < 1.15,
        "impostor / full detail pixels {size:.3}"
    );
    // The light: the mean linear luminance over the pixels each covers.
    let mean = |img: &bake::model::Rgba8Image, m: &[bool]| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for (p, &on) in img.pixels.iter().zip(m) {
            if on {
                let lin = [0, 1, 2].map(|c| bake::color::srgb_to_linear(p[c] as f32 / 255.0));
                sum += bake::color::luminance(lin) as f64;
                n += 1;
            }
        }
        sum / n.max(1) as f64
    };
    let ratio = mean(&far.image, &a) / mean(&full.image, &b);
    eprintln!("bench: mean luminance impostor / full detail {ratio:.3}");
    assert!(
        (ratio - 1.0).abs() < 0.15,
        "impostor / full detail luminance {ratio:.3}"
    );
}

/// (c) The impostor count of a render is the number of culled-in instances `choose` gives the
/// impostor, and each mesh level's count matches too; τ puts the impostor's switch distance at
/// the median instance, so the view mixes impostors and meshes.
#[test]
fn the_impostor_count_is_what_the_selection_rule_assigns() {
    let dir = tempfile::tempdir().unwrap();
    let (base, _, _, _) = impostor_sections(dir.path());
    let pack = write_pack(&dir.path().join("lod.bake"), &base);
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let mut opts = view(1.0);
    let v = bake::render::resolve_view(&pack, &scene, &opts);
    let k = bake::lod::select::pixels_per_unit(opts.height, v.camera.fov_y_deg);
    let mut ratios: Vec<f32> = scene
        .models
        .iter()
        .filter_map(|m| Some((m, m.lod.as_ref()?.impostor.as_ref()?.error)))
        .flat_map(|(m, e)| m.instances.iter().map(move |r| (m, r, e)))
        .map(|(m, r, e)| e * r.scale.abs() * k / (m.sphere.placed(r).0 - v.camera.eye).length())
        .collect();
    ratios.sort_by(f32::total_cmp);
    opts.lod_tau = ratios[ratios.len() / 2];
    let out = render_pack(&pack, &opts).unwrap();
    let frustum = bake::render::cull::Frustum::from_view_proj(v.camera.view_proj(), false);
    let (mut impostors, mut meshes, mut skeletons) = (0u64, 0u64, 0u64);
    let mut per_level: Vec<u64> = Vec::new();
    for m in &scene.models {
        let meta = m.lod.as_ref().expect("every model has a lod section");
        for r in &m.instances {
            let (c, rad) = m.sphere.placed(r);
            if !frustum.meets_sphere(c, rad) {
                continue;
            }
            let d = (c - v.camera.eye).length();
            let l = match bake::lod::select::choose(meta, r.scale, d, k, opts.lod_tau) {
                bake::lod::select::Choice::Impostor => {
                    impostors += 1;
                    meta.levels.len()
                }
                bake::lod::select::Choice::Mesh(l) => {
                    meshes += 1;
                    l
                }
                bake::lod::select::Choice::Skeleton => {
                    skeletons += 1;
                    meta.levels.len() + meta.impostor.is_some() as usize
                }
            };
            if per_level.len() <= l {
                per_level.resize(l + 1, 0);
            }
            per_level[l] += 1;
        }
    }
    let s = &out.stats;
    assert!(
        impostors > 0 && meshes > 0,
        "{impostors} impostors, {meshes} meshes"
    );
    assert_eq!(s.impostor_instances, impostors, "{s:?}");
    assert_eq!(s.skeleton_instances, skeletons, "{s:?}");
    assert_eq!(s.instances, impostors + meshes + skeletons);
    per_level.resize(s.instances_per_level.len().max(per_level.len()), 0);
    assert_eq!(s.instances_per_level, per_level);
}

/// The pack's `lod` sections with every skeleton's pixel threshold set to `pixels` (so that a
/// test can draw a skeleton large enough to check where its lines land).
fn with_skeleton_pixels(sections: &[bake::pack::Section], pixels: f32) -> Vec<bake::pack::Section> {
    use bake::lod::section::{ImpostorAtlas, from_view, to_section};
    sections
        .iter()
        .map(|s| {
            if s.kind != bake::lod::section::KIND {
                return s.clone();
            }
            let pack = Pack::from_sections(std::slice::from_ref(s), "lod.bake");
            let view = pack.view_named(&s.name).unwrap();
            let v = from_view(&view, None).unwrap();
            let mut meta = v.meta.clone();
            if let Some(sk) = &mut meta.skeleton {
                sk.pixels = pixels;
            }
            let arrays = LodArrays {
                positions: v.positions.to_vec(),
                vertex_source: v.vertex_source.to_vec(),
                indices: v.indices.to_vec(),
                triangle_materials: v.triangle_materials.to_vec(),
                impostor: v.impostor.as_ref().map(|i| ImpostorAtlas {
                    color: i.color.to_vec(),
                    normal: i.normal.to_vec(),
                    depth: i.depth.to_vec(),
                }),
                skeleton_lines: v.skeleton_lines.to_vec(),
                skeleton_points: v.skeleton_points.to_vec(),
            };
            to_section(&s.name, &meta, &arrays)
        })
        .collect()
}

/// (d) A plant whose sphere projects below its skeleton's threshold is drawn as its TXF line and
/// point arrays, where the CPU projection of the segments puts them: every pixel the plant
/// changes (against the background, the plant behind the eye) lies within 1.5 px of a projected
/// segment or point, and the segments are drawn along their length (a pixel within 1 px of at
/// least 90 % of the 1-px steps along them). The threshold is raised to 40 px for the test so
/// that the lines are long enough to check (the default, 1 px, gives a dot); no terrain.
#[test]
fn a_plant_below_its_skeleton_threshold_draws_its_lines_where_they_project() {
    use glam::{Vec3, Vec4Swizzles};
    let dir = tempfile::tempdir().unwrap();
    let (base, name, meta, inst) = impostor_sections(dir.path());
    let plant = OnePlant::new(with_skeleton_pixels(&base, 40.0), name, meta, &inst, false);
    let pack = plant.pack(&dir.path().join("one.bake"), None);
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let m = scene
        .models
        .iter()
        .find(|m| m.instances.len() == 1)
        .unwrap();
    let sk = m.skeleton.as_ref().expect("the plant's TXF has a skeleton");
    assert!(!sk.lines.is_empty() && !sk.points.is_empty());
    let r = &m.instances[0];
    let (c, radius) = m.sphere.placed(r);
    let (w, h) = (256u32, 256u32);
    let k = bake::lod::select::pixels_per_unit(h, 45.0);
    // The sphere 36 px in radius (under the 40 px threshold), seen from 20° above the horizon.
    let d = radius * k / 36.0;
    let dir_to_eye = Vec3::new(0.94, 0.0, 0.34).normalize();
    let eye = c + dir_to_eye * d;
    let opts = RenderOptions {
        width: w,
        height: h,
        eye: Some(eye.to_array()),
        target: Some(c.to_array()),
        fov_y_deg: 45.0,
        msaa: 1,
        ..RenderOptions::default()
    };
    let out = render_pack(&pack, &opts).unwrap();
    assert_eq!(out.stats.skeleton_instances, 1, "{:?}", out.stats);
    assert_eq!(out.stats.instances, 1);
    assert_eq!(out.stats.impostor_instances, 0);
    assert_eq!(out.stats.triangles, 0, "no triangles: {:?}", out.stats);
    let back = Vec3::from(plant.one.position) + (eye - c) * 2.0 + Vec3::Z * 1000.0;
    let bg_pack = plant.pack(&dir.path().join("bg.bake"), Some(back.to_array()));
    let bg = render_pack(&bg_pack, &opts).unwrap();
    assert_eq!(bg.stats.instances, 0);
    // The CPU projection of the placed skeleton, in pixels from the top-left corner.
    let cam = bake::render::resolve_view(&pack, &scene, &opts).camera;
    let vp = cam.view_proj();
    let (sn, cs) = r.rotation_deg.to_radians().sin_cos();
    let place = |p: [f32; 3]| {
        let q = Vec3::from(p) * r.scale;
        Vec3::new(cs * q.x - sn * q.y, sn * q.x + cs * q.y, q.z) + Vec3::from(r.position)
    };
    let px = |p: Vec3| {
        let clip = vp * p.extend(1.0);
        let n = clip.xyz() / clip.w;
        glam::Vec2::new((n.x + 1.0) * 0.5 * w as f32, (1.0 - n.y) * 0.5 * h as f32)
    };
    let segs: Vec<(glam::Vec2, glam::Vec2)> = sk
        .lines
        .chunks_exact(2)
        .map(|s| (px(place(s[0])), px(place(s[1]))))
        .collect();
    let points: Vec<glam::Vec2> = sk.points.iter().map(|&p| px(place(p))).collect();
    let seg_dist = |q: glam::Vec2, (a, b): (glam::Vec2, glam::Vec2)| {
        let ab = b - a;
        let t = ((q - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        (a + ab * t - q).length()
    };
    let changed: Vec<glam::Vec2> = out
        .image
        .pixels
        .iter()
        .zip(&bg.image.pixels)
        .enumerate()
        .filter(|(_, (p, q))| (0..3).any(|ch| p[ch].abs_diff(q[ch]) > 2))
        .map(|(i, _)| glam::Vec2::new((i as u32 % w) as f32 + 0.5, (i as u32 / w) as f32 + 0.5))
        .collect();
    assert!(changed.len() >= 20, "{} pixels changed", changed.len());
    for q in &changed {
        let near_seg = segs
            .iter()
            .map(|&s| seg_dist(*q, s))
            .fold(f32::MAX, f32::min);
        let near_pt = points
            .iter()
            .map(|p| (*p - *q).length())
            .fold(f32::MAX, f32::min);
        assert!(
            near_seg.min(near_pt) <= 1.5,
            "pixel {q} is {near_seg} px from every segment and {near_pt} from every point"
        );
    }
    let (mut steps, mut hit) = (0, 0);
    for &(a, b) in &segs {
        let n = (b - a).length().ceil().max(1.0) as usize;
        for i in 0..=n {
            let s = a + (b - a) * (i as f32 / n as f32);
            steps += 1;
            if changed.iter().any(|q| (*q - s).length() <= 1.0) {
                hit += 1;
            }
        }
    }
    assert!(
        hit as f64 >= 0.9 * steps as f64,
        "{hit} of {steps} steps along the segments drawn"
    );
}

/// The plant's own shadow on itself in the direct term: the impostor's shadow-map lookup moves
/// towards the sun past the impostor's own shadow (the two tiles' angular error × radius), which
/// lost the crown's shadow on the trunk and the inner leaves; the atlas' view nearest the sun
/// now gives it back (`impostor_self_visibility`). Mean linear radiance of the plant's pixels in
/// the direct term, impostor against full detail.
#[test]
fn a_far_plant_drawn_as_impostor_shadows_itself_like_full_detail() {
    let [far, full, bg] = far_plant_views(false, Terms::Direct);
    let lum = |out: &bake::render::RenderOutput| {
        let lin = out.linear.as_ref().expect("linear radiance");
        let (mut sum, mut n) = (0.0f64, 0usize);
        for ((p, b), l) in out
            .image
            .pixels
            .iter()
            .zip(&bg.image.pixels)
            .zip(&lin.pixels)
        {
            if p != b {
                sum += (0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]) as f64;
                n += 1;
            }
        }
        (sum / n.max(1) as f64, n)
    };
    let ((l_far, n_far), (l_full, n_full)) = (lum(&far), lum(&full));
    let ratio = l_far / l_full;
    eprintln!(
        "direct term: impostor {l_far:.4} over {n_far} px, full detail {l_full:.4} over {n_full} px ({ratio:.3})"
    );
    assert!(n_full > 500, "the plant covers {n_full} px");
    assert!(
        (0.9..=1.1).contains(&ratio),
        "impostor / full detail direct {ratio:.3}"
    );
}

/// A pack's only instance rendered with its region image as impostor (τ large) and at full
/// detail (τ = 0), `opts` otherwise.
fn impostor_and_full_detail(
    pack: &Pack,
    opts: RenderOptions,
) -> (bake::render::RenderOutput, bake::render::RenderOutput) {
    let with = |tau: f32| RenderOptions {
        regions: true,
        lod_tau: tau,
        ..opts.clone()
    };
    let far = render_pack(pack, &with(1e6)).unwrap();
    let full = render_pack(pack, &with(0.0)).unwrap();
    assert_eq!(far.stats.impostor_instances, 1, "{:?}", far.stats);
    assert_eq!(full.stats.impostor_instances, 0);
    (far, full)
}

/// A small far impostor of a model without alpha-tested materials covers the pixels its mesh
/// covers, as MSAA covers the mesh's triangles: each sample tests the level-0 atlas texel under
/// it. The fixture's 3DS bench (slats and legs a few centimetres wide), drawn about 10 px wide
/// from 8 azimuths 35° up, as impostor (τ large) and at full detail (τ = 0), no terrain; the
/// region image's opaque coverage per pixel. Over the pixels the mesh covers wholly (all four
/// samples), the impostor's mean coverage; and the overlap Σ min / Σ mesh over all pixels.
/// When a pixel kept the samples whose thresholds the block's fractional coverage at the
/// footprint's level reached (a 4×4 block's ⅜ covers one or two samples wherever the slat lies
/// in the pixel), the ground showed through the bench's pixels: spec0's far houses and posts
/// read 0.857 of the path tracer's ambient term (docs/VALIDATION.md).
///
/// Measured (lavapipe, 2026-12-06, 132 px wholly covered by the mesh over the 8 views): before,
/// mean coverage 0.920 and overlap 0.803 (the block's coverage against the samples'
/// thresholds); after, 0.958 and 0.879. Bounds: 0.94 and 0.85. And the light: the summed linear
/// luminance of the pixels either covers, impostor / mesh, 0.978 before, 1.011 after (1.022
/// when the pixel was shaded with the footprint level's block, not the level-0 texel under its
/// centre). Bound: ±5 %. With parallax (2026-12-07, each sample's ray marched through the
/// level-0 depth atlas): 0.958 → 0.981, 0.879 → 0.967, radiance 1.049 → 0.996 (main measured
/// the same day).
#[test]
fn a_small_far_impostor_covers_the_pixels_its_mesh_covers() {
    use glam::Vec3;
    let dir = tempfile::tempdir().unwrap();
    let (_, pack) = one_bench(dir.path());
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let m = the_one_model(&scene);
    assert!(
        m.lod.as_ref().and_then(|l| l.impostor.as_ref()).is_some(),
        "the bench has an impostor"
    );
    let r = &m.instances[0];
    let (c, radius) = m.sphere.placed(r);
    let w = 64u32;
    let k = bake::lod::select::pixels_per_unit(w, 45.0);
    // The bench's sphere 6 px in radius.
    let d = radius * k / 6.0;
    let (mut full_px, mut covered, mut sum_min, mut sum_full) = (0usize, 0.0f64, 0.0f64, 0.0f64);
    let mut light = [0.0f64; 2];
    for a in 0..8 {
        let az = (a as f32 * 45.0 + 10.0).to_radians();
        let el = 35f32.to_radians();
        let dirv = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let (far, full) = impostor_and_full_detail(
            &pack,
            RenderOptions {
                linear: true,
                ..square_view(c + dirv * d, c, w, 0.0)
            },
        );
        let (fr, mr) = (
            far.regions.as_ref().unwrap(),
            full.regions.as_ref().unwrap(),
        );
        for (k, out) in [&far, &full].into_iter().enumerate() {
            let lin = &out.linear.as_ref().unwrap().pixels;
            for (i, l) in lin.iter().enumerate() {
                if fr.pixels[i][1] > 0.0 || mr.pixels[i][1] > 0.0 {
                    light[k] += (0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2]) as f64;
                }
            }
        }
        for (p, q) in fr.pixels.iter().zip(&mr.pixels) {
            let (imp, mesh) = (p[1] as f64, q[1] as f64);
            sum_min += imp.min(mesh);
            sum_full += mesh;
            if mesh > 0.99 {
                full_px += 1;
                covered += imp;
            }
        }
    }
    let mean = covered / full_px.max(1) as f64;
    let overlap = sum_min / sum_full.max(1e-9);
    eprintln!(
        "bench at 6 px: {full_px} px wholly covered by the mesh, the impostor's mean coverage \
         there {mean:.3}; overlap {overlap:.3} (mesh coverage {sum_full:.1} px); \
         radiance impostor / mesh {:.3}",
        light[0] / light[1]
    );
    assert!(full_px >= 40, "the mesh covers {full_px} px wholly");
    assert!(mean > 0.94, "mean coverage {mean:.3}");
    assert!(overlap > 0.85, "overlap {overlap:.3}");
    let ratio = light[0] / light[1];
    assert!(
        (ratio - 1.0).abs() < 0.05,
        "radiance impostor / mesh {ratio:.3}"
    );
}

/// Where an impostor's leaves lie, from views between tiles: the fixture's plant (alpha-tested
/// leaves) seen 30° up from 8 azimuths (each 2°–11° from its nearest tile), at two sizes (its
/// sphere 40 px in radius, the atlas read at level 0, and 10 px, read at level 1–2 as the
/// generated scene's far trees are), drawn as impostor (τ large) and at full detail (τ = 0), no
/// terrain; the region images. Two figures over the 8 views of each size: the share of full
/// detail's leaf pixels (leaves cover at least half) where the impostor draws a leaf (the
/// ground-truth harness's leaf fraction, with full detail as the reference), and the overlap of
/// the model's coverage, Σ min / Σ max per pixel (a soft intersection over union).
///
/// A picture from one tile shows each texel where the tile's plane through the centre puts it:
/// a leaf at depth δ in front of (behind) that plane lies δ·sin e off, e the angle between the
/// eye and the tile. Marching the eye's ray through the tile's depth atlas (parallax,
/// `shaders/impostor.wgsl` `march`) puts it where its depth does.
///
/// Measured (lavapipe, 2026-12-07, the 8 views 9.0°–9.6° from their tiles): at 40 px, leaf
/// fraction 0.638 of 2,724 px and overlap 0.438 with the tile's picture, 0.849 and 0.634 with
/// parallax; at 10 px (175 px), 0.783 and 0.446, then 0.903 and 0.475. Bounds: 0.80 and 0.55 at
/// 40 px, 0.85 at 10 px (its overlap, a few hundred pixels of partial coverage, is reported).
#[test]
fn an_impostor_seen_between_tiles_puts_its_leaves_where_full_detail_has_them() {
    use glam::Vec3;
    let dir = tempfile::tempdir().unwrap();
    let (base, name, meta, inst) = impostor_sections(dir.path());
    let plant = OnePlant::new(base, name, meta, &inst, false);
    let pack = plant.pack(&dir.path().join("one.bake"), None);
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let m = the_one_model(&scene);
    let imp = m.lod.as_ref().unwrap().impostor.as_ref().unwrap();
    let r = &m.instances[0];
    let (c, radius) = m.sphere.placed(r);
    let mut figures = Vec::new();
    for (w, px) in [(128u32, 40.0f32), (48, 10.0)] {
        let k = bake::lod::select::pixels_per_unit(w, 45.0);
        let d = radius * k / px;
        let (mut leaf_px, mut leaf_hit, mut sum_min, mut sum_max) = (0usize, 0usize, 0.0, 0.0);
        let mut gaps = Vec::new();
        for a in 0..8 {
            let az = (a as f32 * 45.0 + 10.0).to_radians();
            let el = 30f32.to_radians();
            let dirv = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            let wv = bake::render::impostor::model_view_direction(c + dirv, c, r.rotation_deg);
            let (ti, tj) = bake::render::impostor::nearest_tile(wv, imp.grid);
            let wt = bake::lod::octa::tile_direction(ti, tj, imp.grid);
            gaps.push(wv.dot(wt).clamp(-1.0, 1.0).acos().to_degrees());
            let (far, full) = impostor_and_full_detail(&pack, square_view(c + dirv * d, c, w, 0.0));
            let (fr, mr) = (
                far.regions.as_ref().unwrap(),
                full.regions.as_ref().unwrap(),
            );
            for (p, q) in fr.pixels.iter().zip(&mr.pixels) {
                if q[2] >= 0.5 {
                    leaf_px += 1;
                    leaf_hit += usize::from(p[2] > 0.0);
                }
                let (imp, mesh) = (f64::from(p[1] + p[2]), f64::from(q[1] + q[2]));
                sum_min += imp.min(mesh);
                sum_max += imp.max(mesh);
            }
        }
        let fraction = leaf_hit as f64 / leaf_px.max(1) as f64;
        let overlap = sum_min / f64::max(sum_max, 1e-9);
        eprintln!(
            "plant at {px} px: views {gaps:.1?}° from their tiles; leaf fraction {fraction:.3} \
             of {leaf_px} px, coverage overlap {overlap:.3}"
        );
        assert!(
            gaps.iter().filter(|&&g| g > 5.0).count() >= 4,
            "views between tiles: {gaps:?}"
        );
        assert!(leaf_px > 100, "full detail's leaves cover {leaf_px} px");
        figures.push((px, fraction, overlap));
    }
    let (_, fraction, overlap) = figures[0];
    assert!(fraction > 0.80, "leaf fraction {fraction:.3} at 40 px");
    assert!(overlap > 0.55, "coverage overlap {overlap:.3} at 40 px");
    let (_, fraction, _) = figures[1];
    assert!(fraction > 0.85, "leaf fraction {fraction:.3} at 10 px");
}
