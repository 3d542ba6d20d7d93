//! Texture processing: decoded RGBA8 textures into GPU-ready mip chains (seed 000 3.1.2).
//!
//! A colour map is linearized ([`linear`]), filtered into a full mip chain with alpha-weighted
//! colour and coverage-preserving alpha ([`mips`]), and gets a height map from its mean colour
//! and a tangent-space normal map from that ([`normalmap`]), whose filtered lengths are kept for
//! the Toksvig factor. An authored normal map is only decoded and filtered. [`section`] stores
//! the result as a kind `texture` section with format `rgba16f_linear` or `normal_rgba8`.

pub mod linear;
pub mod mips;
pub mod normalmap;
pub mod section;
pub mod source_section;

use crate::model::Rgba8Image;
use linear::TransferFunction;
use mips::{ColorMips, MipLevel, MipOptions};
use normalmap::NormalMips;
use serde::{Deserialize, Serialize};

/// What a texture is used as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum TextureRole {
    /// A colour map (display-encoded, alpha-tested): colour mips plus derived height and normals.
    Color,
    /// An authored tangent-space normal map (linear data).
    Normal,
}

/// Options of [`process_texture`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureOptions {
    pub transfer: TransferFunction,
    pub mips: MipOptions,
    /// Tangent-space slope of a height step of 1 over one texel (see
    /// [`normalmap::normals_from_height`]); [`TextureOptions::slope_for`] derives it.
    pub slope: f32,
}

/// The bump amplitude used wherever a normal map exists (seed 000: ±1 mm).
pub const BUMP_HEIGHT_M: f32 = 0.001;

/// Texture size in metres assumed when no mesh tells (a leaf texture about 10 cm across).
pub const DEFAULT_TEXTURE_SPAN_M: f32 = 0.1;

impl TextureOptions {
    /// The slope for heights spanning ±`bump_height` metres on texels `texel_size` metres wide.
    pub fn slope_for(bump_height: f32, texel_size: f32) -> f32 {
        if texel_size > 0.0 && bump_height.is_finite() {
            2.0 * bump_height / texel_size
        } else {
            0.0
        }
    }

    /// Defaults for a texture of `width × height` texels with the thesis' ±1 mm bumps.
    pub fn for_size(width: u32, height: u32) -> Self {
        let texel = DEFAULT_TEXTURE_SPAN_M / (width as f32 * height as f32).sqrt().max(1.0);
        TextureOptions {
            transfer: TransferFunction::Srgb,
            mips: MipOptions::default(),
            slope: Self::slope_for(BUMP_HEIGHT_M, texel),
        }
    }
}

/// A processed texture: every array ready for upload.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessedTexture {
    pub role: TextureRole,
    /// Colour mips (linear RGB, straight alpha); `None` for normal maps.
    pub color: Option<ColorMips>,
    pub normals: NormalMips,
    /// Height mips in [0, 1] (colour maps only).
    pub heights: Option<Vec<MipLevel<f32>>>,
}

/// Decoded texture to GPU-ready mips (a stage: pure, no I/O).
pub fn process_texture(
    img: &Rgba8Image,
    role: TextureRole,
    opts: &TextureOptions,
) -> ProcessedTexture {
    let (w, h) = (img.width, img.height);
    match role {
        TextureRole::Color => {
            let base = MipLevel {
                width: w,
                height: h,
                texels: linear::linearize_rgba8(&img.pixels, opts.transfer),
            };
            let heights = normalmap::height_from_color(&base.texels);
            let normals = normalmap::normals_from_height(&heights, w, h, opts.slope);
            ProcessedTexture {
                role,
                color: Some(mips::build_color_mips(base, &opts.mips)),
                normals: normalmap::build_normal_mips(normals, w, h),
                heights: Some(normalmap::build_scalar_mips(heights, w, h)),
            }
        }
        TextureRole::Normal => {
            let normals = img
                .pixels
                .iter()
                .map(|&p| normalmap::decode_normal(p))
                .collect();
            ProcessedTexture {
                role,
                color: None,
                normals: normalmap::build_normal_mips(normals, w, h),
                heights: None,
            }
        }
    }
}
