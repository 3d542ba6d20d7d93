//! `bake render PACK --view svo`: the pack's `svo` section drawn by a compute-shader ray march
//! ([`crate::voxel::lod_gpu`]) that stops at the filtered parents, the level chosen by distance
//! ([`crate::voxel::lod_trace`] holds the rule), and the same rays traced on the CPU for the
//! reference image.
//!
//! Rays: one per pixel centre from the render camera ([`super::camera::Camera::ray`]; default: the
//! grid's world bounds framed as [`super::camera::Camera::frame_box`] frames a scene), moved to
//! voxel units and normalized there, so t is a distance in voxels (the grid's voxels are cubic,
//! as [`crate::voxel::Grid::fit`] makes them). The cone is `lod_scale · 2 tan(fov_y / 2) /
//! height`, the angle one pixel spans at the image centre: at lod scale 1 a cell stops the
//! descent once it is no wider than the pixel where the ray enters it.
//!
//! Shading ([`shade`], the same function for the GPU's and the CPU's answers, so the images
//! differ only where the traversals do): `colour` is the cell's un-premultiplied colour ×
//! ([`AMBIENT`] + (1 − [`AMBIENT`]) · max(N·L, 0)), N turned towards the viewer, L the pack's
//! sun direction (its `sun` section) or [`DEFAULT_LIGHT`], written sRGB-encoded; `normal` is the
//! stored normal as (N + 1) / 2 in RGB; `level` is [`LEVEL_PALETTE`]`[level]`. Misses are
//! [`BACKGROUND`].

use super::camera::Camera;
use crate::error::{Error, Result};
use crate::model::Rgba8Image;
use crate::pack::Pack;
use crate::voxel::Grid;
use crate::voxel::instanced::SceneHit;
use crate::voxel::lod_trace::{LodHit, trace_lod};
use crate::voxel::svo::Svo;
use crate::voxel::traverse::VoxelRay;
use glam::Vec3;
use rayon::prelude::*;

/// What `--view svo` shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SvoShow {
    /// The filtered colour, lit.
    #[default]
    Colour,
    /// The filtered normal as RGB.
    Normal,
    /// The level each pixel stopped at, as a palette colour.
    Level,
}

/// Options of the SVO view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SvoViewOptions {
    pub show: SvoShow,
    /// Factor on the pixel's cone: 0 always descends to the voxels, larger stops coarser.
    pub lod_scale: f32,
}

/// Default [`SvoViewOptions::lod_scale`].
pub const DEFAULT_LOD_SCALE: f32 = 1.0;
/// Ambient fraction of the `colour` shading.
pub const AMBIENT: f32 = 0.3;
/// Unit vector towards the light when the pack has no `sun` section.
pub const DEFAULT_LIGHT: [f32; 3] = [0.36, -0.48, 0.8];
/// Colour of pixels whose ray misses every cell.
pub const BACKGROUND: [u8; 4] = [40, 44, 52, 255];
/// sRGB colour per level (0: the root; an octree has at most 12 levels, root to voxel).
pub const LEVEL_PALETTE: [[u8; 3]; 12] = [
    [230, 25, 75],
    [245, 130, 48],
    [255, 225, 25],
    [60, 180, 75],
    [70, 240, 240],
    [0, 130, 200],
    [145, 30, 180],
    [240, 50, 230],
    [250, 190, 212],
    [170, 110, 40],
    [128, 128, 0],
    [255, 255, 255],
];

/// The octree and the rays of one view, shared by the GPU and the CPU pass.
#[derive(Debug, Clone)]
pub struct SvoScene {
    pub svo: Svo,
    pub camera: Camera,
    /// Per pixel, row 0 at the top: the ray in voxel units, unit direction.
    pub rays: Vec<VoxelRay>,
    /// The footprint of every ray at t is `cone · t` voxels.
    pub cone: f32,
    /// Unit vector towards the light of the `colour` shading, and where it came from.
    pub light: [f32; 3],
    pub light_from_sun: bool,
    pub size: (u32, u32),
    pub opts: SvoViewOptions,
}

/// What a view's traversal found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SvoViewStats {
    pub width: u32,
    pub height: u32,
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub fov_y_deg: f32,
    pub show: SvoShow,
    pub lod_scale: f32,
    pub cone: f32,
    /// Octree levels L (a voxel is level L, the root 0).
    pub levels: u32,
    pub light: [f32; 3],
    pub light_from_sun: bool,
    pub hits: u64,
    /// Pixels that stopped at each level 0..=L.
    pub pixels_per_level: Vec<u64>,
    /// Mean distance from the eye (metres) of those pixels' hits, per level (0 where none).
    pub mean_distance_per_level: Vec<f64>,
}

/// The `svo` section of `pack`, and the view of `opts` over it (see the module documentation).
pub fn prepare_svo_view(
    pack: &Pack,
    opts: &super::RenderOptions,
    view: SvoViewOptions,
) -> Result<SvoScene> {
    super::check_options(opts)?;
    if !(view.lod_scale >= 0.0 && view.lod_scale.is_finite()) {
        return Err(Error::usage(format!(
            "svo lod scale {} must be 0 or more",
            view.lod_scale
        )));
    }
    let entry = pack
        .of_kind(crate::voxel::section::KIND)
        .next()
        .ok_or_else(|| {
            let two_level = pack
                .of_kind(crate::voxel::instanced_section::KIND)
                .next()
                .is_some();
            Error::invalid_at(
                pack.path(),
                "section table",
                if two_level {
                    "no svo section for the LOD view: the pack holds the two-level svo-scene \
                     section (written where the flattened scene exceeds --max-memory), which \
                     `bake render --view svo` draws at its voxels (prepare_scene_view)"
                } else {
                    "no svo section to render (run `bake svo` first)"
                },
            )
        })?;
    let (_, svo) = crate::voxel::section::from_section(&pack.view(entry)?)
        .map_err(|e| Error::invalid(pack.path(), e))?;
    let g = svo.grid;
    let hi = [0, 1, 2].map(|k| g.origin[k] + g.dims[k] as f32 * g.voxel_size[k]);
    let aspect = opts.width as f32 / opts.height as f32;
    let camera = super::camera_for_bounds(g.origin, hi, opts, aspect);
    let size = (opts.width, opts.height);
    let sun = pack
        .view_named(crate::sky::SUN_SECTION)
        .ok()
        .and_then(|v| crate::sky::section::sun_from_section(&v).ok());
    let (light, light_from_sun) = match sun {
        Some(s) => (
            Vec3::from(s.direction).normalize_or(Vec3::Z).to_array(),
            true,
        ),
        None => (Vec3::from(DEFAULT_LIGHT).normalize().to_array(), false),
    };
    Ok(SvoScene {
        rays: pixel_rays(&camera, &g, size),
        cone: pixel_cone(&camera, opts.height, view.lod_scale),
        svo,
        camera,
        light,
        light_from_sun,
        size,
        opts: view,
    })
}

/// `lod_scale` × the angle one pixel spans at the image centre, `2 tan(fov_y / 2) / height`: the
/// footprint of a ray at distance t is `cone · t` (in voxels, or metres, alike).
pub fn pixel_cone(cam: &Camera, height: u32, lod_scale: f32) -> f32 {
    lod_scale * 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / height as f32
}

/// The centre of pixel `i` (row-major, `w` wide) in pixels from the top-left corner.
fn pixel_centre(i: u32, w: u32) -> (f32, f32) {
    ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5)
}

/// One ray per pixel centre in voxel units, unit direction, row 0 at the top.
pub fn pixel_rays(cam: &Camera, grid: &Grid, (w, h): (u32, u32)) -> Vec<VoxelRay> {
    let origin = grid.to_grid(cam.eye.to_array());
    (0..w * h)
        .map(|i| {
            let d = cam.pixel_ray(pixel_centre(i, w), (w, h));
            let dv = Vec3::from([0, 1, 2].map(|k| d[k] / grid.voxel_size[k])).normalize();
            VoxelRay {
                origin,
                dir: dv.to_array(),
                t_min: 0.0,
                t_max: f32::MAX,
            }
        })
        .collect()
}

/// The CPU traversal of every ray ([`trace_lod`]).
pub fn trace_cpu(scene: &SvoScene) -> Vec<Option<LodHit>> {
    scene
        .rays
        .par_iter()
        .map(|r| trace_lod(&scene.svo, r, scene.cone))
        .collect()
}

/// One pixel of the view (see the module documentation); `dir` is the ray's world direction.
pub fn shade(hit: Option<&LodHit>, show: SvoShow, light: [f32; 3], dir: Vec3) -> [u8; 4] {
    let Some(h) = hit else {
        return BACKGROUND;
    };
    let n = Vec3::from(h.normal());
    let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    match show {
        SvoShow::Colour => {
            let c = h.straight_color();
            let facing = if n.dot(dir) > 0.0 { -n } else { n };
            let e = AMBIENT + (1.0 - AMBIENT) * facing.dot(Vec3::from(light)).max(0.0);
            let s = |v: f32| byte(crate::color::linear_to_srgb((v * e).clamp(0.0, 1.0)));
            [s(c[0]), s(c[1]), s(c[2]), 255]
        }
        SvoShow::Normal => {
            let m = (n + Vec3::ONE) * 0.5;
            [byte(m.x), byte(m.y), byte(m.z), 255]
        }
        SvoShow::Level => {
            let p = LEVEL_PALETTE[(h.level as usize).min(LEVEL_PALETTE.len() - 1)];
            [p[0], p[1], p[2], 255]
        }
    }
}

/// The image of a view's answers.
pub fn shade_image(scene: &SvoScene, hits: &[Option<LodHit>]) -> Rgba8Image {
    let (w, h) = scene.size;
    let pixels = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let dir = scene.camera.pixel_ray(pixel_centre(i, w), (w, h));
            shade(hits[i as usize].as_ref(), scene.opts.show, scene.light, dir)
        })
        .collect();
    Rgba8Image {
        width: w,
        height: h,
        pixels,
    }
}

/// Levels and distances of a view's answers.
pub fn view_stats(scene: &SvoScene, hits: &[Option<LodHit>]) -> SvoViewStats {
    let levels = scene.svo.levels;
    let mut count = vec![0u64; levels as usize + 1];
    let mut dist = vec![0.0f64; levels as usize + 1];
    // t is in voxels (unit direction in voxel units, cubic voxels).
    let voxel = scene.svo.grid.voxel_size[0] as f64;
    for h in hits.iter().flatten() {
        let l = (h.level as usize).min(levels as usize);
        count[l] += 1;
        dist[l] += h.t as f64 * voxel;
    }
    for (d, &n) in dist.iter_mut().zip(&count) {
        *d = if n > 0 { *d / n as f64 } else { 0.0 };
    }
    SvoViewStats {
        width: scene.size.0,
        height: scene.size.1,
        eye: scene.camera.eye.to_array(),
        target: scene.camera.target.to_array(),
        fov_y_deg: scene.camera.fov_y_deg,
        show: scene.opts.show,
        lod_scale: scene.opts.lod_scale,
        cone: scene.cone,
        levels,
        light: scene.light,
        light_from_sun: scene.light_from_sun,
        hits: count.iter().sum(),
        pixels_per_level: count,
        mean_distance_per_level: dist,
    }
}

/// The GPU render of a view: the traversal on the device, then [`shade_image`].
pub struct SvoRender {
    pub image: Rgba8Image,
    pub hits: Vec<Option<LodHit>>,
    pub adapter: super::AdapterSummary,
    pub seconds: f64,
}

/// Traces the view's rays with the compute kernel and shades them.
pub fn render_svo(scene: &SvoScene, backend: super::BackendChoice) -> Result<SvoRender> {
    let gpu = crate::gpu::init_gpu(backend)?;
    let t0 = std::time::Instant::now();
    let dev = crate::voxel::lod_gpu::SvoLodGpu::new(&gpu, &scene.svo)?;
    let hits = dev.trace(&scene.rays, scene.cone)?;
    let seconds = t0.elapsed().as_secs_f64();
    Ok(SvoRender {
        image: shade_image(scene, &hits),
        hits,
        adapter: gpu.adapter.clone(),
        seconds,
    })
}

/// The two-level `svo-scene` section of a pack: one world ray per pixel centre from the camera
/// framing the scene grid, walked with the pixel's cone ([`pixel_cone`] × `--svo-lod-scale`, in
/// metres per metre: the rays' directions are unit vectors) on the GPU
/// (`voxel::instanced_gpu`) or the CPU (`InstancedSvo::trace_lod`): a top cell or sub-cell no
/// wider than the footprint where the ray enters it ends the walk on its filtered aggregate,
/// nearer ones descend into their instances' octrees, where the same rule stops on a model's
/// filtered node (its side × |scale| × the model's voxel side against the footprint) or reaches
/// a voxel. Shaded as [`shade`] shades a cell: an aggregate's or node's colour
/// un-premultiplied and its world normal (a node's turned by the instance's rotation); a
/// voxel's colour and its turned normal; `level` shows 0 for a top cell, 1 for a sub-cell, a
/// model node's level in its octree (at least 2) and the model's voxel level (its octree's
/// `levels`, at least 2) for a voxel.
pub struct SceneView {
    pub scene: crate::voxel::instanced::InstancedSvo,
    pub camera: Camera,
    pub rays: Vec<crate::voxel::instanced_gpu::WorldRay>,
    pub light: [f32; 3],
    pub size: (u32, u32),
    pub show: SvoShow,
    /// Footprint per metre along a ray, in metres (0: the voxels).
    pub cone: f32,
}

/// The `svo-scene` section of `pack` and the view of `opts` over it, or None without one.
pub fn prepare_scene_view(
    pack: &Pack,
    opts: &super::RenderOptions,
    view: SvoViewOptions,
) -> Result<Option<SceneView>> {
    if !(view.lod_scale >= 0.0 && view.lod_scale.is_finite()) {
        return Err(Error::usage(format!(
            "svo lod scale {} must be 0 or more",
            view.lod_scale
        )));
    }
    let Some(e) = pack.of_kind(crate::voxel::instanced_section::KIND).next() else {
        return Ok(None);
    };
    let (_, scene) = crate::voxel::instanced_section::from_section(&pack.view(e)?)
        .map_err(|err| Error::invalid(pack.path(), err))?;
    let g = scene.scene_grid;
    let hi = g.to_world(g.dims.map(|d| d as f32));
    let aspect = opts.width as f32 / opts.height as f32;
    let camera = super::camera_for_bounds(g.origin, hi, opts, aspect);
    let (w, h) = (opts.width, opts.height);
    let eye = camera.eye.to_array();
    let rays = (0..w * h)
        .map(|i| {
            let d = camera.pixel_ray(pixel_centre(i, w), (w, h)).to_array();
            (eye, d, [0.0, f32::INFINITY])
        })
        .collect();
    let light = pack
        .view_named(crate::sky::SUN_SECTION)
        .ok()
        .and_then(|v| crate::sky::section::sun_from_section(&v).ok())
        .map_or(Vec3::from(DEFAULT_LIGHT).normalize(), |s| {
            Vec3::from(s.direction).normalize_or(Vec3::Z)
        })
        .to_array();
    Ok(Some(SceneView {
        scene,
        cone: pixel_cone(&camera, h, view.lod_scale),
        camera,
        rays,
        light,
        size: (w, h),
        show: view.show,
    }))
}

/// The CPU's answers of a [`SceneView`].
pub fn trace_scene_cpu(v: &SceneView) -> Vec<Option<SceneHit>> {
    v.rays
        .par_iter()
        .map(|(o, d, t)| v.scene.trace_lod(*o, *d, *t, v.cone))
        .collect()
}

/// A [`SceneView`] answer as the cell [`shade`] draws (None where a voxel has no attributes).
pub fn scene_cell(v: &SceneView, hit: &SceneHit) -> Option<LodHit> {
    use crate::voxel::svo::{pack_normal, pack_rgba8};
    match hit {
        SceneHit::Voxel(hit) => {
            let (c, n) = v.scene.hit_attributes(hit)?;
            let model = v.scene.instances[hit.instance as usize].model as usize;
            Some(LodHit {
                level: v.scene.models[model].svo.levels,
                cell: hit.voxel,
                t: hit.t,
                color: pack_rgba8([c[0] * c[3], c[1] * c[3], c[2] * c[3], c[3]]),
                normal: pack_normal(n),
                attr: 0,
            })
        }
        SceneHit::Node(hit) => {
            let (_, n) = v.scene.node_attributes(hit)?;
            let model = v.scene.instances[hit.instance as usize].model as usize;
            let svo = &v.scene.models[model].svo;
            Some(LodHit {
                // Below the voxels' level by the node's height above them, at least 2 (0 and 1
                // are the top level's).
                level: hit.level.max(2),
                cell: hit.cell,
                t: hit.t,
                color: svo.node_colors[hit.attr as usize],
                normal: pack_normal(n),
                attr: hit.attr,
            })
        }
        SceneHit::Aggregate(a) => Some(LodHit {
            level: a.level,
            cell: [a.attr, 0, 0],
            t: a.t,
            color: v.scene.aggregates.colors[a.attr as usize],
            normal: v.scene.aggregates.normals[a.attr as usize],
            attr: a.attr,
        }),
    }
}

/// The image of a [`SceneView`]'s answers.
pub fn shade_scene(v: &SceneView, hits: &[Option<SceneHit>]) -> Rgba8Image {
    let (w, h) = v.size;
    let pixels = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let Some(cell) = hits[i as usize].as_ref().and_then(|h| scene_cell(v, h)) else {
                return BACKGROUND;
            };
            let dir = v.camera.pixel_ray(pixel_centre(i, w), (w, h));
            shade(Some(&cell), v.show, v.light, dir)
        })
        .collect();
    Rgba8Image {
        width: w,
        height: h,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(level: u32, color: [f32; 4], normal: [f32; 3]) -> LodHit {
        LodHit {
            level,
            cell: [0; 3],
            t: 1.0,
            color: crate::voxel::svo::pack_rgba8(color),
            normal: crate::voxel::svo::pack_normal(normal),
            attr: 0,
        }
    }

    #[test]
    fn the_cone_spans_one_pixel_and_the_rays_pass_through_the_pixel_centres() {
        let cam = Camera::look_at(
            Vec3::new(1.0, -10.0, 3.0),
            Vec3::new(0.0, 5.0, 0.0),
            45.0,
            1.6,
        );
        let (w, h) = (32u32, 20u32);
        // Two points cone·t apart across the central ray project one pixel apart.
        let cone = pixel_cone(&cam, h, 1.0);
        let b = cam.basis();
        let vp = cam.view_proj();
        for t in [2.0f32, 7.0, 40.0] {
            let p = cam.eye + b.forward * t;
            let q = p + b.up * (cone * t);
            let pixels = (vp.project_point3(q).y - vp.project_point3(p).y) * 0.5 * h as f32;
            assert!((pixels - 1.0).abs() < 1e-3, "t {t}: {pixels} px");
        }
        assert_eq!(pixel_cone(&cam, h, 3.0), 3.0 * cone);
        // Rays in the voxels of a non-unit grid: unit directions whose points project back to
        // the pixel centres.
        let grid = Grid {
            origin: [-4.0, 2.0, -1.0],
            voxel_size: [0.25; 3],
            dims: [64, 64, 16],
        };
        let rays = pixel_rays(&cam, &grid, (w, h));
        assert_eq!(rays.len(), (w * h) as usize);
        for (i, r) in rays.iter().enumerate() {
            let l: f32 = r.dir.iter().map(|d| d * d).sum::<f32>().sqrt();
            assert!((l - 1.0).abs() < 1e-5);
            let g = [0, 1, 2].map(|k| r.origin[k] + r.dir[k] * 30.0);
            let p = vp.project_point3(Vec3::from(grid.to_world(g)));
            let (x, y) = ((p.x + 1.0) * 0.5 * w as f32, (1.0 - p.y) * 0.5 * h as f32);
            let (px, py) = ((i as u32 % w) as f32 + 0.5, (i as u32 / w) as f32 + 0.5);
            assert!(
                (x - px).abs() < 1e-3 && (y - py).abs() < 1e-3,
                "{i}: {x},{y}"
            );
        }
    }

    #[test]
    fn shading_follows_the_documented_formulas() {
        let l = [0.0, 0.0, 1.0];
        let down = Vec3::new(0.0, 0.0, -1.0);
        // Premultiplied (0.2, 0.1, 0, 0.4): straight (0.5, 0.25, 0); lit fully from above.
        let h = hit(3, [0.2, 0.1, 0.0, 0.4], [0.0, 0.0, 1.0]);
        let want = |v: f32| (crate::color::linear_to_srgb(v) * 255.0 + 0.5) as u8;
        let px = shade(Some(&h), SvoShow::Colour, l, down);
        assert!(
            px[0].abs_diff(want(0.5)) <= 1 && px[1].abs_diff(want(0.25)) <= 1,
            "{px:?}"
        );
        assert_eq!(px[2], 0);
        // A normal facing away from the viewer is turned towards it: the same pixel.
        let back = hit(3, [0.2, 0.1, 0.0, 0.4], [0.0, 0.0, -1.0]);
        assert_eq!(shade(Some(&back), SvoShow::Colour, l, down), px);
        // Lit from the side: ambient alone.
        let side = shade(Some(&h), SvoShow::Colour, [1.0, 0.0, 0.0], down);
        assert!(side[0].abs_diff(want(0.5 * AMBIENT)) <= 1, "{side:?}");
        assert_eq!(
            shade(Some(&h), SvoShow::Normal, l, down),
            [128, 128, 255, 255]
        );
        let lv = shade(Some(&h), SvoShow::Level, l, down);
        assert_eq!(lv[..3], LEVEL_PALETTE[3]);
        assert_eq!(shade(None, SvoShow::Level, l, down), BACKGROUND);
    }
}
