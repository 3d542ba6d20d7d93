//! Float cube maps: the face convention, exact texel solid angles, filtered resampling from
//! latitude/longitude images and back.
//!
//! # Face order and orientation
//!
//! Faces are stored in the order +X, −X, +Y, −Y, +Z, −Z (index 0..6), each `size × size` texels,
//! row 0 first. The orientation is the one OpenGL, Vulkan, D3D and wgpu share (OpenGL 4.6 spec,
//! table 8.19), applied to **world** axes (Z up), so a shader samples the cube texture with the
//! world-space direction unchanged. With `s, t ∈ [−1, 1]` the face coordinates of a texel
//! (s grows with the column, t with the row; texel centre `s = 2(col + ½)/size − 1`):
//!
//! ```text
//!  face   direction (x, y, z)         unfolded (each face seen from the centre):
//!  +X     ( 1, −t, −s)
//!  −X     (−1, −t,  s)                        +----+
//!  +Y     ( s,  1,  t)                        | +Y |
//!  −Y     ( s, −1, −t)                   +----+----+----+----+
//!  +Z     ( s, −t,  1)                   | −X | +Z | +X | −Z |
//!  −Z     (−s, −t, −1)                   +----+----+----+----+
//!                                             | −Y |
//!                                             +----+
//! ```
//!
//! Adjacent edges in the unfolding meet on the cube (e.g. the right column of +Z is the left
//! column of +X). The sky's zenith is the centre of +Z; the horizon (z = 0) runs through the
//! middle column of ±X and the middle row of ±Y. Cube crosses and face files read from disk are
//! authored Y-up; see `crate::sky::load` for how they map onto these world-axis faces.
//!
//! # Solid angles
//!
//! A texel spanning `[s0, s1] × [t0, t1]` on the face plane at distance 1 covers the exact solid
//! angle `F(s1,t1) − F(s0,t1) − F(s1,t0) + F(s0,t0)` with `F(s, t) = atan2(s·t, √(s² + t² + 1))`
//! (the integral of `dA / (1 + s² + t²)^{3/2}`); the six faces sum to 4π.

use crate::model::FloatImage;
use rayon::prelude::*;

/// One face of a cube map; the discriminant is its index in the face order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Face {
    PosX = 0,
    NegX = 1,
    PosY = 2,
    NegY = 3,
    PosZ = 4,
    NegZ = 5,
}

impl Face {
    /// All faces in storage order.
    pub const ALL: [Face; 6] = [
        Face::PosX,
        Face::NegX,
        Face::PosY,
        Face::NegY,
        Face::PosZ,
        Face::NegZ,
    ];

    /// Short name (`+X` ...).
    pub fn name(self) -> &'static str {
        ["+X", "-X", "+Y", "-Y", "+Z", "-Z"][self as usize]
    }

    /// The (unnormalized) direction through face coordinates (s, t) ∈ [−1, 1]².
    pub fn direction(self, s: f64, t: f64) -> [f64; 3] {
        match self {
            Face::PosX => [1.0, -t, -s],
            Face::NegX => [-1.0, -t, s],
            Face::PosY => [s, 1.0, t],
            Face::NegY => [s, -1.0, -t],
            Face::PosZ => [s, -t, 1.0],
            Face::NegZ => [-s, -t, -1.0],
        }
    }
}

/// The face a direction falls on and its face coordinates (s, t) ∈ [−1, 1]².
///
/// Ties between axes go to the first of x, y, z (so every direction has exactly one face).
pub fn face_coords(d: [f64; 3]) -> (Face, f64, f64) {
    let [x, y, z] = d;
    let (ax, ay, az) = (x.abs(), y.abs(), z.abs());
    if ax >= ay && ax >= az {
        if x >= 0.0 {
            (Face::PosX, -z / ax, -y / ax)
        } else {
            (Face::NegX, z / ax, -y / ax)
        }
    } else if ay >= az {
        if y >= 0.0 {
            (Face::PosY, x / ay, z / ay)
        } else {
            (Face::NegY, x / ay, -z / ay)
        }
    } else if z >= 0.0 {
        (Face::PosZ, x / az, -y / az)
    } else {
        (Face::NegZ, -x / az, -y / az)
    }
}

/// dω / (ds dt) at face coordinates (s, t): 1 / (1 + s² + t²)^{3/2} (the weight of a sample when
/// a texel is averaged over its solid angle).
pub fn solid_angle_density(s: f64, t: f64) -> f64 {
    let r2 = 1.0 + s * s + t * t;
    1.0 / (r2 * r2.sqrt())
}

/// `F(s, t)`: the solid angle of the face rectangle [0, s] × [0, t] (signed).
fn area_element(s: f64, t: f64) -> f64 {
    (s * t).atan2((s * s + t * t + 1.0).sqrt())
}

/// Exact solid angle of texel (col, row) of a face of `size × size` texels (same on every face).
pub fn texel_solid_angle(size: u32, col: u32, row: u32) -> f64 {
    let n = size as f64;
    let s0 = 2.0 * col as f64 / n - 1.0;
    let s1 = 2.0 * (col + 1) as f64 / n - 1.0;
    let t0 = 2.0 * row as f64 / n - 1.0;
    let t1 = 2.0 * (row + 1) as f64 / n - 1.0;
    area_element(s1, t1) - area_element(s0, t1) - area_element(s1, t0) + area_element(s0, t0)
}

/// The solid angles of one face's texels, row-major (every face has the same table).
///
/// Each texel is [`texel_solid_angle`]'s difference of `F` at its four corners, with `F`
/// evaluated once per corner ((n + 1)² instead of 4n² `atan2`s): the same numbers.
pub fn solid_angle_table(size: u32) -> Vec<f64> {
    let n = size as f64;
    let m = size as usize + 1;
    let coord = |i: usize| 2.0 * i as f64 / n - 1.0;
    let f: Vec<f64> = (0..m * m)
        .into_par_iter()
        .with_min_len(4096)
        .map(|i| area_element(coord(i % m), coord(i / m)))
        .collect();
    (0..size as usize)
        .flat_map(|row| {
            let f = &f;
            (0..size as usize).map(move |col| {
                let at = |c: usize, r: usize| f[r * m + c];
                at(col + 1, row + 1) - at(col, row + 1) - at(col + 1, row) + at(col, row)
            })
        })
        .collect()
}

/// Normalizes a vector.
pub fn normalize(d: [f64; 3]) -> [f64; 3] {
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    [d[0] / l, d[1] / l, d[2] / l]
}

/// A float RGB cube map (linear radiance), faces in [`Face::ALL`] order.
#[derive(Debug, Clone, PartialEq)]
pub struct CubeMap {
    /// Texels per face edge.
    pub size: u32,
    /// `6 · size²` texels: face-major, then row-major.
    pub texels: Vec<[f32; 3]>,
}

impl CubeMap {
    /// A cube map filled with one value.
    pub fn filled(size: u32, value: [f32; 3]) -> Self {
        CubeMap {
            size,
            texels: vec![value; 6 * (size as usize).pow(2)],
        }
    }

    /// A cube map whose texel centres take `f(direction)` (unit direction).
    pub fn from_fn(size: u32, f: impl Fn([f64; 3]) -> [f32; 3] + Sync) -> Self {
        let n = size as usize;
        let texels = (0..6 * n)
            .into_par_iter()
            .flat_map_iter(|fr| {
                let (face, row) = (Face::ALL[fr / n], (fr % n) as u32);
                let f = &f;
                (0..size).map(move |col| f(texel_direction(size, face, col, row)))
            })
            .collect();
        CubeMap { size, texels }
    }

    /// Index of texel (face, col, row).
    pub fn index(&self, face: Face, col: u32, row: u32) -> usize {
        let n = self.size as usize;
        (face as usize * n + row as usize) * n + col as usize
    }

    /// The texels of one face.
    pub fn face(&self, face: Face) -> &[[f32; 3]] {
        let n2 = (self.size as usize).pow(2);
        &self.texels[face as usize * n2..(face as usize + 1) * n2]
    }

    /// Bilinear lookup in direction `d` (need not be normalized). Across face edges the
    /// neighbouring texel is found through its direction, so filtering is seamless.
    pub fn sample(&self, d: [f64; 3]) -> [f32; 3] {
        let (face, s, t) = face_coords(d);
        let n = self.size as f64;
        let x = (s + 1.0) * 0.5 * n - 0.5;
        let y = (t + 1.0) * 0.5 * n - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let mut acc = [0.0f64; 3];
        for (dx, dy, w) in [
            (0.0, 0.0, (1.0 - fx) * (1.0 - fy)),
            (1.0, 0.0, fx * (1.0 - fy)),
            (0.0, 1.0, (1.0 - fx) * fy),
            (1.0, 1.0, fx * fy),
        ] {
            if w == 0.0 {
                continue;
            }
            let v = self.texel_at(face, x0 + dx, y0 + dy);
            for k in 0..3 {
                acc[k] += w * v[k] as f64;
            }
        }
        [acc[0] as f32, acc[1] as f32, acc[2] as f32]
    }

    /// The texel at (possibly out-of-face) texel coordinates: outside the face, the texel of the
    /// face the texel centre's direction falls on.
    fn texel_at(&self, face: Face, x: f64, y: f64) -> [f32; 3] {
        let n = self.size as f64;
        let (face, col, row) = if x >= 0.0 && y >= 0.0 && x < n && y < n {
            (face, x as u32, y as u32)
        } else {
            let s = (x + 0.5) / n * 2.0 - 1.0;
            let t = (y + 0.5) / n * 2.0 - 1.0;
            // Clamp the overshoot so a corner texel maps onto one of its two neighbours.
            let (f2, s2, t2) = face_coords(face.direction(s, t));
            let col = (((s2 + 1.0) * 0.5 * n).floor()).clamp(0.0, n - 1.0) as u32;
            let row = (((t2 + 1.0) * 0.5 * n).floor()).clamp(0.0, n - 1.0) as u32;
            (f2, col, row)
        };
        self.texels[self.index(face, col, row)]
    }
}

/// Unit direction through the centre of texel (col, row) of `face`.
pub fn texel_direction(size: u32, face: Face, col: u32, row: u32) -> [f64; 3] {
    let n = size as f64;
    let s = 2.0 * (col as f64 + 0.5) / n - 1.0;
    let t = 2.0 * (row as f64 + 0.5) / n - 1.0;
    normalize(face.direction(s, t))
}

/// The unit directions of every texel centre in storage order (face by face, row by row):
/// [`texel_direction`] of each index without dividing the index apart.
pub fn texel_directions(size: u32) -> impl Iterator<Item = [f64; 3]> {
    Face::ALL.into_iter().flat_map(move |face| {
        (0..size)
            .flat_map(move |row| (0..size).map(move |col| texel_direction(size, face, col, row)))
    })
}

/// Lat-long pixel coordinates (continuous, pixel centres at +0.5) of a unit direction
/// (docs/CONVENTIONS.md: u = φ/2π, v = θ/π, row 0 at the zenith).
pub fn latlong_coords(d: [f64; 3], width: u32, height: u32) -> (f64, f64) {
    let theta = d[2].clamp(-1.0, 1.0).acos();
    let mut phi = d[1].atan2(d[0]);
    if phi < 0.0 {
        phi += std::f64::consts::TAU;
    }
    (
        phi / std::f64::consts::TAU * width as f64,
        theta / std::f64::consts::PI * height as f64,
    )
}

/// `atan2(y, x)` within 1.2·10⁻⁸ rad (about 4·10⁻⁶ of a pixel of a 2048-wide lat-long): the
/// octant is reduced to a ratio a ∈ [0, 1] and atan(a) = a·P(a²), P of degree 8 fitted by least
/// squares at Chebyshev nodes (the error bound is checked by
/// `tests::fast_atan2_is_within_its_bound`). For the millions of lookups of cube resampling,
/// where libm's `atan2` and `acos` were a fifth of the sky stage.
pub fn fast_atan2(y: f64, x: f64) -> f64 {
    const P: [f64; 9] = [
        9.999_999_842_426_349e-1,
        -3.333_306_678_069_143e-1,
        1.999_248_357_849_903e-1,
        -1.420_257_051_168e-1,
        1.063_675_409_803_417_4e-1,
        -7.495_445_443_115_649e-2,
        4.258_760_746_273_718e-2,
        -1.600_503_050_182_296e-2,
        2.834_064_298_554_246e-3,
    ];
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ax >= ay { (ay, ax) } else { (ax, ay) };
    if hi == 0.0 {
        return 0.0;
    }
    let a = lo / hi;
    let a2 = a * a;
    let mut p = P[8];
    for c in P[..8].iter().rev() {
        // (Not mul_add: without the `fma` target feature that is a call into a software fma.)
        p = p * a2 + c;
    }
    let mut r = a * p;
    if ay > ax {
        r = std::f64::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = std::f64::consts::PI - r;
    }
    if y < 0.0 { -r } else { r }
}

/// [`latlong_coords`] of a direction that need not be normalized, through [`fast_atan2`]
/// (θ = atan2(√(x² + y²), z) instead of acos z).
pub fn latlong_coords_fast(d: [f64; 3], width: u32, height: u32) -> (f64, f64) {
    let mut phi = fast_atan2(d[1], d[0]);
    if phi < 0.0 {
        phi += std::f64::consts::TAU;
    }
    let theta = fast_atan2((d[0] * d[0] + d[1] * d[1]).sqrt(), d[2]);
    (
        phi * (width as f64 / std::f64::consts::TAU),
        theta * (height as f64 / std::f64::consts::PI),
    )
}

/// Unit direction of lat-long pixel coordinates (x, y) (continuous; centres at +0.5).
pub fn latlong_direction(x: f64, y: f64, width: u32, height: u32) -> [f64; 3] {
    let phi = x / width as f64 * std::f64::consts::TAU;
    let theta = y / height as f64 * std::f64::consts::PI;
    [
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    ]
}

/// Exact solid angle of lat-long row `row`: Δφ · (cos θ0 − cos θ1), the same for every column.
pub fn latlong_row_solid_angle(row: u32, width: u32, height: u32) -> f64 {
    let h = height as f64;
    let t0 = row as f64 / h * std::f64::consts::PI;
    let t1 = (row + 1) as f64 / h * std::f64::consts::PI;
    std::f64::consts::TAU / width as f64 * (t0.cos() - t1.cos())
}

/// A lat-long image as [`sample_latlong`] reads it: its size and any pixel (row-major, row 0 at
/// the top) as linear float RGB. A [`FloatImage`], or a Radiance image kept as RGBE quadruples
/// (`ingest::rgbe::RgbeImage`, decoded pixel by pixel to the same bits).
pub trait LatLongPixels: Sync {
    /// (width, height) in pixels.
    fn size(&self) -> (u32, u32);
    fn pixel(&self, i: usize) -> [f32; 3];
    /// Whether every pixel of `row` is provably below luminance `below` (finite, no negative
    /// component): false when unsure.
    fn row_below(&self, row: u32, below: f32) -> bool {
        let w = self.size().0 as usize;
        (0..w).all(|c| {
            let p = self.pixel(row as usize * w + c);
            p.iter().all(|&v| v >= 0.0) && crate::color::luminance(p) < below
        })
    }
}

impl LatLongPixels for FloatImage {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    #[inline]
    fn pixel(&self, i: usize) -> [f32; 3] {
        self.pixels[i]
    }
}

/// Bilinear lookup in a lat-long image at continuous pixel coordinates: wraps in φ, clamps in θ.
/// (Inlined into the resampling's sample loop, where it is most of the sky stage's time.)
#[inline(always)]
pub fn sample_latlong<I: LatLongPixels + ?Sized>(img: &I, x: f64, y: f64) -> [f32; 3] {
    let (w, h) = img.size();
    let (w, h) = (w as i64, h as i64);
    let (xf, yf) = (x - 0.5, (y - 0.5).clamp(0.0, (h - 1) as f64));
    // floor by truncation (`f64::floor` is a libm call on the baseline x86-64 target).
    let floor = |v: f64| {
        let i = v as i64;
        if (i as f64) > v { i - 1 } else { i }
    };
    let (x0, y0) = (floor(xf), floor(yf));
    let (fx, fy) = ((xf - x0 as f64) as f32, (yf - y0 as f64) as f32);
    // Columns wrap (x0 is −1 … w − 1 for coordinates in [0, w)); rows clamp.
    let c0 = if (0..w).contains(&x0) {
        x0
    } else {
        x0.rem_euclid(w)
    };
    let c1 = if c0 + 1 == w { 0 } else { c0 + 1 };
    let r1 = (y0 + 1).min(h - 1);
    let px = |row: i64, col: i64| img.pixel((row * w + col) as usize);
    let (a, b, c, d) = (px(y0, c0), px(y0, c1), px(r1, c0), px(r1, c1));
    let (w00, w10, w01, w11) = (
        (1.0 - fx) * (1.0 - fy),
        fx * (1.0 - fy),
        (1.0 - fx) * fy,
        fx * fy,
    );
    let mix = |k: usize| w00 * a[k] + w10 * b[k] + w01 * c[k] + w11 * d[k];
    [mix(0), mix(1), mix(2)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solid_angles_sum_to_4pi() {
        for size in [1, 2, 7, 64] {
            let total: f64 = solid_angle_table(size).iter().sum::<f64>() * 6.0;
            assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-12, "{size}");
        }
    }

    #[test]
    fn solid_angle_matches_brute_force_integration() {
        // Independent oracle: integrate 1/(1+s²+t²)^{3/2} over the texel with a fine midpoint rule.
        let size = 5;
        for (col, row) in [(0, 0), (2, 2), (4, 1)] {
            let n = 400;
            let s0 = 2.0 * col as f64 / size as f64 - 1.0;
            let t0 = 2.0 * row as f64 / size as f64 - 1.0;
            let h = 2.0 / size as f64 / n as f64;
            let mut sum = 0.0;
            for i in 0..n {
                for j in 0..n {
                    let s = s0 + (i as f64 + 0.5) * h;
                    let t = t0 + (j as f64 + 0.5) * h;
                    sum += h * h / (1.0 + s * s + t * t).powf(1.5);
                }
            }
            let exact = texel_solid_angle(size, col, row);
            assert!((sum - exact).abs() < 1e-6 * exact, "{sum} vs {exact}");
        }
    }

    #[test]
    fn the_solid_angle_table_is_texel_solid_angle_exactly() {
        for size in [1, 3, 16, 255] {
            let table = solid_angle_table(size);
            for row in 0..size {
                for col in 0..size {
                    let i = (row * size + col) as usize;
                    assert_eq!(
                        table[i],
                        texel_solid_angle(size, col, row),
                        "{size} {col} {row}"
                    );
                }
            }
        }
    }

    #[test]
    fn fast_atan2_is_within_its_bound() {
        // Oracle: libm's atan2, on a dense ring of directions (every octant, both axes, the
        // diagonals) and at scales from 1e-300 to 1e300 (the ratio is what matters).
        let mut worst = 0.0f64;
        for i in 0..=100_000 {
            let a = i as f64 / 100_000.0 * std::f64::consts::TAU - std::f64::consts::PI;
            for scale in [1e-300, 1e-3, 1.0, 7.5, 1e300] {
                let (y, x) = (a.sin() * scale, a.cos() * scale);
                worst = worst.max((fast_atan2(y, x) - y.atan2(x)).abs());
            }
        }
        for (y, x) in [
            (0.0, 1.0),
            (1.0, 0.0),
            (0.0, -1.0),
            (-1.0, 0.0),
            (1.0, 1.0),
            (-2.0, -2.0),
        ] {
            worst = worst.max((fast_atan2(y, x) - f64::atan2(y, x)).abs());
        }
        assert!(worst < 1.3e-8, "worst {worst}");
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
    }

    #[test]
    fn fast_latlong_coords_match_the_exact_ones_for_unnormalized_directions() {
        let (w, h) = (2048, 1024);
        let mut worst = 0.0f64;
        for i in 0..20_000u32 {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / 20_000.0;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f64 * 2.399_963_229_728_653;
            let d = [r * phi.cos(), r * phi.sin(), z];
            let (x0, y0) = latlong_coords(d, w, h);
            let (x1, y1) = latlong_coords_fast(d.map(|c| c * 3.7), w, h);
            // x wraps at the seam: compare on the circle.
            let dx = (x0 - x1).abs();
            worst = worst.max(dx.min(w as f64 - dx)).max((y0 - y1).abs());
        }
        assert!(worst < 1e-5, "worst {worst} px");
    }

    #[test]
    fn texel_directions_are_in_storage_order() {
        let size = 5;
        let all: Vec<_> = texel_directions(size).collect();
        assert_eq!(all.len(), 6 * 25);
        for face in Face::ALL {
            for row in 0..size {
                for col in 0..size {
                    let cube = CubeMap::filled(size, [0.0; 3]);
                    let i = cube.index(face, col, row);
                    assert_eq!(all[i], texel_direction(size, face, col, row));
                }
            }
        }
    }

    #[test]
    fn face_coords_inverts_direction() {
        for face in Face::ALL {
            for (s, t) in [(0.3, -0.7), (-0.99, 0.5), (0.0, 0.0)] {
                let (f, s2, t2) = face_coords(face.direction(s, t));
                assert_eq!(f, face);
                assert!((s - s2).abs() < 1e-12 && (t - t2).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn faces_follow_the_gpu_table() {
        // Spot checks against OpenGL table 8.19: the major axis and the sc/tc axes.
        assert_eq!(face_coords([1.0, 0.0, -0.5]).0, Face::PosX);
        assert_eq!(face_coords([1.0, 0.0, -0.5]).1, 0.5); // sc = −rz
        assert_eq!(face_coords([0.5, 0.2, 1.0]).1, 0.5); // +Z: sc = rx
        assert_eq!(face_coords([0.5, 0.2, 1.0]).2, -0.2); // +Z: tc = −ry
        assert_eq!(face_coords([0.0, 1.0, 0.3]).2, 0.3); // +Y: tc = rz
    }
}
