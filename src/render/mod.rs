//! The wgpu runtime stage: renders a pack offscreen to an image, proving that its arrays go
//! straight into GPU buffers and come out as a picture.
//!
//! Order of work, each step its own module so later issues can swap one: [`scene`] reads and
//! checks the pack on the CPU; [`gpu`] opens a device (a real GPU, or Mesa's lavapipe/llvmpipe);
//! [`pipelines`] builds the passes; [`upload`] moves the arrays to the GPU; [`draw`] renders the
//! sky, the terrain and the instanced models into an `Rgba16Float` target and tone-maps it
//! (1 − exp(−L·s), then sRGB) into the output. [`light`] and [`camera`] hold the conventions.
//! [`cull`] and [`levels`] choose each instance's level; [`impostor`] draws the instances the
//! LOD rule gives the impostor atlas (quads, the nearest of the atlas' views, no blend: its
//! module documentation holds the rules). [`svo_view`] is the other view mode: the `svo`
//! section ray-marched by a compute shader at a level chosen by distance.

pub mod ambient;
pub mod ambient_gpu;
pub mod camera;
pub mod coverage;
pub mod cull;
pub mod draw;
pub mod impostor;
pub mod levels;
pub mod light;
pub mod pipelines;
pub mod reference;
pub mod sample;
pub mod scene;
pub mod shadow;
pub mod skeleton;
pub mod soft_shadow;
pub mod svo_view;
pub mod terrain_lod;
pub mod upload;

use crate::error::{Error, Result};
pub use crate::gpu::{AdapterSummary, BackendChoice};
use crate::model::Rgba8Image;
use crate::pack::Pack;
use glam::Vec3;
pub use light::Lighting;

/// Options of [`render_pack`].
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    pub width: u32,
    pub height: u32,
    /// Camera position; default: framing the area of interest (see [`camera::Camera::frame_box`]).
    pub eye: Option<[f32; 3]>,
    /// Point looked at; default: the centre of the area of interest.
    pub target: Option<[f32; 3]>,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    /// Tone-map exposure s in 1 − exp(−L·s); default: [`light::auto_exposure`].
    pub exposure: Option<f32>,
    /// Sun, sky ambient; default: [`light::default_lighting`] of the sky.
    pub lighting: Option<Lighting>,
    pub backend: BackendChoice,
    /// PRT layout the ambient term evaluates (see [`ambient`]).
    pub prt_layout: ambient::PrtLayout,
    /// The sun's visibility from the line-space soft shadows (needs a `linespace` section).
    pub soft_shadows: Option<soft_shadow::SoftShadows>,
    /// Which light terms to draw (the shading contract: L = L_direct + L_ambient).
    pub terms: Terms,
    /// Pixel threshold τ of the LOD rule ([`crate::lod::select`]): each instance draws the
    /// coarsest level whose projected error is at most τ pixels; 0 draws full detail.
    pub lod_tau: f32,
    /// Cascades of the sun's shadow map, 1 to [`shadow::MAX_CASCADES`] (1: one map over the
    /// whole scene).
    pub shadow_cascades: u32,
    /// Samples per pixel of the scene pass: 1, or [`MSAA_SAMPLES`] (multisampling with alpha
    /// to coverage on alpha-tested leaf cards).
    pub msaa: u32,
    /// Display encoding of the tone-mapped value L_s (see [`Encoding`]).
    pub encoding: Encoding,
    /// Toksvig's roughness from the normal map's filtered length |n̄| (on by default; off draws
    /// the renormalized mip normals with the material's own roughness).
    pub toksvig: bool,
    /// Parallax mapping from the colour maps' height chains (seed 000 §4.7.3; off by default).
    pub parallax: bool,
    /// Also read back the linear radiance before the tone map ([`RenderOutput::linear`]).
    pub linear: bool,
    /// Also draw the region image ([`RenderOutput::regions`]): a second scene pass.
    pub regions: bool,
}

/// The multisample count of `--msaa` (the one count every WebGPU device supports beside 1).
pub const MSAA_SAMPLES: u32 = 4;

/// How the tone-mapped L_s = 1 − exp(−L·s) in [0, 1] is written to the 8-bit image.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase", tag = "kind", content = "gamma")]
pub enum Encoding {
    /// The sRGB transfer function (IEC 61966-2-1), the default.
    Srgb,
    /// The thesis' L_g = L_s^γ (seed 000 §4.7.4, eq. 4.10), written as 8-bit values without
    /// further encoding: γ = 1/2.2 ≈ 0.4545 is the classic CRT correction, other values darken
    /// (γ > 1/2.2) or lighten the image on purpose.
    Gamma(f32),
}

/// Default [`RenderOptions::lod_tau`], pixels.
pub const DEFAULT_LOD_TAU: f32 = 1.0;

/// Which terms of `L = L_direct + L_ambient` a render draws (the sky background is always drawn).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Terms {
    #[default]
    All,
    /// The sun alone: E_sun · visibility · BRDF · cos.
    Direct,
    /// Sky and indirect light alone.
    Ambient,
}

impl Terms {
    /// Weights of the direct and ambient terms (1 or 0), as the shaders get them.
    pub fn weights(self) -> [f32; 2] {
        match self {
            Terms::All => [1.0, 1.0],
            Terms::Direct => [1.0, 0.0],
            Terms::Ambient => [0.0, 1.0],
        }
    }
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 1280,
            height: 720,
            eye: None,
            target: None,
            fov_y_deg: camera::DEFAULT_FOV_Y_DEG,
            exposure: None,
            lighting: None,
            backend: BackendChoice::Auto,
            prt_layout: ambient::PrtLayout::Full,
            soft_shadows: None,
            terms: Terms::All,
            lod_tau: DEFAULT_LOD_TAU,
            shadow_cascades: shadow::DEFAULT_CASCADES,
            msaa: MSAA_SAMPLES,
            encoding: Encoding::Srgb,
            toksvig: true,
            parallax: false,
            linear: false,
            regions: false,
        }
    }
}

/// What a render did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RenderStats {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel of the scene pass ([`RenderOptions::msaa`]).
    pub msaa: u32,
    pub encoding: Encoding,
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub fov_y_deg: f32,
    pub exposure: f32,
    pub lighting: Lighting,
    /// True when the pack had no sky and the analytic one was drawn.
    pub analytic_sky: bool,
    pub models: usize,
    /// Where the instances were read from: the `bittree` section when the pack has one, else
    /// the `instances` records ([`scene::bittree_instances`]).
    pub instances_from: scene::InstanceSource,
    /// Instances the camera pass drew (after culling).
    pub instances: u64,
    /// Instances outside the view, not drawn by the camera pass.
    pub instances_culled: u64,
    /// Instances the camera pass drew at each level (index 0: full detail; for a model with an
    /// impostor, the index after its last mesh level counts its impostors).
    pub instances_per_level: Vec<u64>,
    /// Of `instances`, those drawn as impostor quads ([`impostor`]).
    pub impostor_instances: u64,
    /// Of `instances`, those drawn as their skeleton's lines and points ([`skeleton`]).
    pub skeleton_instances: u64,
    /// Triangles of the camera pass (terrain and models).
    pub triangles: u64,
    /// Triangles of the shadow pass(es).
    pub shadow_triangles: u64,
    /// Of `triangles`, the terrain's.
    pub terrain_triangles: u64,
    /// World size of one shadow-map texel in metres near the camera (the first cascade) and at
    /// the far plane (the last); `None` without a shadow map.
    pub shadow_texel_near_m: Option<f32>,
    pub shadow_texel_far_m: Option<f32>,
    /// Each cascade's view-depth range and texel size (empty without a shadow map).
    pub shadow_cascades: Vec<shadow::CascadeStats>,
    /// Terrain chunks outside the view, and those drawn at each step 2^s cells (index s).
    pub terrain_chunks_culled: u32,
    pub terrain_chunks_per_step: Vec<u32>,
    pub draw_calls: u32,
    pub uploaded_bytes: u64,
    /// Reading the pack's sections and resolving the ambient light (CPU).
    pub seconds_load: f64,
    pub seconds_setup: f64,
    pub seconds_upload: f64,
    /// Culling, LOD selection and the instance buckets (CPU), and their upload.
    pub seconds_select: f64,
    /// Recording, drawing and reading back the frame.
    pub seconds_draw: f64,
    /// Where the ambient term's light came from.
    pub ambient: ambient::AmbientSummary,
}

/// The rendered image and how it was made.
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// sRGB-encoded, row 0 at the top, alpha 255.
    pub image: Rgba8Image,
    /// The linear radiance the image was tone-mapped from ([`RenderOptions::linear`]): the
    /// resolved HDR target (half floats, so the sun's disc may read +∞).
    pub linear: Option<crate::model::FloatImage>,
    /// With [`RenderOptions::regions`]: per pixel the covered fraction of each region, R the
    /// terrain, G opaque model surfaces, B leaves (alpha-tested materials, impostor texels of
    /// such a material, skeletons of models with leaves); the
    /// sky is 1 − R − G − B.
    pub regions: Option<crate::model::FloatImage>,
    pub adapter: AdapterSummary,
    pub stats: RenderStats,
    pub warnings: Vec<crate::diag::Warning>,
    /// The soft-shadow pass's receivers and visibility, with `--soft-shadows`.
    pub soft_shadows: Option<soft_shadow::SoftShadowImage>,
}

/// The light the sky stage measured: its extracted sun, and the horizontal irradiance of the
/// sun-free sky's SH as ambient. `None` when the pack has no `sh` section.
pub fn pack_lighting(pack: &Pack) -> Option<light::Lighting> {
    let (_, _, irr) =
        crate::sky::section::sh_from_section(&pack.view_named(crate::sky::SH_SECTION).ok()?)
            .ok()?;
    let sun = pack
        .view_named(crate::sky::SUN_SECTION)
        .ok()
        .and_then(|v| crate::sky::section::sun_from_section(&v).ok());
    let (dir, e, omega) = sun.map_or(([0.0, 0.0, 1.0], [0.0; 3], 0.0), |s| {
        (s.direction, s.irradiance, s.solid_angle as f32)
    });
    Some(light::Lighting {
        sun_direction: dir,
        sun_irradiance: e,
        ambient: irr.eval([0.0, 0.0, 1.0]).map(|v| v.max(0.0)),
        sun_solid_angle: omega,
    })
}

/// What both renderers (GPU and [`reference`]) agree on before drawing: camera, light, exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    pub camera: camera::Camera,
    pub lighting: Lighting,
    pub exposure: f32,
}

/// The view of `opts` over `scene` (defaults filled in from the pack).
pub fn resolve_view(pack: &Pack, scene: &scene::SceneData, opts: &RenderOptions) -> View {
    let aspect = opts.width as f32 / opts.height as f32;
    let camera = choose_camera(scene, opts, aspect);
    let lighting = opts
        .lighting
        .or_else(|| {
            // The disc only where the drawn sky is the one its sun was taken out of.
            pack_lighting(pack).map(|l| light::Lighting {
                sun_solid_angle: if scene.sky.sun_removed {
                    l.sun_solid_angle
                } else {
                    0.0
                },
                ..l
            })
        })
        .unwrap_or_else(|| {
            light::default_lighting(
                &scene.sky.texels,
                scene.sky.width,
                scene.sky.height,
                scene.sky.analytic,
            )
        });
    let exposure = opts
        .exposure
        .unwrap_or_else(|| light::auto_exposure(&lighting));
    View {
        camera,
        lighting,
        exposure,
    }
}

/// Renders `pack`.
pub fn render_pack(pack: &Pack, opts: &RenderOptions) -> Result<RenderOutput> {
    check_options(opts)?;
    let tl = std::time::Instant::now();
    let scene = scene::load_scene(pack)?;
    let View {
        camera: cam,
        lighting,
        exposure,
    } = resolve_view(pack, &scene, opts);
    let mut amb = ambient::load_ambient(pack, &scene, opts.prt_layout, opts.lighting.as_ref())?;

    let t0 = std::time::Instant::now();
    let gpu = crate::gpu::init_gpu(opts.backend)?;
    let pipes = pipelines::Pipelines::new(&gpu.device, opts.msaa, gpu.backend);
    gpu.check()?;
    let t1 = std::time::Instant::now();
    let mut gpu_scene = upload::upload_scene(&gpu, &pipes, &scene)?;
    let amb_gpu = ambient_gpu::upload_ambient(&gpu, &pipes, &scene, &amb, opts.terms.weights()[1])?;
    // The GPU holds the ambient term now: its CPU copy (the light maps and PRT rows, hundreds of
    // MB at scale) goes before the draw.
    let (amb_summary, amb_warnings) = (amb.summary(), std::mem::take(&mut amb.warnings));
    drop(amb);
    gpu_scene.bytes += amb_gpu.bytes;
    gpu_scene.ambient = Some(amb_gpu);
    gpu.wait()?;
    let t2 = std::time::Instant::now();
    let size = (opts.width, opts.height);
    let mut globals = draw::Globals::new(&cam, &lighting, exposure, size, opts.terms);
    // cam_up.w: 1 where the normal map's length corrects the roughness (Toksvig).
    globals.cam_up[3] = if opts.toksvig { 1.0 } else { 0.0 };
    // cam_right.w: 1 where the height maps displace the texture lookups (parallax).
    globals.cam_right[3] = if opts.parallax { 1.0 } else { 0.0 };
    let soft = match &opts.soft_shadows {
        Some(s) => Some(soft_shadow::for_render(
            &gpu, &pipes, &gpu_scene, &globals, size, pack, &lighting, s,
        )?),
        None => None,
    };
    let lit = soft_shadow::fully_lit(&gpu);
    let visibility = soft.as_ref().map_or(&lit, |v| &v.view);
    // Soft shadows replace the shadow map: direct.wgsl reads the visibility texture where
    // sun_direction.w is 1.
    let shadows = match soft {
        Some(_) => {
            globals.sun_direction[3] = 1.0;
            None
        }
        None => shadow::shadows(&scene, &cam, lighting.sun_direction, opts.shadow_cascades),
    };
    let ts = std::time::Instant::now();
    // Pass 0 the camera, pass 1 + i cascade i: casters are culled per cascade.
    let mut views = vec![cull::Frustum::from_view_proj(cam.view_proj(), false)];
    for c in shadows.as_ref().map_or(&[][..], |s| &s.cascades[..]) {
        views.push(cull::Frustum::from_view_proj(c.view_proj, true));
    }
    let k = opts.height as f32 / (2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan());
    let rules: Vec<levels::ModelRule> = scene
        .models
        .iter()
        .map(|m| levels::ModelRule::new(m, k, opts.lod_tau))
        .collect();
    let buckets = cull::bucket(
        &scene
            .models
            .iter()
            .map(|m| m.instances.as_slice())
            .collect::<Vec<_>>(),
        &scene.models.iter().map(|m| m.sphere).collect::<Vec<_>>(),
        &rules
            .iter()
            .map(|r| r as &dyn cull::LevelRule)
            .collect::<Vec<_>>(),
        cam.eye,
        &views,
    );
    let mut per_level = Vec::new();
    for b in &buckets {
        for (l, r) in b.ranges[draw::CAMERA_PASS].iter().enumerate() {
            if per_level.len() <= l {
                per_level.resize(l + 1, 0u64);
            }
            per_level[l] += r.len() as u64;
        }
    }
    // The terrain's chunks per pass, each culled by its own view, the step from the camera.
    let chunks: Vec<terrain_lod::Selection> = match &scene.terrain {
        Some(t) => views
            .iter()
            .map(|f| t.chunks.select(f, cam.eye, k, opts.lod_tau))
            .collect(),
        None => Vec::new(),
    };
    let terrain_culled = chunks.first().map_or(0, |c| c.culled);
    let frame = draw::FrameInstances::upload(&gpu, buckets, &chunks);
    let seconds_select = ts.elapsed().as_secs_f64();
    let drawn = draw::draw_frame(
        &gpu,
        &pipes,
        &gpu_scene,
        &globals,
        size,
        shadows.as_ref(),
        visibility,
        &frame,
        opts.encoding,
        opts.linear,
    )?;
    let (pixels, counts) = (drawn.pixels, drawn.counts);
    let t3 = std::time::Instant::now();
    let float_image = |texels: Vec<[f32; 4]>| crate::model::FloatImage {
        width: opts.width,
        height: opts.height,
        pixels: texels.into_iter().map(|t| [t[0], t[1], t[2]]).collect(),
    };
    let linear = drawn.linear.map(float_image);
    // The region pass: the same frame with every fragment writing its region's indicator
    // (globals.ambient.w = 1, shaders/common.wgsl `REGION_*`), resolved like the radiance.
    let regions = if opts.regions {
        let mut g = globals;
        g.ambient[3] = 1.0;
        let r = draw::draw_frame(
            &gpu,
            &pipes,
            &gpu_scene,
            &g,
            size,
            shadows.as_ref(),
            visibility,
            &frame,
            opts.encoding,
            true,
        )?;
        r.linear.map(float_image)
    } else {
        None
    };
    let total_instances: u64 = scene.models.iter().map(|m| m.instances.len() as u64).sum();

    let image = Rgba8Image {
        width: opts.width,
        height: opts.height,
        pixels: bytemuck::cast_slice(&pixels).to_vec(),
    };
    let stats = RenderStats {
        width: opts.width,
        height: opts.height,
        msaa: opts.msaa,
        encoding: opts.encoding,
        eye: cam.eye.to_array(),
        target: cam.target.to_array(),
        fov_y_deg: cam.fov_y_deg,
        exposure,
        lighting,
        analytic_sky: scene.sky.analytic,
        models: scene.models.len(),
        instances_from: scene.instance_source,
        instances: counts.instances,
        instances_culled: total_instances - counts.instances,
        instances_per_level: per_level,
        impostor_instances: counts.impostor_instances,
        skeleton_instances: counts.skeleton_instances,
        triangles: counts.triangles,
        shadow_triangles: counts.shadow_triangles,
        terrain_triangles: counts.terrain_triangles,
        shadow_texel_near_m: shadows
            .as_ref()
            .and_then(|s| s.cascades.first())
            .map(|c| c.texel_m),
        shadow_texel_far_m: shadows
            .as_ref()
            .and_then(|s| s.cascades.last())
            .map(|c| c.texel_m),
        shadow_cascades: shadows.as_ref().map_or(Vec::new(), |s| s.stats()),
        terrain_chunks_culled: terrain_culled,
        terrain_chunks_per_step: chunks.first().map_or(Vec::new(), |c| {
            c.by_step.iter().map(|v| v.len() as u32).collect()
        }),
        draw_calls: counts.draw_calls,
        uploaded_bytes: gpu_scene.bytes,
        seconds_load: (t0 - tl).as_secs_f64(),
        seconds_setup: (t1 - t0).as_secs_f64(),
        seconds_upload: (t2 - t1).as_secs_f64(),
        seconds_select,
        seconds_draw: (t3 - t2).as_secs_f64() - seconds_select,
        ambient: amb_summary,
    };
    let mut warnings = scene.warnings;
    warnings.extend(amb_warnings);
    Ok(RenderOutput {
        image,
        linear,
        regions,
        adapter: gpu.adapter.clone(),
        stats,
        warnings,
        soft_shadows: soft.map(|v| v.image),
    })
}

pub fn check_options(opts: &RenderOptions) -> Result<()> {
    if opts.width == 0 || opts.height == 0 || opts.width > 16384 || opts.height > 16384 {
        return Err(Error::usage(format!(
            "image size {}×{}: each side must be 1 to 16384",
            opts.width, opts.height
        )));
    }
    if !(opts.fov_y_deg > 0.0 && opts.fov_y_deg < 180.0) {
        return Err(Error::usage(format!(
            "field of view {}° is not in (0, 180)",
            opts.fov_y_deg
        )));
    }
    if !(opts.lod_tau >= 0.0 && opts.lod_tau.is_finite()) {
        return Err(Error::usage(format!(
            "LOD threshold {} px must be 0 or more (0: full detail)",
            opts.lod_tau
        )));
    }
    if !(1..=shadow::MAX_CASCADES as u32).contains(&opts.shadow_cascades) {
        return Err(Error::usage(format!(
            "{} shadow cascades: must be 1 to {}",
            opts.shadow_cascades,
            shadow::MAX_CASCADES
        )));
    }
    if opts.msaa != 1 && opts.msaa != MSAA_SAMPLES {
        return Err(Error::usage(format!(
            "{} samples per pixel: must be 1 or {MSAA_SAMPLES}",
            opts.msaa
        )));
    }
    if let Encoding::Gamma(g) = opts.encoding
        && !(g > 0.0 && g.is_finite())
    {
        return Err(Error::usage(format!("gamma {g} must be positive")));
    }
    if let Some(s) = opts.exposure
        && !(s > 0.0 && s.is_finite())
    {
        return Err(Error::usage(format!("exposure {s} must be positive")));
    }
    let finite = |v: &Option<[f32; 3]>| v.is_none_or(|v| v.iter().all(|c| c.is_finite()));
    if !finite(&opts.eye) || !finite(&opts.target) {
        return Err(Error::usage("--eye and --target must be finite"));
    }
    if let (Some(e), Some(t)) = (opts.eye, opts.target)
        && Vec3::from(e) == Vec3::from(t)
    {
        return Err(Error::usage("--eye and --target are the same point"));
    }
    Ok(())
}

/// The default camera frames the scene's focus bounds; `--eye`/`--target` override either part.
fn choose_camera(scene: &scene::SceneData, opts: &RenderOptions, aspect: f32) -> camera::Camera {
    let (lo, hi) = scene.focus_bounds();
    camera_for_bounds(lo, hi, opts, aspect)
}

/// The camera of `opts` over the box `lo..hi`: the box framed ([`camera::Camera::frame_box`])
/// unless `--eye`/`--target` override either part.
pub fn camera_for_bounds(
    lo: [f32; 3],
    hi: [f32; 3],
    opts: &RenderOptions,
    aspect: f32,
) -> camera::Camera {
    let framed = camera::Camera::frame_box(Vec3::from(lo), Vec3::from(hi), opts.fov_y_deg, aspect);
    match (opts.eye, opts.target) {
        (None, None) => framed,
        (eye, target) => {
            let eye = eye.map_or(framed.eye, Vec3::from);
            let mut target = target.map_or(framed.target, Vec3::from);
            if eye == target {
                target = eye + Vec3::new(0.0, 1.0, 0.0);
            }
            camera::Camera::look_at(eye, target, opts.fov_y_deg, aspect)
        }
    }
}

/// Encodes an image as PNG (RGBA, 8 bits).
pub fn encode_png(img: &Rgba8Image) -> Result<Vec<u8>> {
    let raw: Vec<u8> = bytemuck::cast_slice(&img.pixels).to_vec();
    let buf = image::RgbaImage::from_raw(img.width, img.height, raw)
        .ok_or_else(|| Error::runtime("image buffer does not match its size"))?;
    let mut out = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| Error::runtime(format!("PNG encoding failed: {e}")))?;
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shadow_cascades_outside_one_to_four_are_a_usage_error() {
        for n in [0, shadow::MAX_CASCADES as u32 + 1] {
            let opts = RenderOptions {
                shadow_cascades: n,
                ..RenderOptions::default()
            };
            let e = check_options(&opts).unwrap_err().to_string();
            assert!(e.contains("shadow cascades"), "{n}: {e}");
        }
        for n in 1..=shadow::MAX_CASCADES as u32 {
            let opts = RenderOptions {
                shadow_cascades: n,
                ..RenderOptions::default()
            };
            assert!(check_options(&opts).is_ok());
        }
    }
}
