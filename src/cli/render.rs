//! `bake render PACK -o OUT.png`: an offscreen wgpu render of a pack (see src/render).

use super::{Global, Outcome, parse_vec3};
use crate::error::Result;
use crate::pack::Pack;
use crate::render::svo_view::{self, SvoShow, SvoViewOptions};
use crate::render::{BackendChoice, RenderOptions, Terms, encode_png, render_pack};
use std::path::PathBuf;

/// The view of a render: image size and camera (`bake render`, `bake mitsuba`).
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ViewArgs {
    /// Image width in pixels.
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Camera position x,y,z in metres (default: framing the area of interest).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<[f32; 3]>,
    /// Point looked at x,y,z (default: the centre of the area of interest).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub target: Option<[f32; 3]>,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = crate::render::camera::DEFAULT_FOV_Y_DEG)]
    pub fov: f32,
}

impl ViewArgs {
    /// Render options with this view, the rest default.
    pub(crate) fn options(&self) -> RenderOptions {
        RenderOptions {
            width: self.width,
            height: self.height,
            eye: self.eye,
            target: self.target,
            fov_y_deg: self.fov,
            ..RenderOptions::default()
        }
    }
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct RenderArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    /// Output image: PNG (tone-mapped, sRGB), or by the extension .exr the linear radiance
    /// of --terms before the tone map (RGB f32; the sun's disc may read +inf).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also write the region image: per pixel the covered fraction of the terrain (R), of
    /// opaque model surfaces (G) and of leaves (B: alpha-tested materials, impostor texels of
    /// such a material, and the skeletons of models that have them); the sky is the rest. PNG
    /// (×255) or EXR.
    #[arg(long)]
    pub regions: Option<PathBuf>,
    #[command(flatten)]
    pub camera: ViewArgs,
    /// Exposure s of the tone map 1 − exp(−L·s) (default: an 18 % grey card in full light maps to 0.5).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Graphics API.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
    /// PRT layout of the ambient term: the full transfer or the thesis' 5 vec4 per side.
    #[arg(long, value_enum, default_value_t = crate::render::ambient::PrtLayout::Full)]
    pub prt_layout: crate::render::ambient::PrtLayout,
    /// The sun's visibility from the line-space soft shadows (the pack needs a `linespace`
    /// section); the light is the sun's disc unless --area-light is given.
    #[arg(long)]
    pub soft_shadows: bool,
    /// Quad light of the soft shadows: corner, edge u, edge v (cx,cy,cz,ux,uy,uz,vx,vy,vz, metres).
    #[arg(long, value_parser = crate::render::soft_shadow::parse_area_light, allow_hyphen_values = true, requires = "soft_shadows")]
    pub area_light: Option<crate::linespace::query::AreaLight>,
    /// Light samples per side of the soft shadows (samples² shadow segments per pixel).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub shadow_samples: u32,
    /// Deepest-level refinement of the soft shadows' line-space query (shaft: the thesis;
    /// cells: leaf cells on the segment; exact: their triangles; near: exact within one
    /// deepest-node side of the receiver).
    #[arg(long, value_enum, default_value_t = crate::linespace::ntree::Refine::default())]
    pub shadow_refine: crate::linespace::ntree::Refine,
    /// Also run the soft shadows as exact ray-traced visibility (same receivers and samples,
    /// no line spaces) and report both passes' GPU times and their difference.
    #[arg(long, requires = "soft_shadows")]
    pub shadow_compare: bool,
    /// Light terms to draw: all (direct sun + ambient), direct or ambient alone.
    #[arg(long, value_enum, default_value_t = Terms::All)]
    pub terms: Terms,
    /// Also render the view on the CPU (ray-cast reference, src/render/reference.rs) into this
    /// PNG, or by the extension .exr its linear radiance of --terms; the JSON result adds the
    /// difference between the two tone-mapped images.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// LOD pixel threshold τ: each instance draws the coarsest level of its model's `lod`
    /// section whose projected error is at most τ pixels (0: full detail everywhere).
    #[arg(long, default_value_t = crate::render::DEFAULT_LOD_TAU)]
    pub lod_tau: f32,
    /// Full detail everywhere (the same as --lod-tau 0).
    #[arg(long, conflicts_with = "lod_tau")]
    pub no_lod: bool,
    /// Cascades of the sun's shadow map, 1 to 4 (1: one map over the whole scene).
    #[arg(long, default_value_t = crate::render::shadow::DEFAULT_CASCADES)]
    pub shadow_cascades: u32,
    /// Samples per pixel: 4 (MSAA, leaf cards' coverage as the sample mask; the CPU reference
    /// averages rays at the same 4 positions) or 1.
    #[arg(long, default_value_t = crate::render::MSAA_SAMPLES)]
    pub msaa: u32,
    /// Write the thesis' L_g = L_s^γ (seed 000 §4.7.4) instead of the sRGB encoding of the
    /// tone-mapped L_s (γ 0.4545 ≈ a 2.2 display gamma).
    #[arg(long)]
    pub gamma: Option<f32>,
    /// Draw the normal maps' mips without Toksvig's roughness correction (the renormalized
    /// filtered normals with the material's own roughness: minified bumpy gloss sparkles).
    #[arg(long)]
    pub no_toksvig: bool,
    /// Parallax mapping with offset limiting (seed 000 §4.7.3): colour and normal maps read
    /// where the view ray crosses the height map's surface (mean-colour height ± the bump).
    #[arg(long)]
    pub parallax: bool,
    /// What to draw: the scene (meshes, terrain, sky), or the `svo` section ray-marched by a
    /// compute shader that stops at the filtered parents, the level chosen by distance.
    #[arg(long, value_enum, default_value_t = ViewMode::Scene)]
    pub view: ViewMode,
    /// With --view svo: the filtered colour (lit by the pack's sun or a fixed light), the
    /// normal as RGB, or the level each pixel stopped at as a palette colour.
    #[arg(long, value_enum, default_value_t = SvoShow::Colour)]
    pub svo_show: SvoShow,
    /// With --view svo: factor on the pixel's cone; a cell stops the descent once its side is
    /// at most scale × the pixel's footprint where the ray enters it (0: always the voxels).
    #[arg(long, default_value_t = svo_view::DEFAULT_LOD_SCALE)]
    pub svo_lod_scale: f32,
}

/// `bake render --view`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ViewMode {
    Scene,
    Svo,
}

/// True for a path whose extension is `exr` (any case).
fn is_exr(path: &std::path::Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// Writes linear RGB as OpenEXR (f32) where the extension says so, else as an 8-bit PNG of the
/// values clamped to [0, 1] (the region image's coverages).
fn write_float_image(path: &std::path::Path, img: &crate::model::FloatImage) -> Result<()> {
    let bytes = if is_exr(path) {
        crate::dump::images::exr_rgb(img)
            .map_err(|e| crate::error::Error::runtime(format!("EXR encoding failed: {e}")))?
    } else {
        let pixels = img
            .pixels
            .iter()
            .flat_map(|p| {
                let b = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
                [b(p[0]), b(p[1]), b(p[2]), 255]
            })
            .collect();
        encode_png(&crate::model::Rgba8Image {
            width: img.width,
            height: img.height,
            pixels: bytemuck::cast_vec::<u8, [u8; 4]>(pixels),
        })?
    };
    crate::pack::write_atomic(path, &bytes)
}

/// Threshold (8-bit steps) of the `pixels_over` fraction in the reference comparison.
pub(crate) const REFERENCE_THRESHOLD: u8 = 24;

/// Silences the warning Mesa's device-select Vulkan layer prints on machines without a display,
/// unless the user set `NODEVICE_SELECT` already. `main` calls it first thing, while the process
/// has one thread.
pub(crate) fn quiet_mesa_layer() {
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: called by `main` before wgpu or rayon start any thread; nothing else
        // reads or writes the environment concurrently.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

pub(crate) fn run(args: &RenderArgs, _g: &Global) -> Result<Outcome> {
    let opts = RenderOptions {
        exposure: args.exposure,
        lighting: None,
        backend: args.backend,
        prt_layout: args.prt_layout,
        soft_shadows: args
            .soft_shadows
            .then_some(crate::render::soft_shadow::SoftShadows {
                area_light: args.area_light,
                samples: args.shadow_samples,
                refine: args.shadow_refine,
                compare_exact: args.shadow_compare,
            }),
        terms: args.terms,
        lod_tau: if args.no_lod { 0.0 } else { args.lod_tau },
        shadow_cascades: args.shadow_cascades,
        msaa: args.msaa,
        encoding: args.gamma.map_or(
            crate::render::Encoding::Srgb,
            crate::render::Encoding::Gamma,
        ),
        toksvig: !args.no_toksvig,
        parallax: args.parallax,
        linear: is_exr(&args.output),
        regions: args.regions.is_some(),
        ..args.camera.options()
    };
    let pack = Pack::open(&args.pack)?;
    if args.view == ViewMode::Svo {
        return run_svo(args, &pack, &opts);
    }
    let out = render_pack(&pack, &opts)?;
    match &out.linear {
        Some(img) => write_float_image(&args.output, img)?,
        None => crate::pack::write_atomic(&args.output, &encode_png(&out.image)?)?,
    }
    if let (Some(path), Some(img)) = (&args.regions, &out.regions) {
        write_float_image(path, img)?;
    }
    let s = &out.stats;
    let mut text = format!(
        "{}: {}×{} on {}, {} instances of {} models, {} triangles, {:.3} s\n",
        args.output.display(),
        s.width,
        s.height,
        out.adapter,
        s.instances,
        s.models,
        s.triangles,
        s.seconds_setup + s.seconds_upload + s.seconds_draw
    );
    let mut json = serde_json::json!({
        "output": args.output,
        "regions": args.regions,
        "adapter": out.adapter,
        "stats": out.stats,
        "soft_shadows": out.soft_shadows.as_ref().map(|s| s.stats),
        "soft_shadow_comparison": out.soft_shadows.as_ref().and_then(|s| s.comparison),
    });
    if let Some(path) = &args.reference {
        let r = crate::render::reference::render_reference(&pack, &opts)?;
        if is_exr(path) {
            let img = crate::model::FloatImage {
                width: opts.width,
                height: opts.height,
                pixels: r.radiance.clone(),
            };
            write_float_image(path, &img)?;
        } else {
            crate::pack::write_atomic(path, &encode_png(&r.image)?)?;
        }
        let d =
            crate::render::reference::image_difference(&out.image, &r.image, REFERENCE_THRESHOLD)
                .ok_or_else(|| crate::error::Error::runtime("reference image has another size"))?;
        text += &format!(
            "{}: CPU reference, {:.3} s; mean absolute difference {:.2}/255, {:.2} % of pixels off by more than {}/255\n",
            path.display(),
            r.seconds,
            d.mad,
            d.fraction_over * 100.0,
            d.threshold
        );
        json["reference"] = serde_json::json!({
            "output": path, "seconds": r.seconds, "mad": d.mad,
            "pixels_over": d.fraction_over, "threshold": d.threshold, "max": d.max,
        });
    }
    Ok(Outcome {
        json,
        text,
        warnings: out.warnings,
    })
}

/// `--view svo`: the GPU traversal's image, and with `--reference` the CPU traversal's on the
/// same rays with the difference of the images and of the answers.
fn run_svo(args: &RenderArgs, pack: &Pack, opts: &RenderOptions) -> Result<Outcome> {
    // The options of the mesh view that the SVO view does not read: refused, not ignored.
    let defaults = RenderOptions::default();
    let unread = [
        (args.soft_shadows, "--soft-shadows"),
        (args.parallax, "--parallax"),
        (args.no_toksvig, "--no-toksvig"),
        (
            args.no_lod || args.lod_tau != crate::render::DEFAULT_LOD_TAU,
            "--lod-tau/--no-lod",
        ),
        (args.gamma.is_some(), "--gamma"),
        (args.regions.is_some(), "--regions"),
        (is_exr(&args.output), "an .exr output (linear radiance)"),
        (args.exposure.is_some(), "--exposure"),
        (args.terms != Terms::All, "--terms"),
        (args.msaa != defaults.msaa, "--msaa"),
        (args.prt_layout != defaults.prt_layout, "--prt-layout"),
        (
            args.shadow_cascades != defaults.shadow_cascades,
            "--shadow-cascades",
        ),
    ];
    if let Some((_, flag)) = unread.iter().find(|(set, _)| *set) {
        return Err(crate::error::Error::usage(format!(
            "{flag} has no effect with --view svo (it draws the svo section: --svo-show, --svo-lod-scale, the camera, --reference)"
        )));
    }
    let view = SvoViewOptions {
        show: args.svo_show,
        lod_scale: args.svo_lod_scale,
    };
    if pack.of_kind(crate::voxel::section::KIND).next().is_none()
        && let Some(v) = svo_view::prepare_scene_view(pack, opts, view)?
    {
        return run_svo_scene(args, &v);
    }
    let scene = svo_view::prepare_svo_view(pack, opts, view)?;
    let out = svo_view::render_svo(&scene, args.backend)?;
    crate::pack::write_atomic(&args.output, &encode_png(&out.image)?)?;
    let stats = svo_view::view_stats(&scene, &out.hits);
    let mut text = format!(
        "{}: svo view {}×{} on {}, lod scale {}, {} of {} pixels hit, per level (root first) {:?}, {:.3} s\n",
        args.output.display(),
        stats.width,
        stats.height,
        out.adapter,
        stats.lod_scale,
        stats.hits,
        scene.rays.len(),
        stats.pixels_per_level,
        out.seconds
    );
    let mut json = serde_json::json!({
        "output": args.output,
        "adapter": out.adapter,
        "seconds": out.seconds,
        "svo": stats,
    });
    if let Some(path) = &args.reference {
        let t0 = std::time::Instant::now();
        let cpu = svo_view::trace_cpu(&scene);
        let seconds = t0.elapsed().as_secs_f64();
        let image = svo_view::shade_image(&scene, &cpu);
        crate::pack::write_atomic(path, &encode_png(&image)?)?;
        let d = crate::render::reference::image_difference(&out.image, &image, REFERENCE_THRESHOLD)
            .ok_or_else(|| crate::error::Error::runtime("reference image has another size"))?;
        let a = crate::voxel::lod_gpu::compare_lod_hits(&out.hits, &cpu);
        text += &format!(
            "{}: CPU traversal, {:.3} s; mean absolute difference {:.2}/255, {:.2} % of pixels off by more than {}/255; {} of {} rays disagree\n",
            path.display(),
            seconds,
            d.mad,
            d.fraction_over * 100.0,
            d.threshold,
            a.mismatches(),
            a.rays
        );
        json["reference"] = serde_json::json!({
            "output": path, "seconds": seconds, "mad": d.mad,
            "pixels_over": d.fraction_over, "threshold": d.threshold, "max": d.max,
            "agreement": a,
        });
    }
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
}

/// `--view svo` of a pack whose voxels are the two-level `svo-scene` section: the GPU's LOD
/// walk (the top level's aggregates where a region is no wider than the pixel's footprint,
/// `--svo-lod-scale` scaling the cone; 0: the voxels), with `--reference` the CPU's on the same
/// rays and how many answers differ.
fn run_svo_scene(args: &RenderArgs, v: &svo_view::SceneView) -> Result<Outcome> {
    use crate::voxel::instanced::SceneHit;
    let gpu = crate::gpu::init_gpu(args.backend)?;
    let t0 = std::time::Instant::now();
    let hits = crate::voxel::instanced_gpu::trace_gpu(&gpu, &v.scene, &v.rays, v.cone)?;
    let seconds = t0.elapsed().as_secs_f64();
    let image = svo_view::shade_scene(v, &hits);
    crate::pack::write_atomic(&args.output, &encode_png(&image)?)?;
    let count = |level: Option<u32>| {
        hits.iter()
            .filter(|h| match (h, level) {
                (Some(SceneHit::Voxel(_)), None) => true,
                (Some(SceneHit::Node(_)), Some(2)) => true,
                (Some(SceneHit::Aggregate(a)), Some(l)) => a.level == l,
                _ => false,
            })
            .count()
    };
    let (voxel_hits, cell_hits, sub_hits) = (count(None), count(Some(0)), count(Some(1)));
    let node_hits = count(Some(2));
    let terrain = v.scene.terrain.then(|| v.scene.grid_instances() as u32);
    let terrain_node_hits = hits
        .iter()
        .filter(|h| matches!(h, Some(SceneHit::Node(n)) if Some(n.instance) == terrain))
        .count();
    let hit_count = voxel_hits + cell_hits + sub_hits + node_hits;
    let mut text = format!(
        "{}: svo-scene view (two-level) {}×{} on {}, lod scale {}, {} of {} pixels hit ({} on top cells, {} on sub-cells, {} on model nodes of which {} the terrain's, {} on voxels), {:.3} s\n",
        args.output.display(),
        v.size.0,
        v.size.1,
        gpu.adapter,
        args.svo_lod_scale,
        hit_count,
        v.rays.len(),
        cell_hits,
        sub_hits,
        node_hits,
        terrain_node_hits,
        voxel_hits,
        seconds
    );
    let mut json = serde_json::json!({
        "output": args.output,
        "adapter": gpu.adapter,
        "seconds": seconds,
        "svo_scene": {
            "width": v.size.0, "height": v.size.1, "hits": hit_count, "show": v.show,
            "lod_scale": args.svo_lod_scale, "cone": v.cone,
            "cell_hits": cell_hits, "sub_cell_hits": sub_hits, "node_hits": node_hits,
            "terrain_node_hits": terrain_node_hits, "voxel_hits": voxel_hits,
        },
    });
    if let Some(path) = &args.reference {
        let t0 = std::time::Instant::now();
        let cpu = svo_view::trace_scene_cpu(v);
        let seconds = t0.elapsed().as_secs_f64();
        let reference = svo_view::shade_scene(v, &cpu);
        crate::pack::write_atomic(path, &encode_png(&reference)?)?;
        let d = crate::render::reference::image_difference(&image, &reference, REFERENCE_THRESHOLD)
            .ok_or_else(|| crate::error::Error::runtime("reference image has another size"))?;
        let disagree = hits
            .iter()
            .zip(&cpu)
            .filter(|(g, c)| !crate::voxel::instanced_gpu::same_scene_hit(g, c))
            .count();
        text += &format!(
            "{}: CPU traversal, {:.3} s; mean absolute difference {:.2}/255; {} of {} rays disagree\n",
            path.display(),
            seconds,
            d.mad,
            disagree,
            cpu.len()
        );
        json["reference"] = serde_json::json!({
            "output": path, "seconds": seconds, "mad": d.mad,
            "pixels_over": d.fraction_over, "threshold": d.threshold, "max": d.max,
            "rays_disagree": disagree,
        });
    }
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct RenderBenchArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Renders (each opens its own device).
    #[arg(long, default_value_t = 5)]
    pub repeat: u32,
    /// LOD pixel threshold τ (0: full detail), as `bake render --lod-tau`.
    #[arg(long, default_value_t = crate::render::DEFAULT_LOD_TAU)]
    pub lod_tau: f32,
    /// Cascades of the sun's shadow map, 1 to 4 (1: one map over the whole scene).
    #[arg(long, default_value_t = crate::render::shadow::DEFAULT_CASCADES)]
    pub shadow_cascades: u32,
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
    /// Also time the CPU reference (src/render/reference.rs) of the same view.
    #[arg(long)]
    pub reference: bool,
    /// Samples per pixel (4: MSAA, 1: none), as `bake render --msaa`.
    #[arg(long, default_value_t = crate::render::MSAA_SAMPLES)]
    pub msaa: u32,
}

/// `bake bench render PACK`: see [`crate::bench::render::bench_render`].
pub(crate) fn bench(args: &RenderBenchArgs, _g: &Global) -> Result<Outcome> {
    let opts = RenderOptions {
        width: args.width,
        height: args.height,
        backend: args.backend,
        lod_tau: args.lod_tau,
        shadow_cascades: args.shadow_cascades,
        msaa: args.msaa,
        ..RenderOptions::default()
    };
    let r = crate::bench::render::bench_render(&args.pack, &opts, args.repeat, args.reference)?;
    Ok(r.into())
}
