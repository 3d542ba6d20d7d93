//! Terrain visibility by horizons (issue 37; Stewart 1998, "Fast horizon computation at all points
//! of a terrain with visibility and shading applications"; Timonen and Westerholm 2010,
//! "Scalable Height Field Self-Shadowing").
//!
//! **Horizons.** For a direction (a, b) of the texel lattice (a primitive integer vector, in texel
//! columns and rows with rows counted northwards), every texel lies on exactly one lattice line
//! through texel centres in that direction. Each line is swept from its far end backwards; the
//! profile along it is the drawn two-triangle surface ([`Terrain::mesh_height_at`]) at the texel
//! centres and at `m − 1` points between neighbours (`m` such that the step is at most one
//! terrain cell), beyond the line's last texel at the same step up to the terrain's edge, and
//! one a tenth of a step ahead of every texel (the slope of the triangle under it). The upper convex hull of the points already swept is kept on a stack; a new
//! point pops the hull vertices that are not above its tangent, the top is then the point of
//! the steepest slope ahead (the horizon), and the point is pushed (Timonen and Westerholm's
//! linear-time sweep: every point is pushed and popped once). Exact for the profile: the
//! horizon of a texel centre in a lattice direction is the largest elevation of any profile
//! point ahead of it, up to the terrain's edge (nothing beyond it).
//!
//! `K` lattice directions ([`lattice_vectors`], all primitive vectors with max(|a|, |b|) ≤ D:
//! 8, 16, 32, 48 directions for D = 1, 2, 3, 4) split the azimuth into sectors (boundaries
//! halfway between neighbouring directions); in a sector the horizon is taken as constant, its
//! direction's. Stored as sin(elevation), rounded up to 1/32767.
//!
//! A band of rows is swept by walking every line that reaches it from its far end. A map
//! baked in several bands walks each southward line once ([`BandedSweeps`]): it keeps its
//! position and hull from one band to the next.
//!
//! **Sky above the horizons.** The sky's radiance is SH order 4, so `∫ L(d) (n·d) dω` over
//! `{d in sector k, sin(elevation) > s}` is `n · V_k(s)` with `V_k(s) = ∫ L(d) d dω` a function
//! of s alone: [`SkyTables`] holds it per sector on 2,049 values of s (dω = ds dφ; 16
//! Gauss–Legendre nodes in φ, two Gauss points per interval of s), interpolated linearly.
//! The horizon of a sector is raised to the texel's tangent plane where that is higher
//! ([`SkyTables::effective`]), so the region lies in the hemisphere n·d ≥ 0.
//!
//! **Sun.** One more sweep in the lattice direction closest to the sun's azimuth (|a|, |b| ≤ 16:
//! within ≈ 0.2° for most azimuths) gives each texel's horizon towards the sun; the visible
//! fraction of the sun's disc (angular radius [`super::SUN_RADIUS`]) is the area of the disc
//! above that horizon ([`disc_fraction`]).

use crate::model::Terrain;
use crate::sh::ShRadiance;
use rayon::prelude::*;
use std::ops::Range;

/// Scale of the stored sin(elevation).
const Q: f32 = 32767.0;

/// Intervals of sin(elevation) in a [`SkyTables`] table.
const TABLE: usize = 2048;

/// Where the profile's point just ahead of each texel lies, in profile steps.
pub const NEAR: f32 = 0.1;

/// Largest |a|, |b| of the lattice vector chosen for the sun.
const SUN_LATTICE: i32 = 16;

fn gcd(a: i32, b: i32) -> i32 {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// Most horizon directions ([`lattice_vectors`] of 4).
pub const MAX_DIRECTIONS: usize = 48;

/// The primitive lattice vectors (a, b) with max(|a|, |b|) ≤ `d` (clamped to 1..=4), sorted by
/// their angle in the lattice (column, row-northwards) plane.
pub fn lattice_vectors(d: u32) -> Vec<(i32, i32)> {
    let d = d.clamp(1, 4) as i32;
    let mut v = Vec::new();
    for a in -d..=d {
        for b in -d..=d {
            if (a, b) != (0, 0) && gcd(a.abs(), b.abs()) == 1 {
                v.push((a, b));
            }
        }
    }
    v.sort_by(|p, q| {
        (p.1 as f64)
            .atan2(p.0 as f64)
            .total_cmp(&(q.1 as f64).atan2(q.0 as f64))
    });
    v
}

/// The texels of a terrain light map: texel (i, j) at x = x₀ + (i + ½)/W · extent_x,
/// y = y₀ + (1 − (j + ½)/H) · extent_y (row 0 north), as the light map places them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelGrid {
    pub width: u32,
    pub height: u32,
    pub origin: [f32; 2],
    pub extent: [f32; 2],
    /// The terrain's cell size (x, y).
    pub cell: [f32; 2],
}

impl TexelGrid {
    pub fn new(t: &Terrain, width: u32, height: u32) -> Self {
        TexelGrid {
            width,
            height,
            origin: t.origin,
            extent: t.extent,
            cell: [
                t.extent[0] / (t.width - 1).max(1) as f32,
                t.extent[1] / (t.height - 1).max(1) as f32,
            ],
        }
    }

    /// World (x, y) of texel (i, j).
    #[inline]
    pub fn xy(&self, i: u32, j: u32) -> (f32, f32) {
        let x = self.origin[0] + (i as f32 + 0.5) / self.width as f32 * self.extent[0];
        let y = self.origin[1] + (1.0 - (j as f32 + 0.5) / self.height as f32) * self.extent[1];
        (x, y)
    }

    /// Texel size (x, y).
    pub(crate) fn step(&self) -> [f32; 2] {
        [
            self.extent[0] / self.width as f32,
            self.extent[1] / self.height as f32,
        ]
    }

    /// World azimuth (radians, from +x towards +y) of lattice vector (a, b).
    pub fn azimuth(&self, a: i32, b: i32) -> f64 {
        let s = self.step();
        (b as f64 * s[1] as f64).atan2(a as f64 * s[0] as f64)
    }
}

/// The geometry of one lattice direction's sweep over a texel grid: the lattice lines, their
/// profile step and how a line is walked (see the file comment).
struct LineWalk<'a> {
    t: &'a Terrain,
    g: &'a TexelGrid,
    a: i64,
    b: i64,
    w: i64,
    h: i64,
    dx: f32,
    dy: f32,
    len: f64,
    m: i64,
}

/// Where a line's walk stands before a texel: the texel (i, jj) with jj counted northwards and
/// its index k along the line (0: the walk has not started). The walk's other state is the
/// upper hull of the profile points swept so far; every u and z the walk adds to it is an f32
/// (u an f32 difference or an integer below 2²⁴), so a hull kept as f32 pairs resumes to the
/// same slopes ([`BandedSweeps`]).
#[derive(Debug, Clone, Copy)]
struct LinePos {
    i: i64,
    jj: i64,
    k: i64,
}

impl<'a> LineWalk<'a> {
    fn new(t: &'a Terrain, g: &'a TexelGrid, (a, b): (i32, i32)) -> Self {
        let step = g.step();
        let dx = a as f32 * step[0];
        let dy = b as f32 * step[1];
        let m = ((dx.abs() / g.cell[0]).max(dy.abs() / g.cell[1]) * (1.0 - 1e-4))
            .ceil()
            .max(1.0) as i64;
        LineWalk {
            t,
            g,
            a: a as i64,
            b: b as i64,
            w: g.width as i64,
            h: g.height as i64,
            dx,
            dy,
            len: (dx as f64).hypot(dy as f64),
            m,
        }
    }

    #[inline]
    fn inside(&self, i: i64, jj: i64) -> bool {
        (0..self.w).contains(&i) && (0..self.h).contains(&jj)
    }

    /// Line ends, texels whose next texel ahead lies outside the grid, in a fixed order.
    fn ends(&self, mut f: impl FnMut(i64, i64)) {
        for jj in 0..self.h {
            if !self.inside(0, jj + self.b) {
                for i in 0..self.w {
                    f(i, jj);
                }
            } else {
                let cols = if self.a > 0 {
                    (self.w - self.a).max(0)..self.w
                } else {
                    0..(-self.a).min(self.w)
                };
                for i in cols {
                    f(i, jj);
                }
            }
        }
    }

    /// Adds a profile point (u along the line in lattice steps, height z) to the upper hull;
    /// returns the horizon slope it sees.
    #[inline]
    fn add(&self, hull: &mut Vec<(f64, f64)>, u: f64, z: f64) -> f32 {
        while hull.len() >= 2 {
            let (u1, z1) = hull[hull.len() - 1];
            let (u2, z2) = hull[hull.len() - 2];
            if (z2 - z) * (u1 - u) >= (z1 - z) * (u2 - u) {
                hull.pop();
            } else {
                break;
            }
        }
        let slope = hull.last().map_or(f32::NEG_INFINITY, |&(u1, z1)| {
            ((z1 - z) / ((u1 - u) * self.len)) as f32
        });
        hull.push((u, z));
        slope
    }

    /// Walks a line from `pos` (with `hull`, empty at k = 0) backwards while the texel is inside
    /// the grid and `go(pos, hull)` says so, calling `visit(i, jj, slope)` after each texel;
    /// returns where it stopped.
    fn walk(
        &self,
        hull: &mut Vec<(f64, f64)>,
        mut pos: LinePos,
        mut go: impl FnMut(LinePos, &[(f64, f64)]) -> bool,
        mut visit: impl FnMut(i64, i64, f32),
    ) -> LinePos {
        let (g, t, m, dx, dy) = (self.g, self.t, self.m, self.dx, self.dy);
        while self.inside(pos.i, pos.jj) && go(pos, hull) {
            let LinePos { i, jj, k } = pos;
            let j = (self.h - 1 - jj) as u32;
            let (x, y) = g.xy(i as u32, j);
            if k == 0 {
                // The terrain beyond the line's last texel, up to the terrain's edge.
                let on = |f: f32| {
                    let (px, py) = (x + f * dx, y + f * dy);
                    px >= g.origin[0]
                        && px <= g.origin[0] + g.extent[0]
                        && py >= g.origin[1]
                        && py <= g.origin[1] + g.extent[1]
                };
                let mut last = 0;
                while on((last + 1) as f32 / m as f32) {
                    last += 1;
                }
                for f in (1..=last).rev() {
                    let f = f as f32 / m as f32;
                    let z = t.mesh_height_at(x + f * dx, y + f * dy);
                    self.add(hull, f as f64, z as f64);
                }
            } else {
                for f in (1..m).rev() {
                    let f = f as f32 / m as f32;
                    let z = t.mesh_height_at(x + f * dx, y + f * dy);
                    self.add(hull, (f - k as f32) as f64, z as f64);
                }
            }
            // A point a tenth of a step ahead: the slope of the triangle under the texel.
            let f = NEAR / m as f32;
            let z = t.mesh_height_at(x + f * dx, y + f * dy);
            self.add(hull, (f - k as f32) as f64, z as f64);
            let slope = self.add(hull, -k as f64, t.mesh_height_at(x, y) as f64);
            visit(i, jj, slope);
            pos = LinePos {
                i: i - self.a,
                jj: jj - self.b,
                k: k + 1,
            };
        }
        pos
    }

    /// Whether a walk that has reached lattice row `jj` has left rows `jj_lo..=jj_hi` behind
    /// (walking backwards: jj decreases for b > 0, increases for b < 0).
    #[inline]
    fn past(&self, jj: i64, jj_lo: i64, jj_hi: i64) -> bool {
        (self.b > 0 && jj < jj_lo) || (self.b < 0 && jj > jj_hi)
    }
}

/// The horizon slope (tan of elevation; −∞ where nothing lies ahead) of every texel of rows
/// `rows` in lattice direction (a, b), passed to `store(index in the rows, slope)`.
pub fn sweep(
    t: &Terrain,
    g: &TexelGrid,
    dir: (i32, i32),
    rows: Range<u32>,
    mut store: impl FnMut(usize, f32),
) {
    let rows = rows.start.min(g.height)..rows.end.min(g.height);
    if rows.is_empty() || dir == (0, 0) {
        return;
    }
    let lw = LineWalk::new(t, g, dir);
    // Lattice rows counted northwards: jj = h − 1 − j.
    let (jj_lo, jj_hi) = (lw.h - rows.end as i64, lw.h - 1 - rows.start as i64);
    let w = lw.w;
    let mut hull: Vec<(f64, f64)> = Vec::new();
    lw.ends(|ei, ejj| {
        // Lines that never reach the rows (walking backwards) are skipped.
        if lw.b == 0 && !(jj_lo..=jj_hi).contains(&ejj) {
            return;
        }
        hull.clear();
        lw.walk(
            &mut hull,
            LinePos {
                i: ei,
                jj: ejj,
                k: 0,
            },
            |p, _| !lw.past(p.jj, jj_lo, jj_hi),
            |i, jj, slope| {
                if (jj_lo..=jj_hi).contains(&jj) {
                    let j = (lw.h - 1 - jj) as u32;
                    store(((j - rows.start) as i64 * w + i) as usize, slope);
                }
            },
        );
    });
}

/// sin of the elevation whose tangent is `slope`.
#[inline]
pub fn sin_of_slope(slope: f32) -> f32 {
    if slope == f32::NEG_INFINITY {
        -1.0
    } else if slope == f32::INFINITY {
        1.0
    } else {
        slope / (1.0 + slope * slope).sqrt()
    }
}

/// sin(elevation) stored in an i16, rounded up (the stored horizon is never below the true one).
#[inline]
fn quantize(s: f32) -> i16 {
    (s * Q).ceil().clamp(-Q, Q) as i16
}

/// Horizons of the texels of some rows in every direction of a lattice, and towards the sun.
#[derive(Debug, Clone)]
pub struct Horizons {
    pub rows: Range<u32>,
    pub width: u32,
    /// The lattice directions, in [`SkyTables`]' sector order.
    pub directions: Vec<(i32, i32)>,
    /// sin(horizon elevation) × 32767 rounded up, `[direction][texel of the rows]`.
    sin_q: Vec<i16>,
    /// Horizon slope towards the sun per texel (empty without a sun).
    pub sun_slope: Vec<f32>,
    /// The lattice direction of the sun sweep.
    pub sun_lattice: Option<(i32, i32)>,
}

impl Horizons {
    /// Sweeps the rows `rows` in every direction of `directions` and, given a sun direction,
    /// towards the sun (in parallel over directions; the result does not depend on the
    /// thread count).
    pub fn compute(
        t: &Terrain,
        g: &TexelGrid,
        directions: &[(i32, i32)],
        sun: Option<[f32; 3]>,
        rows: Range<u32>,
    ) -> Self {
        BandedSweeps::new(g, directions, sun, vec![rows]).horizons(t, g)
    }

    /// Texels covered.
    pub fn len(&self) -> usize {
        self.rows.len() * self.width as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The stored sin(elevation) of texel `k` (index within the rows) in direction `d`.
    #[inline]
    pub fn sin(&self, d: usize, k: usize) -> f32 {
        self.sin_q[d * self.len() + k] as f32 / Q
    }
}

/// A line walking southwards that has left one band and not yet the next: where it stands and
/// its hull as f32 pairs (exact, see [`LinePos`]).
#[derive(Debug, Clone)]
struct Live {
    pos: LinePos,
    hull: Vec<(f32, f32)>,
}

/// One direction's state across the bands of a [`BandedSweeps`]: the lines that walk
/// southwards (b > 0: rows in the bands' order) still walking.
#[derive(Debug, Default)]
struct DirectionState {
    live: Vec<Live>,
}

/// The horizons of consecutive bands of rows, taken in order. A band's own sweep
/// ([`Horizons::compute`]) walks every line from its far end up to the band, so N bands of a
/// large map walk about N/2 grids per direction. Here the lines that walk southwards (those of
/// directions with b > 0, rows in the bands' order) are walked once: each keeps its position and
/// upper hull from one band to the next. The others are swept per band as before, so such a
/// map walks about 1 + N/2 grids per two directions where it walked N; the live lines hold
/// their hulls meanwhile. The horizons are the same bits as each band's own
/// sweep (tests/horizons.rs).
#[derive(Debug)]
pub struct BandedSweeps {
    bands: Vec<Range<u32>>,
    directions: Vec<(i32, i32)>,
    sun_lattice: Option<(i32, i32)>,
    /// `[direction (the sun's last)]`
    states: Vec<DirectionState>,
    /// The next band `horizons` takes.
    next: usize,
}

impl BandedSweeps {
    /// The sweeps of `bands` (consecutive, increasing) in every direction of
    /// `directions` and, given a sun direction, towards the sun.
    pub fn new(
        g: &TexelGrid,
        directions: &[(i32, i32)],
        sun: Option<[f32; 3]>,
        bands: Vec<Range<u32>>,
    ) -> Self {
        assert!(
            bands.windows(2).all(|p| p[0].end == p[1].start),
            "consecutive bands"
        );
        let sun_lattice = sun.map(|s| sun_lattice(g, s));
        let n = directions.len() + sun_lattice.is_some() as usize;
        BandedSweeps {
            bands,
            directions: directions.to_vec(),
            sun_lattice,
            states: (0..n).map(|_| DirectionState::default()).collect(),
            next: 0,
        }
    }

    /// Band `band`'s rows in direction `dir` (a southward one: b > 0), passed to
    /// `store(index in the rows, slope)`: the live lines resumed, the lines that start before
    /// the band's end walked from their start (from above the band where it is the `first`),
    /// and unless it is the `last` band the lines still walking kept live.
    fn southwards(
        t: &Terrain,
        g: &TexelGrid,
        dir: (i32, i32),
        state: &mut DirectionState,
        rows: Range<u32>,
        (first, last): (bool, bool),
        mut store: impl FnMut(usize, f32),
    ) {
        if rows.is_empty() {
            return;
        }
        let lw = LineWalk::new(t, g, dir);
        let (jj_lo, jj_hi) = (lw.h - rows.end as i64, lw.h - 1 - rows.start as i64);
        let mut hull: Vec<(f64, f64)> = Vec::new();
        let mut live = Vec::new();
        let mut run = |hull: &mut Vec<(f64, f64)>, pos: LinePos| {
            let end = lw.walk(
                hull,
                pos,
                |p, _| !lw.past(p.jj, jj_lo, jj_hi),
                |i, jj, slope| {
                    if (jj_lo..=jj_hi).contains(&jj) {
                        let j = (lw.h - 1 - jj) as u32;
                        store(((j - rows.start) as i64 * lw.w + i) as usize, slope);
                    }
                },
            );
            if !last && lw.inside(end.i, end.jj) {
                live.push(Live {
                    pos: end,
                    hull: hull.iter().map(|&(u, z)| (u as f32, z as f32)).collect(),
                });
            }
        };
        for l in std::mem::take(&mut state.live) {
            hull.clear();
            hull.extend(l.hull.iter().map(|&(u, z)| (u as f64, z as f64)));
            run(&mut hull, l.pos);
        }
        // Lines starting in the band, and for the first band every line starting above it.
        lw.ends(|ei, ejj| {
            if ejj >= jj_lo && (first || ejj <= jj_hi) {
                hull.clear();
                run(
                    &mut hull,
                    LinePos {
                        i: ei,
                        jj: ejj,
                        k: 0,
                    },
                );
            }
        });
        state.live = live;
    }

    /// The next band's horizons (bands are taken in order), equal to
    /// `Horizons::compute(t, g, directions, sun, rows)` of its rows.
    pub fn horizons(&mut self, t: &Terrain, g: &TexelGrid) -> Horizons {
        let band = self.next;
        self.next += 1;
        let (first, last) = (band == 0, band + 1 == self.bands.len());
        let rows = self.bands[band].start.min(g.height)..self.bands[band].end.min(g.height);
        let n = rows.len() * g.width as usize;
        let (dir_states, sun_state) = self.states.split_at_mut(self.directions.len());
        let band_sweep =
            |dir: (i32, i32), state: &mut DirectionState, store: &mut dyn FnMut(usize, f32)| {
                if dir.1 > 0 {
                    Self::southwards(t, g, dir, state, rows.clone(), (first, last), store);
                } else {
                    sweep(t, g, dir, rows.clone(), store);
                }
            };
        let mut sin_q = vec![0i16; n * self.directions.len()];
        let mut sun_slope = Vec::new();
        rayon::join(
            || {
                if n > 0 {
                    sin_q
                        .par_chunks_mut(n)
                        .zip(self.directions.par_iter().zip(dir_states.par_iter_mut()))
                        .for_each(|(out, (&dir, state))| {
                            band_sweep(dir, state, &mut |k, s| out[k] = quantize(sin_of_slope(s)))
                        });
                }
            },
            || {
                if let (Some(dir), Some(state)) = (self.sun_lattice, sun_state.first_mut()) {
                    sun_slope = vec![f32::NEG_INFINITY; n];
                    band_sweep(dir, state, &mut |k, s| sun_slope[k] = s);
                }
            },
        );
        Horizons {
            rows,
            width: g.width,
            directions: self.directions.clone(),
            sin_q,
            sun_slope,
            sun_lattice: self.sun_lattice,
        }
    }
}

/// The lattice vector (|a|, |b| ≤ 16, primitive) whose world azimuth is closest to the sun's
/// (a sun in the zenith gets (1, 0): its azimuth does not matter).
pub fn sun_lattice(g: &TexelGrid, s: [f32; 3]) -> (i32, i32) {
    let target = (s[1] as f64).atan2(s[0] as f64);
    let mut best = ((1, 0), f64::INFINITY);
    for a in -SUN_LATTICE..=SUN_LATTICE {
        for b in -SUN_LATTICE..=SUN_LATTICE {
            if (a, b) == (0, 0) || gcd(a.abs(), b.abs()) != 1 {
                continue;
            }
            let d = angle_diff(g.azimuth(a, b), target).abs();
            // Ties go to the shorter vector (cheaper sweep); the order is fixed.
            if d < best.1 - 1e-12 {
                best = ((a, b), d);
            }
        }
    }
    best.0
}

/// a − b wrapped into (−π, π].
fn angle_diff(a: f64, b: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let d = (a - b).rem_euclid(tau);
    if d > std::f64::consts::PI { d - tau } else { d }
}

/// The angle `p` moved by whole turns into [lo, lo + 2π).
#[inline]
fn wrap_from(p: f64, lo: f64) -> f64 {
    lo + (p - lo).rem_euclid(std::f64::consts::TAU)
}

/// Fraction of a disc of angular radius `r` centred at elevation `e` that lies above a horizon
/// at elevation `horizon` (the chord of a flat disc: the sun is small).
pub fn disc_fraction(horizon: f32, e: f32, r: f32) -> f32 {
    let u = ((horizon - e) / r).clamp(-1.0, 1.0);
    ((u.acos() - u * (1.0 - u * u).sqrt()) / std::f32::consts::PI).clamp(0.0, 1.0)
}

/// The visible fraction of the sun's disc seen from a point whose horizon towards the sun has
/// slope `slope`, for a sun in direction `s` (unit).
pub fn sun_fraction(slope: f32, s: [f32; 3]) -> f32 {
    let horizon = slope.atan();
    let e = s[2].clamp(-1.0, 1.0).asin();
    disc_fraction(horizon, e, super::SUN_RADIUS)
}

/// Per sector of azimuth, the sky's `V(s) = ∫ L(d) d dω` over the directions of the sector with
/// sin(elevation) above s (see the file comment).
#[derive(Debug, Clone)]
pub struct SkyTables {
    /// Sector bounds (radians, increasing; `hi` of the last is `lo` of the first + 2π).
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// cos, sin of the bounds.
    lo_cs: Vec<(f32, f32)>,
    hi_cs: Vec<(f32, f32)>,
    /// `[sector][node]` with node i at s = −1 + 2i/TABLE: `[x, y, z]` of RGB.
    table: Vec<[[f32; 3]; 3]>,
}

impl SkyTables {
    /// The sectors of `directions` (lattice vectors on grid `g`) and the tables of `sky`.
    pub fn new(g: &TexelGrid, directions: &[(i32, i32)], sky: &ShRadiance) -> Self {
        let phi: Vec<f64> = directions.iter().map(|&(a, b)| g.azimuth(a, b)).collect();
        let k = phi.len();
        let tau = std::f64::consts::TAU;
        let mut lo = Vec::with_capacity(k);
        let mut hi = Vec::with_capacity(k);
        for i in 0..k {
            let prev = if i == 0 { phi[k - 1] - tau } else { phi[i - 1] };
            let next = if i + 1 == k { phi[0] + tau } else { phi[i + 1] };
            lo.push(0.5 * (prev + phi[i]));
            hi.push(0.5 * (phi[i] + next));
        }
        let gl = crate::sh::gauss_legendre(16);
        let g2 = [0.5 - 0.5 / 3f64.sqrt(), 0.5 + 0.5 / 3f64.sqrt()];
        let table: Vec<[[f32; 3]; 3]> = (0..k)
            .into_par_iter()
            .flat_map_iter(|sector| {
                let (a, b) = (lo[sector], hi[sector]);
                let phis: Vec<(f64, f64, f64)> = gl
                    .iter()
                    .map(|&(x, wt)| {
                        let p = a + (b - a) * 0.5 * (x + 1.0);
                        (p.cos(), p.sin(), wt * 0.5 * (b - a))
                    })
                    .collect();
                let ds = 2.0 / TABLE as f64;
                let mut acc = [[0.0f64; 3]; 3];
                let mut col = vec![[[0.0f32; 3]; 3]; TABLE + 1];
                for i in (0..TABLE).rev() {
                    let s0 = -1.0 + i as f64 * ds;
                    for gs in g2 {
                        let s = s0 + gs * ds;
                        let r = (1.0 - s * s).max(0.0).sqrt();
                        for &(c, sn, wp) in &phis {
                            let d = [r * c, r * sn, s];
                            let l = sky.eval(d.map(|v| v as f32));
                            let wt = wp * 0.5 * ds;
                            for (x, dx) in d.iter().enumerate() {
                                for ch in 0..3 {
                                    acc[x][ch] += l[ch] as f64 * dx * wt;
                                }
                            }
                        }
                    }
                    col[i] = acc.map(|r| r.map(|v| v as f32));
                }
                col
            })
            .collect();
        let cs = |v: &Vec<f64>| v.iter().map(|p| (p.cos() as f32, p.sin() as f32)).collect();
        SkyTables {
            lo_cs: cs(&lo),
            hi_cs: cs(&hi),
            lo,
            hi,
            table,
        }
    }

    pub fn sectors(&self) -> usize {
        self.lo.len()
    }

    /// The sector of a direction's azimuth (an exact partition of the circle).
    #[inline]
    pub fn sector_of(&self, x: f32, y: f32) -> usize {
        let p = wrap_from((y as f64).atan2(x as f64), self.lo[0]);
        self.hi.partition_point(|&h| h <= p).min(self.hi.len() - 1)
    }

    /// `∫ L(d) (n·d) dω` over sector k above sin(elevation) s.
    #[inline]
    pub fn integral(&self, k: usize, s: f32, n: [f32; 3]) -> [f32; 3] {
        let pos = ((s.clamp(-1.0, 1.0) + 1.0) * 0.5 * TABLE as f32).min(TABLE as f32);
        let i = (pos as usize).min(TABLE - 1);
        let f = pos - i as f32;
        let row = &self.table[k * (TABLE + 1)..];
        let (v0, v1) = (&row[i], &row[i + 1]);
        std::array::from_fn(|ch| {
            (0..3)
                .map(|x| n[x] * (v0[x][ch] + f * (v1[x][ch] - v0[x][ch])))
                .sum()
        })
    }

    /// The horizon of sector k used for a texel with unit normal `n` (n_z > 0): the stored
    /// sin(elevation) `s`, raised to the highest point of the tangent plane over the sector.
    #[inline]
    pub fn effective(&self, k: usize, s: f32, n: [f32; 3]) -> f32 {
        self.effective_at(k, s, n, Self::downhill(n))
    }

    /// The azimuth in which the tangent plane of unit normal `n` is highest, −(n_x, n_y)
    /// (`None` for a level plane): what [`Self::effective_at`] takes, the same for every sector.
    #[inline]
    pub fn downhill(n: [f32; 3]) -> Option<f64> {
        (n[0].hypot(n[1]) > 0.0).then(|| (-n[1] as f64).atan2(-n[0] as f64))
    }

    /// [`Self::effective`] with the normal's [`Self::downhill`] azimuth computed once for all
    /// sectors (the same value, so the same bits).
    #[inline]
    pub fn effective_at(&self, k: usize, s: f32, n: [f32; 3], downhill: Option<f64>) -> f32 {
        let nz = n[2].max(1e-6);
        let tan_at = |(c, sn): (f32, f32)| -(n[0] * c + n[1] * sn) / nz;
        let mut t = tan_at(self.lo_cs[k]).max(tan_at(self.hi_cs[k]));
        // The tangent plane is highest in the azimuth of −(n_x, n_y).
        if let Some(a) = downhill
            && wrap_from(a, self.lo[k]) < self.hi[k]
        {
            t = t.max(n[0].hypot(n[1]) / nz);
        }
        s.max(sin_of_slope(t))
    }
}
