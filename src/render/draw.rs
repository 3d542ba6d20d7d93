//! Drawing one frame: per-frame constants, the sun's shadow map (terrain and alpha-tested
//! models, depth only), the scene pass into the HDR target (sky, terrain, instanced models), the
//! tone-map pass into the sRGB output, and the readback.

use super::camera::Camera;
use super::light::Lighting;
use super::pipelines::{DEPTH_FORMAT, HDR_FORMAT, OUTPUT_FORMAT, Pipelines, SHADOW_FORMAT};
use super::shadow::{ShadowParams, Shadows};
use super::upload::GpuScene;
use crate::error::Result;
use crate::gpu::Gpu;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// Per-frame constants (shaders/common.wgsl `Globals`): repr(C), Pod, 192 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Globals {
    pub view_proj: [[f32; 4]; 4],
    /// xyz camera position, w exposure
    pub eye: [f32; 4],
    /// right · tan(fov/2) · aspect
    pub cam_right: [f32; 4],
    /// up · tan(fov/2)
    pub cam_up: [f32; 4],
    pub cam_forward: [f32; 4],
    pub sun_direction: [f32; 4],
    pub sun_irradiance: [f32; 4],
    pub ambient: [f32; 4],
    /// width, height, then the weights of the direct and ambient terms (1 or 0)
    pub viewport: [f32; 4],
}
const _: () = assert!(size_of::<Globals>() == 192);

fn v4(v: [f32; 3], w: f32) -> [f32; 4] {
    [v[0], v[1], v[2], w]
}

impl Globals {
    pub fn new(
        cam: &Camera,
        light: &Lighting,
        exposure: f32,
        size: (u32, u32),
        terms: super::Terms,
    ) -> Globals {
        let [kd, ka] = terms.weights();
        let b = cam.basis();
        let ty = (cam.fov_y_deg.to_radians() * 0.5).tan();
        Globals {
            view_proj: cam.view_proj().to_cols_array_2d(),
            eye: v4(cam.eye.to_array(), exposure),
            cam_right: v4((b.right * ty * cam.aspect).to_array(), 0.0),
            cam_up: v4((b.up * ty).to_array(), 0.0),
            cam_forward: v4(b.forward.to_array(), 0.0),
            sun_direction: v4(light.sun_direction, 0.0),
            sun_irradiance: v4(light.sun_irradiance, light.sun_solid_angle),
            ambient: v4(light.ambient, 0.0),
            viewport: [size.0 as f32, size.1 as f32, kd, ka],
        }
    }
}

/// What a frame drew.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct DrawCounts {
    pub draw_calls: u32,
    /// Triangles of the camera pass (terrain and models).
    pub triangles: u64,
    /// Instances drawn by the camera pass (impostors included).
    pub instances: u64,
    /// Of `instances`, those drawn as impostors (two triangles each, counted in `triangles`).
    pub impostor_instances: u64,
    /// Of `instances`, those drawn as skeletons (lines and points, not in `triangles`).
    pub skeleton_instances: u64,
    /// Triangles of the shadow passes.
    pub shadow_triangles: u64,
    /// Of `triangles`, the terrain's (chunk surfaces and skirts, zero-area ones past the grid
    /// included).
    pub terrain_triangles: u64,
}

/// The frame's instance buckets ([`super::cull::bucket`]) and, per model, their records on the
/// GPU (vertex slot 3).
pub struct FrameInstances {
    pub buckets: Vec<super::cull::ModelBuckets>,
    pub buffers: Vec<wgpu::Buffer>,
    /// The terrain chunks of each pass: (step log2, chunk records on the GPU, chunk count).
    pub terrain: Vec<Vec<(u32, wgpu::Buffer, u32)>>,
}

impl FrameInstances {
    pub fn upload(
        gpu: &Gpu,
        buckets: Vec<super::cull::ModelBuckets>,
        chunks: &[super::terrain_lod::Selection],
    ) -> FrameInstances {
        let terrain = chunks
            .iter()
            .map(|sel| {
                sel.by_step
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| !c.is_empty())
                    .map(|(s, c)| {
                        let b = gpu
                            .device
                            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                                label: Some("terrain chunks"),
                                contents: bytemuck::cast_slice(c),
                                usage: wgpu::BufferUsages::VERTEX,
                            });
                        (s as u32, b, c.len() as u32)
                    })
                    .collect()
            })
            .collect();
        let buffers = buckets
            .iter()
            .map(|b| {
                // wgpu refuses empty vertex buffers: an unused record stands in.
                let empty = [bytemuck::Zeroable::zeroed()];
                let recs: &[crate::ingest::instances_section::InstanceRecord] =
                    if b.records.is_empty() {
                        &empty
                    } else {
                        &b.records
                    };
                gpu.device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some("frame instances"),
                        contents: bytemuck::cast_slice(recs),
                        usage: wgpu::BufferUsages::VERTEX,
                    })
            })
            .collect();
        FrameInstances {
            buckets,
            buffers,
            terrain,
        }
    }
}

fn target(
    gpu: &Gpu,
    label: &str,
    size: (u32, u32),
    format: wgpu::TextureFormat,
    copy: bool,
) -> wgpu::Texture {
    let mut usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
    if copy {
        usage |= wgpu::TextureUsages::COPY_SRC;
    }
    texture_2d(gpu, label, size, format, usage)
}

/// A single-level 2D texture (also the soft-shadow pass's targets).
pub(crate) fn texture_2d(
    gpu: &Gpu,
    label: &str,
    size: (u32, u32),
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    texture_2d_samples(gpu, label, size, format, usage, 1)
}

/// A single-level 2D texture of `samples` samples per texel (the scene pass's MSAA targets).
fn texture_2d_samples(
    gpu: &Gpu,
    label: &str,
    size: (u32, u32),
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
    samples: u32,
) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: size.0,
            height: size.1,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: samples,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// Group 0: the per-frame constants, the sky and the soft-shadow visibility.
pub(crate) fn globals_group(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    sun_visibility: &wgpu::TextureView,
) -> wgpu::BindGroup {
    // cam_forward.w: 1 where the sky pass samples the cube.
    let mut globals = *globals;
    globals.cam_forward[3] = if scene.sky_is_cube { 1.0 } else { 0.0 };
    let buf = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("globals"),
            contents: bytemuck::bytes_of(&globals),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("globals"),
        layout: &pipes.globals_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(&scene.sky_view),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(sun_visibility),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::TextureView(&scene.sky_cube),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::Sampler(&scene.sky_sampler),
            },
        ],
    })
}

/// Draws the scene and returns the tone-mapped image as tightly packed RGBA8 rows (sRGB, or
/// `encoding`'s power law), and with `linear` the resolved linear radiance it was made from.
/// `shadow`: the sun's cascades (`None`: no shadow map, everything sees the sun).
/// `sun_visibility`: the soft-shadow visibility per pixel (used where `globals.sun_direction.w`
/// is 1, see src/render/soft_shadow.rs). `frame`: the instances each pass draws, per level.
#[allow(clippy::too_many_arguments)]
pub fn draw_frame(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    size: (u32, u32),
    shadow: Option<&Shadows>,
    sun_visibility: &wgpu::TextureView,
    frame: &FrameInstances,
    encoding: super::Encoding,
    linear: bool,
) -> Result<DrawnFrame> {
    let hdr = target(gpu, "hdr", size, HDR_FORMAT, linear);
    let out = target(gpu, "output", size, OUTPUT_FORMAT, true);
    let hdr_view = hdr.create_view(&Default::default());
    // Under MSAA the scene pass draws into multisampled colour and depth and resolves the
    // colour (the linear radiance) into `hdr`, which the tone map reads.
    let samples = pipes.samples;
    let attachment = |label, format| {
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
        texture_2d_samples(gpu, label, size, format, usage, samples)
    };
    let depth = attachment("depth", DEPTH_FORMAT);
    let hdr_ms = (samples > 1).then(|| attachment("hdr samples", HDR_FORMAT));
    let hdr_ms_view = hdr_ms.as_ref().map(|t| t.create_view(&Default::default()));
    let globals_bg = globals_group(gpu, pipes, scene, globals, sun_visibility);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let mut counts = DrawCounts::default();
    let shadow_bg = shadow_group(
        gpu,
        pipes,
        scene,
        globals,
        shadow,
        sun_visibility,
        (frame, &mut counts),
        &mut enc,
    );
    scene_pass(
        &mut enc,
        pipes,
        scene,
        (frame, &mut counts),
        [&globals_bg, &shadow_bg],
        (
            hdr_ms_view.as_ref().unwrap_or(&hdr_view),
            hdr_ms_view.as_ref().map(|_| &hdr_view),
        ),
        &depth.create_view(&Default::default()),
    );
    tonemap_pass(
        gpu,
        &mut enc,
        pipes,
        &hdr_view,
        &out.create_view(&Default::default()),
        match encoding {
            super::Encoding::Srgb => [globals.eye[3], 0.0, 0.0, 0.0],
            super::Encoding::Gamma(g) => [globals.eye[3], 1.0, g, 0.0],
        },
    );
    gpu.queue.submit([enc.finish()]);
    gpu.check()?;
    let pixels = gpu.read_texture_rgba8(&out)?;
    let linear = if linear {
        let bytes = gpu.read_texture(&hdr, 8)?;
        let halves: Vec<u16> = bytes
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        Some(
            halves
                .chunks_exact(4)
                .map(|t| [0, 1, 2, 3].map(|c| half::f16::from_bits(t[c]).to_f32()))
                .collect(),
        )
    } else {
        None
    };
    Ok(DrawnFrame {
        pixels,
        linear,
        counts,
    })
}

/// What [`draw_frame`] returns.
pub struct DrawnFrame {
    /// The tone-mapped image, tightly packed RGBA8 rows.
    pub pixels: Vec<u8>,
    /// The resolved linear radiance before the tone map (RGBA, row 0 at the top), when asked.
    pub linear: Option<Vec<[f32; 4]>>,
    pub counts: DrawCounts,
}

/// Renders the cascades' shadow maps (when `shadows` is given), one layer of an array texture
/// each (bucket pass `SHADOW_PASS + i`), and returns bind group 2 of the scene pass.
#[allow(clippy::too_many_arguments)]
fn shadow_group(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    shadows: Option<&Shadows>,
    sun_visibility: &wgpu::TextureView,
    (frame, counts): (&FrameInstances, &mut DrawCounts),
    enc: &mut wgpu::CommandEncoder,
) -> wgpu::BindGroup {
    let (side, layers) = shadows.map_or((1, 1), |s| (s.size, s.cascades.len() as u32));
    // The shader reads a `D2Array` view: on GL a one-layer texture could not give one.
    let layers = gpu.array_layers(layers);
    let map = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("shadow maps"),
        size: wgpu::Extent3d {
            width: side,
            height: side,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: SHADOW_FORMAT,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    });
    let view = map.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    // Without a map the shader sees a cascade count of 0 and reads nothing.
    let p = shadows.map_or(ShadowParams::zeroed(), |s| {
        s.params(glam::Vec3::from_slice(&globals.cam_forward[..3]))
    });
    for (i, c) in shadows
        .map_or(&[][..], |s| &s.cascades[..])
        .iter()
        .enumerate()
    {
        let light = Globals {
            view_proj: c.view_proj.to_cols_array_2d(),
            ..*globals
        };
        let bg = globals_group(gpu, pipes, scene, &light, sun_visibility);
        let layer = map.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2),
            base_array_layer: i as u32,
            array_layer_count: Some(1),
            ..Default::default()
        });
        shadow_pass(
            enc,
            pipes,
            scene,
            (frame, counts),
            SHADOW_PASS + i,
            &bg,
            &layer,
        );
    }
    let buf = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow params"),
            contents: bytemuck::bytes_of(&p),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    let sampler = gpu.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("shadow"),
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        compare: Some(wgpu::CompareFunction::LessEqual),
        ..Default::default()
    });
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("shadow"),
        layout: &pipes.shadow_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(&view),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::Sampler(&sampler),
            },
        ],
    })
}

/// Depth of the terrain and the instances of bucket pass `p` as seen from the sun
/// (alpha-tested models).
fn shadow_pass(
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    scene: &GpuScene,
    (frame, counts): (&FrameInstances, &mut DrawCounts),
    p: usize,
    light_bg: &wgpu::BindGroup,
    map: &wgpu::TextureView,
) {
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("shadow"),
        color_attachments: &[],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: map,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(1.0),
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    pass.set_bind_group(0, light_bg, &[]);
    if let Some(t) = &scene.terrain {
        pass.set_pipeline(&pipes.terrain_shadow);
        pass.set_bind_group(1, &t.bind_group, &[]);
        counts.shadow_triangles += draw_chunks(&mut pass, frame, p);
    }
    pass.set_pipeline(&pipes.mesh_shadow);
    counts.shadow_triangles += draw_levels(&mut pass, scene, frame, p, |_, _, _, _| {}).triangles;
    counts.shadow_triangles +=
        super::impostor::draw_shadow(&mut pass, &pipes.impostor, scene, frame, p);
}

/// The terrain chunks of pass `p`, one instanced draw per step; returns the triangles drawn.
fn draw_chunks(pass: &mut wgpu::RenderPass, frame: &FrameInstances, p: usize) -> u64 {
    let mut triangles = 0;
    for (s, buf, n) in frame.terrain.get(p).map_or(&[][..], |t| &t[..]) {
        let v = super::terrain_lod::vertices_per_chunk(*s);
        pass.set_vertex_buffer(0, buf.slice(..));
        pass.draw(0..v, 0..*n);
        triangles += v as u64 / 3 * *n as u64;
    }
    triangles
}

/// The bucket pass of the first cascade (cascade i is pass `SHADOW_PASS + i`).
pub const SHADOW_PASS: usize = 1;

/// Every draw range of every model at full detail with all its instances, with its material in
/// bind group 1 (passes without the ambient term's group 3).
pub(crate) fn draw_models(pass: &mut wgpu::RenderPass, scene: &GpuScene) {
    for m in &scene.models {
        let level = &m.levels[0];
        bind_level(pass, level, &m.instances);
        for d in &level.draws {
            pass.set_bind_group(1, &m.materials[d.material as usize], &[]);
            pass.draw_indexed(d.first * 3..(d.first + d.count) * 3, 0, 0..m.instance_count);
        }
    }
}

/// What [`draw_levels`] drew.
#[derive(Debug, Default, Clone, Copy)]
struct Drawn {
    draw_calls: u32,
    triangles: u64,
    instances: u64,
}

/// The mesh levels of bucket pass `p`: per model, level and material range one instanced draw
/// with the material in group 1; `per_draw(pass, model, level, material)` binds what else a
/// pass needs before each draw (the scene pass's ambient group).
fn draw_levels(
    pass: &mut wgpu::RenderPass,
    scene: &GpuScene,
    frame: &FrameInstances,
    p: usize,
    mut per_draw: impl FnMut(&mut wgpu::RenderPass, usize, usize, usize),
) -> Drawn {
    let mut drawn = Drawn::default();
    for (k, m) in scene.models.iter().enumerate() {
        for (l, level) in m.levels.iter().enumerate() {
            let range = frame.buckets[k].range(p, l);
            if range.is_empty() {
                continue;
            }
            bind_level(pass, level, &frame.buffers[k]);
            for d in &level.draws {
                pass.set_bind_group(1, &m.materials[d.material as usize], &[]);
                per_draw(pass, k, l, d.material as usize);
                pass.draw_indexed(d.first * 3..(d.first + d.count) * 3, 0, range.clone());
                drawn.draw_calls += 1;
                drawn.triangles += d.count as u64 * range.len() as u64;
            }
            drawn.instances += range.len() as u64;
        }
    }
    drawn
}

/// The vertex and index buffers of a model level and an instance buffer (slots as in
/// pipelines.rs).
fn bind_level(pass: &mut wgpu::RenderPass, m: &super::upload::LevelGpu, instances: &wgpu::Buffer) {
    pass.set_vertex_buffer(0, m.positions.slice(..));
    pass.set_vertex_buffer(1, m.normals.slice(..));
    pass.set_vertex_buffer(2, m.uvs.slice(..));
    pass.set_vertex_buffer(3, instances.slice(..));
    pass.set_vertex_buffer(4, m.tangents.slice(..));
    pass.set_index_buffer(m.indices.slice(..), wgpu::IndexFormat::Uint32);
}

fn scene_pass(
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    scene: &GpuScene,
    (frame, counts): (&FrameInstances, &mut DrawCounts),
    [globals_bg, shadow_bg]: [&wgpu::BindGroup; 2],
    (hdr, resolve): (&wgpu::TextureView, Option<&wgpu::TextureView>),
    depth: &wgpu::TextureView,
) {
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("scene"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: hdr,
            depth_slice: None,
            resolve_target: resolve,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                // The samples are needed only until they are resolved.
                store: if resolve.is_some() {
                    wgpu::StoreOp::Discard
                } else {
                    wgpu::StoreOp::Store
                },
            },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            // Reversed Z: 0 is infinitely far.
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
    pass.set_bind_group(0, globals_bg, &[]);
    pass.set_bind_group(2, shadow_bg, &[]);
    // The sky first, without depth writes: everything else covers it.
    pass.set_pipeline(&pipes.sky);
    pass.draw(0..3, 0..1);
    counts.draw_calls += 1;
    if let Some(t) = &scene.terrain {
        pass.set_pipeline(&pipes.terrain);
        pass.set_bind_group(1, &t.bind_group, &[]);
        if let Some(a) = &scene.ambient {
            pass.set_bind_group(3, &a.terrain, &[]);
        }
        counts.terrain_triangles = draw_chunks(&mut pass, frame, CAMERA_PASS);
        counts.triangles += counts.terrain_triangles;
        counts.draw_calls += frame.terrain.get(CAMERA_PASS).map_or(0, |t| t.len() as u32);
    }
    pass.set_pipeline(&pipes.mesh);
    let drawn = draw_levels(
        &mut pass,
        scene,
        frame,
        CAMERA_PASS,
        |pass, k, l, material| {
            if let Some(a) = &scene.ambient {
                pass.set_bind_group(3, &a.models[k][l][material], &[]);
            }
        },
    );
    counts.draw_calls += drawn.draw_calls;
    counts.triangles += drawn.triangles;
    counts.instances += drawn.instances;
    super::impostor::draw(&mut pass, &pipes.impostor, scene, frame, counts);
    super::skeleton::draw(&mut pass, &pipes.skeleton, scene, frame, counts);
}

/// The bucket pass of the camera.
pub const CAMERA_PASS: usize = 0;

fn tonemap_pass(
    gpu: &Gpu,
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    hdr: &wgpu::TextureView,
    out: &wgpu::TextureView,
    tone: [f32; 4],
) {
    let params = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tone"),
            contents: bytemuck::bytes_of(&tone),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    let bg = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("tonemap"),
        layout: &pipes.tonemap_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(hdr),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: params.as_entire_binding(),
            },
        ],
    });
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("tonemap"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: out,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: None,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    pass.set_pipeline(&pipes.tonemap);
    pass.set_bind_group(0, &bg, &[]);
    pass.draw(0..3, 0..1);
}
