//! Per-vertex precomputed radiance transfer (PRT) for plant models (seed 000, 4.6.1).
//!
//! For every vertex and each of its two sides (front F along the vertex normal, back B against
//! it), Monte-Carlo paths start in the cosine-weighted hemisphere of that side and are traced
//! against the model itself (alpha-tested BVH). At a hit the path scatters diffusely: it is
//! reflected into the hemisphere it came from with probability 1 − t or transmitted through the
//! leaf with probability t (translucence), and its throughput is multiplied by the hit
//! material's albedo (the BSDF is ρ(1−t)/π on the reflection side and ρt/π on the transmission
//! side, so the sampling probabilities cancel and only ρ remains); Russian roulette on the
//! throughput, from the second hit on, ends most deeper paths on dark leaves, unbiased. When a
//! path leaves the model, the SH basis of its final direction, weighted by the throughput, is
//! added to the side's transfer: set 0 collects every path (V(D|G|S)*C), set 1 only paths with
//! at least one bounce (V(D|G|S)+C, for the indirect sun). Paths still inside the model after `bounces` scattering
//! events are dropped (a slight, documented underestimate of deep interreflection).
//!
//! What the transfer means: with an environment C given as SH radiance coefficients (16 RGB),
//! `L = Σ_i P_i · C_i` is the radiance the side reflects diffusely, i.e. the receiving vertex's
//! albedo ρ and the 1/π of the diffuse BRDF are folded in: an unoccluded upward vertex has the
//! SH projection of ρ·max(0, cos θ)/π. Translucence t of the receiving vertex is *not* folded
//! in: the runtime applies it (eq. 4.8, `L_P = (P_FH·C_H + P_FS·C_S)(1 − t) + (P_BH·C_H +
//! P_BS·C_S)·t`). That renderer integration is not part of this stage.
//!
//! Sides ([`PrtSides`], `prt.sides`): under `auto` (the default) the back side is traced only
//! for vertices whose material is double-sided ([`crate::model::Material::double_sided`]: glTF's
//! `doubleSided`, true for every other input); a one-sided material is opaque and seen from the
//! front only, so its back transfer is never used and stays zero (the layout is unchanged).
//! `both` traces every back side (the behaviour before), `front` none. The front side's paths do
//! not depend on whether the back is traced: its bytes are the same under every choice.
//!
//! Sampling: the first direction of sample k is the k-th point of the 2-D Sobol (0,2)-sequence
//! with a random digital shift (XOR scramble, the base-2 form of a Cranley–Patterson rotation)
//! derived from a hash of (vertex, side); later bounces use a SplitMix64 stream seeded by
//! (vertex, side, k). Every vertex is computed on its own, so results are byte-identical
//! whatever the thread count. Vertices equal in position, normal and material are welded and
//! traced once ([`weld_vertices`]). [`bake_prt_adaptive`] spreads the same mean count over the
//! sides by their variance (measured in `bake bench prt-error`: no gain on a dense crown, so the
//! stage keeps the fixed count).
//!
//! Albedo and translucence (until the material stage's two-layer Schlick conversion lands):
//! albedo = sRGB-decoded diffuse colour × the mean linear colour of the colour map's opaque
//! texels; translucence = the TXF set's translucence, else [`PrtOptions::default_translucence`].

use crate::error::Result;
use crate::model::Mesh;
pub use crate::trace::materials::{PrtMaterial, alpha_masks, prt_materials};
use crate::trace::{
    AlphaMask, BuildPreset, ModelBvh, ModelTracer, Ray, Rng, cosine_hemisphere, mix64,
};
use glam::Vec3A;
use rayon::prelude::*;

/// SH order (bands) of the transfer.
pub const ORDER: usize = crate::sh::ORDER;
/// Coefficients per transfer vector.
pub const COEFFS: usize = ORDER * ORDER;
/// Sides per vertex: 0 = front (along the normal), 1 = back.
pub const SIDES: usize = 2;
/// Transfer sets: 0 = all paths, 1 = paths with at least one bounce.
pub const SETS: usize = 2;
/// RGB transfer coefficients per vertex.
pub const PER_VERTEX: usize = SIDES * SETS * COEFFS;

/// The ray-tracing backend of the PRT: `cpu` (obvhs on the CPU threads, every build),
/// `embree` (Embree 3 through [`ModelTracer`]; builds with the cargo feature `embree` only,
/// elsewhere the option is refused, see [`PrtOptions::check`]) or `gpu` (a wgpu compute shader
/// over the same CWBVH, [`crate::prt::gpu`]). The sampler is the same on every backend, so the
/// transfer agrees up to rare float-level differences of the hits; each backend on its own is
/// deterministic (the GPU's per device: not bit-equal to the CPU or to another device).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PrtTracer {
    #[default]
    Cpu,
    Embree,
    Gpu,
}

/// Which sides of a vertex the PRT traces (`prt.sides`); a side not traced has a zero transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PrtSides {
    /// The back side only for vertices of double-sided materials
    /// ([`crate::model::Material::double_sided`]).
    #[default]
    Auto,
    /// Front and back of every vertex.
    Both,
    /// The front side only.
    Front,
}

impl PrtSides {
    /// The option's name as options spell it.
    pub fn name(self) -> &'static str {
        match self {
            PrtSides::Auto => "auto",
            PrtSides::Both => "both",
            PrtSides::Front => "front",
        }
    }
}

/// Options of the PRT stage.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrtOptions {
    /// Paths per vertex side.
    pub samples: u32,
    /// Scattering events a path may take inside the model (0: visibility only).
    pub bounces: u32,
    pub preset: BuildPreset,
    /// Subdivision depth of the alpha-aware BVH build ([`crate::trace::bvh::ALPHA_SPLIT_DEPTH`]).
    pub alpha_split: u32,
    /// Ray origin offset along the normal, relative to the model's bounding-box diagonal.
    pub offset: f32,
    /// Translucence of materials that carry none (TXF plants: 0.3; objects: 0).
    pub default_translucence: f32,
    /// Seed of the per-vertex sample scrambles.
    pub seed: u64,
    /// Ray-tracing backend ([`PrtTracer`]).
    pub tracer: PrtTracer,
    /// Sides traced ([`PrtSides`]): `auto` skips the back of one-sided materials.
    pub sides: PrtSides,
}

impl PrtOptions {
    /// Quick look: 64 paths per side, 2 bounces.
    pub const fn preview() -> Self {
        PrtOptions {
            samples: 64,
            bounces: 2,
            preset: BuildPreset::VeryFast,
            alpha_split: crate::trace::bvh::ALPHA_SPLIT_DEPTH,
            offset: 1e-4,
            default_translucence: 0.3,
            seed: 0,
            tracer: PrtTracer::Cpu,
            sides: PrtSides::Auto,
        }
    }
    /// Final quality: 1,024 paths per side, 4 bounces.
    pub const fn final_quality() -> Self {
        PrtOptions {
            samples: 1024,
            bounces: 4,
            ..Self::preview()
        }
    }
}

impl PrtOptions {
    /// The default: 256 paths per side, 3 bounces.
    pub const fn standard() -> Self {
        PrtOptions {
            samples: 256,
            bounces: 3,
            ..Self::preview()
        }
    }
}

impl PrtTracer {
    /// The backend's name as options spell it.
    pub fn name(self) -> &'static str {
        match self {
            PrtTracer::Cpu => "cpu",
            PrtTracer::Embree => "embree",
            PrtTracer::Gpu => "gpu",
        }
    }

    /// Whether this binary can trace on the backend (`embree`: the cargo feature `embree`;
    /// `gpu` is in every build and needs an adapter at run time).
    pub fn available(self) -> std::result::Result<(), String> {
        match self {
            PrtTracer::Cpu | PrtTracer::Gpu => Ok(()),
            PrtTracer::Embree if cfg!(feature = "embree") => Ok(()),
            PrtTracer::Embree => Err(
                "prt.tracer = \"embree\" needs a bake built with the cargo feature `embree` \
                 (Debian: apt-get install libembree-dev; then cargo build --release --features \
                 embree); this binary has tracer = \"cpu\" and \"gpu\""
                    .into(),
            ),
        }
    }
}

impl PrtOptions {
    /// Options this binary cannot run (a tracer it was built without).
    pub fn check(&self) -> std::result::Result<(), String> {
        self.tracer.available()
    }
}

impl Default for PrtOptions {
    fn default() -> Self {
        Self::standard()
    }
}

/// The transfer of a mesh: `coeffs[((v·2 + side)·2 + set)·16 + i]` is the RGB coefficient i.
#[derive(Debug, Clone, PartialEq)]
pub struct Transfer {
    pub vertices: u32,
    pub samples: u32,
    pub bounces: u32,
    pub coeffs: Vec<[f32; 3]>,
    /// Rays traced (closest-hit queries), for the ray-rate statistics.
    pub rays: u64,
    /// Vertices with no usable normal or not used by any triangle (their transfer is zero).
    pub skipped_vertices: u32,
}

impl Transfer {
    /// The 16 coefficients of one vertex, side and set.
    pub fn get(&self, vertex: usize, side: usize, set: usize) -> &[[f32; 3]] {
        let at = ((vertex * SIDES + side) * SETS + set) * COEFFS;
        &self.coeffs[at..at + COEFFS]
    }
}

/// Bakes the transfer of `mesh`: builds the scene of `opts.tracer`, then [`bake_prt_with`].
pub fn bake_prt(
    mesh: &Mesh,
    materials: &[PrtMaterial],
    masks: &[Option<AlphaMask>],
    opts: &PrtOptions,
) -> Result<Transfer> {
    let scene = PrtScene::build(mesh, masks, opts)?;
    Ok(scene.bake(mesh, materials, opts, &|_| {}))
}

/// A model's scene on the backend [`PrtOptions::tracer`] names.
#[allow(
    clippy::large_enum_variant,
    reason = "one per model, built once and traced millions of times"
)]
pub enum PrtScene {
    Cpu(ModelBvh),
    #[cfg(feature = "embree")]
    Embree(crate::trace::embree::EmbreeScene),
}

impl PrtScene {
    /// Builds the scene of `mesh` (`masks` as for [`ModelBvh::build`]); a backend this binary
    /// was built without is a usage error.
    pub fn build(mesh: &Mesh, masks: &[Option<AlphaMask>], opts: &PrtOptions) -> Result<Self> {
        opts.check().map_err(crate::error::Error::usage)?;
        match opts.tracer {
            // The GPU tracer walks this BVH's CWBVH on the device.
            PrtTracer::Cpu | PrtTracer::Gpu => Ok(PrtScene::Cpu(ModelBvh::build_split(
                mesh,
                masks,
                opts.preset,
                opts.alpha_split,
            )?)),
            #[cfg(feature = "embree")]
            PrtTracer::Embree => {
                mesh.validate().map_err(|m| {
                    crate::error::Error::runtime(format!("cannot build an Embree scene: {m}"))
                })?;
                Ok(PrtScene::Embree(crate::trace::embree::EmbreeScene::build(
                    mesh, masks,
                )?))
            }
            #[cfg(not(feature = "embree"))]
            PrtTracer::Embree => unreachable!("refused by PrtOptions::check"),
        }
    }

    /// Triangles the backend left out (non-finite positions).
    pub fn skipped_triangles(&self) -> usize {
        match self {
            PrtScene::Cpu(b) => b.skipped_triangles(),
            #[cfg(feature = "embree")]
            PrtScene::Embree(e) => e.skipped_triangles(),
        }
    }

    /// [`bake_prt_with`] on this scene.
    pub fn bake(
        &self,
        mesh: &Mesh,
        materials: &[PrtMaterial],
        opts: &PrtOptions,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Transfer {
        match self {
            PrtScene::Cpu(b) => bake_prt_with(b, mesh, materials, opts, progress),
            #[cfg(feature = "embree")]
            PrtScene::Embree(e) => bake_prt_with(e, mesh, materials, opts, progress),
        }
    }

    /// [`bake_prt_subset`] on this scene.
    pub(crate) fn bake_subset(
        &self,
        mesh: &Mesh,
        materials: &[PrtMaterial],
        opts: &PrtOptions,
        vertices: &[u32],
    ) -> Transfer {
        match self {
            PrtScene::Cpu(b) => bake_prt_subset(b, mesh, materials, opts, vertices, &|_| {}),
            #[cfg(feature = "embree")]
            PrtScene::Embree(e) => bake_prt_subset(e, mesh, materials, opts, vertices, &|_| {}),
        }
    }
}

/// Bakes the transfer against a prebuilt scene of `mesh` (any [`ModelTracer`]), tracing each
/// set of duplicate vertices once ([`weld_vertices`]). `progress` is called with the number of
/// vertices finished since its last call.
pub(crate) fn bake_prt_with<T: ModelTracer>(
    bvh: &T,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> Transfer {
    let Ok(t) =
        bake_welded::<std::convert::Infallible, T>(bvh, mesh, materials, opts, progress, |u| {
            Ok(bake_prt_subset(bvh, mesh, materials, opts, u, progress))
        });
    t
}

/// Welds duplicate vertices ([`weld_vertices`]), bakes the representatives with `subset` (the
/// transfer of the listed vertices, in order: [`bake_prt_subset`] or the GPU tracer's), and
/// copies each representative's transfer to the vertices welded to it.
pub fn bake_welded<E, T: ModelTracer>(
    bvh: &T,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    progress: &(dyn Fn(u64) + Sync),
    subset: impl FnOnce(&[u32]) -> std::result::Result<Transfer, E>,
) -> std::result::Result<Transfer, E> {
    let reps = weld_vertices(mesh);
    let unique: Vec<u32> = (0..reps.len() as u32)
        .filter(|&v| reps[v as usize] == v)
        .collect();
    let mut t = subset(&unique)?;
    if unique.len() == reps.len() {
        return Ok(t);
    }
    // Copy each representative's transfer to the vertices welded to it.
    let mut slot = vec![0u32; reps.len()];
    for (i, &v) in unique.iter().enumerate() {
        slot[v as usize] = i as u32;
    }
    let ctx = Ctx::new(bvh, mesh, materials, opts);
    let mut coeffs = Vec::with_capacity(reps.len() * PER_VERTEX);
    let mut skipped = 0;
    for &r in &reps {
        let at = slot[r as usize] as usize * PER_VERTEX;
        coeffs.extend_from_slice(&t.coeffs[at..at + PER_VERTEX]);
        skipped += ctx.vertex_frame(r as usize).is_none() as u32;
    }
    progress((reps.len() - unique.len()) as u64);
    t.coeffs = coeffs;
    t.vertices = reps.len() as u32;
    t.skipped_vertices = skipped;
    Ok(t)
}

/// Welds duplicate vertices: for each vertex, the first vertex with the same position, normal
/// (bit for bit) and material (of the first triangle using it), whose transfer it shares (real
/// TXF files repeat positions across sets). Unused vertices stay their own.
pub fn weld_vertices(mesh: &Mesh) -> Vec<u32> {
    let n = mesh.positions.len();
    let mut material = vec![u32::MAX; n];
    for (t, tri) in mesh.indices.iter().enumerate() {
        for &i in tri {
            if let Some(m) = material.get_mut(i as usize)
                && *m == u32::MAX
            {
                *m = mesh.triangle_materials.get(t).copied().unwrap_or(u32::MAX);
            }
        }
    }
    let mut first = std::collections::HashMap::with_capacity(n);
    (0..n)
        .map(|v| {
            if material[v] == u32::MAX {
                return v as u32;
            }
            let key = (
                mesh.positions[v].map(f32::to_bits),
                mesh.normals
                    .get(v)
                    .copied()
                    .unwrap_or_default()
                    .map(f32::to_bits),
                material[v],
            );
            *first.entry(key).or_insert(v as u32)
        })
        .collect()
}

/// The number of distinct vertices after [`weld_vertices`].
pub fn weld_key_count(mesh: &Mesh) -> usize {
    let reps = weld_vertices(mesh);
    reps.iter()
        .enumerate()
        .filter(|&(v, &r)| r as usize == v)
        .count()
}

/// The transfer of the listed vertices only (in that order; benchmarks trace a sample of a
/// large model). Out-of-range indices count as skipped.
pub(crate) fn bake_prt_subset<T: ModelTracer>(
    bvh: &T,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    vertices: &[u32],
    progress: &(dyn Fn(u64) + Sync),
) -> Transfer {
    let ctx = Ctx::new(bvh, mesh, materials, opts);
    let per_vertex: Vec<VertexResult> = vertices
        .par_iter()
        .with_min_len(16)
        .map(|&v| {
            let r = ctx.vertex(v as usize);
            progress(1);
            r
        })
        .collect();
    collect_transfer(per_vertex, opts)
}

/// The transfer of the vertices' results, in order.
pub(crate) fn collect_transfer(per_vertex: Vec<VertexResult>, opts: &PrtOptions) -> Transfer {
    let n = per_vertex.len();
    let mut t = Transfer {
        vertices: n as u32,
        samples: opts.samples,
        bounces: opts.bounces,
        coeffs: Vec::with_capacity(n * PER_VERTEX),
        rays: 0,
        skipped_vertices: 0,
    };
    for r in per_vertex {
        match r {
            Some((c, rays)) => {
                t.coeffs.extend_from_slice(&c[..]);
                t.rays += rays;
            }
            None => {
                t.coeffs.extend_from_slice(&[[0.0; 3]; PER_VERTEX]);
                t.skipped_vertices += 1;
            }
        }
    }
    t
}

/// Adaptive per-side path counts ([`bake_prt_adaptive`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adaptive {
    /// Paths per side of the pilot pass that estimates each side's variance.
    pub pilot: u32,
    /// Most paths a side may get, as a multiple of `PrtOptions::samples`.
    pub max_factor: u32,
}

impl Adaptive {
    /// A pilot of 1/8 of the mean count (at least 16 paths), at most 8× the mean per side.
    pub const fn for_samples(samples: u32) -> Self {
        let pilot = samples / 8;
        Adaptive {
            pilot: if pilot < 16 { 16 } else { pilot },
            max_factor: 8,
        }
    }
}

/// The transfer of `vertices` with, on average, `opts.samples` paths per side, spread over the
/// sides by their noise: a pilot pass of `adaptive.pilot` paths estimates each side's per-path
/// variance σ² (summed over sets, coefficients and channels), then each side gets
/// N = clamp(λσ, pilot, max) paths in all, with λ chosen so that the mean N is `opts.samples`
/// (N ∝ σ minimizes the summed variance Σ σ²/N of a fixed budget). The second pass continues
/// each side's sequence after the pilot's paths, which are kept. Deterministic and independent
/// of the thread count: λ comes from a sequential bisection over the pilot's variances in vertex
/// order. (N depends on the pilot's own paths, a small bias the error benchmark measures.)
pub fn bake_prt_adaptive<T: ModelTracer>(
    bvh: &T,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    vertices: &[u32],
    adaptive: Adaptive,
) -> Transfer {
    let ctx = Ctx::new(bvh, mesh, materials, opts);
    let pilot = adaptive.pilot.clamp(1, opts.samples.max(1));
    let first: Vec<Option<Pilot>> = vertices
        .par_iter()
        .with_min_len(16)
        .map(|&v| ctx.pilot(v as usize, pilot))
        .collect();
    let sigmas: Vec<f64> = first
        .iter()
        .flatten()
        .flat_map(|p| p.sigma[..p.sides].iter().copied())
        .collect();
    let max = opts
        .samples
        .saturating_mul(adaptive.max_factor.max(1))
        .max(pilot);
    let target = opts.samples.max(1) as f64 * sigmas.len() as f64;
    let lambda = allocation_scale(&sigmas, pilot, max, target);
    let count = |sigma: f64| (lambda * sigma).round().clamp(pilot as f64, max as f64) as u32;
    let per_vertex: Vec<VertexResult> = vertices
        .par_iter()
        .zip(first)
        .with_min_len(16)
        .map(|(&v, p)| ctx.finish(v as usize, p?, pilot, count))
        .collect();
    collect_transfer(per_vertex, opts)
}

/// The smallest λ whose clamped counts clamp(λσ, lo, hi) add up to at least `target`
/// (bisection; sequential, so the same on any thread count).
fn allocation_scale(sigmas: &[f64], lo: u32, hi: u32, target: f64) -> f64 {
    let total = |l: f64| -> f64 {
        sigmas
            .iter()
            .map(|&s| (l * s).round().clamp(lo as f64, hi as f64))
            .sum()
    };
    let mut high = 1.0f64;
    while total(high) < target && high < 1e30 {
        high *= 2.0;
    }
    let mut low = 0.0;
    for _ in 0..60 {
        let mid = 0.5 * (low + high);
        if total(mid) < target {
            low = mid;
        } else {
            high = mid;
        }
    }
    high
}

/// The pilot pass of one vertex: its path sums (unnormalized, receiving albedo not applied),
/// each side's per-path standard deviation, and the rays traced.
struct Pilot {
    sums: Box<[[f32; 3]; PER_VERTEX]>,
    sigma: [f64; SIDES],
    /// Sides traced (the first `sides` of `sigma` count).
    sides: usize,
    rays: u64,
}

/// One vertex's coefficients and ray count, or `None` if it was skipped.
pub(crate) type VertexResult = Option<(Box<[[f32; 3]; PER_VERTEX]>, u64)>;

/// Everything the per-vertex loop reads.
struct Ctx<'a, T: ModelTracer> {
    bvh: &'a T,
    mesh: &'a Mesh,
    materials: Vec<PrtMaterial>,
    /// Material of each vertex (of the first triangle using it), `u32::MAX` if unused.
    vertex_material: Vec<u32>,
    /// Area-weighted face normal per vertex: the fallback for unusable vertex normals.
    face_normal: Vec<Vec3A>,
    eps: f32,
    opts: &'a PrtOptions,
}

impl<'a, T: ModelTracer> Ctx<'a, T> {
    fn new(bvh: &'a T, mesh: &'a Mesh, materials: &[PrtMaterial], opts: &'a PrtOptions) -> Self {
        let n = mesh.positions.len();
        let mut vertex_material = vec![u32::MAX; n];
        let mut face_normal = vec![Vec3A::ZERO; n];
        for (t, tri) in mesh.indices.iter().enumerate() {
            let p = |i: u32| Vec3A::from(mesh.positions[i as usize]);
            let ng = (p(tri[1]) - p(tri[0])).cross(p(tri[2]) - p(tri[0]));
            for &i in tri {
                let i = i as usize;
                if vertex_material[i] == u32::MAX {
                    vertex_material[i] = mesh.triangle_materials[t];
                }
                if ng.is_finite() {
                    face_normal[i] += ng;
                }
            }
        }
        let (lo, hi) = bvh.bounds();
        let diag = (hi - lo).length();
        let diag = if diag.is_finite() && diag > 0.0 {
            diag
        } else {
            1.0
        };
        // Materials the mesh names but the caller did not describe absorb everything.
        let mut mats = materials.to_vec();
        mats.resize(
            mesh.materials.len().max(mats.len()),
            PrtMaterial {
                albedo: [0.0; 3],
                translucence: 0.0,
            },
        );
        Ctx {
            bvh,
            mesh,
            materials: mats,
            vertex_material,
            face_normal,
            eps: opts.offset * diag,
            opts,
        }
    }

    /// The unit normal of vertex `v`: its own, or the face normal where that is unusable.
    fn normal(&self, v: usize) -> Option<Vec3A> {
        let n = Vec3A::from(self.mesh.normals[v]);
        n.try_normalize()
            .or_else(|| self.face_normal[v].try_normalize())
    }

    fn vertex(&self, v: usize) -> VertexResult {
        let (mat, n, p) = self.vertex_frame(v)?;
        let mut out = Box::new([[0.0f32; 3]; PER_VERTEX]);
        let mut rays = 0;
        for side in 0..self.traced_sides(v) {
            let mut acc = SideSums::default();
            rays += self.side(v, side, p, n, 0..self.opts.samples, &mut acc);
            let scale = 1.0 / self.opts.samples.max(1) as f64;
            let dst = &mut out[side * SETS * COEFFS..(side + 1) * SETS * COEFFS];
            for (o, a) in dst.iter_mut().zip(acc.sum.iter().flatten()) {
                *o = std::array::from_fn(|k| (a[k] * scale * mat.albedo[k] as f64) as f32);
            }
        }
        Some((out, rays))
    }

    /// How many sides of vertex `v` are traced (1: the front only, 2: both), by
    /// [`PrtOptions::sides`] and the material of the first triangle using it.
    fn traced_sides(&self, v: usize) -> usize {
        match self.opts.sides {
            PrtSides::Both => SIDES,
            PrtSides::Front => 1,
            PrtSides::Auto => {
                let m = self.vertex_material.get(v).copied().unwrap_or(u32::MAX);
                match self.mesh.materials.get(m as usize) {
                    Some(m) if !m.double_sided => 1,
                    _ => SIDES,
                }
            }
        }
    }

    /// The material, unit normal and position of vertex `v`, or `None` if it is skipped.
    fn vertex_frame(&self, v: usize) -> Option<(PrtMaterial, Vec3A, Vec3A)> {
        let mat = *self.materials.get(*self.vertex_material.get(v)? as usize)?;
        let n = self.normal(v)?;
        let p = Vec3A::from(self.mesh.positions[v]);
        p.is_finite().then_some((mat, n, p))
    }

    /// The pilot pass of [`bake_prt_adaptive`] for vertex `v`: `pilot` paths per side.
    fn pilot(&self, v: usize, pilot: u32) -> Option<Pilot> {
        let (mat, n, p) = self.vertex_frame(v)?;
        let mut sums = Box::new([[0.0f32; 3]; PER_VERTEX]);
        let mut sigma = [0.0; SIDES];
        let mut rays = 0;
        let sides = self.traced_sides(v);
        for side in 0..sides {
            let mut acc = SideSums::default();
            rays += self.side(v, side, p, n, 0..pilot, &mut acc);
            sigma[side] = acc.variance(pilot, mat.albedo).sqrt();
            let dst = &mut sums[side * SETS * COEFFS..(side + 1) * SETS * COEFFS];
            for (o, a) in dst.iter_mut().zip(acc.sum.iter().flatten()) {
                *o = a.map(|x| x as f32);
            }
        }
        Some(Pilot {
            sums,
            sigma,
            sides,
            rays,
        })
    }

    /// The second pass of [`bake_prt_adaptive`]: continues each side of `v` after the pilot's
    /// paths up to `count(σ)` paths and normalizes.
    fn finish(
        &self,
        v: usize,
        pilot: Pilot,
        first: u32,
        count: impl Fn(f64) -> u32,
    ) -> VertexResult {
        let (mat, n, p) = self.vertex_frame(v)?;
        let mut out = pilot.sums;
        let mut rays = pilot.rays;
        for side in 0..pilot.sides {
            let total = count(pilot.sigma[side]).max(first);
            let mut acc = SideSums::default();
            rays += self.side(v, side, p, n, first..total, &mut acc);
            let scale = 1.0 / total as f64;
            let dst = &mut out[side * SETS * COEFFS..(side + 1) * SETS * COEFFS];
            for (o, a) in dst.iter_mut().zip(acc.sum.iter().flatten()) {
                *o = std::array::from_fn(|k| {
                    ((o[k] as f64 + a[k]) * scale * mat.albedo[k] as f64) as f32
                });
            }
        }
        Some((out, rays))
    }

    /// Traces paths `ks` of one side of vertex `v` (at `p`, normal `n`), adding throughput × SH
    /// basis of each escape direction to `acc`. Path k is the same whatever range it is traced
    /// in, so a side can be continued (adaptive sampling).
    fn side(
        &self,
        v: usize,
        side: usize,
        p: Vec3A,
        n: Vec3A,
        ks: std::ops::Range<u32>,
        acc: &mut SideSums,
    ) -> u64 {
        let s = self.side_start(v, side, p, n);
        let n = s.normal;
        let mut rays = 0;
        for k in ks {
            let (u1, u2) = sobol_scrambled(k, s.shift.0, s.shift.1);
            let d = cosine_hemisphere(n, u1, u2);
            let mut rng = Rng::hashed(s.path_seed(k));
            let (escape, r) = self.trace(s.origin, d, &mut rng);
            rays += r;
            if let Some((dir, beta, bounces)) = escape {
                let y = crate::sh::eval_basis16(dir.to_array());
                // Set 0 takes every escaping path, set 1 only those that bounced.
                let sets = if bounces == 0 { 1 } else { SETS };
                for set_acc in acc.sum.iter_mut().take(sets) {
                    for (a, &yi) in set_acc.iter_mut().zip(&y) {
                        for c in 0..3 {
                            a[c] += (beta[c] * yi) as f64;
                        }
                    }
                }
                let yy: f64 = y.iter().map(|&yi| (yi as f64) * (yi as f64)).sum();
                for (sq, &b) in acc.squares.iter_mut().zip(&beta) {
                    *sq += (b as f64).powi(2) * yy * sets as f64;
                }
            }
        }
        rays
    }

    /// Where the paths of side `side` of vertex `v` (at `p`, unit normal `n`) start.
    fn side_start(&self, v: usize, side: usize, p: Vec3A, n: Vec3A) -> SideStart {
        let n = if side == 0 { n } else { -n };
        let key = self.opts.seed ^ ((v as u64) << 1 | side as u64);
        let shift = mix64(key);
        SideStart {
            origin: p + n * self.eps,
            normal: n,
            shift: (shift as u32, (shift >> 32) as u32),
            key_hash: mix64(key),
        }
    }

    /// Follows one path; returns (escape direction, throughput, bounces) if it left the model,
    /// and the number of rays traced.
    fn trace(&self, mut o: Vec3A, mut d: Vec3A, rng: &mut Rng) -> (Option<Escape>, u64) {
        let mut beta = [1.0f32; 3];
        for bounce in 0..=self.opts.bounces {
            let ray = Ray::new(o, d, 0.0);
            if bounce == self.opts.bounces {
                // The last ray only has to tell whether the path escapes: any hit will do.
                let escape = (!self.bvh.any_hit(&ray)).then_some((d, beta, bounce));
                return (escape, bounce as u64 + 1);
            }
            let Some(h) = self.bvh.closest_hit(&ray) else {
                return (Some((d, beta, bounce)), bounce as u64 + 1);
            };
            let (position, ng, material) = self.bvh.hit_point(&h);
            let m = self.materials[material as usize];
            beta = std::array::from_fn(|k| beta[k] * m.albedo[k]);
            if beta == [0.0; 3] || ng == Vec3A::ZERO {
                return (None, bounce as u64 + 1);
            }
            // Russian roulette from the second hit on: go on with probability q = max(β) and
            // divide by it, so dark leaves (albedo ≈ 0.1) end most deep paths without biasing
            // the estimate. The first hit always goes on: roulette there multiplied the variance
            // of the bounced set (40 % of the noise, 1 % of the signal) by ~1/ρ; without it a
            // bake takes 1.5× the rays for 0.59× the mean square error, ~11 % fewer rays at
            // equal error (docs/PERFORMANCE.md, issue 19).
            let q = beta[0].max(beta[1]).max(beta[2]).min(1.0);
            if q < 1.0 && bounce >= 1 {
                if rng.f32() >= q {
                    return (None, bounce as u64 + 1);
                }
                beta = beta.map(|b| b / q);
            }
            let facing = if ng.dot(d) < 0.0 { ng } else { -ng };
            let out = if rng.f32() < m.translucence {
                -facing
            } else {
                facing
            };
            o = position + out * self.eps;
            d = cosine_hemisphere(out, rng.f32(), rng.f32());
        }
        unreachable!("the loop returns at bounce == bounces at the latest")
    }
}

/// Where the paths of one vertex side start, and their random numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SideStart {
    /// The vertex moved off its surface by the ray offset along `normal`.
    pub origin: Vec3A,
    /// The side's unit normal (the vertex normal, negated for the back side).
    pub normal: Vec3A,
    /// The digital shift of the side's Sobol points (x, y).
    pub shift: (u32, u32),
    /// `mix64` of the side's key: path k's bounce stream is `Rng::hashed(path_seed(k))`.
    pub key_hash: u64,
}

/// The multiplier that spreads the path index over the bounce stream's seed.
pub const PATH_SEED_MUL: u64 = 0xD1B5_4A32_D192_ED03;

impl SideStart {
    /// The seed of path k's bounce stream ([`Rng::hashed`]).
    pub fn path_seed(&self, k: u32) -> u64 {
        self.key_hash ^ (k as u64).wrapping_mul(PATH_SEED_MUL)
    }
}

/// What another tracer needs to follow the same paths as [`bake_prt_subset`]: the ray offset,
/// the materials (padded as the CPU pads them: unknown materials absorb everything) and per
/// listed vertex its albedo and the starts of its sides (`None`: skipped, zero transfer; a side
/// `None`: not traced under [`PrtOptions::sides`], zero transfer).
#[derive(Debug, Clone)]
pub struct PathStarts {
    pub eps: f32,
    pub materials: Vec<PrtMaterial>,
    pub vertices: Vec<Option<VertexStarts>>,
}

/// One vertex's albedo and the starts of its sides (`None`: the side is not traced).
pub type VertexStarts = ([f32; 3], [Option<SideStart>; SIDES]);

/// The [`PathStarts`] of `vertices` (in order).
pub fn path_starts(
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    opts: &PrtOptions,
    vertices: &[u32],
) -> PathStarts {
    let ctx = Ctx::new(bvh, mesh, materials, opts);
    let starts = vertices
        .iter()
        .map(|&v| {
            let v = v as usize;
            let (mat, n, p) = ctx.vertex_frame(v)?;
            let sides = ctx.traced_sides(v);
            Some((
                mat.albedo,
                [0, 1].map(|side| (side < sides).then(|| ctx.side_start(v, side, p, n))),
            ))
        })
        .collect();
    PathStarts {
        eps: ctx.eps,
        materials: ctx.materials.clone(),
        vertices: starts,
    }
}

/// Escape direction, throughput, bounces taken.
type Escape = (Vec3A, [f32; 3], u32);

/// The running sums of one side's paths: Σ throughput × SH basis per set, coefficient and
/// channel, and per channel Σ over sets and coefficients of its square (for the variance).
#[derive(Debug, Clone, Default)]
struct SideSums {
    sum: [[[f64; 3]; COEFFS]; SETS],
    squares: [f64; 3],
}

impl SideSums {
    /// The per-path variance of the side's estimate, summed over sets, coefficients and
    /// channels, after `n` paths, with the receiving albedo applied.
    fn variance(&self, n: u32, albedo: [f32; 3]) -> f64 {
        let n = n.max(1) as f64;
        (0..3)
            .map(|c| {
                let mean_sq: f64 = self.sum.iter().flatten().map(|a| (a[c] / n).powi(2)).sum();
                (self.squares[c] / n - mean_sq).max(0.0) * (albedo[c] as f64).powi(2)
            })
            .sum()
    }
}

/// Point k of the 2-D Sobol (0,2)-sequence, XOR-scrambled, in [0, 1)².
pub fn sobol_scrambled(k: u32, sx: u32, sy: u32) -> (f32, f32) {
    let mut v = 1u32 << 31;
    let mut y = 0u32;
    let mut i = k;
    while i != 0 {
        if i & 1 != 0 {
            y ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    let x = k.reverse_bits();
    let to_unit = |b: u32| (b >> 8) as f32 * (1.0 / (1u32 << 24) as f32);
    (to_unit(x ^ sx), to_unit(y ^ sy))
}

pub use crate::color::luminance;

/// Vec4s per side in the GPU layout.
pub const GPU_VEC4_PER_SIDE: usize = 5;

/// The thesis' GPU layout (4.6.1): per vertex and side 5 vec4. vec4 0 holds band 0 of set 0 in
/// RGB and, in alpha, the indirect fraction (band-0 luminance of set 1 over set 0, in [0, 1]:
/// the runtime approximates P_S by this fraction × P_H); vec4 1–4 hold the luminance of
/// coefficients 1–15 of set 0 (bands 1–3 monochrome), the last float is 0.
pub fn pack_gpu(t: &Transfer) -> Vec<[f32; 4]> {
    let mut out = Vec::with_capacity(t.vertices as usize * SIDES * GPU_VEC4_PER_SIDE);
    for v in 0..t.vertices as usize {
        for side in 0..SIDES {
            let all = t.get(v, side, 0);
            let ind = t.get(v, side, 1);
            let l0 = luminance(all[0]);
            let frac = if l0 > 0.0 {
                (luminance(ind[0]) / l0).clamp(0.0, 1.0)
            } else {
                0.0
            };
            out.push([all[0][0], all[0][1], all[0][2], frac]);
            let mut mono = [0.0f32; 16];
            for i in 1..COEFFS {
                mono[i - 1] = luminance(all[i]);
            }
            for c in mono.chunks_exact(4) {
                out.push([c[0], c[1], c[2], c[3]]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests;
