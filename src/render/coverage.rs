//! Alpha coverage of leaf cards far away (issue 35: shrubs beyond about 30 m vanished while their
//! shadows stayed).
//!
//! The material stage keeps each mip level's alpha-tested area equal to level 0's (Castaño's
//! scaling, src/texture/mips.rs) as far as a level's texel count allows; at 2×2 and 1×1 it
//! cannot (a leaf of coverage 0.475 has a 1×1 level of alpha 0.475, which the test at 0.5
//! discards everywhere). So where the pixel's mip level `λ` passes the 4×4 level, the fragment's
//! test blends towards each sample's own test of the level-0 shape: `t = clamp(min(λ, top) −
//! (top − 2), 0, 1)` with `top` the 1×1 level (0 below three levels), and `f_k` 1 where the
//! colour map's level-0 alpha (bilinear) times the opacity reaches ½ at the card's point under
//! sample `k` (the fragment's uv carried to the sample by its screen derivatives, `mesh.wgsl`
//! `far_sample`; the CPU reference: the ray's own hit), else 0. Without MSAA a fragment passes
//! where `mix(α ≥ ½, f, t)` (f at the pixel's centre) reaches the pixel's 4×4 ordered-dither
//! (Bayer) threshold `d`. Under MSAA every sample gets a threshold of its own, `d + k/4` modulo 1
//! for sample k, and the shader writes the sample mask itself (`@builtin(sample_mask)`, no device
//! alpha to coverage: how a device turns a fractional alpha into samples is its own, and
//! lavapipe keeps ⌊4α⌋ of 4, which halved a coverage of 0.45): a sample is kept where
//! `mix(ramp_k, f_k, t)` reaches its threshold (`ramp_k` the near alpha edge at the sample,
//! `clamp((α_k − ½)/w + ½)`, α carried to the sample by its derivatives). Far away a card so keeps
//! the samples that lie on its leaves, as a path tracer's rays do: the leaves' share of every
//! pixel, c₀ of its quad on average. Before, every sample tested the level-0 coverage c₀ itself,
//! the same over the whole quad: a far card was drawn in every pixel it touched but under-covered
//! those its leaves fill (0.67 of their coverage, `tests/render_far_leaves.rs`; the ground-truth
//! harness' generated close view's leaves 0.86 of the path tracer's). The CPU reference's four
//! rays test `mix(α ≥ ½, f, t)` against the same thresholds ([`AlphaTest`]); `mesh.wgsl`
//! computes the same (`far_weight`, `far_sample`, `bayer4`, `sample_threshold`).
//!
//! The dither threshold is the pixel's shifted by a layer's offset ([`layer_dither`]): a
//! multiple of 1/16 hashed from the fragment's distance to the eye in slabs of
//! 1/[`LAYERS_PER_METRE`] metres. With one threshold per pixel, N far cards behind each other covered
//! the same pixels as one (a coverage of c₀ where the leaves' union covers 1 − (1 − c₀)^N: a far
//! crown drawn as a checkerboard the ground shows through, found by the ground-truth harness on
//! the generated forest); shifted per slab, each layer still passes exactly its share of a 4×4
//! block's thresholds, and layers at other depths pass independent shares.

/// λ of a colour map of level-0 size `(w, h)` for the texture-coordinate derivatives
/// `d = (∂u/∂x, ∂v/∂x, ∂u/∂y, ∂v/∂y)`: log₂ of the larger footprint side in level-0 texels (the
/// Vulkan spec's scale factor), unclamped.
pub fn mip_lambda((w, h): (u32, u32), d: [f32; 4]) -> f32 {
    let (w, h) = (w as f32, h as f32);
    let rho_x = ((d[0] * w).powi(2) + (d[1] * h).powi(2)).sqrt();
    let rho_y = ((d[2] * w).powi(2) + (d[3] * h).powi(2)).sqrt();
    rho_x.max(rho_y).max(1e-30).log2()
}

/// The weight `t` of the level-0 coverage at mip level `lambda` of a chain of `levels` levels.
pub fn far_weight(levels: usize, lambda: f32) -> f32 {
    if levels < 3 {
        return 0.0;
    }
    let top = (levels - 1) as f32;
    (lambda.min(top) - (top - 2.0)).clamp(0.0, 1.0)
}

/// The coverage of a hit with filtered alpha `alpha` (times the opacity) for a hard test:
/// `mix(alpha ≥ ½, far, t)`.
pub fn hard_coverage(alpha: f32, far: f32, t: f32) -> f32 {
    let test = if alpha >= 0.5 { 1.0 } else { 0.0 };
    test + (far - test) * t
}

/// The alpha test of one primary ray: the pixel's dither threshold and, under MSAA, the
/// sample's index `k` among `n` ([`sample_threshold`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlphaTest {
    pub dither: f32,
    /// `(k, n)`: sample `k` of `n` per pixel; `None` without MSAA.
    pub sample: Option<(u32, u32)>,
}

impl AlphaTest {
    /// Whether a hit of filtered alpha `alpha` (times the opacity) passes, `far` the ray's own
    /// far test (1 where the level-0 alpha at its hit reaches ½, else 0; any coverage in [0, 1])
    /// at far weight `t` (see the module note).
    pub fn passes(&self, alpha: f32, far: f32, t: f32) -> bool {
        self.passes_at(alpha, far, t, None)
    }

    /// [`AlphaTest::passes`] for a hit at `distance` metres from the eye: the dither threshold
    /// shifted by the layer's offset ([`layer_dither`]), as `mesh.wgsl` tests a fragment.
    pub fn passes_at(&self, alpha: f32, far: f32, t: f32, distance: Option<f32>) -> bool {
        let dither = distance.map_or(self.dither, |d| layer_dither(self.dither, d));
        let threshold = match self.sample {
            None => dither,
            Some((k, n)) => sample_threshold(dither, k, n),
        };
        hard_coverage(alpha, far, t) >= threshold
    }
}

/// The threshold of sample `k` of `n` in a pixel of dither threshold `dither`: `dither + k/n`
/// modulo 1. For n = 4 every term is a multiple of 1/32, exact in `f32` (as `mesh.wgsl`).
pub fn sample_threshold(dither: f32, k: u32, n: u32) -> f32 {
    let x = dither + k as f32 / n as f32;
    if x >= 1.0 { x - 1.0 } else { x }
}

/// The 4×4 ordered-dither threshold of pixel (x, y), in (0, 1): `(index + ½)/16`.
pub fn bayer4(x: u32, y: u32) -> f32 {
    const M: [[u32; 4]; 4] = [[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]];
    (M[(y & 3) as usize][(x & 3) as usize] as f32 + 0.5) / 16.0
}

/// Dither layers per metre of distance from the eye (slabs of 2 cm): fragments further apart
/// get independent dither offsets (a leaf card's layer in a crown is a few centimetres).
pub const LAYERS_PER_METRE: f32 = 50.0;

/// The dither threshold of a pixel's threshold `pixel` for a fragment `distance` metres from
/// the eye: `pixel` plus `k/16` modulo 1, `k` the top four bits of a 32-bit integer hash
/// (Wellons' lowbias32) of the slab `⌊distance · LAYERS_PER_METRE⌋`. The sum stays a multiple of 1/32,
/// exact in `f32`, so `mesh.wgsl` computes the same bits.
pub fn layer_dither(pixel: f32, distance: f32) -> f32 {
    let slab = (distance.max(0.0) * LAYERS_PER_METRE).floor() as u32;
    let k = lowbias32(slab) >> 28;
    let x = pixel + k as f32 / 16.0;
    if x >= 1.0 { x - 1.0 } else { x }
}

/// Chris Wellons' `lowbias32` integer hash (as in `mesh.wgsl`).
pub fn lowbias32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weight_ramps_from_the_4x4_level_to_the_2x2_level() {
        // A 256² chain: 9 levels, 4×4 at λ = 6, 2×2 at 7, 1×1 at 8.
        assert_eq!(far_weight(9, 0.0), 0.0);
        assert_eq!(far_weight(9, 6.0), 0.0);
        assert!((far_weight(9, 6.5) - 0.5).abs() < 1e-6);
        assert_eq!(far_weight(9, 7.0), 1.0);
        assert_eq!(far_weight(9, 20.0), 1.0);
        // One level (no mips) or tiny chains: the plain test.
        assert_eq!(far_weight(1, 20.0), 0.0);
        assert_eq!(far_weight(2, 20.0), 0.0);
    }

    #[test]
    fn the_dither_thresholds_cover_the_unit_interval_evenly() {
        let mut t: Vec<f32> = (0..16).map(|k| bayer4(k % 4, k / 4)).collect();
        t.sort_by(f32::total_cmp);
        for (k, v) in t.iter().enumerate() {
            assert!((v - (k as f32 + 0.5) / 16.0).abs() < 1e-7);
        }
        // A coverage c passes round(16 c) of the 16 thresholds.
        for c in [0.0f32, 0.1, 0.475, 0.5, 0.9, 1.0] {
            let pass = t.iter().filter(|&&x| c >= x).count();
            assert_eq!(pass, (16.0 * c).round() as usize, "{c}");
        }
    }

    #[test]
    fn a_pixels_sample_thresholds_keep_a_sample_wherever_a_far_card_lies() {
        // Every pixel of a 4×4 block, every layer offset: the four thresholds are a quarter
        // apart, the lowest at most 7/32, so a coverage of 0.475 keeps one or two samples in
        // every pixel (with one threshold per pixel, 8 of 16 pixels kept none).
        for shift in 0..16 {
            let mut kept = 0;
            for p in 0..16u32 {
                let d = bayer4(p % 4, p / 4) + shift as f32 / 16.0;
                let d = if d >= 1.0 { d - 1.0 } else { d };
                let t: Vec<f32> = (0..4).map(|k| sample_threshold(d, k, 4)).collect();
                let n = t.iter().filter(|&&x| 0.475 >= x).count();
                assert!((1..=2).contains(&n), "pixel {p}, shift {shift}: {t:?}");
                assert!(t.iter().cloned().fold(1.0, f32::min) <= 7.0 / 32.0);
                kept += n;
                // Multiples of 1/32, so the shader's f32 sums are these bits.
                for x in t {
                    assert_eq!((x * 32.0).fract(), 0.0);
                }
            }
            // The block keeps round(16 c) sixteenths of its 64 samples.
            assert_eq!(
                kept,
                4 * (16.0f32 * 0.475).round() as usize,
                "shift {shift}"
            );
            let one_per_pixel = (0..16u32)
                .filter(|&p| {
                    let d = bayer4(p % 4, p / 4) + shift as f32 / 16.0;
                    0.475 >= if d >= 1.0 { d - 1.0 } else { d }
                })
                .count();
            assert_eq!(one_per_pixel, 8);
        }
    }
}
