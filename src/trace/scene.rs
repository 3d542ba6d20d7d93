//! Two-level scene: instances of model BVHs (bottom level) under a BVH over the instances'
//! world bounds (top level), for tracing from one instance into the others (the environment-map
//! stage, seed 000 4.6.3), plus optionally the terrain as a [`Heightfield`] beside the top level.
//!
//! The terrain counts as one more instance, numbered after the model instances: its hits carry
//! the terrain-mesh triangle numbering (see [`Heightfield::closest_hit`]). A closest-hit query
//! traces the terrain first and the top level only up to the terrain's hit: the ground ends most
//! rays that would otherwise traverse far.
//!
//! An instance places its model by `world = translation + scale · Rz(rotation) · local`
//! (ECO: uniform scale, rotation about +Z in degrees). A world ray is mapped into the model with
//! the inverse transform and its direction is *not* renormalized, so the ray parameter `t` is the
//! same in both spaces and hits of different instances compare directly.

use super::bvh::{ModelBvh, PACKET, SurfacePoint};
use super::heightfield::Heightfield;
use super::{Hit, Ray};
use crate::error::{Error, Result};
use glam::{Mat3A, Vec3A};
use obvhs::cwbvh::CwBvh;
use rayon::prelude::*;
use std::sync::Arc;

/// Test rays per candidate of [`SceneBvh::enclosing`].
pub const ENCLOSURE_RAYS: u32 = 64;

/// Where an instance puts its model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceTransform {
    pub model: u32,
    pub translation: [f32; 3],
    pub scale: f32,
    /// Rotation about +Z, degrees (counter-clockwise seen from above).
    pub rotation_deg: f32,
}

impl InstanceTransform {
    /// The transform of a scene instance.
    pub fn from_instance(i: &crate::model::Instance) -> Self {
        InstanceTransform {
            model: i.model,
            translation: i.position,
            scale: i.scale,
            rotation_deg: i.rotation_deg,
        }
    }

    fn rotation(&self) -> Mat3A {
        Mat3A::from_rotation_z(self.rotation_deg.to_radians())
    }

    /// Model-space point to world space.
    pub fn point_to_world(&self, p: Vec3A) -> Vec3A {
        Vec3A::from(self.translation) + self.rotation() * p * self.scale
    }

    /// Model-space normal to world space (uniform scale: a rotation).
    pub fn normal_to_world(&self, n: Vec3A) -> Vec3A {
        self.rotation() * n
    }

    /// A world ray in model space, with the same `t` range.
    pub fn ray_to_local(&self, r: &Ray) -> Ray {
        ToLocal::of(self).ray(r)
    }
}

/// The inverse of an [`InstanceTransform`], computed once: a scene's rays visit each instance
/// many times, and the rotation's sine and cosine were a visible part of the light map's
/// profile. Maps rays to exactly the bits [`InstanceTransform::ray_to_local`] gives.
#[derive(Debug, Clone, Copy)]
struct ToLocal {
    inv_rotation: Mat3A,
    translation: Vec3A,
    inv_scale: f32,
}

impl ToLocal {
    fn of(t: &InstanceTransform) -> Self {
        ToLocal {
            inv_rotation: t.rotation().transpose(),
            translation: Vec3A::from(t.translation),
            inv_scale: 1.0 / t.scale,
        }
    }

    fn ray(&self, r: &Ray) -> Ray {
        Ray {
            origin: self.inv_rotation * (r.origin - self.translation) * self.inv_scale,
            dir: self.inv_rotation * r.dir * self.inv_scale,
            tmin: r.tmin,
            tmax: r.tmax,
        }
    }
}

/// A hit in the scene: which instance, and the hit in its model (`t` is the world ray's `t`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneHit {
    pub instance: u32,
    pub hit: Hit,
}

/// Instances of model BVHs under a top-level BVH.
#[derive(Debug, Clone)]
pub struct SceneBvh {
    models: Vec<Arc<ModelBvh>>,
    instances: Vec<InstanceTransform>,
    /// Each instance's inverse transform (world rays into its model).
    to_local: Vec<ToLocal>,
    /// Each instance's world box ([`world_box`], padded), as the top level holds it.
    boxes: Vec<obvhs::aabb::Aabb>,
    tlas: Option<CwBvh>,
    terrain: Option<Arc<Heightfield>>,
}

impl SceneBvh {
    /// Builds the top level. Fails on an instance that names a missing model or has a
    /// non-positive or non-finite scale.
    pub fn build(models: Vec<Arc<ModelBvh>>, instances: Vec<InstanceTransform>) -> Result<Self> {
        for (k, i) in instances.iter().enumerate() {
            if i.model as usize >= models.len() {
                return Err(Error::runtime(format!(
                    "instance {k} refers to model {} of {}",
                    i.model,
                    models.len()
                )));
            }
            if i.scale <= 0.0 || !i.scale.is_finite() || !i.rotation_deg.is_finite() {
                return Err(Error::runtime(format!(
                    "instance {k}: scale {} / rotation {} is not usable",
                    i.scale, i.rotation_deg
                )));
            }
        }
        let boxes: Vec<obvhs::aabb::Aabb> = instances
            .iter()
            .map(|i| world_box(&models[i.model as usize], i))
            .collect();
        let tlas = (!boxes.is_empty()).then(|| {
            obvhs::cwbvh::builder::build_cwbvh(
                &boxes,
                crate::trace::BuildPreset::Medium.params(),
                &mut std::time::Duration::default(),
            )
        });
        Ok(SceneBvh {
            to_local: instances.iter().map(ToLocal::of).collect(),
            models,
            instances,
            boxes,
            tlas,
            terrain: None,
        })
    }

    /// Adds the terrain, traced as a heightfield; it becomes instance number
    /// `instances().len()`.
    pub fn with_terrain(mut self, terrain: Arc<Heightfield>) -> Self {
        self.terrain = Some(terrain);
        self
    }

    /// The model instances (the heightfield terrain has no transform and is not among them).
    pub fn instances(&self) -> &[InstanceTransform] {
        &self.instances
    }

    /// The instance number of the heightfield terrain, if the scene has one.
    pub fn terrain_instance(&self) -> Option<u32> {
        self.terrain.as_ref().map(|_| self.instances.len() as u32)
    }

    /// The terrain's closest hit unless it is skipped.
    fn terrain_hit(&self, ray: &Ray, skip: &[u32]) -> Option<SceneHit> {
        let instance = self.terrain_instance()?;
        if skip.contains(&instance) {
            return None;
        }
        let hit = self.terrain.as_ref()?.closest_hit(ray)?;
        Some(SceneHit { instance, hit })
    }

    /// The closest opaque hit over all instances.
    pub fn closest_hit(&self, ray: &Ray) -> Option<SceneHit> {
        self.closest_hit_excluding(ray, &[])
    }

    /// The closest opaque hit over all instances but those in `skip` (tracing from an instance
    /// into the rest of the scene: the environment-map stage ignores the instance itself and
    /// the instances that enclose its probe; the light map ignores the terrain).
    pub fn closest_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> Option<SceneHit> {
        let mut best = self.terrain_hit(ray, skip);
        let Some(tlas) = self.tlas.as_ref() else {
            return best;
        };
        let bounded = Ray {
            tmax: best.map_or(ray.tmax, |b| b.hit.t),
            ..*ray
        };
        let mut hit = obvhs::ray::RayHit::none();
        tlas.ray_traverse(bounded.to_obvhs(), &mut hit, |r, slot| {
            let k = tlas.primitive_indices[slot];
            if skip.contains(&k) {
                return f32::INFINITY;
            }
            let inst = &self.instances[k as usize];
            let local = Ray {
                tmax: r.tmax,
                ..self.to_local[k as usize].ray(ray)
            };
            match self.models[inst.model as usize].closest_hit(&local) {
                Some(h) if h.t < r.tmax => {
                    best = Some(SceneHit {
                        instance: k,
                        hit: h,
                    });
                    h.t
                }
                _ => f32::INFINITY,
            }
        });
        best
    }

    /// Whether any instance blocks the ray segment.
    pub fn any_hit(&self, ray: &Ray) -> bool {
        if self.terrain.as_ref().is_some_and(|t| t.any_hit(ray)) {
            return true;
        }
        let Some(tlas) = self.tlas.as_ref() else {
            return false;
        };
        !tlas.ray_traverse_miss(ray.to_obvhs(), |_, slot| {
            let k = tlas.primitive_indices[slot] as usize;
            let model = &self.models[self.instances[k].model as usize];
            let blocked = model.any_hit(&self.to_local[k].ray(ray));
            if blocked { ray.tmin } else { f32::INFINITY }
        })
    }

    /// Whether any instance but those in `skip` blocks the ray segment (the terrain is the
    /// instance after the models'): the answer of [`Self::closest_hit_excluding`], stopping at
    /// the first hit found (the light map's sun rays among the instances; issue 37).
    pub fn any_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> bool {
        if self.terrain_instance().is_some_and(|t| !skip.contains(&t))
            && self.terrain.as_ref().is_some_and(|t| t.any_hit(ray))
        {
            return true;
        }
        let Some(tlas) = self.tlas.as_ref() else {
            return false;
        };
        !tlas.ray_traverse_miss(ray.to_obvhs(), |_, slot| {
            let k = tlas.primitive_indices[slot];
            if skip.contains(&k) {
                return f32::INFINITY;
            }
            let model = &self.models[self.instances[k as usize].model as usize];
            let blocked = model.any_hit(&self.to_local[k as usize].ray(ray));
            if blocked { ray.tmin } else { f32::INFINITY }
        })
    }

    /// The model instances whose world box (the top level's, padded by a relative 1e-5)
    /// contains `p`, in ascending order: the candidates of [`Self::enclosing`].
    pub fn instances_containing(&self, p: Vec3A) -> Vec<u32> {
        let Some(tlas) = self.tlas.as_ref() else {
            return Vec::new();
        };
        // The top level's leaves along a 2 m segment through `p` (obvhs' traversal has no point
        // query this crate can call: its macro needs obvhs' glam version), each checked exactly.
        let d = Vec3A::ONE.normalize();
        let segment = Ray {
            tmax: 2.0,
            ..Ray::new(p - d, d, 0.0)
        };
        let q = Ray::new(p, d, 0.0).to_obvhs().origin;
        let mut out = Vec::new();
        tlas.ray_traverse_anyhit(segment.to_obvhs(), |_, slot| {
            let k = tlas.primitive_indices[slot];
            if self.boxes[k as usize].contains_point(q) {
                out.push(k);
            }
        });
        out.sort_unstable();
        out.dedup();
        out
    }

    /// Whether instance `k`'s model alone blocks the ray segment (alpha-tested; `k` a model
    /// instance): the test [`Self::any_hit_excluding`] makes of each instance its top level
    /// reaches; the beam's tests' brute force.
    #[cfg(test)]
    pub(crate) fn instance_any_hit(&self, k: u32, ray: &Ray) -> bool {
        let model = &self.models[self.instances[k as usize].model as usize];
        model.any_hit(&self.to_local[k as usize].ray(ray))
    }

    /// Whether instance `k`'s model alone blocks each ray segment (`blocked[i]` for `rays[i]`;
    /// alpha-tested; `k` a model instance), for [`super::beam::SunBeam`]: the test
    /// [`Self::any_hit_excluding`] makes of each instance its top level reaches, the rays
    /// mapped into the model as it maps them, answered by one packet walk of the model's BVH
    /// ([`ModelBvh::any_hits_packet`], the same booleans as `ModelBvh::any_hit` per ray).
    ///
    /// Panics if the two slices' lengths differ.
    pub(crate) fn instance_any_hits(&self, k: u32, rays: &[Ray], blocked: &mut [bool]) {
        assert_eq!(rays.len(), blocked.len(), "one answer per ray");
        let model = &self.models[self.instances[k as usize].model as usize];
        let to_local = &self.to_local[k as usize];
        for (rays, blocked) in rays.chunks(PACKET).zip(blocked.chunks_mut(PACKET)) {
            let mut local = [Ray::new(Vec3A::ZERO, Vec3A::Z, 0.0); PACKET];
            for (l, r) in local.iter_mut().zip(rays) {
                *l = to_local.ray(r);
            }
            model.any_hits_packet(&local[..rays.len()], blocked);
        }
    }

    /// The closest opaque hit of instance `k` alone (a model instance, not the terrain).
    pub fn instance_hit(&self, ray: &Ray, k: u32) -> Option<SceneHit> {
        let inst = self.instances.get(k as usize)?;
        let local = self.to_local[k as usize].ray(ray);
        let hit = self.models[inst.model as usize].closest_hit(&local)?;
        Some(SceneHit { instance: k, hit })
    }

    /// The model instances other than `own` that enclose the point `p`, in ascending order:
    /// those whose world box contains `p` and for which, of the [`ENCLOSURE_RAYS`] test rays
    /// from `p` (a fixed spherical Fibonacci set) traced against that instance alone with its
    /// alpha test, those whose first hit is a back face outnumber those whose first hit is a
    /// front face by at least half the rays. A face's side is its winding's (the geometric
    /// normal), turned to the interpolated vertex normal's side where the two disagree, as path
    /// tracers orient it; a back face points away from `p` (n·d > 0). A hit on an alpha-tested
    /// material (a leaf card: see-through foliage shelters, it never encloses) counts as a
    /// front face whichever way it faces: foliage normals are often bent outwards or up, which
    /// would make a canopy look like a closed shell from inside.
    ///
    /// Inside a closed mesh every ray meets a back face first (difference 1); inside a house
    /// open at the bottom most do (0.69 low in it, 0.88 at mid-height); under a shed's roof
    /// (a roof on two walls) 0.42, beside or under a mesh none; among opaque cards wound either
    /// way back and front about cancel. It is a ray estimate of the generalized winding number,
    /// robust to open and two-sided geometry. The environment maps' probes ignore these
    /// instances (docs/CONVENTIONS.md, "Environment-map probes").
    pub fn enclosing(&self, p: Vec3A, own: u32) -> Vec<u32> {
        self.instances_containing(p)
            .into_iter()
            .filter(|&k| k != own && self.encloses(k, p))
            .collect()
    }

    /// Whether model instance `k` encloses `p` by the rule of [`Self::enclosing`] (its world
    /// box holds `p`, then the test rays): `k` is in `enclosing(p, j)` for any `j != k` exactly
    /// when this holds.
    pub fn instance_encloses(&self, k: u32, p: Vec3A) -> bool {
        let q = Ray::new(p, Vec3A::Z, 0.0).to_obvhs().origin;
        self.boxes
            .get(k as usize)
            .is_some_and(|b| b.contains_point(q))
            && self.encloses(k, p)
    }

    /// The world box of model instance `k` (the top level's, padded), as (min, max).
    pub fn instance_bounds(&self, k: u32) -> (Vec3A, Vec3A) {
        let b = &self.boxes[k as usize];
        (Vec3A::from(b.min.to_array()), Vec3A::from(b.max.to_array()))
    }

    /// Whether instance `k` encloses `p` by the test rays of [`Self::enclosing`].
    fn encloses(&self, k: u32, p: Vec3A) -> bool {
        let (back, front) = self.faces_seen(k, p);
        2 * (back as i64 - front as i64) >= ENCLOSURE_RAYS as i64
    }

    /// How many of the test rays of [`Self::enclosing`] from `p` first meet a back face of
    /// instance `k`, and how many a front face.
    fn faces_seen(&self, k: u32, p: Vec3A) -> (u32, u32) {
        let (mut back, mut front) = (0, 0);
        for j in 0..ENCLOSURE_RAYS {
            let d = crate::trace::fibonacci_direction(j, ENCLOSURE_RAYS);
            if let Some(h) = self.instance_hit(&Ray::new(p, d, 0.0), k) {
                let surf = self.surface(&h);
                let model = &self.models[self.instances[k as usize].model as usize];
                // The triangle's side by its winding, turned to the interpolated vertex
                // normal's side where the two disagree (as path tracers orient it); an
                // alpha-tested card is a front face whichever way it faces.
                let n = surf.geometric_normal;
                let n = if n.dot(surf.shading_normal) < 0.0 {
                    -n
                } else {
                    n
                };
                if n.dot(d) > 0.0 && !model.alpha_tested(surf.material) {
                    back += 1;
                } else {
                    front += 1;
                }
            }
        }
        (back, front)
    }

    /// Reference: every instance in turn, without the top level.
    pub fn brute_force_closest_hit(&self, ray: &Ray) -> Option<SceneHit> {
        let mut best: Option<SceneHit> = self.terrain_hit(ray, &[]);
        for (k, inst) in self.instances.iter().enumerate() {
            let local = Ray {
                tmax: best.map_or(ray.tmax, |b| b.hit.t),
                ..inst.ray_to_local(ray)
            };
            if let Some(h) = self.models[inst.model as usize].closest_hit(&local) {
                best = Some(SceneHit {
                    instance: k as u32,
                    hit: h,
                });
            }
        }
        best
    }

    /// Closest hits of many rays over rayon, in input order.
    pub fn closest_hits(&self, rays: &[Ray]) -> Vec<Option<SceneHit>> {
        rays.par_iter().map(|r| self.closest_hit(r)).collect()
    }

    /// The hit's surface in world space.
    pub fn surface(&self, h: &SceneHit) -> SurfacePoint {
        surface_of(&self.models, &self.instances, self.terrain.as_deref(), h)
    }

    /// The model BVHs (for another backend built from the same scene).
    pub fn models(&self) -> &[Arc<ModelBvh>] {
        &self.models
    }

    /// The heightfield terrain, if any.
    pub fn terrain(&self) -> Option<&Arc<Heightfield>> {
        self.terrain.as_ref()
    }
}

/// A scene hit's surface in world space: the terrain's (instance number `instances.len()`) or
/// the instance's model surface transformed; shared by every [`super::SceneTracer`].
pub(crate) fn surface_of(
    models: &[Arc<ModelBvh>],
    instances: &[InstanceTransform],
    terrain: Option<&Heightfield>,
    h: &SceneHit,
) -> SurfacePoint {
    if let Some(t) = terrain
        && h.instance as usize == instances.len()
    {
        return t.surface(&h.hit);
    }
    let inst = &instances[h.instance as usize];
    let s = models[inst.model as usize].surface(&h.hit);
    SurfacePoint {
        position: inst.point_to_world(s.position),
        geometric_normal: inst.normal_to_world(s.geometric_normal),
        shading_normal: inst.normal_to_world(s.shading_normal),
        ..s
    }
}

/// World bounds of an instance: its model's box corners transformed.
fn world_box(model: &ModelBvh, inst: &InstanceTransform) -> obvhs::aabb::Aabb {
    let (lo, hi) = model.bounds();
    let mut wlo = Vec3A::splat(f32::INFINITY);
    let mut whi = Vec3A::splat(f32::NEG_INFINITY);
    for c in 0..8 {
        let p = Vec3A::select(
            glam::BVec3A::new(c & 1 != 0, c & 2 != 0, c & 4 != 0),
            hi,
            lo,
        );
        let w = inst.point_to_world(p);
        wlo = wlo.min(w);
        whi = whi.max(w);
    }
    // Pad by a relative epsilon so rounding in the transform never clips a surface.
    let pad = (whi - wlo).max_element() * 1e-5 + 1e-6;
    obvhs::aabb::Aabb::new((wlo - pad).to_array().into(), (whi + pad).to_array().into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, Mesh};
    use crate::trace::{BuildPreset, Rng};

    fn blob(seed: u64, n: usize) -> Mesh {
        let mut rng = Rng::hashed(seed);
        let mut m = Mesh {
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        for t in 0..n as u32 {
            let c = [rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() * 2.0];
            for _ in 0..3 {
                m.positions.push([
                    c[0] + rng.f32() * 0.3,
                    c[1] + rng.f32() * 0.3,
                    c[2] + rng.f32() * 0.3,
                ]);
                m.normals.push([0.0, 0.0, 1.0]);
                m.uvs.push([0.0, 0.0]);
            }
            m.indices.push([3 * t, 3 * t + 1, 3 * t + 2]);
            m.triangle_materials.push(0);
        }
        m
    }

    fn scene() -> (SceneBvh, Vec<Mesh>) {
        let meshes = vec![blob(1, 60), blob(2, 90)];
        let models = meshes
            .iter()
            .map(|m| Arc::new(ModelBvh::build(m, &[], BuildPreset::Fast).unwrap()))
            .collect();
        let mut rng = Rng::hashed(4);
        let instances = (0..30)
            .map(|k| InstanceTransform {
                model: k % 2,
                translation: [rng.f32() * 10.0, rng.f32() * 10.0, 0.0],
                scale: 0.5 + rng.f32() * 2.0,
                rotation_deg: rng.f32() * 360.0,
            })
            .collect();
        (SceneBvh::build(models, instances).unwrap(), meshes)
    }

    #[test]
    fn top_level_equals_instance_loop() {
        let (s, _) = scene();
        let mut rng = Rng::hashed(5);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = Vec3A::new(
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 3.0,
            );
            let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
            let r = Ray::new(o, d.normalize_or(Vec3A::X), 0.0);
            let (a, b) = (s.closest_hit(&r), s.brute_force_closest_hit(&r));
            assert_eq!(a.map(|h| h.hit.t), b.map(|h| h.hit.t));
            assert_eq!(s.any_hit(&r), a.is_some());
            hits += a.is_some() as u32;
        }
        assert!(hits > 300, "{hits}");
    }

    #[test]
    fn instance_hit_equals_flattened_world_mesh() {
        // Oracle: the model transformed into world space by hand and traced directly.
        let (s, meshes) = scene();
        let inst = s.instances()[7];
        let mut world = meshes[inst.model as usize].clone();
        for p in &mut world.positions {
            *p = inst.point_to_world(Vec3A::from(*p)).to_array();
        }
        let flat = ModelBvh::build(&world, &[], BuildPreset::Fast).unwrap();
        let only = SceneBvh::build(s.models.clone(), vec![inst]).unwrap();
        let mut rng = Rng::hashed(6);
        let (c, _) = flat.bounds();
        let mut checked = 0;
        for _ in 0..2000 {
            let target = c + Vec3A::new(rng.f32(), rng.f32(), rng.f32()) * 2.0;
            let o = target + Vec3A::new(3.0, -2.0, 4.0) * (rng.f32() + 0.5);
            let r = Ray::new(o, (target - o).normalize(), 0.0);
            let (a, b) = (only.closest_hit(&r), flat.closest_hit(&r));
            if let (Some(a), Some(b)) = (a, b) {
                assert!((a.hit.t - b.t).abs() < 1e-3 * b.t.max(1.0), "{a:?} {b:?}");
                let sa = only.surface(&a);
                let sb = flat.surface(&b);
                assert!((sa.position - sb.position).length() < 1e-3);
                assert!((sa.geometric_normal - sb.geometric_normal).length() < 1e-3);
                checked += 1;
            } else {
                // Only a ray grazing an edge may disagree; none do with these seeds.
                assert_eq!(a.is_some(), b.is_some(), "{r:?}");
            }
        }
        assert!(checked > 100, "{checked}");
    }

    /// A rough terrain under the instances of [`scene`] (they stand on z = 0..2).
    fn ground() -> crate::model::Terrain {
        let mut rng = Rng::hashed(12);
        let (w, h) = (23u32, 19u32);
        crate::model::Terrain {
            width: w,
            height: h,
            heights: (0..w * h).map(|_| rng.f32() * 1.5 - 0.5).collect(),
            origin: [-2.0, -1.5],
            extent: [14.0, 13.0],
            color: None,
        }
    }

    #[test]
    fn heightfield_terrain_equals_terrain_mesh_instance() {
        // Oracle: the same scene with the terrain as a triangle-mesh instance (the switch kept
        // in `pack_scene`); the terrain is the last instance in both.
        let (s, _) = scene();
        let t = ground();
        let hf = Arc::new(crate::trace::Heightfield::new(&t).unwrap());
        let with_hf = s.clone().with_terrain(hf);
        let mut models = s.models.clone();
        let mesh = crate::trace::pack_scene::terrain_mesh(&t);
        models.push(Arc::new(
            ModelBvh::build(&mesh, &[], BuildPreset::Fast).unwrap(),
        ));
        let mut instances = s.instances().to_vec();
        instances.push(InstanceTransform {
            model: (models.len() - 1) as u32,
            translation: [0.0; 3],
            scale: 1.0,
            rotation_deg: 0.0,
        });
        let with_mesh = SceneBvh::build(models, instances).unwrap();
        assert_eq!(with_hf.terrain_instance(), Some(30));
        let mut rng = Rng::hashed(13);
        let mut terrain_hits = 0;
        for _ in 0..3000 {
            let o = Vec3A::new(
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 4.0 - 0.5,
            );
            let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
            let r = Ray::new(o, d.normalize_or(Vec3A::X), 1e-4);
            let (a, b) = (with_hf.closest_hit(&r), with_mesh.closest_hit(&r));
            assert_eq!(
                a.map(|h| (h.hit.t, h.instance)),
                b.map(|h| (h.hit.t, h.instance))
            );
            assert_eq!(
                with_hf.brute_force_closest_hit(&r).map(|h| h.hit.t),
                a.map(|h| h.hit.t)
            );
            assert_eq!(with_hf.any_hit(&r), a.is_some());
            if let (Some(a), Some(b)) = (a, b) {
                let (sa, sb) = (with_hf.surface(&a), with_mesh.surface(&b));
                assert!((sa.position - sb.position).length() < 1e-4);
                terrain_hits += (a.instance == 30) as u32;
            }
            // Skipping the terrain leaves the instances only.
            let skipped = with_hf.closest_hit_excluding(&r, &[30]);
            assert_eq!(skipped.map(|h| h.hit.t), s.closest_hit(&r).map(|h| h.hit.t));
        }
        assert!(terrain_hits > 500, "{terrain_hits}");
    }

    /// The any-hit query with one instance skipped (the light map's sun rays among the
    /// instances) against the brute-force loop over every instance but the skipped one, on
    /// bounded and unbounded rays, skipping the terrain, an instance, or nothing.
    #[test]
    fn any_hit_excluding_equals_brute_force_without_the_skipped_instance() {
        let (s, _) = scene();
        let hf = Arc::new(crate::trace::Heightfield::new(&ground()).unwrap());
        let with_hf = s.clone().with_terrain(hf);
        let mut rng = Rng::hashed(21);
        let (mut blocked, mut open) = (0, 0);
        for i in 0..3000 {
            let o = Vec3A::new(
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 4.0 - 0.5,
            );
            let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
            let mut r = Ray::new(o, d.normalize_or(Vec3A::X), 1e-4);
            if i % 2 == 0 {
                r.tmax = rng.f32() * 6.0;
            }
            let skip = match i % 3 {
                0 => Some(30),
                1 => Some(i as u32 % 30),
                _ => None,
            };
            // Oracle: every instance but `skip` in turn, and the terrain unless skipped.
            let mut want = skip != Some(30)
                && with_hf
                    .terrain
                    .as_ref()
                    .unwrap()
                    .brute_force_closest_hit(&r)
                    .is_some();
            for (k, inst) in with_hf.instances().iter().enumerate() {
                if Some(k as u32) != skip {
                    let local = Ray {
                        tmax: r.tmax,
                        ..inst.ray_to_local(&r)
                    };
                    want |= with_hf.models[inst.model as usize]
                        .brute_force_closest_hit(&local)
                        .is_some();
                }
            }
            assert_eq!(
                with_hf.any_hit_excluding(&r, skip.as_slice()),
                want,
                "{r:?} {skip:?}"
            );
            assert_eq!(
                with_hf.closest_hit_excluding(&r, skip.as_slice()).is_some(),
                want,
                "{r:?} {skip:?}"
            );
            if want {
                blocked += 1;
            } else {
                open += 1;
            }
        }
        assert!(blocked > 300 && open > 300, "{blocked} {open}");
    }

    #[test]
    fn box_faces_are_wound_outwards() {
        let m = crate::fixtures::box_faces([-1.0; 3], [1.0; 3], [true; 6]);
        for t in &m.indices {
            let [a, b, c] = t.map(|k| Vec3A::from(m.positions[k as usize]));
            let n = (b - a).cross(c - a).normalize();
            assert!((n - Vec3A::from(m.normals[t[0] as usize])).length() < 1e-6);
            assert!(n.dot((a + b + c) / 3.0) > 0.0, "outward");
        }
    }

    /// The instances around a point, by the rule of [`SceneBvh::enclosing`], against what each
    /// model is: a closed house, a house open at the bottom, a shed (a roof on two walls, open
    /// on two sides), a canopy of two-sided cards (random triangles, each wound either way).
    #[test]
    fn enclosing_finds_the_instances_around_a_point_and_no_others() {
        let house = crate::fixtures::box_faces([-1.5, -1.0, 0.0], [1.5, 1.0, 2.5], [true; 6]);
        let open = crate::fixtures::box_faces(
            [-1.5, -1.0, 0.0],
            [1.5, 1.0, 2.5],
            [false, true, true, true, true, true],
        );
        let shed = crate::fixtures::box_faces(
            [-1.5, -1.0, 0.0],
            [1.5, 1.0, 2.5],
            [false, true, true, false, true, false],
        );
        // Opaque cards wound either way, each with its own normal.
        let mut canopy = blob(3, 400);
        for (k, t) in canopy.indices.iter_mut().enumerate() {
            if k % 2 == 0 {
                t.swap(1, 2);
            }
            let [a, b, c] = t.map(|i| Vec3A::from(canopy.positions[i as usize]));
            let n = (b - a).cross(c - a).normalize_or(Vec3A::Z).to_array();
            for i in *t {
                canopy.normals[i as usize] = n;
            }
        }
        // Alpha-tested leaf cards whose normals all point up (as foliage often has them).
        let mut leaves = blob(3, 400);
        for (uv, q) in leaves.uvs.iter_mut().zip(&leaves.positions) {
            *uv = [q[0] * 7.0, q[1] * 7.0 + q[2] * 3.0];
        }
        let mut checker = crate::model::Rgba8Image {
            width: 2,
            height: 2,
            pixels: vec![[255; 4]; 4],
        };
        checker.pixels[1][3] = 0;
        let leaf_mask = [Some(crate::trace::AlphaMask::from_rgba8(&checker))];
        let build = |m: &Mesh, masks: &[Option<crate::trace::AlphaMask>]| {
            Arc::new(ModelBvh::build(m, masks, BuildPreset::Fast).unwrap())
        };
        let models = vec![
            build(&house, &[]),
            build(&open, &[]),
            build(&shed, &[]),
            build(&canopy, &[]),
            build(&leaves, &leaf_mask),
        ];
        let at = |model, t: [f32; 3], r| InstanceTransform {
            model,
            translation: t,
            scale: 1.0,
            rotation_deg: r,
        };
        let s = SceneBvh::build(
            models,
            vec![
                at(0, [0.0, 0.0, 0.0], 30.0),  // 0: closed house
                at(0, [0.5, 0.3, 0.0], 200.0), // 1: a second house overlapping it
                at(1, [10.0, 0.0, 0.0], 0.0),  // 2: open at the bottom
                at(2, [20.0, 0.0, 0.0], 0.0),  // 3: shed
                at(3, [30.0, 0.0, 0.0], 0.0),  // 4: canopy (spans x ±0.5, y ±0.5, z 0..2.3)
                at(0, [40.0, 0.0, 0.0], 0.0),  // 5: a house alone
                at(4, [50.0, 0.0, 0.0], 0.0),  // 6: leaf cards facing up
            ],
        )
        .unwrap();
        let p = |x, y, z| Vec3A::new(x, y, z);
        // Every ray from inside a closed house meets its back faces.
        assert_eq!(s.faces_seen(0, p(0.2, 0.1, 1.25)), (ENCLOSURE_RAYS, 0));
        // Inside both overlapping houses: each encloses the other's probe, not its own.
        assert_eq!(s.enclosing(p(0.2, 0.1, 1.25), 0), vec![1]);
        assert_eq!(s.enclosing(p(0.2, 0.1, 1.25), 1), vec![0]);
        assert_eq!(s.enclosing(p(0.2, 0.1, 1.25), 99), vec![0, 1]);
        // A post's probe (1.5 m up) inside the house open at the bottom, low and high.
        assert_eq!(s.enclosing(p(10.8, 0.5, 1.5), 99), vec![2]);
        assert_eq!(s.enclosing(p(9.0, -0.5, 0.3), 99), vec![2]);
        // Inside the shed's box, under its roof, but open to two sides: not enclosed.
        assert_eq!(s.instances_containing(p(20.5, 0.0, 1.0)), vec![3]);
        assert!(s.enclosing(p(20.5, 0.0, 1.0), 99).is_empty());
        // Among the canopies' cards: not enclosed.
        for z in [0.5, 1.0, 1.5] {
            for (k, x) in [(4, 30.3), (6, 50.3)] {
                assert_eq!(s.instances_containing(p(x, 0.3, z)), vec![k]);
                assert!(s.enclosing(p(x, 0.3, z), 99).is_empty(), "{k} {z}");
            }
        }
        // Beside, above and under the lone house: not enclosed.
        for q in [p(41.6, 0.0, 1.0), p(40.0, 0.0, 2.6), p(40.0, 0.0, -0.1)] {
            assert!(s.enclosing(q, 99).is_empty(), "{q}");
        }
        assert_eq!(s.enclosing(p(40.0, 0.0, 1.0), 99), vec![5]);
        assert!(s.enclosing(p(40.0, 0.0, 1.0), 5).is_empty());
        // One instance at a time (the env maps' inverse relation) answers as the whole query.
        let mut rng = Rng::hashed(41);
        for _ in 0..400 {
            let q = p(
                rng.f32() * 56.0 - 3.0,
                rng.f32() * 4.0 - 2.0,
                rng.f32() * 3.0,
            );
            let all = s.enclosing(q, 99);
            for k in 0..s.instances().len() as u32 {
                assert_eq!(s.instance_encloses(k, q), all.contains(&k), "{k} {q}");
            }
        }
    }

    /// The top level's point query against a loop over every instance's world box.
    #[test]
    fn instances_containing_equals_a_loop_over_the_boxes() {
        let (s, _) = scene();
        let mut rng = Rng::hashed(31);
        let mut found = 0;
        for _ in 0..3000 {
            let q = Vec3A::new(
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 12.0 - 1.0,
                rng.f32() * 5.0 - 0.5,
            );
            let want: Vec<u32> = (0..s.instances().len() as u32)
                .filter(|&k| {
                    let b = world_box(
                        &s.models[s.instances[k as usize].model as usize],
                        &s.instances[k as usize],
                    );
                    let (lo, hi) = (Vec3A::from(b.min.to_array()), Vec3A::from(b.max.to_array()));
                    q.cmpge(lo).all() && q.cmple(hi).all()
                })
                .collect();
            assert_eq!(s.instances_containing(q), want, "{q}");
            found += want.len();
        }
        assert!(found > 500, "{found}");
    }

    #[test]
    fn bad_instances_are_rejected() {
        let (s, _) = scene();
        let bad = InstanceTransform {
            model: 9,
            translation: [0.0; 3],
            scale: 1.0,
            rotation_deg: 0.0,
        };
        assert!(SceneBvh::build(s.models.clone(), vec![bad]).is_err());
        let bad = InstanceTransform {
            model: 0,
            scale: 0.0,
            ..bad
        };
        assert!(SceneBvh::build(s.models.clone(), vec![bad]).is_err());
    }
}
