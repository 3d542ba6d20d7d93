//! The procedural TXF plant fixture read back by the TXF reader, and through the whole
//! `ingest` pipeline into a pack.

use bake::fixtures::plant::{self, LEAF_ROWS, LEAF_TEXTURE, LEAVES, STEM_RINGS, STEM_SEGMENTS};
use bake::ingest::{sgi, texture, txf};
use bake::model::Material;

const STEM_VERTICES: usize = STEM_SEGMENTS * STEM_RINGS;
const STEM_TRIANGLES: usize = 2 * STEM_SEGMENTS * (STEM_RINGS - 1);
const LEAF_VERTICES: usize = 2 * (LEAF_ROWS + 1);
const LEAF_TRIANGLES: usize = 2 * LEAF_ROWS;

fn file(name: &str) -> Vec<u8> {
    plant::plant_files()
        .into_iter()
        .find(|(n, _)| n == name)
        .unwrap()
        .1
}

#[test]
fn fixture_is_deterministic_and_small() {
    let a = plant::plant_files();
    assert_eq!(a, plant::plant_files());
    let names: Vec<&str> = a.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["plant.txf", "leaf.rgb"]);
    let tris = STEM_TRIANGLES + LEAVES * LEAF_TRIANGLES;
    assert!((200..=500).contains(&tris), "{tris} triangles");
    // Both payload placements occur: "<data>\n" and "<data>" followed by a binary byte.
    let txf = file("plant.txf");
    let after: Vec<u8> = txf
        .windows(7)
        .filter(|w| &w[..6] == b"<data>")
        .map(|w| w[6])
        .collect();
    assert!(after.contains(&b'\n'));
    assert!(after.iter().any(|&b| b != b'\n'));
}

#[test]
fn fixture_plant_parses_back() {
    let model = plant::plant_model();
    let mesh = txf::parse(&file("plant.txf")).unwrap();
    assert_eq!(mesh.validate(), Ok(()));
    // The stem gains one duplicate per ring (its u = 0 vertex, reused by the closing segment).
    let dups = STEM_RINGS;
    assert_eq!(
        mesh.positions.len(),
        STEM_VERTICES + dups + LEAVES * LEAF_VERTICES
    );
    assert_eq!(mesh.indices.len(), STEM_TRIANGLES + LEAVES * LEAF_TRIANGLES);
    assert_eq!(mesh.objects, ["set 0", "set 1", "set 2"]);
    assert!(mesh.warnings.is_empty(), "{:?}", mesh.warnings);

    // Vertices in file order: stem, its duplicates, then the two leaf sets.
    let leaf_start = STEM_VERTICES + dups;
    let written: Vec<_> = model.sets[0]
        .vertices
        .iter()
        .chain(model.sets[1].vertices.iter())
        .chain(model.sets[2].vertices.iter())
        .collect();
    let read: Vec<usize> = (0..STEM_VERTICES)
        .chain(leaf_start..mesh.positions.len())
        .collect();
    assert_eq!(written.len(), read.len());
    for (w, &i) in written.iter().zip(&read) {
        assert_eq!(mesh.positions[i], w.position);
        assert_eq!(mesh.uvs[i], [w.texcoord[0], 1.0 - w.texcoord[1]]);
        let n = mesh.normals[i];
        assert!((0..3).all(|k| (n[k] - w.normal[k]).abs() < 1e-6));
    }
    for d in 0..dups {
        let orig = d * STEM_SEGMENTS;
        assert_eq!(mesh.positions[STEM_VERTICES + d], mesh.positions[orig]);
        assert_eq!(mesh.uvs[STEM_VERTICES + d][0], 1.0);
        assert_eq!(mesh.uvs[orig][0], 0.0, "the shared vertex is unchanged");
    }
    // Every stem triangle spans one segment in u after the fix.
    for t in &mesh.indices[..STEM_TRIANGLES] {
        let us = t.map(|i| mesh.uvs[i as usize][0]);
        let span = us.iter().cloned().fold(f32::MIN, f32::max)
            - us.iter().cloned().fold(f32::MAX, f32::min);
        assert!((span - 1.0 / STEM_SEGMENTS as f32).abs() < 1e-6, "{us:?}");
    }

    // Two materials: the OpenGL default (stem, untextured) and the leaf (textured).
    assert_eq!(mesh.materials.len(), 2);
    let (stem, leaf) = (&mesh.materials[0], &mesh.materials[1]);
    assert_eq!(
        (
            stem.diffuse,
            stem.ambient,
            stem.specular,
            stem.emission,
            stem.shininess
        ),
        {
            let d = Material::default();
            (d.diffuse, d.ambient, d.specular, d.emission, d.shininess)
        }
    );
    assert_eq!(stem.color_map, None);
    assert_eq!(leaf.diffuse, [0.35, 0.6, 0.25, 1.0]);
    assert_eq!(leaf.shininess, 24.0);
    assert_eq!(leaf.translucence, Some(0.3));
    assert_eq!(leaf.color_map, Some(0));
    assert_eq!(mesh.textures.len(), 1);
    assert_eq!(mesh.textures[0].name, "leaf.rgb");
    let stem_tris = &mesh.triangle_materials[..STEM_TRIANGLES];
    assert!(stem_tris.iter().all(|&m| m == 0));
    assert!(
        mesh.triangle_materials[STEM_TRIANGLES..]
            .iter()
            .all(|&m| m == 1)
    );

    // Z up, on the ground, about 1.5 m tall.
    let (lo, hi) = mesh.bounds().unwrap();
    assert_eq!(lo[2], 0.0);
    assert!((1.4..=2.0).contains(&hi[2]), "{hi:?}");
}

#[test]
fn leaf_texture_has_a_leaf_shaped_alpha_mask() {
    let bytes = file("leaf.rgb");
    assert!(sgi::is_sgi(&bytes));
    assert_eq!(bytes[2], 1, "RLE");
    let img = texture::decode(&bytes).unwrap();
    assert_eq!(img, plant::leaf_image());
    let n = LEAF_TEXTURE as usize;
    assert_eq!((img.width as usize, img.height as usize), (n, n));
    let alpha = |x: usize, y: usize| img.pixels[y * n + x][3];
    assert_eq!(alpha(n / 2, n / 2), 255);
    assert_eq!(alpha(0, 0), 0);
    assert_eq!(alpha(n - 1, n - 1), 0);
    let covered = img.pixels.iter().filter(|p| p[3] >= 128).count() as f32 / (n * n) as f32;
    assert!((0.3..0.7).contains(&covered), "{covered}");
    // Alpha is binary, so an alpha test at 0.5 keeps exactly the outline.
    assert!(img.pixels.iter().all(|p| p[3] == 0 || p[3] == 255));
}

#[test]
fn truncations_of_the_fixture_fail_cleanly() {
    let bytes = file("plant.txf");
    let full = txf::parse(&bytes).unwrap().indices.len();
    for n in (0..bytes.len()).step_by(7) {
        // A cut between blocks is a smaller valid file; anything else is an error.
        if let Ok(m) = txf::parse(&bytes[..n]) {
            assert!(m.indices.len() < full, "cut at {n}");
        }
    }
    for at in (0..bytes.len()).step_by(3) {
        let mut g = bytes.clone();
        g[at] ^= 0xa5;
        if let Ok(m) = txf::parse(&g) {
            assert_eq!(m.validate(), Ok(()), "flip at {at}");
        }
    }
    let leaf = file("leaf.rgb");
    for n in (0..leaf.len()).step_by(7) {
        assert!(sgi::decode(&leaf[..n]).is_err(), "leaf.rgb cut at {n}");
    }
}

#[test]
fn plant_ingests_into_a_pack_with_mesh_and_texture() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in plant::plant_files() {
        std::fs::write(dir.path().join(name), bytes).unwrap();
    }
    let input = dir.path().join("plant.txf");
    // load() resolves texture names against the TXF file's folder.
    let mesh = txf::load(&input).unwrap();
    assert_eq!(mesh.textures[0].path, dir.path().join("leaf.rgb"));
    let broken = dir.path().join("broken.txf");
    std::fs::write(
        &broken,
        b"<?txf_version='0.91'?>\n<Set>\n<set_number> x </set_number>",
    )
    .unwrap();
    let e = txf::load(&broken).unwrap_err();
    assert_eq!(e.exit_code(), bake::error::exit::INVALID_INPUT);
    let msg = e.to_string();
    assert!(
        msg.contains("broken.txf") && msg.contains("line 3"),
        "{msg}"
    );
    let (w, warnings) = bake::pipeline::ingest_to_pack(&input, &Default::default()).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    let out = dir.path().join("p.bake");
    w.write(&out).unwrap();
    let pack = bake::pack::Pack::open(&out).unwrap();
    let doc = bake::dump::dump_json(&pack, &Default::default()).unwrap();
    let sections = doc["sections"].as_array().unwrap();
    let of_kind = |k: &str| {
        sections
            .iter()
            .filter(|s| s["kind"] == k)
            .collect::<Vec<_>>()
    };
    let meshes = of_kind("mesh");
    assert_eq!(meshes.len(), 1);
    let s = &meshes[0]["summary"];
    assert_eq!(s["triangles"], STEM_TRIANGLES + LEAVES * LEAF_TRIANGLES);
    assert_eq!(
        s["vertices"],
        STEM_VERTICES + STEM_RINGS + LEAVES * LEAF_VERTICES
    );
    assert_eq!(s["materials"], 2);
    let textures = of_kind("texture");
    assert_eq!(textures.len(), 1);
    assert_eq!(textures[0]["summary"]["width"], LEAF_TEXTURE);
    assert!(sections.iter().all(|s| s["checksum_ok"] == true));
    // A missing texture is a warning, not a failure.
    std::fs::remove_file(dir.path().join("leaf.rgb")).unwrap();
    let (_, warnings) = bake::pipeline::ingest_to_pack(&input, &Default::default()).unwrap();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
}
