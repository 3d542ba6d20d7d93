//! Drawing skeletons: where [`crate::lod::select::choose`] gives an instance
//! [`crate::lod::select::Choice::Skeleton`] (its model's bounding sphere projects to at most
//! `skeleton.pixels` pixels of radius), the renderer draws the model's own line and point arrays
//! (TXF `<line_array>`, `<point_array>`, kept by the `lod` stage) instead of a mesh or an
//! impostor: all of a model's skeleton instances in one instanced line-list draw and one
//! instanced point-list draw (`shaders/skeleton.wgsl`; lines and points one pixel wide).
//!
//! - **Place:** each position `p` goes to `R_z(θ)·(s·p) + t`, the instance transform of the
//!   meshes.
//! - **Colour:** the model's mean albedo (`lod` section, `skeleton.albedo`: the surface's area
//!   mean with alpha-tested holes left out), lit as a surface facing +Z: the sun by Lambert with
//!   the shadow-map lookup, the sky SH irradiance at +Z as the ambient term.
//! - **Shadows:** skeleton instances cast none (a model of a pixel or two covers less than one
//!   texel of the far cascades).
//! - **Counts:** `skeleton_instances` in the statistics; segments and points are not triangles
//!   and are not counted in `triangles`.

use super::draw::{CAMERA_PASS, DrawCounts, FrameInstances};
use super::pipelines;
use super::scene::SkeletonData;
use super::upload::{GpuScene, Uploader};
use bytemuck::{Pod, Zeroable};

/// `shaders/skeleton.wgsl` `SkeletonParams`: 16 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SkeletonParams {
    albedo: [f32; 4],
}

/// One model's skeleton on the GPU.
pub struct SkeletonGpu {
    pub bind_group: wgpu::BindGroup,
    /// Segment end points (two per segment) and their count.
    pub lines: Option<(wgpu::Buffer, u32)>,
    /// Points and their count.
    pub points: Option<(wgpu::Buffer, u32)>,
}

/// The skeleton passes' pipelines (line list, point list) and their group 1 layout.
pub struct SkeletonPipeline {
    pub layout: wgpu::BindGroupLayout,
    pub lines: wgpu::RenderPipeline,
    pub points: wgpu::RenderPipeline,
}

impl SkeletonPipeline {
    pub(super) fn new(
        device: &wgpu::Device,
        globals: &wgpu::BindGroupLayout,
        shadow: &wgpu::BindGroupLayout,
        ambient: &wgpu::BindGroupLayout,
        samples: u32,
    ) -> SkeletonPipeline {
        use wgpu::ShaderStages as S;
        let layout = pipelines::layout(
            device,
            "skeleton",
            &[pipelines::uniform_entry(0, S::FRAGMENT)],
        );
        let module = pipelines::shader(
            device,
            "skeleton",
            &[
                pipelines::COMMON_WGSL,
                pipelines::DIRECT_WGSL,
                pipelines::AMBIENT_WGSL,
                include_str!("shaders/skeleton.wgsl"),
            ],
        );
        let buffers = [
            Some(wgpu::VertexBufferLayout {
                array_stride: 12,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &[wgpu::VertexAttribute {
                    format: wgpu::VertexFormat::Float32x3,
                    offset: 0,
                    shader_location: 0,
                }],
            }),
            Some(wgpu::VertexBufferLayout {
                array_stride: size_of::<crate::ingest::instances_section::InstanceRecord>() as u64,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &pipelines::INSTANCE_ATTRS,
            }),
        ];
        let layouts = [Some(globals), Some(&layout), Some(shadow), Some(ambient)];
        let pass = |label, topology| {
            pipelines::pipeline(
                device,
                &pipelines::hdr_pass(label, &module, &layouts, &buffers, Some(true))
                    .multisampled(samples, false)
                    .primitives(topology),
            )
        };
        SkeletonPipeline {
            lines: pass("skeleton lines", wgpu::PrimitiveTopology::LineList),
            points: pass("skeleton points", wgpu::PrimitiveTopology::PointList),
            layout,
        }
    }
}

/// Uploads a model's skeleton (`label`: its mesh section); `leaves`: the model has alpha-tested
/// materials (the region pass counts it as leaves).
pub(super) fn upload(
    up: &mut Uploader,
    pipe: &SkeletonPipeline,
    label: &str,
    d: &SkeletonData,
    leaves: bool,
) -> SkeletonGpu {
    let lin = |c: u8| crate::color::srgb_to_linear(c as f32 / 255.0);
    let params = SkeletonParams {
        albedo: [
            lin(d.albedo[0]),
            lin(d.albedo[1]),
            lin(d.albedo[2]),
            if leaves { 1.0 } else { 0.0 },
        ],
    };
    let params = up.buffer(
        &format!("{label}: skeleton colour"),
        bytemuck::bytes_of(&params),
        wgpu::BufferUsages::UNIFORM,
    );
    let bind_group = up.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("skeleton"),
        layout: &pipe.layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: params.as_entire_binding(),
        }],
    });
    let mut vertices = |what: &str, p: &[[f32; 3]]| {
        (!p.is_empty()).then(|| {
            let b = up.buffer(
                &format!("{label}: skeleton {what}"),
                bytemuck::cast_slice(p),
                wgpu::BufferUsages::VERTEX,
            );
            (b, p.len() as u32)
        })
    };
    SkeletonGpu {
        lines: vertices("lines", &d.lines),
        points: vertices("points", &d.points),
        bind_group,
    }
}

/// The camera pass's skeletons: per model with one, its skeleton bucket (the last level) as one
/// instanced line draw and one instanced point draw. Groups 0 and 2 are the scene pass's.
pub(super) fn draw(
    pass: &mut wgpu::RenderPass,
    pipe: &SkeletonPipeline,
    scene: &GpuScene,
    frame: &FrameInstances,
    counts: &mut DrawCounts,
) {
    for (which, pipeline) in [(0, &pipe.lines), (1, &pipe.points)] {
        let mut bound = false;
        for (k, m) in scene.models.iter().enumerate() {
            let Some(sk) = &m.skeleton else {
                continue;
            };
            let level = m.levels.len() + m.impostor.is_some() as usize;
            let range = frame.buckets[k].range(CAMERA_PASS, level);
            let part = if which == 0 { &sk.lines } else { &sk.points };
            if range.is_empty() {
                continue;
            }
            if which == 0 {
                counts.instances += range.len() as u64;
                counts.skeleton_instances += range.len() as u64;
            }
            let Some((buffer, n)) = part else {
                continue;
            };
            if !bound {
                pass.set_pipeline(pipeline);
                if let Some(a) = &scene.ambient {
                    pass.set_bind_group(3, &a.terrain, &[]);
                }
                bound = true;
            }
            pass.set_bind_group(1, &sk.bind_group, &[]);
            pass.set_vertex_buffer(0, buffer.slice(..));
            pass.set_vertex_buffer(1, frame.buffers[k].slice(..));
            pass.draw(0..*n, range.clone());
            counts.draw_calls += 1;
        }
    }
}
