//! What the tracer knows of a model's surfaces: per material the light-transport parameters
//! (albedo and translucence, [`prt_materials`]) and the alpha masks of alpha-tested colour maps
//! ([`alpha_masks`]). The PRT stage and the trace scene of a pack both build them here.
//!
//! albedo = [`crate::material::convert::diffuse_albedo`] (linear, the one albedo of every stage
//! and the renderer) × the mean linear colour of the colour map's opaque texels; translucence =
//! [`crate::material::convert::translucence`] (the converted material's, the caller's default
//! for the thesis' leaf without a TXF value).

use super::AlphaMask;
use crate::model::{Mesh, Rgba8Image};
use serde::{Deserialize, Serialize};

/// The light-transport parameters of one material.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PrtMaterial {
    /// Diffuse albedo, linear RGB in [0, 1].
    pub albedo: [f32; 3],
    /// Fraction of scattered light transmitted through the surface, in [0, 1].
    pub translucence: f32,
}

/// sRGB-encoded value (0..1) to linear.
fn srgb_to_linear(c: f32) -> f32 {
    let c = if c.is_finite() {
        c.clamp(0.0, 1.0)
    } else {
        0.0
    };
    crate::color::srgb_to_linear(c)
}

/// Mean linear colour of an image's opaque texels (all texels if none is opaque).
fn mean_color(img: &Rgba8Image) -> [f32; 3] {
    let lut: Vec<f64> = (0..256)
        .map(|i| srgb_to_linear(i as f32 / 255.0) as f64)
        .collect();
    let mut sum = [0.0f64; 3];
    let mut n = 0u64;
    let any_opaque = img.pixels.iter().any(|p| p[3] >= 128);
    for p in img.pixels.iter().filter(|p| !any_opaque || p[3] >= 128) {
        for k in 0..3 {
            sum[k] += lut[p[k] as usize];
        }
        n += 1;
    }
    sum.map(|s| if n == 0 { 1.0 } else { (s / n as f64) as f32 })
}

/// Albedo and translucence per material. `textures[i]` is the decoded `mesh.textures[i]`
/// (`None` where it is missing: the colour map then counts as white).
pub fn prt_materials(
    mesh: &Mesh,
    textures: &[Option<Rgba8Image>],
    default_translucence: f32,
) -> Vec<PrtMaterial> {
    mesh.materials
        .iter()
        .map(|m| {
            let map = m
                .color_map
                .and_then(|i| textures.get(i as usize))
                .and_then(|t| t.as_ref())
                .map_or([1.0; 3], mean_color);
            let base = crate::material::convert::diffuse_albedo(m);
            let albedo = std::array::from_fn(|k| base[k] * map[k]);
            PrtMaterial {
                albedo,
                translucence: crate::material::convert::translucence(m, default_translucence),
            }
        })
        .collect()
}

/// Alpha masks per material from the decoded textures (see [`prt_materials`]).
pub fn alpha_masks(mesh: &Mesh, textures: &[Option<Rgba8Image>]) -> Vec<Option<AlphaMask>> {
    mesh.materials
        .iter()
        .map(|m| {
            m.color_map
                .and_then(|i| textures.get(i as usize))
                .and_then(|t| t.as_ref())
                .map(AlphaMask::from_rgba8)
        })
        .collect()
}
