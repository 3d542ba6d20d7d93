//! The ambient term on the GPU: uploads what [`super::ambient::AmbientScene`] resolved (PRT per
//! vertex, per-instance maps, light maps, the sky's SH irradiance) into bind group 3 of the
//! terrain and mesh passes (`shaders/ambient.wgsl`). Each model gets one bind group per material
//! (the translucence and folded albedo differ per material); the big arrays are shared.

use super::ambient::{AmbientScene, LightTexture, MeshAmbientMode, PrtLayout};
use super::pipelines::Pipelines;
use super::scene::SceneData;
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// `AmbientParams` of ambient.wgsl: repr(C), Pod, 304 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct AmbientParams {
    pub sky_irradiance: [[f32; 4]; 16],
    pub albedo_scale_t: [f32; 4],
    pub mode: [u32; 4],
    pub scale: [f32; 4],
}
const _: () = assert!(size_of::<AmbientParams>() == 304);

/// Group 3 of the scene passes.
pub struct AmbientGpu {
    pub terrain: wgpu::BindGroup,
    /// Per model, one bind group per material.
    pub models: Vec<Vec<wgpu::BindGroup>>,
    pub bytes: u64,
}

struct Up<'g> {
    gpu: &'g Gpu,
    bytes: u64,
}

impl Up<'_> {
    fn buffer(&mut self, label: &str, data: &[u8], usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.bytes += data.len() as u64;
        self.gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: data,
                usage,
            })
    }

    /// A storage buffer; an empty one gets 16 zero bytes (bindings must not be empty).
    fn storage(&mut self, label: &str, data: &[u8]) -> Result<wgpu::Buffer> {
        let max = self.gpu.device.limits().max_storage_buffer_binding_size;
        if data.len() as u64 > max {
            return Err(Error::runtime(format!(
                "{label}: {} bytes, this GPU binds at most {max} per storage buffer",
                data.len()
            )));
        }
        let data = if data.is_empty() {
            &[0u8; 16][..]
        } else {
            data
        };
        Ok(self.buffer(label, data, wgpu::BufferUsages::STORAGE))
    }

    fn light_texture(&mut self, label: &str, t: &LightTexture) -> Result<wgpu::TextureView> {
        let max = self.gpu.max_texture_side();
        if t.width == 0 || t.height == 0 || t.width > max || t.height > max {
            return Err(Error::runtime(format!(
                "{label}: {}×{} texels, this GPU takes 1 to {max} per side",
                t.width, t.height
            )));
        }
        let data: &[u8] = bytemuck::cast_slice(&t.texels);
        self.bytes += data.len() as u64;
        let tex = self.gpu.device.create_texture_with_data(
            &self.gpu.queue,
            &wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: t.width,
                    height: t.height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
            wgpu::util::TextureDataOrder::LayerMajor,
            data,
        );
        Ok(tex.create_view(&Default::default()))
    }
}

/// The resources of one bind group.
struct Group<'a> {
    params: AmbientParams,
    light_map: &'a wgpu::TextureView,
    prt: &'a wgpu::Buffer,
    maps: &'a wgpu::Buffer,
    uvs: &'a wgpu::Buffer,
}

fn bind(up: &mut Up, pipes: &Pipelines, label: &str, g: &Group) -> wgpu::BindGroup {
    let params = up.buffer(
        label,
        bytemuck::bytes_of(&g.params),
        wgpu::BufferUsages::UNIFORM,
    );
    let entry = |binding, resource| wgpu::BindGroupEntry { binding, resource };
    up.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &pipes.ambient_layout,
        entries: &[
            entry(0, params.as_entire_binding()),
            entry(1, wgpu::BindingResource::TextureView(g.light_map)),
            entry(2, g.prt.as_entire_binding()),
            entry(3, g.maps.as_entire_binding()),
            entry(4, g.uvs.as_entire_binding()),
        ],
    })
}

/// Uploads the ambient term of `scene`; `weight` is 1 to draw it, 0 to leave it out (`terms`).
pub fn upload_ambient(
    gpu: &Gpu,
    pipes: &Pipelines,
    scene: &SceneData,
    amb: &AmbientScene,
    weight: f32,
) -> Result<AmbientGpu> {
    let mut up = Up { gpu, bytes: 0 };
    let mut base = AmbientParams {
        sky_irradiance: std::array::from_fn(|i| {
            let c = amb.light.irradiance.coeffs[i];
            [c[0], c[1], c[2], 0.0]
        }),
        albedo_scale_t: [0.0; 4],
        mode: [2, 0, 0, 0],
        scale: [weight, 0.0, 0.0, 0.0],
    };
    let empty = up.storage("ambient placeholder", &[])?;
    let black = LightTexture {
        width: 1,
        height: 1,
        texels: vec![[0.0; 4]],
    };
    let black = up.light_texture("ambient placeholder", &black)?;
    let terrain_map = match &amb.terrain {
        Some(t) => Some(up.light_texture("terrain light map", t)?),
        None => None,
    };
    base.mode[3] = terrain_map.is_some() as u32;
    let terrain = bind(
        &mut up,
        pipes,
        "terrain ambient",
        &Group {
            params: base,
            light_map: terrain_map.as_ref().unwrap_or(&black),
            prt: &empty,
            maps: &empty,
            uvs: &empty,
        },
    );
    base.mode[3] = 0;
    let mut models = Vec::with_capacity(scene.models.len());
    for (m, a) in scene.models.iter().zip(&amb.models) {
        models.push(upload_model(
            &mut up, pipes, m, a, amb.layout, &base, &black,
        )?);
    }
    Ok(AmbientGpu {
        terrain,
        models,
        bytes: up.bytes,
    })
}

fn upload_model(
    up: &mut Up,
    pipes: &Pipelines,
    m: &super::scene::ModelData,
    a: &super::ambient::ModelAmbient,
    layout: PrtLayout,
    base: &AmbientParams,
    black: &wgpu::TextureView,
) -> Result<Vec<wgpu::BindGroup>> {
    let label = |what: &str| format!("{}: {what}", m.section);
    let mode = a.mode();
    let maps: Vec<f32> = a
        .envs
        .iter()
        .flat_map(|e| e.sky.iter().chain(&e.sun).flatten().copied())
        .collect();
    let (prt, maps) = match (&a.prt, mode) {
        (Some(p), MeshAmbientMode::Prt) => {
            let data: &[u8] = match layout {
                PrtLayout::Full => bytemuck::cast_slice(&p.transfer),
                PrtLayout::Packed => bytemuck::cast_slice(&p.packed),
            };
            (
                up.storage(&label("PRT"), data)?,
                up.storage(&label("instance maps"), bytemuck::cast_slice(&maps))?,
            )
        }
        _ => (up.storage("none", &[])?, up.storage("none", &[])?),
    };
    let (uvs, map, per_instance) = match (&a.lightmap, mode) {
        (Some(lm), MeshAmbientMode::Lightmap) => (
            up.storage(&label("light-map UVs"), bytemuck::cast_slice(&lm.uvs))?,
            Some(up.light_texture(&label("light map"), &lm.texture)?),
            if lm.per_instance {
                m.positions.len() as u32
            } else {
                0
            },
        ),
        _ => (up.storage("none", &[])?, None, 0),
    };
    let mut groups = Vec::with_capacity(m.materials.len());
    for k in 0..m.materials.len() {
        let mut params = *base;
        params.mode[0] = match mode {
            MeshAmbientMode::Prt => 0,
            MeshAmbientMode::Lightmap => 1,
            MeshAmbientMode::SkyIrradiance => 2,
        };
        params.mode[1] = (layout == PrtLayout::Packed) as u32;
        params.mode[2] = per_instance;
        if let Some(p) = &a.prt {
            let s = p.albedo_scale(k);
            params.albedo_scale_t = [s[0], s[1], s[2], p.translucence(k)];
        }
        let g = Group {
            params,
            light_map: map.as_ref().unwrap_or(black),
            prt: &prt,
            maps: &maps,
            uvs: &uvs,
        };
        groups.push(bind(up, pipes, &label("ambient"), &g));
    }
    Ok(groups)
}
