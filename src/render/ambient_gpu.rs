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

/// `AmbientParams` of ambient.wgsl: repr(C), Pod, 4,656 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct AmbientParams {
    pub sky_irradiance: [[f32; 4]; 16],
    pub albedo_scale_t: [f32; 4],
    pub mode: [u32; 4],
    pub scale: [f32; 4],
    /// Radiance SH of the sun-free sky (world frame).
    pub sky_radiance: [[f32; 4]; 16],
    /// [`super::ambient::GlossLut::packed`].
    pub gloss_lut: [[f32; 4]; GLOSS_VEC4],
}
const GLOSS_VEC4: usize = super::ambient::LUT_V * super::ambient::LUT_R / 2;
const _: () = assert!(size_of::<AmbientParams>() == 4656);

/// Group 3 of the scene passes.
pub struct AmbientGpu {
    pub terrain: wgpu::BindGroup,
    /// Per model and level (finest first), one bind group per material.
    pub models: Vec<Vec<Vec<wgpu::BindGroup>>>,
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
        // Half floats (11-bit mantissa, 2⁻¹¹ relative): irradiance needs no more, and a 4097²
        // terrain map is 134 MB on the device instead of 268 (plus as much again in staging).
        let half: Vec<u16> = t
            .texels
            .iter()
            .flatten()
            .map(|&c| half::f16::from_f32(c).to_bits())
            .collect();
        let data: &[u8] = bytemuck::cast_slice(&half);
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
                format: wgpu::TextureFormat::Rgba16Float,
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
        sky_radiance: std::array::from_fn(|i| {
            let c = amb.light.sky.coeffs[i];
            [c[0], c[1], c[2], 0.0]
        }),
        gloss_lut: {
            let packed = super::ambient::gloss_lut().packed();
            std::array::from_fn(|i| packed[i])
        },
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

/// Rows of `k` items of `a`, one per entry of `source` (the row it names).
fn gather_rows<T: Copy>(a: &[T], source: &[u32], k: usize) -> Vec<T> {
    source
        .iter()
        .flat_map(|&v| &a[v as usize * k..(v as usize + 1) * k])
        .copied()
        .collect()
}

/// The ambient bind groups of every level of a model: level 0 reads the arrays as resolved,
/// a simplified level the PRT rows and light-map UVs of each vertex's source mesh vertex.
fn upload_model(
    up: &mut Up,
    pipes: &Pipelines,
    m: &super::scene::ModelData,
    a: &super::ambient::ModelAmbient,
    layout: PrtLayout,
    base: &AmbientParams,
    black: &wgpu::TextureView,
) -> Result<Vec<Vec<wgpu::BindGroup>>> {
    let label = |what: &str| format!("{}: {what}", m.section);
    let mode = a.mode();
    let maps: Vec<f32> = a
        .envs
        .iter()
        .flat_map(|e| e.sky.iter().chain(&e.sun).flatten().copied())
        .collect();
    let maps = match mode {
        MeshAmbientMode::Prt => up.storage(&label("instance maps"), bytemuck::cast_slice(&maps))?,
        _ => up.storage("none", &[])?,
    };
    let map = match (&a.lightmap, mode) {
        (Some(lm), MeshAmbientMode::Lightmap) => {
            Some(up.light_texture(&label("light map"), &lm.texture)?)
        }
        _ => None,
    };
    let n0 = m.positions.len();
    let mut levels = Vec::with_capacity(1 + m.lod_levels.len());
    for level in 0..=m.lod_levels.len() {
        let source = (level > 0).then(|| m.lod_levels[level - 1].source.as_slice());
        let vertices = source.map_or(n0, <[u32]>::len);
        let prt = match (&a.prt, mode) {
            (Some(p), MeshAmbientMode::Prt) => {
                let data: Vec<u8> = match (layout, source) {
                    (PrtLayout::Full, None) => bytemuck::cast_slice(&p.transfer).to_vec(),
                    (PrtLayout::Packed, None) => bytemuck::cast_slice(&p.packed).to_vec(),
                    (PrtLayout::Full, Some(s)) => bytemuck::cast_slice(&gather_rows(
                        &p.transfer,
                        s,
                        p.transfer.len() / p.vertices.max(1),
                    ))
                    .to_vec(),
                    (PrtLayout::Packed, Some(s)) => bytemuck::cast_slice(&gather_rows(
                        &p.packed,
                        s,
                        p.packed.len() / p.vertices.max(1),
                    ))
                    .to_vec(),
                };
                up.storage(&label("PRT"), &data)?
            }
            _ => up.storage("none", &[])?,
        };
        let (uvs, per_instance) = match (&a.lightmap, mode) {
            (Some(lm), MeshAmbientMode::Lightmap) => {
                let uvs: Vec<[f32; 2]> = match (source, lm.per_instance) {
                    (None, _) => lm.uvs.clone(),
                    (Some(s), false) => gather_rows(&lm.uvs, s, 1),
                    (Some(s), true) => (0..lm.uvs.len() / n0.max(1))
                        .flat_map(|i| s.iter().map(move |&v| (i, v)))
                        .map(|(i, v)| lm.uvs[i * n0 + v as usize])
                        .collect(),
                };
                (
                    up.storage(&label("light-map UVs"), bytemuck::cast_slice(&uvs))?,
                    if lm.per_instance { vertices as u32 } else { 0 },
                )
            }
            _ => (up.storage("none", &[])?, 0),
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
        levels.push(groups);
    }
    Ok(levels)
}
