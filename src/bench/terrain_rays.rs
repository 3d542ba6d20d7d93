//! `bake bench terrain-rays`: heightfield tracing ([`Heightfield`], through the min/max
//! quadtree) against the triangle-mesh terrain (obvhs CWBVH over two triangles per cell, the
//! preset the trace scene used) on the same rays in the same run.
//!
//! Terrain: [`super::terrain::generated_terrain`] (rolling hills with per-sample noise,
//! 1 m spacing). Ray sets, all starting at random surface points lifted 1 cm along the normal:
//! `gather`: cosine-distributed directions around the normal, closest hit (what light-map and
//! environment-map gathering traces); `shadow`: any hit towards a sun 25° above the horizon;
//! `grazing`: closest hit along directions 0–5° above the horizon (the worst case for both).
//! Every set is traced over rayon on all threads, best of three, wall and CPU time (the
//! machine is shared); the two answers are compared ray by ray.

use super::{Report, Timing, time_best};
use crate::error::Result;
use crate::trace::{BuildPreset, Heightfield, ModelBvh, Ray, Rng, cosine_hemisphere};
use glam::Vec3A;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, Clone, Serialize)]
pub struct RaySetResult {
    pub set: &'static str,
    pub rays: usize,
    pub hits: usize,
    pub heightfield_rays_per_second: f64,
    pub mesh_rays_per_second: f64,
    pub heightfield_rays_per_cpu_second: Option<f64>,
    pub mesh_rays_per_cpu_second: Option<f64>,
    /// Heightfield over mesh, per CPU-second where measured, else wall clock.
    pub speedup: f64,
    /// Rays whose hit/miss or hit distance (beyond 1e-5 relative) differ.
    pub mismatches: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct TerrainRaysReport {
    pub samples: [u32; 2],
    pub triangles: u64,
    pub threads: usize,
    pub heightfield_build_seconds: f64,
    pub mesh_build_seconds: f64,
    pub sets: Vec<RaySetResult>,
}

/// Runs the benchmark on a generated `size`² terrain with `rays` rays per set.
pub fn bench_terrain_rays_report(size: u32, rays: usize) -> Result<TerrainRaysReport> {
    let t = super::terrain::generated_terrain(size.max(2));
    let start = Instant::now();
    let hf = Heightfield::new(&t)?;
    let heightfield_build_seconds = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let mesh = crate::trace::pack_scene::terrain_mesh(&t);
    let bvh = ModelBvh::build(&mesh, &[], BuildPreset::Medium)?;
    let mesh_build_seconds = start.elapsed().as_secs_f64();
    let sun = Vec3A::new(0.6, 0.5, 25f32.to_radians().tan()).normalize();
    let mut sets = Vec::new();
    for set in ["gather", "shadow", "grazing"] {
        let rays = ray_set(&hf, set, sun, rays);
        sets.push(if set == "shadow" {
            any_set(&hf, &bvh, set, &rays)
        } else {
            closest_set(&hf, &bvh, set, &rays)
        });
    }
    Ok(TerrainRaysReport {
        samples: [t.width, t.height],
        triangles: mesh.indices.len() as u64,
        threads: rayon::current_num_threads(),
        heightfield_build_seconds,
        mesh_build_seconds,
        sets,
    })
}

/// `n` rays of one set from random surface points (deterministic).
fn ray_set(hf: &Heightfield, set: &str, sun: Vec3A, n: usize) -> Vec<Ray> {
    let (lo, hi) = hf.bounds();
    (0..n as u64)
        .into_par_iter()
        .map(|k| {
            let mut rng = Rng::hashed(k ^ 0x007e_44a1);
            let (x, y) = (
                lo.x + (hi.x - lo.x) * rng.f32(),
                lo.y + (hi.y - lo.y) * rng.f32(),
            );
            // The surface point under (x, y): a vertical ray down from above the terrain.
            let down = Ray::new(Vec3A::new(x, y, hi.z + 1.0), Vec3A::NEG_Z, 0.0);
            let (p, n) = hf
                .closest_hit(&down)
                .map_or((Vec3A::new(x, y, lo.z), Vec3A::Z), |h| {
                    let s = hf.hit_point(&h);
                    (s.position, s.normal)
                });
            let d = match set {
                "gather" => cosine_hemisphere(n, rng.f32(), rng.f32()),
                "shadow" => sun,
                _ => {
                    let (phi, elev) = (std::f32::consts::TAU * rng.f32(), rng.f32());
                    let e = (5.0 * elev).to_radians();
                    Vec3A::new(phi.cos() * e.cos(), phi.sin() * e.cos(), e.sin())
                }
            };
            Ray::new(p + n * 0.01, d, 0.0)
        })
        .collect()
}

fn rate(n: usize, t: Timing) -> (f64, Option<f64>) {
    (n as f64 / t.wall, t.cpu.map(|c| n as f64 / c))
}

fn result(
    set: &'static str,
    n: usize,
    hits: usize,
    mismatches: usize,
    (h, m): (Timing, Timing),
) -> RaySetResult {
    let (hw, hc) = rate(n, h);
    let (mw, mc) = rate(n, m);
    RaySetResult {
        set,
        rays: n,
        hits,
        heightfield_rays_per_second: hw,
        mesh_rays_per_second: mw,
        heightfield_rays_per_cpu_second: hc,
        mesh_rays_per_cpu_second: mc,
        speedup: hc.zip(mc).map_or(hw / mw, |(h, m)| h / m),
        mismatches,
    }
}

fn closest_set(hf: &Heightfield, bvh: &ModelBvh, set: &'static str, rays: &[Ray]) -> RaySetResult {
    let mut a = Vec::new();
    let mut b = Vec::new();
    let th = time_best(|| a = hf.closest_hits(rays));
    let tm = time_best(|| b = bvh.closest_hits(rays));
    let mismatches = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| match (x, y) {
            (Some(x), Some(y)) => (x.t - y.t).abs() > 1e-5 * x.t.abs().max(1.0),
            (x, y) => x.is_some() != y.is_some(),
        })
        .count();
    let hits = a.iter().filter(|h| h.is_some()).count();
    result(set, rays.len(), hits, mismatches, (th, tm))
}

fn any_set(hf: &Heightfield, bvh: &ModelBvh, set: &'static str, rays: &[Ray]) -> RaySetResult {
    let mut a = Vec::new();
    let mut b = Vec::new();
    let th = time_best(|| a = hf.any_hits(rays));
    let tm = time_best(|| b = bvh.any_hits(rays));
    let mismatches = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    let hits = a.iter().filter(|&&h| h).count();
    result(set, rays.len(), hits, mismatches, (th, tm))
}

/// The `bake bench terrain-rays` report and its table.
pub fn bench_terrain_rays(size: u32, rays: usize) -> Result<Report> {
    let r = bench_terrain_rays_report(size, rays)?;
    let m = |v: Option<f64>| v.map_or("-".into(), |v| format!("{:.3}", v / 1e6));
    let mut text = format!(
        "terrain {}×{} ({} triangles), {} threads; build: heightfield {:.3} s, mesh BVH {:.3} s\n\
         set       rays      hits   M rays/s heightfield (wall, CPU-s)   mesh (wall, CPU-s)   speedup  mismatches\n",
        r.samples[0],
        r.samples[1],
        r.triangles,
        r.threads,
        r.heightfield_build_seconds,
        r.mesh_build_seconds
    );
    for s in &r.sets {
        text.push_str(&format!(
            "{:<8} {:>7} {:>8}   {:>8.3} {:>8}                  {:>8.3} {:>8}      {:>6.2}  {}\n",
            s.set,
            s.rays,
            s.hits,
            s.heightfield_rays_per_second / 1e6,
            m(s.heightfield_rays_per_cpu_second),
            s.mesh_rays_per_second / 1e6,
            m(s.mesh_rays_per_cpu_second),
            s.speedup,
            s.mismatches
        ));
    }
    Ok(Report {
        json: serde_json::to_value(&r).unwrap_or_default(),
        text,
    })
}
