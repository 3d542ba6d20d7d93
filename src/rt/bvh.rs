//! Per-model BVH on obvhs (compressed wide BVH8) with alpha-tested triangles.
//!
//! A hit on a texel whose alpha is below 0.5 is no hit: plant leaves are mostly transparent
//! quads (seed 000, 4.5.4). The colour-map alpha is sampled at the interpolated texture
//! coordinate, nearest texel, repeating (the GPU alpha test at 0.5 on the finest mip).
//!
//! Triangles are stored in BVH leaf order ("slots") with precomputed edges for Möller–Trumbore,
//! so a leaf's triangles are contiguous in memory. [`ModelBvh::brute_force_closest_hit`] is the
//! reference implementation (an exhaustive loop with the same triangle test) the tests compare
//! against.

use super::{Hit, Ray};
use crate::error::{Error, Result};
use crate::model::{Mesh, Rgba8Image};
use glam::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use rayon::prelude::*;

/// obvhs build presets, fastest build first. The default was chosen by `bake bench rays`
/// (docs/PERFORMANCE.md, "Ray tracing and PRT").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum BuildPreset {
    Fastest,
    #[default]
    VeryFast,
    Fast,
    Medium,
    Slow,
    VerySlow,
}

impl BuildPreset {
    pub const ALL: [BuildPreset; 6] = [
        BuildPreset::Fastest,
        BuildPreset::VeryFast,
        BuildPreset::Fast,
        BuildPreset::Medium,
        BuildPreset::Slow,
        BuildPreset::VerySlow,
    ];

    pub const fn params(self) -> BvhBuildParams {
        match self {
            BuildPreset::Fastest => BvhBuildParams::fastest_build(),
            BuildPreset::VeryFast => BvhBuildParams::very_fast_build(),
            BuildPreset::Fast => BvhBuildParams::fast_build(),
            BuildPreset::Medium => BvhBuildParams::medium_build(),
            BuildPreset::Slow => BvhBuildParams::slow_build(),
            BuildPreset::VerySlow => BvhBuildParams::very_slow_build(),
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            BuildPreset::Fastest => "fastest",
            BuildPreset::VeryFast => "very-fast",
            BuildPreset::Fast => "fast",
            BuildPreset::Medium => "medium",
            BuildPreset::Slow => "slow",
            BuildPreset::VerySlow => "very-slow",
        }
    }
}

/// One bit per texel: is the texel's alpha at least 0.5 (a ≥ 128 of 255)?
#[derive(Debug, Clone, PartialEq)]
pub struct AlphaMask {
    width: u32,
    height: u32,
    bits: Vec<u64>,
    /// Every texel is opaque: the mask never rejects a hit and is dropped at build time.
    all_opaque: bool,
}

impl AlphaMask {
    /// The alpha-test mask of an RGBA8 image (row 0 at the top, as [`Rgba8Image`] stores it).
    pub fn from_rgba8(img: &Rgba8Image) -> Self {
        let n = img.pixels.len();
        let mut bits = vec![0u64; n.div_ceil(64)];
        for (i, p) in img.pixels.iter().enumerate() {
            if p[3] >= 128 {
                bits[i / 64] |= 1 << (i % 64);
            }
        }
        let all_opaque = img.pixels.iter().all(|p| p[3] >= 128);
        AlphaMask {
            width: img.width.max(1),
            height: img.height.max(1),
            bits,
            all_opaque: all_opaque || n == 0,
        }
    }

    /// Whether the texel under `(u, v)` is opaque: nearest texel, repeating, v = 0 at the top.
    #[inline]
    pub fn opaque_at(&self, u: f32, v: f32) -> bool {
        // `as i64` saturates and maps NaN to 0, so bad coordinates cannot index out of range.
        let x = ((u * self.width as f32).floor() as i64).rem_euclid(self.width as i64) as usize;
        let y = ((v * self.height as f32).floor() as i64).rem_euclid(self.height as i64) as usize;
        let i = y * self.width as usize + x;
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    pub fn is_all_opaque(&self) -> bool {
        self.all_opaque
    }
}

/// A triangle prepared for Möller–Trumbore: `v0`, `e1 = v1 − v0`, `e2 = v2 − v0`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PreTri {
    pub(crate) v0: Vec3A,
    pub(crate) e1: Vec3A,
    pub(crate) e2: Vec3A,
}

/// What a slot (a triangle in leaf order) refers to.
#[derive(Debug, Clone, Copy)]
struct SlotInfo {
    triangle: u32,
    /// Index into `masks`, or `NO_MASK` for opaque triangles.
    mask: u32,
    material: u32,
}

/// Texture coordinates of a slot's triangle: `uv0`, `uv1 − uv0`, `uv2 − uv0`. Kept in slot
/// order beside the triangles so the alpha test of a candidate hit reads memory the traversal
/// has just touched instead of three random vertex loads.
type SlotUv = [[f32; 2]; 3];

const NO_MASK: u32 = u32::MAX;

/// A point on the surface at a hit, with attributes interpolated from the vertices.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    pub position: Vec3A,
    /// Unit normal of the triangle's plane, (p1 − p0) × (p2 − p0) normalized.
    pub geometric_normal: Vec3A,
    /// Interpolated vertex normal, normalized (the geometric normal where it degenerates).
    pub shading_normal: Vec3A,
    pub uv: [f32; 2],
    pub material: u32,
    pub triangle: u32,
}

/// A model's BVH with the geometry it was built from.
#[derive(Debug, Clone)]
pub struct ModelBvh {
    bvh: Option<CwBvh>,
    slots: Vec<PreTri>,
    slot_info: Vec<SlotInfo>,
    slot_uv: Vec<SlotUv>,
    masks: Vec<AlphaMask>,
    positions: Vec<Vec3A>,
    normals: Vec<Vec3A>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<[u32; 3]>,
    triangle_materials: Vec<u32>,
    bounds: (Vec3A, Vec3A),
    skipped: usize,
}

impl ModelBvh {
    /// Builds the BVH of `mesh`. `masks[m]` is the alpha mask of material `m` (`None` or a
    /// missing entry: opaque). Triangles with non-finite positions are left out and counted in
    /// [`ModelBvh::skipped_triangles`].
    pub fn build(mesh: &Mesh, masks: &[Option<AlphaMask>], preset: BuildPreset) -> Result<Self> {
        mesh.validate()
            .map_err(|m| Error::runtime(format!("cannot build a BVH: {m}")))?;
        let finite = |i: u32| mesh.positions[i as usize].iter().all(|c| c.is_finite());
        let kept: Vec<u32> = (0..mesh.indices.len() as u32)
            .filter(|&t| mesh.indices[t as usize].iter().all(|&i| finite(i)))
            .collect();
        let tris: Vec<obvhs::triangle::Triangle> = kept
            .iter()
            .map(|&t| {
                let [a, b, c] = mesh.indices[t as usize];
                obvhs::triangle::Triangle {
                    v0: mesh.positions[a as usize].into(),
                    v1: mesh.positions[b as usize].into(),
                    v2: mesh.positions[c as usize].into(),
                }
            })
            .collect();
        let bvh = (!tris.is_empty()).then(|| {
            obvhs::cwbvh::builder::build_cwbvh_from_tris(
                &tris,
                preset.params(),
                &mut std::time::Duration::default(),
            )
        });
        let mut model = Self::from_mesh(mesh, masks, mesh.indices.len() - kept.len());
        if let Some(b) = &bvh {
            model.fill_slots(&b.primitive_indices, &kept, masks);
        }
        model.bvh = bvh;
        Ok(model)
    }

    fn from_mesh(mesh: &Mesh, masks: &[Option<AlphaMask>], skipped: usize) -> Self {
        let positions: Vec<Vec3A> = mesh.positions.iter().map(|&p| p.into()).collect();
        let (lo, hi) = mesh.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
        ModelBvh {
            bvh: None,
            slots: Vec::new(),
            slot_info: Vec::new(),
            slot_uv: Vec::new(),
            masks: masks.iter().flatten().cloned().collect(),
            positions,
            normals: mesh.normals.iter().map(|&n| n.into()).collect(),
            uvs: mesh.uvs.clone(),
            indices: mesh.indices.clone(),
            triangle_materials: mesh.triangle_materials.clone(),
            bounds: (lo.into(), hi.into()),
            skipped,
        }
    }

    /// Lays the triangles out in leaf order (`order[slot]` indexes `kept`).
    fn fill_slots(&mut self, order: &[u32], kept: &[u32], masks: &[Option<AlphaMask>]) {
        // Material → index into `self.masks` (which holds only the present masks).
        let mut mask_of = Vec::with_capacity(masks.len());
        let mut next = 0u32;
        for m in masks {
            mask_of.push(match m {
                Some(m) if !m.is_all_opaque() => next,
                _ => NO_MASK,
            });
            next += m.is_some() as u32;
        }
        for &k in order {
            let t = kept[k as usize];
            let [a, b, c] = self.indices[t as usize];
            let p = |i: u32| self.positions[i as usize];
            self.slots.push(PreTri {
                v0: p(a),
                e1: p(b) - p(a),
                e2: p(c) - p(a),
            });
            let mat = self.triangle_materials[t as usize];
            self.slot_info.push(SlotInfo {
                triangle: t,
                mask: mask_of.get(mat as usize).copied().unwrap_or(NO_MASK),
                material: mat,
            });
            let uv = |i: u32| self.uvs[i as usize];
            let (ua, ub, uc) = (uv(a), uv(b), uv(c));
            self.slot_uv.push([
                ua,
                [ub[0] - ua[0], ub[1] - ua[1]],
                [uc[0] - ua[0], uc[1] - ua[1]],
            ]);
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Triangles left out of the BVH (non-finite positions).
    pub fn skipped_triangles(&self) -> usize {
        self.skipped
    }

    /// Axis-aligned bounds of the model's positions.
    pub fn bounds(&self) -> (Vec3A, Vec3A) {
        self.bounds
    }

    /// Whether a hit on slot `slot` at barycentrics (u, v) is on an opaque texel.
    #[inline]
    fn opaque(&self, slot: usize, info: SlotInfo, u: f32, v: f32) -> bool {
        if info.mask == NO_MASK {
            return true;
        }
        let [t0, d1, d2] = self.slot_uv[slot];
        let s = t0[0] + u * d1[0] + v * d2[0];
        let t = t0[1] + u * d1[1] + v * d2[1];
        self.masks[info.mask as usize].opaque_at(s, t)
    }

    /// Tests slot `slot` against the ray; a hit on a transparent texel is no hit.
    #[inline]
    fn hit_slot(&self, slot: usize, ray: &Ray, tmax: f32) -> Option<Hit> {
        let (t, u, v) = intersect(&self.slots[slot], ray.origin, ray.dir, ray.tmin, tmax)?;
        let info = self.slot_info[slot];
        self.opaque(slot, info, u, v).then_some(Hit {
            t,
            triangle: info.triangle,
            slot: slot as u32,
            u,
            v,
        })
    }

    /// The closest opaque hit along the ray.
    pub fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let mut best = None;
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray.to_obvhs(), &mut hit, |r, slot| {
            match self.hit_slot(slot, ray, r.tmax) {
                Some(h) if h.t < r.tmax => {
                    best = Some(h);
                    h.t
                }
                _ => f32::INFINITY,
            }
        });
        best
    }

    /// Whether any opaque hit lies on the ray segment (stops at the first one).
    pub fn any_hit(&self, ray: &Ray) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        !bvh.ray_traverse_miss(ray.to_obvhs(), |r, slot| {
            self.hit_slot(slot, ray, r.tmax)
                .map_or(f32::INFINITY, |h| h.t)
        })
    }

    /// Reference closest hit: every triangle, in order, with the same triangle and alpha test.
    pub fn brute_force_closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for slot in 0..self.slots.len() {
            let tmax = best.map_or(ray.tmax, |h| h.t);
            if let Some(h) = self.hit_slot(slot, ray, tmax)
                && h.t < tmax
            {
                best = Some(h);
            }
        }
        best
    }

    /// Closest hits of many rays over rayon, in input order.
    pub fn closest_hits(&self, rays: &[Ray]) -> Vec<Option<Hit>> {
        rays.par_iter().map(|r| self.closest_hit(r)).collect()
    }

    /// Any-hit results of many rays over rayon, in input order.
    pub fn any_hits(&self, rays: &[Ray]) -> Vec<bool> {
        rays.par_iter().map(|r| self.any_hit(r)).collect()
    }

    /// Position, unit geometric normal and material at a hit, from the slot data only (the
    /// fast path for path tracing; [`ModelBvh::surface`] interpolates every attribute).
    #[inline]
    pub fn hit_point(&self, hit: &Hit) -> (Vec3A, Vec3A, u32) {
        let p = &self.slots[hit.slot as usize];
        let position = p.v0 + p.e1 * hit.u + p.e2 * hit.v;
        let ng = p.e1.cross(p.e2).normalize_or_zero();
        (position, ng, self.slot_info[hit.slot as usize].material)
    }

    /// Position, normals, texture coordinate and material at a hit.
    pub fn surface(&self, hit: &Hit) -> SurfacePoint {
        let [a, b, c] = self.indices[hit.triangle as usize];
        let (a, b, c) = (a as usize, b as usize, c as usize);
        let w = 1.0 - hit.u - hit.v;
        let (p0, p1, p2) = (self.positions[a], self.positions[b], self.positions[c]);
        let ng = (p1 - p0).cross(p2 - p0).normalize_or_zero();
        let ns = (self.normals[a] * w + self.normals[b] * hit.u + self.normals[c] * hit.v)
            .try_normalize()
            .unwrap_or(ng);
        let (ta, tb, tc) = (self.uvs[a], self.uvs[b], self.uvs[c]);
        SurfacePoint {
            position: p0 * w + p1 * hit.u + p2 * hit.v,
            geometric_normal: ng,
            shading_normal: ns,
            uv: [
                w * ta[0] + hit.u * tb[0] + hit.v * tc[0],
                w * ta[1] + hit.u * tb[1] + hit.v * tc[1],
            ],
            material: self.triangle_materials[hit.triangle as usize],
            triangle: hit.triangle,
        }
    }

    /// Raw obvhs traversal with obvhs' own triangle test and no alpha: the baseline the
    /// `bench rays` efficiency is measured against. Returns the hit distance.
    pub fn raw_closest_t(&self, tris: &[obvhs::triangle::Triangle], ray: &Ray) -> f32 {
        let Some(bvh) = self.bvh.as_ref() else {
            return f32::INFINITY;
        };
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray.to_obvhs(), &mut hit, |r, slot| tris[slot].intersect(r));
        hit.t
    }

    /// The triangles in slot order as obvhs triangles (for [`ModelBvh::raw_closest_t`]).
    pub fn raw_triangles(&self) -> Vec<obvhs::triangle::Triangle> {
        self.slots
            .iter()
            .map(|p| obvhs::triangle::Triangle {
                v0: p.v0.to_array().into(),
                v1: (p.v0 + p.e1).to_array().into(),
                v2: (p.v0 + p.e2).to_array().into(),
            })
            .collect()
    }
}

/// Möller–Trumbore ray/triangle test (both faces). Returns (t, u, v) for t in [tmin, tmax].
/// Comparisons are written so that NaN never passes.
#[inline(always)]
pub(crate) fn intersect(tri: &PreTri, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
    let p = d.cross(tri.e2);
    let det = tri.e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri.v0;
    let u = s.dot(p) * inv;
    // Written so that NaN fails the test too.
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(tri.e1);
    let v = d.dot(q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = tri.e2.dot(q) * inv;
    (t >= tmin && t <= tmax).then_some((t, u, v))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Material;
    use crate::rt::Rng;

    /// A mesh of `n` random triangles in the unit cube, one material.
    fn random_mesh(n: usize, seed: u64) -> Mesh {
        let mut rng = Rng::new(seed);
        let mut mesh = Mesh {
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        for t in 0..n {
            let c = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
            for _ in 0..3 {
                let p = [
                    c[0] + (rng.next_f32() - 0.5) * 0.2,
                    c[1] + (rng.next_f32() - 0.5) * 0.2,
                    c[2] + (rng.next_f32() - 0.5) * 0.2,
                ];
                mesh.positions.push(p);
                mesh.normals.push([0.0, 0.0, 1.0]);
                mesh.uvs.push([rng.next_f32(), rng.next_f32()]);
            }
            let i = 3 * t as u32;
            mesh.indices.push([i, i + 1, i + 2]);
            mesh.triangle_materials.push(0);
        }
        mesh
    }

    fn random_ray(rng: &mut Rng) -> Ray {
        let o = Vec3A::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 1.4 - 0.2;
        let d = Vec3A::new(
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
        );
        Ray::new(o, d.normalize_or(Vec3A::Z), 0.0)
    }

    /// A checkerboard mask: alpha 255 and 0 alternating over 8×8 texels.
    fn checker() -> AlphaMask {
        let mut img = Rgba8Image {
            width: 8,
            height: 8,
            pixels: vec![[255; 4]; 64],
        };
        for (i, p) in img.pixels.iter_mut().enumerate() {
            if (i % 8 + i / 8) % 2 == 1 {
                p[3] = 0;
            }
        }
        AlphaMask::from_rgba8(&img)
    }

    fn same_hit(a: Option<Hit>, b: Option<Hit>) {
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                assert_eq!(a.t, b.t);
                // Equal t from two triangles is a tie either may win.
                if a.triangle != b.triangle {
                    assert_eq!(a.t, b.t);
                } else {
                    assert_eq!((a.u, a.v), (b.u, b.v));
                }
            }
            _ => panic!("bvh {a:?} vs brute force {b:?}"),
        }
    }

    #[test]
    fn bvh_closest_hit_equals_brute_force_for_every_preset() {
        let mesh = random_mesh(400, 3);
        for preset in BuildPreset::ALL {
            let bvh = ModelBvh::build(&mesh, &[], preset).unwrap();
            let mut rng = Rng::new(11);
            let mut hits = 0;
            for _ in 0..2000 {
                let r = random_ray(&mut rng);
                let (a, b) = (bvh.closest_hit(&r), bvh.brute_force_closest_hit(&r));
                hits += a.is_some() as u32;
                same_hit(a, b);
                assert_eq!(bvh.any_hit(&r), b.is_some());
            }
            assert!(hits > 200, "too few hits to mean anything: {hits}");
        }
    }

    #[test]
    fn alpha_tested_bvh_equals_brute_force() {
        let mesh = random_mesh(300, 5);
        let bvh = ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::default()).unwrap();
        let opaque = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        let mut rng = Rng::new(9);
        let mut differ = 0;
        for _ in 0..2000 {
            let r = random_ray(&mut rng);
            let a = bvh.closest_hit(&r);
            same_hit(a, bvh.brute_force_closest_hit(&r));
            assert_eq!(bvh.any_hit(&r), a.is_some());
            if let Some(h) = a {
                let s = bvh.surface(&h);
                assert!(checker().opaque_at(s.uv[0], s.uv[1]));
            }
            differ += (a != opaque.closest_hit(&r)) as u32;
        }
        assert!(differ > 50, "the mask changed nothing: {differ}");
    }

    #[test]
    fn batched_queries_match_single_queries() {
        let mesh = random_mesh(200, 8);
        let bvh = ModelBvh::build(&mesh, &[Some(checker())], BuildPreset::Fast).unwrap();
        let mut rng = Rng::new(2);
        let rays: Vec<Ray> = (0..500).map(|_| random_ray(&mut rng)).collect();
        let single: Vec<_> = rays.iter().map(|r| bvh.closest_hit(r)).collect();
        assert_eq!(bvh.closest_hits(&rays), single);
        let any: Vec<_> = rays.iter().map(|r| bvh.any_hit(r)).collect();
        assert_eq!(bvh.any_hits(&rays), any);
    }

    #[test]
    fn surface_interpolates_attributes() {
        let mesh = Mesh {
            positions: vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            indices: vec![[0, 1, 2]],
            triangle_materials: vec![0],
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        let bvh = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        let r = Ray::new(Vec3A::new(0.5, 0.25, 3.0), Vec3A::new(0.0, 0.0, -2.0), 0.0);
        let h = bvh.closest_hit(&r).unwrap();
        assert!((h.t - 1.5).abs() < 1e-6, "t is in units of dir");
        let s = bvh.surface(&h);
        assert!((s.position - Vec3A::new(0.5, 0.25, 0.0)).length() < 1e-6);
        assert!((s.uv[0] - 0.25).abs() < 1e-6 && (s.uv[1] - 0.125).abs() < 1e-6);
        assert_eq!(s.geometric_normal, Vec3A::Z);
        let expect = Vec3A::new(0.25, 0.0, 0.75).normalize();
        assert!((s.shading_normal - expect).length() < 1e-6);
        let (p, ng, m) = bvh.hit_point(&h);
        assert!((p - s.position).length() < 1e-6 && ng == s.geometric_normal && m == 0);
        // A segment ending before the triangle misses it.
        let short = Ray { tmax: 1.4, ..r };
        assert!(bvh.closest_hit(&short).is_none() && !bvh.any_hit(&short));
    }

    #[test]
    fn empty_and_non_finite_meshes_do_not_panic() {
        let empty = ModelBvh::build(&Mesh::default(), &[], BuildPreset::default()).unwrap();
        let r = Ray::new(Vec3A::ZERO, Vec3A::Z, 0.0);
        assert!(empty.closest_hit(&r).is_none() && !empty.any_hit(&r));
        let mut mesh = random_mesh(3, 1);
        mesh.positions[0] = [f32::NAN, 0.0, 0.0];
        let bvh = ModelBvh::build(&mesh, &[], BuildPreset::default()).unwrap();
        assert_eq!(bvh.skipped_triangles(), 1);
    }

    #[test]
    fn alpha_mask_samples_nearest_texel_with_repeat() {
        let m = checker();
        assert!(m.opaque_at(0.01, 0.01));
        assert!(!m.opaque_at(0.14, 0.01));
        assert!(m.opaque_at(1.01, -0.99), "repeats in both directions");
        assert!(m.opaque_at(f32::NAN, 0.0), "NaN maps to texel 0, no panic");
        assert!(!m.is_all_opaque());
    }
}
