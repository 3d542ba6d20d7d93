//! Ray tracing: per-model BVHs with alpha-tested triangles ([`bvh`]), the terrain traced through
//! its min/max quadtree ([`heightfield`]), a two-level scene of instanced models on the terrain
//! ([`scene`]), that scene built from a pack ([`pack_scene`]), rays near the sun among its
//! instances without the top level ([`beam`]), the surfaces the tracer sees ([`materials`]),
//! and the shared ray, hit and sampling types.
//!
//! Every query here is pure and single-threaded; batch helpers run queries over rayon and
//! collect in input order, so results never depend on the thread count.

pub mod beam;
pub mod bvh;
#[cfg(feature = "embree")]
pub mod embree;
pub mod heightfield;
pub mod materials;
pub mod pack_scene;
pub mod scene;

pub use beam::SunBeam;
pub use bvh::{AlphaMask, BuildPreset, ModelBvh, SurfacePoint};
#[cfg(feature = "embree")]
pub use embree::EmbreeSceneBvh;
pub use heightfield::{Heightfield, TerrainPoint};
pub use scene::{InstanceTransform, SceneBvh, SceneHit};

use glam::Vec3A;

/// A ray segment: points `origin + t·dir` for `t` in `[tmin, tmax]`.
///
/// `dir` need not be unit length: `t` is in units of `dir` (the two-level scene relies on this
/// to keep `t` unchanged when it maps a ray into a scaled instance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: Vec3A,
    pub dir: Vec3A,
    pub tmin: f32,
    pub tmax: f32,
}

impl Ray {
    /// A ray from `origin` along `dir` with `t` in `[tmin, ∞)`.
    pub fn new(origin: Vec3A, dir: Vec3A, tmin: f32) -> Self {
        Ray {
            origin,
            dir,
            tmin,
            tmax: f32::INFINITY,
        }
    }

    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3A {
        self.origin + self.dir * t
    }

    /// The same ray as obvhs expects it (obvhs uses its own glam version).
    pub(crate) fn to_obvhs(self) -> obvhs::ray::Ray {
        obvhs::ray::Ray::new(
            self.origin.to_array().into(),
            self.dir.to_array().into(),
            self.tmin,
            self.tmax,
        )
    }
}

/// A ray/triangle hit: parameter `t`, the triangle (index into the mesh's triangles), its BVH
/// slot, and the barycentrics: the hit point is `(1 − u − v)·p0 + u·p1 + v·p2`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub triangle: u32,
    /// Position of the triangle in the BVH's leaf order (for [`ModelBvh::hit_point`]).
    pub slot: u32,
    pub u: f32,
    pub v: f32,
}

/// An orthonormal frame around a unit normal (Duff et al. 2017, "Building an Orthonormal Basis,
/// Revisited"): returns tangent and bitangent so that (t, b, n) is right-handed.
pub fn frame(n: Vec3A) -> (Vec3A, Vec3A) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = Vec3A::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = Vec3A::new(b, sign + n.y * n.y * a, -n.y);
    (t, bt)
}

/// Cosine-weighted direction on the hemisphere around unit `n` from `(u1, u2)` in [0, 1)²
/// (Malley's method: a uniform disk point lifted to the hemisphere). pdf = cos θ / π.
pub fn cosine_hemisphere(n: Vec3A, u1: f32, u2: f32) -> Vec3A {
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (s, c) = phi.sin_cos();
    let z = (1.0 - u1).max(0.0).sqrt();
    let (t, b) = frame(n);
    t * (r * c) + b * (r * s) + n * z
}

/// Point k of an N-point spherical Fibonacci set (uniform area, low discrepancy).
pub fn fibonacci_direction(k: u32, n: u32) -> Vec3A {
    let golden = 0.618_033_988_749_894_9f64;
    let z = 1.0 - (2.0 * k as f64 + 1.0) / n as f64;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * ((k as f64 * golden).fract());
    Vec3A::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32)
}

pub use crate::rng::{Rng, mix64};

/// What a path tracer over one model needs of its ray-tracing backend: the closest hit and
/// an any-hit query, both with the alpha test, and the surface at a hit. Implemented by
/// [`ModelBvh`] (obvhs) and, with the cargo feature `embree`, by `embree::EmbreeScene`; the
/// PRT's path loop is generic over it, so one sampler drives every backend.
pub trait ModelTracer: Sync {
    /// The closest opaque hit along the ray segment.
    fn closest_hit(&self, ray: &Ray) -> Option<Hit>;
    /// Whether any opaque hit lies on the ray segment.
    fn any_hit(&self, ray: &Ray) -> bool;
    /// Position, unit geometric normal ((p1 − p0) × (p2 − p0) normalized, zero where the
    /// triangle degenerates) and material at a hit this tracer returned.
    fn hit_point(&self, hit: &Hit) -> (Vec3A, Vec3A, u32);
    /// Axis-aligned bounds of the model's positions (`Mesh::bounds`).
    fn bounds(&self) -> (Vec3A, Vec3A);
}

impl ModelTracer for ModelBvh {
    #[inline]
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        ModelBvh::closest_hit(self, ray)
    }
    #[inline]
    fn any_hit(&self, ray: &Ray) -> bool {
        ModelBvh::any_hit(self, ray)
    }
    #[inline]
    fn hit_point(&self, hit: &Hit) -> (Vec3A, Vec3A, u32) {
        ModelBvh::hit_point(self, hit)
    }
    fn bounds(&self) -> (Vec3A, Vec3A) {
        ModelBvh::bounds(self)
    }
}

/// The ray-tracing backend of the light-map and env-map stages as their options spell it
/// (`lightmap.tracer`, `envmaps.tracer`; the same spelling as `prt.tracer`, which also has
/// `gpu`): `cpu` (obvhs and the heightfield quadtree, every build) or `embree` (Embree 3, builds
/// with the cargo feature `embree` only; elsewhere the option is refused, see
/// [`Tracer::available_as`]). The samplers are the same on every backend, so the outputs agree up
/// to rare float-level differences of the hits; each backend on its own is deterministic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Tracer {
    #[default]
    Cpu,
    Embree,
}

impl Tracer {
    /// The backend's name as options spell it.
    pub fn name(self) -> &'static str {
        match self {
            Tracer::Cpu => "cpu",
            Tracer::Embree => "embree",
        }
    }

    /// A backend as the options and `--tracer` spell it.
    pub fn parse(s: &str) -> std::result::Result<Tracer, String> {
        match s {
            "cpu" => Ok(Tracer::Cpu),
            "embree" => Ok(Tracer::Embree),
            _ => Err(format!("unknown tracer {s:?}: expected cpu or embree")),
        }
    }

    /// Whether this binary can trace on the backend (`embree`: the cargo feature `embree`);
    /// the refusal names the option `key` (`lightmap.tracer`, ...) and the feature.
    pub fn available_as(self, key: &str) -> std::result::Result<(), String> {
        match self {
            Tracer::Cpu => Ok(()),
            Tracer::Embree if cfg!(feature = "embree") => Ok(()),
            Tracer::Embree => Err(format!(
                "{key} = \"embree\" needs a bake built with the cargo feature `embree` \
                 (Debian: apt-get install libembree-dev; then cargo build --release --features \
                 embree); this binary has only tracer = \"cpu\""
            )),
        }
    }
}

/// What the light-map and environment-map stages need of a two-level scene (instances of models
/// plus the terrain as the last instance): the closest hit with some instances ignored, an
/// any-hit query, both alpha-tested, the world-space surface at a hit, and the instances that
/// enclose a point. Implemented by [`SceneBvh`]
/// (obvhs instances and the heightfield quadtree) and, with the cargo feature `embree`, by
/// `embree::EmbreeSceneBvh` (Embree instances of one Embree scene per model, the heightfield as
/// user geometry); the stages' estimators take `&dyn SceneTracer`, so one sampler drives both.
pub trait SceneTracer: Sync + Send {
    /// The model instances (the terrain, if any, is instance number `instances().len()`).
    fn instances(&self) -> &[InstanceTransform];
    /// The closest opaque hit over all instances but those in `skip` (`t` is the world ray's;
    /// `skip` is short: a linear search).
    fn closest_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> Option<SceneHit>;
    /// The closest opaque hit over all instances.
    fn closest_hit(&self, ray: &Ray) -> Option<SceneHit> {
        self.closest_hit_excluding(ray, &[])
    }
    /// Whether any instance blocks the ray segment.
    fn any_hit(&self, ray: &Ray) -> bool;
    /// Whether any instance but those in `skip` blocks the ray segment:
    /// `closest_hit_excluding(ray, skip).is_some()`, where a backend may stop at the first hit
    /// it finds.
    fn any_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> bool {
        self.closest_hit_excluding(ray, skip).is_some()
    }
    /// The model instances other than `own` that enclose the point `p`
    /// ([`SceneBvh::enclosing`]'s rule, decided on the CPU BVH by every backend, so that all
    /// skip the same instances).
    fn enclosing(&self, p: Vec3A, own: u32) -> Vec<u32>;
    /// Whether model instance `k` encloses `p` ([`SceneBvh::instance_encloses`]; the CPU
    /// scene's answer on every backend).
    fn instance_encloses(&self, k: u32, p: Vec3A) -> bool;
    /// The world box of model instance `k` as (min, max) ([`SceneBvh::instance_bounds`]).
    fn instance_bounds(&self, k: u32) -> (Vec3A, Vec3A);
    /// The hit's surface in world space.
    fn surface(&self, hit: &SceneHit) -> SurfacePoint;
}

impl SceneTracer for SceneBvh {
    fn instances(&self) -> &[InstanceTransform] {
        SceneBvh::instances(self)
    }
    #[inline]
    fn closest_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> Option<SceneHit> {
        SceneBvh::closest_hit_excluding(self, ray, skip)
    }
    #[inline]
    fn closest_hit(&self, ray: &Ray) -> Option<SceneHit> {
        SceneBvh::closest_hit(self, ray)
    }
    #[inline]
    fn any_hit(&self, ray: &Ray) -> bool {
        SceneBvh::any_hit(self, ray)
    }
    #[inline]
    fn any_hit_excluding(&self, ray: &Ray, skip: &[u32]) -> bool {
        SceneBvh::any_hit_excluding(self, ray, skip)
    }
    fn enclosing(&self, p: Vec3A, own: u32) -> Vec<u32> {
        SceneBvh::enclosing(self, p, own)
    }
    fn instance_encloses(&self, k: u32, p: Vec3A) -> bool {
        SceneBvh::instance_encloses(self, k, p)
    }
    fn instance_bounds(&self, k: u32) -> (Vec3A, Vec3A) {
        SceneBvh::instance_bounds(self, k)
    }
    #[inline]
    fn surface(&self, hit: &SceneHit) -> SurfacePoint {
        SceneBvh::surface(self, hit)
    }
}

/// A lighting stage's tracer in its key: absent for `cpu` (the keys, and so the cached units,
/// of the CPU backend are those from before the option existed), named otherwise.
pub fn keyed_tracer(o: &mut serde_json::Value, t: Tracer) {
    if t != Tracer::Cpu
        && let Some(m) = o.as_object_mut()
    {
        m.insert("tracer".into(), t.name().into());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal() {
        let mut rng = Rng::hashed(1);
        for _ in 0..1000 {
            let n = Vec3A::new(
                rng.f32() * 2.0 - 1.0,
                rng.f32() * 2.0 - 1.0,
                rng.f32() * 2.0 - 1.0,
            )
            .normalize();
            let (t, b) = frame(n);
            assert!((t.length() - 1.0).abs() < 1e-4);
            assert!((b.length() - 1.0).abs() < 1e-4);
            assert!(t.dot(b).abs() < 1e-4 && t.dot(n).abs() < 1e-4 && b.dot(n).abs() < 1e-4);
            assert!((t.cross(b) - n).length() < 1e-4);
        }
    }

    #[test]
    fn cosine_samples_have_mean_cosine_two_thirds() {
        // E[cos θ] under pdf cos θ/π is 2/3: an independent check of the warp.
        let n = Vec3A::new(0.3, -0.5, 0.8).normalize();
        let mut rng = Rng::hashed(7);
        let k = 200_000;
        let mut sum = 0.0f64;
        for _ in 0..k {
            let d = cosine_hemisphere(n, rng.f32(), rng.f32());
            assert!((d.length() - 1.0).abs() < 1e-4);
            assert!(d.dot(n) >= -1e-6);
            sum += d.dot(n) as f64;
        }
        let mean = sum / k as f64;
        assert!((mean - 2.0 / 3.0).abs() < 3e-3, "{mean}");
    }
}
