//! Texel-space filters of the terrain light map (issue 37, item 4): a bilateral filter of the
//! part without the direct sun (sky and bounce), edge-preserving through its range kernel,
//! and a plain box (the benchmark's comparison). Each output texel is a pure function of its
//! neighbourhood, so the result does not depend on the thread count.

use rayon::prelude::*;

fn lum(p: [f32; 3]) -> f64 {
    (p[0] + p[1] + p[2]) as f64 / 3.0
}

/// Every texel of a map (or a strip of rows) `width` texels wide replaced by the mean of the
/// texels in its (2r+1)² window clamped at the edges, weighted by `weight(centre, neighbour)`
/// (their indices): the one loop of the filters below.
fn window_mean(
    v: &[[f32; 3]],
    width: usize,
    r: usize,
    weight: impl Fn(usize, usize) -> f64 + Sync,
) -> Vec<[f32; 3]> {
    let width = width.max(1);
    let h = v.len() / width;
    let mut out = vec![[0.0f32; 3]; v.len()];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let centre = y * width + x;
            let mut s = [0.0f64; 3];
            let mut wsum = 0.0f64;
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(width) {
                    let i = yy * width + xx;
                    let w = weight(centre, i);
                    for c in 0..3 {
                        s[c] += w * v[i][c] as f64;
                    }
                    wsum += w;
                }
            }
            *o = s.map(|q| (q / wsum) as f32);
        }
    });
    out
}

/// Bilateral filter of radius `r` over a map (or a strip of rows) `width` texels wide, clamped
/// at its edges: neighbours weighted by exp(−(Δ / (t·c))²), Δ the difference of their RGB mean
/// from the centre texel's mean c, so a step larger than about t of the value is kept and
/// differences well below it (the Monte-Carlo noise) are averaged.
pub fn bilateral(v: &[[f32; 3]], width: usize, r: usize, t: f32) -> Vec<[f32; 3]> {
    joint_bilateral(v, v, width, r, t)
}

/// [`bilateral`] with the range weights taken from a guide (same size) instead of the values:
/// exp(−((g(q) − g(p)) / (t·g(p)))²) over the RGB means of the guide; the values averaged are
/// `v`'s. With a guide less noisy than `v` (its 3×3 box, [`guided_bilateral`]) the weights follow
/// the map's edges rather than the noise of the centre texel.
pub fn joint_bilateral(
    v: &[[f32; 3]],
    guide: &[[f32; 3]],
    width: usize,
    r: usize,
    t: f32,
) -> Vec<[f32; 3]> {
    window_mean(v, width, r, |p, q| {
        let c = lum(guide[p]);
        let scale = (t as f64 * c.abs()).max(1e-12);
        (-((lum(guide[q]) - c) / scale).powi(2)).exp()
    })
}

/// [`joint_bilateral`] guided by the values' own 3×3 box ([`box_filter`] of radius 1).
pub fn guided_bilateral(v: &[[f32; 3]], width: usize, r: usize, t: f32) -> Vec<[f32; 3]> {
    joint_bilateral(v, &box_filter(v, width, 1), width, r, t)
}

/// Bilateral filter of radius `r` whose range follows each texel's noise: neighbours weighted
/// by exp(−Δ² / (k² (σ²_p + σ²_q))), Δ the difference of their RGB means, σ² the texels' noise
/// variances (`variance`, the same size) averaged over their 3×3 box first (a texel's own
/// estimate from its few rays is itself noisy: a texel whose rays all escaped states none).
/// Two texels that differ by their noise alone weigh about exp(−1/k²); a step well above both
/// noises is kept, however small relative to the value.
pub fn noise_bilateral(
    v: &[[f32; 3]],
    variance: &[f32],
    width: usize,
    r: usize,
    k: f32,
) -> Vec<[f32; 3]> {
    let k2 = (k as f64).powi(2);
    let boxed: Vec<[f32; 3]> = variance.iter().map(|&s| [s; 3]).collect();
    let variance: Vec<f32> = box_filter(&boxed, width, 1).iter().map(|s| s[0]).collect();
    window_mean(v, width, r, |p, q| {
        let d = lum(v[q]) - lum(v[p]);
        let s2 = k2 * (variance[p] as f64 + variance[q] as f64);
        if q == p {
            1.0
        } else if s2 > 0.0 {
            (-d * d / s2).exp()
        } else {
            0.0
        }
    })
}

/// Box filter of radius `r` over a strip of rows `width` texels wide (clamped at the edges:
/// the mean of the texels inside both the box and the strip).
pub fn box_filter(v: &[[f32; 3]], width: usize, r: usize) -> Vec<[f32; 3]> {
    window_mean(v, width, r, |_, _| 1.0)
}

/// The texels with their part without the direct sun (`texels − direct`) filtered by
/// [`bilateral`] and the direct sun added back unfiltered (its shadow edges are sharp).
pub fn filter_indirect(
    texels: &[[f32; 3]],
    direct: &[[f32; 3]],
    width: usize,
    r: usize,
    t: f32,
) -> Vec<[f32; 3]> {
    let ind: Vec<[f32; 3]> = texels
        .iter()
        .zip(direct)
        .map(|(e, d)| std::array::from_fn(|c| e[c] - d[c]))
        .collect();
    bilateral(&ind, width, r, t)
        .iter()
        .zip(direct)
        .map(|(f, d)| std::array::from_fn(|c| f[c] + d[c]))
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_box_filter_averages_inside_the_strip() {
        // 3 × 2 strip: values 0..6 (one channel repeated).
        let v: Vec<[f32; 3]> = (0..6).map(|i| [i as f32; 3]).collect();
        let f = super::box_filter(&v, 3, 1);
        // Corner (0, 0): texels 0, 1, 3, 4; centre top (1, 0): 0, 1, 2, 3, 4, 5.
        assert_eq!(f[0], [2.0; 3]);
        assert_eq!(f[1], [2.5; 3]);
        assert_eq!(f[5], [(1.0 + 2.0 + 4.0 + 5.0) / 4.0; 3]);
        assert_eq!(super::box_filter(&v, 3, 0), v);
    }

    #[test]
    fn the_bilateral_keeps_an_edge_and_averages_noise_below_its_range() {
        // A step 1 → 10 across a 6 × 3 strip, ±2 % noise: a range of 0.2 averages the noise
        // and keeps the step; a huge range blurs it (a box).
        let v: Vec<[f32; 3]> = (0..18)
            .map(|i| {
                let base = if i % 6 < 3 { 1.0 } else { 10.0 };
                [base * (1.0 + if i % 2 == 0 { 0.02 } else { -0.02 }); 3]
            })
            .collect();
        let f = super::bilateral(&v, 6, 1, 0.2);
        for (i, t) in f.iter().enumerate() {
            let base = if i % 6 < 3 { 1.0 } else { 10.0 };
            assert!((t[0] - base).abs() < 0.02 * base, "{i}: {t:?}");
        }
        let b = super::bilateral(&v, 6, 1, 1e6);
        assert!(b[2][0] > 3.0, "{:?}", b[2]);
    }

    #[test]
    fn filtering_the_indirect_part_keeps_the_direct_sun() {
        // A sharp direct-sun edge on a flat indirect field: untouched.
        let direct: Vec<[f32; 3]> = (0..16)
            .map(|i| [if i % 4 < 2 { 0.0 } else { 5.0 }; 3])
            .collect();
        let texels: Vec<[f32; 3]> = direct.iter().map(|d| [d[0] + 1.0; 3]).collect();
        let f = super::filter_indirect(&texels, &direct, 4, 2, 0.3);
        for (a, b) in f.iter().zip(&texels) {
            assert!((a[0] - b[0]).abs() < 1e-6, "{a:?} {b:?}");
        }
    }

    #[test]
    fn the_guided_bilateral_averages_noise_on_a_flat_field_and_joint_with_itself_is_the_bilateral()
    {
        // ±10 % alternating noise on a flat field of 2: at range 0.05 the plain bilateral keeps
        // most of it (each neighbour 20 % off its centre), the guided one (weights from the 3×3
        // box, about ±1 %) averages it.
        let v: Vec<[f32; 3]> = (0..64)
            .map(|i| [2.0 * (1.0 + if (i + i / 8) % 2 == 0 { 0.1 } else { -0.1 }); 3])
            .collect();
        let dev = |f: &[[f32; 3]]| f.iter().map(|t| (t[0] - 2.0).abs()).fold(0.0f32, f32::max);
        let (plain, guided) = (
            super::bilateral(&v, 8, 2, 0.05),
            super::guided_bilateral(&v, 8, 2, 0.05),
        );
        assert!(dev(&plain) > 0.15, "{}", dev(&plain));
        assert!(dev(&guided) < 0.05, "{}", dev(&guided));
        assert_eq!(
            super::joint_bilateral(&v, &v, 8, 2, 0.3),
            super::bilateral(&v, 8, 2, 0.3)
        );
    }

    #[test]
    fn the_noise_aware_bilateral_keeps_a_step_above_the_noise_and_averages_below_it() {
        // A step 10 → 11 (10 %) across an 8 × 4 strip with ±0.05 noise (σ² = 0.0025 stated):
        // at k = 2 the noise is averaged and the step kept; the fixed-range bilateral that
        // averages the same noise (range 0.3) blurs the step.
        let v: Vec<[f32; 3]> = (0..32)
            .map(|i| {
                let base = if i % 8 < 4 { 10.0 } else { 11.0 };
                [base + if (i + i / 8) % 2 == 0 { 0.05 } else { -0.05 }; 3]
            })
            .collect();
        let var = vec![0.0025f32; 32];
        let f = super::noise_bilateral(&v, &var, 8, 2, 2.0);
        for (i, t) in f.iter().enumerate() {
            let base = if i % 8 < 4 { 10.0 } else { 11.0 };
            assert!((t[0] - base).abs() < 0.04, "{i}: {t:?}");
        }
        let fixed = super::bilateral(&v, 8, 2, 0.3);
        assert!((fixed[3][0] - 10.0).abs() > 0.1, "{:?}", fixed[3]);
        // Without noise nothing is averaged.
        assert_eq!(super::noise_bilateral(&v, &[0.0; 32], 8, 2, 2.0), v);
    }
}
