//! Drawing one frame: per-frame constants, the sun's shadow map (terrain and alpha-tested
//! models, depth only), the scene pass into the HDR target (sky, terrain, instanced models), the
//! tone-map pass into the sRGB output, and the readback.

use super::camera::Camera;
use super::light::Lighting;
use super::pipelines::{DEPTH_FORMAT, HDR_FORMAT, OUTPUT_FORMAT, Pipelines, SHADOW_FORMAT};
use super::shadow::{SHADOW_MAP_SIZE, ShadowParams};
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
            sun_irradiance: v4(light.sun_irradiance, 0.0),
            ambient: v4(light.ambient, 0.0),
            viewport: [size.0 as f32, size.1 as f32, kd, ka],
        }
    }
}

/// What a frame drew.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct DrawCounts {
    pub draw_calls: u32,
    pub triangles: u64,
    pub instances: u64,
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
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: size.0,
            height: size.1,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
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
    let buf = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("globals"),
            contents: bytemuck::bytes_of(globals),
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
        ],
    })
}

/// Draws the scene and returns the tone-mapped image as tightly packed RGBA8 rows (sRGB).
/// `shadow`: the sun's shadow-map view (`None`: no shadow map, everything sees the sun).
/// `sun_visibility`: the soft-shadow visibility per pixel (used where `globals.sun_direction.w`
/// is 1, see src/render/soft_shadow.rs).
pub fn draw_frame(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    size: (u32, u32),
    shadow: Option<&ShadowParams>,
    sun_visibility: &wgpu::TextureView,
) -> Result<(Vec<u8>, DrawCounts)> {
    let hdr = target(gpu, "hdr", size, HDR_FORMAT, false);
    let depth = target(gpu, "depth", size, DEPTH_FORMAT, false);
    let out = target(gpu, "output", size, OUTPUT_FORMAT, true);
    let hdr_view = hdr.create_view(&Default::default());
    let globals_bg = globals_group(gpu, pipes, scene, globals, sun_visibility);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let shadow_bg = shadow_group(gpu, pipes, scene, globals, shadow, sun_visibility, &mut enc);
    let counts = scene_pass(
        &mut enc,
        pipes,
        scene,
        [&globals_bg, &shadow_bg],
        &hdr_view,
        &depth.create_view(&Default::default()),
    );
    tonemap_pass(
        gpu,
        &mut enc,
        pipes,
        &hdr_view,
        &out.create_view(&Default::default()),
        globals.eye[3],
    );
    gpu.queue.submit([enc.finish()]);
    gpu.check()?;
    let pixels = gpu.read_texture_rgba8(&out)?;
    Ok((pixels, counts))
}

/// Renders the shadow map (when `params` is given) and returns bind group 2 of the scene pass.
fn shadow_group(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &GpuScene,
    globals: &Globals,
    params: Option<&ShadowParams>,
    sun_visibility: &wgpu::TextureView,
    enc: &mut wgpu::CommandEncoder,
) -> wgpu::BindGroup {
    let side = if params.is_some() { SHADOW_MAP_SIZE } else { 1 };
    let map = target(gpu, "shadow map", (side, side), SHADOW_FORMAT, false);
    let view = map.create_view(&Default::default());
    let off = ShadowParams {
        light_view_proj: glam::Mat4::IDENTITY.to_cols_array_2d(),
        params: [1.0, 0.0, 0.0, 0.0],
    };
    let p = params.copied().unwrap_or(off);
    if params.is_some() {
        let light = Globals {
            view_proj: p.light_view_proj,
            ..*globals
        };
        let bg = globals_group(gpu, pipes, scene, &light, sun_visibility);
        shadow_pass(enc, pipes, scene, &bg, &view);
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

/// Depth of the terrain and every instance as seen from the sun (alpha-tested models).
fn shadow_pass(
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    scene: &GpuScene,
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
        pass.draw(0..t.vertex_count, 0..1);
    }
    pass.set_pipeline(&pipes.mesh_shadow);
    draw_models(&mut pass, scene);
}

/// Every draw range of every model, with its material in bind group 1 (passes without the
/// ambient term's group 3).
pub(crate) fn draw_models(pass: &mut wgpu::RenderPass, scene: &GpuScene) {
    for m in &scene.models {
        bind_model(pass, m);
        for d in &m.draws {
            pass.set_bind_group(1, &m.materials[d.material as usize], &[]);
            pass.draw_indexed(d.first * 3..(d.first + d.count) * 3, 0, 0..m.instance_count);
        }
    }
}

/// The vertex and index buffers of a model (slots as in pipelines.rs).
fn bind_model(pass: &mut wgpu::RenderPass, m: &super::upload::ModelGpu) {
    pass.set_vertex_buffer(0, m.positions.slice(..));
    pass.set_vertex_buffer(1, m.normals.slice(..));
    pass.set_vertex_buffer(2, m.uvs.slice(..));
    pass.set_vertex_buffer(3, m.instances.slice(..));
    pass.set_vertex_buffer(4, m.tangents.slice(..));
    pass.set_index_buffer(m.indices.slice(..), wgpu::IndexFormat::Uint32);
}

fn scene_pass(
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    scene: &GpuScene,
    [globals_bg, shadow_bg]: [&wgpu::BindGroup; 2],
    hdr: &wgpu::TextureView,
    depth: &wgpu::TextureView,
) -> DrawCounts {
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("scene"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: hdr,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                store: wgpu::StoreOp::Store,
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
    let mut counts = DrawCounts::default();
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
        pass.draw(0..t.vertex_count, 0..1);
        counts.draw_calls += 1;
        counts.triangles += t.vertex_count as u64 / 3;
    }
    pass.set_pipeline(&pipes.mesh);
    for (k, m) in scene.models.iter().enumerate() {
        bind_model(&mut pass, m);
        for d in &m.draws {
            pass.set_bind_group(1, &m.materials[d.material as usize], &[]);
            if let Some(a) = &scene.ambient {
                pass.set_bind_group(3, &a.models[k][d.material as usize], &[]);
            }
            pass.draw_indexed(d.first * 3..(d.first + d.count) * 3, 0, 0..m.instance_count);
            counts.draw_calls += 1;
            counts.triangles += d.count as u64 * m.instance_count as u64;
        }
        counts.instances += m.instance_count as u64;
    }
    counts
}

fn tonemap_pass(
    gpu: &Gpu,
    enc: &mut wgpu::CommandEncoder,
    pipes: &Pipelines,
    hdr: &wgpu::TextureView,
    out: &wgpu::TextureView,
    exposure: f32,
) {
    let params = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tone"),
            contents: bytemuck::bytes_of(&[exposure, 0.0, 0.0, 0.0]),
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
