//! Mip chains: exact-area box filtering, alpha-weighted colour and coverage-preserving alpha
//! (seed 000 3.1.2, Fig. 3.4).
//!
//! Leaves are drawn with an alpha test (texels with alpha ≥ 0.5 are opaque, the rest discarded),
//! so two things matter when shrinking a leaf texture:
//!
//! * colour is averaged with alpha as the weight, so the leaf keeps its green instead of mixing
//!   in the undefined colour of the transparent area (`c = Σ w·a·c / Σ w·a`; where no texel of the
//!   footprint has alpha, the plain mean);
//! * the alpha-tested area must neither shrink nor grow. The thesis takes the arithmetic mean of
//!   alpha and the threshold 0.5 and notes it is "not optimal"; the mean alone drifts (thin leaf
//!   tips vanish, gaps close). After the mean, each level's alpha is therefore scaled (Castaño,
//!   "Computing Alpha Mipmaps", 2010) so that the fraction of texels passing 0.5 equals the base
//!   level's, to the nearest texel: the scale puts the threshold between the k-th and (k+1)-th
//!   largest alpha, with k = round(coverage₀ · texels).
//!
//! Levels are computed from the previous level's *unscaled* mean alpha, so every level is the
//! exact box-filtered mean of the base and scaling never compounds. Sizes halve with floor
//! (min 1); odd sizes use exact-area weights (a destination texel covers 2.5 source texels of
//! a 5-texel row), so non-power-of-two textures filter without shifting.

use rayon::prelude::*;

/// The alpha-test threshold the renderer uses (texels with alpha ≥ this are drawn).
pub const ALPHA_THRESHOLD: f32 = 0.5;

/// One level of a mip chain, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct MipLevel<T> {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<T>,
}

/// A colour mip chain with its alpha bookkeeping.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorMips {
    /// Level 0 is the input; alpha in levels ≥ 1 is scaled for coverage.
    pub levels: Vec<MipLevel<[f32; 4]>>,
    /// Fraction of texels with alpha ≥ 0.5, per level (after scaling).
    pub coverage: Vec<f32>,
    /// The factor each level's mean alpha was multiplied by (1 for level 0).
    pub alpha_scale: Vec<f32>,
}

/// Options of [`build_color_mips`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MipOptions {
    /// Scale alpha per level to keep the alpha-tested area (off: the thesis' plain mean).
    pub preserve_coverage: bool,
}

impl Default for MipOptions {
    fn default() -> Self {
        Self {
            preserve_coverage: true,
        }
    }
}

/// Level sizes from `(w, h)` down to 1×1.
pub fn mip_sizes(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut sizes = vec![(width.max(1), height.max(1))];
    while let Some(&(w, h)) = sizes.last() {
        if w == 1 && h == 1 {
            break;
        }
        sizes.push(((w / 2).max(1), (h / 2).max(1)));
    }
    sizes
}

/// Per destination index, the source indices and their area weights (summing to 1).
pub fn box_weights(src: u32, dst: u32) -> Vec<Vec<(u32, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|d| {
            let (lo, hi) = (d as f64 * scale, (d + 1) as f64 * scale);
            let mut taps = Vec::with_capacity(3);
            let mut s = lo.floor() as u32;
            while (s as f64) < hi && s < src {
                let overlap = (hi.min(s as f64 + 1.0) - lo.max(s as f64)) / scale;
                if overlap > 1e-12 {
                    taps.push((s, overlap as f32));
                }
                s += 1;
            }
            taps
        })
        .collect()
}

/// Downsamples `src` to `w × h` with `reduce(taps)`, where taps are (texel, weight) pairs.
pub fn downsample<T, U, F>(src: &MipLevel<T>, w: u32, h: u32, reduce: F) -> MipLevel<U>
where
    T: Sync,
    U: Send + Sync + Clone + Default,
    F: Fn(&mut dyn Iterator<Item = (&T, f32)>) -> U + Sync,
{
    let wx = box_weights(src.width, w);
    let wy = box_weights(src.height, h);
    let sw = src.width as usize;
    let mut texels = vec![U::default(); w as usize * h as usize];
    texels
        .par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, dst)| {
            for (x, out) in dst.iter_mut().enumerate() {
                let mut taps = wy[y].iter().flat_map(|&(sy, fy)| {
                    wx[x].iter().map(move |&(sx, fx)| {
                        (&src.texels[sy as usize * sw + sx as usize], fx * fy)
                    })
                });
                *out = reduce(&mut taps);
            }
        });
    MipLevel {
        width: w,
        height: h,
        texels,
    }
}

/// Alpha-weighted colour and mean alpha of a footprint.
fn reduce_color(taps: &mut dyn Iterator<Item = (&[f32; 4], f32)>) -> [f32; 4] {
    let (mut premul, mut plain, mut alpha) = ([0.0f32; 3], [0.0f32; 3], 0.0f32);
    for (t, w) in taps {
        for k in 0..3 {
            premul[k] += w * t[3] * t[k];
            plain[k] += w * t[k];
        }
        alpha += w * t[3];
    }
    if alpha > 1e-6 {
        [
            premul[0] / alpha,
            premul[1] / alpha,
            premul[2] / alpha,
            alpha,
        ]
    } else {
        [plain[0], plain[1], plain[2], alpha]
    }
}

/// Fraction of alphas ≥ [`ALPHA_THRESHOLD`].
pub fn alpha_coverage(alphas: impl Iterator<Item = f32>) -> f32 {
    let (mut pass, mut n) = (0usize, 0usize);
    for a in alphas {
        pass += usize::from(a >= ALPHA_THRESHOLD);
        n += 1;
    }
    if n == 0 { 0.0 } else { pass as f32 / n as f32 }
}

/// The scale that makes round(`target` · n) of `alphas` pass the threshold (nearest possible
/// when values tie); 1 when the level already has that many.
pub fn coverage_scale(alphas: &[f32], target: f32) -> f32 {
    let n = alphas.len();
    if n == 0 {
        return 1.0;
    }
    let mut sorted = alphas.to_vec();
    sorted.sort_unstable_by(|a, b| b.total_cmp(a));
    let want = ((target * n as f32).round() as usize).min(n);
    // With ties across the cut, k is the achievable count closest to `want` (on a draw the
    // larger, so thin features stay visible).
    let k = achievable_count(&sorted, want);
    // Any threshold t in (sorted[k], sorted[k−1]] lets exactly the k largest pass.
    let hi = if k == 0 { f32::INFINITY } else { sorted[k - 1] };
    let lo = if k == n { f32::NEG_INFINITY } else { sorted[k] };
    if ALPHA_THRESHOLD > lo && ALPHA_THRESHOLD <= hi {
        return 1.0;
    }
    let t = match (k == 0, k == n) {
        (true, _) => lo * 1.001 + 1e-6,
        (_, true) => hi,
        _ => 0.5 * (lo + hi),
    };
    // Slightly above 0.5/t so that a texel exactly at t still passes after rounding.
    (ALPHA_THRESHOLD / t.max(1e-6)) * (1.0 + 1e-6)
}

/// The number of largest values a threshold can separate (values tie) closest to `want`.
fn achievable_count(sorted_desc: &[f32], want: usize) -> usize {
    if want == 0 || want == sorted_desc.len() || sorted_desc[want - 1] > sorted_desc[want] {
        return want;
    }
    let v = sorted_desc[want - 1];
    let first = sorted_desc.partition_point(|&a| a > v);
    let last = sorted_desc.partition_point(|&a| a >= v);
    if want - first < last - want {
        first
    } else {
        last
    }
}

/// Builds the whole chain from linear RGBA (straight, not premultiplied, alpha).
pub fn build_color_mips(base: MipLevel<[f32; 4]>, opts: &MipOptions) -> ColorMips {
    let target = alpha_coverage(base.texels.iter().map(|t| t[3]));
    let sizes = mip_sizes(base.width, base.height);
    let mut out = ColorMips {
        levels: Vec::with_capacity(sizes.len()),
        coverage: vec![target],
        alpha_scale: vec![1.0],
    };
    // `raw` carries the unscaled mean alpha from level to level.
    let mut raw = base.clone();
    out.levels.push(base);
    for &(w, h) in &sizes[1..] {
        raw = downsample(&raw, w, h, reduce_color);
        let mut level = raw.clone();
        let scale = if opts.preserve_coverage {
            let alphas: Vec<f32> = level.texels.iter().map(|t| t[3]).collect();
            coverage_scale(&alphas, target)
        } else {
            1.0
        };
        for t in &mut level.texels {
            t[3] = (t[3] * scale).min(1.0);
        }
        out.coverage
            .push(alpha_coverage(level.texels.iter().map(|t| t[3])));
        out.alpha_scale.push(scale);
        out.levels.push(level);
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A procedural leaf: an ellipse pointed at both ends with a serrated rim and a
    /// one-texel antialiased edge, on a transparent white background.
    pub(crate) fn leaf(size: u32) -> MipLevel<[f32; 4]> {
        let s = size as f32;
        let texels = (0..size * size)
            .map(|i| {
                let (x, y) = ((i % size) as f32 + 0.5, (i / size) as f32 + 0.5);
                let (u, v) = (2.0 * x / s - 1.0, 2.0 * y / s - 1.0);
                // Half-width of the leaf at height v, pointed at v = ±0.9, serrated.
                let t = (v / 0.9).clamp(-1.0, 1.0);
                let half = 0.42 * (1.0 - t * t).powf(0.8) * (1.0 + 0.08 * (t * 40.0).sin());
                let inside = (half - u.abs()) * s / 2.0; // texels inside the rim
                let a = (inside + 0.5).clamp(0.0, 1.0);
                let vein = if u.abs() < 0.02 { 0.8 } else { 0.3 };
                if a > 0.0 {
                    [0.1 * vein, vein, 0.05, a]
                } else {
                    [1.0, 1.0, 1.0, 0.0]
                }
            })
            .collect();
        MipLevel {
            width: size,
            height: size,
            texels,
        }
    }

    #[test]
    fn coverage_is_preserved_down_to_8x8_on_a_leaf() {
        let mips = build_color_mips(leaf(512), &MipOptions::default());
        let c0 = mips.coverage[0];
        assert!(c0 > 0.2 && c0 < 0.6, "leaf covers {c0}");
        for (level, c) in mips.levels.iter().zip(&mips.coverage) {
            // Recount from the texels (not the bookkeeping).
            let recount = alpha_coverage(level.texels.iter().map(|t| t[3]));
            assert_eq!(recount, *c);
            // Within 2 % of the texels (absolute): at 8×8 one texel is 1.6 %, and this leaf is
            // mirror-symmetric, so texels pass in pairs.
            if level.width >= 8 {
                assert!(
                    (c - c0).abs() <= 0.02,
                    "{}×{}: coverage {c} vs {c0}",
                    level.width,
                    level.height
                );
            }
        }
    }

    /// Tapered grass blades with antialiased edges, on transparent ground.
    fn grass(size: u32) -> MipLevel<[f32; 4]> {
        let s = size as f32;
        let blades = [
            (0.12, 0.010, 0.9),
            (0.31, 0.006, 0.7),
            (0.5, 0.012, 0.95),
            (0.68, 0.005, 0.6),
            (0.86, 0.008, 0.8),
        ];
        let texels = (0..size * size)
            .map(|i| {
                let (x, y) = (
                    ((i % size) as f32 + 0.5) / s,
                    1.0 - ((i / size) as f32 + 0.5) / s,
                );
                let a = blades
                    .iter()
                    .map(|&(cx, half, top)| {
                        let taper = (1.0 - y / top).max(0.0);
                        let lean = cx + 0.05 * y * y;
                        ((half * taper - (x - lean).abs()) * s + 0.5).clamp(0.0, 1.0)
                    })
                    .fold(0.0f32, f32::max);
                [0.2, 0.6, 0.1, a]
            })
            .collect();
        MipLevel {
            width: size,
            height: size,
            texels,
        }
    }

    #[test]
    fn plain_mean_alpha_drifts_where_scaling_does_not() {
        // Why the scale exists: the thesis' plain mean lets thin blade tips vanish.
        let plain = build_color_mips(
            grass(256),
            &MipOptions {
                preserve_coverage: false,
            },
        );
        let scaled = build_color_mips(grass(256), &MipOptions::default());
        let drift = |m: &ColorMips| {
            m.levels
                .iter()
                .zip(&m.coverage)
                .filter(|(l, _)| l.width >= 8)
                .map(|(_, c)| (c - m.coverage[0]).abs())
                .fold(0.0f32, f32::max)
        };
        assert!(
            drift(&plain) > drift(&scaled),
            "{:?} vs {:?}",
            plain.coverage,
            scaled.coverage
        );
        assert!(drift(&scaled) <= 0.02, "{:?}", scaled.coverage);
        // On the leaf, the scaled chain is never further off than texel counts force.
        let leafy = build_color_mips(leaf(512), &MipOptions::default());
        for (l, c) in leafy.levels.iter().zip(&leafy.coverage) {
            let n = (l.width * l.height) as f32;
            assert!(
                (c - leafy.coverage[0]).abs() <= 2.0 / n + 1e-6,
                "{}×{}",
                l.width,
                l.height
            );
        }
    }

    #[test]
    fn colour_is_alpha_weighted_and_alpha_is_the_mean() {
        let base = MipLevel {
            width: 2,
            height: 2,
            texels: vec![
                [0.0, 1.0, 0.0, 1.0],
                [1.0, 1.0, 1.0, 0.0],
                [0.0, 0.5, 0.0, 1.0],
                [1.0, 1.0, 1.0, 0.0],
            ],
        };
        let m = build_color_mips(
            base,
            &MipOptions {
                preserve_coverage: false,
            },
        );
        assert_eq!(m.levels.len(), 2);
        let t = m.levels[1].texels[0];
        assert_eq!(t, [0.0, 0.75, 0.0, 0.5]);
    }

    #[test]
    fn odd_sizes_use_exact_area_weights() {
        let w = box_weights(5, 2);
        assert_eq!(w[0], vec![(0, 0.4), (1, 0.4), (2, 0.2)]);
        assert_eq!(w[1], vec![(2, 0.2), (3, 0.4), (4, 0.4)]);
        for taps in box_weights(7, 3) {
            let s: f32 = taps.iter().map(|t| t.1).sum();
            assert!((s - 1.0).abs() < 1e-6);
        }
        assert_eq!(mip_sizes(5, 3), vec![(5, 3), (2, 1), (1, 1)]);
        // A constant image stays constant through odd sizes.
        let base = MipLevel {
            width: 5,
            height: 3,
            texels: vec![[0.25, 0.5, 0.75, 1.0]; 15],
        };
        for l in build_color_mips(base, &MipOptions::default()).levels {
            for t in l.texels {
                for k in 0..4 {
                    assert!((t[k] - [0.25, 0.5, 0.75, 1.0][k]).abs() < 1e-6);
                }
            }
        }
    }
}
