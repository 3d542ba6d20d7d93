//! Real renders of small packs built here, checked against CPU oracles written independently of
//! the renderer: the camera (glam look_at/perspective), the lat-long lookup, Lambert shading of a
//! flat terrain, the tone map 1 − exp(−L·s) and the sRGB encoding. Runs on any wgpu adapter,
//! including Mesa's lavapipe (Vulkan) or llvmpipe (GL) on a machine without a GPU.

use bake::ingest::instances_section as instances;
use bake::mesh::section as mesh;
use bake::model::{FloatImage, Instance, Instances, Mesh, Rgba8Image, Terrain};
use bake::pack::{Pack, PackWriter};
use bake::render::{Lighting, RenderOptions, render_pack};
use bake::sky::source_section as sky;
use bake::terrain::source_section as terrain;
use bake::texture::source_section as texture;
use glam::{Mat4, Vec3, Vec4Swizzles};
use std::f32::consts::PI;

mod common;
use common::{srgb_decode, srgb_encode};

const W: u32 = 128;
const H: u32 = 96;
const EYE: [f32; 3] = [10.0, -10.0, 8.0];
const TARGET: [f32; 3] = [10.0, 10.0, 3.0];
const FOV: f32 = 60.0;
/// Rotation of instance 1, degrees about +Z.
const ROT1: f32 = 150.0;
const EXPOSURE: f32 = 1.0;

/// Terrain colour-map quadrants (sRGB bytes): north-west, north-east, south-west, south-east.
const NW: [u8; 3] = [200, 40, 40];
const NE: [u8; 3] = [40, 40, 200];
const SW: [u8; 3] = [40, 180, 40];
const SE: [u8; 3] = [220, 200, 60];
/// The opaque half of the quad's texture.
const LEAF: [u8; 3] = [200, 60, 180];

fn lighting() -> Lighting {
    Lighting {
        sun_direction: Vec3::new(0.2, -0.5, 0.8).normalize().to_array(),
        sun_irradiance: [3.0, 2.9, 2.7],
        ambient: [0.8, 0.9, 1.1],
        sun_solid_angle: 0.0,
    }
}

/// A smooth lat-long sky: radiance varies with both θ and φ, so a wrong lookup shows.
fn sky_radiance_at(u: f32, v: f32) -> [f32; 3] {
    let (phi, theta) = (u * 2.0 * PI, v * PI);
    [
        0.3 + 0.2 * phi.cos(),
        0.4 + 0.3 * theta.cos(),
        0.5 + 0.4 * (phi * 0.5).sin() * theta.sin(),
    ]
}

fn sky_image(w: u32, h: u32) -> FloatImage {
    let mut pixels = Vec::new();
    for j in 0..h {
        for i in 0..w {
            pixels.push(sky_radiance_at(
                (i as f32 + 0.5) / w as f32,
                (j as f32 + 0.5) / h as f32,
            ));
        }
    }
    FloatImage {
        width: w,
        height: h,
        pixels,
    }
}

/// 8×8 colour map in quadrants, row 0 north.
fn terrain_colors() -> Rgba8Image {
    let mut pixels = Vec::new();
    for row in 0..8 {
        for col in 0..8 {
            let c = match (row < 4, col < 4) {
                (true, true) => NW,
                (true, false) => NE,
                (false, true) => SW,
                (false, false) => SE,
            };
            pixels.push([c[0], c[1], c[2], 255]);
        }
    }
    Rgba8Image {
        width: 8,
        height: 8,
        pixels,
    }
}

/// 8×8 texture: left half opaque LEAF, right half alpha 0 (green, which must never show).
fn leaf_texture() -> Rgba8Image {
    let mut pixels = Vec::new();
    for _row in 0..8 {
        for col in 0..8 {
            pixels.push(if col < 4 {
                [LEAF[0], LEAF[1], LEAF[2], 255]
            } else {
                [0, 255, 0, 0]
            });
        }
    }
    Rgba8Image {
        width: 8,
        height: 8,
        pixels,
    }
}

/// Instance 0 at (6, 10, 0), instance 1 at (14, 10, 0) turned 150° about +Z (still seen from
/// its back, by the camera in the south); both scaled 4×.
fn quad_instances() -> Instances {
    let item = |x: f32, rot: f32| Instance {
        model: 0,
        position: [x, 10.0, 0.0],
        scale: 4.0,
        rotation_deg: rot,
        layer: 0,
    };
    Instances {
        models: vec!["quad".into()],
        items: vec![item(6.0, 0.0), item(14.0, ROT1)],
    }
}

/// Writes the quad's leaf texture and mesh sections; returns the mesh section's name.
fn insert_quad(w: &mut PackWriter) -> String {
    let leaf = bake::texture::source_section::texture_section_name("quad", "leaf.png");
    w.insert(texture::to_section(&leaf, "test", &leaf_texture()));
    let mesh_name = bake::mesh::section::mesh_section_name("quad");
    w.insert(mesh::to_section(
        &mesh_name,
        "test",
        &common::leaf_card(),
        &[Some(leaf)],
    ));
    mesh_name
}

/// A flat 5×5 terrain over [0, 20]² at z = 0 with the quadrant colour map, the quad instanced
/// twice, and (optionally) the sky.
fn build_pack(with_sky: bool) -> Pack {
    let mut w = PackWriter::new();
    let t = Terrain {
        width: 5,
        height: 5,
        heights: vec![0.0; 25],
        origin: [0.0, 0.0],
        extent: [20.0, 20.0],
        color: None,
    };
    let color = bake::texture::source_section::texture_section_name("terrain", "color");
    w.insert(texture::to_section(&color, "test", &terrain_colors()));
    w.insert(terrain::to_section("terrain", "test", &t, Some(color)));
    let mesh_name = insert_quad(&mut w);
    w.insert(instances::to_section(
        "instances",
        &quad_instances(),
        vec![mesh_name],
    ));
    if with_sky {
        w.insert(sky::to_section("sky", "test", &sky_image(64, 32)));
    }
    Pack::from_bytes(&w.to_bytes().unwrap(), "test.bake").unwrap()
}

fn options() -> RenderOptions {
    RenderOptions {
        width: W,
        height: H,
        eye: Some(EYE),
        target: Some(TARGET),
        fov_y_deg: FOV,
        exposure: Some(EXPOSURE),
        lighting: Some(lighting()),
        ..RenderOptions::default()
    }
}

// ---- the oracles ----------------------------------------------------------------------------

/// The camera, from glam's own look-at and perspective (not the renderer's code).
struct Oracle {
    size: (u32, u32),
    eye: Vec3,
    view_proj: Mat4,
    forward: Vec3,
    right: Vec3,
    up: Vec3,
    tan_half: f32,
    aspect: f32,
}

impl Oracle {
    fn new(eye: [f32; 3], target: [f32; 3], fov: f32) -> Oracle {
        Oracle::sized(eye, target, fov, (W, H))
    }

    fn sized(eye: [f32; 3], target: [f32; 3], fov: f32, size: (u32, u32)) -> Oracle {
        let (eye, target) = (Vec3::from(eye), Vec3::from(target));
        let aspect = size.0 as f32 / size.1 as f32;
        let forward = (target - eye).normalize();
        let right = forward.cross(Vec3::Z).normalize();
        let up = right.cross(forward);
        Oracle {
            size,
            eye,
            view_proj: Mat4::perspective_rh(fov.to_radians(), aspect, 0.1, 1000.0)
                * Mat4::look_at_rh(eye, target, Vec3::Z),
            forward,
            right,
            up,
            tan_half: (fov.to_radians() / 2.0).tan(),
            aspect,
        }
    }

    /// The pixel a world point falls in.
    fn pixel(&self, p: Vec3) -> (u32, u32) {
        let (x, y) = self.image_xy(p);
        assert!(
            x >= 0.0 && y >= 0.0 && x < self.size.0 as f32 && y < self.size.1 as f32,
            "{p} is off screen"
        );
        (x as u32, y as u32)
    }

    /// Image coordinates (pixels, y down) of a point in front of the camera.
    fn image_xy(&self, p: Vec3) -> (f32, f32) {
        let c = self.view_proj * p.extend(1.0);
        assert!(c.w > 0.0, "{p} is behind the camera");
        let ndc = c.xyz() / c.w;
        let x = (ndc.x + 1.0) * 0.5 * self.size.0 as f32;
        let y = (1.0 - ndc.y) * 0.5 * self.size.1 as f32;
        (x, y)
    }

    /// The ray through a pixel centre.
    fn ray(&self, px: u32, py: u32) -> Vec3 {
        let nx = (px as f32 + 0.5) / self.size.0 as f32 * 2.0 - 1.0;
        let ny = 1.0 - (py as f32 + 0.5) / self.size.1 as f32 * 2.0;
        (self.forward
            + self.right * (nx * self.tan_half * self.aspect)
            + self.up * (ny * self.tan_half))
            .normalize()
    }
}

/// Radiance → displayed byte: 1 − exp(−L·s), then sRGB.
fn display(l: [f32; 3]) -> [f32; 3] {
    display_at(l, EXPOSURE)
}

fn display_at(l: [f32; 3], exposure: f32) -> [f32; 3] {
    l.map(|c| srgb_encode(1.0 - (-c * exposure).exp()) * 255.0)
}

/// Lambert under the test's sun and sky for albedo (sRGB bytes) and unit normal n.
fn lit(albedo: [u8; 3], n: Vec3) -> [f32; 3] {
    let l = lighting();
    let cos = n.dot(Vec3::from(l.sun_direction)).max(0.0);
    let sky = 0.5 + 0.5 * n.z;
    let mut out = [0.0; 3];
    for k in 0..3 {
        out[k] = srgb_decode(albedo[k]) * (l.sun_irradiance[k] * cos + l.ambient[k] * sky) / PI;
    }
    out
}

/// The sky along d, bilinear between texel centres of the 64×32 test image (wrap in u, clamp
/// in v), from the brief's lat-long convention.
fn sky_along(d: Vec3) -> [f32; 3] {
    let (w, h) = (64i32, 32i32);
    let theta = d.z.clamp(-1.0, 1.0).acos();
    let phi = d.y.atan2(d.x).rem_euclid(2.0 * PI);
    let x = phi / (2.0 * PI) * w as f32 - 0.5;
    let y = theta / PI * h as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let texel = |i: i32, j: i32| {
        let i = i.rem_euclid(w);
        let j = j.clamp(0, h - 1);
        sky_radiance_at((i as f32 + 0.5) / w as f32, (j as f32 + 0.5) / h as f32)
    };
    let (i, j) = (x0 as i32, y0 as i32);
    std::array::from_fn(|k| {
        let a = texel(i, j)[k] * (1.0 - fx) + texel(i + 1, j)[k] * fx;
        let b = texel(i, j + 1)[k] * (1.0 - fx) + texel(i + 1, j + 1)[k] * fx;
        a * (1.0 - fy) + b * fy
    })
}

/// The terrain colour under world (x, y): the quadrant of the colour map (row 0 north).
fn terrain_albedo(x: f32, y: f32) -> [u8; 3] {
    match (y >= 10.0, x < 10.0) {
        (true, true) => NW,
        (true, false) => NE,
        (false, true) => SW,
        (false, false) => SE,
    }
}

fn pixel(img: &Rgba8Image, (x, y): (u32, u32)) -> [u8; 4] {
    img.pixels[(y * img.width + x) as usize]
}

fn assert_close(got: [u8; 4], want: [f32; 3], tol: f32, what: &str) {
    for k in 0..3 {
        assert!(
            (got[k] as f32 - want[k]).abs() <= tol,
            "{what}: got {got:?}, expected {want:?} ± {tol}"
        );
    }
    assert_eq!(got[3], 255, "{what}: alpha");
}

/// Where the ray through a pixel meets the ground plane z = 0.
fn ground_hit(o: &Oracle, px: (u32, u32)) -> Vec3 {
    let d = o.ray(px.0, px.1);
    assert!(d.z < 0.0, "pixel {px:?} looks up");
    o.eye + d * (-o.eye.z / d.z)
}

// ---- the tests --------------------------------------------------------------------------------

#[test]
fn background_pixels_show_the_sky_along_their_ray() {
    let out = render_pack(&build_pack(true), &options()).unwrap();
    let o = Oracle::new(EYE, TARGET, FOV);
    let mut checked = 0;
    // The top rows look above the horizon, past everything in the scene.
    for py in [0u32, 3, 9, 17] {
        for px in (0..W).step_by(9) {
            let d = o.ray(px, py);
            assert!(d.z > 0.0);
            let want = display(sky_along(d));
            assert_close(
                pixel(&out.image, (px, py)),
                want,
                2.5,
                &format!("sky at ({px}, {py})"),
            );
            checked += 1;
        }
    }
    assert!(checked > 50);
    assert!(!out.stats.analytic_sky);
}

#[test]
fn terrain_pixels_have_the_colour_map_under_the_sun_and_sky() {
    let out = render_pack(&build_pack(true), &options()).unwrap();
    let o = Oracle::new(EYE, TARGET, FOV);
    // Points well inside each quadrant, away from the instances and the colour map's seams.
    for (x, y) in [(3.0f32, 3.0f32), (16.0, 4.0), (1.0, 17.0), (19.5, 19.0)] {
        let px = o.pixel(Vec3::new(x, y, 0.0));
        let hit = ground_hit(&o, px);
        let want = display(lit(terrain_albedo(hit.x, hit.y), Vec3::Z));
        assert_close(
            pixel(&out.image, px),
            want,
            2.5,
            &format!("terrain at ({x}, {y})"),
        );
    }
}

/// Model point → world for instance `k`: counter-clockwise rotation about +Z by its angle, the
/// scale, then the translation (the ECO convention, written out here independently).
fn instance_point(k: usize, p: Vec3) -> Vec3 {
    let inst = quad_instances().items[k];
    let a = inst.rotation_deg.to_radians();
    let q = p * inst.scale;
    Vec3::new(
        a.cos() * q.x - a.sin() * q.y,
        a.sin() * q.x + a.cos() * q.y,
        q.z,
    ) + Vec3::from(inst.position)
}

/// The quad's normal (−Y in model space) for instance `k`, turned towards the viewer at `eye`.
fn instance_normal(k: usize, eye: Vec3) -> Vec3 {
    let n = instance_point(k, Vec3::NEG_Y) - instance_point(k, Vec3::ZERO);
    let n = n.normalize();
    if n.dot(eye - instance_point(k, Vec3::ZERO)) < 0.0 {
        -n
    } else {
        n
    }
}

#[test]
fn instances_are_placed_scaled_and_rotated() {
    let out = render_pack(&build_pack(true), &options()).unwrap();
    let o = Oracle::new(EYE, TARGET, FOV);
    for k in 0..2 {
        let want = display(lit(LEAF, instance_normal(k, o.eye)));
        // Inside the opaque half (model x < 0; u < 0.44 where the texture is purely opaque).
        for p in [
            Vec3::new(-0.25, 0.0, 0.5),
            Vec3::new(-0.35, 0.0, 0.875),
            Vec3::new(-0.35, 0.0, 0.125),
        ] {
            let w = instance_point(k, p);
            assert_close(
                pixel(&out.image, o.pixel(w)),
                want,
                2.5,
                &format!("instance {k} at {w}"),
            );
        }
        // Just outside the scaled quad the instance colour must not appear.
        for p in [Vec3::new(-0.7, 0.0, 0.5), Vec3::new(-0.25, 0.0, 1.2)] {
            let w = instance_point(k, p);
            let got = pixel(&out.image, o.pixel(w));
            let off = (0..3)
                .map(|c| (got[c] as f32 - want[c]).abs())
                .fold(0.0, f32::max);
            assert!(
                off > 20.0,
                "instance {k}: its colour {got:?} outside the quad at {w}"
            );
        }
    }
    assert_eq!(out.stats.instances, 2);
    // Two quads of two triangles, and the terrain (chunked: src/render/terrain_lod.rs).
    assert!(out.stats.terrain_triangles > 0);
    assert_eq!(out.stats.triangles - out.stats.terrain_triangles, 2 * 2);
}

#[test]
fn alpha_tested_texels_show_what_is_behind() {
    let out = render_pack(&build_pack(true), &options()).unwrap();
    let o = Oracle::new(EYE, TARGET, FOV);
    // The transparent half (model x > 0, alpha 0 for u > 0.56) of each instance.
    for k in 0..2 {
        let w = instance_point(k, Vec3::new(0.3, 0.0, 0.5));
        let px = o.pixel(w);
        let hit = ground_hit(&o, px);
        assert!(
            hit.y > 10.5 && hit.y < 20.0,
            "the ray passes the quad to the terrain: {hit}"
        );
        let want = display(lit(terrain_albedo(hit.x, hit.y), Vec3::Z));
        assert_close(
            pixel(&out.image, px),
            want,
            2.5,
            &format!("behind the cut-out at {w}"),
        );
    }
}

#[test]
fn rendering_is_deterministic() {
    let pack = build_pack(true);
    let a = render_pack(&pack, &options()).unwrap();
    let b = render_pack(&pack, &options()).unwrap();
    assert!(a.image.pixels == b.image.pixels, "two renders differ");
}

#[test]
fn default_camera_frames_every_instance() {
    let pack = build_pack(false);
    let opts = RenderOptions {
        eye: None,
        target: None,
        ..options()
    };
    let out = render_pack(&pack, &opts).unwrap();
    let s = &out.stats;
    assert!(s.analytic_sky);
    let o = Oracle::new(s.eye, s.target, s.fov_y_deg);
    // Whatever the framing, the opaque halves' centres are in view and unoccluded.
    for k in 0..2 {
        let p = instance_point(k, Vec3::new(-0.25, 0.0, 0.5));
        let got = pixel(&out.image, o.pixel(p));
        let want = display(lit(LEAF, instance_normal(k, o.eye)));
        assert_close(got, want, 2.5, &format!("instance {k} at {p}"));
    }
    // The analytic sky is blue above: the top row is bluer than it is red.
    let top = pixel(&out.image, (W / 2, 0));
    assert!(top[2] > top[0], "analytic sky at the top: {top:?}");
}

#[test]
fn a_pack_with_only_a_mesh_renders_it_at_the_origin() {
    let mut w = PackWriter::new();
    let leaf = bake::texture::source_section::texture_section_name("quad", "leaf.png");
    w.insert(texture::to_section(&leaf, "test", &leaf_texture()));
    w.insert(mesh::to_section(
        &bake::mesh::section::mesh_section_name("quad"),
        "test",
        &common::leaf_card(),
        &[Some(leaf)],
    ));
    let pack = Pack::from_bytes(&w.to_bytes().unwrap(), "mesh.bake").unwrap();
    let out = render_pack(
        &pack,
        &RenderOptions {
            eye: None,
            target: None,
            ..options()
        },
    )
    .unwrap();
    let s = &out.stats;
    assert_eq!(s.instances, 1);
    let o = Oracle::new(s.eye, s.target, s.fov_y_deg);
    let got = pixel(&out.image, o.pixel(Vec3::new(-0.25, 0.0, 0.5)));
    assert_close(got, display(lit(LEAF, Vec3::NEG_Y)), 2.5, "lone mesh");
}

#[test]
fn a_corrupt_instance_record_is_an_invalid_input_error() {
    let mut w = PackWriter::new();
    let mut inst = quad_instances();
    inst.items[1].model = 7;
    // Write the records by hand: to_section keeps what it is given.
    w.insert(instances::to_section(
        "instances",
        &inst,
        vec![bake::mesh::section::mesh_section_name("quad")],
    ));
    w.insert(mesh::to_section(
        &bake::mesh::section::mesh_section_name("quad"),
        "test",
        &common::leaf_card(),
        &[None],
    ));
    let pack = Pack::from_bytes(&w.to_bytes().unwrap(), "bad.bake").unwrap();
    let err = render_pack(&pack, &options()).unwrap_err();
    assert_eq!(err.exit_code(), bake::error::exit::INVALID_INPUT, "{err}");
    assert!(err.to_string().contains("instance 1"), "{err}");
}

/// The command line: a PNG of the requested size, the adapter in the JSON report, exit 0; a
/// missing pack is an I/O error (exit 3).
#[test]
fn bake_render_writes_a_png_and_reports_the_adapter() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = dir.path().join("scene.bake");
    let png = dir.path().join("scene.png");
    PackWriter::from_pack(&build_pack(true))
        .write(&pack_path)
        .unwrap();
    let bin = env!("CARGO_BIN_EXE_bake");
    let out = std::process::Command::new(bin)
        .args(["render", "--json", "--width", "64", "--height", "48", "-o"])
        .arg(&png)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        !doc["adapter"]["name"].as_str().unwrap().is_empty(),
        "{doc}"
    );
    assert_eq!(doc["stats"]["instances"], 2);
    assert_eq!(doc["stats"]["instances_per_level"], serde_json::json!([2]));
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (64, 48));

    // The LOD threshold: --no-lod is --lod-tau 0; a negative one is a usage error naming it.
    let no_lod = std::process::Command::new(bin)
        .args([
            "render", "--json", "--width", "64", "--height", "48", "--no-lod", "-o",
        ])
        .arg(&png)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert!(no_lod.status.success());
    let bad = std::process::Command::new(bin)
        .args(["render", "--lod-tau=-1", "-o"])
        .arg(&png)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(bake::error::exit::USAGE));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("LOD threshold"));

    let missing = std::process::Command::new(bin)
        .args(["render", "-o"])
        .arg(&png)
        .arg(dir.path().join("nope.bake"))
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(bake::error::exit::IO));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nope.bake"));
}

/// The generated fixture scene (`bake fixtures`), baked with `bake build` and rendered with the
/// default camera. Oracles: the fixture's analytic sky along each top-row ray, and placement: a
/// second render without the instances differs only inside the projected bounds of instances,
/// and most instances change some pixel inside their bounds.
#[test]
fn the_fixture_scene_renders_with_its_sky_and_every_instance_in_place() {
    use bake::fixtures::scene::sky_radiance;
    let dir = tempfile::tempdir().unwrap();
    bake::fixtures::write_all(dir.path()).unwrap();
    let out_path = dir.path().join("scene.bake");
    bake::graph::build(
        &bake::graph::BuildOptions {
            scenes: vec![dir.path().join("scene.eco")],
            output: Some(out_path.clone()),
            sky: Some(dir.path().join("sky.hdr")),
            cache: bake::graph::CacheMode::Off,
            ..Default::default()
        }
        .preview(),
        &bake::graph::progress::Silent,
    )
    .unwrap();
    let pack = Pack::open(&out_path).unwrap();
    let size = (320u32, 200u32);
    // Sky light only: the sun's shadows fall outside the instances' bounds (the direct term
    // is checked against the CPU reference in tests/render_reference.rs).
    let opts = RenderOptions {
        width: size.0,
        height: size.1,
        terms: bake::render::Terms::Ambient,
        ..RenderOptions::default()
    };
    let full = render_pack(&pack, &opts).unwrap();
    let s = &full.stats;
    let (_, inst) = instances::from_section(&pack.view_named("instances").unwrap()).unwrap();
    assert_eq!(s.instances as usize, inst.items.len());
    assert!(inst.items.len() >= 50);
    let o = Oracle::sized(s.eye, s.target, s.fov_y_deg, size);

    // The sky: the fixture's analytic radiance (the HDR file stores it RGBE-rounded, ~1 %).
    for px in (0..size.0).step_by(7) {
        let d = o.ray(px, 1);
        assert!(d.z > 0.0, "the top row looks at the sky");
        let want = display_at(sky_radiance(d.to_array()), s.exposure);
        assert_close(
            pixel(&full.image, (px, 1)),
            want,
            4.0,
            &format!("fixture sky at ({px}, 1)"),
        );
    }

    // The same pack without instances and meshes.
    let mut w = PackWriter::from_pack(&pack);
    w.remove_kind("instances");
    w.remove_kind("mesh");
    let bare_pack = Pack::from_bytes(&w.to_bytes().unwrap(), "bare.bake").unwrap();
    let bare = render_pack(
        &bare_pack,
        &RenderOptions {
            eye: Some(s.eye),
            target: Some(s.target),
            ..opts.clone()
        },
    )
    .unwrap();
    let boxes: Vec<[f32; 4]> = inst
        .items
        .iter()
        .map(|i| {
            let section = bake::mesh::section::mesh_section_name(&inst.models[i.model as usize]);
            let (_, m) = mesh::from_section(&pack.view_named(&section).unwrap()).unwrap();
            instance_screen_box(&o, i, &m)
        })
        .collect();
    let mut touched = vec![false; boxes.len()];
    let mut changed = 0;
    for y in 0..size.1 {
        for x in 0..size.0 {
            if pixel(&full.image, (x, y)) == pixel(&bare.image, (x, y)) {
                continue;
            }
            changed += 1;
            let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
            let mut inside = false;
            for (k, b) in boxes.iter().enumerate() {
                if fx >= b[0] - 1.0 && fx <= b[2] + 1.0 && fy >= b[1] - 1.0 && fy <= b[3] + 1.0 {
                    inside = true;
                    touched[k] = true;
                }
            }
            assert!(
                inside,
                "pixel ({x}, {y}) changed outside every instance's bounds"
            );
        }
    }
    let seen = touched.iter().filter(|&&t| t).count();
    assert!(changed > 200, "instances cover {changed} pixels");
    assert!(
        seen * 10 >= boxes.len() * 8,
        "only {seen} of {} instances visible",
        boxes.len()
    );
}

/// Screen rectangle [x0, y0, x1, y1] of an instance's model bounds, turned, scaled and moved
/// by the instance (written out here, not the renderer's code).
fn instance_screen_box(o: &Oracle, i: &Instance, m: &Mesh) -> [f32; 4] {
    let (lo, hi) = m.bounds().unwrap();
    let a = i.rotation_deg.to_radians();
    let mut b = [
        f32::INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NEG_INFINITY,
    ];
    for k in 0..8 {
        let c = Vec3::new(
            if k & 1 == 0 { lo[0] } else { hi[0] },
            if k & 2 == 0 { lo[1] } else { hi[1] },
            if k & 4 == 0 { lo[2] } else { hi[2] },
        ) * i.scale;
        let w = Vec3::new(
            a.cos() * c.x - a.sin() * c.y,
            a.sin() * c.x + a.cos() * c.y,
            c.z,
        ) + Vec3::from(i.position);
        let (x, y) = o.image_xy(w);
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    }
    b
}

/// A 64 m square terrain sloping as the plane z = 1 + 0.1 x + 0.05 y (bilinear interpolation
/// reproduces a plane exactly, so the height under any point is known), a random scatter of the
/// quad over it with coincident pairs, and, with `bittree`, the BitTree of `tree_of` (the
/// scatter itself unless a test passes a changed one).
fn scatter_pack(items: &[Instance], tree_of: Option<&[Instance]>) -> Pack {
    let n = 33u32;
    let plane = |x: f32, y: f32| 1.0 + 0.1 * x + 0.05 * y;
    let heights = (0..n)
        .flat_map(|j| (0..n).map(move |i| plane(i as f32 * 2.0, j as f32 * 2.0)))
        .collect();
    let t = Terrain {
        width: n,
        height: n,
        heights,
        origin: [0.0, 0.0],
        extent: [64.0, 64.0],
        color: None,
    };
    let mut w = PackWriter::new();
    w.insert(terrain::to_section("terrain", "test", &t, None));
    let mesh_name = insert_quad(&mut w);
    let inst = |items: &[Instance]| Instances {
        models: vec!["quad".into()],
        items: items.to_vec(),
    };
    w.insert(instances::to_section(
        "instances",
        &inst(items),
        vec![mesh_name],
    ));
    if let Some(tree) = tree_of {
        let area = bake::model::Rect {
            origin: [0.0, 0.0],
            extent: [64.0, 64.0],
        };
        w.insert(
            bake::bittree::section::to_section(
                "bittree",
                &inst(tree),
                area,
                &bake::bittree::BitTreeOptions::DEFAULT,
            )
            .unwrap(),
        );
    }
    Pack::from_bytes(&w.to_bytes().unwrap(), "scatter.bake").unwrap()
}

/// 2,000 instances at pseudo-random places, scales and rotations on the sloped terrain, the
/// first 40 repeated exactly (coincident instances, which share a BitTree leaf).
fn scatter() -> Vec<Instance> {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut items: Vec<Instance> = (0..2000)
        .map(|_| {
            let (x, y) = (next() * 64.0, next() * 64.0);
            Instance {
                model: 0,
                position: [x, y, 1.0 + 0.1 * x + 0.05 * y],
                scale: 0.5 + next(),
                rotation_deg: next() * 360.0,
                layer: (next() * 3.0) as i32,
            }
        })
        .collect();
    items.extend(items[..40].to_vec());
    items
}

/// Issue 16 item 3: with a `bittree` section the renderer reads the instances from it. Each
/// decoded instance stays in the cell of its record (|Δx|, |Δy| ≤ half a cell), stands on the
/// terrain (z the plane's height at the decoded point), keeps its scale, its layer and its
/// rotation to half a quantum (360°/2¹⁶); the coincident pairs decode to one point. A BitTree of
/// other positions is refused as stale, and both packs render.
#[test]
fn instances_are_decoded_from_the_bittree_at_load() {
    let items = scatter();
    let plain = scatter_pack(&items, None);
    let coded = scatter_pack(&items, Some(&items));
    let a = bake::render::scene::load_scene(&plain).unwrap();
    let b = bake::render::scene::load_scene(&coded).unwrap();
    use bake::render::scene::InstanceSource;
    assert_eq!(a.instance_source, InstanceSource::Instances);
    assert_eq!(b.instance_source, InstanceSource::Bittree);
    let meta: bake::bittree::section::BitTreeMeta =
        coded.view_named("bittree").unwrap().meta().unwrap();
    let cells = 4f32.powi(meta.levels as i32);
    let cell = [64.0 / cells, 64.0 / cells];
    let (ra, rb) = (&a.models[0].instances, &b.models[0].instances);
    assert_eq!(ra.len(), items.len());
    assert_eq!(rb.len(), items.len());
    let mut moved = 0.0f32;
    for (k, (p, q)) in ra.iter().zip(rb).enumerate() {
        for (i, c) in cell.iter().enumerate() {
            let d = (p.position[i] - q.position[i]).abs();
            assert!(d <= 0.5 * c * 1.0001, "instance {k}: {d} m off in axis {i}");
            moved = moved.max(d);
        }
        let z = 1.0 + 0.1 * q.position[0] + 0.05 * q.position[1];
        assert!(
            (q.position[2] - z).abs() < 1e-4,
            "instance {k}: z {}",
            q.position[2]
        );
        assert_eq!(p.scale, q.scale);
        assert_eq!(p.layer, q.layer);
        let turn = (p.rotation_deg - q.rotation_deg).rem_euclid(360.0);
        assert!(
            turn.min(360.0 - turn) <= 0.5 * 360.0 / 65536.0 + 1e-4,
            "instance {k}"
        );
    }
    for k in 0..40 {
        assert_eq!(rb[k].position, rb[2000 + k].position, "coincident pair {k}");
    }
    eprintln!(
        "{} levels, cell {:.4} m, largest offset {moved:.4} m",
        meta.levels, cell[0]
    );
    assert!(moved > 0.0, "the decoded positions are the records' own");

    let mut other = items.clone();
    other[7].position[0] = (other[7].position[0] + 20.0) % 64.0;
    let stale = scatter_pack(&items, Some(&other));
    let e = bake::render::scene::load_scene(&stale)
        .expect_err("a stale BitTree is refused")
        .to_string();
    assert!(e.contains("bittree") && e.contains("stale"), "{e}");

    let opts = RenderOptions {
        eye: Some([32.0, -20.0, 30.0]),
        target: Some([32.0, 32.0, 4.0]),
        ..options()
    };
    let ga = render_pack(&plain, &opts).unwrap();
    let gb = render_pack(&coded, &opts).unwrap();
    assert_eq!(gb.stats.instances_from, InstanceSource::Bittree);
    assert_eq!(ga.stats.instances, gb.stats.instances);
}

/// `RenderOptions::linear`: the radiance before the tone map, per term. Oracles: the Lambert
/// terrain of `lit` (linear, no tone map), the tone map of those values giving the PNG's bytes,
/// and direct + ambient = all on the terrain (the sky is drawn in every term).
#[test]
fn the_linear_image_is_the_radiance_before_the_tone_map_per_term() {
    let pack = build_pack(true);
    let o = Oracle::new(EYE, TARGET, FOV);
    let render = |terms| {
        render_pack(
            &pack,
            &RenderOptions {
                terms,
                linear: true,
                ..options()
            },
        )
        .unwrap()
    };
    let all = render(bake::render::Terms::All);
    let lin = all.linear.as_ref().expect("linear image");
    assert_eq!((lin.width, lin.height), (W, H));
    let at = |img: &FloatImage, (x, y): (u32, u32)| img.pixels[(y * img.width + x) as usize];
    for (x, y) in [(3.0f32, 3.0f32), (16.0, 4.0), (19.5, 19.0)] {
        let px = o.pixel(Vec3::new(x, y, 0.0));
        let hit = ground_hit(&o, px);
        let want = lit(terrain_albedo(hit.x, hit.y), Vec3::Z);
        let got = at(lin, px);
        for k in 0..3 {
            assert!(
                (got[k] - want[k]).abs() <= 0.01 * want[k] + 2e-3,
                "terrain at ({x}, {y}): linear {got:?}, Lambert {want:?}"
            );
        }
        assert_close(
            pixel(&all.image, px),
            display(got),
            1.0,
            "tone map of the linear value",
        );
    }
    let direct = render(bake::render::Terms::Direct);
    let ambient = render(bake::render::Terms::Ambient);
    let (d, a) = (direct.linear.unwrap(), ambient.linear.unwrap());
    let px = o.pixel(Vec3::new(3.0, 3.0, 0.0));
    for k in 0..3 {
        let (s, t) = (at(&d, px)[k] + at(&a, px)[k], at(lin, px)[k]);
        assert!(
            (s - t).abs() <= 1e-3 * t + 1e-4,
            "direct + ambient {s} ≠ all {t}"
        );
        assert!(at(&d, px)[k] > 0.0 && at(&a, px)[k] > 0.0);
    }
    // Without the option there is no readback.
    assert!(render_pack(&pack, &options()).unwrap().linear.is_none());
}

/// `RenderOptions::regions`: the sky is (0, 0, 0), the terrain (1, 0, 0), the alpha-tested quad
/// (a leaf card) (0, 0, 1) where its texels are opaque and the terrain behind its cut-out half.
#[test]
fn the_region_image_tells_sky_terrain_and_leaves_apart() {
    let out = render_pack(
        &build_pack(true),
        &RenderOptions {
            regions: true,
            ..options()
        },
    )
    .unwrap();
    let reg = out.regions.expect("region image");
    let o = Oracle::new(EYE, TARGET, FOV);
    let at = |(x, y): (u32, u32)| reg.pixels[(y * reg.width + x) as usize];
    let near = |got: [f32; 3], want: [f32; 3], what: &str| {
        assert!(
            (0..3).all(|k| (got[k] - want[k]).abs() < 1e-3),
            "{what}: {got:?}, want {want:?}"
        );
    };
    near(at((W / 2, 0)), [0.0; 3], "the sky (top row)");
    near(
        at(o.pixel(Vec3::new(3.0, 3.0, 0.0))),
        [1.0, 0.0, 0.0],
        "terrain",
    );
    for k in 0..2 {
        let opaque = instance_point(k, Vec3::new(-0.3, 0.0, 0.5));
        near(
            at(o.pixel(opaque)),
            [0.0, 0.0, 1.0],
            "the leaf card's opaque half",
        );
        let cut = instance_point(k, Vec3::new(0.3, 0.0, 0.5));
        near(at(o.pixel(cut)), [1.0, 0.0, 0.0], "behind the cut-out half");
    }
    // Every pixel's coverages sum to at most 1.
    assert!(
        reg.pixels
            .iter()
            .all(|p| p.iter().sum::<f32>() <= 1.0 + 1e-3)
    );
}

/// `bake render -o X.exr` writes the linear radiance as OpenEXR (and `--regions` beside it);
/// `bake mitsuba` writes the placed scene for the ground-truth harness.
#[test]
fn bake_render_writes_linear_exr_and_bake_mitsuba_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let pack_path = dir.path().join("scene.bake");
    PackWriter::from_pack(&build_pack(true))
        .write(&pack_path)
        .unwrap();
    let bin = env!("CARGO_BIN_EXE_bake");
    let (exr, regions) = (dir.path().join("a.exr"), dir.path().join("r.png"));
    let out = std::process::Command::new(bin)
        .args([
            "render", "--width", "64", "--height", "48", "--terms", "direct",
        ])
        .args([
            "--eye", "10,-10,8", "--target", "10,10,3", "--fov", "60", "-o",
        ])
        .arg(&exr)
        .arg("--regions")
        .arg(&regions)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = exr::prelude::read_first_rgba_layer_from_file(
        &exr,
        |res, _| vec![[0.0f32; 3]; res.width() * res.height()],
        |px: &mut Vec<[f32; 3]>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * 64 + pos.x()] = [r, g, b];
        },
    )
    .unwrap();
    let px = &img.layer_data.channel_data.pixels;
    assert_eq!(px.len(), 64 * 48);
    // Linear radiance, finite; the sky's pixels hold the sky's radiance along their rays.
    assert!(
        px.iter()
            .all(|p| p.iter().all(|v| v.is_finite() && *v >= 0.0))
    );
    let o = Oracle::sized(EYE, TARGET, FOV, (64, 48));
    for x in [5u32, 32, 60] {
        let want = sky_along(o.ray(x, 0));
        let got = px[x as usize];
        assert!(
            (0..3).all(|k| (got[k] - want[k]).abs() <= 0.02 * want[k] + 1e-3),
            "sky at ({x}, 0): {got:?}, want {want:?}"
        );
    }
    let r = image::open(&regions).unwrap().to_rgb8();
    assert_eq!(r.get_pixel(32, 0).0, [0, 0, 0], "sky");
    let (tx, ty) = o.pixel(Vec3::new(10.0, 5.0, 0.0));
    assert_eq!(r.get_pixel(tx, ty).0, [255, 0, 0], "terrain");

    let mdir = dir.path().join("mitsuba");
    let out = std::process::Command::new(bin)
        .args(["mitsuba", "--json", "--width", "64", "--height", "48"])
        .args(["--eye", "10,-10,8", "--target", "10,10,3", "-o"])
        .arg(&mdir)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["instances"], 2);
    assert_eq!(doc["terrain_triangles"], 32);
    assert_eq!(doc["masked_materials"], 1);
    // By default every instance is placed into one world-space mesh per model and material.
    let geo = std::fs::read_to_string(mdir.join("geometry.xml")).unwrap();
    assert_eq!(geo.matches("type=\"instance\"").count(), 0);
    assert!(geo.contains("type=\"mask\""), "{geo}");
    let ply = std::fs::read(mdir.join("meshes/m0_0.ply")).unwrap();
    assert!(String::from_utf8_lossy(&ply[..400]).contains("element vertex 8\n"));
    let out = std::process::Command::new(bin)
        .args([
            "mitsuba",
            "--shapegroups",
            "--eye",
            "10,-10,8",
            "--target",
            "10,10,3",
            "-o",
        ])
        .arg(&mdir)
        .arg(&pack_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let geo = std::fs::read_to_string(mdir.join("geometry.xml")).unwrap();
    assert_eq!(geo.matches("type=\"instance\"").count(), 2);
    let scene = std::fs::read_to_string(mdir.join("scene.xml")).unwrap();
    assert!(
        scene.contains("lookat origin=\"1e1, -1e1, 8e0\""),
        "{scene}"
    );
    for f in [
        "direct.xml",
        "sky.exr",
        "meshes/terrain.ply",
        "meshes/m0_0.ply",
    ] {
        assert!(mdir.join(f).exists(), "{f}");
    }
}
