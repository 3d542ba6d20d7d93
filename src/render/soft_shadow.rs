//! `bake render --soft-shadows`: the sun's visibility per pixel from the line-space soft-shadow
//! query (issue 6). A world-position pass (the terrain and mesh vertex shaders with fragment
//! shaders of our own, `shaders/world_*.wgsl`) writes each pixel's receiver point; the N-tree
//! `shadow` kernel ([`crate::linespace::gpu`], or over a `linespace-scene` section the two-level
//! one of [`crate::linespace::instanced_gpu`]) answers the fraction of a quad light's samples
//! that reach it; the fractions become an `R32Float` texture that the scene pass reads as
//! `soft_visibility` (common.wgsl) in place of the shadow map (direct.wgsl `sun_visibility`).
//!
//! The light is either explicit (`--area-light`) or the sun's disc: a square of the disc's
//! angular diameter, perpendicular to the sun direction at 100 scene diagonals from the line
//! spaces' centre. Receivers are moved off their surface along the (viewer-facing) normal by 10⁻³ of
//! their distance to the eye, against self-shadowing from the rasterizer's depth precision.

use super::draw::Globals;
use super::pipelines::{DEPTH_FORMAT, Pipelines};
use super::upload::GpuScene;
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::ingest::instances_section::InstanceRecord;
use crate::linespace::gpu::NTreeGpu;
use crate::linespace::instanced::SceneLinespace;
use crate::linespace::ntree::{NTree, Refine};
use crate::linespace::query::AreaLight;
use crate::pack::Pack;
use wgpu::util::DeviceExt;

const COMMON_WGSL: &str = include_str!("shaders/common.wgsl");
const TERRAIN_WGSL: &str = include_str!("shaders/terrain.wgsl");
const MESH_WGSL: &str = include_str!("shaders/mesh.wgsl");
const DIRECT_WGSL: &str = include_str!("shaders/direct.wgsl");
use super::pipelines::AMBIENT_WGSL;
const WORLD_TERRAIN_WGSL: &str = include_str!("shaders/world_terrain.wgsl");
const WORLD_MESH_WGSL: &str = include_str!("shaders/world_mesh.wgsl");

/// Format of the world-position target (xyz: receiver, w: 1 where geometry was drawn): the
/// four `f32`s' bits (`fs_world` writes `bitcast<vec4<u32>>`), so the copy to the receiver buffer
/// is exactly what an `Rgba32Float` target held. Unsigned integers because every adapter renders
/// to `Rgba32Uint` (WebGPU and GLES 3.0 guarantee it), while wgpu's GL backend refuses
/// `Rgba32Float` as a render attachment (a desktop GL context does not list
/// `GL_EXT_color_buffer_float`), and `Rgba16Float` would round the receivers to 11 bits.
const WORLD_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;
/// Format of the visibility texture.
pub const VISIBILITY_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// Pixels per padded row: 64 × 4 B and 64 × 16 B rows are multiples of wgpu's 256-byte copy
/// alignment, so the world texture and the visibility buffer copy without repacking.
const ROW_ALIGN: u32 = 64;
/// Angular diameter of the sun's disc, degrees.
pub const SUN_DIAMETER_DEG: f32 = 0.53;

/// Options of the soft shadows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftShadows {
    /// An explicit quad light; None: the sun's disc.
    pub area_light: Option<AreaLight>,
    /// Light samples per side (samples² segments per pixel).
    pub samples: u32,
    /// Deepest-level refinement of the line-space query.
    pub refine: Refine,
    /// Also compute the exact ray-traced visibility of the same receivers and light samples on
    /// the GPU, and report both passes' times and the difference ([`SoftShadowComparison`]).
    pub compare_exact: bool,
}

impl Default for SoftShadows {
    fn default() -> Self {
        SoftShadows {
            area_light: None,
            samples: 4,
            refine: Refine::default(),
            compare_exact: false,
        }
    }
}

/// What the soft-shadow pass computed (padding removed, row 0 at the top).
#[derive(Debug, Clone, PartialEq)]
pub struct SoftShadowImage {
    pub width: u32,
    pub height: u32,
    /// Receiver per pixel: xyz, and w = 1 where geometry was drawn (0: sky, lit).
    pub world: Vec<[f32; 4]>,
    /// Fraction of the light's samples that reach the receiver.
    pub visibility: Vec<f32>,
    pub light: AreaLight,
    /// Segment offset at the receiver (metres), as in `Segment::between`.
    pub offset: f32,
    pub stats: SoftShadowStats,
    /// With `compare_exact`: the line-space pass against exact ray-traced visibility.
    pub comparison: Option<SoftShadowComparison>,
}

/// The GPU soft-shadow pass (line-space visibility per pixel) against an exact per-pixel
/// ray-traced soft shadow with the same light samples: the same `shadow` kernel over the same
/// receivers without line spaces, so every segment walks the N-tree's filled leaves and tests
/// their triangles exactly (the traversal `bake validate` checks against the CPU, whose exact
/// mode agrees with obvhs). Times are wall seconds of one kernel run each, upload of the
/// receivers and read-back included.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SoftShadowComparison {
    pub refine: Refine,
    pub receivers: u64,
    pub samples: u32,
    pub linespace_seconds: f64,
    pub exact_seconds: f64,
    /// Mean and largest |line space − exact| over the drawn pixels.
    pub mean_abs_error: f64,
    pub max_abs_error: f64,
    /// Pixels darker than exact by more than 0.1, and brighter than exact at all.
    pub darker_pixels: u64,
    pub brighter_pixels: u64,
}

/// Counts for the render report.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SoftShadowStats {
    pub receivers: u64,
    pub samples: u32,
    /// Pixels strictly between shadow and light.
    pub penumbra_pixels: u64,
    pub shadowed_pixels: u64,
    pub seconds: f64,
}

/// The visibility texture plus its read-back copy.
pub struct Visibility {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub image: SoftShadowImage,
}

/// The pack's line spaces: one N-tree (`linespace`) or the two-level structure over the
/// instances (`linespace-scene`, where the placed scene exceeded the memory budget).
pub enum Linespaces {
    Flat(Box<NTree>),
    Scene(Box<SceneLinespace>),
}

impl Linespaces {
    /// Sets the deepest-level refinement (of the model trees for the two-level structure).
    pub fn set_refine(&mut self, refine: Refine) {
        match self {
            Linespaces::Flat(t) => t.refine = refine,
            Linespaces::Scene(s) => s.set_refine(refine),
        }
    }

    pub fn refine(&self) -> Refine {
        match self {
            Linespaces::Flat(t) => t.refine,
            Linespaces::Scene(s) => s.refine(),
        }
    }

    /// The box the structure covers: minimum corner and size.
    pub fn root_box(&self) -> ([f32; 3], [f32; 3]) {
        match self {
            Linespaces::Flat(t) => crate::linespace::gpu::root_box(t),
            Linespaces::Scene(s) => crate::linespace::instanced_gpu::scene_box(s),
        }
    }

    /// Uploads it with its query kernels.
    pub fn to_gpu<'g>(&self, gpu: &'g Gpu) -> Result<NTreeGpu<'g>> {
        match self {
            Linespaces::Flat(t) => NTreeGpu::new(gpu, t),
            Linespaces::Scene(s) => NTreeGpu::for_scene(gpu, s),
        }
    }
}

/// The pack's line spaces: its first `linespace` section, else its first `linespace-scene`.
pub fn load_linespaces(pack: &Pack) -> Result<Linespaces> {
    let bad = |err| Error::invalid(pack.path(), err);
    if let Some(e) = pack.of_kind(crate::linespace::section::KIND).next() {
        let (_, tree) = crate::linespace::section::from_section(&pack.view(e)?).map_err(bad)?;
        return Ok(Linespaces::Flat(Box::new(tree)));
    }
    if let Some(e) = pack
        .of_kind(crate::linespace::instanced_section::KIND)
        .next()
    {
        let (_, s) =
            crate::linespace::instanced_section::from_section(&pack.view(e)?).map_err(bad)?;
        return Ok(Linespaces::Scene(Box::new(s)));
    }
    Err(Error::invalid_at(
        pack.path(),
        "section table",
        "--soft-shadows needs a linespace or linespace-scene section (run `bake linespace PACK` \
         first)",
    ))
}

/// The sun's disc as a square quad light, seen from the line spaces' box.
pub fn sun_light(ls: &Linespaces, sun_direction: [f32; 3], samples: u32) -> AreaLight {
    let (lo, size) = ls.root_box();
    let diag = (size[0] * size[0] + size[1] * size[1] + size[2] * size[2]).sqrt();
    let d = glam::Vec3::from(sun_direction).normalize_or(glam::Vec3::Z);
    let centre = glam::Vec3::from(lo) + 0.5 * glam::Vec3::from(size) + d * (100.0 * diag);
    let side = 2.0 * 100.0 * diag * (0.5 * SUN_DIAMETER_DEG).to_radians().tan();
    let u = d.any_orthonormal_vector();
    let v = d.cross(u);
    let corner = centre - 0.5 * side * (u + v);
    AreaLight {
        corner: corner.to_array(),
        edge_u: (u * side).to_array(),
        edge_v: (v * side).to_array(),
        samples,
    }
}

/// A 1×1 visibility of 1 (the scene pass's binding when soft shadows are off).
pub fn fully_lit(gpu: &Gpu) -> wgpu::TextureView {
    let t = gpu.device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("sun visibility (lit)"),
            size: wgpu::Extent3d {
                width: 1,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: VISIBILITY_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::bytes_of(&1.0f32),
    );
    t.create_view(&Default::default())
}

/// The world-position pipelines (terrain, meshes) over the renderer's bind-group layouts.
struct WorldPipelines {
    terrain: wgpu::RenderPipeline,
    mesh: wgpu::RenderPipeline,
}

/// `vertex`: the entry point (meshes use `vs_shadow`, placement without the ambient term's
/// group 3).
fn world_pipeline(
    gpu: &Gpu,
    label: &str,
    vertex: &str,
    parts: &[&str],
    layouts: &[Option<&wgpu::BindGroupLayout>],
    buffers: &[Option<wgpu::VertexBufferLayout>],
) -> wgpu::RenderPipeline {
    let device = &gpu.device;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(parts.concat().into()),
    });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: layouts,
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some(vertex),
            compilation_options: Default::default(),
            buffers,
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            ..Default::default()
        },
        // Reversed Z, as the scene pass: the same nearest surface per pixel.
        depth_stencil: Some(wgpu::DepthStencilState {
            format: DEPTH_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Greater),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs_world"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: WORLD_FORMAT,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

const ATTR_POS: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![0 => Float32x3];
const ATTR_NRM: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![1 => Float32x3];
const ATTR_UV: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![2 => Float32x2];
const ATTR_INSTANCE: [wgpu::VertexAttribute; 4] = super::pipelines::INSTANCE_ATTRS;
const ATTR_TANGENT: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![6 => Float32x4];

impl WorldPipelines {
    fn new(gpu: &Gpu, pipes: &Pipelines) -> Self {
        let vb = |stride: u64, step, attributes| {
            Some(wgpu::VertexBufferLayout {
                array_stride: stride,
                step_mode: step,
                attributes,
            })
        };
        let (v, i) = (wgpu::VertexStepMode::Vertex, wgpu::VertexStepMode::Instance);
        let mesh_buffers = [
            vb(12, v, &ATTR_POS[..]),
            vb(12, v, &ATTR_NRM[..]),
            vb(8, v, &ATTR_UV[..]),
            vb(size_of::<InstanceRecord>() as u64, i, &ATTR_INSTANCE[..]),
            vb(16, v, &ATTR_TANGENT[..]),
        ];
        WorldPipelines {
            terrain: world_pipeline(
                gpu,
                "world terrain",
                "vs_main",
                &[
                    COMMON_WGSL,
                    DIRECT_WGSL,
                    AMBIENT_WGSL,
                    TERRAIN_WGSL,
                    WORLD_TERRAIN_WGSL,
                ],
                &[Some(&pipes.globals_layout), Some(&pipes.terrain_layout)],
                &[],
            ),
            mesh: world_pipeline(
                gpu,
                "world mesh",
                "vs_shadow",
                &[
                    COMMON_WGSL,
                    DIRECT_WGSL,
                    AMBIENT_WGSL,
                    MESH_WGSL,
                    WORLD_MESH_WGSL,
                ],
                &[Some(&pipes.globals_layout), Some(&pipes.material_layout)],
                &mesh_buffers,
            ),
        }
    }
}

/// Draws the receivers of every pixel into `target` (cleared to w = 0).
fn world_pass(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    enc: &mut wgpu::CommandEncoder,
    target: &wgpu::TextureView,
    size: (u32, u32),
) {
    let wp = WorldPipelines::new(gpu, pipes);
    let lit = fully_lit(gpu);
    let bg = super::draw::globals_group(gpu, pipes, scene, globals, &lit);
    let depth = super::draw::texture_2d(
        gpu,
        "world depth",
        size,
        DEPTH_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let depth_view = depth.create_view(&Default::default());
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("world positions"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: target,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &depth_view,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(0.0),
                store: wgpu::StoreOp::Discard,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    pass.set_bind_group(0, &bg, &[]);
    if let Some(t) = &scene.terrain {
        pass.set_pipeline(&wp.terrain);
        pass.set_bind_group(1, &t.bind_group, &[]);
        pass.draw(0..t.vertex_count, 0..1);
    }
    pass.set_pipeline(&wp.mesh);
    super::draw::draw_models(&mut pass, scene);
}

/// The soft-shadow visibility of every pixel of the view in `globals`.
pub fn compute_visibility(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    size: (u32, u32),
    ls: &Linespaces,
    light: &AreaLight,
) -> Result<Visibility> {
    let start = std::time::Instant::now();
    let (w, h) = size;
    let padded = w.next_multiple_of(ROW_ALIGN);
    let count = padded * h;
    let k = light.samples.max(1).pow(2);
    let (_, box_size) = ls.root_box();
    let offset = 1e-4 * box_size.iter().cloned().fold(0.0, f32::max);
    let dev = ls.to_gpu(gpu)?;
    let world_tex = super::draw::texture_2d(
        gpu,
        "world positions",
        size,
        WORLD_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    let queries = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("receivers"),
        size: 16 * (count as u64 + k as u64),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let out = crate::voxel::compute::output(gpu, "visibility", 4 * count as u64);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let world_view = world_tex.create_view(&Default::default());
    world_pass(gpu, pipes, scene, globals, &mut enc, &world_view, size);
    // Rows of `padded` texels: 16 B and 4 B per texel keep both copies 256-byte aligned.
    let rows = |bytes_per_texel: u32| wgpu::TexelCopyBufferLayout {
        offset: 0,
        bytes_per_row: Some(bytes_per_texel * padded),
        rows_per_image: Some(h),
    };
    enc.copy_texture_to_buffer(
        world_tex.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &queries,
            layout: rows(16),
        },
        world_tex.size(),
    );
    dev.record_shadow_fractions(&mut enc, &queries, count, light, offset, &out)?;
    let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
    let vis_tex = super::draw::texture_2d(gpu, "sun visibility", size, VISIBILITY_FORMAT, usage);
    let dst = wgpu::TexelCopyBufferInfo {
        buffer: &out,
        layout: rows(4),
    };
    enc.copy_buffer_to_texture(dst, vis_tex.as_image_copy(), vis_tex.size());
    gpu.queue.submit([enc.finish()]);
    gpu.check()?;
    let world_raw = crate::voxel::compute::read_back(gpu, &queries, 16 * count as u64)?;
    let vis_raw = crate::voxel::compute::read_back(gpu, &out, 4 * count as u64)?;
    let image = unpad(
        size,
        padded,
        bytemuck::cast_slice(&world_raw),
        bytemuck::cast_slice(&vis_raw),
        light,
        offset,
        start,
    );
    Ok(Visibility {
        view: vis_tex.create_view(&Default::default()),
        texture: vis_tex,
        image,
    })
}

fn unpad(
    (w, h): (u32, u32),
    padded: u32,
    world: &[[f32; 4]],
    vis: &[f32],
    light: &AreaLight,
    offset: f32,
    start: std::time::Instant,
) -> SoftShadowImage {
    let rows = |y: u32| (y * padded) as usize..(y * padded + w) as usize;
    let world: Vec<[f32; 4]> = (0..h)
        .flat_map(|y| world[rows(y)].iter().copied())
        .collect();
    let visibility: Vec<f32> = (0..h).flat_map(|y| vis[rows(y)].iter().copied()).collect();
    let drawn = || world.iter().zip(&visibility).filter(|(p, _)| p[3] > 0.5);
    let stats = SoftShadowStats {
        receivers: drawn().count() as u64,
        samples: light.samples.max(1).pow(2),
        penumbra_pixels: drawn().filter(|(_, v)| **v > 0.0 && **v < 1.0).count() as u64,
        shadowed_pixels: drawn().filter(|(_, v)| **v == 0.0).count() as u64,
        seconds: start.elapsed().as_secs_f64(),
    };
    SoftShadowImage {
        width: w,
        height: h,
        world,
        visibility,
        light: *light,
        offset,
        stats,
        comparison: None,
    }
}

/// The render's soft-shadow pass: the pack's N-tree, the explicit light or the sun's disc.
#[allow(clippy::too_many_arguments)]
pub fn for_render(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    size: (u32, u32),
    pack: &Pack,
    lighting: &super::Lighting,
    opts: &SoftShadows,
) -> Result<Visibility> {
    let mut ls = load_linespaces(pack)?;
    ls.set_refine(opts.refine);
    let samples = opts.samples.clamp(1, 64);
    let light = match opts.area_light {
        Some(l) => AreaLight { samples, ..l },
        None => sun_light(&ls, lighting.sun_direction, samples),
    };
    let mut v = compute_visibility(gpu, pipes, scene, globals, size, &ls, &light)?;
    if opts.compare_exact {
        v.image.comparison = Some(compare_with_exact(gpu, &ls, &v.image)?);
    }
    Ok(v)
}

/// Runs the `shadow` kernel over the image's receivers with line spaces and without (exact),
/// timing each, and compares the fractions.
pub fn compare_with_exact(
    gpu: &Gpu,
    ls: &Linespaces,
    image: &SoftShadowImage,
) -> Result<SoftShadowComparison> {
    let receivers: Vec<crate::linespace::gpu::Receiver> = image
        .world
        .iter()
        .map(|p| (p[3] > 0.5).then_some([p[0], p[1], p[2]]))
        .collect();
    let dev = ls.to_gpu(gpu)?;
    let (light, offset) = (&image.light, image.offset);
    let t0 = std::time::Instant::now();
    let lit = dev.shadow_fractions_with(&receivers, light, offset, true)?;
    let t1 = std::time::Instant::now();
    let exact = dev.shadow_fractions_with(&receivers, light, offset, false)?;
    let t2 = std::time::Instant::now();
    let drawn: Vec<(f64, f64)> = receivers
        .iter()
        .zip(lit.iter().zip(&exact))
        .filter(|(r, _)| r.is_some())
        .map(|(_, (&l, &e))| (l as f64, e as f64))
        .collect();
    let n = drawn.len().max(1) as f64;
    Ok(SoftShadowComparison {
        refine: ls.refine(),
        receivers: drawn.len() as u64,
        samples: light.samples.max(1).pow(2),
        linespace_seconds: (t1 - t0).as_secs_f64(),
        exact_seconds: (t2 - t1).as_secs_f64(),
        mean_abs_error: drawn.iter().map(|(l, e)| (l - e).abs()).sum::<f64>() / n,
        max_abs_error: drawn.iter().map(|(l, e)| (l - e).abs()).fold(0.0, f64::max),
        darker_pixels: drawn.iter().filter(|(l, e)| e - l > 0.1).count() as u64,
        brighter_pixels: drawn.iter().filter(|(l, e)| l > e).count() as u64,
    })
}

/// Parses `--area-light cx,cy,cz,ux,uy,uz,vx,vy,vz` (corner, edge u, edge v; metres).
pub fn parse_area_light(s: &str) -> std::result::Result<AreaLight, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("{s:?}: expected 9 numbers cx,cy,cz,ux,uy,uz,vx,vy,vz"))?;
    if v.len() != 9 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!(
            "{s:?}: expected 9 finite numbers cx,cy,cz,ux,uy,uz,vx,vy,vz"
        ));
    }
    Ok(AreaLight {
        corner: [v[0], v[1], v[2]],
        edge_u: [v[3], v[4], v[5]],
        edge_v: [v[6], v[7], v[8]],
        samples: 4,
    })
}
