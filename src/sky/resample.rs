//! The work of [`super::source_to_cube`]: tiles of cube texels, each the solid-angle-weighted mean
//! of `k × k` source samples, refined where the sun is. For a lat-long source the trigonometry is
//! shared between faces (it was four fifths of the stage).
//!
//! Sample points sit on one grid per face: subsample `i` of `N = n·k` along a face edge is at
//! `u_i = 2(i + ½)/N − 1` (texel `col`, subsample `a`: `i = col·k + a`), texel corners at
//! `c_j = 2j/n − 1`. On that grid the lat-long angles of the six faces come from a few tables:
//!
//! ```text
//! face  direction       φ                θ
//! +X    ( 1, −t, −s)    −atan t          π − S(t, s)      S(q, p) = atan2(√(1 + q²), p)
//! −X    (−1, −t,  s)    π + atan t       S(t, s)
//! +Y    ( s,  1,  t)    π/2 − atan s     S(s, t)
//! −Y    ( s, −1, −t)    −π/2 + atan s    π − S(s, t)
//! +Z    ( s, −t,  1)    Φ(s, t)          Z(s, t)          Φ = atan2(−t, s), Z = atan2(√(s² + t²), 1)
//! −Z    (−s, −t, −1)    π − Φ(s, t)      π − Z(s, t)
//! ```
//!
//! So one unit of work is a tile position (row block R, column block C): it computes S and the
//! weights over (t ∈ R, s ∈ C) once and uses them for ±X at (R, C) and, transposed, for ±Y at
//! (C, R); Φ and Z serve ±Z at (R, C). That is a third of the angle evaluations of a sample-by-
//! sample resampling, and each tile reads a compact patch of the source.

use super::cube::{self, Face, LatLongPixels};
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Texels per edge of a tile.
pub(super) const TILE: usize = 16;

/// How a tile reads its source.
pub(super) trait TileSource: Sync {
    /// The sample at subsample (i, j) of `face` (i along s, j along t) and its weight (the
    /// solid-angle Jacobian 1/(1 + s² + t²)^{3/2}).
    fn sample(&self, face: Face, i: usize, j: usize) -> ([f32; 3], f64);
    /// The luminance at corner (i, j) of `face`.
    fn corner(&self, face: Face, i: usize, j: usize) -> f32;
    /// Whether a texel of this unit's tile on `face` can be refined (false only where the
    /// source proves every sample and corner there below [`TileParams::hot`]).
    fn may_refine(&self, _face: Face) -> bool {
        true
    }
}

/// What a tile needs besides its source.
#[derive(Debug, Clone, Copy)]
pub(super) struct TileParams {
    /// Texels per face edge.
    pub n: usize,
    /// Subsamples per texel edge.
    pub k: usize,
    /// Subsamples per texel edge where the texel is refined (≥ k; equal: never refined).
    pub k_fine: usize,
    /// A texel is refined where its brightest sample or corner is above this …
    pub hot: f32,
    /// … and more than this factor above its darkest.
    pub contrast: f32,
}

/// One tile of `face` (rows `r0..r0 + rows`, columns `c0..c0 + cols`) into `out` (its rows, in
/// place in the cube); `fine(face, col, row, k)` is the generic k × k mean used for refined
/// texels.
pub(super) fn tile(
    p: &TileParams,
    src: &impl TileSource,
    fine: &(impl Fn(Face, usize, usize, usize) -> [f32; 3] + ?Sized),
    face: Face,
    (r0, c0): (usize, usize),
    out: &mut [&mut [[f32; 3]]],
) {
    let (rows, cols) = (out.len(), out.first().map_or(0, |r| r.len()));
    let refine = p.k_fine > p.k && src.may_refine(face);
    let m = cols + 1;
    let corners: Vec<f32> = if refine {
        (0..(rows + 1) * m)
            .map(|x| src.corner(face, c0 + x % m, r0 + x / m))
            .collect()
    } else {
        Vec::new()
    };
    let k = p.k;
    // The walk follows the source's rows: on ±X a face column (fixed s, varying t) runs along a
    // lat-long row, a face row down a lat-long column; elsewhere rows run along rows (±Y) or it
    // does not matter (±Z).
    let along_columns = matches!(face, Face::PosX | Face::NegX);
    for outer in 0..if along_columns { cols } else { rows } {
        for inner in 0..if along_columns { rows } else { cols } {
            let (row, col) = if along_columns {
                (inner, outer)
            } else {
                (outer, inner)
            };
            let mut acc = [0.0f64; 3];
            let (mut wsum, mut lo, mut hi) = (0.0, f32::INFINITY, f32::NEG_INFINITY);
            for x in 0..k {
                for y in 0..k {
                    let (a, b) = if along_columns { (x, y) } else { (y, x) };
                    let (v, w) = src.sample(face, (c0 + col) * k + a, (r0 + row) * k + b);
                    if refine {
                        let l = crate::color::luminance(v);
                        (lo, hi) = (lo.min(l), hi.max(l));
                    }
                    for c in 0..3 {
                        acc[c] += w * v[c] as f64;
                    }
                    wsum += w;
                }
            }
            let mut v = acc.map(|c| (c / wsum) as f32);
            if refine {
                for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let l = corners[(row + b) * m + col + a];
                    (lo, hi) = (lo.min(l), hi.max(l));
                }
                if hi > p.hot && hi > p.contrast * lo.max(0.0) {
                    v = fine(face, c0 + col, r0 + row, p.k_fine);
                }
            }
            out[row][col] = v;
        }
    }
}

/// Every work unit's tiles, in parallel, written in place into `texels` (the cube's, face-major):
/// `source(block)` is the unit's source (its tables).
pub(super) fn units<S: TileSource>(
    texels: &mut [[f32; 3]],
    p: &TileParams,
    source: impl Fn((usize, usize)) -> S + Sync,
    fine: &(impl Fn(Face, usize, usize, usize) -> [f32; 3] + Sync + ?Sized),
) {
    use rayon::prelude::*;
    let n = p.n;
    unit_rows(texels, n)
        .into_par_iter()
        .enumerate()
        .for_each(|(u, mut rows)| {
            let per_edge = n.div_ceil(TILE);
            let block = (u / per_edge, u % per_edge);
            let src = source(block);
            let mut at = 0;
            for (face, r0, c0) in unit_tiles(n, block) {
                let (nr, _) = tile_extent(n, r0, c0);
                tile(p, &src, fine, face, (r0, c0), &mut rows[at..at + nr]);
                at += nr;
            }
        });
}

/// The cube's texels cut into the row pieces of each unit's tiles: for unit `u`, the rows of
/// its six tiles in [`unit_tiles`] order (the faces' storage order), each tile's from the top.
/// The pieces are disjoint, so the units write them in parallel without a copy.
fn unit_rows(texels: &mut [[f32; 3]], n: usize) -> Vec<Vec<&mut [[f32; 3]]>> {
    let per_edge = n.div_ceil(TILE);
    let mut units: Vec<Vec<&mut [[f32; 3]]>> = (0..per_edge * per_edge)
        .map(|_| Vec::with_capacity(6 * TILE))
        .collect();
    for (face_row, line) in texels.chunks_mut(n).enumerate() {
        let (face, row) = (Face::ALL[face_row / n], face_row % n);
        for (col_block, piece) in line.chunks_mut(TILE).enumerate() {
            // ±Y's tile at (row block, column block) belongs to the transposed unit.
            let u = match face {
                Face::PosY | Face::NegY => col_block * per_edge + row / TILE,
                _ => (row / TILE) * per_edge + col_block,
            };
            units[u].push(piece);
        }
    }
    units
}

/// [`units`] of a lat-long source into `texels`, each unit with its tables ([`LatLong::unit`]);
/// `skip_cold`: use [`ColdRows`].
pub(super) fn latlong_units<I: LatLongPixels + ?Sized>(
    p: &TileParams,
    img: &I,
    grids: &LatLongGrids,
    (rotate_rad, skip_cold): (f64, bool),
    fine: &(impl Fn(Face, usize, usize, usize) -> [f32; 3] + Sync + ?Sized),
    texels: &mut [[f32; 3]],
) {
    let cold = if p.k_fine > p.k && skip_cold {
        ColdRows::of(img, p.hot)
    } else {
        ColdRows::none()
    };
    let refine = (p.k_fine > p.k).then_some(&cold);
    let source = |block| LatLong::unit(img, grids, (p.n, p.k), block, refine, rotate_rad);
    units(texels, p, source, fine)
}

/// The lat-long rows whose pixels are all provably darker than the refinement threshold: a
/// tile that reads only such rows has no sample or corner above it (a bilinear sample's
/// luminance is a convex combination of its four pixels'), so it is not refined and its corners
/// need not be read. Most tiles of a sunny sky are such (the sun's rows are a few).
pub(super) struct ColdRows {
    cold: Vec<bool>,
}

impl ColdRows {
    /// The rows of `img` below `hot` (with a margin of 10⁻³ for rounding: a sample's luminance
    /// exceeds the largest of its pixels' by a few ulps at most).
    pub(super) fn of<I: LatLongPixels + ?Sized>(img: &I, hot: f32) -> ColdRows {
        use rayon::prelude::*;
        if !(hot.is_finite() && hot > 0.0) {
            return ColdRows::none();
        }
        let below = hot * (1.0 - 1e-3);
        let cold = (0..img.size().1)
            .into_par_iter()
            .map(|row| img.row_below(row, below))
            .collect();
        ColdRows { cold }
    }

    /// No row known to be cold.
    pub(super) fn none() -> ColdRows {
        ColdRows { cold: Vec::new() }
    }

    /// Whether every row from `lo` to `hi` (inclusive) is cold.
    fn all(&self, lo: usize, hi: usize) -> bool {
        self.cold.get(lo..=hi).is_some_and(|r| r.iter().all(|&c| c))
    }
}

/// The six tiles of the work unit at block (row block, column block) `(br, bc)`: ±X and ±Z at
/// (br, bc), ±Y at (bc, br) (the transposed position, where [`LatLong`] shares its tables).
pub(super) fn unit_tiles(n: usize, (br, bc): (usize, usize)) -> [(Face, usize, usize); 6] {
    let (r, c) = (br * TILE, bc * TILE);
    debug_assert!(r < n && c < n);
    [
        (Face::PosX, r, c),
        (Face::NegX, r, c),
        (Face::PosY, c, r),
        (Face::NegY, c, r),
        (Face::PosZ, r, c),
        (Face::NegZ, r, c),
    ]
}

/// Rows and columns of the tile starting at (r0, c0).
pub(super) fn tile_extent(n: usize, r0: usize, c0: usize) -> (usize, usize) {
    (TILE.min(n - r0), TILE.min(n - c0))
}

/// The tables of one block of a grid: rows q ∈ `q0..q0 + nq` (t of ±X/±Z, s of ±Y), columns
/// p ∈ `p0..p0 + np`.
struct Block {
    q0: usize,
    p0: usize,
    np: usize,
    /// S(u_q, u_p) = atan2(√(1 + u_q²), u_p).
    side: Vec<f64>,
    /// Φ(u_p, u_q) = atan2(−u_q, u_p).
    top_phi: Vec<f64>,
    /// Z(u_p, u_q) = atan2(√(u_p² + u_q²), 1).
    top_theta: Vec<f64>,
    /// 1/(1 + u_p² + u_q²)^{3/2} (symmetric, so one table for both orders).
    weight: Vec<f64>,
}

impl Block {
    fn new(us: &[f64], (q0, nq): (usize, usize), (p0, np): (usize, usize)) -> Block {
        let len = nq * np;
        let (mut side, mut top_phi, mut top_theta, mut weight) = (
            Vec::with_capacity(len),
            Vec::with_capacity(len),
            Vec::with_capacity(len),
            Vec::with_capacity(len),
        );
        for &q in &us[q0..q0 + nq] {
            for &p in &us[p0..p0 + np] {
                side.push(cube::fast_atan2((1.0 + q * q).sqrt(), p));
                top_phi.push(cube::fast_atan2(-q, p));
                top_theta.push(cube::fast_atan2((p * p + q * q).sqrt(), 1.0));
                weight.push(cube::solid_angle_density(p, q));
            }
        }
        Block {
            q0,
            p0,
            np,
            side,
            top_phi,
            top_theta,
            weight,
        }
    }

    fn at(&self, q: usize, p: usize) -> usize {
        (q - self.q0) * self.np + p - self.p0
    }
}

/// Per face, whether the unit's tile there may read a row that is not cold: the colatitudes of
/// its samples span [min, max] of the block's tables (mirrored, π − θ, on +X, −Y, −Z), its
/// corners lie within half a subsample diagonal of them (at most √2/N rad on a face of N
/// subsamples, θ being 1-Lipschitz on the sphere), and a bilinear sample at y reads rows
/// ⌊y − ½⌋ and the one below.
fn hot_faces(samples: &Block, cold: &ColdRows, height: u32, big_n: usize) -> [bool; 6] {
    let range = |v: &[f64]| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                (lo.min(x), hi.max(x))
            })
    };
    let (side, top) = (range(&samples.side), range(&samples.top_theta));
    let flip = |(lo, hi): (f64, f64)| (PI - hi, PI - lo);
    let h = height as f64;
    let margin = std::f64::consts::SQRT_2 / big_n as f64;
    let rows = |(lo, hi): (f64, f64)| {
        let y = |theta: f64| ((theta * (h / PI) - 0.5).clamp(0.0, h - 1.0)).floor() as usize;
        // (One more row each side for the rounding of the tables.)
        let (a, b) = (y(lo - margin), y(hi + margin));
        (a.saturating_sub(1), (b + 2).min(height as usize - 1))
    };
    let hot = |range: (f64, f64)| {
        let (a, b) = rows(range);
        !cold.all(a, b)
    };
    // Face::ALL order: +X, −X, +Y, −Y, +Z, −Z.
    [
        hot(flip(side)),
        hot(side),
        hot(side),
        hot(flip(side)),
        hot(top),
        hot(flip(top)),
    ]
}

/// Any source, read direction by direction (`read(face, s, t)`) on the resampling grids.
#[derive(Clone, Copy)]
pub(super) struct Generic<'a, R> {
    pub read: &'a R,
    pub grids: &'a LatLongGrids,
}

impl<R: Fn(Face, f64, f64) -> [f32; 3] + Sync> TileSource for Generic<'_, R> {
    fn sample(&self, face: Face, i: usize, j: usize) -> ([f32; 3], f64) {
        let (s, t) = (self.grids.us[i], self.grids.us[j]);
        ((self.read)(face, s, t), cube::solid_angle_density(s, t))
    }

    fn corner(&self, face: Face, i: usize, j: usize) -> f32 {
        let (s, t) = (self.grids.corner_us[i], self.grids.corner_us[j]);
        crate::color::luminance((self.read)(face, s, t))
    }
}

/// A lat-long source with the tables of one work unit: subsample and corner grids.
pub(super) struct LatLong<'a, I: ?Sized> {
    img: &'a I,
    /// atan(u_i) of every subsample, and of every corner.
    atan: &'a [f64],
    atan_corner: &'a [f64],
    samples: Block,
    corners: Option<Block>,
    /// Per face ([`Face::ALL`] order): whether its tile may have refined texels.
    may_refine: [bool; 6],
    /// The sky's rotation about +Z in [0, 2π): the source is read at φ − rot.
    rot: f64,
}

/// The grids shared by every work unit: coordinates (of any source) and their arctangents (of
/// a lat-long source).
pub(super) struct LatLongGrids {
    pub us: Vec<f64>,
    pub atan: Vec<f64>,
    pub corner_us: Vec<f64>,
    pub atan_corner: Vec<f64>,
}

impl LatLongGrids {
    pub(super) fn new(n: usize, k: usize) -> LatLongGrids {
        let big = n * k;
        let us: Vec<f64> = (0..big)
            .map(|i| 2.0 * (i as f64 + 0.5) / big as f64 - 1.0)
            .collect();
        let corner_us: Vec<f64> = (0..=n).map(|j| 2.0 * j as f64 / n as f64 - 1.0).collect();
        let atan = us.iter().map(|&u| cube::fast_atan2(u, 1.0)).collect();
        let atan_corner = corner_us
            .iter()
            .map(|&u| cube::fast_atan2(u, 1.0))
            .collect();
        LatLongGrids {
            us,
            atan,
            corner_us,
            atan_corner,
        }
    }
}

impl<'a, I: LatLongPixels + ?Sized> LatLong<'a, I> {
    /// The tables of the unit at block (br, bc) of an n-texel face with k subsamples per texel
    /// (`corners`: also the corner grid's).
    pub(super) fn unit(
        img: &'a I,
        grids: &'a LatLongGrids,
        (n, k): (usize, usize),
        (br, bc): (usize, usize),
        refine: Option<&ColdRows>,
        rotate_rad: f64,
    ) -> LatLong<'a, I> {
        let (r0, c0) = (br * TILE, bc * TILE);
        let (rows, cols) = tile_extent(n, r0, c0);
        let samples = Block::new(&grids.us, (r0 * k, rows * k), (c0 * k, cols * k));
        let may_refine = match refine {
            Some(cold) => hot_faces(&samples, cold, img.size().1, n * k),
            None => [false; 6],
        };
        let corners = may_refine
            .contains(&true)
            .then(|| Block::new(&grids.corner_us, (r0, rows + 1), (c0, cols + 1)));
        LatLong {
            img,
            atan: &grids.atan,
            atan_corner: &grids.atan_corner,
            samples,
            corners,
            may_refine,
            rot: rotate_rad.rem_euclid(TAU),
        }
    }

    /// Lat-long pixel coordinates of grid point (i, j) of `face` (i along s, j along t).
    #[inline(always)]
    fn coords(&self, block: &Block, atan: &[f64], face: Face, i: usize, j: usize) -> (f64, f64) {
        let (phi, theta) = match face {
            Face::PosX => (-atan[j], PI - block.side[block.at(j, i)]),
            Face::NegX => (PI + atan[j], block.side[block.at(j, i)]),
            Face::PosY => (FRAC_PI_2 - atan[i], block.side[block.at(i, j)]),
            Face::NegY => (atan[i] - FRAC_PI_2, PI - block.side[block.at(i, j)]),
            Face::PosZ => (
                block.top_phi[block.at(j, i)],
                block.top_theta[block.at(j, i)],
            ),
            Face::NegZ => (
                PI - block.top_phi[block.at(j, i)],
                PI - block.top_theta[block.at(j, i)],
            ),
        };
        // φ − rot lies in (−3π, 2π): at most two turns bring it into [0, 2π).
        let mut phi = phi - self.rot;
        while phi < 0.0 {
            phi += TAU;
        }
        while phi >= TAU {
            phi -= TAU;
        }
        let (w, h) = self.img.size();
        let (w, h) = (w as f64, h as f64);
        (phi * (w / TAU), theta * (h / PI))
    }

    fn weight(block: &Block, face: Face, i: usize, j: usize) -> f64 {
        match face {
            Face::PosY | Face::NegY => block.weight[block.at(i, j)],
            _ => block.weight[block.at(j, i)],
        }
    }

    /// [`Self::coords`] of a subsample, for tests.
    #[cfg(test)]
    pub fn sample_coords(&self, face: Face, i: usize, j: usize) -> (f64, f64) {
        self.coords(&self.samples, self.atan, face, i, j)
    }
}

impl<I: LatLongPixels + ?Sized> TileSource for LatLong<'_, I> {
    #[inline(always)]
    fn sample(&self, face: Face, i: usize, j: usize) -> ([f32; 3], f64) {
        let (x, y) = self.coords(&self.samples, self.atan, face, i, j);
        (
            cube::sample_latlong(self.img, x, y),
            Self::weight(&self.samples, face, i, j),
        )
    }

    fn may_refine(&self, face: Face) -> bool {
        self.may_refine[face as usize]
    }

    fn corner(&self, face: Face, i: usize, j: usize) -> f32 {
        let block = self
            .corners
            .as_ref()
            .expect("corner tables exist where texels may be refined");
        let (x, y) = self.coords(block, self.atan_corner, face, i, j);
        crate::color::luminance(cube::sample_latlong(self.img, x, y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Oracle: libm's acos and atan2 of the normalized, rotated direction of the grid point.
    fn exact(face: Face, s: f64, t: f64, rotate_rad: f64, w: u32, h: u32) -> (f64, f64) {
        let d = cube::normalize(face.direction(s, t));
        let (sr, cr) = (-rotate_rad).sin_cos();
        let d = [cr * d[0] - sr * d[1], sr * d[0] + cr * d[1], d[2]];
        cube::latlong_coords(d, w, h)
    }

    #[test]
    fn the_shared_tables_give_every_faces_exact_lat_long_coordinates() {
        let img = crate::model::FloatImage {
            width: 64,
            height: 32,
            pixels: vec![[0.0; 3]; 64 * 32],
        };
        let mut worst = 0.0f64;
        for (n, k) in [(5, 1), (37, 2), (20, 3)] {
            let grids = LatLongGrids::new(n, k);
            let per_edge = n.div_ceil(TILE);
            for rot in [0.0f64, 37.0, -200.0, 359.9] {
                let rot = rot.to_radians();
                for u in 0..per_edge * per_edge {
                    let block = (u / per_edge, u % per_edge);
                    let ll =
                        LatLong::unit(&img, &grids, (n, k), block, Some(&ColdRows::none()), rot);
                    for (face, r0, c0) in unit_tiles(n, block) {
                        let (rows, cols) = tile_extent(n, r0, c0);
                        let mut check = |got: (f64, f64), want: (f64, f64)| {
                            let dx = (got.0 - want.0).abs();
                            // (At a pole, the centre of ±Z when n·k is odd, φ is arbitrary.)
                            let pole = want.1 == 0.0 || want.1 == img.height as f64;
                            let dx = if pole {
                                0.0
                            } else {
                                dx.min(img.width as f64 - dx)
                            };
                            worst = worst.max(dx).max((got.1 - want.1).abs());
                        };
                        for j in r0 * k..(r0 + rows) * k {
                            for i in c0 * k..(c0 + cols) * k {
                                let (s, t) = (grids.us[i], grids.us[j]);
                                check(ll.sample_coords(face, i, j), exact(face, s, t, rot, 64, 32));
                            }
                        }
                        let block = ll.corners.as_ref().unwrap();
                        for j in r0..=r0 + rows {
                            for i in c0..=c0 + cols {
                                let (s, t) = (grids.corner_us[i], grids.corner_us[j]);
                                let got = ll.coords(block, &grids.atan_corner, face, i, j);
                                check(got, exact(face, s, t, rot, 64, 32));
                            }
                        }
                    }
                }
            }
        }
        assert!(worst < 1e-6, "worst {worst} px");
    }
}
