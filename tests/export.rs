//! `bake export PACK -o scene.glb`: the preview-baked fixture scene as glTF, read back with the
//! `gltf` crate and checked against the pack (counts, one instance's transform, the sun), the
//! Khronos validator's verdict, and the refusal of a pack without meshes.

mod common;

use bake::ingest::instances_section::{self, InstanceRecord, InstancesMeta};
use bake::pack::Pack;
use glam::{Quat, Vec3};
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The fixture scene baked with the preview pipeline and exported to `dir/scene.<ext>`.
fn exported(dir: &Path, ext: &str) -> (PathBuf, PathBuf, Value) {
    let pack = common::preview_fixture_pack(dir);
    let out = dir.join(format!("scene.{ext}"));
    let report = export_json(pack.to_str().unwrap(), out.to_str().unwrap(), &[]);
    (pack, out, report)
}

/// The JSON chunk of a GLB as serde JSON (the extensions the `gltf` crate does not model:
/// EXT_mesh_gpu_instancing, KHR_lights_punctual).
fn glb_json(bytes: &[u8]) -> Value {
    let glb = gltf::Glb::from_slice(bytes).expect("a GLB");
    serde_json::from_slice(&glb.json).expect("its JSON chunk")
}

/// The f32 elements of accessor `index` (tightly packed float accessors, as bake writes them).
fn floats<const N: usize>(doc: &gltf::Document, blob: &[u8], index: usize) -> Vec<[f32; N]> {
    let a = doc.accessors().nth(index).expect("accessor");
    assert_eq!(a.data_type(), gltf::accessor::DataType::F32);
    assert_eq!(a.dimensions().multiplicity(), N);
    let view = a.view().expect("a buffer view");
    let start = view.offset() + a.offset();
    let bytes = &blob[start..start + a.count() * N * 4];
    bytemuck::pod_collect_to_vec(bytes)
}

/// bake's world (Z up) to glTF's (Y up): (x, y, z) → (x, z, −y).
fn y_up(p: Vec3) -> Vec3 {
    Vec3::new(p.x, p.z, -p.y)
}

fn instances_of(pack: &Pack) -> (InstancesMeta, Vec<InstanceRecord>) {
    let v = pack.view_named("instances").unwrap();
    let meta: InstancesMeta = v.meta().unwrap();
    let list: Vec<InstanceRecord> = v.array_vec("instances").unwrap();
    assert!(instances_section::from_section(&v).is_ok());
    (meta, list)
}

#[test]
fn the_fixture_scene_exports_with_the_packs_counts() {
    let dir = tempfile::tempdir().unwrap();
    let (pack_path, out, report) = exported(dir.path(), "glb");
    let pack = Pack::open(&pack_path).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(report["bytes"].as_u64().unwrap(), bytes.len() as u64);
    let (doc, buffers, images) = gltf::import_slice(&bytes).expect("gltf reads the GLB");
    let (meta, list) = instances_of(&pack);

    // Meshes: one per model, one for the terrain.
    let models = meta.models.len();
    assert!(models >= 2, "the fixture places several models");
    assert!(pack.find("terrain").is_some());
    assert_eq!(doc.meshes().count(), models + 1);
    assert_eq!(report["meshes"], models + 1);
    // Each model mesh: one primitive per material that has triangles, named by its section.
    for (name, section) in meta.models.iter().zip(&meta.mesh_sections) {
        let m = doc
            .meshes()
            .find(|m| m.name() == Some(name))
            .unwrap_or_else(|| panic!("no mesh {name}"));
        let v = pack.view_named(section).unwrap();
        let (_, mesh) = bake::mesh::section::from_section(&v).unwrap();
        let used: BTreeSet<u32> = mesh.triangle_materials.iter().copied().collect();
        assert_eq!(m.primitives().count(), used.len(), "{name}");
        let triangles: usize = m
            .primitives()
            .map(|p| p.indices().unwrap().count() / 3)
            .sum();
        assert_eq!(triangles, mesh.indices.len(), "{name}");
        for p in m.primitives() {
            let pos = p.get(&gltf::Semantic::Positions).unwrap();
            assert_eq!(pos.count(), mesh.positions.len());
        }
    }
    // Materials: every material section, plus the terrain's.
    let material_sections = pack.of_kind("material").count();
    assert_eq!(doc.materials().count(), material_sections + 1);
    // Textures and images: every distinct colour map of a material, plus the terrain's.
    let mut maps = BTreeSet::new();
    for e in pack.of_kind("material") {
        let m = bake::material::section::from_section(&pack.view(e).unwrap()).unwrap();
        maps.extend(m.color_map);
    }
    let terrain: bake::terrain::source_section::TerrainMeta =
        pack.view_named("terrain").unwrap().meta().unwrap();
    maps.extend(terrain.color_section.clone());
    // And the terrain's light map (TEXCOORD_1), checked texel by texel further down.
    let (lightmap, ..) = terrain_lightmap(&pack);
    assert_eq!(doc.textures().count(), maps.len() + 1);
    assert_eq!(images.len(), maps.len() + 1);
    for (img, section) in doc.images().zip(&images) {
        let name = img.name().unwrap();
        if name == lightmap {
            continue;
        }
        assert!(maps.contains(name), "image {name}");
        let t: bake::texture::source_section::TextureMeta =
            pack.view_named(name).unwrap().meta().unwrap();
        assert_eq!(
            (section.width, section.height),
            (t.width, t.height),
            "{name}"
        );
    }
    // The leaf card's material (a colour map with alpha) is alpha-tested at 0.5.
    let leaf = doc
        .materials()
        .find(|m| m.name().is_some_and(|n| n.contains("Leaf")))
        .expect("the fixture plant's leaf material");
    assert_eq!(leaf.alpha_mode(), gltf::material::AlphaMode::Mask);
    assert_eq!(leaf.alpha_cutoff(), Some(0.5));
    assert!(leaf.pbr_metallic_roughness().base_color_texture().is_some());
    assert_eq!(leaf.pbr_metallic_roughness().metallic_factor(), 0.0);

    // Nodes: one per model, the terrain, the sun, the root.
    assert_eq!(doc.nodes().count(), models + 3);
    let scene = doc.default_scene().unwrap();
    assert_eq!(scene.nodes().count(), 1, "one root node");
    assert_eq!(scene.nodes().next().unwrap().children().count(), models + 2);

    // Instances: the instancing accessors of every model node hold the section's count.
    let json = glb_json(&bytes);
    let blob = &buffers[0].0;
    let mut count = 0;
    for n in json["nodes"].as_array().unwrap() {
        if let Some(ext) = n["extensions"].get("EXT_mesh_gpu_instancing") {
            let a = &ext["attributes"];
            let t = a["TRANSLATION"].as_u64().unwrap() as usize;
            let r = a["ROTATION"].as_u64().unwrap() as usize;
            let s = a["SCALE"].as_u64().unwrap() as usize;
            let k = floats::<3>(&doc, blob, t).len();
            assert_eq!(floats::<4>(&doc, blob, r).len(), k);
            assert_eq!(floats::<3>(&doc, blob, s).len(), k);
            count += k;
            assert!(
                n["extras"]["section"]
                    .as_str()
                    .unwrap()
                    .starts_with("mesh:")
            );
        }
    }
    assert_eq!(count, list.len());
    assert_eq!(report["instances"], list.len());
    let dump = common::json(&common::bake(&[
        "dump",
        pack_path.to_str().unwrap(),
        "--json",
        "--section",
        "instances",
    ]));
    assert_eq!(dump["sections"][0]["summary"]["count"], count);
}

#[test]
fn an_instance_lands_where_the_pack_places_it_after_the_axis_conversion() {
    let dir = tempfile::tempdir().unwrap();
    let (pack_path, out, _) = exported(dir.path(), "glb");
    let pack = Pack::open(&pack_path).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let blob = &buffers[0].0;
    let (meta, list) = instances_of(&pack);
    // An instance with a rotation and a scale other than 1 where the fixture has one.
    let (k, rec) = list
        .iter()
        .enumerate()
        .max_by(|a, b| {
            let score = |r: &InstanceRecord| r.rotation_deg.abs() + (r.scale - 1.0).abs();
            score(a.1).total_cmp(&score(b.1))
        })
        .unwrap();
    assert!(rec.rotation_deg != 0.0, "the fixture rotates its instances");
    let model = &meta.models[rec.model as usize];
    let within = list[..k].iter().filter(|r| r.model == rec.model).count();
    let node = json["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["name"] == model.as_str())
        .unwrap();
    let a = &node["extensions"]["EXT_mesh_gpu_instancing"]["attributes"];
    let t = floats::<3>(&doc, blob, a["TRANSLATION"].as_u64().unwrap() as usize)[within];
    let r = floats::<4>(&doc, blob, a["ROTATION"].as_u64().unwrap() as usize)[within];
    let s = floats::<3>(&doc, blob, a["SCALE"].as_u64().unwrap() as usize)[within];
    assert_eq!(t, rec.position);
    assert_eq!(s, [rec.scale; 3]);
    // A rotation about +Z by rotation_deg.
    let half = rec.rotation_deg.to_radians() / 2.0;
    for (got, want) in r.iter().zip([0.0, 0.0, half.sin(), half.cos()]) {
        assert!((got - want).abs() < 1e-6, "rotation {r:?}");
    }
    // The root node's rotation and the instance's TRS take a model point to glTF's Y-up world
    // where docs/CONVENTIONS.md's transform puts it in bake's Z-up world.
    let root = doc.default_scene().unwrap().nodes().next().unwrap();
    let (rt, rr, rs) = root.transform().decomposed();
    assert_eq!((rt, rs), ([0.0; 3], [1.0; 3]));
    let root_q = Quat::from_array(rr);
    let inst_q = Quat::from_array(r);
    for p in [Vec3::new(0.3, -0.2, 1.5), Vec3::X, Vec3::Z] {
        let gltf_world = root_q * (Vec3::from(t) + inst_q * (Vec3::from(s) * p));
        let (sn, cs) = rec.rotation_deg.to_radians().sin_cos();
        let q = p * rec.scale;
        let bake_world =
            Vec3::from(rec.position) + Vec3::new(cs * q.x - sn * q.y, sn * q.x + cs * q.y, q.z);
        assert!(
            (gltf_world - y_up(bake_world)).length() < 1e-4 * (1.0 + bake_world.length()),
            "{p}: {gltf_world} vs {}",
            y_up(bake_world)
        );
    }
}

#[test]
fn the_sun_is_a_directional_light_in_lux() {
    let dir = tempfile::tempdir().unwrap();
    let (pack_path, out, report) = exported(dir.path(), "glb");
    let pack = Pack::open(&pack_path).unwrap();
    let sun = bake::sky::section::sun_from_section(&pack.view_named("sun").unwrap()).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let (doc, _, _) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let lights = json["extensions"]["KHR_lights_punctual"]["lights"]
        .as_array()
        .unwrap();
    assert_eq!(lights.len(), 1);
    let light = &lights[0];
    assert_eq!(light["type"], "directional");
    // 683 lm/W × the Rec. 709 luminance of the RGB irradiance (docs/MATERIALS.md).
    let e = sun.irradiance;
    let want = 683.0 * (0.2126 * e[0] + 0.7152 * e[1] + 0.0722 * e[2]);
    let got = light["intensity"].as_f64().unwrap() as f32;
    assert!(want > 0.0);
    assert!((got - want).abs() <= 1e-4 * want, "{got} lx vs {want}");
    assert!((report["sun_lux"].as_f64().unwrap() as f32 - want).abs() <= 1e-4 * want);
    // It shines along its node's −Z: in glTF's world, from the sun's direction.
    let node = doc.nodes().find(|n| n.name() == Some("sun")).unwrap();
    let root = doc.default_scene().unwrap().nodes().next().unwrap();
    let q = Quat::from_array(root.transform().decomposed().1)
        * Quat::from_array(node.transform().decomposed().1);
    let shines = q * Vec3::NEG_Z;
    let towards_sun = y_up(Vec3::from(sun.direction).normalize());
    assert!(
        (shines + towards_sun).length() < 1e-4,
        "{shines} vs −{towards_sun}"
    );
}

#[test]
fn gltf_with_an_embedded_buffer_reads_back_alike() {
    let dir = tempfile::tempdir().unwrap();
    let pack = common::preview_fixture_pack(dir.path());
    let out = dir.path().join("scene.gltf");
    let report = export_json(
        pack.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--embed-buffer"],
    );
    let bytes = std::fs::read(&out).unwrap();
    assert_eq!(&bytes[..1], b"{", "JSON glTF");
    // The streamed file (JSON, then the buffer base64-encoded into its data URI) is as long as
    // the report says, and is the only file beside the pack's sources.
    assert_eq!(report["bytes"].as_u64().unwrap(), bytes.len() as u64);
    let (doc, buffers, images) = gltf::import_slice(&bytes).expect("gltf reads it");
    assert_eq!(buffers.len(), 1);
    assert_eq!(
        doc.meshes().count() as u64,
        report["meshes"].as_u64().unwrap()
    );
    assert_eq!(images.len() as u64, report["images"].as_u64().unwrap());
    assert_eq!(
        std::fs::read_dir(dir.path())
            .unwrap()
            .filter(|e| e
                .as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "bin"))
            .count(),
        0,
        "no side files"
    );
}

#[test]
fn gltf_with_a_side_file_holds_the_glbs_buffer_and_replaces_it_whole() {
    let dir = tempfile::tempdir().unwrap();
    let (pack, glb, _) = exported(dir.path(), "glb");
    let pack = pack.to_str().unwrap();
    let out_dir = dir.path().join("out");
    let gltf = out_dir.join("scene.gltf");
    let bins = || -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(&out_dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".bin"))
            .collect();
        v.sort();
        v
    };
    let report = export_json(pack, gltf.to_str().unwrap(), &[]);
    let side = report["side_file"]
        .as_str()
        .expect("a side file")
        .to_string();
    assert!(
        side.starts_with("scene-") && side.len() == "scene-".len() + 16 + ".bin".len(),
        "{side}"
    );
    assert_eq!(bins(), vec![side.clone()]);
    // The side file is the GLB's binary chunk, byte for byte, and the JSON names it.
    let glb_bytes = std::fs::read(&glb).unwrap();
    let chunk = gltf::Glb::from_slice(&glb_bytes).unwrap();
    let bin = std::fs::read(out_dir.join(&side)).unwrap();
    assert_eq!(bin.as_slice(), &chunk.bin.unwrap()[..]);
    let text = std::fs::read(&gltf).unwrap();
    assert_eq!(
        report["bytes"].as_u64().unwrap(),
        (text.len() + bin.len()) as u64
    );
    let json: Value = serde_json::from_slice(&text).unwrap();
    assert_eq!(json["buffers"][0]["uri"], side.as_str());
    assert_eq!(json["buffers"][0]["byteLength"], bin.len() as u64);
    // The `gltf` crate resolves the side file and reads the scene as the GLB's.
    let (doc, buffers, images) = gltf::import(&gltf).expect("gltf reads it with its side file");
    let (gdoc, _, gimages) = gltf::import(&glb).unwrap();
    assert_eq!(buffers[0].len(), bin.len());
    assert_eq!(doc.meshes().count(), gdoc.meshes().count());
    assert_eq!(doc.nodes().count(), gdoc.nodes().count());
    assert_eq!(images.len(), gimages.len());
    // Another scene under the same name: a new side file, the old one removed.
    let lit = export_json(pack, gltf.to_str().unwrap(), &["--bake-light"]);
    let side2 = lit["side_file"].as_str().unwrap().to_string();
    assert_ne!(side2, side);
    assert_eq!(bins(), vec![side2.clone()]);
    // A failed export (a pack without meshes) leaves the scene and its side file as they were.
    let (before, before_bin) = (
        std::fs::read(&gltf).unwrap(),
        std::fs::read(out_dir.join(&side2)).unwrap(),
    );
    let sky = dir.path().join("sky.bake");
    let o = common::bake(&["sky", "-o", sky.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = common::bake(&[
        "export",
        sky.to_str().unwrap(),
        "-o",
        gltf.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(4));
    assert_eq!(std::fs::read(&gltf).unwrap(), before);
    assert_eq!(std::fs::read(out_dir.join(&side2)).unwrap(), before_bin);
    assert_eq!(bins(), vec![side2]);
    // --embed-buffer is for .gltf only.
    let o = common::bake(&[
        "export",
        pack,
        "-o",
        glb.to_str().unwrap(),
        "--embed-buffer",
    ]);
    assert_eq!(o.status.code(), Some(2));
}

/// `bake export PACK -o OUT EXTRA... --quiet`, which must succeed.
fn export_ok(pack: &str, out: &str, extra: &[&str]) {
    let mut args = vec!["export", pack, "-o", out];
    args.extend_from_slice(extra);
    args.push("--quiet");
    let o = common::bake(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `bake export PACK -o OUT EXTRA... --json`, which must succeed: its report.
fn export_json(pack: &str, out: &str, extra: &[&str]) -> Value {
    let mut args = vec!["export", pack, "-o", out];
    args.extend_from_slice(extra);
    args.push("--json");
    common::json(&common::bake(&args))
}

/// The Khronos validator's package folder, or `None` (a skip; a failure under `CI`).
fn validator() -> Option<PathBuf> {
    let dir = std::env::var_os("GLTF_VALIDATOR")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("target/gltf-validator/node_modules/gltf-validator")
        });
    let node = common::tool_available("node", "runs the Khronos glTF validator");
    if !node {
        return None;
    }
    common::installed(
        &dir.join("package.json"),
        "the Khronos glTF validator (scripts/install-gltf-validator.sh)",
    )
    .then_some(dir)
}

#[test]
fn the_khronos_validator_finds_no_errors() {
    let Some(validator) = validator() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (pack, glb, _) = exported(dir.path(), "glb");
    // The same pack as JSON glTF with the buffer embedded.
    let gltf = dir.path().join("scene.gltf");
    export_ok(pack.to_str().unwrap(), gltf.to_str().unwrap(), &[]);
    // And with the light map baked into an unlit base colour.
    let lit = dir.path().join("lit.glb");
    export_ok(
        pack.to_str().unwrap(),
        lit.to_str().unwrap(),
        &["--bake-light"],
    );
    // And with the PRT ambient as COLOR_0, the LOD chain and the normal maps, beside the baked
    // light.
    let ambient = dir.path().join("ambient.glb");
    export_ok(
        pack.to_str().unwrap(),
        ambient.to_str().unwrap(),
        &["--bake-light", "--vertex-ambient", "--lod", "--normal-maps"],
    );
    // A generated scene (`bake fixtures --instances 2000 --models 4 --terrain 129`, the preview
    // pipeline) with every option and the terrain at every second sample.
    let gen_dir = dir.path().join("gen");
    let g = |f: &str| gen_dir.join(f).to_str().unwrap().to_string();
    let o = common::bake(&[
        "fixtures",
        gen_dir.to_str().unwrap(),
        "--instances",
        "2000",
        "--models",
        "4",
        "--terrain",
        "129",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = common::bake(&[
        &g("scene.eco"),
        "--sky",
        &g("sky.hdr"),
        "--pipeline",
        "preview",
        "--no-cache",
        "-o",
        &g("g.bake"),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let generated = gen_dir.join("g.glb");
    let report = export_json(
        &g("g.bake"),
        generated.to_str().unwrap(),
        &[
            "--bake-light",
            "--vertex-ambient",
            "--lod",
            "--normal-maps",
            "--terrain-step",
            "2",
        ],
    );
    assert_eq!(report["instances"], 2000);
    assert_eq!(report["vertex_ambient_models"], 4);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/gltf-validate.js");
    for file in [glb, gltf, lit, ambient, generated] {
        let o = std::process::Command::new("node")
            .arg(&script)
            .arg(&validator)
            .arg(&file)
            .output()
            .expect("run node");
        let issues: Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
            panic!(
                "the validator printed no JSON ({e}): {}",
                String::from_utf8_lossy(&o.stderr)
            )
        });
        let errors: Vec<&Value> = issues["messages"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|m| m["severity"] == 0)
            .collect();
        assert_eq!(issues["numErrors"], 0, "{}: {errors:#?}", file.display());
        assert_eq!(issues["numWarnings"], 0, "{}", file.display());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        eprintln!(
            "gltf-validator on {}: {} errors, {} warnings, {} infos",
            file.display(),
            issues["numErrors"],
            issues["numWarnings"],
            issues["numInfos"]
        );
    }
}

#[test]
fn a_pack_without_meshes_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let pack = dir.path().join("sky.bake");
    let o = common::bake(&["sky", "-o", pack.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.path().join("out/scene.glb");
    let o = common::bake(&[
        "export",
        pack.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(4));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("sky.bake") && err.contains("no mesh section"),
        "{err}"
    );
    assert!(!out.exists());
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        left,
        vec![std::ffi::OsString::from("sky.bake")],
        "no output, no temporary"
    );
    // An output that is neither .glb nor .gltf is a usage error.
    let o = common::bake(&["export", pack.to_str().unwrap(), "-o", "scene.obj"]);
    assert_eq!(o.status.code(), Some(2));
}

/// `d/m.bake`: a `w × h` RAW terrain (heights (7i + 3j) mod 256, scale 0.05) merged with a 1 × 2 × 3
/// m OBJ box: no instances section, no material sections.
fn terrain_and_box_pack(d: &Path, w: u32, h: u32) {
    let raw: Vec<u8> = (0..h)
        .flat_map(|j| (0..w).map(move |i| ((i * 7 + j * 3) % 256) as u8))
        .collect();
    std::fs::write(d.join("t.raw"), &raw).unwrap();
    std::fs::write(
        d.join("box.obj"),
        common::box_obj([0.0, 0.0, 0.0], [1.0, 2.0, 3.0], 1),
    )
    .unwrap();
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    let size = format!("{w}x{h}");
    for args in [
        vec![
            "ingest",
            &p("t.raw"),
            "--size",
            &size,
            "--scale",
            "0.05",
            "-o",
            &p("t.bake"),
        ],
        vec!["ingest", &p("box.obj"), "-o", &p("b.bake")],
        vec!["merge", &p("t.bake"), &p("b.bake"), "-o", &p("m.bake")],
    ] {
        let args: Vec<&str> = args.iter().map(|s| s.as_ref()).collect();
        let o = common::bake(&[&args[..], &["--quiet"]].concat());
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

#[test]
fn an_ingest_only_pack_exports_its_terrain_in_chunks_and_its_mesh_at_the_origin() {
    // A 130 × 70 RAW terrain (129 × 69 cells: 3 × 2 chunks of at most 64² cells) merged with an
    // OBJ model: no instances section, no material sections (the mesh's own material is used).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (130u32, 70u32);
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    terrain_and_box_pack(d, w, h);
    let report = export_json(&p("m.bake"), &p("m.glb"), &[]);
    assert_eq!(report["terrain_chunks"], 6);
    assert_eq!(report["instances"], 0);
    let bytes = std::fs::read(d.join("m.glb")).unwrap();
    let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    assert!(
        json.get("extensionsUsed").is_none(),
        "no extension without instances"
    );
    let terrain = doc.meshes().find(|m| m.name() == Some("terrain")).unwrap();
    assert_eq!(terrain.primitives().count(), 6);
    let pack = Pack::open(&d.join("m.bake")).unwrap();
    let (tm, t) =
        bake::terrain::source_section::from_section(&pack.view_named("terrain").unwrap()).unwrap();
    let blob = &buffers[0].0;
    let mut vertices = 0;
    let mut triangles = 0;
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for prim in terrain.primitives() {
        let pos = prim.get(&gltf::Semantic::Positions).unwrap();
        let uv = prim.get(&gltf::Semantic::TexCoords(0)).unwrap();
        let ps = floats::<3>(&doc, blob, pos.index());
        let uvs = floats::<2>(&doc, blob, uv.index());
        for (q, u) in ps.iter().zip(&uvs) {
            // Sample (i, j) at x0 + i·dx, y0 + j·dy, its height, UV (i/(W−1), 1 − j/(H−1)).
            let i = ((q[0] - tm.origin[0]) / tm.extent[0] * (w - 1) as f32).round() as u32;
            let j = ((q[1] - tm.origin[1]) / tm.extent[1] * (h - 1) as f32).round() as u32;
            assert_eq!(q[2], t.heights[(j * w + i) as usize]);
            assert!((u[0] - i as f32 / (w - 1) as f32).abs() < 1e-6);
            assert!((u[1] - (1.0 - j as f32 / (h - 1) as f32)).abs() < 1e-6);
            for k in 0..3 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        vertices += ps.len();
        triangles += prim.indices().unwrap().count() / 3;
    }
    assert_eq!(triangles, 2 * 129 * 69);
    // Chunks repeat their border samples: cells 0..64, 64..128, 128..129 across (65, 65 and 2
    // vertex columns), 0..64, 64..69 up (65 and 6 rows).
    assert_eq!(vertices, (65 + 65 + 2) * (65 + 6));
    assert_eq!([lo[0], lo[1]], tm.origin);
    assert_eq!(
        [hi[0], hi[1]],
        [tm.origin[0] + tm.extent[0], tm.origin[1] + tm.extent[1]]
    );
    // The model: one plain node, no instancing, under the root; its material from the mesh.
    let node = doc.nodes().find(|n| n.name() == Some("box.obj")).unwrap();
    assert!(node.mesh().is_some());
    assert_eq!(node.transform().decomposed().0, [0.0; 3]);
    assert_eq!(doc.materials().count(), 2);
}

/// `--terrain-step N`: the terrain at every N-th grid sample and the last row and column, each
/// exported vertex a sample of the pack's grid, and the reported height error against a brute
/// force: every grid sample's height against the exported triangle that covers it (found by
/// barycentric tests over all triangles). Step 0 is refused and writes nothing.
#[test]
fn terrain_step_exports_every_nth_sample_and_reports_its_height_error() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h) = (130u32, 70u32);
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    terrain_and_box_pack(d, w, h);
    let pack = Pack::open(&d.join("m.bake")).unwrap();
    let (tm, t) =
        bake::terrain::source_section::from_section(&pack.view_named("terrain").unwrap()).unwrap();
    let full = export_json(&p("m.bake"), &p("full.glb"), &[]);
    assert_eq!(full["terrain_step"], 1);
    assert_eq!(full["terrain_max_error_m"], 0.0);
    for step in [4u32, 7] {
        let out = p(&format!("s{step}.glb"));
        let report = export_json(&p("m.bake"), &out, &["--terrain-step", &step.to_string()]);
        assert_eq!(report["terrain_step"], step);
        let cols: BTreeSet<u32> = (0..w).filter(|i| i % step == 0 || *i == w - 1).collect();
        let rows: BTreeSet<u32> = (0..h).filter(|j| j % step == 0 || *j == h - 1).collect();
        let bytes = std::fs::read(&out).unwrap();
        let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap();
        let blob = &buffers[0].0;
        let terrain = doc.meshes().find(|m| m.name() == Some("terrain")).unwrap();
        let mut samples = BTreeSet::new();
        let mut tris: Vec<[[f32; 3]; 3]> = Vec::new();
        for prim in terrain.primitives() {
            let ps = floats::<3>(
                &doc,
                blob,
                prim.get(&gltf::Semantic::Positions).unwrap().index(),
            );
            for q in &ps {
                let i = ((q[0] - tm.origin[0]) / tm.extent[0] * (w - 1) as f32).round() as u32;
                let j = ((q[1] - tm.origin[1]) / tm.extent[1] * (h - 1) as f32).round() as u32;
                assert!(
                    cols.contains(&i) && rows.contains(&j),
                    "sample ({i}, {j}) at step {step}"
                );
                assert_eq!(q[2], t.heights[(j * w + i) as usize]);
                samples.insert((i, j));
            }
            let reader = prim.reader(|_| Some(&blob[..]));
            let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            tris.extend(
                idx.chunks(3)
                    .map(|c| [ps[c[0] as usize], ps[c[1] as usize], ps[c[2] as usize]]),
            );
        }
        assert_eq!(samples.len(), cols.len() * rows.len());
        assert_eq!(tris.len(), 2 * (cols.len() - 1) * (rows.len() - 1));
        // The oracle: every grid sample against the exported surface above it.
        let dx = tm.extent[0] as f64 / (w - 1) as f64;
        let dy = tm.extent[1] as f64 / (h - 1) as f64;
        let mut worst = 0.0f64;
        for j in 0..h {
            for i in 0..w {
                let (x, y) = (
                    tm.origin[0] as f64 + i as f64 * dx,
                    tm.origin[1] as f64 + j as f64 * dy,
                );
                let z = tris.iter().find_map(|[a, b, c]| {
                    let f = |v: &[f32; 3]| [v[0] as f64, v[1] as f64, v[2] as f64];
                    let (a, b, c) = (f(a), f(b), f(c));
                    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
                    let l1 = ((x - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (y - a[1])) / det;
                    let l2 = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det;
                    let e = 1e-9;
                    (l1 >= -e && l2 >= -e && l1 + l2 <= 1.0 + e)
                        .then(|| a[2] + l1 * (b[2] - a[2]) + l2 * (c[2] - a[2]))
                });
                let z = z.unwrap_or_else(|| panic!("sample ({i}, {j}) under no triangle"));
                worst = worst.max((t.heights[(j * w + i) as usize] as f64 - z).abs());
            }
        }
        let got = report["terrain_max_error_m"].as_f64().unwrap();
        assert!(worst > 1.0, "the sawtooth terrain is not planar: {worst}");
        assert!(
            (got - worst).abs() <= 1e-4 * worst,
            "step {step}: reported {got}, brute force {worst}"
        );
        let json = glb_json(&bytes);
        let mesh = &json["meshes"][terrain.index()];
        assert_eq!(mesh["extras"]["step"], step);
    }
    // Step 0: refused, nothing written.
    let o = common::bake(&[
        "export",
        &p("m.bake"),
        "-o",
        &p("zero.glb"),
        "--terrain-step",
        "0",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("terrain-step"));
    assert!(!d.join("zero.glb").exists());
}

/// sRGB decoding of an 8-bit code.
fn srgb_linear(c: u8) -> f32 {
    common::srgb_decode(c)
}

/// The pack's light map of the terrain: (section name, width, height, RGB irradiance).
fn terrain_lightmap(pack: &Pack) -> (String, u32, u32, Vec<[f32; 3]>) {
    for e in pack.of_kind("lightmap") {
        let v = pack.view(e).unwrap();
        let meta: bake::lightmap::section::LightmapMeta = v.meta().unwrap();
        if meta.surface == "terrain" {
            let t: Vec<[f32; 4]> = v.array_vec("irradiance").unwrap();
            let rgb = t.iter().map(|x| [x[0], x[1], x[2]]).collect();
            return (e.name.clone(), meta.width, meta.height, rgb);
        }
    }
    panic!("the preview pack has a terrain light map");
}

/// The terrain's material, mesh and the decoded image of texture `index`.
fn texture_pixels(json: &Value, images: &[gltf::image::Data], index: u64) -> (u32, u32, Vec<u8>) {
    let source = json["textures"][index as usize]["source"].as_u64().unwrap() as usize;
    let img = &images[source];
    assert_eq!(img.format, gltf::image::Format::R8G8B8A8, "RGBA PNG");
    (img.width, img.height, img.pixels.clone())
}

#[test]
fn the_terrain_light_map_rides_on_texcoord_1_and_bakes_into_an_unlit_base_colour() {
    let dir = tempfile::tempdir().unwrap();
    let (pack_path, plain, report) = exported(dir.path(), "glb");
    let pack = Pack::open(&pack_path).unwrap();
    let (section, lw, lh, irradiance) = terrain_lightmap(&pack);
    assert_eq!(report["lightmap"], section.as_str());
    assert_eq!(report["bake_light"], false);
    let peak = irradiance.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
    assert!(peak > 0.0);

    // Without --bake-light: the colour map stays the base colour; the light map is a texture on
    // TEXCOORD_1 named in the material's extras, 8-bit sRGB of E / irradiance_scale.
    let bytes = std::fs::read(&plain).unwrap();
    let (_, _, images) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let terrain_material = |json: &Value| {
        json["materials"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["name"] == "terrain")
            .cloned()
            .unwrap()
    };
    let m = terrain_material(&json);
    assert!(m.get("extensions").is_none(), "lit without --bake-light");
    let lm = &m["extras"]["lightmap"];
    assert_eq!(lm["section"], section.as_str());
    assert_eq!(lm["texture"]["texCoord"], 1);
    let scale = lm["irradiance_scale"].as_f64().unwrap() as f32;
    assert!((scale - peak).abs() <= 1e-6 * peak, "{scale} vs {peak}");
    let (w, h, px) = texture_pixels(&json, &images, lm["texture"]["index"].as_u64().unwrap());
    assert_eq!((w, h), (lw, lh));
    for (k, e) in irradiance.iter().enumerate() {
        for c in 0..3 {
            // Row 0 north in both; decoded back within half an 8-bit step (sRGB) of E.
            let got = srgb_linear(px[4 * k + c]) * scale;
            let step = (srgb_linear(px[4 * k + c].saturating_add(1))
                - srgb_linear(px[4 * k + c].saturating_sub(1)))
                * scale;
            assert!(
                (got - e[c]).abs() <= step,
                "texel {k}.{c}: {got} vs {}",
                e[c]
            );
        }
    }
    let terrain_mesh = json["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == "terrain")
        .unwrap();
    for p in terrain_mesh["primitives"].as_array().unwrap() {
        assert_eq!(p["attributes"]["TEXCOORD_1"], p["attributes"]["TEXCOORD_0"]);
    }

    // --bake-light: unlit, its base colour albedo × E / irradiance_scale, sampled at the finer
    // of the two maps' resolutions; the pack's colour map and light map are the oracle.
    let lit = dir.path().join("lit.glb");
    let r = export_json(
        pack_path.to_str().unwrap(),
        lit.to_str().unwrap(),
        &["--bake-light"],
    );
    assert_eq!(r["bake_light"], true);
    let bytes = std::fs::read(&lit).unwrap();
    let (_, _, images) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    assert!(
        json["extensionsUsed"]
            .as_array()
            .unwrap()
            .contains(&Value::from("KHR_materials_unlit"))
    );
    let m = terrain_material(&json);
    assert!(m["extensions"].get("KHR_materials_unlit").is_some());
    assert_eq!(m["extras"]["bake_light"]["irradiance_scale"], scale);
    let pbr = &m["pbrMetallicRoughness"];
    assert_eq!(
        pbr["baseColorFactor"],
        serde_json::json!([1.0, 1.0, 1.0, 1.0])
    );
    let (w, h, px) = texture_pixels(
        &json,
        &images,
        pbr["baseColorTexture"]["index"].as_u64().unwrap(),
    );
    let tmeta: bake::terrain::source_section::TerrainMeta =
        pack.view_named("terrain").unwrap().meta().unwrap();
    let cv = pack
        .view_named(tmeta.color_section.as_deref().unwrap())
        .unwrap();
    let cmeta: bake::texture::source_section::TextureMeta = cv.meta().unwrap();
    let colour: Vec<[u8; 4]> = cv.array_vec("texels").unwrap();
    assert_eq!(
        (w, h),
        (cmeta.width.max(lw), cmeta.height.max(lh)),
        "the finer resolution"
    );
    // Bilinear between texel centres, clamped to the edge (the renderer's light-map lookup).
    let sample = |t: &[[f32; 3]], tw: u32, th: u32, u: f32, v: f32| -> [f32; 3] {
        let (fx, fy) = (u * tw as f32 - 0.5, v * th as f32 - 0.5);
        let (ax, ay) = (fx - fx.floor(), fy - fy.floor());
        let get = |x: f32, y: f32| {
            let x = (x as i64).clamp(0, tw as i64 - 1);
            let y = (y as i64).clamp(0, th as i64 - 1);
            t[(y * tw as i64 + x) as usize]
        };
        let (x0, y0) = (fx.floor(), fy.floor());
        let q = [
            get(x0, y0),
            get(x0 + 1.0, y0),
            get(x0, y0 + 1.0),
            get(x0 + 1.0, y0 + 1.0),
        ];
        std::array::from_fn(|c| {
            (q[0][c] * (1.0 - ax) + q[1][c] * ax) * (1.0 - ay)
                + (q[2][c] * (1.0 - ax) + q[3][c] * ax) * ay
        })
    };
    let albedo: Vec<[f32; 3]> = colour
        .iter()
        .map(|p| [0, 1, 2].map(|c| srgb_linear(p[c])))
        .collect();
    let mut worst = 0i32;
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let a = sample(&albedo, cmeta.width, cmeta.height, u, v);
            let e = sample(&irradiance, lw, lh, u, v);
            let k = 4 * (y * w + x) as usize;
            for c in 0..3 {
                let want = common::srgb_encode((a[c] * e[c] / scale).clamp(0.0, 1.0)) * 255.0;
                worst = worst.max((px[k + c] as i32 - want.round() as i32).abs());
            }
        }
    }
    assert!(worst <= 1, "base colour off by {worst}/255");
}

/// three.js' package folder (`scripts/install-threejs.sh`), or `None` (a skip; a failure under
/// `CI`), with node and Chromium.
fn threejs() -> Option<(PathBuf, PathBuf)> {
    let dir = std::env::var_os("THREEJS")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("target/threejs/node_modules/three")
        });
    let chromium = std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if !common::tool_available("node", "runs scripts/threejs/check.js") {
        return None;
    }
    let found = common::installed(
        &dir.join("package.json"),
        "three.js (scripts/install-threejs.sh)",
    ) && common::installed(&chromium, "Chromium (apt-get install chromium)");
    found.then_some((dir, chromium))
}

/// scripts/threejs/check.js on `d/glb` against `d/<bake>.png`, `d/<bake>-regions.png` (or
/// `regions.png` for `bake`) and `d/render.json` (or `<bake>.json`), writing into `d/out`: whether
/// it passed (exit 0; an exit other than 0 or 1, a check that could not run, fails the test), its
/// metrics and its log.
fn three_check(
    three: &Path,
    chromium: &Path,
    d: &Path,
    glb: &str,
    bake: &str,
    out: &str,
    extra: &[&str],
) -> (bool, Value, String) {
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    let (regions, json) = if bake == "bake" {
        ("regions.png".to_string(), "render.json".to_string())
    } else {
        (format!("{bake}-regions.png"), format!("{bake}.json"))
    };
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/threejs/check.js");
    let o = std::process::Command::new("node")
        .arg(&script)
        .args(["--glb", &p(glb), "--bake", &p(&format!("{bake}.png"))])
        .args(["--regions", &p(&regions), "--render-json", &p(&json)])
        .args(["--out", &p(out), "--timeout", "120"])
        .args(extra)
        .arg("--three")
        .arg(three)
        .arg("--chromium")
        .arg(chromium)
        .output()
        .expect("run node");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{log}");
    assert!(
        matches!(o.status.code(), Some(0 | 1)),
        "three.js check of {glb} {extra:?} did not run: {log}"
    );
    let metrics = d.join(out).join("metrics.json");
    let m = serde_json::from_slice(&std::fs::read(metrics).unwrap()).unwrap();
    (o.status.success(), m, log)
}

#[test]
fn three_js_in_headless_chromium_draws_the_baked_terrain_as_bake_render_does() {
    let Some((three, chromium)) = threejs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pack = common::preview_fixture_pack(d);
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    export_ok(pack.to_str().unwrap(), &p("lit.glb"), &["--bake-light"]);
    // bake's own picture of the default view, its regions and its camera and exposure.
    let o = common::bake(&[
        "render",
        pack.to_str().unwrap(),
        "-o",
        &p("bake.png"),
        "--regions",
        &p("regions.png"),
        "--width",
        "480",
        "--height",
        "270",
        "--json",
    ]);
    common::json(&o);
    std::fs::write(d.join("render.json"), &o.stdout).unwrap();
    // scripts/threejs/check.js on `glb` against bake's picture: its metrics, the run asserted.
    let check = |glb: &str, out: &str, extra: &[&str]| -> Value {
        let (ok, m, log) = three_check(&three, &chromium, d, glb, "bake", out, extra);
        assert!(ok, "three.js check of {glb} {extra:?}: {log}");
        m
    };
    let m = check("lit.glb", "three", &[]);
    assert_eq!(m["failures"], serde_json::json!([]));
    // The script's own bounds, restated: the judge cannot have been loosened silently.
    assert!(m["coverage_iou"].as_f64().unwrap() >= 0.97);
    let ratio = m["terrain"]["ratio"].as_f64().unwrap();
    assert!((0.92..=1.08).contains(&ratio), "terrain ratio {ratio}");
    assert!(m["terrain_blurred_rms"].as_f64().unwrap() <= 0.05);
    assert!(d.join("three/side-by-side.png").is_file());

    // With the LOD chain and the page choosing each instance's level by bake's rule: the same
    // bounds, and the same instanced triangles and skeletons as bake's frame.
    export_ok(
        pack.to_str().unwrap(),
        &p("lod.glb"),
        &["--bake-light", "--lod"],
    );
    let m = check("lod.glb", "three-lod", &["--lod-select", "1"]);
    assert_eq!(m["failures"], serde_json::json!([]));
    let render: Value =
        serde_json::from_slice(&std::fs::read(d.join("render.json")).unwrap()).unwrap();
    let stats = &render["stats"];
    let lod = &m["lod_select"];
    assert!(lod["models"].as_u64().unwrap() >= 1, "{lod}");
    assert_eq!(lod["skeleton"], stats["skeleton_instances"]);
    if stats["impostor_instances"] == 0 {
        assert_eq!(
            lod["instance_triangles"].as_u64().unwrap(),
            stats["triangles"].as_u64().unwrap() - stats["terrain_triangles"].as_u64().unwrap(),
            "{lod} against {stats}"
        );
    }
}

/// A model with ambient light worth seeing: a 4 × 4 m floor slab and a roof slab 1.7 m above it
/// on four posts (the roof's underside and the floor under it are occluded, the roof's top open
/// to the sky), every face its own grid of vertices, one material without a top layer (MTL `Ks 0`:
/// bake's ambient term is then the diffuse eq. 4.8 alone, what COLOR_0 holds). OBJ text and MTL.
fn shelter_obj() -> (String, String) {
    let mut v: Vec<[f32; 3]> = Vec::new();
    let mut f: Vec<[usize; 3]> = Vec::new();
    let mut grid = |o: [f32; 3], u: [f32; 3], w: [f32; 3], n: usize| {
        let base = v.len();
        for j in 0..=n {
            for i in 0..=n {
                let (a, b) = (i as f32 / n as f32, j as f32 / n as f32);
                v.push(std::array::from_fn(|k| o[k] + u[k] * a + w[k] * b));
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = base + j * (n + 1) + i;
                f.push([a, a + 1, a + n + 2]);
                f.push([a, a + n + 2, a + n + 1]);
            }
        }
    };
    let mut boxed = |lo: [f32; 3], hi: [f32; 3], n: usize| {
        let [x0, y0, z0] = lo;
        let [x1, y1, z1] = hi;
        let (dx, dy, dz) = (x1 - x0, y1 - y0, z1 - z0);
        // Each face's (u × w) points out of the box.
        grid([x0, y0, z1], [dx, 0.0, 0.0], [0.0, dy, 0.0], n);
        grid([x0, y0, z0], [0.0, dy, 0.0], [dx, 0.0, 0.0], n);
        grid([x0, y0, z0], [dx, 0.0, 0.0], [0.0, 0.0, dz], n);
        grid([x0, y1, z0], [0.0, 0.0, dz], [dx, 0.0, 0.0], n);
        grid([x0, y0, z0], [0.0, 0.0, dz], [0.0, dy, 0.0], n);
        grid([x1, y0, z0], [0.0, dy, 0.0], [0.0, 0.0, dz], n);
    };
    boxed([-2.0, -2.0, 0.0], [2.0, 2.0, 0.3], 6);
    boxed([-2.0, -2.0, 2.0], [2.0, 2.0, 2.3], 6);
    for (sx, sy) in [(-1.0f32, -1.0f32), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
        let (cx, cy) = (1.8 * sx, 1.8 * sy);
        boxed([cx - 0.2, cy - 0.2, 0.3], [cx + 0.2, cy + 0.2, 2.0], 2);
    }
    let mut obj = String::from("mtllib shelter.mtl\nusemtl Stone\n");
    for p in &v {
        obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for t in &f {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let mtl = "newmtl Stone\nKd 0.7 0.6 0.5\nKs 0 0 0\nKa 0 0 0\n".to_string();
    (obj, mtl)
}

/// `--vertex-ambient`'s COLOR_0 as three.js draws it: the ambient term alone. bake draws it with
/// `bake render --terms ambient`; three.js draws the models unlit as base colour × COLOR_0 ×
/// `vertex_ambient_scale` (scripts/threejs/check.js `--terms ambient`), what docs/MATERIALS.md
/// says is bake's ambient radiance, and the two pictures' model pixels are compared. The scene
/// is the one where that holds exactly (one instance, so the mean of the instances' light is its
/// light; a material without a top layer, whose gloss COLOR_0 leaves out; no model light map,
/// which the renderer would prefer to the PRT): what is left is rasterization and filtering. The
/// same export without COLOR_0 (three.js' hemisphere light, bake's own fallback without PRT)
/// fails the bounds.
#[test]
fn three_js_draws_vertex_ambient_color_0_as_bake_renders_the_ambient_term() {
    let Some((three, chromium)) = threejs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let p = |f: &str| d.join(f).to_str().unwrap().to_string();
    bake::fixtures::write_all(d).unwrap();
    let (obj, mtl) = shelter_obj();
    std::fs::write(d.join("shelter.obj"), obj).unwrap();
    std::fs::write(d.join("shelter.mtl"), mtl).unwrap();
    // The fixture's terrain, area and sky; one shelter instead of its models.
    let eco = std::fs::read_to_string(d.join("scene.eco")).unwrap();
    let mut text: String = eco
        .lines()
        .take_while(|l| !l.starts_with("<LAYER>"))
        .map(|l| format!("{l}\n"))
        .collect();
    text += "<LAYER> 1\nshelter.obj 0.2806 0.7085 1.0 275.0\n";
    std::fs::write(d.join("scene.eco"), text).unwrap();
    let o = common::bake(&[
        &p("scene.eco"),
        "--sky",
        &p("sky.hdr"),
        "--pipeline",
        "preview",
        "--no-cache",
        "--set",
        "stages.atlas=false",
        "-o",
        &p("shelter.bake"),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let pack = p("shelter.bake");
    let report = export_json(
        &pack,
        &p("ambient.glb"),
        &["--vertex-ambient", "--bake-light"],
    );
    assert_eq!(report["vertex_ambient_models"], 1);
    export_ok(&pack, &p("plain.glb"), &["--bake-light"]);
    // A view from 9 m of the shelter, under its roof.
    let (_, list) = instances_of(&Pack::open(Path::new(&pack)).unwrap());
    assert_eq!(list.len(), 1);
    let at = Vec3::from(list[0].position);
    let eye = at + Vec3::new(2.8, -8.3, 1.8);
    let target = at + Vec3::new(0.0, 0.0, 0.8);
    let v3 = |v: Vec3| format!("{},{},{}", v.x, v.y, v.z);
    let o = common::bake(&[
        "render",
        &pack,
        "-o",
        &p("amb.png"),
        "--regions",
        &p("amb-regions.png"),
        "--width",
        "480",
        "--height",
        "270",
        "--terms",
        "ambient",
        "--no-lod",
        &format!("--eye={}", v3(eye)),
        &format!("--target={}", v3(target)),
        "--json",
    ]);
    let render = common::json(&o);
    std::fs::write(d.join("amb.json"), &o.stdout).unwrap();
    let ambient = &render["stats"]["ambient"];
    assert_eq!(ambient["prt_models"], 1, "{ambient}");
    assert_eq!(ambient["lightmap_models"], 0, "{ambient}");

    let terms = ["--terms", "ambient"];
    let (ok, m, log) = three_check(&three, &chromium, d, "ambient.glb", "amb", "three", &terms);
    assert!(ok, "{log}");
    assert_eq!(m["failures"], serde_json::json!([]));
    assert_eq!(m["found"]["vertex_ambient"], 1);
    // The script's bounds, restated: the judge cannot have been loosened silently.
    let pixels = m["models"]["pixels"].as_u64().unwrap();
    assert!(pixels > 10_000, "{pixels} model pixels");
    let ratio = m["models"]["ratio"].as_f64().unwrap();
    assert!((0.97..=1.03).contains(&ratio), "models ratio {ratio}");
    let rms = m["models_blurred_rms"].as_f64().unwrap();
    assert!(rms <= 0.025, "models blurred RMS {rms}");
    let tiles = m["model_tiles"].as_array().unwrap();
    let judged: Vec<f64> = tiles
        .iter()
        .filter(|t| t["pixels"].as_f64().unwrap() >= 0.05 * t["area"].as_f64().unwrap())
        .map(|t| t["ratio"].as_f64().unwrap())
        .collect();
    assert!(judged.len() >= 2, "{judged:?}");
    assert!(
        judged.iter().all(|r| (0.95..=1.05).contains(r)),
        "{judged:?}"
    );

    // Without COLOR_0 the models take three.js' hemisphere light: outside the bounds, and not
    // only for the missing attribute.
    let (ok, m, log) = three_check(
        &three,
        &chromium,
        d,
        "plain.glb",
        "amb",
        "three-plain",
        &terms,
    );
    assert!(!ok, "{log}");
    let fails: Vec<&str> = m["failures"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(
        fails
            .iter()
            .any(|f| f.contains("blurred RMS") || f.contains("tile")),
        "{fails:?}"
    );
}

#[test]
fn blender_imports_the_export_with_the_packs_meshes_materials_and_instances() {
    // Blender's Python module in target/bpy-venv (scripts/install-bpy.sh) or BPY_PYTHON.
    let python = std::env::var_os("BPY_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("target/bpy-venv/bin/python")
        });
    if !common::installed(&python, "Blender's bpy (scripts/install-bpy.sh)") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (pack, plain, _) = exported(dir.path(), "glb");
    let lit = dir.path().join("lit.glb");
    export_ok(
        pack.to_str().unwrap(),
        lit.to_str().unwrap(),
        &["--bake-light"],
    );
    let o = common::bake(&["dump", pack.to_str().unwrap(), "--json", "--full"]);
    common::json(&o);
    let dump = dir.path().join("dump.json");
    std::fs::write(&dump, &o.stdout).unwrap();
    // Every option at once: the LOD chain (MSFT_lod, which Blender does not read: its levels
    // come in as orphan nodes), the PRT ambient as COLOR_0 and the normal maps.
    let all = dir.path().join("all.glb");
    let every = ["--bake-light", "--lod", "--vertex-ambient", "--normal-maps"];
    export_ok(pack.to_str().unwrap(), all.to_str().unwrap(), &every);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/blender/import_check.py");
    let p = Pack::open(&pack).unwrap();
    for (glb, flags) in [
        (&plain, &[][..]),
        (&lit, &["--bake-light"][..]),
        (&all, &every[..]),
    ] {
        let o = std::process::Command::new(&python)
            .arg(&script)
            .arg(glb)
            .arg(&dump)
            .args(flags)
            .output()
            .expect("run Blender's Python");
        let stdout = String::from_utf8_lossy(&o.stdout);
        let summary: Value = stdout
            .lines()
            .rev()
            .find_map(|l| serde_json::from_str(l).ok())
            .unwrap_or_else(|| {
                panic!(
                    "no JSON summary: {stdout}{}",
                    String::from_utf8_lossy(&o.stderr)
                )
            });
        eprintln!("Blender on {}: {summary}", glb.display());
        assert!(o.status.success(), "{summary}");
        assert_eq!(summary["failures"], serde_json::json!([]));
        // The counts Blender saw, against the pack itself (not only the script's reading of the dump).
        let (meta, list) = instances_of(&p);
        let got = &summary["got"];
        assert_eq!(got["instances"], list.len());
        assert_eq!(got["suns"], 1);
        if flags.is_empty() || flags == ["--bake-light"] {
            assert_eq!(got["meshes"], meta.models.len() + 1);
            assert_eq!(got["materials"], p.of_kind("material").count() + 1);
            assert_eq!(got["level_meshes"], 0);
            assert_eq!(got["color_attributes"], 0);
            assert_eq!(got["normal_maps"], 0);
            continue;
        }
        // --lod: per model, its levels past the full mesh and its skeleton, each a mesh whose
        // objects are as many as the model's instances; one material per skeleton.
        let (mut levels, mut level_instances, mut skeletons, mut colored) = (0, 0, 0, 0);
        for (k, section) in meta.mesh_sections.iter().enumerate() {
            let model = section.trim_start_matches("mesh:");
            let placed = list.iter().filter(|r| r.model as usize == k).count();
            let lod = bake::lod::section::read(&p, section).unwrap().unwrap().meta;
            let n = lod.levels.len() - 1 + usize::from(lod.skeleton.is_some());
            levels += n;
            level_instances += n * placed;
            skeletons += usize::from(lod.skeleton.is_some());
            // COLOR_0 on the model's mesh and its mesh levels (the preview fixture has PRT).
            assert!(p.view_named(&format!("prt:{model}")).is_ok());
            colored += lod.levels.len();
        }
        assert!(
            levels >= 1 && skeletons >= 1,
            "the preview fixture has levels"
        );
        assert_eq!(got["level_meshes"], levels);
        assert_eq!(got["level_instances"], level_instances);
        assert_eq!(got["meshes"], meta.models.len() + 1 + levels);
        assert_eq!(
            got["materials"],
            p.of_kind("material").count() + 1 + skeletons
        );
        assert_eq!(got["color_attributes"], colored);
        // --normal-maps: the materials whose section names a normal map.
        let normal = p
            .of_kind("material")
            .filter(|e| {
                let m = bake::material::section::from_section(&p.view(e).unwrap()).unwrap();
                m.normal_map.is_some()
            })
            .count();
        assert!(normal >= 1, "the preview fixture derives normal maps");
        assert_eq!(got["normal_maps"], normal);
    }
}

/// COLOR_0 (`--vertex-ambient`) against the renderer's own evaluation: per model, per instance,
/// `render::ambient::side_radiance` (both transfer sets under the instance's light, as
/// `load_ambient` resolves it for `bake render`), times the material's `1/albedo_folded`, mixed
/// per eq. 4.8 with the translucence for the front side (written out here), averaged over the
/// model's instances; COLOR_0 × the file's scale must match it on every drawn vertex copy of
/// every primitive's triangles.
#[test]
fn vertex_ambient_color_0_is_the_renderers_prt_ambient() {
    use bake::render::ambient::{PrtLayout, load_ambient, side_radiance};
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let out = dir.path().join("ambient.glb");
    let report = export_json(
        pack_path.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--vertex-ambient"],
    );
    let pack = Pack::open(&pack_path).unwrap();
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    let amb = load_ambient(&pack, &scene, PrtLayout::Full, None).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let blob = &buffers[0].0;
    let scale = report["vertex_ambient_scale"].as_f64().unwrap() as f32;
    assert_eq!(
        json["nodes"].as_array().unwrap().last().unwrap()["extras"]["vertex_ambient_scale"]
            .as_f64()
            .unwrap() as f32,
        scale
    );
    let with_prt = amb.models.iter().filter(|m| m.prt.is_some()).count();
    assert!(with_prt >= 1, "the preview fixture has PRT");
    assert_eq!(report["vertex_ambient_models"], with_prt);
    let mut peak = 0.0f32;
    let mut checked = 0usize;
    let mut distinct = BTreeSet::new();
    for (m, a) in scene.models.iter().zip(&amb.models) {
        let mesh = doc
            .meshes()
            .find(|x| x.name() == Some(m.name.as_str()))
            .unwrap_or_else(|| panic!("no mesh {}", m.name));
        let Some(prt) = &a.prt else {
            assert!(
                mesh.primitives()
                    .all(|p| p.get(&gltf::Semantic::Colors(0)).is_none())
            );
            continue;
        };
        let mj = &json["meshes"][mesh.index()];
        assert_eq!(
            mj["extras"]["vertex_ambient"]["section"],
            format!("prt:{}", m.section.trim_start_matches("mesh:"))
        );
        assert_eq!(mj["extras"]["vertex_ambient"]["instances"], a.envs.len());
        // The drawn rows of every mesh vertex (split vertices copy their mesh vertex's transfer).
        let rows: Vec<(usize, usize)> = match &m.vertex_source {
            None => (0..prt.vertices).map(|j| (j, j)).collect(),
            Some(src) => src
                .iter()
                .enumerate()
                .map(|(j, &s)| (s as usize, j))
                .collect(),
        };
        for p in mesh.primitives() {
            let material = p.material().index().unwrap();
            let index = json["materials"][material]["extras"]["index"]
                .as_u64()
                .unwrap() as usize;
            let color = p.get(&gltf::Semantic::Colors(0)).expect("COLOR_0");
            let colors = floats::<3>(&doc, blob, color.index());
            let reader = p.reader(|_| Some(&blob[..]));
            let used: BTreeSet<usize> = reader
                .read_indices()
                .unwrap()
                .into_u32()
                .map(|i| i as usize)
                .collect();
            let k = prt.albedo_scale(index);
            let t = prt.translucence(index);
            for &(v, row) in rows.iter().filter(|(v, _)| used.contains(v)) {
                // The mean over the instances of eq. 4.8 before the renderer's clamp at 0 (the
                // export evaluates it once under the instances' mean light: the same by
                // linearity), then the clamp.
                let mut want = [0.0f64; 3];
                for env in &a.envs {
                    let [f, b] = side_radiance(prt, PrtLayout::Full, row, env);
                    for c in 0..3 {
                        let l = (1.0 - t) * f[c] * k[c] + t * b[c] * k[c];
                        want[c] += l as f64 / a.envs.len() as f64;
                    }
                }
                let want = want.map(|x| x.max(0.0));
                let got = colors[v];
                for c in 0..3 {
                    assert!((0.0..=1.0).contains(&got[c]), "{got:?}");
                    let g = got[c] * scale;
                    assert!(
                        (g as f64 - want[c]).abs() <= 1e-4 * want[c].abs() + 1e-6 * scale as f64,
                        "{} vertex {v} (row {row}) material {index}: {g} against {}",
                        m.name,
                        want[c]
                    );
                    peak = peak.max(want[c] as f32);
                }
                distinct.insert(got.map(f32::to_bits));
                checked += 1;
            }
        }
    }
    assert!(checked > 100, "{checked} vertices checked");
    assert!(distinct.len() > 50, "COLOR_0 varies over the vertices");
    assert!(
        (peak - scale).abs() <= 1e-4 * scale,
        "scale {scale} is the largest value {peak}"
    );
}

#[test]
fn vertex_ambient_on_a_pack_without_prt_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    bake::fixtures::write_all(dir.path()).unwrap();
    let pack = dir.path().join("ingested.bake");
    let o = common::bake(&[
        "ingest",
        dir.path().join("scene.eco").to_str().unwrap(),
        "-o",
        pack.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.path().join("out/scene.glb");
    let o = common::bake(&[
        "export",
        pack.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--vertex-ambient",
    ]);
    assert_eq!(o.status.code(), Some(4));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("ingested.bake")
            && err.contains("no prt section")
            && err.contains("--vertex-ambient"),
        "{err}"
    );
    assert!(
        !out.exists() && !dir.path().join("out").exists(),
        "no output, no folder"
    );
    // The same pack exports without the option.
    export_ok(pack.to_str().unwrap(), out.to_str().unwrap(), &[]);
    assert!(out.exists());
}

/// `--lod`: every model's `lod` levels 1.. (and its skeleton) as meshes on nodes that the model
/// node names through `MSFT_lod`, against the pack's `lod` sections: vertex positions, triangle
/// counts per level, the instances shared, COLOR_0 gathered from the mesh vertex each level
/// vertex copies, and the selection rule's numbers in the extras.
#[test]
fn lod_levels_are_meshes_on_msft_lod_nodes_as_the_pack_has_them() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let out = dir.path().join("lod.glb");
    let report = export_json(
        pack_path.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--lod", "--vertex-ambient"],
    );
    let pack = Pack::open(&pack_path).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let (doc, buffers, _) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let blob = &buffers[0].0;
    assert!(
        json["extensionsUsed"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e == "MSFT_lod")
    );
    let nodes = json["nodes"].as_array().unwrap();
    let mesh_of = |n: &Value| {
        doc.meshes()
            .nth(n["mesh"].as_u64().unwrap() as usize)
            .unwrap()
    };
    let colors = |m: &gltf::Mesh| -> Vec<[f32; 3]> {
        let p = m.primitives().next().unwrap();
        floats::<3>(
            &doc,
            blob,
            p.get(&gltf::Semantic::Colors(0)).unwrap().index(),
        )
    };
    let (meta, _) = instances_of(&pack);
    let mut lod_meshes = 0;
    let mut with_levels = 0;
    for section in &meta.mesh_sections {
        let Some(view) = bake::lod::section::read(&pack, section).unwrap() else {
            continue;
        };
        let named = |n: &&Value| {
            n["extras"]["section"] == section.as_str() && n["extras"].get("lod").is_some()
        };
        if view.meta.levels.len() < 2 && view.meta.skeleton.is_none() {
            // Full detail only: nothing to name.
            assert!(!nodes.iter().any(|n| named(&n)), "{section}");
            continue;
        }
        let node = nodes
            .iter()
            .find(|n| {
                n["extras"]["section"] == section.as_str() && n["extras"].get("lod").is_some()
            })
            .unwrap_or_else(|| panic!("no MSFT_lod node for {section}"));
        let ids: Vec<usize> = node["extensions"]["MSFT_lod"]["ids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i.as_u64().unwrap() as usize)
            .collect();
        let levels = view.meta.levels.len();
        let skeleton = view.meta.skeleton.is_some() as usize;
        assert_eq!(ids.len(), levels - 1 + skeleton, "{section}");
        lod_meshes += ids.len();
        with_levels += (levels > 1) as usize;
        // MSFT_screencoverage: one per node (the model's and each lower one) and a final 0,
        // non-increasing.
        let cover: Vec<f64> = node["extras"]["MSFT_screencoverage"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_f64().unwrap())
            .collect();
        assert_eq!(cover.len(), ids.len() + 1);
        assert!(
            cover.windows(2).all(|w| w[0] >= w[1]) && cover[ids.len()] == 0.0,
            "{cover:?}"
        );
        let lod = &node["extras"]["lod"];
        let errors: Vec<f32> = lod["errors"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e.as_f64().unwrap() as f32)
            .collect();
        assert_eq!(
            errors,
            view.meta.levels.iter().map(|l| l.error).collect::<Vec<_>>()
        );
        assert_eq!(lod["radius"].as_f64().unwrap() as f32, view.meta.radius);
        let base_colors = colors(&mesh_of(node));
        for (l, &id) in ids.iter().enumerate().take(levels - 1) {
            let l = l + 1;
            let n = &nodes[id];
            // The same instances as the model node.
            assert_eq!(
                n["extensions"]["EXT_mesh_gpu_instancing"],
                node["extensions"]["EXT_mesh_gpu_instancing"]
            );
            let m = mesh_of(n);
            let p0 = m.primitives().next().unwrap();
            let pos = floats::<3>(
                &doc,
                blob,
                p0.get(&gltf::Semantic::Positions).unwrap().index(),
            );
            assert_eq!(pos, view.level_positions(l), "{section} level {l}");
            let triangles: usize = m
                .primitives()
                .map(|p| p.indices().unwrap().count() / 3)
                .sum();
            assert_eq!(triangles, view.meta.levels[l].triangle_count as usize);
            // COLOR_0 of a level vertex is that of the mesh vertex it copies.
            let first = view.meta.levels[l].first_vertex as usize;
            let source = &view.vertex_source[first..first + pos.len()];
            for (c, &s) in colors(&m).iter().zip(source) {
                assert_eq!(*c, base_colors[s as usize]);
            }
        }
        if skeleton == 1 {
            let m = mesh_of(&nodes[*ids.last().unwrap()]);
            let modes: Vec<_> = m.primitives().map(|p| p.mode()).collect();
            assert!(modes.contains(&gltf::mesh::Mode::Lines), "{modes:?}");
            let p = m
                .primitives()
                .find(|p| p.mode() == gltf::mesh::Mode::Lines)
                .unwrap();
            let lines = floats::<3>(
                &doc,
                blob,
                p.get(&gltf::Semantic::Positions).unwrap().index(),
            );
            assert_eq!(lines, view.skeleton_lines);
        }
    }
    assert!(
        with_levels >= 1,
        "the preview fixture has a model with levels"
    );
    assert_eq!(report["lod_meshes"], lod_meshes);
    // Without --lod nothing of it.
    let plain = dir.path().join("plain.glb");
    export_ok(pack_path.to_str().unwrap(), plain.to_str().unwrap(), &[]);
    let pj = glb_json(&std::fs::read(&plain).unwrap());
    assert!(!pj.to_string().contains("MSFT_lod"));
    assert_eq!(
        pj["meshes"].as_array().unwrap().len() + lod_meshes,
        json["meshes"].as_array().unwrap().len()
    );
}

/// `--normal-maps`: each normal-mapped material's `normalTexture` is the pack's `normal` array
/// (level 0) in glTF's frame (green mirrored), its primitives carry the pack's tangents with w
/// negated, and the resulting glTF bitangent `w·(n × t)` points up the image (towards
/// decreasing v, glTF's "+Y up" with the UV origin at the top left), checked against each
/// triangle's own ∂p/∂v.
#[test]
fn normal_maps_ride_in_gltfs_tangent_frame() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = common::preview_fixture_pack(dir.path());
    let out = dir.path().join("normals.glb");
    export_ok(
        pack_path.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--normal-maps"],
    );
    let pack = Pack::open(&pack_path).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    let (doc, buffers, images) = gltf::import_slice(&bytes).unwrap();
    let json = glb_json(&bytes);
    let blob = &buffers[0].0;
    let mut mapped = 0;
    let (mut up, mut down) = (0usize, 0usize);
    for mesh in doc.meshes() {
        let section = json["meshes"][mesh.index()]["extras"]["section"]
            .as_str()
            .unwrap()
            .to_string();
        for p in mesh.primitives() {
            let mj = &json["materials"][p.material().index().unwrap()];
            let Some(nt) = mj.get("normalTexture") else {
                assert!(p.get(&gltf::Semantic::Tangents).is_none());
                continue;
            };
            mapped += 1;
            // The texture against the pack's normal array, level 0.
            let name = mj["extras"]["normal_map"].as_str().unwrap();
            let v = pack.view_named(name).unwrap();
            let meta: bake::texture::source_section::TextureMeta = v.meta().unwrap();
            let table = bake::texture::section::levels(&v, &meta, "normal").unwrap();
            let normal: Vec<[u8; 4]> = v.array_vec("normal").unwrap();
            let l0 = table[0];
            let texture = &json["textures"][nt["index"].as_u64().unwrap() as usize];
            let img = &images[texture["source"].as_u64().unwrap() as usize];
            assert_eq!((img.width, img.height), (l0[0], l0[1]));
            assert_eq!(img.format, gltf::image::Format::R8G8B8A8);
            for (k, px) in img.pixels.chunks(4).enumerate() {
                let n = normal[l0[2] as usize + k];
                assert_eq!(
                    [px[0], px[1], px[2]],
                    [n[0], 255 - n[1], n[2]],
                    "{name} texel {k}"
                );
            }
            // TANGENT: the pack's, w negated.
            let tv = pack
                .of_kind("tangents")
                .map(|e| pack.view(e).unwrap())
                .find(|v| {
                    bake::mesh::tangents::from_section(v)
                        .unwrap()
                        .0
                        .mesh_section
                        == section
                })
                .expect("the model's tangents");
            let (_, tangents) = bake::mesh::tangents::from_section(&tv).unwrap();
            let t = floats::<4>(
                &doc,
                blob,
                p.get(&gltf::Semantic::Tangents).unwrap().index(),
            );
            assert_eq!(t.len(), tangents.len());
            for (a, b) in t.iter().zip(&tangents) {
                assert_eq!(*a, [b[0], b[1], b[2], -b[3]]);
            }
            // glTF's bitangent against each triangle's ∂p/∂v.
            let pos = floats::<3>(
                &doc,
                blob,
                p.get(&gltf::Semantic::Positions).unwrap().index(),
            );
            let nrm = floats::<3>(&doc, blob, p.get(&gltf::Semantic::Normals).unwrap().index());
            let uv = floats::<2>(
                &doc,
                blob,
                p.get(&gltf::Semantic::TexCoords(0)).unwrap().index(),
            );
            let reader = p.reader(|_| Some(&blob[..]));
            let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
            for tri in idx.chunks(3) {
                let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| i as usize);
                let (e1, e2) = (
                    Vec3::from(pos[b]) - Vec3::from(pos[a]),
                    Vec3::from(pos[c]) - Vec3::from(pos[a]),
                );
                let (du1, dv1) = (uv[b][0] - uv[a][0], uv[b][1] - uv[a][1]);
                let (du2, dv2) = (uv[c][0] - uv[a][0], uv[c][1] - uv[a][1]);
                let det = du1 * dv2 - du2 * dv1;
                if det.abs() < 1e-8 {
                    continue;
                }
                let dpdv = (e2 * du1 - e1 * du2) / det;
                for i in [a, b, c] {
                    let tt = t[i];
                    let bt = Vec3::from(nrm[i]).cross(Vec3::new(tt[0], tt[1], tt[2])) * tt[3];
                    let d = bt.dot(dpdv);
                    if d < 0.0 {
                        up += 1;
                    } else if d > 0.0 {
                        down += 1;
                    }
                }
            }
        }
    }
    assert!(
        mapped >= 1,
        "the preview fixture has normal-mapped materials"
    );
    assert!(
        up as f64 >= 0.95 * (up + down) as f64,
        "glTF bitangents up the image at {up} corners, down at {down}"
    );
    eprintln!("bitangent up the image at {up} of {} corners", up + down);
}
