//! Per-frame instance selection on the CPU: frustum culling by bounding sphere, the level each
//! instance draws (the LOD rule of [`crate::lod::select`], or full detail), and the instance
//! buckets the draw passes use: per model, one contiguous run of instance records per
//! (pass, level), so each (model, level, material range) is one instanced draw.
//!
//! Pass 0 is the camera; passes 1.. are the shadow views (one per cascade). Every instance gets
//! its level from the camera (its distance to the eye), whichever pass draws it, so an instance
//! casts the same shape it shows. Each record's `reserved` field carries the instance's index
//! among its model's instances ([`super::scene::ModelData::instances`]): the ambient shader reads
//! the instance's maps and light-map UVs with it, not with the draw's instance index.
//! The loop is sequential in model and instance order: the buckets, and so the image, do not
//! depend on the thread count.

use crate::ingest::instances_section::InstanceRecord;
use glam::{Mat4, Vec3, Vec4};

/// The planes of a view's clip volume, `n·p + d ≥ 0` inside, normalized.
#[derive(Debug, Clone, PartialEq)]
pub struct Frustum {
    pub planes: Vec<Vec4>,
}

impl Frustum {
    /// The side planes of a wgpu clip volume (x, y in [−w, w]) and its near plane (z ≤ w);
    /// with `depth_range`, also z ≥ 0 (an orthographic shadow view's far plane; the camera's
    /// reversed infinite projection has none).
    pub fn from_view_proj(m: Mat4, depth_range: bool) -> Frustum {
        let r = m.transpose();
        let (r0, r1, r2, r3) = (r.x_axis, r.y_axis, r.z_axis, r.w_axis);
        let mut planes = vec![r3 + r0, r3 - r0, r3 + r1, r3 - r1, r3 - r2];
        if depth_range {
            planes.push(r2);
        }
        for p in &mut planes {
            let l = p.truncate().length();
            if l > 0.0 {
                *p /= l;
            }
        }
        Frustum { planes }
    }

    /// True when the box `[lo, hi]` reaches inside every plane (conservative, like the sphere).
    pub fn meets_box(&self, lo: Vec3, hi: Vec3) -> bool {
        self.planes.iter().all(|p| {
            let n = p.truncate();
            let far = Vec3::select(n.cmpge(Vec3::ZERO), hi, lo);
            n.dot(far) + p.w >= 0.0
        })
    }

    /// True when the sphere reaches inside every plane (conservative: a sphere near a corner
    /// outside the volume may still pass).
    pub fn meets_sphere(&self, centre: Vec3, radius: f32) -> bool {
        self.planes
            .iter()
            .all(|p| p.truncate().dot(centre) + p.w >= -radius)
    }
}

/// A model's bounding sphere in model units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub centre: [f32; 3],
    pub radius: f32,
}

impl Sphere {
    /// The sphere around the box of `positions` (centre of the box, radius to the farthest
    /// vertex); a zero sphere at the origin for no positions.
    pub fn around(positions: &[[f32; 3]]) -> Sphere {
        let Some((lo, hi)) = crate::model::bounds_of(positions) else {
            return Sphere {
                centre: [0.0; 3],
                radius: 0.0,
            };
        };
        let c = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
        let r = positions
            .iter()
            .map(|&p| (Vec3::from(p) - c).length())
            .fold(0.0f32, f32::max);
        Sphere {
            centre: c.to_array(),
            radius: r,
        }
    }

    /// The sphere of an instance in the world: `p + R_z(θ)·(s·c)`, radius `|s|·r`.
    pub fn placed(&self, r: &InstanceRecord) -> (Vec3, f32) {
        let (s, c) = r.rotation_deg.to_radians().sin_cos();
        let q = Vec3::from(self.centre) * r.scale;
        let rotated = Vec3::new(c * q.x - s * q.y, s * q.x + c * q.y, q.z);
        (
            Vec3::from(r.position) + rotated,
            self.radius * r.scale.abs(),
        )
    }
}

/// How one model is bucketed: its sphere and how it picks a level.
pub trait LevelRule {
    /// Number of drawable levels (mesh levels, then the impostor if any).
    fn levels(&self) -> usize;
    /// Level of an instance of scale `scale` whose sphere centre is `distance` from the eye.
    fn level(&self, scale: f32, distance: f32) -> usize;
}

/// Full detail: one level.
pub struct FullDetail;

impl LevelRule for FullDetail {
    fn levels(&self) -> usize {
        1
    }
    fn level(&self, _: f32, _: f32) -> usize {
        0
    }
}

/// One model's instance records, grouped by pass then level.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelBuckets {
    /// Instance records (`reserved` = index among the model's instances).
    pub records: Vec<InstanceRecord>,
    /// `ranges[pass][level]`: the records `start..end` that pass draws at that level.
    pub ranges: Vec<Vec<std::ops::Range<u32>>>,
}

impl ModelBuckets {
    /// The instances `pass` draws at `level`.
    pub fn range(&self, pass: usize, level: usize) -> std::ops::Range<u32> {
        self.ranges
            .get(pass)
            .and_then(|p| p.get(level))
            .cloned()
            .unwrap_or(0..0)
    }
}

/// Buckets of every model for the camera (`views[0]`) and the shadow views (`views[1..]`).
/// `spheres[m]`, `rules[m]` and `instances[m]` belong to model m; `eye` is the camera position.
pub fn bucket(
    instances: &[&[InstanceRecord]],
    spheres: &[Sphere],
    rules: &[&dyn LevelRule],
    eye: Vec3,
    views: &[Frustum],
) -> Vec<ModelBuckets> {
    let mut out = Vec::with_capacity(instances.len());
    for ((inst, sphere), rule) in instances.iter().zip(spheres).zip(rules) {
        let levels = rule.levels().max(1);
        // (pass, level) of every drawn copy, then a counting sort into contiguous runs.
        let mut keys: Vec<(u32, u32)> = Vec::new();
        let mut counts = vec![0u32; views.len() * levels];
        for (k, r) in inst.iter().enumerate() {
            let (c, radius) = sphere.placed(r);
            let level = rule
                .level(r.scale.abs(), (c - eye).length())
                .min(levels - 1);
            for (pass, f) in views.iter().enumerate() {
                if f.meets_sphere(c, radius) {
                    keys.push((k as u32, (pass * levels + level) as u32));
                    counts[pass * levels + level] += 1;
                }
            }
        }
        let mut starts = vec![0u32; counts.len() + 1];
        for (i, &n) in counts.iter().enumerate() {
            starts[i + 1] = starts[i] + n;
        }
        let mut fill = starts.clone();
        let mut records = vec![inst.first().copied().unwrap_or(EMPTY); keys.len()];
        for &(k, b) in &keys {
            let mut r = inst[k as usize];
            r.reserved = k;
            records[fill[b as usize] as usize] = r;
            fill[b as usize] += 1;
        }
        let ranges = (0..views.len())
            .map(|p| {
                (0..levels)
                    .map(|l| starts[p * levels + l]..starts[p * levels + l + 1])
                    .collect()
            })
            .collect();
        out.push(ModelBuckets { records, ranges });
    }
    out
}

const EMPTY: InstanceRecord = InstanceRecord {
    position: [0.0; 3],
    scale: 0.0,
    rotation_deg: 0.0,
    model: 0,
    layer: 0,
    reserved: 0,
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera::Camera;

    fn rec(p: [f32; 3], scale: f32, rot: f32) -> InstanceRecord {
        InstanceRecord {
            position: p,
            scale,
            rotation_deg: rot,
            ..EMPTY
        }
    }

    /// Brute-force oracle: a sphere is in view when some point of it projects inside the image
    /// in front of the near plane (sampled densely on and inside the sphere).
    fn sampled_visible(vp: Mat4, c: Vec3, r: f32) -> bool {
        let n = 24;
        for i in 0..=n {
            for j in 0..=2 * n {
                for &rr in &[0.0, 0.5, 1.0] {
                    let th = std::f32::consts::PI * i as f32 / n as f32;
                    let ph = std::f32::consts::PI * j as f32 / n as f32;
                    let d = Vec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                    let q = vp * (c + d * r * rr).extend(1.0);
                    if q.w > 0.0 && q.x.abs() <= q.w && q.y.abs() <= q.w && q.z <= q.w {
                        return true;
                    }
                }
            }
        }
        false
    }

    #[test]
    fn culling_keeps_every_sphere_in_view_and_drops_those_far_outside() {
        let cam = Camera::look_at(Vec3::new(0.0, -20.0, 5.0), Vec3::ZERO, 45.0, 16.0 / 9.0);
        let vp = cam.view_proj();
        let f = Frustum::from_view_proj(vp, false);
        let mut rng = crate::rng::Rng::new(7);
        let (mut kept, mut dropped) = (0, 0);
        for _ in 0..3000 {
            let c = Vec3::new(
                rng.range(-80.0, 80.0),
                rng.range(-60.0, 100.0),
                rng.range(-30.0, 40.0),
            );
            let r = rng.range(0.1, 6.0);
            let inside = sampled_visible(vp, c, r);
            let meets = f.meets_sphere(c, r);
            // Never drop what is visible.
            assert!(!inside || meets, "visible sphere {c} r {r} culled");
            // A sphere whose centre is outside a plane by more than its radius is invisible:
            // the plane test is exact per plane, so a kept invisible sphere must be near a
            // corner of the volume (outside two planes' slabs at once).
            if meets {
                kept += 1;
            } else {
                dropped += 1;
            }
        }
        assert!(
            kept > 100 && dropped > 100,
            "{kept} kept, {dropped} dropped"
        );
    }

    #[test]
    fn placed_spheres_contain_the_placed_vertices() {
        let pts = [[1.0, 2.0, 0.0], [3.0, -1.0, 4.0], [-2.0, 0.5, 1.0]];
        let s = Sphere::around(&pts);
        let r = rec([10.0, -4.0, 2.0], 1.7, 130.0);
        let (c, rad) = s.placed(&r);
        for p in pts {
            let (sn, cs) = r.rotation_deg.to_radians().sin_cos();
            let q = Vec3::from(p) * r.scale;
            let w =
                Vec3::from(r.position) + Vec3::new(cs * q.x - sn * q.y, sn * q.x + cs * q.y, q.z);
            assert!(
                (w - c).length() <= rad * (1.0 + 1e-5),
                "{w} outside {c} r {rad}"
            );
        }
    }

    struct ByDistance;
    impl LevelRule for ByDistance {
        fn levels(&self) -> usize {
            3
        }
        fn level(&self, scale: f32, d: f32) -> usize {
            ((d / scale) / 10.0) as usize
        }
    }

    #[test]
    fn buckets_hold_each_visible_instance_once_per_pass_at_its_level() {
        let cam = Camera::look_at(
            Vec3::new(0.0, -5.0, 1.0),
            Vec3::new(0.0, 10.0, 1.0),
            60.0,
            1.0,
        );
        let views = [
            Frustum::from_view_proj(cam.view_proj(), false),
            // A second view that sees everything.
            Frustum { planes: Vec::new() },
        ];
        let inst: Vec<InstanceRecord> = (0..40)
            .map(|k| rec([0.0, k as f32 * 1.5 - 10.0, 1.0], 1.0, k as f32 * 9.0))
            .collect();
        let sphere = Sphere {
            centre: [0.0; 3],
            radius: 0.5,
        };
        let b = bucket(&[&inst], &[sphere], &[&ByDistance], cam.eye, &views);
        let m = &b[0];
        for pass in 0..2 {
            let mut seen = vec![false; inst.len()];
            for level in 0..3 {
                for r in &m.records
                    [m.range(pass, level).start as usize..m.range(pass, level).end as usize]
                {
                    let k = r.reserved as usize;
                    assert!(!seen[k]);
                    seen[k] = true;
                    assert_eq!(r.position, inst[k].position);
                    let d = (Vec3::from(inst[k].position) - cam.eye).length();
                    assert_eq!(level, ByDistance.level(1.0, d).min(2));
                }
            }
            for (k, s) in seen.iter().enumerate() {
                let (c, r) = sphere.placed(&inst[k]);
                let expect = pass == 1 || views[0].meets_sphere(c, r);
                assert_eq!(*s, expect, "pass {pass} instance {k}");
            }
        }
        // Behind the eye (y < −5) is culled from the camera pass.
        assert!(m.range(0, 0).len() + m.range(0, 1).len() + m.range(0, 2).len() < inst.len());
    }
}
