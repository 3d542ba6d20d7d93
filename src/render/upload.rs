//! Scene upload: the pack's arrays go into GPU buffers and textures byte for byte (bytemuck
//! casts, no per-vertex conversion): mesh `positions`/`normals`/`uvs`/`indices` become vertex and
//! index buffers, `InstanceRecord`s an instance buffer per model, terrain heights an `R32Float`
//! texture, colour maps `Rgba8UnormSrgb` textures, the sky stage's cube an `Rgba16Float` cube
//! texture (a lat-long sky an `Rgba32Float` texture).

use super::pipelines::Pipelines;
use super::scene::{DrawRange, ImageData, SceneData};
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// Terrain parameters as the shader reads them: repr(C), Pod, 32 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct TerrainParams {
    /// origin x, y; extent x, y (metres)
    pub origin_extent: [f32; 4],
    /// samples per row, rows, 0, 0
    pub size: [u32; 4],
}
const _: () = assert!(size_of::<TerrainParams>() == 32);

/// Material parameters: repr(C), Pod, 32 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct MaterialParams {
    pub base_color: [f32; 4],
    /// x: mip levels of the colour map as uploaded (the far cards' weight, src/render/coverage.rs),
    /// y, z, w: 0.
    pub alpha: [f32; 4],
}
const _: () = assert!(size_of::<MaterialParams>() == 32);

/// The direct-sun material (shaders/mesh.wgsl `DirectMaterial`): the material section's record
/// and how to use it. repr(C), Pod, 112 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct DirectMaterialParams {
    pub record: crate::material::section::MaterialRecord,
    /// x: 1 = two-layer Schlick, 0 = Lambert; y: 1 = normal map; z: opacity; w: 1 = a height
    /// map for parallax (binding 5). The record's `reserved` is 1 for an alpha-tested material
    /// (the region pass's leaves, [`super::scene::MaterialData::alpha_tested`]).
    pub mode: [f32; 4],
}
const _: () = assert!(size_of::<DirectMaterialParams>() == 112);

impl DirectMaterialParams {
    pub fn new(mat: &super::scene::MaterialData) -> Self {
        let mut p = Self::shading(mat);
        // The record's spare float: 1 for an alpha-tested material (the region pass's leaves).
        p.record.reserved = if mat.alpha_tested() { 1.0 } else { 0.0 };
        p
    }

    fn shading(mat: &super::scene::MaterialData) -> Self {
        match &mat.schlick {
            Some(m) => DirectMaterialParams {
                record: crate::material::section::material_record(m),
                mode: [
                    1.0,
                    if mat.normal_map.is_some() { 1.0 } else { 0.0 },
                    m.opacity,
                    if mat.height_mips.is_some() { 1.0 } else { 0.0 },
                ],
            },
            None => DirectMaterialParams {
                record: Zeroable::zeroed(),
                mode: [0.0, 0.0, 1.0, 0.0],
            },
        }
    }
}

/// The terrain on the GPU; drawn with `vertex_count` vertices and no vertex buffer.
pub struct TerrainGpu {
    pub bind_group: wgpu::BindGroup,
    pub vertex_count: u32,
}

/// One detail level of a model on the GPU: level 0 is the mesh as drawn, the others the `lod`
/// section's simplified meshes with their attributes gathered through `vertex_source`.
pub struct LevelGpu {
    pub positions: wgpu::Buffer,
    pub normals: wgpu::Buffer,
    pub uvs: wgpu::Buffer,
    /// The `tangents:<model>` frames (vertex slot 4).
    pub tangents: wgpu::Buffer,
    pub indices: wgpu::Buffer,
    pub draws: Vec<DrawRange>,
    pub triangles: u64,
}

/// One model on the GPU.
pub struct ModelGpu {
    /// The mesh levels, finest first.
    pub levels: Vec<LevelGpu>,
    /// Every instance, `reserved` = its index among the model's instances (passes that draw all
    /// instances at full detail, e.g. the soft shadows' world pass).
    pub instances: wgpu::Buffer,
    pub instance_count: u32,
    /// One per material, indexed by `DrawRange::material`.
    pub materials: Vec<wgpu::BindGroup>,
    /// The impostor atlas, drawn for the instances of bucket level `levels.len()`.
    pub impostor: Option<super::impostor::ImpostorGpu>,
    /// The skeleton, drawn for the instances of bucket level `levels.len()` plus one where there
    /// is an impostor.
    pub skeleton: Option<super::skeleton::SkeletonGpu>,
}

/// Everything uploaded for a frame.
pub struct GpuScene {
    /// The lat-long sky (1×1 where the cube is drawn).
    pub sky_view: wgpu::TextureView,
    /// The cube sky (a 1×1 black cube where the lat-long one is drawn) and its sampler.
    pub sky_cube: wgpu::TextureView,
    pub sky_sampler: wgpu::Sampler,
    /// True when the sky pass samples `sky_cube`.
    pub sky_is_cube: bool,
    pub terrain: Option<TerrainGpu>,
    pub models: Vec<ModelGpu>,
    /// Bytes sent to the GPU.
    pub bytes: u64,
    /// Group 3, the ambient term (set after [`upload_scene`], see `render_pack`).
    pub ambient: Option<super::ambient_gpu::AmbientGpu>,
}

pub(crate) struct Uploader<'g> {
    pub(super) gpu: &'g Gpu,
    bytes: u64,
}

impl Uploader<'_> {
    pub(super) fn buffer(
        &mut self,
        label: &str,
        contents: &[u8],
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        self.bytes += contents.len() as u64;
        self.gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
    }

    /// A 2D texture (array) the shaders sample, filled by copies.
    fn sampled_texture(
        &self,
        label: &str,
        size: wgpu::Extent3d,
        mip_level_count: u32,
        format: wgpu::TextureFormat,
    ) -> wgpu::Texture {
        self.gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        })
    }

    /// A 2D texture from tightly packed rows of `bytes_per_texel` bytes.
    pub(super) fn texture(
        &mut self,
        label: &str,
        (width, height): (u32, u32),
        format: wgpu::TextureFormat,
        bytes_per_texel: u32,
        data: &[u8],
    ) -> Result<wgpu::TextureView> {
        let max = self.gpu.max_texture_side();
        if width > max || height > max || width == 0 || height == 0 {
            return Err(Error::runtime(format!(
                "{label}: {width}×{height} texels, this GPU ({}) takes 1 to {max} per side",
                self.gpu.adapter
            )));
        }
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let texture = self.sampled_texture(label, size, 1, format);
        self.gpu.queue.write_texture(
            texture.as_image_copy(),
            data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(width * bytes_per_texel),
                rows_per_image: Some(height),
            },
            size,
        );
        self.bytes += data.len() as u64;
        Ok(texture.create_view(&Default::default()))
    }

    /// A cube texture (`Rgba16Float`, six layers in the face order of `src/cube.rs`, which is
    /// wgpu's on world axes) and its cube view. The texels are the sky section's half floats,
    /// already made finite and non-negative by [`super::scene`] (so the conversion is exact).
    pub(super) fn cube_texture(
        &mut self,
        label: &str,
        cube: &crate::cube::CubeMap,
    ) -> Result<wgpu::TextureView> {
        let n = cube.size;
        let max = self.gpu.max_texture_side();
        if n == 0 || n > max {
            return Err(Error::runtime(format!(
                "{label}: cube faces of {n}×{n} texels, this GPU ({}) takes 1 to {max} per side",
                self.gpu.adapter
            )));
        }
        let half = |v: f32| half::f16::from_f32(v).to_bits();
        let data: Vec<[u16; 4]> = cube
            .texels
            .iter()
            .map(|t| [half(t[0]), half(t[1]), half(t[2]), half(1.0)])
            .collect();
        let size = wgpu::Extent3d {
            width: n,
            height: n,
            depth_or_array_layers: 6,
        };
        let texture = self.sampled_texture(label, size, 1, wgpu::TextureFormat::Rgba16Float);
        let bytes: &[u8] = bytemuck::cast_slice(&data);
        self.gpu.queue.write_texture(
            texture.as_image_copy(),
            bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(n * 8),
                rows_per_image: Some(n),
            },
            size,
        );
        self.bytes += bytes.len() as u64;
        Ok(texture.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::Cube),
            ..Default::default()
        }))
    }

    /// A processed texture with its whole mip chain (the section's texels level by level, in
    /// `format` of `texel_bytes` per texel), sampled trilinear: colour maps as `Rgba16Float`,
    /// normal maps as `Rgba8Unorm` (the alpha, |n̄|, filtered like the rest).
    pub(super) fn mips<T: Pod>(
        &mut self,
        label: &str,
        mips: &super::scene::Mips<T>,
        format: wgpu::TextureFormat,
        texel_bytes: u32,
    ) -> Result<wgpu::TextureView> {
        let [width, height, ..] = mips.levels[0];
        let max = self.gpu.max_texture_side();
        if width > max || height > max {
            return Err(Error::runtime(format!(
                "{label}: {width}×{height} texels, this GPU ({}) takes 1 to {max} per side",
                self.gpu.adapter
            )));
        }
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let levels = mips.levels.len() as u32;
        let texture = self.sampled_texture(label, size, levels, format);
        for (level, &[w, h, first, count]) in mips.levels.iter().enumerate() {
            let data: &[u8] =
                bytemuck::cast_slice(&mips.texels[first as usize..(first + count) as usize]);
            self.gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: level as u32,
                    origin: wgpu::Origin3d::ZERO,
                    aspect: wgpu::TextureAspect::All,
                },
                data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(w * texel_bytes),
                    rows_per_image: Some(h),
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
            );
            self.bytes += data.len() as u64;
        }
        Ok(texture.create_view(&Default::default()))
    }

    /// A normal map (`(n + 1)/2` in RGB, read as linear unorm), one level.
    fn normal_map(&mut self, label: &str, img: &ImageData) -> Result<wgpu::TextureView> {
        self.texture(
            label,
            (img.width, img.height),
            wgpu::TextureFormat::Rgba8Unorm,
            4,
            bytemuck::cast_slice(img.texels),
        )
    }

    fn color_map(&mut self, label: &str, img: &ImageData) -> Result<wgpu::TextureView> {
        self.texture(
            label,
            (img.width, img.height),
            wgpu::TextureFormat::Rgba8UnormSrgb,
            4,
            bytemuck::cast_slice(img.texels),
        )
    }
}

fn sampler(gpu: &Gpu, address: wgpu::AddressMode) -> wgpu::Sampler {
    gpu.device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("colour maps"),
        address_mode_u: address,
        address_mode_v: address,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        // Trilinear where a texture has mips (processed colour maps); no effect on one level.
        mipmap_filter: wgpu::MipmapFilterMode::Linear,
        ..Default::default()
    })
}

/// Uploads the scene.
pub fn upload_scene(gpu: &Gpu, pipes: &Pipelines, scene: &SceneData) -> Result<GpuScene> {
    let mut up = Uploader { gpu, bytes: 0 };
    let sky = &scene.sky;
    let (sky_view, sky_cube) = match &sky.cube {
        Some(cube) => (
            up.texture(
                "sky (unused)",
                (1, 1),
                wgpu::TextureFormat::Rgba32Float,
                16,
                bytemuck::cast_slice(&[[0f32; 4]]),
            )?,
            up.cube_texture("sky cube", cube)?,
        ),
        None => (
            up.texture(
                "sky",
                (sky.width, sky.height),
                wgpu::TextureFormat::Rgba32Float,
                16,
                bytemuck::cast_slice(&sky.texels),
            )?,
            up.cube_texture(
                "sky cube (unused)",
                &crate::cube::CubeMap::filled(1, [0.0; 3]),
            )?,
        ),
    };
    let sky_sampler = sampler(gpu, wgpu::AddressMode::ClampToEdge);
    let white = up.color_map(
        "white",
        &ImageData {
            width: 1,
            height: 1,
            texels: &[[255; 4]],
        },
    )?;
    let terrain = upload_terrain(&mut up, pipes, scene)?;
    let repeat = sampler(gpu, wgpu::AddressMode::Repeat);
    let mut models = Vec::with_capacity(scene.models.len());
    for m in &scene.models {
        models.push(upload_model(&mut up, pipes, m, &white, &repeat)?);
    }
    Ok(GpuScene {
        sky_view,
        sky_cube,
        sky_sampler,
        sky_is_cube: sky.cube.is_some(),
        terrain,
        models,
        bytes: up.bytes,
        ambient: None,
    })
}

fn upload_terrain(
    up: &mut Uploader,
    pipes: &Pipelines,
    scene: &SceneData,
) -> Result<Option<TerrainGpu>> {
    let Some(t) = &scene.terrain else {
        return Ok(None);
    };
    let (w, h) = (t.meta.width, t.meta.height);
    let heights = up.texture(
        "terrain heights",
        (w, h),
        wgpu::TextureFormat::R32Float,
        4,
        bytemuck::cast_slice(t.heights),
    )?;
    // Without a colour map the terrain is a mid grey (sRGB 128, albedo 0.22), not white.
    let grey = ImageData {
        width: 1,
        height: 1,
        texels: &[crate::terrain::DEFAULT_COLOR_SRGB8],
    };
    let color = up.color_map("terrain colour", t.color.as_ref().unwrap_or(&grey))?;
    let normals = up.normal_map(
        "terrain normals",
        &ImageData {
            width: w,
            height: h,
            texels: &t.normals,
        },
    )?;
    let params = TerrainParams {
        origin_extent: [
            t.meta.origin[0],
            t.meta.origin[1],
            t.meta.extent[0],
            t.meta.extent[1],
        ],
        size: [w, h, 0, 0],
    };
    let params = up.buffer(
        "terrain params",
        bytemuck::bytes_of(&params),
        wgpu::BufferUsages::UNIFORM,
    );
    let clamp = sampler(up.gpu, wgpu::AddressMode::ClampToEdge);
    let bind_group = up.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("terrain"),
        layout: &pipes.terrain_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(&heights),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&color),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::Sampler(&clamp),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::TextureView(&normals),
            },
        ],
    });
    let quads = (w as u64 - 1) * (h as u64 - 1);
    let vertex_count = u32::try_from(quads * 6).map_err(|_| {
        Error::runtime(format!(
            "terrain {w}×{h} has too many vertices for one draw"
        ))
    })?;
    Ok(Some(TerrainGpu {
        bind_group,
        vertex_count,
    }))
}

fn upload_model(
    up: &mut Uploader,
    pipes: &Pipelines,
    m: &super::scene::ModelData,
    white: &wgpu::TextureView,
    sampler: &wgpu::Sampler,
) -> Result<ModelGpu> {
    // Unused where a material has no normal map (the shader reads the flag), but bound.
    let flat = up.normal_map(
        "flat normal",
        &ImageData {
            width: 1,
            height: 1,
            texels: &[[128, 128, 255, 255]],
        },
    )?;
    // Likewise the height map of a material without one: 0.5, the undisplaced surface.
    let level_ground = up.texture(
        "level height",
        (1, 1),
        wgpu::TextureFormat::R16Float,
        2,
        bytemuck::bytes_of(&half::f16::from_f32(0.5).to_bits()),
    )?;
    use wgpu::BufferUsages as U;
    let mut levels = vec![upload_level(
        up,
        &LevelArrays {
            positions: &m.positions,
            normals: &m.normals,
            uvs: &m.uvs,
            tangents: &m.tangents,
            indices: &m.indices,
            draws: &m.draws,
        },
    )];
    for l in &m.lod_levels {
        levels.push(upload_level(
            up,
            &LevelArrays {
                positions: &l.positions,
                normals: &l.normals,
                uvs: &l.uvs,
                tangents: &l.tangents,
                indices: &l.indices,
                draws: &l.draws,
            },
        ));
    }
    let all: Vec<_> = m
        .instances
        .iter()
        .enumerate()
        .map(|(k, r)| crate::ingest::instances_section::InstanceRecord {
            reserved: k as u32,
            ..*r
        })
        .collect();
    let instances = up.buffer("instances", bytemuck::cast_slice(&all), U::VERTEX);
    let mut materials = Vec::with_capacity(m.materials.len());
    for (k, mat) in m.materials.iter().enumerate() {
        let label = format!("{}: material {k}", m.section);
        let (view, levels) = match (&mat.color_mips, &mat.color_map) {
            (Some(mips), _) => (
                up.mips(&label, mips, wgpu::TextureFormat::Rgba16Float, 8)?,
                mips.levels.len(),
            ),
            (None, Some(img)) => (up.color_map(&label, img)?, 1),
            (None, None) => (white.clone(), 1),
        };
        let params = MaterialParams {
            base_color: mat.base_color,
            alpha: [levels as f32, 0.0, 0.0, 0.0],
        };
        let params = up.buffer("material", bytemuck::bytes_of(&params), U::UNIFORM);
        let direct = up.buffer(
            "direct material",
            bytemuck::bytes_of(&DirectMaterialParams::new(mat)),
            U::UNIFORM,
        );
        let height_view = match &mat.height_mips {
            Some(mips) => up.mips(
                &format!("{}: height map {k}", m.section),
                mips,
                wgpu::TextureFormat::R16Float,
                2,
            )?,
            None => level_ground.clone(),
        };
        let normal_view = match &mat.normal_map {
            Some(mips) => up.mips(
                &format!("{}: normal map {k}", m.section),
                mips,
                wgpu::TextureFormat::Rgba8Unorm,
                4,
            )?,
            None => flat.clone(),
        };
        materials.push(up.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("material"),
            layout: &pipes.material_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: direct.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&normal_view),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&height_view),
                },
            ],
        }));
    }
    let leaves = m.has_leaves();
    let impostor = match &m.impostor {
        Some(d) => Some(super::impostor::upload(
            up,
            &pipes.impostor,
            &m.section,
            d,
            leaves,
            &m.materials
                .iter()
                .map(DirectMaterialParams::new)
                .collect::<Vec<_>>(),
        )?),
        None => None,
    };
    let skeleton = m
        .skeleton
        .as_ref()
        .map(|d| super::skeleton::upload(up, &pipes.skeleton, &m.section, d, leaves));
    Ok(ModelGpu {
        impostor,
        skeleton,
        levels,
        instances,
        instance_count: m.instances.len() as u32,
        materials,
    })
}

/// The vertex and index arrays of one level.
struct LevelArrays<'a> {
    positions: &'a [[f32; 3]],
    normals: &'a [[f32; 3]],
    uvs: &'a [[f32; 2]],
    tangents: &'a [[f32; 4]],
    indices: &'a [[u32; 3]],
    draws: &'a [DrawRange],
}

fn upload_level(up: &mut Uploader, l: &LevelArrays) -> LevelGpu {
    use wgpu::BufferUsages as U;
    // wgpu refuses empty vertex buffers: a level without vertices gets one zero vertex.
    fn bytes<T: Pod>(a: &[T], min: usize) -> std::borrow::Cow<'_, [u8]> {
        if a.is_empty() {
            std::borrow::Cow::Owned(vec![0u8; min])
        } else {
            std::borrow::Cow::Borrowed(bytemuck::cast_slice(a))
        }
    }
    LevelGpu {
        positions: up.buffer("positions", &bytes(l.positions, 12), U::VERTEX),
        normals: up.buffer("normals", &bytes(l.normals, 12), U::VERTEX),
        uvs: up.buffer("uvs", &bytes(l.uvs, 8), U::VERTEX),
        tangents: up.buffer("tangents", &bytes(l.tangents, 16), U::VERTEX),
        indices: up.buffer("indices", &bytes(l.indices, 12), U::INDEX),
        draws: l.draws.to_vec(),
        triangles: l.indices.len() as u64,
    }
}
