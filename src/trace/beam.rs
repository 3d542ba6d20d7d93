//! Rays near one fixed direction (the sun's disc) traced among a [`SceneBvh`]'s model instances
//! without its top level: the [`SunBeam`] (issue 37).
//!
//! The light map traces, per texel, a handful of shadow rays that all start at the texel and lie
//! within the sun's disc around the one sun direction `s` of the whole map. Most texels are in no
//! instance's shadow, yet each of their rays walked the top-level BVH from its root. The beam
//! projects every instance's world box along `s` onto the plane z = 0 (an oblique projection,
//! `P(p) = (p.x − p.z·s.x/s.z, p.y − p.z·s.y/s.z)`: a ray along `s` projects to one point, a ray
//! near `s` to a short segment) and bins the projected rectangles in a uniform 2D grid, once per
//! map. A query takes a texel's rays, bounds their projected segments (clipped to the instances'
//! height range) by one rectangle, and gathers the instances whose rectangles overlap it: every
//! instance whose box a ray's segment can touch is among them. Where there is none, every ray is
//! open with no traversal at all; else each ray is tested against those candidates' boxes and,
//! where it meets one, against that instance's model BVH (alpha-tested), exactly as
//! [`SceneBvh::any_hit_excluding`] tests an instance its top level reaches: the rays that meet
//! one candidate's box in one packet walk of its model's BVH
//! (`SceneBvh::instance_any_hits`, [`super::bvh::ModelBvh::any_hits_packet`]: the same
//! answer per ray as that ray's own walk, for the 16 near-parallel rays of a texel one pass
//! over the nodes they share).
//!
//! The answers are the same as the top level's: both are "some instance's model is hit by the
//! ray mapped into it", the one model query decides each instance, and each path skips only
//! instances whose (padded) world box the ray misses, which contain none of the ray's hits. The
//! projected rectangles, the query rectangle and the boxes tested per ray are padded beyond
//! rounding (absolute 1 mm plus a relative 1e-5 of the coordinates), so the beam never skips an
//! instance the top level would find a hit in. The terrain is not traced (the light map's sun
//! rays skip it: the horizons stand for it).

use super::Ray;
use super::scene::SceneBvh;
use glam::Vec3A;

/// Sun elevations below this sine (≈ 2.9°) get no beam: the projected rectangles grow as
/// 1/tan(elevation) and the grid would hold every instance in many cells.
const MIN_AXIS_Z: f32 = 0.05;

/// The largest number of rays one query handles at once (a query with more runs in chunks).
const CHUNK: usize = 64;

/// An instance's projected box and its world box, both padded.
#[derive(Debug, Clone, Copy)]
struct Entry {
    /// Projected rectangle: x0, y0, x1, y1.
    rect: [f64; 4],
    lo: [f64; 3],
    hi: [f64; 3],
}

/// An instance as a grid cell lists it: its projected rectangle rounded outwards to f32 and
/// the top of its box (rounded up), beside its number, so that a query reads the cell's list
/// alone until an instance's rectangle overlaps its own.
#[derive(Debug, Clone, Copy)]
struct Item {
    rect: [f32; 4],
    top: f32,
    instance: u32,
}

/// The f32 at or below `x`.
fn down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x { f.next_down() } else { f }
}

/// The f32 at or above `x`.
fn up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

/// The empty rectangle (x0, y0, x1, y1) that [`grow`] widens.
const EMPTY: [f64; 4] = [
    f64::INFINITY,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NEG_INFINITY,
];

/// Rectangle `r` widened to hold point `q`.
fn grow(r: [f64; 4], q: [f64; 2]) -> [f64; 4] {
    [
        r[0].min(q[0]),
        r[1].min(q[1]),
        r[2].max(q[0]),
        r[3].max(q[1]),
    ]
}

/// Point `p` projected along the beam's axis onto z = 0 (`shear` = (s.x / s.z, s.y / s.z)).
fn project(shear: [f64; 2], p: [f64; 3]) -> [f64; 2] {
    [p[0] - shear[0] * p[2], p[1] - shear[1] * p[2]]
}

/// A rectangle rounded outwards to f32.
fn outwards(r: &[f64; 4]) -> [f32; 4] {
    [down(r[0]), down(r[1]), up(r[2]), up(r[3])]
}

/// A ray of a query as the box tests read it: origin, inverse direction (∞ for a zero
/// component, tested apart), its `t` range.
#[derive(Debug, Clone, Copy, Default)]
struct Segment {
    o: [f64; 3],
    d: [f64; 3],
    inv: [f64; 3],
    t: [f64; 2],
}

/// The model instances of a [`SceneBvh`] binned by their boxes' shadows along one direction:
/// any-hit queries of rays near that direction among the instances only (see the module's text).
#[derive(Debug)]
pub struct SunBeam<'a> {
    scene: &'a SceneBvh,
    /// The projection's shear: (s.x / s.z, s.y / s.z).
    shear: [f64; 2],
    /// The instances' height range (padded boxes, padded again).
    z: [f64; 2],
    entries: Vec<Entry>,
    /// The grid: its lower corner, its cell size, its cells per side.
    corner: [f64; 2],
    cell: f64,
    cells: [usize; 2],
    /// Cell c's instances are `items[starts[c]..starts[c + 1]]`, ascending.
    starts: Vec<u32>,
    items: Vec<Item>,
}

/// The padding of a coordinate of magnitude `m`: beyond f32 rounding of every value the query
/// compares, and beyond the rounding of the f32 rays the model BVHs see.
fn pad(m: f64) -> f64 {
    1e-3 + 1e-5 * m.abs()
}

impl<'a> SunBeam<'a> {
    /// The beam of `scene`'s model instances along `axis` (a unit direction up towards the sun);
    /// `None` without instances, or for an axis that is not finite or below [`MIN_AXIS_Z`].
    pub fn new(scene: &'a SceneBvh, axis: Vec3A) -> Option<SunBeam<'a>> {
        let n = scene.instances().len();
        if n == 0 || !axis.is_finite() || axis.z < MIN_AXIS_Z {
            return None;
        }
        let shear = [axis.x as f64 / axis.z as f64, axis.y as f64 / axis.z as f64];
        let mut z = [f64::INFINITY, f64::NEG_INFINITY];
        let entries: Vec<Entry> = (0..n as u32)
            .map(|k| {
                let (lo, hi) = scene.instance_bounds(k);
                let (lo, hi) = (lo.to_array().map(f64::from), hi.to_array().map(f64::from));
                let m = lo.iter().chain(&hi).fold(0.0f64, |m, v| m.max(v.abs()));
                let lo = lo.map(|v| v - pad(m));
                let hi = hi.map(|v| v + pad(m));
                z = [z[0].min(lo[2]), z[1].max(hi[2])];
                let mut rect = EMPTY;
                for c in 0..8 {
                    let p = [
                        if c & 1 != 0 { hi[0] } else { lo[0] },
                        if c & 2 != 0 { hi[1] } else { lo[1] },
                        if c & 4 != 0 { hi[2] } else { lo[2] },
                    ];
                    rect = grow(rect, project(shear, p));
                }
                let m = rect.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let e = pad(m);
                Entry {
                    rect: [rect[0] - e, rect[1] - e, rect[2] + e, rect[3] + e],
                    lo,
                    hi,
                }
            })
            .collect();
        if entries.iter().any(|e| {
            !e.rect
                .iter()
                .chain(&e.lo)
                .chain(&e.hi)
                .all(|v| v.is_finite())
        }) {
            return None;
        }
        let m = z[0].abs().max(z[1].abs());
        let z = [z[0] - pad(m), z[1] + pad(m)];
        // The grid over the rectangles: cells about the rectangles' mean size (geometric mean
        // of the sides), at least a quarter of the area per instance, grown while the cells
        // would list the instances more than 32 times over.
        let mut bound = EMPTY;
        let mut side = 0.0f64;
        for e in &entries {
            let r = e.rect;
            bound = grow(grow(bound, [r[0], r[1]]), [r[2], r[3]]);
            side += ((r[2] - r[0]) * (r[3] - r[1])).sqrt();
        }
        let (wx, wy) = (bound[2] - bound[0], bound[3] - bound[1]);
        let mut cell = (side / n as f64)
            .max((wx * wy / (4.0 * n as f64)).sqrt())
            .max(1e-3);
        let corner = [bound[0], bound[1]];
        let budget = 32 * n + 1024;
        let cells = loop {
            let cells = [
                ((wx / cell).floor() as usize + 1).min(1 << 16),
                ((wy / cell).floor() as usize + 1).min(1 << 16),
            ];
            let grid = Grid {
                corner,
                cell,
                cells,
            };
            let listed: usize = entries
                .iter()
                .map(|e| {
                    let ([x0, y0], [x1, y1]) = grid.span(&outwards(&e.rect));
                    (x1 - x0 + 1) * (y1 - y0 + 1)
                })
                .sum();
            if listed <= budget && cells[0] * cells[1] <= budget {
                break cells;
            }
            cell *= 1.5;
        };
        let grid = Grid {
            corner,
            cell,
            cells,
        };
        let mut starts = vec![0u32; cells[0] * cells[1] + 1];
        for e in &entries {
            let ([x0, y0], [x1, y1]) = grid.span(&outwards(&e.rect));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    starts[y * cells[0] + x + 1] += 1;
                }
            }
        }
        for c in 1..starts.len() {
            starts[c] += starts[c - 1];
        }
        let mut fill = starts.clone();
        let blank = Item {
            rect: [0.0; 4],
            top: 0.0,
            instance: 0,
        };
        let mut items = vec![blank; *starts.last().unwrap_or(&0) as usize];
        for (k, e) in entries.iter().enumerate() {
            let item = Item {
                rect: outwards(&e.rect),
                top: up(e.hi[2]),
                instance: k as u32,
            };
            let ([x0, y0], [x1, y1]) = grid.span(&item.rect);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let c = y * cells[0] + x;
                    items[fill[c] as usize] = item;
                    fill[c] += 1;
                }
            }
        }
        Some(SunBeam {
            scene,
            shear,
            z,
            entries,
            corner,
            cell,
            cells,
            starts,
            items,
        })
    }

    fn grid(&self) -> Grid {
        Grid {
            corner: self.corner,
            cell: self.cell,
            cells: self.cells,
        }
    }

    /// Whether some model instance blocks each ray: `blocked[i]` is
    /// `scene.any_hit_excluding(&rays[i], &[terrain])` (the terrain, if any, is not traced).
    /// Rays that do not rise (`dir.z ≤ 0`) or are not finite go through the top level.
    ///
    /// Panics if the two slices' lengths differ.
    pub fn any_hits(&self, rays: &[Ray], blocked: &mut [bool]) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        for (rays, blocked) in rays.chunks(CHUNK).zip(blocked.chunks_mut(CHUNK)) {
            self.any_hits_chunk(rays, blocked);
        }
    }

    fn any_hits_chunk(&self, rays: &[Ray], blocked: &mut [bool]) {
        let skip = [self.scene.instances().len() as u32];
        // The rectangle that holds every ray's projected segment within the instances' heights.
        let mut q = EMPTY;
        let mut zmin = f64::INFINITY;
        // Which rays the candidates must decide, and those rays for the box tests.
        let mut open = [false; CHUNK];
        let mut segments = [Segment::default(); CHUNK];
        for (i, r) in rays.iter().enumerate() {
            blocked[i] = false;
            let ok = r.origin.is_finite() && r.dir.is_finite() && !r.tmin.is_nan();
            if !ok || r.dir.z <= 0.0 || r.tmax.is_nan() {
                blocked[i] = self.scene.any_hit_excluding(r, &skip);
                continue;
            }
            let o = r.origin.to_array().map(f64::from);
            let d = r.dir.to_array().map(f64::from);
            // The part of the segment within the instances' heights (padded: the f32 ray's
            // points differ from these by rounding only).
            let t0 = (r.tmin as f64).max((self.z[0] - o[2]) / d[2]);
            let t1 = (r.tmax as f64).min((self.z[1] - o[2]) / d[2]);
            if !(t0.is_finite() && t1.is_finite()) {
                // An infinite tmin or a tmax of −∞: no segment to bound.
                blocked[i] = self.scene.any_hit_excluding(r, &skip);
                continue;
            }
            let slack = 1e-6 * t0.abs().max(t1.abs()) + 1e-9;
            if t0 > t1 + slack {
                // The segment ends below the lowest box or starts above the highest.
                continue;
            }
            open[i] = true;
            segments[i] = Segment {
                o,
                d,
                inv: d.map(|v| 1.0 / v),
                t: [r.tmin as f64, r.tmax as f64],
            };
            let p = project(self.shear, o);
            let v = project(self.shear, d);
            for t in [t0, t1] {
                q = grow(q, [p[0] + t * v[0], p[1] + t * v[1]]);
            }
            zmin = zmin.min(o[2] + t0 * d[2]);
        }
        if !open[..rays.len()].iter().any(|&o| o) {
            return;
        }
        let m = q.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let e = pad(m);
        let q = outwards(&[q[0] - e, q[1] - e, q[2] + e, q[3] + e]);
        let zmin = down(zmin - pad(zmin));
        let grid = self.grid();
        let ([x0, y0], [x1, y1]) = grid.span(&q);
        let mut left = open[..rays.len()].iter().filter(|&&o| o).count();
        // A candidate's rays: the picked rays, their places in `rays`, their answers.
        let mut picked = [rays[0]; CHUNK];
        let mut which = [0usize; CHUNK];
        let mut hit = [false; CHUNK];
        for y in y0..=y1 {
            for x in x0..=x1 {
                let c = y * self.cells[0] + x;
                for item in &self.items[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let r = item.rect;
                    if r[0] > q[2] || r[2] < q[0] || r[1] > q[3] || r[3] < q[1] || item.top < zmin {
                        continue;
                    }
                    // Each overlapping instance once: in the cell of the overlap's low corner.
                    if grid.at([r[0].max(q[0]) as f64, r[1].max(q[1]) as f64]) != [x, y] {
                        continue;
                    }
                    let k = item.instance;
                    let e = &self.entries[k as usize];
                    // The open rays that meet the instance's box, traced as one packet.
                    let mut m = 0;
                    for (i, ray) in rays.iter().enumerate() {
                        if open[i] && segments[i].meets(e) {
                            (picked[m], which[m]) = (*ray, i);
                            m += 1;
                        }
                    }
                    if m == 0 {
                        continue;
                    }
                    self.scene.instance_any_hits(k, &picked[..m], &mut hit[..m]);
                    for (&i, &h) in which[..m].iter().zip(&hit[..m]) {
                        if h {
                            open[i] = false;
                            blocked[i] = true;
                            left -= 1;
                        }
                    }
                    if left == 0 {
                        return;
                    }
                }
            }
        }
    }
}

impl Segment {
    /// Whether the segment meets the (padded) box, in f64 and conservatively: a direction
    /// component of zero tests the origin's coordinate against the slab.
    #[inline]
    fn meets(&self, e: &Entry) -> bool {
        let [mut t0, mut t1] = self.t;
        for a in 0..3 {
            let o = self.o[a];
            if self.d[a] == 0.0 {
                if o < e.lo[a] || o > e.hi[a] {
                    return false;
                }
                continue;
            }
            let (ta, tb) = ((e.lo[a] - o) * self.inv[a], (e.hi[a] - o) * self.inv[a]);
            let (ta, tb) = if ta <= tb { (ta, tb) } else { (tb, ta) };
            t0 = t0.max(ta);
            t1 = t1.min(tb);
        }
        // NaN (an infinite bound times a zero offset) reads as meeting the box: conservative.
        let slack = 1e-6 * t0.abs().max(t1.abs()) + 1e-9;
        t0.partial_cmp(&(t1 + slack)) != Some(std::cmp::Ordering::Greater)
    }
}

/// The uniform grid of a [`SunBeam`].
struct Grid {
    corner: [f64; 2],
    cell: f64,
    cells: [usize; 2],
}

impl Grid {
    /// The cell of a point, clamped into the grid (monotone in each coordinate).
    fn at(&self, p: [f64; 2]) -> [usize; 2] {
        [0, 1].map(|a| {
            let c = ((p[a] - self.corner[a]) / self.cell).floor();
            if c >= 0.0 {
                (c as usize).min(self.cells[a] - 1)
            } else {
                0
            }
        })
    }

    /// The cells of a rectangle (x0, y0, x1, y1): its low and high corners' cells.
    fn span(&self, r: &[f32; 4]) -> ([usize; 2], [usize; 2]) {
        let r = r.map(f64::from);
        (self.at([r[0], r[1]]), self.at([r[2], r[3]]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, Mesh};
    use crate::trace::scene::InstanceTransform;
    use crate::trace::{BuildPreset, ModelBvh, Rng};
    use std::sync::Arc;

    /// A mesh of random triangles in the box [-0.5, 0.5]² × [0, 2] (some big, some small).
    fn blob(seed: u64, n: usize) -> Mesh {
        let mut rng = Rng::hashed(seed);
        let mut m = Mesh {
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        for t in 0..n as u32 {
            let c = [rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() * 1.6];
            let s = if t % 5 == 0 { 0.6 } else { 0.2 };
            for _ in 0..3 {
                m.positions.push([
                    (c[0] + rng.f32() * s).clamp(-0.5, 0.5),
                    (c[1] + rng.f32() * s).clamp(-0.5, 0.5),
                    (c[2] + rng.f32() * s).clamp(0.0, 2.0),
                ]);
                m.normals.push([0.0, 0.0, 1.0]);
                m.uvs.push([rng.f32(), rng.f32()]);
            }
            m.indices.push([3 * t, 3 * t + 1, 3 * t + 2]);
            m.triangle_materials.push(0);
        }
        m
    }

    /// 600 instances of three models (one alpha-tested), rotated, scaled 0.3–3×, on a 60 m
    /// square at heights 0–4 m (boxes overlap).
    fn scene() -> SceneBvh {
        let meshes = [blob(1, 40), blob(2, 120), blob(3, 80)];
        // Half of every card of model 2 see-through.
        let mask = crate::trace::bvh::tests::checker();
        let models = meshes
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let masks = if k == 2 {
                    vec![Some(mask.clone())]
                } else {
                    vec![]
                };
                Arc::new(ModelBvh::build(m, &masks, BuildPreset::Fast).unwrap())
            })
            .collect();
        let mut rng = Rng::hashed(4);
        let instances = (0..600)
            .map(|k| InstanceTransform {
                model: k % 3,
                translation: [rng.f32() * 60.0, rng.f32() * 60.0, rng.f32() * 4.0],
                scale: 0.3 + rng.f32() * 2.7,
                rotation_deg: rng.f32() * 360.0,
            })
            .collect();
        SceneBvh::build(models, instances).unwrap()
    }

    /// Brute force: every instance's model tested per ray, no top level, no boxes.
    fn brute(scene: &SceneBvh, r: &Ray) -> bool {
        (0..scene.instances().len() as u32).any(|k| scene.instance_any_hit(k, r))
    }

    /// A direction within `radius` radians of `axis`.
    fn near(rng: &mut Rng, axis: Vec3A, radius: f32) -> Vec3A {
        let (tx, bx) = crate::trace::frame(axis);
        let r = radius * rng.f32().sqrt();
        let phi = std::f32::consts::TAU * rng.f32();
        (axis + tx * (r * phi.cos()) + bx * (r * phi.sin())).normalize()
    }

    fn check(scene: &SceneBvh, axis: Vec3A, seed: u64) -> (usize, usize) {
        let beam = SunBeam::new(scene, axis).expect("a beam");
        let mut rng = Rng::hashed(seed);
        let (mut hits, mut total) = (0, 0);
        for case in 0..1500 {
            // Origins: anywhere over the square, inside a random instance's box, or on a
            // box's face or edge (rays grazing and starting on the boundary).
            let k = (rng.f32() * scene.instances().len() as f32) as u32;
            let (lo, hi) = scene.instance_bounds(k.min(scene.instances().len() as u32 - 1));
            let u = Vec3A::new(rng.f32(), rng.f32(), rng.f32());
            let o = match case % 4 {
                0 => Vec3A::new(
                    rng.f32() * 70.0 - 5.0,
                    rng.f32() * 70.0 - 5.0,
                    rng.f32() * 6.0 - 1.0,
                ),
                1 => lo + (hi - lo) * u,
                2 => {
                    // On an edge of the box: two coordinates at a bound.
                    let mut p = lo + (hi - lo) * u;
                    p.x = if rng.f32() < 0.5 { lo.x } else { hi.x };
                    p.z = if rng.f32() < 0.5 { lo.z } else { hi.z };
                    p
                }
                _ => {
                    // Just outside a face, to graze the box along the beam.
                    let mut p = lo + (hi - lo) * u;
                    p.y = hi.y + 1e-4;
                    p
                }
            };
            let n = 1 + (rng.f32() * 20.0) as usize;
            let rays: Vec<Ray> = (0..n)
                .map(|j| {
                    let d = if j % 7 == 3 {
                        // Now and then exactly the axis, or a direction with a zero component.
                        Vec3A::new(0.0, axis.y, axis.z).normalize()
                    } else {
                        near(&mut rng, axis, 0.00465)
                    };
                    let tmax = match j % 3 {
                        0 => f32::INFINITY,
                        1 => 5.0 + rng.f32() * 20.0,
                        _ => ((4.0 * 3.0 + 2.0 - o.z) / d.z).max(0.0) + 1e-3,
                    };
                    Ray {
                        tmax,
                        ..Ray::new(o, d, 1e-4)
                    }
                })
                .collect();
            let mut got = vec![false; n];
            beam.any_hits(&rays, &mut got);
            for (r, g) in rays.iter().zip(&got) {
                let want = brute(scene, r);
                assert_eq!(*g, want, "{r:?}");
                let skip = [scene.instances().len() as u32];
                assert_eq!(*g, scene.any_hit_excluding(r, &skip), "{r:?}");
                hits += want as usize;
                total += 1;
            }
        }
        (hits, total)
    }

    #[test]
    fn sun_beam_equals_brute_force_for_high_and_low_suns() {
        let s = scene();
        for (k, axis) in [
            Vec3A::new(0.3, 0.2, 0.93),
            Vec3A::new(-0.7, 0.45, 0.25),
            Vec3A::new(0.0, -0.8, 0.6),
            Vec3A::Z,
        ]
        .into_iter()
        .enumerate()
        {
            let (hits, total) = check(&s, axis.normalize(), 10 + k as u64);
            // Both answers occur often: the test tells a beam that finds nothing from one
            // that is right.
            assert!(
                hits > total / 20 && hits < total * 9 / 10,
                "{hits} of {total}"
            );
        }
    }

    #[test]
    fn sun_beam_refuses_low_or_bad_axes_and_empty_scenes() {
        let s = scene();
        assert!(SunBeam::new(&s, Vec3A::new(1.0, 0.0, 0.01).normalize()).is_none());
        assert!(SunBeam::new(&s, Vec3A::new(f32::NAN, 0.0, 1.0)).is_none());
        let empty = SceneBvh::build(s.models().to_vec(), vec![]).unwrap();
        assert!(SunBeam::new(&empty, Vec3A::Z).is_none());
    }

    #[test]
    fn rays_that_do_not_rise_go_through_the_top_level() {
        let s = scene();
        let beam = SunBeam::new(&s, Vec3A::new(0.3, 0.2, 0.93).normalize()).unwrap();
        let mut rng = Rng::hashed(77);
        let mut hits = 0;
        for _ in 0..1000 {
            let o = Vec3A::new(rng.f32() * 60.0, rng.f32() * 60.0, rng.f32() * 4.0);
            let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, -rng.f32()).normalize();
            let r = Ray::new(o, d, 1e-4);
            let mut got = [false];
            beam.any_hits(&[r], &mut got);
            assert_eq!(got[0], brute(&s, &r));
            hits += got[0] as u32;
        }
        assert!(hits > 10, "{hits}");
    }
}
