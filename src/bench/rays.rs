//! `bake bench rays`: raw obvhs traversal against the rays per second the PRT stage achieves on
//! the same model in the same run, per BVH build preset, and optionally a timed full bake.
//!
//! Raw rays: closest hit on obvhs' own BVH over the triangles (`build_cwbvh_from_tris`) with
//! obvhs' triangle test and no alpha test, for the incoherent
//! cosine-distributed hemisphere rays that leave a sample of the model's vertices (both sides).
//! PRT rays: every closest-hit query the PRT stage makes for the same vertices (first rays and
//! bounce rays, with alpha tests, sampling and SH accumulation included). Both run over rayon on
//! all threads; each is timed three times and the fastest run counts. The machine is shared, so
//! CPU time (Linux schedstat) is measured beside wall time and the efficiency is the ratio of
//! rays per CPU-second.
//!
//! With `--embree` (cargo feature `embree`): the raw rays through Embree's own BVH with the same
//! alpha test as a filter function, and the PRT loop on the Embree backend (`tracer = "embree"`,
//! the same sampler and the same rays definition as the PRT rays above).

use super::{Timing, cpu_seconds, time_best};
use crate::error::Result;
use crate::model::Mesh;
use crate::prt::transfer::{self as prt, PrtMaterial, PrtOptions};
use crate::trace::{AlphaMask, BuildPreset, ModelBvh, Ray, cosine_hemisphere};
use glam::Vec3A;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// What to measure.
#[derive(Debug, Clone)]
pub struct RaysBenchOptions {
    /// Vertices traced (evenly strided over the model).
    pub vertices: usize,
    /// PRT options for the measured rays (samples per side, bounces, preset).
    pub prt: PrtOptions,
    /// Presets whose build time and raw rate are measured.
    pub presets: Vec<BuildPreset>,
    /// Also bake every vertex with this many samples and time it.
    pub full_bake_samples: Option<u32>,
    /// Also trace the raw rays through Embree (feature `embree`).
    pub embree: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct PresetResult {
    pub preset: &'static str,
    /// Build time of the alpha-aware BVH the PRT uses.
    pub build_seconds: f64,
    pub raw_rays_per_second: f64,
    pub raw_rays_per_cpu_second: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct FullBake {
    pub vertices: u32,
    pub samples: u32,
    pub bounces: u32,
    pub seconds: f64,
    /// CPU time of the whole bake (all threads; Linux only).
    pub cpu_seconds: Option<f64>,
    pub build_seconds: f64,
    pub rays: u64,
    pub rays_per_second: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct RaysBenchReport {
    pub triangles: usize,
    pub vertices_traced: usize,
    pub threads: usize,
    pub preset: &'static str,
    pub raw_rays: u64,
    pub raw_rays_per_second: f64,
    pub prt_rays: u64,
    pub prt_rays_per_second: f64,
    /// PRT rays per CPU-second over raw rays per CPU-second (wall-clock ratio where CPU time
    /// is not available).
    pub efficiency: f64,
    /// The same ratio from wall-clock rates.
    pub efficiency_wall: f64,
    pub raw_rays_per_cpu_second: Option<f64>,
    pub prt_rays_per_cpu_second: Option<f64>,
    /// PRT rays per second with every texel opaque (no alpha test).
    pub prt_opaque_rays_per_second: f64,
    pub prt_opaque_rays_per_cpu_second: Option<f64>,
    /// The raw rays again, through the PRT's alpha-tested BVH (closest hit with the alpha test,
    /// no PRT machinery): the cost of the query itself on alpha-tested geometry.
    pub raw_alpha_rays_per_second: f64,
    pub raw_alpha_rays_per_cpu_second: Option<f64>,
    /// PRT rays per CPU-second over raw alpha-tested rays per CPU-second (the overhead of the
    /// PRT machinery alone; wall-clock ratio where CPU time is not available).
    pub efficiency_alpha: f64,
    pub presets: Vec<PresetResult>,
    pub full_bake: Option<FullBake>,
    /// The raw rays through Embree's own BVH with the same alpha test (`--embree` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub embree_rays_per_second: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub embree_rays_per_cpu_second: Option<f64>,
    /// Embree scene build time.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub embree_build_seconds: Option<f64>,
    /// PRT rays per second over Embree rays per second (wall).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_over_embree: Option<f64>,
    /// PRT rays per second with the Embree backend (`tracer = "embree"`), counted as
    /// `prt_rays_per_second` counts them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_embree_rays: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_embree_rays_per_second: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_embree_rays_per_cpu_second: Option<f64>,
    /// PRT-on-Embree rays per second over raw Embree rays per second (wall; the goal of issue
    /// 19 is at least 0.7).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_embree_over_embree: Option<f64>,
    /// The same ratio per CPU-second (where CPU time is measured).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prt_embree_over_embree_cpu: Option<f64>,
}

/// The Embree side of the benchmark.
#[derive(Debug, Clone, Copy)]
struct EmbreeTimes {
    build: f64,
    raw: Timing,
    prt_rays: u64,
    prt: Timing,
}

/// Runs the benchmark on `mesh` with its materials and alpha masks.
pub fn bench_rays(
    mesh: &Mesh,
    materials: &[PrtMaterial],
    masks: &[Option<AlphaMask>],
    opts: &RaysBenchOptions,
) -> Result<RaysBenchReport> {
    let stride = (mesh.positions.len() / opts.vertices.max(1)).max(1);
    let verts: Vec<u32> = (0..mesh.positions.len() as u32)
        .step_by(stride)
        .take(opts.vertices.max(1))
        .collect();
    let rays = hemisphere_rays(mesh, &verts, &opts.prt);
    let mut list = opts.presets.clone();
    if !list.contains(&opts.prt.preset) {
        list.push(opts.prt.preset);
    }
    let mut presets = Vec::new();
    let mut chosen = None;
    for p in list {
        // Raw: obvhs' own BVH over the triangles (no alpha masks, no alpha-aware boxes).
        let plain = ModelBvh::build(mesh, &[], p)?;
        let raw = raw_timing(&plain, &rays);
        let start = Instant::now();
        let bvh = ModelBvh::build_split(mesh, masks, p, opts.prt.alpha_split)?;
        let build_seconds = start.elapsed().as_secs_f64();
        if opts.presets.contains(&p) {
            presets.push(PresetResult {
                preset: p.name(),
                build_seconds,
                raw_rays_per_second: rays.len() as f64 / raw.wall,
                raw_rays_per_cpu_second: raw.cpu.map(|c| rays.len() as f64 / c),
            });
        }
        if p == opts.prt.preset {
            chosen = Some((bvh, plain, raw));
        }
    }
    let Some((bvh, opaque, raw)) = chosen else {
        return Err(crate::error::Error::runtime("the PRT preset was not built"));
    };
    let raw_rays = rays.len() as u64;
    let (prt_rays, prt) = prt_timing(&bvh, mesh, materials, &verts, &opts.prt);
    // The same PRT without alpha masks: separates the cost of the alpha test (rays that pass
    // through transparent texels travel further) from the cost of the PRT machinery.
    let (opaque_rays, opaque_t) = prt_timing(&opaque, mesh, materials, &verts, &opts.prt);
    let raw_alpha = time_best(|| {
        let hits: usize = rays
            .par_iter()
            .map(|r| bvh.closest_hit(r).is_some() as usize)
            .sum();
        std::hint::black_box(hits);
    });
    // Both measured or neither: a ratio of a CPU rate and a wall rate means nothing.
    let (raw, prt) = match (raw.cpu, prt.cpu) {
        (Some(_), Some(_)) => (raw, prt),
        _ => (Timing { cpu: None, ..raw }, Timing { cpu: None, ..prt }),
    };
    let per = |n: u64, t: Option<f64>| t.map(|t| n as f64 / t);
    let raw_cpu = per(raw_rays, raw.cpu);
    let prt_cpu = per(prt_rays, prt.cpu);
    let wall_eff = (raw_rays as f64 / raw.wall).recip() * (prt_rays as f64 / prt.wall);
    let embree = if opts.embree {
        Some(embree_timing(
            mesh, materials, masks, &verts, &opts.prt, &rays,
        )?)
    } else {
        None
    };
    let full_bake = opts
        .full_bake_samples
        .map(|s| full_bake(mesh, materials, masks, &opts.prt, s))
        .transpose()?;
    Ok(RaysBenchReport {
        triangles: mesh.indices.len(),
        vertices_traced: verts.len(),
        threads: rayon::current_num_threads(),
        preset: opts.prt.preset.name(),
        raw_rays,
        raw_rays_per_second: raw_rays as f64 / raw.wall,
        prt_rays,
        prt_rays_per_second: prt_rays as f64 / prt.wall,
        efficiency: raw_cpu.zip(prt_cpu).map_or(wall_eff, |(r, p)| p / r),
        efficiency_wall: wall_eff,
        raw_rays_per_cpu_second: raw_cpu,
        prt_rays_per_cpu_second: prt_cpu,
        prt_opaque_rays_per_second: opaque_rays as f64 / opaque_t.wall,
        prt_opaque_rays_per_cpu_second: per(opaque_rays, opaque_t.cpu),
        raw_alpha_rays_per_second: raw_rays as f64 / raw_alpha.wall,
        raw_alpha_rays_per_cpu_second: per(raw_rays, raw_alpha.cpu),
        efficiency_alpha: per(raw_rays, raw_alpha.cpu).zip(prt_cpu).map_or(
            prt_rays as f64 / prt.wall * raw_alpha.wall / raw_rays as f64,
            |(r, p)| p / r,
        ),
        presets,
        full_bake,
        embree_rays_per_second: embree.map(|e| raw_rays as f64 / e.raw.wall),
        embree_rays_per_cpu_second: embree.and_then(|e| per(raw_rays, e.raw.cpu)),
        embree_build_seconds: embree.map(|e| e.build),
        prt_over_embree: embree.map(|e| prt_rays as f64 / prt.wall * e.raw.wall / raw_rays as f64),
        prt_embree_rays: embree.map(|e| e.prt_rays),
        prt_embree_rays_per_second: embree.map(|e| e.prt_rays as f64 / e.prt.wall),
        prt_embree_rays_per_cpu_second: embree.and_then(|e| per(e.prt_rays, e.prt.cpu)),
        prt_embree_over_embree: embree
            .map(|e| e.prt_rays as f64 / e.prt.wall * e.raw.wall / raw_rays as f64),
        prt_embree_over_embree_cpu: embree.and_then(|e| {
            per(e.prt_rays, e.prt.cpu)
                .zip(per(raw_rays, e.raw.cpu))
                .map(|(p, r)| p / r)
        }),
    })
}

/// The raw rays through Embree with the alpha test, and the PRT of `verts` on Embree.
#[cfg(feature = "embree")]
fn embree_timing(
    mesh: &Mesh,
    materials: &[PrtMaterial],
    masks: &[Option<AlphaMask>],
    verts: &[u32],
    o: &PrtOptions,
    rays: &[Ray],
) -> Result<EmbreeTimes> {
    let start = Instant::now();
    let scene = crate::trace::embree::EmbreeScene::build(mesh, masks)?;
    let build = start.elapsed().as_secs_f64();
    let raw = time_best(|| {
        let hits: usize = rays
            .par_iter()
            .map(|r| scene.closest_hit(r).is_some() as usize)
            .sum();
        std::hint::black_box(hits);
    });
    let o = PrtOptions {
        tracer: prt::PrtTracer::Embree,
        ..o.clone()
    };
    let (prt_rays, prt) = prt_timing(&scene, mesh, materials, verts, &o);
    Ok(EmbreeTimes {
        build,
        raw,
        prt_rays,
        prt,
    })
}

#[cfg(not(feature = "embree"))]
fn embree_timing(
    _mesh: &Mesh,
    _materials: &[PrtMaterial],
    _masks: &[Option<AlphaMask>],
    _verts: &[u32],
    _o: &PrtOptions,
    _rays: &[Ray],
) -> Result<EmbreeTimes> {
    Err(crate::error::Error::runtime(
        "--embree needs a build with the cargo feature `embree` (cargo build --features embree)",
    ))
}

/// The first rays of the PRT paths of `verts`, without the PRT machinery: origin offset along
/// the normal, cosine-distributed directions (pseudo-random here; the distribution is the same).
fn hemisphere_rays(mesh: &Mesh, verts: &[u32], o: &PrtOptions) -> Vec<Ray> {
    let (lo, hi) = mesh.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
    let eps = o.offset * (Vec3A::from(hi) - Vec3A::from(lo)).length().max(1e-6);
    let mut rays = Vec::with_capacity(verts.len() * 2 * o.samples as usize);
    for &v in verts {
        let n = Vec3A::from(mesh.normals[v as usize]).normalize_or(Vec3A::Z);
        let p = Vec3A::from(mesh.positions[v as usize]);
        let mut rng = crate::trace::Rng::hashed(v as u64);
        for side in [n, -n] {
            for _ in 0..o.samples {
                let d = cosine_hemisphere(side, rng.f32(), rng.f32());
                rays.push(Ray::new(p + side * eps, d, 0.0));
            }
        }
    }
    rays
}

/// Raw obvhs closest-hit traversal of `rays`.
fn raw_timing(bvh: &ModelBvh, rays: &[Ray]) -> Timing {
    let tris = bvh.raw_triangles();
    time_best(|| {
        let hits: usize = rays
            .par_iter()
            .map(|r| bvh.raw_closest_t(&tris, r).is_finite() as usize)
            .sum();
        std::hint::black_box(hits);
    })
}

/// PRT over `verts`: (rays traced, timing).
fn prt_timing<T: crate::trace::ModelTracer>(
    bvh: &T,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    verts: &[u32],
    o: &PrtOptions,
) -> (u64, Timing) {
    let mut rays = 0;
    let t = time_best(|| {
        rays = prt::bake_prt_subset(bvh, mesh, materials, o, verts, &|_| {}).rays;
    });
    (rays, t)
}

fn full_bake(
    mesh: &Mesh,
    materials: &[PrtMaterial],
    masks: &[Option<AlphaMask>],
    o: &PrtOptions,
    samples: u32,
) -> Result<FullBake> {
    let o = PrtOptions {
        samples,
        ..o.clone()
    };
    let (start, cpu0) = (Instant::now(), cpu_seconds());
    let bvh = ModelBvh::build_split(mesh, masks, o.preset, o.alpha_split)?;
    let build_seconds = start.elapsed().as_secs_f64();
    let t = prt::bake_prt_with(&bvh, mesh, materials, &o, &|_| {});
    let seconds = start.elapsed().as_secs_f64();
    let cpu_seconds = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
    Ok(FullBake {
        vertices: t.vertices,
        samples,
        bounces: o.bounces,
        seconds,
        cpu_seconds,
        build_seconds,
        rays: t.rays,
        rays_per_second: t.rays as f64 / (seconds - build_seconds).max(1e-9),
    })
}
