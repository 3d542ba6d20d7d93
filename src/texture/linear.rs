//! Display-encoded colour to linear reflectivity and back (seed 000 3.1.2, Fig. 3.3).
//!
//! Textures from cameras and scanners carry the display's transfer curve; lighting needs the
//! reflectivity, so colour maps are linearized before filtering. The default is the sRGB curve
//! (IEC 61966-2-1, piecewise: linear toe below 0.04045); `Gamma22` is the plain power law the
//! thesis names. Alpha is linear coverage and never transformed.

use serde::{Deserialize, Serialize};

/// Which transfer curve the 8-bit values carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum TransferFunction {
    /// The sRGB curve (what PNG/JPEG files without a profile mean).
    #[default]
    Srgb,
    /// A pure power law with exponent 2.2.
    Gamma22,
    /// Already linear (normal maps, data textures).
    Linear,
}

impl TransferFunction {
    /// Encoded value in [0, 1] to linear.
    pub fn to_linear(self, e: f32) -> f32 {
        let e = e.clamp(0.0, 1.0);
        match self {
            TransferFunction::Srgb => crate::color::srgb_to_linear(e),
            TransferFunction::Gamma22 => e.powf(2.2),
            TransferFunction::Linear => e,
        }
    }

    /// Linear value in [0, 1] to encoded.
    pub fn from_linear(self, l: f32) -> f32 {
        let l = l.clamp(0.0, 1.0);
        match self {
            TransferFunction::Srgb => crate::color::linear_to_srgb(l),
            TransferFunction::Gamma22 => l.powf(1.0 / 2.2),
            TransferFunction::Linear => l,
        }
    }

    /// The 256-entry table from 8-bit codes to linear values.
    pub fn table(self) -> [f32; 256] {
        std::array::from_fn(|i| self.to_linear(i as f32 / 255.0))
    }
}

/// RGBA8 texels to linear RGBA f32 (alpha divided by 255, not transformed).
pub fn linearize_rgba8(texels: &[[u8; 4]], transfer: TransferFunction) -> Vec<[f32; 4]> {
    let lut = transfer.table();
    texels
        .iter()
        .map(|p| {
            [
                lut[p[0] as usize],
                lut[p[1] as usize],
                lut[p[2] as usize],
                p[3] as f32 / 255.0,
            ]
        })
        .collect()
}

/// Linear RGBA f32 back to 8-bit codes (rounded to nearest).
pub fn encode_rgba8(texels: &[[f32; 4]], transfer: TransferFunction) -> Vec<[u8; 4]> {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    texels
        .iter()
        .map(|p| {
            [
                q(transfer.from_linear(p[0])),
                q(transfer.from_linear(p[1])),
                q(transfer.from_linear(p[2])),
                q(p[3]),
            ]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_round_trips_through_linear() {
        for t in [
            TransferFunction::Srgb,
            TransferFunction::Gamma22,
            TransferFunction::Linear,
        ] {
            let codes: Vec<[u8; 4]> = (0..=255u8).map(|c| [c, 255 - c, c / 2, c]).collect();
            let lin = linearize_rgba8(&codes, t);
            assert_eq!(encode_rgba8(&lin, t), codes, "{t:?}");
        }
    }

    #[test]
    fn srgb_matches_published_values() {
        // Independent oracle: the sRGB standard's reference points.
        let t = TransferFunction::Srgb;
        assert!((t.to_linear(0.5) - 0.214_041).abs() < 1e-5);
        assert!((t.to_linear(0.04045) - 0.003_130_8).abs() < 1e-6);
        assert!((t.to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((TransferFunction::Gamma22.to_linear(0.5) - 0.5f32.powf(2.2)).abs() < 1e-7);
        // The two branches meet (continuity at the toe).
        let below = t.to_linear(0.04045 - 1e-6);
        let above = t.to_linear(0.04045 + 1e-6);
        assert!((below - above).abs() < 1e-6);
    }
}
