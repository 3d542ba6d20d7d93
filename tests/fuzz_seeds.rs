//! The seed corpora of the cargo-fuzz targets (`fuzz/corpus/<target>/`, docs/FUZZING.md): every
//! seed must be accepted by its target's reader, so a campaign starts from files that reach deep
//! into each format instead of stopping at the first check.
//!
//! Seeds are small and committed. The generated ones (EXR, glTF/GLB, OBJ+MTL, RAW, the
//! hand-made pack) and the copies of the fixtures are rewritten by
//! `BAKE_BLESS=1 cargo test --test fuzz_seeds`; review the diff before committing it.

use bake::model::{FloatImage, Instance, Instances, Material, Mesh, Rect, Rgba8Image, TextureRef};
use bake::pack::PackWriter;
use std::path::{Path, PathBuf};

mod common;

fn corpus(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(target)
}

fn fixture(name: &str) -> Vec<u8> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/scene")
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

const OBJ: &str = "mtllib two.mtl\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl leaf\nf 1/1/1 2/2/1 3/3/1 4/4/1\ng back\nusemtl bark\nf 3 2 1\n";
const MTL: &str = "newmtl leaf\nKd 0.2 0.6 0.1\nKs 0.1 0.1 0.1\nNs 40\nd 0.9\nmap_Kd leaf.png\nmap_Bump -bm 1 leaf_n.png\nnewmtl bark\nKd 0.4 0.3 0.2\nTr 0.0\n";

fn base64(data: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in data.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            s.push(if k <= c.len() {
                A[(n >> (18 - 6 * k) & 63) as usize] as char
            } else {
                '='
            });
        }
    }
    s
}

/// Three positions, three normals, three UVs, then three u16 indices (padded): 110 bytes.
fn gltf_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [
        [0f32, 0., 0.],
        [1., 0., 0.],
        [0., 1., 0.],
        [0., 0., 1.],
        [0., 0., 1.],
        [0., 0., 1.],
    ] {
        b.extend(v.iter().flat_map(|c| c.to_le_bytes()));
    }
    for v in [[0f32, 0.], [1., 0.], [0., 1.]] {
        b.extend(v.iter().flat_map(|c| c.to_le_bytes()));
    }
    b.extend([0u16, 1, 2].iter().flat_map(|i| i.to_le_bytes()));
    b.extend([0, 0]);
    b
}

fn gltf_json(buffer: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
"nodes":[{{"name":"n","translation":[0,0,1],"rotation":[0,0,0,1],"scale":[1,1,1],"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2}},"indices":3,"material":0}}]}}],
"materials":[{{"name":"m","pbrMetallicRoughness":{{"baseColorFactor":[1,0.5,0.25,1],"metallicFactor":0.1,"roughnessFactor":0.8,"baseColorTexture":{{"index":0}}}},"normalTexture":{{"index":0}}}}],
"textures":[{{"source":0}}],"images":[{{"uri":"leaf.png"}}],
"buffers":[{buffer}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":72}},{{"buffer":0,"byteOffset":72,"byteLength":24}},{{"buffer":0,"byteOffset":96,"byteLength":6}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
{{"bufferView":0,"byteOffset":36,"componentType":5126,"count":3,"type":"VEC3"}},
{{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}},
{{"bufferView":2,"componentType":5123,"count":3,"type":"SCALAR"}}]}}"#
    )
}

fn glb() -> Vec<u8> {
    let bin = gltf_buffer();
    let mut j = gltf_json(&format!(r#"{{"byteLength":{}}}"#, bin.len())).into_bytes();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let total = 12 + 8 + j.len() + 8 + bin.len();
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(j);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(bin);
    out
}

fn exr() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sky.exr");
    exr::prelude::write_rgb_file(&path, 8, 4, |x, y| (x as f32 * 0.5, y as f32, 2.0)).unwrap();
    std::fs::read(path).unwrap()
}

/// RAW seeds: a 4-byte declared size (u16 width, u16 height) before the samples.
fn raw(width: u16, height: u16, bytes_per_sample: usize) -> Vec<u8> {
    let mut b = [width.to_le_bytes(), height.to_le_bytes()].concat();
    let n = width as usize * height as usize * bytes_per_sample;
    b.extend((0..n).map(|k| (k * 37 % 251) as u8));
    b
}

/// A small pack with the ingest kinds plus a BitTree and the sky's SH: every reference resolves.
fn small_pack() -> Vec<u8> {
    let mesh = Mesh {
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
    };
    let img = Rgba8Image {
        width: 2,
        height: 2,
        pixels: vec![
            [1, 2, 3, 255],
            [4, 5, 6, 255],
            [7, 8, 9, 0],
            [10, 11, 12, 128],
        ],
    };
    let items: Vec<Instance> = (0..5)
        .map(|k| Instance {
            model: 0,
            position: [k as f32 * 0.2, 1.0 - k as f32 * 0.2, 0.5],
            scale: 1.0 + k as f32 * 0.1,
            rotation_deg: 30.0 * k as f32,
            layer: k % 2,
        })
        .collect();
    let inst = Instances {
        models: vec!["tri.obj".into()],
        items,
    };
    let terrain = bake::model::Terrain {
        width: 3,
        height: 2,
        heights: vec![0.0, 1.0, 2.0, 0.5, 1.5, 2.5],
        origin: [0.0, 0.0],
        extent: [1.0, 1.0],
        color: None,
    };
    let sky = FloatImage {
        width: 4,
        height: 2,
        pixels: vec![[1.0, 0.5, 0.25]; 8],
    };
    let mut w = PackWriter::new();
    w.insert(bake::texture::source_section::to_section(
        "texture:tri.obj/leaf.png",
        "leaf.png",
        &img,
    ));
    let tex = [Some("texture:tri.obj/leaf.png".to_string())];
    w.insert(bake::mesh::section::to_section(
        "mesh:tri.obj",
        "tri.obj",
        &mesh,
        &tex,
    ));
    w.insert(bake::terrain::source_section::to_section(
        "terrain", "t.raw", &terrain, None,
    ));
    w.insert(bake::ingest::instances_section::to_section(
        "instances",
        &inst,
        vec!["mesh:tri.obj".into()],
    ));
    w.insert(bake::sky::source_section::to_section(
        "sky", "sky.hdr", &sky,
    ));
    let sh = bake::sh::ShRadiance {
        coeffs: [[0.1, 0.2, 0.3]; bake::sh::COEFFS],
    };
    w.insert(bake::sky::section::sh_to_section("sh", "sky", &sh));
    let area = Rect {
        origin: [0.0, 0.0],
        extent: [1.0, 1.0],
    };
    w.insert(
        bake::bittree::section::to_section("bittree", &inst, area, &Default::default()).unwrap(),
    );
    w.to_bytes().unwrap()
}

/// Every generated or copied seed: (target, file name, bytes).
fn seeds() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let mut s = vec![
        ("txf", "plant.txf", fixture("plant.txf")),
        ("max3ds", "object.3ds", fixture("object.3ds")),
        ("eco", "scene.eco", fixture("scene.eco")),
        ("sgi", "leaf.rgb", fixture("leaf.rgb")),
        ("sgi", "objwood.png", fixture("objwood.png")),
        ("hdr", "sky.hdr", fixture("sky.hdr")),
        (
            "obj",
            "quad.obj",
            [OBJ.as_bytes(), b"\0", MTL.as_bytes()].concat(),
        ),
        ("gltf", "tri.glb", glb()),
        ("exr", "gradient.exr", exr()),
        ("raw", "8bit_5x3.raw", raw(5, 3, 1)),
        ("raw", "16bit_4x4.raw", raw(4, 4, 2)),
        ("pack", "small.bake", small_pack()),
    ];
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64(&gltf_buffer())
    );
    let json = gltf_json(&format!(
        r#"{{"byteLength":{},"uri":"{uri}"}}"#,
        gltf_buffer().len()
    ));
    s.push(("gltf", "tri_data_uri.gltf", json.into_bytes()));
    s
}

/// One test, so that blessing happens before the corpus is read.
#[test]
fn seeds_match_their_generators_and_are_accepted() {
    if std::env::var_os("BAKE_BLESS").is_some() {
        for (target, name, bytes) in seeds() {
            std::fs::create_dir_all(corpus(target)).unwrap();
            std::fs::write(corpus(target).join(name), bytes).unwrap();
        }
    }
    committed_seeds_match_the_generators();
    for target in common::FUZZ_TARGETS {
        let dir = corpus(target);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "{target}: empty corpus");
        for f in files {
            let data = std::fs::read(&f).unwrap();
            assert!(
                data.len() <= 64 * 1024,
                "{}: seeds stay under 64 KiB",
                f.display()
            );
            if let Err(e) = common::fuzz_entry(target, &data) {
                panic!("{}: not accepted by the {target} reader: {e}", f.display());
            }
        }
    }
}

fn committed_seeds_match_the_generators() {
    for (target, name, bytes) in seeds() {
        if target == "exr" {
            continue; // the exr crate's writer output may change with its version
        }
        let path = corpus(target).join(name);
        let committed = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(
            committed == bytes,
            "{} differs from its generator: BAKE_BLESS=1 cargo test --test fuzz_seeds",
            path.display()
        );
    }
}
