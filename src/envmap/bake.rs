//! Per-instance environment maps (seed 000, 4.6.3): for every instance, SH order 4 RGB of the
//! light arriving at the instance from the sky without the sun (C_H) and from the sun (C_S), with
//! the terrain and the other instances occluding and reflecting; the instance itself is ignored,
//! and so is every instance that encloses the probe ([`crate::trace::SceneBvh::enclosing`]: a
//! probe inside another instance, such as a post inside a house or two houses overlapping,
//! would otherwise see only that instance's inside) and every instance whose probe the instance
//! encloses (the post inside the house, hidden from the house's outside by its walls); the hit
//! points' sun rays ignore them too, so the probe sees the scene without them; where the
//! instance's model encloses its own footprint (a house), a hit inside the instance's box is lit
//! as if the instance were absent (docs/CONVENTIONS.md, "Environment-map probes").
//!
//! Estimator (instead of the thesis' photon map): from a probe point at the instance (its position
//! raised by half its model's height × scale), `samples` directions on a spherical Fibonacci set
//! rotated by a per-instance random rotation (deterministic: seeded by the instance index) are
//! traced into the two-level scene; each is weighted 4π/N.
//!
//! Noise estimate (issue 20, item 2; option `noise_estimate`, on by default): the N rays are
//! traced as two independent halves, each a ⌈N/2⌉- or ⌊N/2⌋-point spherical Fibonacci set with
//! its own random rotation (independent: the difference of two halves of one low-discrepancy set
//! would not estimate the full set's error). The map is the ray-count-weighted mean of the two
//! half estimates A and B (each weighted 4π/N per ray, so it is the same sum as one N-ray set),
//! and the difference D = A − B (world frame) gives the noise covariance of the mean,
//! E[D Dᵀ]/4, at no extra ray cost (`super::envmaps_section` sums it over all instances).
//! - A ray that escapes sees the sun-free sky: C_H += L_sky(d)·y(d)·4π/N.
//! - A ray that hits a surface with albedo ρ and normal n (facing the ray) sees its outgoing
//!   diffuse radiance: the sun's part ρ/π·E_sun·max(0, n·s)·V_sun(x) goes to C_S, the sky's part
//!   ρ/π·E_sky(n) (the sky's unoccluded irradiance, one bounce) to C_H.
//! - The sun's direct light is not in C_S: C_S is the sun's *indirect* light, reflected once by the
//!   terrain and the other instances. The direct sun (and its bounces inside the plant, PRT's
//!   ≥ 1-bounce transfer against the sun's own SH) is the runtime's, with shadow-map visibility; a
//!   binary direct-sun visibility in C_S would also make neighbouring maps jump and defeat the
//!   clustering.
//!
//! Sky control variate (issue 37, item 2; option `sky_control_variate`, off by default): the sky's
//! SH is known exactly, so C_H = (the sky's own coefficients) + Σ (f(d) − L_sky(d))·y(d)·4π/N, f the
//! radiance the ray brings as above: the same expectation, and a ray that escapes adds nothing
//! (where L_sky < 0 it adds the clamp, max(L, 0) − L). Noise comes only from blocked rays, and
//! none where nothing blocks. The two halves carry the same correction sums, so their
//! difference (the noise estimate) is the correction's. Measured (`tests/lighting.rs`): unbiased,
//! but the variance falls only 1.06× on a cluttered probe over a ground plane: the spherical
//! Fibonacci set already integrates the smooth unblocked sky almost exactly, and the noise is
//! at the visibility edges, which the correction keeps. Hence off.
//!
//! Both maps are finally rotated into the instance's frame (rotation about +Z, seed 000 4.7.3).
//! Unbiased for that light model; it converges to the brute-force answer as samples grow.

use crate::sh::{self, ShIrradiance, ShRadiance};
pub use crate::trace::fibonacci_direction;
use crate::trace::{Ray, SceneTracer, Tracer};
use glam::Vec3A;
use rayon::prelude::*;

/// Sun as a directional light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SunLight {
    /// Unit direction towards the sun.
    pub direction: [f32; 3],
    /// Irradiance on a surface facing the sun, linear RGB.
    pub irradiance: [f32; 3],
}

/// What the estimator traces against.
pub struct EnvmapScene<'a> {
    /// Instances (and the terrain as one more instance, if any).
    pub bvh: &'a dyn SceneTracer,
    /// Number of plant instances: BVH instances `0..count` get maps; later ones (terrain) do not.
    pub count: usize,
    /// Probe height above each instance's position, metres.
    pub probe_height: Vec<f32>,
    /// Diffuse albedo (linear RGB) of each BVH instance.
    pub albedo: Vec<[f32; 3]>,
    /// The sky without the sun.
    pub sky: ShRadiance,
    pub sun: Option<SunLight>,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvmapOptions {
    pub samples: u32,
    pub seed: u64,
    /// Ray-tracing backend ([`Tracer`]: `cpu` | `embree`).
    pub tracer: Tracer,
    /// Trace the rays as two independently rotated halves and keep their difference (the
    /// `envmaps` section's noise estimate); false: one rotated N-point set, no noise estimate.
    pub noise_estimate: bool,
    /// C_H as the exact unoccluded sky SH plus the traced difference where a ray is blocked
    /// (a control variate, issue 37); false (the default): every ray's radiance summed.
    pub sky_control_variate: bool,
}

impl EnvmapOptions {
    /// The defaults, as a constant (the pipeline presets are built from it).
    pub const DEFAULT: EnvmapOptions = EnvmapOptions {
        samples: 256,
        seed: 0x00e0_2005,
        tracer: Tracer::Cpu,
        noise_estimate: true,
        sky_control_variate: false,
    };

    /// Options this binary cannot run (a tracer it was built without).
    pub fn check(&self) -> std::result::Result<(), String> {
        self.tracer.available_as("envmaps.tracer")
    }
}

impl Default for EnvmapOptions {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Per-instance (C_H, C_S) in the instance's frame.
pub type InstanceMaps = ([[f32; 3]; 16], [[f32; 3]; 16]);

/// Floats of one instance's half difference: C_H then C_S, `[coefficient][rgb]`
/// (`section::flatten`'s order).
pub const NOISE_DIM: usize = 96;

/// One instance's half difference A − B in the **world** frame (the frame the cluster stage
/// works in), flattened as [`NOISE_DIM`].
pub type HalfDifference = [f32; NOISE_DIM];

/// The traced maps of some instances and, with [`EnvmapOptions::noise_estimate`], each one's
/// half difference (else empty).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Traced {
    pub maps: Vec<InstanceMaps>,
    pub diffs: Vec<HalfDifference>,
}

impl Traced {
    /// Appends another batch (a later shard).
    pub fn extend(&mut self, other: Traced) {
        self.maps.extend(other.maps);
        self.diffs.extend(other.diffs);
    }
}

/// Bakes the maps of every instance (parallel, deterministic).
pub fn bake_envmaps(scene: &EnvmapScene, opts: &EnvmapOptions) -> Vec<InstanceMaps> {
    bake_envmaps_range(scene, opts, 0..scene.count)
}

/// The maps of instances `range` (clamped to the scene's count).
pub fn bake_envmaps_range(
    scene: &EnvmapScene,
    opts: &EnvmapOptions,
    range: std::ops::Range<usize>,
) -> Vec<InstanceMaps> {
    trace_envmaps_range(scene, opts, range).maps
}

/// The maps of instances `range` (clamped to the scene's count) and their half differences.
pub fn trace_envmaps_range(
    scene: &EnvmapScene,
    opts: &EnvmapOptions,
    range: std::ops::Range<usize>,
) -> Traced {
    let range = range.start.min(scene.count)..range.end.min(scene.count);
    let idx: Vec<usize> = range.collect();
    trace_envmaps_subset(scene, opts, &idx)
}

/// The maps of the instances `subset` (indices below the scene's count), in that order: a
/// high-ray reference of some instances (`bench::cluster`).
pub(crate) fn bake_envmaps_subset(
    scene: &EnvmapScene,
    opts: &EnvmapOptions,
    subset: &[usize],
) -> Vec<InstanceMaps> {
    trace_envmaps_subset(scene, opts, subset).maps
}

/// [`bake_envmaps_subset`] with the half differences.
pub(crate) fn trace_envmaps_subset(
    scene: &EnvmapScene,
    opts: &EnvmapOptions,
    subset: &[usize],
) -> Traced {
    let sky_irr = scene.sky.to_irradiance();
    let inside = enclosed_instances(scene, subset);
    let shells = own_shells(scene, subset);
    let (maps, diffs): (Vec<InstanceMaps>, Vec<Option<HalfDifference>>) = subset
        .par_iter()
        .zip(&inside)
        .zip(&shells)
        .map(|((&i, inside), &shell)| bake_one(scene, &sky_irr, i, inside, shell, opts))
        .unzip();
    Traced {
        maps,
        diffs: diffs.into_iter().flatten().collect(),
    }
}

/// Whether these options trace two halves (and so give a noise estimate).
pub fn traces_halves(opts: &EnvmapOptions) -> bool {
    opts.noise_estimate && opts.samples >= 2
}

/// The probe of instance `i`, world space.
fn probe(scene: &EnvmapScene, i: usize) -> Vec3A {
    Vec3A::from(scene.bvh.instances()[i].translation) + Vec3A::Z * scene.probe_height[i]
}

/// Per instance of `subset` (in its order), whether its model encloses its own footprint, so
/// that nothing inside its box is seen from its outside (a house, a closed rock; not a tree,
/// whose crown never encloses and whose trunk is narrow): the model's first instance in the
/// scene (with a map) encloses ([`crate::trace::SceneTracer::instance_encloses`]) each of the
/// four points at ±20 % of its world box's extent from the box's centre in x and y, 1 % of its
/// height above its bottom. Decided once per model (4 × 64 rays), so the answer is the same in
/// every unit, and the points keep inside a square footprint turned by any angle.
fn own_shells(scene: &EnvmapScene, subset: &[usize]) -> Vec<bool> {
    let instances = scene.bvh.instances();
    let mut first: std::collections::BTreeMap<u32, usize> = std::collections::BTreeMap::new();
    for &i in subset {
        first.entry(instances[i].model).or_insert(usize::MAX);
    }
    for (k, inst) in instances.iter().enumerate().take(scene.count) {
        if let Some(f) = first.get_mut(&inst.model) {
            *f = (*f).min(k);
        }
    }
    let encloses: std::collections::BTreeMap<u32, bool> = first
        .into_iter()
        .map(|(m, k)| (m, encloses_footprint(scene.bvh, k as u32)))
        .collect();
    subset
        .iter()
        .map(|&i| encloses[&instances[i].model])
        .collect()
}

/// Whether instance `k` encloses the four footprint points of [`own_shells`].
fn encloses_footprint(bvh: &dyn SceneTracer, k: u32) -> bool {
    let (lo, hi) = bvh.instance_bounds(k);
    let (c, e) = ((lo + hi) * 0.5, hi - lo);
    let z = lo.z + 0.01 * e.z;
    [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
        .iter()
        .all(|&(sx, sy)| {
            let p = Vec3A::new(c.x + sx * 0.2 * e.x, c.y + sy * 0.2 * e.y, z);
            bvh.instance_encloses(k, p)
        })
}

/// Per instance of `subset` (in its order), the instances with a map whose probe it encloses
/// (the inverse of [`crate::trace::SceneTracer::enclosing`]), ascending: the probes in the
/// instance's world box, found in the probes sorted by x, each tested by
/// [`crate::trace::SceneTracer::instance_encloses`] (so `k` encloses `j`'s probe here exactly
/// when `k` is in `enclosing(probe j, j)`). A unit's cost follows its own instances, not the
/// scene's.
fn enclosed_instances(scene: &EnvmapScene, subset: &[usize]) -> Vec<Vec<u32>> {
    let mut by_x: Vec<(f32, u32)> = (0..scene.count)
        .map(|j| (probe(scene, j).x, j as u32))
        .collect();
    by_x.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    subset
        .par_iter()
        .map(|&k| {
            let (lo, hi) = scene.bvh.instance_bounds(k as u32);
            let start = by_x.partition_point(|&(x, _)| x < lo.x);
            let end = by_x.partition_point(|&(x, _)| x <= hi.x);
            let mut inside: Vec<u32> = by_x[start..end.max(start)]
                .iter()
                .map(|&(_, j)| j)
                .filter(|&j| {
                    j as usize != k
                        && scene
                            .bvh
                            .instance_encloses(k as u32, probe(scene, j as usize))
                })
                .collect();
            inside.sort_unstable();
            inside
        })
        .collect()
}

fn bake_one(
    scene: &EnvmapScene,
    sky_irr: &ShIrradiance,
    i: usize,
    inside: &[u32],
    own_shell: bool,
    opts: &EnvmapOptions,
) -> (InstanceMaps, Option<HalfDifference>) {
    let inst = scene.bvh.instances()[i];
    let p = probe(scene, i);
    let n = opts.samples.max(1);
    let w = 4.0 * std::f64::consts::PI / n as f64;
    let base = opts.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let cv = opts.sky_control_variate;
    // The instances the probe's rays ignore: the instance itself, then those that enclose the
    // probe and those whose probe the instance encloses (docs/CONVENTIONS.md, "Environment-map
    // probes"), which the hit points' sun rays ignore too: the probe sees the scene without them.
    let mut skip: Vec<u32> = std::iter::once(i as u32)
        .chain(scene.bvh.enclosing(p, i as u32))
        .collect();
    for &j in inside {
        if !skip.contains(&j) {
            skip.push(j);
        }
    }
    // An instance whose model encloses its footprint (a house, not a tree: `own_shells`) hides
    // what lies inside its box from its outer surfaces: the probe's view of it stands in for the
    // ground around the instance, so a hit point there is lit as if the instance were absent
    // (its own shadow on the ground outside the box stays). docs/CONVENTIONS.md,
    // "Environment-map probes".
    let shell = own_shell.then(|| scene.bvh.instance_bounds(i as u32));
    // One rotated set of `m` points, each ray weighted `w`; sums in the world frame. With the
    // control variate a ray adds (f − L)(d)·y(d)·w to C_H: zero where it escapes (unless the
    // SH sky is negative there), the hit's radiance minus the sky it hides where it is blocked.
    let set = |seed: u64, m: u32| {
        let rot = random_rotation(crate::trace::mix64(seed));
        let mut ch = [[0.0f64; 3]; 16];
        let mut cs = [[0.0f64; 3]; 16];
        for k in 0..m {
            let d = rot * fibonacci_direction(k, m);
            let (mut lh, ls) = radiance_along(scene, sky_irr, &skip, shell, p, d);
            if cv {
                let l = scene.sky.eval(d.to_array());
                lh = [0, 1, 2].map(|c| lh[c] - l[c]);
            }
            let y = sh::eval_basis16(d.to_array());
            for c in 0..16 {
                for ch_k in 0..3 {
                    ch[c][ch_k] += (lh[ch_k] * y[c]) as f64 * w;
                    cs[c][ch_k] += (ls[ch_k] * y[c]) as f64 * w;
                }
            }
        }
        (ch, cs)
    };
    let (ch, cs, diff) = if traces_halves(opts) {
        // Two independent halves: ⌈n/2⌉ and ⌊n/2⌋ points, their own rotations. The sum of the
        // two (each ray weighted 4π/n) is the n-ray estimate; each half alone, rescaled to
        // its own ray count, is an estimate A or B.
        let (na, nb) = (n - n / 2, n / 2);
        let (ha, sa) = set(base, na);
        let (hb, sb) = set(crate::trace::mix64(base ^ 0x6a09_e667_f3bc_c909), nb);
        let (fa, fb) = (n as f64 / na as f64, n as f64 / nb as f64);
        let mut d = [0.0f32; NOISE_DIM];
        for (half, (a, b)) in [(&ha, &hb), (&sa, &sb)].into_iter().enumerate() {
            for c in 0..16 {
                for k in 0..3 {
                    d[half * 48 + c * 3 + k] = (a[c][k] * fa - b[c][k] * fb) as f32;
                }
            }
        }
        let add = |a: [[f64; 3]; 16], b: [[f64; 3]; 16]| {
            std::array::from_fn(|c| std::array::from_fn(|k| a[c][k] + b[c][k]))
        };
        (add(ha, hb), add(sa, sb), Some(d))
    } else {
        let (ch, cs) = set(base, n);
        (ch, cs, None)
    };
    // The exact part of the control variate: ∫ L y dω is the sky's own SH (order 4, world frame).
    let ch = if cv {
        std::array::from_fn(|c| std::array::from_fn(|k| ch[c][k] + scene.sky.coeffs[c][k] as f64))
    } else {
        ch
    };
    let to_f32 = |m: [[f64; 3]; 16]| m.map(|c| c.map(|v| v as f32));
    // Into the instance's frame: C_local(d) = C_world(Rz(θ)·d).
    let angle = -(inst.rotation_deg as f64).to_radians();
    let h = ShRadiance { coeffs: to_f32(ch) }.rotated_z(angle);
    let s = ShRadiance { coeffs: to_f32(cs) }.rotated_z(angle);
    ((h.coeffs, s.coeffs), diff)
}

/// Radiance from direction d at p: (sky part, sun part). `skip`: the probe's own instance, then
/// the instances enclosing it; the hit points' sun rays ignore the latter, and the own instance
/// too where the hit lies in `shell` (the own instance's box, where its model encloses its
/// footprint: [`own_shells`]).
fn radiance_along(
    scene: &EnvmapScene,
    sky_irr: &ShIrradiance,
    skip: &[u32],
    shell: Option<(Vec3A, Vec3A)>,
    p: Vec3A,
    d: Vec3A,
) -> ([f32; 3], [f32; 3]) {
    let ray = Ray::new(p, d, 1e-4);
    match scene.bvh.closest_hit_excluding(&ray, skip) {
        None => (scene.sky.eval(d.to_array()).map(|v| v.max(0.0)), [0.0; 3]),
        Some(h) => {
            let surf = scene.bvh.surface(&h);
            let mut n = surf.shading_normal;
            if n.dot(d) > 0.0 {
                n = -n;
            }
            let rho = scene.albedo[h.instance as usize];
            let e_sky = sky_irr.eval(n.to_array()).map(|v| v.max(0.0));
            let lh = [0, 1, 2].map(|k| rho[k] / std::f32::consts::PI * e_sky[k]);
            let ls = match scene.sun {
                Some(sun) => {
                    let s = Vec3A::from(sun.direction);
                    let cos = n.dot(s);
                    let x = surf.position;
                    let inside =
                        shell.is_some_and(|(lo, hi)| x.cmpge(lo).all() && x.cmple(hi).all());
                    let ignored = if inside { skip } else { &skip[1..] };
                    if cos > 0.0 && !blocked(scene.bvh, ignored, x + n * 1e-3, s) {
                        [0, 1, 2].map(|k| rho[k] / std::f32::consts::PI * sun.irradiance[k] * cos)
                    } else {
                        [0.0; 3]
                    }
                }
                None => [0.0; 3],
            };
            (lh, ls)
        }
    }
}

fn blocked(bvh: &dyn SceneTracer, skip: &[u32], p: Vec3A, d: Vec3A) -> bool {
    bvh.any_hit_excluding(&Ray::new(p, d, 1e-4), skip)
}

/// A uniformly random rotation from a seed (Shoemake's quaternion method).
fn random_rotation(seed: u64) -> glam::Mat3A {
    let mut rng = crate::trace::Rng::hashed(seed);
    let (u1, u2, u3) = (rng.f32(), rng.f32(), rng.f32());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let t = std::f32::consts::TAU;
    let q = glam::Quat::from_xyzw(
        a * (t * u2).sin(),
        a * (t * u2).cos(),
        b * (t * u3).sin(),
        b * (t * u3).cos(),
    )
    .normalize();
    glam::Mat3A::from_quat(q)
}
