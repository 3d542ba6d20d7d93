//! `verify` on a small hand-made pack: clean as written, every single-bit flip caught, and
//! packs with valid checksums but broken invariants caught with the right section, array and
//! byte offset.

use super::*;
use crate::model::{Instance, Instances, Material, Mesh, Rgba8Image, TextureRef};
use crate::pack::{ArrayFormat, PackWriter, SectionBuilder};

fn mesh() -> Mesh {
    Mesh {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        normals: vec![[0.0, 0.0, 1.0]; 3],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
        indices: vec![[0, 1, 2]],
        triangle_materials: vec![0],
        materials: vec![Material {
            color_map: Some(0),
            ..Material::default()
        }],
        textures: vec![TextureRef {
            name: "leaf.png".into(),
            path: "leaf.png".into(),
        }],
        objects: vec!["tri".into()],
        warnings: Vec::new(),
        skeleton: Default::default(),
    }
}

/// A mesh with a texture, and instances placing it: every reference resolves.
fn small_pack(m: &Mesh) -> PackWriter {
    let mut w = PackWriter::new();
    let img = Rgba8Image {
        width: 2,
        height: 1,
        pixels: vec![[1, 2, 3, 255], [4, 5, 6, 255]],
    };
    w.insert(crate::texture::source_section::to_section(
        "texture:tri.obj/leaf.png",
        "leaf.png",
        &img,
    ));
    let tex = [Some("texture:tri.obj/leaf.png".to_string())];
    w.insert(crate::mesh::section::to_section(
        "mesh:tri.obj",
        "tri.obj",
        m,
        &tex,
    ));
    let inst = Instances {
        models: vec!["tri.obj".into()],
        items: vec![Instance {
            model: 0,
            position: [1.0, 2.0, 3.0],
            scale: 1.0,
            rotation_deg: 90.0,
            layer: 1,
        }],
    };
    w.insert(crate::ingest::instances_section::to_section(
        "instances",
        &inst,
        vec!["mesh:tri.obj".into()],
    ));
    w
}

fn checks(bytes: &[u8]) -> Vec<&'static str> {
    verify_bytes(bytes)
        .violations
        .iter()
        .map(|v| v.check)
        .collect()
}

#[test]
fn the_small_pack_verifies_clean() {
    let bytes = small_pack(&mesh()).to_bytes().unwrap();
    let r = verify_bytes(&bytes);
    assert!(r.ok(), "{:#?}", r.violations);
    assert_eq!(
        (r.version, r.sections, r.decoded),
        (Some(crate::pack::VERSION), 3, 3)
    );
}

#[test]
fn every_single_bit_flip_is_caught() {
    let bytes = small_pack(&mesh()).to_bytes().unwrap();
    let mut missed = Vec::new();
    for bit in 0..bytes.len() * 8 {
        let mut b = bytes.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        if verify_bytes(&b).ok() {
            missed.push(bit);
        }
    }
    assert!(
        missed.is_empty(),
        "{} of {} flips missed, first at byte {}",
        missed.len(),
        bytes.len() * 8,
        missed[0] / 8
    );
}

#[test]
fn truncations_and_extensions_are_caught() {
    let bytes = small_pack(&mesh()).to_bytes().unwrap();
    for cut in [0, 1, 63, 64, 200, bytes.len() - 1] {
        assert!(!verify_bytes(&bytes[..cut]).ok(), "cut at {cut}");
    }
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 16]);
    assert_eq!(checks(&longer), ["header.file_size"]);
}

#[test]
fn an_index_past_the_vertex_count_is_caught_with_valid_checksums() {
    let mut m = mesh();
    m.indices[0][2] = 3;
    let r = verify_bytes(&small_pack(&m).to_bytes().unwrap());
    assert_eq!(r.violations.len(), 1, "{:#?}", r.violations);
    let v = &r.violations[0];
    assert_eq!(
        (v.check, v.section.as_deref()),
        ("kind.decode", Some("mesh:tri.obj"))
    );
    assert!(
        v.message.contains("refers to a vertex past 3"),
        "{}",
        v.message
    );
}

#[test]
fn a_nan_is_caught_at_its_byte() {
    let mut m = mesh();
    m.positions[1][2] = f32::NAN;
    let bytes = small_pack(&m).to_bytes().unwrap();
    let r = verify_bytes(&bytes);
    assert_eq!(r.violations.len(), 1, "{:#?}", r.violations);
    let v = &r.violations[0];
    assert_eq!(
        (v.check, v.array.as_deref()),
        ("float.finite", Some("positions"))
    );
    // Element 1, component 2 of the positions array: the NaN's own bytes.
    let at = v.offset as usize;
    assert!(f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()).is_nan());
}

#[test]
fn a_normal_that_is_not_unit_length_is_caught() {
    let mut m = mesh();
    m.normals[2] = [0.0, 0.0, 2.0];
    let r = verify_bytes(&small_pack(&m).to_bytes().unwrap());
    assert_eq!(checks_of(&r), ["vector.unit"]);
    assert!(r.violations[0].message.contains("vector 2"));
}

fn checks_of(r: &VerifyReport) -> Vec<&'static str> {
    r.violations.iter().map(|v| v.check).collect()
}

#[test]
fn dangling_references_are_caught() {
    let mut w = small_pack(&mesh());
    let inst = Instances {
        models: vec!["gone.obj".into()],
        items: vec![],
    };
    w.insert(crate::ingest::instances_section::to_section(
        "instances",
        &inst,
        vec!["mesh:gone.obj".into()],
    ));
    let r = verify_bytes(&w.to_bytes().unwrap());
    assert_eq!(checks_of(&r), ["reference.dangling"]);
    assert!(
        r.violations[0]
            .message
            .contains("\"mesh:gone.obj\": no such section")
    );

    let mut w = small_pack(&mesh());
    w.remove_kind("texture");
    let r = verify_bytes(&w.to_bytes().unwrap());
    assert_eq!(checks_of(&r), ["reference.dangling"]);
    assert_eq!(r.violations[0].section.as_deref(), Some("mesh:tri.obj"));
}

#[test]
fn wrong_array_types_unknown_kinds_and_names_are_caught() {
    let mut w = small_pack(&mesh());
    let mut s = SectionBuilder::new("sky", "sky");
    s.meta(&("x".to_string(),))
        .array("texels", ArrayFormat::U8, 4, &[[0u8; 4]]);
    w.insert(s.finish());
    let mut s = SectionBuilder::new("gizmo", "gizmo");
    s.array("x", ArrayFormat::U8, 1, &[1u8]);
    w.insert(s.finish());
    w.insert(SectionBuilder::new("mesh", "notamesh").finish());
    let r = verify_bytes(&w.to_bytes().unwrap());
    assert_eq!(
        checks_of(&r),
        ["array.type", "kind.unknown", "kind.name"],
        "{:#?}",
        r.violations
    );
    assert_eq!(r.violations[0].array.as_deref(), Some("texels"));
}

#[test]
fn reserved_instance_fields_must_be_zero() {
    let mut bytes = small_pack(&mesh()).to_bytes().unwrap();
    let pack = crate::pack::Pack::from_bytes(&bytes, "mem").unwrap();
    let e = pack.find("instances").unwrap().clone();
    let view = pack.view(&e).unwrap();
    let a = view.info("instances").unwrap().clone();
    let at = (e.offset + a.offset + 28) as usize;
    bytes[at] = 1;
    // Re-seal the checksum so only the invariant can catch it.
    let payload = bytes[e.offset as usize..(e.offset + e.size) as usize].to_vec();
    let table = u64::from_le_bytes(bytes[24..32].try_into().unwrap()) as usize;
    let entry = (0..pack.sections().len())
        .map(|k| table + 168 * k)
        .find(|&e| bytes[e + 16..e + 26] == *b"instances\0")
        .unwrap();
    bytes[entry + 136..entry + 168].copy_from_slice(blake3::hash(&payload).as_bytes());
    let r = verify_bytes(&bytes);
    assert_eq!(checks_of(&r), ["instances.reserved"]);
    assert_eq!(r.violations[0].offset as usize, at);
}

#[test]
fn a_future_version_is_refused_naming_the_version_read() {
    let mut bytes = small_pack(&mesh()).to_bytes().unwrap();
    let next = crate::pack::VERSION + 1;
    bytes[8..12].copy_from_slice(&next.to_le_bytes());
    let r = verify_bytes(&bytes);
    assert_eq!(r.version, Some(next));
    assert_eq!(checks_of(&r), ["header.version"]);
    assert_eq!(
        r.violations[0].message,
        format!("pack format version {next}, this bake reads versions 1 to 2")
    );
}
