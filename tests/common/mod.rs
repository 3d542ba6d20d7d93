//! Helpers shared by the integration tests (each test binary includes this module with
//! `mod common;` and uses what it needs).
#![allow(dead_code)]

use serde_json::Value;
use std::process::{Command, Output};

/// Runs the `bake` binary built for these tests (Mesa's device-select layer silenced).
pub fn bake(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bake"))
        .args(args)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("run bake")
}

/// The JSON `bake` printed on stdout; fails the test with its stderr when it failed.
pub fn json(o: &Output) -> Value {
    assert!(
        o.status.success(),
        "bake failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).expect("stdout is JSON")
}

/// Area of the intersection of two circles (radii r1, r2, centre distance d): the part of the
/// sun's disc an opaque disc hides, for the analytic penumbra tests.
pub fn lens_area(d: f64, r1: f64, r2: f64) -> f64 {
    if d >= r1 + r2 {
        return 0.0;
    }
    if d <= (r1 - r2).abs() {
        return std::f64::consts::PI * r1.min(r2).powi(2);
    }
    let a1 = ((d * d + r1 * r1 - r2 * r2) / (2.0 * d * r1)).acos();
    let a2 = ((d * d + r2 * r2 - r1 * r1) / (2.0 * d * r2)).acos();
    r1 * r1 * a1 + r2 * r2 * a2
        - 0.5 * ((-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)).sqrt()
}

/// sRGB 8-bit value to linear (the standard transfer function, written here independently of
/// the renderer so the render tests have their own oracle).
pub fn srgb_decode(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear to sRGB-encoded in [0, 1] (see [`srgb_decode`]).
pub fn srgb_encode(l: f32) -> f32 {
    if l <= 0.003_130_8 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

/// Sky radiance a + b·z as SH: L00 = a·√(4π), L_{1,0} = b·√(4π/3).
pub fn linear_sky(a: f32, b: f32) -> bake::sh::ShRadiance {
    let mut s = bake::sh::ShRadiance::default();
    s.coeffs[0] = [a * (4.0 * std::f32::consts::PI).sqrt(); 3];
    s.coeffs[2] = [b * (4.0 * std::f32::consts::PI / 3.0).sqrt(); 3];
    s
}

/// A scene BVH of `models` placed by `inst`.
pub fn scene_bvh(
    models: &[&bake::model::Mesh],
    inst: Vec<bake::trace::InstanceTransform>,
) -> bake::trace::SceneBvh {
    use bake::trace::{BuildPreset, ModelBvh};
    let bvhs = models
        .iter()
        .map(|m| std::sync::Arc::new(ModelBvh::build(m, &[], BuildPreset::Medium).unwrap()))
        .collect();
    bake::trace::SceneBvh::build(bvhs, inst).unwrap()
}

/// Instance of `model` at `t`, rotated about z by `rotation_deg`, scale 1.
pub fn place(model: u32, t: [f32; 3], rotation_deg: f32) -> bake::trace::InstanceTransform {
    bake::trace::InstanceTransform {
        model,
        translation: t,
        scale: 1.0,
        rotation_deg,
    }
}

/// The fuzz targets of fuzz/fuzz_targets/, by name.
pub const FUZZ_TARGETS: [&str; 10] = [
    "txf", "max3ds", "eco", "sgi", "obj", "gltf", "raw", "hdr", "exr", "pack",
];

/// One input through a fuzz target's entry point (the same calls as fuzz/fuzz_targets/):
/// `Ok` when the reader accepts it. For `pack`, accepted means `verify` finds nothing.
pub fn fuzz_entry(target: &str, data: &[u8]) -> Result<(), String> {
    let e = |e: bake::error::ParseError| e.to_string();
    match target {
        "txf" => bake::ingest::txf::parse(data).map(drop).map_err(e),
        "max3ds" => bake::ingest::max3ds::parse(data).map(drop).map_err(e),
        "eco" => bake::ingest::eco::parse(data).map(drop).map_err(e),
        "sgi" => bake::ingest::texture::decode(data).map(drop).map_err(e),
        "hdr" => bake::ingest::skyimage::parse_hdr(data).map(drop).map_err(e),
        "exr" => bake::ingest::skyimage::parse_exr(data).map(drop).map_err(e),
        "gltf" => bake::ingest::gltf::parse(data).map(drop).map_err(e),
        "obj" => {
            let k = data.iter().position(|&b| b == 0).unwrap_or(data.len());
            let mtl = data.get(k + 1..).unwrap_or_default();
            let m = bake::ingest::obj::parse_with_mtl(&data[..k], mtl).map_err(e)?;
            (m.materials.len() >= 2)
                .then_some(())
                .ok_or("MTL not read".into())
        }
        "raw" if data.len() < 4 => Err("shorter than the size prefix".into()),
        "raw" => {
            let spec = bake::ingest::raw::RawSpec {
                width: u16::from_le_bytes([data[0], data[1]]) as u32,
                height: u16::from_le_bytes([data[2], data[3]]) as u32,
                scale: 0.05,
                origin: [0.0, 0.0],
                extent: [1.0, 1.0],
            };
            bake::ingest::raw::parse(&data[4..], &spec)
                .map(drop)
                .map_err(e)
        }
        "pack" => {
            let r = bake::verify::verify_bytes(data);
            r.ok().then_some(()).ok_or(format!("{:?}", r.violations))
        }
        other => Err(format!("no such target {other}")),
    }
}

/// The `bake` binary built for these tests.
pub fn bake_bin() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_BIN_EXE_bake"))
}

/// Whether a peer tool is on PATH. Missing under CI (`CI` set) it fails the test, so that a
/// check cannot pass by not running; elsewhere it prints a visible skip and returns false.
pub fn tool_available(tool: &str, why: &str) -> bool {
    let found = Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            std::env::var_os("CI").is_none(),
            "{tool} ({why}) is not installed; .ci/run installs it"
        );
        eprintln!("SKIPPED: {tool} ({why}) is not installed");
    }
    found
}

/// Whether `path` exists; if not, a skip with `what` (how to install it), or a failure under
/// `CI` (`.ci/run` installs everything), as [`tool_available`] does for commands.
pub fn installed(path: &std::path::Path, what: &str) -> bool {
    let found = path.exists();
    if !found {
        assert!(
            std::env::var_os("CI").is_none(),
            "{what} is not at {}",
            path.display()
        );
        eprintln!("SKIPPED: {what} is not at {}", path.display());
    }
    found
}

/// A 1×1 m card standing in the XZ plane (x ∈ [−½, ½], z ∈ [0, 1]) facing −Y; u runs with x,
/// v = 0 at the top (z = 1); an authored white material of specular 0 (Lambertian) under the
/// texture `leaf.png` (colour map 0).
pub fn leaf_card() -> bake::model::Mesh {
    use bake::model::{Material, Mesh, TextureRef};
    Mesh {
        positions: vec![
            [-0.5, 0.0, 0.0],
            [0.5, 0.0, 0.0],
            [0.5, 0.0, 1.0],
            [-0.5, 0.0, 1.0],
        ],
        normals: vec![[0.0, -1.0, 0.0]; 4],
        uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        triangle_materials: vec![0, 0],
        materials: vec![Material {
            diffuse: [1.0, 1.0, 1.0, 1.0],
            color_map: Some(0),
            ..Material::default()
        }],
        textures: vec![TextureRef {
            name: "leaf.png".into(),
            path: "leaf.png".into(),
        }],
        ..Mesh::default()
    }
}

/// The fixture scene (`bake::fixtures::write_all` into `dir`) baked with the preview pipeline
/// and no stage cache; returns the pack's path (`dir/scene.bake`).
pub fn preview_fixture_pack(dir: &std::path::Path) -> std::path::PathBuf {
    bake::fixtures::write_all(dir).unwrap();
    let out = dir.join("scene.bake");
    bake::graph::build(
        &bake::graph::BuildOptions {
            scenes: vec![dir.join("scene.eco")],
            output: Some(out.clone()),
            sky: Some(dir.join("sky.hdr")),
            cache: bake::graph::CacheMode::Off,
            ..Default::default()
        }
        .preview(),
        &bake::graph::progress::Silent,
    )
    .unwrap();
    out
}

/// The OBJ text of a closed axis-aligned box from `lo` to `hi`: eight vertices numbered from
/// `first` (1 when the box comes first in the file) and twelve outward-facing triangles.
pub fn box_obj(lo: [f32; 3], hi: [f32; 3], first: u32) -> String {
    let mut s = String::new();
    for z in [lo[2], hi[2]] {
        for (x, y) in [
            (lo[0], lo[1]),
            (hi[0], lo[1]),
            (hi[0], hi[1]),
            (lo[0], hi[1]),
        ] {
            s += &format!("v {x} {y} {z}\n");
        }
    }
    for f in [
        [1, 3, 2],
        [1, 4, 3],
        [5, 6, 7],
        [5, 7, 8],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 4, 8],
        [3, 8, 7],
        [4, 1, 5],
        [4, 5, 8],
    ] {
        let f = f.map(|i| i + first - 1);
        s += &format!("f {} {} {}\n", f[0], f[1], f[2]);
    }
    s
}

/// A 4 × 4 m plate, horizontal, centred on its origin.
pub fn plate() -> bake::model::Mesh {
    bake::model::Mesh {
        positions: vec![
            [-2.0, -2.0, 0.0],
            [2.0, -2.0, 0.0],
            [2.0, 2.0, 0.0],
            [-2.0, 2.0, 0.0],
        ],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        indices: vec![[0, 1, 2], [0, 2, 3]],
        triangle_materials: vec![0, 0],
        materials: vec![bake::model::Material {
            diffuse: [0.8, 0.8, 0.8, 1.0],
            ..bake::model::Material::default()
        }],
        ..bake::model::Mesh::default()
    }
}

/// A flat 9×9 terrain at z = 0 over `origin` to `origin + extent` and one instance of `mesh`
/// (model `name`) at `position`, unrotated, at scale 1.
pub fn one_model_on_flat_terrain(
    name: &str,
    mesh: &bake::model::Mesh,
    position: [f32; 3],
    origin: [f32; 2],
    extent: f32,
) -> bake::pack::PackWriter {
    let mut w = bake::pack::PackWriter::new();
    let t = bake::model::Terrain {
        width: 9,
        height: 9,
        heights: vec![0.0; 81],
        origin,
        extent: [extent, extent],
        color: None,
    };
    w.insert(bake::terrain::source_section::to_section(
        "terrain", "test", &t, None,
    ));
    let section = bake::mesh::section::mesh_section_name(name);
    w.insert(bake::mesh::section::to_section(&section, "test", mesh, &[]));
    let inst = bake::model::Instances {
        models: vec![name.into()],
        items: vec![bake::model::Instance {
            model: 0,
            position,
            scale: 1.0,
            rotation_deg: 0.0,
            layer: 0,
        }],
    };
    w.insert(bake::ingest::instances_section::to_section(
        "instances",
        &inst,
        vec![section],
    ));
    w
}

/// The mean of linear pixels' green channel.
pub fn mean_green(px: &[[f32; 3]]) -> f64 {
    px.iter().map(|p| p[1] as f64).sum::<f64>() / px.len() as f64
}

/// A 96×72 view of the sun's direct term alone (white sun, no sky, one shadow cascade), in linear
/// radiance: what `against_exact_shadows` compares.
pub fn sun_only_view(
    eye: [f32; 3],
    target: [f32; 3],
    fov_y_deg: f32,
    sun_direction: [f32; 3],
) -> bake::render::RenderOptions {
    bake::render::RenderOptions {
        width: 96,
        height: 72,
        eye: Some(eye),
        target: Some(target),
        fov_y_deg,
        lighting: Some(bake::render::Lighting {
            sun_direction,
            sun_irradiance: [1.0; 3],
            ambient: [0.0; 3],
            sun_solid_angle: 0.0,
        }),
        terms: bake::render::Terms::Direct,
        shadow_cascades: 1,
        linear: true,
        ..bake::render::RenderOptions::default()
    }
}

/// One view drawn by the GPU (`opts.linear` must be set) and by the CPU reference renderer (4
/// samples per pixel) with and without its exact shadow rays: the oracle of the shadow maps.
pub struct AgainstExactShadows {
    pub gpu: Vec<[f32; 3]>,
    pub exact: Vec<[f32; 3]>,
    pub unshadowed: Vec<[f32; 3]>,
    /// The nearest cascade's texel in metres.
    pub texel_m: f32,
}

pub fn against_exact_shadows(
    pack: &bake::pack::Pack,
    opts: &bake::render::RenderOptions,
) -> AgainstExactShadows {
    let gpu = bake::render::render_pack(pack, opts).unwrap();
    let texel_m = gpu.stats.shadow_texel_near_m.unwrap();
    let scene = bake::render::scene::load_scene(pack).unwrap();
    let view = bake::render::resolve_view(pack, &scene, opts);
    let mut r = bake::render::reference::Reference::build(&scene).unwrap();
    let size = (opts.width, opts.height);
    let exact = r.radiance_image_sampled(&view, size, opts.terms, 4);
    r.shadows = false;
    let unshadowed = r.radiance_image_sampled(&view, size, opts.terms, 4);
    AgainstExactShadows {
        gpu: gpu.linear.unwrap().pixels,
        exact,
        unshadowed,
        texel_m,
    }
}

/// Flat terrain over [0, 20]² at z = 0, the plate at (10, 10, 3) casting a shadow, and (with
/// `linespace`) the N-tree of both for the soft shadows.
pub fn plate_pack(linespace: bool) -> bake::pack::Pack {
    let mut w = one_model_on_flat_terrain("plate", &plate(), [10.0, 10.0, 3.0], [0.0, 0.0], 20.0);
    if linespace {
        let first = bake::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "scene.bake").unwrap();
        let geo = bake::voxel::geometry::pack_geometry(&first).unwrap();
        let tris = bake::linespace::world_triangles(&geo.mesh);
        let opts = bake::linespace::ntree::NTreeOptions {
            n: 4,
            depth: 3,
            cubic_cells: true,
        };
        let tree = bake::linespace::ntree::build_ntree(
            &tris,
            &opts,
            &std::sync::Arc::new(bake::linespace::shaft::ShaftTable::build(4)),
        )
        .unwrap();
        w.insert(bake::linespace::section::to_section(
            "linespace",
            "test",
            &tree,
        ));
    }
    bake::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "scene.bake").unwrap()
}

/// A closed box from `lo` to `hi` (twelve outward-wound triangles, outward vertex normals).
pub fn closed_box(lo: [f32; 3], hi: [f32; 3]) -> bake::model::Mesh {
    bake::fixtures::box_faces(lo, hi, [true; 6])
}
