//! Height maps from colour, tangent-space normal maps from heights, and normal-map mips that
//! keep the filtered normal's length for the Toksvig factor (seed 000 3.1.2, 4.7.3).
//!
//! Tangent space: +X along increasing u (image columns), +Y along increasing v (image rows, v = 0
//! at the top row, see model.rs), +Z the surface normal: the frame MikkTSpace builds from the
//! mesh's UVs. Encoding `(r, g, b) = (n + 1) / 2` with `z > 0`. Filtered levels average the
//! unit normals of the footprint; the average is shorter where the normals disagree, and that
//! length `|n̄|` (1 at level 0) is kept beside the renormalized direction: the shader multiplies
//! the roughness by it (Toksvig's factor adapted to Schlick, 4.7.3).

use super::mips::{MipLevel, downsample, mip_sizes};
use rayon::prelude::*;

/// A normal-map mip chain: unit direction and the length of the filtered (averaged) normal.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalMips {
    /// Per level: (unit normal, length of the averaged normal in [0, 1]).
    pub levels: Vec<MipLevel<([f32; 3], f32)>>,
}

/// Height in [0, 1] from the mean of the linear colour (the thesis' "Mittelwert der Farben").
pub fn height_from_color(texels: &[[f32; 4]]) -> Vec<f32> {
    texels
        .iter()
        .map(|t| ((t[0] + t[1] + t[2]) / 3.0).clamp(0.0, 1.0))
        .collect()
}

/// Normals of a height field by central differences (one-sided at the edges): `n ∝ (−s·∂h/∂x,
/// −s·∂h/∂y, 1)` with derivatives per texel. `slope` converts a height difference of 1 over one
/// texel into tangent-space slope: `slope = 2·bump_height / texel_size` for heights spanning
/// ±bump_height metres.
pub fn normals_from_height(heights: &[f32], width: u32, height: u32, slope: f32) -> Vec<[f32; 3]> {
    let (w, h) = (width as usize, height as usize);
    let mut out = vec![[0.0f32; 3]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, dst)| {
        let at = |x: usize, y: usize| heights[y * w + x];
        let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for (x, n) in dst.iter_mut().enumerate() {
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let dx = (at(x1, y) - at(x0, y)) / (x1 - x0).max(1) as f32;
            let dy = (at(x, y1) - at(x, y0)) / (y1 - y0).max(1) as f32;
            *n = normalize([-slope * dx, -slope * dy, 1.0]);
        }
    });
    out
}

pub(crate) fn normalize(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 1e-12 {
        v.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// Decodes an authored normal map texel (`n = 2·rgb − 1`), forcing the normal to the front side.
pub fn decode_normal(rgba: [u8; 4]) -> [f32; 3] {
    let c = |k: usize| rgba[k] as f32 / 255.0 * 2.0 - 1.0;
    let n = normalize([c(0), c(1), c(2)]);
    if n[2] > 1e-3 {
        n
    } else {
        normalize([n[0], n[1], 1e-3])
    }
}

/// Encodes a unit normal as `(n + 1) / 2` in 8 bits and the Toksvig length in alpha.
pub fn encode_normal(n: [f32; 3], length: f32) -> [u8; 4] {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    [
        q((n[0] + 1.0) * 0.5),
        q((n[1] + 1.0) * 0.5),
        q((n[2] + 1.0) * 0.5),
        q(length),
    ]
}

/// Builds the chain from level-0 unit normals: each level averages the *unit* normals of
/// level 0 over its footprint (through the previous level's unnormalized averages, which is the
/// same box filter), so the kept length is the true filtered length.
pub fn build_normal_mips(normals: Vec<[f32; 3]>, width: u32, height: u32) -> NormalMips {
    let sizes = mip_sizes(width, height);
    let mut avg = MipLevel {
        width,
        height,
        texels: normals,
    };
    let mut levels = Vec::with_capacity(sizes.len());
    let split = |l: &MipLevel<[f32; 3]>| MipLevel {
        width: l.width,
        height: l.height,
        texels: l
            .texels
            .iter()
            .map(|&n| {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                (normalize(n), len.min(1.0))
            })
            .collect(),
    };
    levels.push(split(&avg));
    for &(w, h) in &sizes[1..] {
        avg = downsample(&avg, w, h, |taps| {
            let mut s = [0.0f32; 3];
            for (n, wt) in taps {
                for k in 0..3 {
                    s[k] += wt * n[k];
                }
            }
            s
        });
        levels.push(split(&avg));
    }
    NormalMips { levels }
}

/// Box-filtered mips of a scalar map (heights).
pub fn build_scalar_mips(values: Vec<f32>, width: u32, height: u32) -> Vec<MipLevel<f32>> {
    let sizes = mip_sizes(width, height);
    let mut levels = vec![MipLevel {
        width,
        height,
        texels: values,
    }];
    for &(w, h) in &sizes[1..] {
        let next = downsample(levels.last().expect("level 0"), w, h, |taps| {
            taps.map(|(v, wt)| v * wt).sum()
        });
        levels.push(next);
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ramp_gives_the_analytic_normal() {
        // h = 0.01·x: slope s·0.01 along +x, so n ∝ (−0.01·s, 0, 1).
        let (w, h) = (16u32, 8u32);
        let heights: Vec<f32> = (0..w * h).map(|i| 0.01 * (i % w) as f32).collect();
        let s = 50.0;
        let n = normals_from_height(&heights, w, h, s);
        let expect = normalize([-0.5, 0.0, 1.0]);
        for v in &n {
            for k in 0..3 {
                assert!((v[k] - expect[k]).abs() < 1e-5, "{v:?} vs {expect:?}");
            }
        }
        // Encoded: z > 0 always, (r, g, b) = (n + 1)/2.
        let e = encode_normal(expect, 1.0);
        assert_eq!(e[0], ((expect[0] + 1.0) * 0.5 * 255.0).round() as u8);
        assert!(e[2] > 128);
        let back = decode_normal(e);
        assert!((back[0] - expect[0]).abs() < 0.01 && (back[2] - expect[2]).abs() < 0.01);
    }

    #[test]
    fn filtered_length_matches_the_mean_of_unit_normals() {
        // A checkerboard of two tilted normals ±30° about Y: the 2×2 mean is (0, 0, cos 30°).
        let a = [0.5f32, 0.0, 0.75f32.sqrt()];
        let b = [-0.5f32, 0.0, 0.75f32.sqrt()];
        let normals: Vec<[f32; 3]> = (0..16)
            .map(|i| if (i + i / 4) % 2 == 0 { a } else { b })
            .collect();
        let m = build_normal_mips(normals, 4, 4);
        assert_eq!(m.levels.len(), 3);
        assert!(m.levels[0].texels.iter().all(|t| (t.1 - 1.0).abs() < 1e-6));
        for l in &m.levels[1..] {
            for (n, len) in &l.texels {
                assert!((len - 0.75f32.sqrt()).abs() < 1e-5, "{len}");
                assert!((n[2] - 1.0).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn height_is_the_mean_colour() {
        assert!((height_from_color(&[[0.3, 0.6, 0.9, 1.0]])[0] - 0.6).abs() < 1e-6);
    }
}
