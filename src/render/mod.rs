//! The wgpu runtime stage: renders a pack offscreen to an image, proving that its arrays go
//! straight into GPU buffers and come out as a picture.
//!
//! Order of work, each step its own module so later issues can swap one: [`scene`] reads and
//! checks the pack on the CPU; [`gpu`] opens a device (a real GPU, or Mesa's lavapipe/llvmpipe);
//! [`pipelines`] builds the passes; [`upload`] moves the arrays to the GPU; [`draw`] renders the
//! sky, the terrain and the instanced models into an `Rgba16Float` target and tone-maps it
//! (1 − exp(−L·s), then sRGB) into the output. [`light`] and [`camera`] hold the conventions.

pub mod ambient;
pub mod ambient_gpu;
pub mod camera;
pub mod draw;
pub mod light;
pub mod pipelines;
pub mod reference;
pub mod sample;
pub mod scene;
pub mod shadow;
pub mod soft_shadow;
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
}

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
        }
    }
}

/// What a render did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RenderStats {
    pub width: u32,
    pub height: u32,
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub fov_y_deg: f32,
    pub exposure: f32,
    pub lighting: Lighting,
    /// True when the pack had no sky and the analytic one was drawn.
    pub analytic_sky: bool,
    pub models: usize,
    pub instances: u64,
    pub triangles: u64,
    pub draw_calls: u32,
    pub uploaded_bytes: u64,
    pub seconds_setup: f64,
    pub seconds_upload: f64,
    pub seconds_draw: f64,
    /// Where the ambient term's light came from.
    pub ambient: ambient::AmbientSummary,
}

/// The rendered image and how it was made.
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// sRGB-encoded, row 0 at the top, alpha 255.
    pub image: Rgba8Image,
    pub adapter: AdapterSummary,
    pub stats: RenderStats,
    pub warnings: Vec<String>,
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
    let (dir, e) = sun.map_or(([0.0, 0.0, 1.0], [0.0; 3]), |s| (s.direction, s.irradiance));
    Some(light::Lighting {
        sun_direction: dir,
        sun_irradiance: e,
        ambient: irr.eval([0.0, 0.0, 1.0]).map(|v| v.max(0.0)),
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
        .or_else(|| pack_lighting(pack))
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
    let scene = scene::load_scene(pack)?;
    let View {
        camera: cam,
        lighting,
        exposure,
    } = resolve_view(pack, &scene, opts);

    let t0 = std::time::Instant::now();
    let gpu = crate::gpu::init_gpu(opts.backend)?;
    let pipes = pipelines::Pipelines::new(&gpu.device);
    gpu.check()?;
    let t1 = std::time::Instant::now();
    let amb = ambient::load_ambient(pack, &scene, opts.prt_layout, opts.lighting.as_ref())?;
    let mut gpu_scene = upload::upload_scene(&gpu, &pipes, &scene)?;
    let amb_gpu = ambient_gpu::upload_ambient(&gpu, &pipes, &scene, &amb, opts.terms.weights()[1])?;
    gpu_scene.bytes += amb_gpu.bytes;
    gpu_scene.ambient = Some(amb_gpu);
    gpu.wait()?;
    let t2 = std::time::Instant::now();
    let size = (opts.width, opts.height);
    let mut globals = draw::Globals::new(&cam, &lighting, exposure, size, opts.terms);
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
    let shadow_params = match soft {
        Some(_) => {
            globals.sun_direction[3] = 1.0;
            None
        }
        None => shadow::shadow_params(&scene, lighting.sun_direction),
    };
    let (pixels, counts) = draw::draw_frame(
        &gpu,
        &pipes,
        &gpu_scene,
        &globals,
        size,
        shadow_params.as_ref(),
        visibility,
    )?;
    let t3 = std::time::Instant::now();

    let image = Rgba8Image {
        width: opts.width,
        height: opts.height,
        pixels: bytemuck::cast_slice(&pixels).to_vec(),
    };
    let stats = RenderStats {
        width: opts.width,
        height: opts.height,
        eye: cam.eye.to_array(),
        target: cam.target.to_array(),
        fov_y_deg: cam.fov_y_deg,
        exposure,
        lighting,
        analytic_sky: scene.sky.analytic,
        models: scene.models.len(),
        instances: counts.instances,
        triangles: counts.triangles,
        draw_calls: counts.draw_calls,
        uploaded_bytes: gpu_scene.bytes,
        seconds_setup: (t1 - t0).as_secs_f64(),
        seconds_upload: (t2 - t1).as_secs_f64(),
        seconds_draw: (t3 - t2).as_secs_f64(),
        ambient: amb.summary(),
    };
    let mut warnings = scene.warnings;
    warnings.extend(amb.warnings);
    Ok(RenderOutput {
        image,
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
