use super::*;
use crate::fixtures::object3ds::{
    Object3ds, bench_3ds, box_object, chunk, cstr, file_3ds, material_chunk, node_chunk,
};

fn bounds(m: &Mesh) -> ([f32; 3], [f32; 3]) {
    m.bounds().unwrap()
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5)
}

/// One triangle, one material, written byte by byte (not through the fixture writer).
fn hand_written() -> Vec<u8> {
    let mut f = Vec::new();
    let le16 = |v: u16| v.to_le_bytes();
    let le32 = |v: u32| v.to_le_bytes();
    // material: name "Red" (0xA000, 10 bytes), diffuse 0xA020 > 0x0011 (255, 0, 0),
    // shininess 0xA040 > 0x0030 50 %
    let mut mat = Vec::new();
    mat.extend(le16(0xA000));
    mat.extend(le32(10));
    mat.extend(b"Red\0");
    mat.extend(le16(0xA020));
    mat.extend(le32(15));
    mat.extend(le16(0x0011));
    mat.extend(le32(9));
    mat.extend([255, 0, 0]);
    mat.extend(le16(0xA040));
    mat.extend(le32(14));
    mat.extend(le16(0x0030));
    mat.extend(le32(8));
    mat.extend(le16(50));
    // vertices: 3 × 12 bytes + count = 38 + 6
    let mut verts = Vec::new();
    verts.extend(le16(0x4110));
    verts.extend(le32(44));
    verts.extend(le16(3));
    for v in [1.0f32, 2.0, 3.0, 4.0, 2.0, 3.0, 1.0, 5.0, 3.0] {
        verts.extend(v.to_le_bytes());
    }
    // faces: count + 1 face (8 bytes) + face material list "Red" 1 face
    let mut fm = Vec::new();
    fm.extend(le16(0x4130));
    fm.extend(le32(6 + 4 + 2 + 2));
    fm.extend(b"Red\0");
    fm.extend(le16(1));
    fm.extend(le16(0));
    let mut faces = Vec::new();
    faces.extend(le16(0x4120));
    faces.extend(le32((6 + 2 + 8 + fm.len()) as u32));
    faces.extend(le16(1));
    faces.extend([0, 0, 1, 0, 2, 0, 0, 0]);
    faces.extend(&fm);
    let mut tri = Vec::new();
    tri.extend(le16(0x4100));
    tri.extend(le32((6 + verts.len() + faces.len()) as u32));
    tri.extend(&verts);
    tri.extend(&faces);
    let mut obj = Vec::new();
    obj.extend(le16(0x4000));
    obj.extend(le32((6 + 4 + tri.len()) as u32));
    obj.extend(b"Tri\0");
    obj.extend(&tri);
    let mut afff = Vec::new();
    afff.extend(le16(0xAFFF));
    afff.extend(le32((6 + mat.len()) as u32));
    afff.extend(&mat);
    let mut editor = Vec::new();
    editor.extend(le16(0x3D3D));
    editor.extend(le32((6 + afff.len() + obj.len()) as u32));
    editor.extend(&afff);
    editor.extend(&obj);
    f.extend(le16(0x4D4D));
    f.extend(le32((6 + editor.len()) as u32));
    f.extend(&editor);
    f
}

#[test]
fn hand_written_triangle_has_known_values() {
    let m = parse(&hand_written()).unwrap();
    assert_eq!(m.indices.len(), 1);
    assert_eq!(m.objects, vec!["Tri".to_string()]);
    let tri = m.indices[0].map(|i| m.positions[i as usize]);
    assert_eq!(tri, [[1.0, 2.0, 3.0], [4.0, 2.0, 3.0], [1.0, 5.0, 3.0]]);
    // (3,0,0) × (0,3,0) points along +z.
    assert!(m.normals.iter().all(|n| close(*n, [0.0, 0.0, 1.0])));
    assert_eq!(m.materials.len(), 1, "no default material needed");
    assert_eq!(m.materials[0].name, "Red");
    assert_eq!(m.materials[0].diffuse, [1.0, 0.0, 0.0, 1.0]);
    assert_eq!(m.materials[0].shininess, 64.0, "50 % of 128");
    assert_eq!(m.triangle_materials, vec![0]);
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    assert_eq!(m.validate(), Ok(()));
}

#[test]
fn bench_fixture_reads_back_with_materials_and_texture() {
    let m = parse(&bench_3ds()).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    assert_eq!(m.objects, vec!["Seat".to_string(), "Legs".to_string()]);
    assert_eq!(m.indices.len(), 12 + 24);
    let names: Vec<_> = m.materials.iter().map(|x| x.name.as_str()).collect();
    assert_eq!(names, ["Wood", "Iron"]);
    assert_eq!(m.textures.len(), 1);
    assert_eq!(m.textures[0].name, "OBJWOOD.PNG");
    assert_eq!(m.materials[0].color_map, Some(0));
    assert_eq!(m.materials[1].color_map, None);
    assert!((m.materials[1].shininess - 0.6 * 128.0).abs() < 1e-4);
    assert_eq!(m.triangle_materials[..12], [0; 12]);
    assert_eq!(m.triangle_materials[12..], [1; 24]);
    // The keyframer placement equals the mesh matrix: the stored vertices come back.
    let (lo, hi) = bounds(&m);
    assert!(close(lo, [-0.8, -0.2, 0.0]), "{lo:?}");
    assert!(close(hi, [0.8, 0.2, 0.45]), "{hi:?}");
    // Box sides are flat: every normal is a unit axis vector.
    for n in &m.normals {
        let ones = n.iter().filter(|c| (c.abs() - 1.0).abs() < 1e-5).count();
        assert_eq!(ones, 1, "{n:?}");
    }
    // 24 vertices per box (4 per side, smoothing groups per side keep them apart).
    assert_eq!(m.positions.len(), 24 * 3);
    // v is flipped: stored uvs are 0/1 corners, so still 0/1 values.
    assert!(m.uvs.iter().flatten().all(|&c| c == 0.0 || c == 1.0));
    assert_eq!(m.validate(), Ok(()));
}

#[test]
fn load_resolves_texture_case_insensitively() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in crate::fixtures::object3ds::object_files() {
        std::fs::write(dir.path().join(name), bytes).unwrap();
    }
    let m = load(&dir.path().join("object.3ds")).unwrap();
    assert_eq!(m.textures[0].path, dir.path().join("objwood.png"));
}

/// Regression: with a model named by a bare relative path (`bake ingest scene.eco` run in
/// the scene's folder) the texture's folder was "", `read_dir("")` failed, and the
/// case-insensitive match was skipped ("OBJWOOD.PNG: No such file or directory").
#[test]
fn bare_relative_texture_name_resolves_case_insensitively() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("objwood.png"), b"x").unwrap();
    let here = std::env::current_dir().unwrap();
    let rel = pathdiff(dir.path(), &here);
    let found = resolve_texture(&rel, "OBJWOOD.PNG");
    assert_eq!(found, rel.join("objwood.png"));
    assert_eq!(
        resolve_texture(Path::new(""), "Cargo.TOML"),
        PathBuf::from("Cargo.toml")
    );
}

/// `to` relative to `from` through `..` (both absolute).
fn pathdiff(to: &Path, from: &Path) -> PathBuf {
    let mut p = PathBuf::new();
    for _ in from.components().skip(1) {
        p.push("..");
    }
    p.join(to.strip_prefix("/").unwrap())
}

fn one_box(matrix: Option<[f32; 12]>) -> Object3ds {
    let mut o = box_object("B", [0.0; 3], [1.0; 3]);
    o.matrix = matrix;
    o
}

#[test]
fn keyframer_position_moves_the_object_like_assimp() {
    // Identity mesh matrix, node at (1, 2, 3): vertices move by (1, 2, 3).
    let kf = node_chunk(0, "B", [1.0, 2.0, 3.0], (0.0, [0.0, 0.0, 1.0]), [1.0; 3]);
    let m = parse(&file_3ds(&[], &[one_box(None)], Some(&kf))).unwrap();
    let (lo, hi) = bounds(&m);
    assert!(
        close(lo, [1.0, 2.0, 3.0]) && close(hi, [2.0, 3.0, 4.0]),
        "{lo:?} {hi:?}"
    );
}

#[test]
fn mesh_matrix_is_undone_then_node_applied() {
    // Mesh matrix: translate by (10, 0, 0); node: rotation key +90° about z, which assimp
    // applies as a rotation by -90°: local (x, y, z) -> (y, -x, z), then scale 2.
    let mut mat = [0.0; 12];
    mat[0] = 1.0;
    mat[4] = 1.0;
    mat[8] = 1.0;
    mat[9] = 10.0;
    let o = Object3ds {
        name: "T".into(),
        positions: vec![[11.0, 0.0, 0.0], [10.0, 1.0, 0.0], [10.0, 0.0, 1.0]],
        faces: vec![[0, 1, 2]],
        matrix: Some(mat),
        ..Object3ds::default()
    };
    let kf = node_chunk(
        0,
        "T",
        [0.0; 3],
        (std::f32::consts::FRAC_PI_2, [0.0, 0.0, 1.0]),
        [2.0; 3],
    );
    let m = parse(&file_3ds(&[], &[o], Some(&kf))).unwrap();
    let tri = m.indices[0].map(|i| m.positions[i as usize]);
    assert!(close(tri[0], [0.0, -2.0, 0.0]), "{tri:?}");
    assert!(close(tri[1], [2.0, 0.0, 0.0]), "{tri:?}");
    assert!(close(tri[2], [0.0, 0.0, 2.0]), "{tri:?}");
}

#[test]
fn negative_determinant_mirrors_local_x() {
    // Mesh matrix mirrors x; node identity: local = flip(inverse(M) v) = v again in x.
    let mut mat = [0.0; 12];
    mat[0] = -1.0;
    mat[4] = 1.0;
    mat[8] = 1.0;
    mat[9] = 5.0;
    let kf = node_chunk(0, "B", [0.0; 3], (0.0, [0.0, 0.0, 1.0]), [1.0; 3]);
    let m = parse(&file_3ds(&[], &[one_box(Some(mat))], Some(&kf))).unwrap();
    // inverse(M) v = (5 - x, y, z), mirrored: (x - 5, y, z).
    let (lo, hi) = bounds(&m);
    assert!(
        close(lo, [-5.0, 0.0, 0.0]) && close(hi, [-4.0, 1.0, 1.0]),
        "{lo:?} {hi:?}"
    );
}

#[test]
fn without_keyframer_matrix_is_ignored() {
    let mut mat = [0.0; 12];
    mat[0] = 2.0;
    mat[4] = 2.0;
    mat[8] = 2.0;
    let m = parse(&file_3ds(&[], &[one_box(Some(mat))], None)).unwrap();
    assert_eq!(bounds(&m), ([0.0; 3], [1.0; 3]));
}

#[test]
fn smoothing_groups_average_normals_across_seams() {
    // A roof: two faces meeting at the ridge x = 0, z = 1; the ridge vertices are stored
    // twice (a texture seam), so only positions can tell they are shared.
    let roof = |groups: Vec<u32>| Object3ds {
        name: "R".into(),
        positions: vec![
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 1.0],
        ],
        faces: vec![[0, 1, 2], [3, 4, 5]],
        smoothing: groups,
        ..Object3ds::default()
    };
    let ridge = |m: &Mesh| -> Vec<[f32; 3]> {
        (0..m.positions.len())
            .filter(|&i| m.positions[i][0] == 0.0)
            .map(|i| m.normals[i])
            .collect()
    };
    let smooth = parse(&file_3ds(&[], &[roof(vec![1, 1])], None)).unwrap();
    let r = ridge(&smooth);
    assert_eq!(r.len(), 4);
    assert!(
        r.iter()
            .all(|n| close(*n, [0.0, 0.0, -1.0]) || close(*n, [0.0, 0.0, 1.0]))
    );
    let n0 = r[0];
    assert!(
        r.iter().all(|n| *n == n0),
        "one averaged normal on the ridge: {r:?}"
    );
    let flat = parse(&file_3ds(&[], &[roof(vec![1, 2])], None)).unwrap();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!(
        ridge(&flat)
            .iter()
            .all(|n| (n[0].abs() - h).abs() < 1e-5 && (n[2].abs() - h).abs() < 1e-5)
    );
}

#[test]
fn rock_has_its_analytic_counts() {
    // Two rocks of 250 × 125 quads: 2 · 62500 triangles.
    let m = parse(&crate::fixtures::object3ds::rock_3ds(250, 2)).unwrap();
    assert_eq!(m.indices.len(), 2 * 2 * 250 * 125);
    assert_eq!(m.objects, ["Rock0", "Rock1"]);
    assert_eq!(m.validate(), Ok(()));
    let (lo, hi) = bounds(&m);
    assert!(lo.iter().all(|c| (-1.11..-0.85).contains(c)), "{lo:?}");
    assert!(
        (3.35..3.61).contains(&hi[0]) && (0.85..1.11).contains(&hi[2]),
        "{hi:?}"
    );
}

#[test]
fn out_of_range_faces_are_dropped_with_a_warning() {
    let mut o = one_box(None);
    o.faces.push([0, 1, 99]);
    let m = parse(&file_3ds(&[], &[o], None)).unwrap();
    assert_eq!(m.indices.len(), 12);
    assert!(
        m.warnings.iter().any(|w| w.contains("1 of 13 faces")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn faces_without_material_get_the_default_and_unknown_names_warn() {
    let mut o = one_box(None);
    o.face_materials = vec![("Nope".into(), vec![0, 1])];
    let mats = [material_chunk("Tex", [9, 9, 9], 0, 50, Some("T.PNG"))];
    let m = parse(&file_3ds(&mats, &[o], None)).unwrap();
    assert_eq!(m.materials.len(), 2);
    assert_eq!(m.materials[1].name, "default");
    assert_eq!(m.materials[0].transparency, 0.5);
    assert!(m.triangle_materials.iter().all(|&t| t == 1));
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("unknown material \"Nope\""))
    );
}

#[test]
fn missing_uvs_on_a_textured_object_warn() {
    let mut o = one_box(None);
    o.uvs.clear();
    o.face_materials = vec![("Tex".into(), (0..12).collect())];
    let mats = [material_chunk("Tex", [9, 9, 9], 0, 0, Some("T.PNG"))];
    let m = parse(&file_3ds(&mats, &[o], None)).unwrap();
    assert!(m.uvs.iter().all(|uv| *uv == [0.0, 0.0]));
    assert!(
        m.warnings.iter().any(|w| w.contains("0x4140")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn truncation_at_every_length_is_an_error_not_a_panic() {
    let bytes = bench_3ds();
    for n in 0..bytes.len() {
        let e = parse(&bytes[..n]).expect_err("a truncated file must fail");
        assert!(e.place.starts_with("byte"), "{n}: {e}");
    }
}

#[test]
fn zero_length_chunk_is_skipped_with_a_warning() {
    let mut o = Vec::new();
    o.extend(chunk(0x1234, &[])[..2].iter()); // id only ...
    o.extend(0u32.to_le_bytes()); // ... with length 0
    let obj = crate::fixtures::object3ds::object_chunk(&one_box(None));
    let editor = chunk(0x3D3D, &[&o, &obj]);
    let m = parse(&chunk(0x4D4D, &[&editor])).unwrap();
    assert_eq!(m.indices.len(), 12);
    assert!(
        m.warnings.iter().any(|w| w.contains("length 0")),
        "{:?}",
        m.warnings
    );
}

#[test]
fn chunk_past_its_parent_is_clamped_and_past_the_file_is_an_error() {
    let obj = crate::fixtures::object3ds::object_chunk(&one_box(None));
    let mut editor = chunk(0x3D3D, &[&obj]);
    // Editor claims 4 more bytes than the main chunk holds; the file has them (padding).
    let len = editor.len() as u32 + 4;
    editor[2..6].copy_from_slice(&len.to_le_bytes());
    let mut file = chunk(0x4D4D, &[&editor]);
    file.extend([0; 4]);
    let m = parse(&file).unwrap();
    assert!(
        m.warnings.iter().any(|w| w.contains("past its parent")),
        "{:?}",
        m.warnings
    );
    // The same without the padding runs past the end of the file.
    file.truncate(file.len() - 4);
    let e = parse(&file).unwrap_err();
    assert!(
        e.place.contains("chunk 0x3D3D") && e.message.contains("truncated"),
        "{e}"
    );
}

#[test]
fn vertex_count_larger_than_its_chunk_names_chunk_and_offset() {
    let mut verts = 60000u16.to_le_bytes().to_vec();
    verts.extend([0u8; 12]);
    let tri = chunk(0x4100, &[&chunk(0x4110, &[&verts])]);
    let obj = chunk(0x4000, &[&cstr("X"), &tri]);
    let file = chunk(0x4D4D, &[&chunk(0x3D3D, &[&obj])]);
    let e = parse(&file).unwrap_err();
    assert!(e.place.contains("chunk 0x4110"), "{e}");
    assert!(
        e.message.contains("60000 vertices needs 720000 bytes"),
        "{e}"
    );
}

#[test]
fn not_a_3ds_file_and_no_triangles_are_errors() {
    assert!(
        parse(b"hello world")
            .unwrap_err()
            .message
            .contains("0x4D4D")
    );
    let e = parse(&file_3ds(&[], &[], None)).unwrap_err();
    assert!(e.message.contains("no triangles"), "{e}");
}

#[test]
fn random_mutations_never_panic() {
    let base = bench_3ds();
    let mut rng = crate::rng::Rng::new(7);
    for _ in 0..3000 {
        let mut b = base.clone();
        for _ in 0..1 + rng.next_u64() % 4 {
            let k = (rng.next_u64() % b.len() as u64) as usize;
            b[k] = rng.next_u64() as u8;
        }
        if let Ok(m) = parse(&b) {
            assert_eq!(m.validate(), Ok(()));
        }
    }
}
