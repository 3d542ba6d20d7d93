//! Sun extraction (seed 000, 3.4.2, with the brief's corrections) and the sky's irradiance.
//!
//! The thesis takes the n brightest texels covering the sun's solid angle `a = π r²`
//! (r = atan(0.5 d / l) = 0.00465 rad) enlarged by a factor (4.0) for scattering and blooming,
//! replaces them by the (n+1)-th brightest value T_{n+1} so the remaining sky stays continuous, and
//! reports `I_S = Σ_{i≤n} (T_i − T_{n+1}) / n · a` (eq. 3.2) and `I_H = Σ_m T_i / m · 2π` (3.3).
//!
//! What bake does better, reporting the thesis' numbers beside its own:
//! - texels are counted by their exact solid angle until they cover `enlargement · a` (cube
//!   texels differ by up to 5.2× between a face's centre and its corners); a sun larger than
//!   that (blurred, painted, or at low resolution) is taken whole: texels still 100× brighter
//!   than the median sky join it, up to 1% of the sphere;
//! - the texels are replaced by the local sky, the mean of a ring two texels wide around them,
//!   not by T_{n+1}: the map's (n+1)-th brightest texel is the sky beside the sun only when the
//!   circumsolar sky is the brightest part of the map (a bright ground, cloud or a steep aureole
//!   biased the sun by percents);
//! - the sun irradiance is the energy actually removed, `Σ (T_i − T_ring) · ω_i` (the thesis'
//!   mean × a undercounts by the enlargement factor), so sky + sun conserve the map's energy;
//! - the direction is the energy-weighted centroid of the removed excess, not the brightest texel;
//! - a plateau at the map's maximum (a clipped sun, common in real HDRIs) is reported;
//! - the sky's irradiance on a horizontal surface is `∫_{z>0} L cos θ dω`.
//!
//! On an overcast sky the n brightest texels barely exceed T_{n+1}, so the sun is negligible.

use super::cube::{self, CubeMap, Face};
use serde::{Deserialize, Serialize};

/// Angular radius of the sun seen from the earth: atan(0.5 · 1 392 000 km / 149 600 000 km).
pub const SUN_ANGULAR_RADIUS: f64 = 0.004_652_3;
/// The thesis' enlargement of the sun's area (3.4.2).
pub const DEFAULT_ENLARGEMENT: f64 = 4.0;
/// Relative distance from the maximum within which texels count as one plateau (clipping).
const PLATEAU_TOLERANCE: f32 = 1e-3;
/// Texels this many times brighter than the median sky still belong to the sun (the sun is
/// ~10⁵ times the sky; circumsolar sky and clipped suns stay below).
const SUN_CONTRAST: f32 = 100.0;
/// Upper bound of the sun's area when it is taken by contrast: 1% of the sphere.
const MAX_SUN_AREA: f64 = 0.04 * std::f64::consts::PI;
/// Texels at the maximum needed to call the sun clipped (more than the 4 equal texels of a
/// symmetric disc centred on a texel corner).
const PLATEAU_MIN_TEXELS: u32 = 5;

/// Options of [`extract_sun`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SunOptions {
    /// Factor on the sun's solid angle `π r²` covered by the extracted texels.
    pub enlargement: f64,
}

impl SunOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: SunOptions = SunOptions {
        enlargement: DEFAULT_ENLARGEMENT,
    };
}

impl Default for SunOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The extracted sun.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sun {
    /// Unit direction towards the sun: energy-weighted centroid of the removed excess.
    pub direction: [f32; 3],
    /// Direction of the brightest texel (the thesis' choice).
    pub direction_brightest: [f32; 3],
    /// Irradiance on a surface facing the sun: `Σ (T_i − T_ring) ω_i` (RGB).
    pub irradiance: [f32; 3],
    /// The thesis' eq. 3.2: `Σ (T_i − T_{n+1}) / n · π r²` (RGB).
    pub irradiance_thesis: [f32; 3],
    /// Texels replaced (n).
    pub texels: u32,
    /// Their total solid angle (sr).
    pub solid_angle: f64,
    /// The replacement value T_ring, the sky around the sun (RGB radiance; T_{n+1} when the
    /// ring is empty).
    pub replacement: [f32; 3],
    /// Largest radiance (luminance) of the map.
    pub peak_luminance: f32,
    /// Texels within 0.1% of the peak.
    pub plateau_texels: u32,
    /// A plateau of at least 5 texels at the map's maximum: the sun was probably clipped in the
    /// source, and its irradiance is a lower bound.
    pub clipped: bool,
    /// The enlargement factor used.
    pub enlargement: f64,
    /// The sun's angular radius assumed (rad).
    pub angular_radius: f64,
}

/// Irradiance of the (sun-free) sky.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SkyIrradiance {
    /// `∫_{z>0} L cos θ dω`: what a horizontal surface receives (RGB).
    pub horizontal: [f32; 3],
    /// The thesis' eq. 3.3: mean radiance of the upper-hemisphere texels × 2π (RGB).
    pub thesis: [f32; 3],
}

pub use crate::color::luminance;

/// Median luminance of the upper hemisphere's texels (the sky's typical brightness).
fn median_sky_luminance(cube: &CubeMap, lum: &[f32]) -> f32 {
    use rayon::prelude::*;
    let size = cube.size;
    let n = size as usize;
    // (z > 0 of the unnormalized direction is z > 0 of the texel's unit direction.)
    let mut up: Vec<f32> = lum
        .par_chunks(n)
        .enumerate()
        .flat_map_iter(|(fr, line)| {
            let (face, t) = (
                Face::ALL[fr / n],
                2.0 * ((fr % n) as f64 + 0.5) / n as f64 - 1.0,
            );
            line.iter().enumerate().filter_map(move |(col, &l)| {
                let s = 2.0 * (col as f64 + 0.5) / n as f64 - 1.0;
                (face.direction(s, t)[2] > 0.0).then_some(l)
            })
        })
        .collect();
    if up.is_empty() {
        return 0.0;
    }
    let mid = up.len() / 2;
    *up.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Texel indices ordered by luminance, brightest first (ties by index, so the order is unique),
/// and n, the number of sun texels: enough to cover `area` sr, then on while the next texel is
/// still [`SUN_CONTRAST`] times brighter than the median sky (a sun larger than the enlarged
/// disc: blurred, painted or seen at low resolution), up to [`MAX_SUN_AREA`]. The order holds
/// at least n + 1 texels.
fn brightest_covering(cube: &CubeMap, omega: &[f64], area: f64) -> (Vec<usize>, usize) {
    use rayon::prelude::*;
    let n2 = omega.len();
    let lum: Vec<f32> = cube.texels.par_iter().map(|&t| luminance(t)).collect();
    let median = median_sky_luminance(cube, &lum);
    let threshold = if median > 0.0 {
        median * SUN_CONTRAST
    } else {
        f32::INFINITY
    };
    let hot = lum.par_iter().filter(|&&l| l > threshold).count();
    let min_omega = omega.iter().cloned().fold(f64::INFINITY, f64::min);
    let bound = ((area / min_omega).ceil() as usize + 2)
        .max(hot + 2)
        .min(cube.texels.len());
    let order = |a: &usize, b: &usize| lum[*b].total_cmp(&lum[*a]).then(a.cmp(b));
    // The `bound` first texels of that order: every texel at least as bright as the bound-th
    // brightest luminance (found from each chunk's own brightest, in parallel), sorted.
    let floor = bound_th_brightest(&lum, bound);
    let mut idx: Vec<usize> = (0..lum.len())
        .into_par_iter()
        .filter(|&i| lum[i].total_cmp(&floor).is_ge())
        .collect();
    idx.sort_unstable_by(order);
    idx.truncate(bound);
    let mut covered = 0.0;
    let mut n = 0;
    while n + 1 < idx.len()
        && (covered < area || (lum[idx[n]] > threshold && covered < MAX_SUN_AREA))
    {
        covered += omega[idx[n] % n2];
        n += 1;
    }
    let n = n.max(1).min(idx.len().saturating_sub(1));
    (idx, n)
}

/// The `k`-th largest of `lum` (1-based, `f32::total_cmp` order; the smallest if k ≥ len): the
/// k-th largest of the union of every chunk's k largest.
fn bound_th_brightest(lum: &[f32], k: usize) -> f32 {
    use rayon::prelude::*;
    let desc = |a: &f32, b: &f32| b.total_cmp(a);
    let k_largest = |v: &mut Vec<f32>| {
        if v.len() > k {
            v.select_nth_unstable_by(k - 1, desc);
            v.truncate(k);
        }
    };
    let mut tops: Vec<f32> = lum
        .par_chunks(1 << 14)
        .flat_map_iter(|c| {
            let mut v = c.to_vec();
            k_largest(&mut v);
            v
        })
        .collect();
    k_largest(&mut tops);
    tops.into_iter().min_by(f32::total_cmp).unwrap_or(0.0)
}

/// Unit direction of texel `i` of the cube (face-major index).
pub fn texel_index_direction(size: u32, i: usize) -> [f64; 3] {
    let n2 = (size as usize).pow(2);
    let (face, rc) = (Face::ALL[i / n2], i % n2);
    let (col, row) = ((rc % size as usize) as u32, (rc / size as usize) as u32);
    cube::texel_direction(size, face, col, row)
}

/// Cosine of the angle from the sun's direction within which texels belong to the sun: the
/// radius of [`MAX_SUN_AREA`]. (The n brightest texels that fill the enlarged disc's area also
/// take the brightest sky texels elsewhere when the sun covers fewer texels than that area.)
fn cos_near_sun() -> f64 {
    (MAX_SUN_AREA / std::f64::consts::PI).sqrt().cos()
}

/// The sky around the sun: the solid-angle-weighted mean of the texels in a ring two centre
/// texels wide just outside the sun's texels `sun` near `dir` (angles beyond the farthest one's
/// within the radius of [`MAX_SUN_AREA`]), or `None` when the ring is empty. It replaces the sun's texels: the (n+1)-th
/// brightest texel of the whole map (the thesis' T_{n+1}) is the local sky only when the
/// circumsolar sky is the brightest; elsewhere (a bright ground or cloud, a steep aureole whose
/// ring value is below the sky under the disc) it biased the sun's irradiance by percents.
fn ring_mean(cube: &CubeMap, omega: &[f64], sun: &[usize], dir: [f64; 3]) -> Option<[f32; 3]> {
    use rayon::prelude::*;
    let n2 = omega.len();
    let dot = |d: [f64; 3]| d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2];
    let cos_in = sun
        .iter()
        .map(|&i| dot(texel_index_direction(cube.size, i)))
        .filter(|&c| c >= cos_near_sun())
        .fold(1.0f64, f64::min);
    let inner = cos_in.clamp(-1.0, 1.0).acos();
    let cos_out = (inner + 2.0 * 2.0 / cube.size as f64)
        .min(std::f64::consts::PI)
        .cos();
    let mut in_sun = sun.to_vec();
    in_sun.sort_unstable();
    // The ring's texels, found in parallel, in index order (so the sum below is the same on any
    // thread count).
    let n = cube.size as usize;
    // Texels surely outside cos_out, from the unnormalized direction v (v·dir < cos_out·|v|,
    // with a margin far above rounding), skip the exact test.
    let surely_out = move |v: [f64; 3]| {
        let (c, l2) = (dot(v), v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        cos_out > 0.0 && (c <= 0.0 || c * c < cos_out * cos_out * l2 * (1.0 - 1e-9))
    };
    let ring: Vec<usize> = (0..6 * n)
        .into_par_iter()
        .flat_map_iter(|fr| {
            let (face, row) = (Face::ALL[fr / n], (fr % n) as u32);
            let (in_sun, size) = (&in_sun, cube.size);
            let t = 2.0 * (row as f64 + 0.5) / n as f64 - 1.0;
            (0..n).filter_map(move |col| {
                let i = fr * n + col;
                let s = 2.0 * (col as f64 + 0.5) / n as f64 - 1.0;
                if surely_out(face.direction(s, t)) {
                    return None;
                }
                let c = dot(cube::texel_direction(size, face, col as u32, row));
                let out = c < cos_out || c > cos_in || in_sun.binary_search(&i).is_ok();
                (!out).then_some(i)
            })
        })
        .collect();
    let (mut acc, mut wsum) = ([0.0f64; 3], 0.0);
    for i in ring {
        let t = &cube.texels[i];
        let w = omega[i % n2];
        for k in 0..3 {
            acc[k] += t[k] as f64 * w;
        }
        wsum += w;
    }
    (wsum > 0.0).then(|| acc.map(|v| (v / wsum) as f32))
}

/// Separates the sun from the sky: returns the sun-free cube map and the sun.
pub fn extract_sun(cube: &CubeMap, opts: &SunOptions) -> (CubeMap, Sun) {
    let mut out = cube.clone();
    let sun = extract_sun_in_place(&mut out, &cube::solid_angle_table(cube.size), opts);
    (out, sun)
}

/// [`extract_sun`] without a copy: replaces the sun's texels of `cube` and returns the sun
/// (`omega`: the cube's [`cube::solid_angle_table`]).
pub fn extract_sun_in_place(cube: &mut CubeMap, omega: &[f64], opts: &SunOptions) -> Sun {
    use rayon::prelude::*;
    let n2 = omega.len();
    let a = std::f64::consts::PI * SUN_ANGULAR_RADIUS * SUN_ANGULAR_RADIUS;
    let (order, n) = brightest_covering(cube, omega, opts.enlargement.max(0.0) * a);
    // The direction: the centroid of the excess over T_{n+1}.
    let next_lum = luminance(cube.texels[order[n]]) as f64;
    let mut centroid = [0.0f64; 3];
    for &i in &order[..n] {
        let d = texel_index_direction(cube.size, i);
        let e = (luminance(cube.texels[i]) as f64 - next_lum).max(0.0) * omega[i % n2];
        for k in 0..3 {
            centroid[k] += e * d[k];
        }
    }
    let brightest = texel_index_direction(cube.size, order[0]);
    let direction = if centroid.iter().any(|&c| c != 0.0) {
        cube::normalize(centroid)
    } else {
        brightest
    };
    let replacement =
        ring_mean(cube, omega, &order[..n], direction).unwrap_or(cube.texels[order[n]]);
    let next = cube.texels[order[n]];
    let peak = luminance(cube.texels[order[0]]);
    // Over the whole map: a clipped region can be larger than the sun's enlarged area.
    let plateau = cube
        .texels
        .par_iter()
        .filter(|&&t| luminance(t) >= peak * (1.0 - PLATEAU_TOLERANCE))
        .count() as u32;
    let (mut irr, mut mean_excess, mut solid_angle) = ([0.0f64; 3], [0.0f64; 3], 0.0);
    for &i in &order[..n] {
        let t = cube.texels[i];
        let w = omega[i % n2];
        // Far texels (the brightest sky elsewhere, filling the area) keep T_{n+1}: a ring value
        // there would punch a hole in the sky.
        let d = texel_index_direction(cube.size, i);
        let near =
            d[0] * direction[0] + d[1] * direction[1] + d[2] * direction[2] >= cos_near_sun();
        let rep = if near { replacement } else { next };
        for k in 0..3 {
            irr[k] += (t[k] - rep[k]) as f64 * w;
            mean_excess[k] += (t[k] - next[k]) as f64 / n as f64;
        }
        solid_angle += w;
        // (Each sun texel is read, then replaced, once: `order` holds distinct texels.)
        cube.texels[i] = rep;
    }
    Sun {
        direction: direction.map(|c| c as f32),
        direction_brightest: brightest.map(|c| c as f32),
        irradiance: irr.map(|c| c as f32),
        irradiance_thesis: mean_excess.map(|c| (c * a) as f32),
        texels: n as u32,
        solid_angle,
        replacement,
        peak_luminance: peak,
        plateau_texels: plateau,
        clipped: peak > 0.0 && plateau >= PLATEAU_MIN_TEXELS,
        enlargement: opts.enlargement,
        angular_radius: SUN_ANGULAR_RADIUS,
    }
}

/// The sky's irradiance on a horizontal surface, exact solid angles, and the thesis' estimate.
pub fn sky_irradiance(cube: &CubeMap) -> SkyIrradiance {
    sky_irradiance_with(cube, &cube::solid_angle_table(cube.size))
}

/// [`sky_irradiance`] with the cube's [`cube::solid_angle_table`] computed already.
pub(crate) fn sky_irradiance_with(cube: &CubeMap, omega: &[f64]) -> SkyIrradiance {
    use rayon::prelude::*;
    let n = cube.size as usize;
    // Per face row (in parallel), then summed in row order: the same sums on any thread count.
    let rows: Vec<([f64; 3], [f64; 3], usize)> = cube
        .texels
        .par_chunks(n)
        .enumerate()
        .map(|(fr, texels)| {
            let (face, row) = (Face::ALL[fr / n], fr % n);
            let (mut horizontal, mut sum, mut m) = ([0.0f64; 3], [0.0f64; 3], 0usize);
            for (col, t) in texels.iter().enumerate() {
                let d = cube::texel_direction(cube.size, face, col as u32, row as u32);
                if d[2] <= 0.0 {
                    continue;
                }
                m += 1;
                for k in 0..3 {
                    horizontal[k] += t[k] as f64 * d[2] * omega[row * n + col];
                    sum[k] += t[k] as f64;
                }
            }
            (horizontal, sum, m)
        })
        .collect();
    let (mut horizontal, mut sum, mut m) = ([0.0f64; 3], [0.0f64; 3], 0usize);
    for (h, s, c) in rows {
        for k in 0..3 {
            horizontal[k] += h[k];
            sum[k] += s[k];
        }
        m += c;
    }
    let tau = std::f64::consts::TAU;
    SkyIrradiance {
        horizontal: horizontal.map(|c| c as f32),
        thesis: sum.map(|c| (c / m.max(1) as f64 * tau) as f32),
    }
}

/// Adds a sun disc of angular `radius` around unit `dir` with centre radiance `radiance` and
/// linear limb darkening `L(μ) = L0 (1 − u (1 − μ))`. Texels near the disc are supersampled
/// (`sub × sub` points weighted by the solid-angle Jacobian), so the added energy is the disc's
/// to a fraction of a percent. Returns the added irradiance `Σ ΔL · ω` (RGB).
pub fn add_sun_disc(
    cube: &mut CubeMap,
    dir: [f64; 3],
    radius: f64,
    radiance: [f32; 3],
    limb_u: f64,
    sub: u32,
) -> [f64; 3] {
    let size = cube.size;
    let omega = cube::solid_angle_table(size);
    let n2 = omega.len();
    let texel_angle = 2.0 / size as f64 * 1.5;
    let cos_reach = (radius + texel_angle).min(std::f64::consts::PI).cos();
    let cos_r = radius.cos();
    let mut added = [0.0f64; 3];
    for i in 0..cube.texels.len() {
        let c = texel_index_direction(size, i);
        if c[0] * dir[0] + c[1] * dir[1] + c[2] * dir[2] < cos_reach {
            continue;
        }
        let (face, rc) = (Face::ALL[i / n2], i % n2);
        let (col, row) = ((rc % size as usize) as f64, (rc / size as usize) as f64);
        let (mut acc, mut wsum) = (0.0, 0.0);
        for a in 0..sub {
            for b in 0..sub {
                let s = 2.0 * (col + (a as f64 + 0.5) / sub as f64) / size as f64 - 1.0;
                let t = 2.0 * (row + (b as f64 + 0.5) / sub as f64) / size as f64 - 1.0;
                let jac = (1.0 + s * s + t * t).powf(-1.5);
                let d = cube::normalize(face.direction(s, t));
                let cosang = d[0] * dir[0] + d[1] * dir[1] + d[2] * dir[2];
                if cosang >= cos_r {
                    // μ = cos of the angle at the sun's surface: √(1 − (ρ/r)²).
                    let rho = cosang.min(1.0).acos() / radius;
                    let mu = (1.0 - rho * rho).max(0.0).sqrt();
                    acc += jac * (1.0 - limb_u * (1.0 - mu));
                }
                wsum += jac;
            }
        }
        let cover = acc / wsum;
        if cover > 0.0 {
            for k in 0..3 {
                let dl = (radiance[k] as f64 * cover) as f32;
                cube.texels[i][k] += dl;
                added[k] += dl as f64 * omega[rc];
            }
        }
    }
    added
}

#[cfg(test)]
mod tests;
