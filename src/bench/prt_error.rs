//! `bake bench prt-error`: the PRT's error against a converged reference, against wall time,
//! per sampler and sample count: the time to a transfer of a given quality.
//!
//! The error ([`crate::prt::error`]) is the RMS over vertices, sides, sets, coefficients and
//! channels of the difference from the reference, relative to the reference's RMS, with the
//! reference's own noise measured (two independent halves, other seeds) and subtracted. The
//! vertices are an even stride over the model (`vertices`, default 1,000); times are measured
//! on them and projected to the whole model in proportion to its vertex count. The reference
//! is cached in a file keyed by the model, the options and the vertex sample.
//!
//! Methods: `fixed` (today's sampler: the same count per side, a scrambled 2-D Sobol first
//! direction, pseudo-random bounces) and `adaptive` ([`prt::bake_prt_adaptive`]: the same
//! mean count, spread over the sides in proportion to their standard deviation) and `filtered`
//! (`fixed`, then each vertex averaged with its neighbours of like normal, [`crate::prt::filter`];
//! its time includes baking the neighbourhoods, and its projected time is per vertex baked)
//! and `embree` (`fixed` on the Embree backend, `tracer = "embree"`; cargo feature `embree`:
//! the same sampler, so its error is that of `fixed` and only the time differs) and `gpu`
//! (`fixed`'s estimator on the GPU, [`crate::prt::gpu`]: its time includes uploading the BVH and
//! compiling the shader, not opening the device; the report names the adapter).

use super::cpu_seconds;
use crate::error::{Error, Result};
use crate::model::Mesh;
use crate::prt::error::{Shares, TransferError, error_shares, signal_shares, transfer_error};
use crate::prt::filter::{FilterOptions, Neighbourhoods, filter_vertices};
use crate::prt::transfer::{self as prt, Adaptive, PrtMaterial, PrtOptions, Transfer};
use crate::trace::{AlphaMask, ModelBvh};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Seeds of the reference's two halves (the estimates use `PrtOptions::seed`).
const REFERENCE_SEEDS: [u64; 2] = [0x5EED_0000_0001, 0x5EED_0000_0002];
/// Bumped when the sampler's output changes, so that cached references are recomputed.
const REFERENCE_VERSION: u32 = 1;

/// A sampler the benchmark compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    Fixed,
    Adaptive,
    /// `fixed`, then [`crate::prt::filter`] over each measured vertex's neighbourhood (which
    /// is baked too, and timed).
    Filtered,
    /// `fixed` traced on Embree ([`prt::PrtTracer::Embree`]; cargo feature `embree`).
    Embree,
    /// `fixed` traced by the wgpu compute shader ([`crate::prt::gpu`]).
    Gpu,
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Fixed,
        Method::Adaptive,
        Method::Filtered,
        Method::Embree,
        Method::Gpu,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Method::Fixed => "fixed",
            Method::Adaptive => "adaptive",
            Method::Filtered => "filtered",
            Method::Embree => "embree",
            Method::Gpu => "gpu",
        }
    }
}

/// What to measure.
#[derive(Debug, Clone)]
pub struct PrtErrorOptions {
    /// Vertices measured (an even stride over the model; 0: all).
    pub vertices: usize,
    /// Paths per side of the reference (split into two halves of half as many).
    pub reference_samples: u32,
    /// Paths per side of the measured runs.
    pub samples: Vec<u32>,
    pub methods: Vec<Method>,
    /// Bounces, preset, seed and the rest of the measured runs.
    pub prt: PrtOptions,
    /// Folder of the cached references (`None`: no cache).
    pub cache: Option<PathBuf>,
    /// Radius of the `filtered` method, relative to the model's bounding-box diagonal, and the
    /// least cosine between filtered normals.
    pub filter_radius: f32,
    pub filter_min_cos: f32,
}

#[derive(Debug, Clone, Serialize)]
pub struct ErrorRun {
    pub method: &'static str,
    pub samples: u32,
    pub wall_seconds: f64,
    pub cpu_seconds: Option<f64>,
    /// Corrected relative RMS error (0.01 = 1 %).
    pub rms_error: f64,
    /// Uncorrected relative RMS difference from the reference.
    pub rms_difference: f64,
    pub rays: u64,
    /// Where the squared error lies (by side, set, SH band; each part noise-corrected).
    pub error_shares: Shares,
    /// `wall_seconds` scaled to every vertex of the model (BVH build excluded).
    pub projected_wall_seconds: f64,
    pub projected_cpu_seconds: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct PrtErrorReport {
    pub model: String,
    pub triangles: usize,
    pub vertices: usize,
    pub vertices_measured: usize,
    /// Vertices left after welding those with equal position, normal and material.
    pub unique_vertices: usize,
    pub bounces: u32,
    /// Sides traced by the runs and the reference (`prt.sides`).
    pub sides: prt::PrtSides,
    pub threads: usize,
    /// The GPU adapter of the `gpu` method (absent without it).
    pub adapter: Option<String>,
    pub reference_samples: u32,
    /// The reference's own relative RMS noise (subtracted from every run's error).
    pub reference_noise: f64,
    pub reference_seconds: f64,
    pub reference_cached: bool,
    /// Where the reference's signal energy lies (by side, set, SH band).
    pub signal_shares: Shares,
    pub build_seconds: f64,
    /// Embree scene build time (method `embree` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub embree_build_seconds: Option<f64>,
    pub runs: Vec<ErrorRun>,
}

/// Runs the benchmark on `mesh` (named `model` in the report).
pub fn bench_prt_error(
    model: &str,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    masks: &[Option<AlphaMask>],
    opts: &PrtErrorOptions,
) -> Result<PrtErrorReport> {
    if opts.reference_samples < 2 {
        return Err(Error::usage("--reference-samples: expected at least 2"));
    }
    let total = mesh.positions.len();
    let stride = match opts.vertices {
        0 => 1,
        k => (total / k).max(1),
    };
    let verts: Vec<u32> = (0..total as u32)
        .step_by(stride)
        .take(if opts.vertices == 0 {
            total
        } else {
            opts.vertices
        })
        .collect();
    // The device is opened before any timing (once per process).
    let adapter = match opts.methods.contains(&Method::Gpu) {
        true => Some(crate::gpu::shared_gpu()?.adapter.to_string()),
        false => None,
    };
    let start = Instant::now();
    let bvh = ModelBvh::build_split(mesh, masks, opts.prt.preset, opts.prt.alpha_split)?;
    let build_seconds = start.elapsed().as_secs_f64();
    // The Embree scene, before anything slow runs: a binary without the feature refuses here.
    let start = Instant::now();
    let embree = opts
        .methods
        .contains(&Method::Embree)
        .then(|| {
            let o = PrtOptions {
                tracer: prt::PrtTracer::Embree,
                ..opts.prt.clone()
            };
            prt::PrtScene::build(mesh, masks, &o)
        })
        .transpose()?;
    let embree_build_seconds = embree.as_ref().map(|_| start.elapsed().as_secs_f64());
    let start = Instant::now();
    let (halves, cached) = reference(&bvh, mesh, materials, &verts, opts)?;
    let reference_seconds = start.elapsed().as_secs_f64();
    let mut runs = Vec::new();
    let mut noise = 0.0;
    for &method in &opts.methods {
        for &samples in &opts.samples {
            let o = PrtOptions {
                samples,
                ..opts.prt.clone()
            };
            let (t, wall, cpu, baked) = match method {
                Method::Filtered => filtered(&bvh, mesh, materials, &o, &verts, opts),
                Method::Embree => {
                    let scene = embree.as_ref().expect("built above for this method");
                    let o = PrtOptions {
                        tracer: prt::PrtTracer::Embree,
                        ..o
                    };
                    let (start, cpu0) = (Instant::now(), cpu_seconds());
                    let t = scene.bake_subset(mesh, materials, &o, &verts);
                    let wall = start.elapsed().as_secs_f64();
                    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
                    (t, wall, cpu, verts.len())
                }
                _ => {
                    let (start, cpu0) = (Instant::now(), cpu_seconds());
                    let t = bake(method, &bvh, mesh, materials, &o, &verts)?;
                    let wall = start.elapsed().as_secs_f64();
                    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
                    (t, wall, cpu, verts.len())
                }
            };
            let scale = total as f64 / baked.max(1) as f64;
            let e: TransferError = transfer_error(&t, &halves[0], &halves[1]);
            noise = e.reference_noise;
            runs.push(ErrorRun {
                method: method.name(),
                samples,
                wall_seconds: wall,
                cpu_seconds: cpu,
                rms_error: e.rms_error,
                rms_difference: e.rms_difference,
                rays: t.rays,
                error_shares: error_shares(&t, &halves[0], &halves[1]),
                projected_wall_seconds: wall * scale,
                projected_cpu_seconds: cpu.map(|c| c * scale),
            });
        }
    }
    Ok(PrtErrorReport {
        model: model.to_string(),
        triangles: mesh.indices.len(),
        vertices: total,
        vertices_measured: verts.len(),
        unique_vertices: prt::weld_key_count(mesh),
        sides: opts.prt.sides,
        bounces: opts.prt.bounces,
        threads: rayon::current_num_threads(),
        adapter,
        reference_samples: opts.reference_samples,
        reference_noise: noise,
        reference_seconds,
        reference_cached: cached,
        signal_shares: signal_shares(&halves[0], &halves[1]),
        build_seconds,
        embree_build_seconds,
        runs,
    })
}

/// The `filtered` method: bakes the measured vertices' neighbourhoods with the fixed sampler,
/// then filters: (transfer of `verts`, wall and CPU seconds, vertices baked).
fn filtered(
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    o: &PrtOptions,
    verts: &[u32],
    opts: &PrtErrorOptions,
) -> (Transfer, f64, Option<f64>, usize) {
    let (lo, hi) = bvh.bounds();
    let f = FilterOptions {
        radius: opts.filter_radius * (hi - lo).length().max(1e-6),
        min_cos: opts.filter_min_cos,
    };
    let (start, cpu0) = (Instant::now(), cpu_seconds());
    let hoods = Neighbourhoods::new(mesh, f);
    let mut union: Vec<u32> = verts
        .iter()
        .flat_map(|&v| hoods.of(v))
        .map(|(u, _)| u)
        .collect();
    union.sort_unstable();
    union.dedup();
    let t = prt::bake_prt_subset(bvh, mesh, materials, o, &union, &|_| {});
    let row = |u: u32| union.binary_search(&u).ok();
    let t = filter_vertices(&hoods, &t, verts, &row);
    let wall = start.elapsed().as_secs_f64();
    let cpu = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
    (t, wall, cpu, union.len())
}

fn bake(
    method: Method,
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    o: &PrtOptions,
    verts: &[u32],
) -> Result<Transfer> {
    Ok(match method {
        Method::Fixed | Method::Filtered | Method::Embree => {
            prt::bake_prt_subset(bvh, mesh, materials, o, verts, &|_| {})
        }
        Method::Adaptive => prt::bake_prt_adaptive(
            bvh,
            mesh,
            materials,
            o,
            verts,
            Adaptive::for_samples(o.samples),
        ),
        Method::Gpu => {
            let gpu = crate::gpu::shared_gpu()?;
            crate::prt::gpu::bake_prt_gpu_subset(gpu, bvh, mesh, materials, o, verts, &|_| {})?
        }
    })
}

/// The reference's two halves, from the cache or baked (and then cached); `true` if cached.
fn reference(
    bvh: &ModelBvh,
    mesh: &Mesh,
    materials: &[PrtMaterial],
    verts: &[u32],
    opts: &PrtErrorOptions,
) -> Result<([Transfer; 2], bool)> {
    // The reference is always traced on the CPU backend (obvhs): an independent oracle for
    // the `embree` method.
    let half = PrtOptions {
        samples: opts.reference_samples / 2,
        tracer: prt::PrtTracer::Cpu,
        ..opts.prt.clone()
    };
    let file = opts.cache.as_ref().map(|dir| {
        dir.join(format!(
            "prt-reference-{}.bin",
            reference_key(mesh, materials, verts, &half)
        ))
    });
    if let Some(f) = &file
        && let Some(h) = read_reference(f, verts.len(), &half)
    {
        return Ok((h, true));
    }
    let halves = REFERENCE_SEEDS.map(|seed| {
        let o = PrtOptions {
            seed,
            ..half.clone()
        };
        prt::bake_prt_subset(bvh, mesh, materials, &o, verts, &|_| {})
    });
    if let Some(f) = &file {
        write_reference(f, &halves)?;
    }
    Ok((halves, false))
}

/// A hash of everything the reference depends on.
fn reference_key(
    mesh: &Mesh,
    materials: &[PrtMaterial],
    verts: &[u32],
    half: &PrtOptions,
) -> String {
    let mut h = blake3::Hasher::new();
    h.update(&REFERENCE_VERSION.to_le_bytes());
    h.update(bytemuck::cast_slice(&mesh.positions));
    h.update(bytemuck::cast_slice(&mesh.normals));
    h.update(bytemuck::cast_slice(&mesh.indices));
    h.update(bytemuck::cast_slice(&mesh.triangle_materials));
    for m in materials {
        h.update(bytemuck::cast_slice(&m.albedo));
        h.update(&m.translucence.to_le_bytes());
    }
    // `prt.sides = "auto"` reads the mesh's one-sided materials.
    let one_sided: Vec<u8> = mesh
        .materials
        .iter()
        .map(|m| !m.double_sided as u8)
        .collect();
    h.update(&one_sided);
    h.update(bytemuck::cast_slice(verts));
    h.update(serde_json::to_string(half).unwrap_or_default().as_bytes());
    h.finalize().to_hex()[..32].to_string()
}

fn read_reference(file: &Path, vertices: usize, half: &PrtOptions) -> Option<[Transfer; 2]> {
    let bytes = std::fs::read(file).ok()?;
    let n = vertices * prt::PER_VERTEX * 3;
    if bytes.len() != 2 * n * 4 {
        return None;
    }
    let floats: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let transfer = |f: &[f32]| Transfer {
        vertices: vertices as u32,
        samples: half.samples,
        bounces: half.bounces,
        coeffs: f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        rays: 0,
        skipped_vertices: 0,
    };
    Some([transfer(&floats[..n]), transfer(&floats[n..])])
}

fn write_reference(file: &Path, halves: &[Transfer; 2]) -> Result<()> {
    let mut bytes = Vec::new();
    for t in halves {
        for c in t.coeffs.iter().flatten() {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::pack::write_atomic(file, &bytes)
}

/// The report as text: one line per run.
pub fn report_text(r: &PrtErrorReport) -> String {
    let mut text = format!(
        "{}: {} triangles, {} vertices ({} unique), {} measured, {} bounces, sides {}, {} threads\n\
         reference: {} paths per side (two halves), noise {:.3} %, {:.1} s{}\n\
         method     samples   RMS error   wall s (measured)   CPU s   projected wall s (all vertices)\n",
        r.model,
        r.triangles,
        r.vertices,
        r.unique_vertices,
        r.vertices_measured,
        r.bounces,
        r.sides.name(),
        r.threads,
        r.reference_samples,
        r.reference_noise * 100.0,
        r.reference_seconds,
        if r.reference_cached { " (cached)" } else { "" },
    );
    if let Some(a) = &r.adapter {
        text.push_str(&format!("gpu method on {a}\n"));
    }
    for run in &r.runs {
        text.push_str(&format!(
            "{:<10} {:>7}   {:>8.3} %   {:>8.2}   {:>8}   {:>10.1}\n",
            run.method,
            run.samples,
            run.rms_error * 100.0,
            run.wall_seconds,
            run.cpu_seconds.map_or("-".into(), |c| format!("{c:.2}")),
            run.projected_wall_seconds,
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_key_includes_the_sides_and_the_one_sided_materials() {
        let (mut mesh, tex) = crate::prt::plant::procedural_plant(100, 1);
        let mats = prt::prt_materials(&mesh, &[Some(tex)], 0.3);
        let verts = [0u32, 1, 2];
        let with = |sides| PrtOptions {
            sides,
            ..PrtOptions::default()
        };
        let key = |mesh: &Mesh, sides| reference_key(mesh, &mats, &verts, &with(sides));
        let auto = key(&mesh, prt::PrtSides::Auto);
        assert_ne!(auto, key(&mesh, prt::PrtSides::Both));
        assert_ne!(auto, key(&mesh, prt::PrtSides::Front));
        mesh.materials[0].double_sided = false;
        assert_ne!(auto, key(&mesh, prt::PrtSides::Auto));
    }
}
