//! The render pipelines and their bind-group layouts: sky, terrain, instanced meshes (all into the
//! `Rgba16Float` HDR target with a reversed-Z `Depth32Float` buffer) and the tone map into the
//! `Rgba8UnormSrgb` output. Shaders live in `shaders/*.wgsl`; `common.wgsl` is prepended to the
//! scene passes. Replacing the shading (PRT, Schlick, shadow maps) means a new pipeline here and
//! a new shader, nothing else.

use crate::ingest::instances_section::InstanceRecord;

/// Format of the HDR scene target.
pub const HDR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Format of the depth buffer (reversed Z: cleared to 0, nearer is greater).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Format of the displayed image (the hardware applies the sRGB encoding on store).
pub const OUTPUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

pub(super) const COMMON_WGSL: &str = include_str!("shaders/common.wgsl");
const SKY_WGSL: &str = include_str!("shaders/sky.wgsl");
const TERRAIN_WGSL: &str = include_str!("shaders/terrain.wgsl");
pub(super) const MESH_WGSL: &str = include_str!("shaders/mesh.wgsl");
pub(super) const DIRECT_WGSL: &str = include_str!("shaders/direct.wgsl");
/// Format of the sun's shadow map (orthographic, normal Z: cleared to 1, nearer is smaller).
pub const SHADOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const TONEMAP_WGSL: &str = include_str!("shaders/tonemap.wgsl");
pub(super) const AMBIENT_WGSL: &str = concat!(
    include_str!("../sh/basis.wgsl"),
    include_str!("shaders/ambient.wgsl")
);

/// Every pipeline and layout of a frame.
pub struct Pipelines {
    /// Group 0 of the scene passes: globals uniform, sky texture.
    pub globals_layout: wgpu::BindGroupLayout,
    /// Group 1 of the terrain: params uniform, heights, colour map, sampler.
    pub terrain_layout: wgpu::BindGroupLayout,
    /// Group 1 of the meshes: material uniform, colour map, sampler.
    pub material_layout: wgpu::BindGroupLayout,
    /// Group 0 of the tone map: HDR image, exposure uniform.
    pub tonemap_layout: wgpu::BindGroupLayout,
    /// Group 2 of the terrain and meshes: shadow parameters, the cascades' shadow maps (a 2D
    /// array, one layer per cascade), comparison sampler.
    pub shadow_layout: wgpu::BindGroupLayout,
    /// Group 3 of the terrain and meshes: the ambient term (see [`super::ambient_gpu`]).
    pub ambient_layout: wgpu::BindGroupLayout,
    pub sky: wgpu::RenderPipeline,
    pub terrain: wgpu::RenderPipeline,
    pub mesh: wgpu::RenderPipeline,
    pub tonemap: wgpu::RenderPipeline,
    /// Depth-only passes into the shadow map (the mesh one alpha-tested).
    pub terrain_shadow: wgpu::RenderPipeline,
    pub mesh_shadow: wgpu::RenderPipeline,
    /// The camera pass's impostor quads ([`super::impostor`]).
    pub impostor: super::impostor::ImpostorPipeline,
    /// The skeletons' lines and points ([`super::skeleton`]).
    pub skeleton: super::skeleton::SkeletonPipeline,
    /// Samples per pixel of the scene pass's targets.
    pub samples: u32,
}

pub(super) fn uniform_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

pub(super) fn texture_entry(
    binding: u32,
    visibility: wgpu::ShaderStages,
    filterable: bool,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

fn sampler_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
        count: None,
    }
}

pub(super) fn layout(
    device: &wgpu::Device,
    label: &str,
    entries: &[wgpu::BindGroupLayoutEntry],
) -> wgpu::BindGroupLayout {
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries,
    })
}

pub(super) fn shader(device: &wgpu::Device, label: &str, parts: &[&str]) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(parts.concat().into()),
    })
}

/// Vertex buffers of the mesh pipeline: slots 0–2 are the mesh section's `positions`, `normals`
/// and `uvs` arrays as stored; slot 3 the instances as `InstanceRecord`s (32-byte stride).
const MESH_ATTRS_POS: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![0 => Float32x3];
const MESH_ATTRS_NRM: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![1 => Float32x3];
const MESH_ATTRS_UV: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![2 => Float32x2];
const MESH_ATTRS_TAN: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![6 => Float32x4];
/// InstanceRecord: position at 0, scale at 12, rotation_deg at 16, and at 28 the `reserved`
/// field, which the renderer's instance buckets set to the instance's index among its model's
/// instances (src/render/cull.rs).
pub const INSTANCE_ATTRS: [wgpu::VertexAttribute; 4] = [
    wgpu::VertexAttribute {
        format: wgpu::VertexFormat::Float32x3,
        offset: 0,
        shader_location: 3,
    },
    wgpu::VertexAttribute {
        format: wgpu::VertexFormat::Float32,
        offset: 12,
        shader_location: 4,
    },
    wgpu::VertexAttribute {
        format: wgpu::VertexFormat::Float32,
        offset: 16,
        shader_location: 5,
    },
    wgpu::VertexAttribute {
        format: wgpu::VertexFormat::Uint32,
        offset: 28,
        shader_location: 7,
    },
];

/// ChunkRecord (src/render/terrain_lod.rs): first cell at 0, step log2 at 8, skirt bottom at 12.
const CHUNK_ATTRS: [wgpu::VertexAttribute; 3] =
    wgpu::vertex_attr_array![0 => Uint32x2, 1 => Uint32, 2 => Float32];

pub(super) struct PassDesc<'a> {
    label: &'a str,
    module: &'a wgpu::ShaderModule,
    layouts: &'a [Option<&'a wgpu::BindGroupLayout>],
    buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
    target: wgpu::TextureFormat,
    /// Depth writes and test on (scene geometry) or off (full-screen passes).
    depth: Option<bool>,
    /// The vertex entry point.
    vertex: &'a str,
    /// Samples per pixel of the target (1, or [`super::MSAA_SAMPLES`] for the scene pass).
    samples: u32,
    /// Coverage by sample mask (leaf cards under MSAA): the shader's `SAMPLE_MASK` override
    /// turns the alpha test into a coverage tested against four sample thresholds
    /// (src/render/coverage.rs), written as the fragment's sample mask.
    sample_mask: bool,
    /// The fragment entry point.
    fragment: &'a str,
    /// Triangles, except the skeletons' lines and points.
    topology: wgpu::PrimitiveTopology,
}

pub(super) fn pipeline(device: &wgpu::Device, d: &PassDesc) -> wgpu::RenderPipeline {
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(d.label),
        bind_group_layouts: d.layouts,
        immediate_size: 0,
    });
    let depth_stencil = d.depth.map(|write| wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(write),
        depth_compare: Some(if write {
            wgpu::CompareFunction::Greater
        } else {
            wgpu::CompareFunction::Always
        }),
        stencil: Default::default(),
        bias: Default::default(),
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(d.label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: d.module,
            entry_point: Some(d.vertex),
            compilation_options: Default::default(),
            buffers: d.buffers,
        },
        primitive: wgpu::PrimitiveState {
            topology: d.topology,
            // Plants are thin and seen from both sides; terrain and sky cannot be seen from behind.
            cull_mode: None,
            ..Default::default()
        },
        depth_stencil,
        multisample: wgpu::MultisampleState {
            count: d.samples,
            mask: !0,
            alpha_to_coverage_enabled: false,
        },
        fragment: Some(wgpu::FragmentState {
            module: d.module,
            entry_point: Some(d.fragment),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: if d.sample_mask {
                    &[("SAMPLE_MASK", 1.0)]
                } else {
                    &[]
                },
                ..Default::default()
            },
            targets: &[Some(wgpu::ColorTargetState {
                format: d.target,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// A depth-only pipeline into the shadow map; `vertex` and `fragment` name the entry points
/// (the latter the alpha test).
pub(super) fn shadow_pipeline(
    device: &wgpu::Device,
    d: &PassDesc,
    vertex: &str,
    fragment: Option<&str>,
) -> wgpu::RenderPipeline {
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(d.label),
        bind_group_layouts: d.layouts,
        immediate_size: 0,
    });
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(d.label),
        layout: Some(&layout),
        vertex: wgpu::VertexState {
            module: d.module,
            entry_point: Some(vertex),
            compilation_options: Default::default(),
            buffers: d.buffers,
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleList,
            cull_mode: None,
            ..Default::default()
        },
        // The bias is applied in the lookup (shaders/direct.wgsl), in world units.
        depth_stencil: Some(wgpu::DepthStencilState {
            format: SHADOW_FORMAT,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: fragment.map(|entry| wgpu::FragmentState {
            module: d.module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            targets: &[],
        }),
        multiview_mask: None,
        cache: None,
    })
}

fn shadow_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let f = wgpu::ShaderStages::FRAGMENT;
    layout(
        device,
        "shadow",
        &[
            uniform_entry(0, f),
            wgpu::BindGroupLayoutEntry {
                binding: 1,
                visibility: f,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 2,
                visibility: f,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                count: None,
            },
        ],
    )
}

/// Layout entries of group 3, the ambient term (see ambient.wgsl, [`super::ambient_gpu`]).
pub fn ambient_layout_entries() -> [wgpu::BindGroupLayoutEntry; 5] {
    use wgpu::ShaderStages as S;
    let storage = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: S::VERTEX,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    [
        wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: S::VERTEX | S::FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: S::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        },
        storage(2),
        storage(3),
        storage(4),
    ]
}

/// Phase 1 of [`Pipelines::new`]: the bind-group layouts.
struct Layouts {
    globals: wgpu::BindGroupLayout,
    terrain: wgpu::BindGroupLayout,
    material: wgpu::BindGroupLayout,
    tonemap: wgpu::BindGroupLayout,
    shadow: wgpu::BindGroupLayout,
    ambient: wgpu::BindGroupLayout,
}

impl Layouts {
    fn new(device: &wgpu::Device) -> Layouts {
        use wgpu::ShaderStages as S;
        let vf = S::VERTEX | S::FRAGMENT;
        let globals = layout(
            device,
            "globals",
            &[
                uniform_entry(0, vf),
                texture_entry(1, S::FRAGMENT, false),
                // The sun's visibility (soft shadows), R32Float.
                texture_entry(2, S::FRAGMENT, false),
                // The cube sky (Rgba16Float) and its bilinear sampler.
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: S::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::Cube,
                        multisampled: false,
                    },
                    count: None,
                },
                sampler_entry(4),
            ],
        );
        let terrain = layout(
            device,
            "terrain",
            &[
                uniform_entry(0, vf),
                texture_entry(1, S::VERTEX, false),
                texture_entry(2, S::FRAGMENT, true),
                sampler_entry(3),
                texture_entry(4, S::FRAGMENT, true),
            ],
        );
        let material = layout(
            device,
            "material",
            &[
                uniform_entry(0, vf),
                texture_entry(1, S::FRAGMENT, true),
                sampler_entry(2),
                uniform_entry(3, S::FRAGMENT),
                texture_entry(4, S::FRAGMENT, true),
                texture_entry(5, S::FRAGMENT, true),
            ],
        );
        let shadow = shadow_layout(device);
        let tonemap = layout(
            device,
            "tonemap",
            &[
                texture_entry(0, S::FRAGMENT, false),
                uniform_entry(1, S::FRAGMENT),
            ],
        );
        let ambient = layout(device, "ambient", &ambient_layout_entries());
        Layouts {
            globals,
            terrain,
            material,
            tonemap,
            shadow,
            ambient,
        }
    }
}

/// Phase 2 of [`Pipelines::new`]: the shader modules (`common.wgsl` prepended to the scene
/// passes; the lit passes also get the direct and ambient terms).
struct Modules {
    sky: wgpu::ShaderModule,
    terrain: wgpu::ShaderModule,
    mesh: wgpu::ShaderModule,
    tonemap: wgpu::ShaderModule,
}

impl Modules {
    fn new(device: &wgpu::Device) -> Modules {
        Modules {
            sky: shader(device, "sky", &[COMMON_WGSL, SKY_WGSL]),
            terrain: shader(
                device,
                "terrain",
                &[COMMON_WGSL, DIRECT_WGSL, AMBIENT_WGSL, TERRAIN_WGSL],
            ),
            mesh: shader(
                device,
                "mesh",
                &[COMMON_WGSL, DIRECT_WGSL, AMBIENT_WGSL, MESH_WGSL],
            ),
            tonemap: shader(device, "tonemap", &[TONEMAP_WGSL]),
        }
    }
}

/// The vertex buffers of the mesh passes (see [`MESH_ATTRS_POS`]): positions, normals, UVs,
/// instances, tangents.
fn mesh_buffers() -> [Option<wgpu::VertexBufferLayout<'static>>; 5] {
    let per_vertex = |array_stride, attributes| {
        Some(wgpu::VertexBufferLayout {
            array_stride,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes,
        })
    };
    [
        per_vertex(12, &MESH_ATTRS_POS),
        per_vertex(12, &MESH_ATTRS_NRM),
        per_vertex(8, &MESH_ATTRS_UV),
        Some(wgpu::VertexBufferLayout {
            array_stride: size_of::<InstanceRecord>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &INSTANCE_ATTRS,
        }),
        per_vertex(16, &MESH_ATTRS_TAN),
    ]
}

/// A pass into the HDR target.
pub(super) fn hdr_pass<'a>(
    label: &'a str,
    module: &'a wgpu::ShaderModule,
    layouts: &'a [Option<&'a wgpu::BindGroupLayout>],
    buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
    depth: Option<bool>,
) -> PassDesc<'a> {
    PassDesc {
        label,
        module,
        layouts,
        buffers,
        target: HDR_FORMAT,
        depth,
        vertex: "vs_main",
        samples: 1,
        sample_mask: false,
        fragment: "fs_main",
        topology: wgpu::PrimitiveTopology::TriangleList,
    }
}

impl<'a> PassDesc<'a> {
    /// The same pass into a target of `samples` samples per pixel (1 or
    /// [`super::MSAA_SAMPLES`], the four thresholds `mesh.wgsl` writes its mask from), with
    /// coverage by sample mask when `sample_mask` and more than one sample.
    pub(super) fn multisampled(self, samples: u32, sample_mask: bool) -> PassDesc<'a> {
        debug_assert!(samples == 1 || samples == super::MSAA_SAMPLES);
        PassDesc {
            samples,
            sample_mask: sample_mask && samples > 1,
            ..self
        }
    }

    /// The same pass for a backend that cannot write the sample mask (`gl`: naga writes
    /// `gl_SampleMask` as a scalar, gfx-rs/wgpu#6085): the entry point `fs_main_per_sample`,
    /// shaded once per sample (once per pixel without MSAA), each keeping its sample where the
    /// mask has it.
    pub(super) fn mask_by_sample(self, gl: bool) -> PassDesc<'a> {
        if !gl {
            return self;
        }
        PassDesc {
            fragment: "fs_main_per_sample",
            ..self
        }
    }

    /// The same pass drawing `topology` (line or point lists) instead of triangles.
    pub(super) fn primitives(self, topology: wgpu::PrimitiveTopology) -> PassDesc<'a> {
        PassDesc { topology, ..self }
    }
}

impl Pipelines {
    /// Layouts, then shader modules, then the scene passes (sky, terrain, meshes, impostors;
    /// `samples` per pixel, coverage by sample mask on the alpha-tested meshes when more than one),
    /// the depth-only shadow passes and the tone map. `backend` picks how the leaf cards'
    /// sample mask is written ([`PassDesc::mask_by_sample`] on GL).
    pub fn new(device: &wgpu::Device, samples: u32, backend: wgpu::Backend) -> Pipelines {
        let l = Layouts::new(device);
        let m = Modules::new(device);
        let mesh_buffers = mesh_buffers();
        let sky = pipeline(
            device,
            &hdr_pass("sky", &m.sky, &[Some(&l.globals)], &[], Some(false))
                .multisampled(samples, false),
        );
        let lit = [Some(&l.shadow), Some(&l.ambient)];
        let chunk_buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: size_of::<super::terrain_lod::ChunkRecord>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &CHUNK_ATTRS,
        })];
        let terrain = pipeline(
            device,
            &PassDesc {
                vertex: "vs_chunk",
                ..hdr_pass(
                    "terrain",
                    &m.terrain,
                    &[Some(&l.globals), Some(&l.terrain), lit[0], lit[1]],
                    &chunk_buffers,
                    Some(true),
                )
                .multisampled(samples, false)
            },
        );
        let mesh = pipeline(
            device,
            &hdr_pass(
                "mesh",
                &m.mesh,
                &[Some(&l.globals), Some(&l.material), lit[0], lit[1]],
                &mesh_buffers,
                Some(true),
            )
            .multisampled(samples, true)
            .mask_by_sample(backend == wgpu::Backend::Gl),
        );
        let terrain_shadow = shadow_pipeline(
            device,
            &hdr_pass(
                "terrain shadow",
                &m.terrain,
                &[Some(&l.globals), Some(&l.terrain)],
                &chunk_buffers,
                Some(true),
            ),
            "vs_chunk",
            None,
        );
        let mesh_shadow = shadow_pipeline(
            device,
            &hdr_pass(
                "mesh shadow",
                &m.mesh,
                &[Some(&l.globals), Some(&l.material)],
                &mesh_buffers,
                Some(true),
            ),
            "vs_shadow",
            Some("fs_shadow"),
        );
        let tonemap = pipeline(
            device,
            &PassDesc {
                label: "tonemap",
                module: &m.tonemap,
                layouts: &[Some(&l.tonemap)],
                buffers: &[],
                target: OUTPUT_FORMAT,
                depth: None,
                vertex: "vs_main",
                samples: 1,
                sample_mask: false,
                fragment: "fs_main",
                topology: wgpu::PrimitiveTopology::TriangleList,
            },
        );
        let impostor = super::impostor::ImpostorPipeline::new(
            device, &l.globals, &l.shadow, &l.ambient, samples, backend,
        );
        let skeleton = super::skeleton::SkeletonPipeline::new(
            device, &l.globals, &l.shadow, &l.ambient, samples,
        );
        Pipelines {
            samples,
            impostor,
            skeleton,
            globals_layout: l.globals,
            terrain_layout: l.terrain,
            material_layout: l.material,
            tonemap_layout: l.tonemap,
            shadow_layout: l.shadow,
            ambient_layout: l.ambient,
            sky,
            terrain,
            mesh,
            tonemap,
            terrain_shadow,
            mesh_shadow,
        }
    }
}
