//! Per-instance environment maps (seed 000, 4.6.3): clustering and multiquadric interpolation.
pub mod bake;
pub mod cluster;
pub mod interp;
use crate::kdtree;
pub mod local;
pub mod section;
pub mod stage;
pub mod synthetic;

use cluster::{ClusterOptions, Clustering};
use rayon::prelude::*;
use section::ClustersMeta;

/// Per-instance neighbour indices and weights (k each, padded with sample 0 / weight 0).
pub type NeighbourWeights = (Vec<u32>, Vec<f32>);

/// The stage's result: the shared part (the clustering), the local part if stored, and every
/// instance's final error (shared + local against the input maps, relative as
/// [`ClusterOptions::error`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Compressed {
    pub clustering: Clustering,
    pub local: Option<local::LocalPart>,
    pub errors: Vec<f32>,
    /// The byte budget honoured (None: unlimited).
    pub budget: Option<u64>,
    /// The stored value of each sample (samples × dim): with a local part, the mean map of the
    /// sample's cluster (a low-pass of the members' noise and local occlusion); else None, the
    /// sample instance's own map.
    pub sample_values: Option<Vec<f32>>,
}

impl Compressed {
    /// The shared part alone (no local part, no budget).
    pub fn shared_only(c: Clustering) -> Compressed {
        let errors = c.errors.clone();
        Compressed {
            clustering: c,
            local: None,
            errors,
            budget: None,
            sample_values: None,
        }
    }

    /// The stored sample values (samples × dim).
    pub fn sample_rows(&self, values: &[f32], dim: usize) -> Vec<f32> {
        match &self.sample_values {
            Some(v) => v.clone(),
            None => self
                .clustering
                .samples
                .iter()
                .flat_map(|&s| &values[s as usize * dim..(s as usize + 1) * dim])
                .copied()
                .collect(),
        }
    }
    pub fn rms_error(&self) -> f32 {
        cluster::rms_of(&self.errors)
    }
    pub fn max_error(&self) -> f32 {
        cluster::max_of(&self.errors)
    }
    /// Bytes of the samples and the local part (the section's arrays without stored weights).
    pub fn packed_bytes(&self, dim: usize) -> u64 {
        let c = &self.clustering;
        let p = self.local.as_ref().map_or(0, |l| l.components);
        c.samples.len() as u64 * cluster::sample_bytes(dim)
            + local::local_bytes(c.assignment.len(), p, dim)
    }
    /// Raw maps over [`Self::packed_bytes`].
    pub fn compression(&self, dim: usize) -> f64 {
        let raw = (self.clustering.assignment.len() * dim * 4) as f64;
        let packed = self.packed_bytes(dim) as f64;
        if packed > 0.0 { raw / packed } else { 0.0 }
    }
}

/// Compresses the maps (issue 20): the split loop clusters them within the byte budget
/// ([`ClusterOptions::budget`], room kept for a local part of `opts.local` components); if it
/// stops at the budget with instances over the bound, the residual of the shared part goes into
/// the local part ([`local`]); if the bound holds first, no local part is stored.
pub fn compress(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
) -> Compressed {
    compress_denoised(positions, values, dim, opts, None, None)
}

/// [`compress`] with the local part Wiener-filtered by a noise covariance (dim × dim, the
/// maps' frame; [`local::fit_denoised`]): the stage's default with the `envmaps` section's
/// noise estimate; `scale`, a per-instance noise scale, is the bench's experimental
/// `--heteroscedastic`.
pub fn compress_denoised(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
    noise: Option<&[f64]>,
    scale: Option<&[f32]>,
) -> Compressed {
    let n = positions.len();
    let budget = opts.budget(n, dim);
    // The local part takes at most half the budget (small scenes: fewer components, since the
    // basis costs dim floats per component whatever the instance count).
    let mut p = (opts.local as usize).min(dim);
    if let Some(b) = budget {
        while p > 0 && local::local_bytes(n, p, dim) > b / 2 {
            p -= 1;
        }
    }
    let c =
        cluster::cluster_envmaps_limited(positions, values, dim, opts, opts.max_samples(n, dim, p));
    if !c.budget_limited || p == 0 || n == 0 {
        return Compressed {
            budget,
            ..Compressed::shared_only(c)
        };
    }
    let rows = cluster_means(values, dim, &c);
    let (nb, w) = instance_weights(positions, values, dim, &c);
    let mut rec = apply_weights_rows(&rows, dim, c.k, &nb, &w);
    let mut c = c;
    // The shared part's own errors, with the stored (mean) sample values.
    c.errors = relative_errors(&rec, values, dim, c.rms);
    let residual: Vec<f32> = values.par_iter().zip(&rec).map(|(v, r)| v - r).collect();
    let l = local::fit_denoised(&residual, dim, p, noise, scale);
    l.add_all(&mut rec);
    let errors = relative_errors(&rec, values, dim, c.rms);
    Compressed {
        clustering: c,
        local: Some(l),
        errors,
        budget,
        sample_values: Some(rows),
    }
}

/// The mean map of each cluster's members (samples × dim), summed in member order.
pub fn cluster_means(values: &[f32], dim: usize, c: &Clustering) -> Vec<f32> {
    let mut sum = vec![0.0f64; c.samples.len() * dim];
    let mut count = vec![0u32; c.samples.len()];
    for (i, &a) in c.assignment.iter().enumerate() {
        let a = a as usize;
        count[a] += 1;
        for (s, &v) in sum[a * dim..(a + 1) * dim]
            .iter_mut()
            .zip(&values[i * dim..(i + 1) * dim])
        {
            *s += v as f64;
        }
    }
    sum.chunks(dim)
        .zip(&count)
        .flat_map(|(m, &n)| m.iter().map(move |&x| (x / n.max(1) as f64) as f32))
        .collect()
}

/// Per-instance RMS of (a − b) relative to `rms`.
pub fn relative_errors(a: &[f32], b: &[f32], dim: usize, rms: f32) -> Vec<f32> {
    a.par_chunks(dim)
        .zip(b.par_chunks(dim))
        .map(|(x, y)| {
            let e: f64 = x.iter().zip(y).map(|(p, q)| ((p - q) as f64).powi(2)).sum();
            ((e / dim as f64).sqrt() / rms.max(f32::MIN_POSITIVE) as f64) as f32
        })
        .collect()
}

/// Every instance's reconstruction from a [`Compressed`] (the shared part from stored-style
/// f32 weights plus the local part), as the runtime forms it, world frame.
pub fn reconstruct_all(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    z: &Compressed,
) -> Vec<f32> {
    let c = &z.clustering;
    let (nb, w) = instance_weights(positions, values, dim, c);
    let mut rec = apply_weights_rows(&z.sample_rows(values, dim), dim, c.k, &nb, &w);
    if let Some(l) = &z.local {
        l.add_all(&mut rec);
    }
    rec
}

/// Compresses the maps and, if asked, computes every instance's interpolation weights.
pub fn cluster_and_weigh(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
    store_weights: bool,
) -> (ClustersMeta, Compressed, Option<NeighbourWeights>) {
    cluster_and_weigh_noisy(positions, values, dim, opts, store_weights, None)
}

/// [`cluster_and_weigh`] with the input's noise estimate (`envmaps` section): with
/// [`ClusterOptions::denoise`] the local part is Wiener-filtered with its covariance, and the
/// metadata states the noise.
fn cluster_and_weigh_noisy(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
    store_weights: bool,
    noise: Option<&section::EnvmapNoise>,
) -> (ClustersMeta, Compressed, Option<NeighbourWeights>) {
    let filter = noise.filter(|_| opts.denoise && dim == section::DIM);
    let z = compress_denoised(
        positions,
        values,
        dim,
        opts,
        filter.map(|nz| nz.covariance.as_slice()),
        None,
    );
    let c = &z.clustering;
    let input_noise_relative = match noise {
        Some(nz) if c.rms > 0.0 => (nz.mean_variance().sqrt() / c.rms as f64) as f32,
        _ => 0.0,
    };
    let weights = store_weights.then(|| instance_weights(positions, values, dim, c));
    let meta = ClustersMeta {
        instances: positions.len() as u64,
        clusters: c.samples.len() as u64,
        dim: dim as u32,
        k: c.k as u32,
        radius: c.radius,
        constant_term: true,
        error_bound: opts.error,
        rms_error_relative: z.rms_error(),
        max_error_relative: z.max_error(),
        ill_conditioned: c.ill_conditioned as u64,
        weights: store_weights,
        local_components: z.local.as_ref().map_or(0, |l| l.components as u32),
        max_bytes: z.budget.unwrap_or(0),
        shared_rms_error_relative: c.rms_error(),
        input_noise_relative,
        denoised: filter.is_some() && z.local.is_some(),
    };
    (meta, z, weights)
}

/// The k sample neighbours (indices into `c.samples`, nearest first) and multiquadric weights of
/// every instance, k per instance, padded with sample 0 and weight 0. One pass without
/// allocations per instance, in Morton order so that consecutive instances with the same
/// neighbour set reuse its factorization ([`interp::MultiquadricSolver`]).
pub fn instance_weights(
    positions: &[[f32; 3]],
    _values: &[f32],
    _dim: usize,
    c: &Clustering,
) -> NeighbourWeights {
    let pts: Vec<[f32; 3]> = c.samples.iter().map(|&s| positions[s as usize]).collect();
    let tree = kdtree::KdTree::build(&pts);
    let (k, n) = (c.k.max(1), positions.len());
    // Computed in Morton order (neighbouring instances share neighbour sets, and the solver
    // keeps the factorizations of the last few), then put back in instance order.
    let order = kdtree::morton_order(positions);
    // Zeroed by writing on this thread (see `apply_weights`).
    let (mut nb_z, mut w_z) = (Vec::with_capacity(n * k), Vec::with_capacity(n * k));
    nb_z.resize(n * k, 0u32);
    w_z.resize(n * k, 0.0f32);
    nb_z.par_chunks_mut(k)
        .zip(w_z.par_chunks_mut(k))
        .zip(order.par_iter().map(|&i| positions[i as usize]))
        .for_each_init(
            || {
                let solver = interp::MultiquadricSolver::default();
                (Vec::new(), Vec::new(), solver, Vec::new(), None)
            },
            |(near, ids, solver, wt, prev), ((nb_out, w_out), x)| {
                tree.nearest_after(x, k.min(pts.len()), *prev, near);
                *prev = near.last().map(|&(d2, _)| (x, d2));
                // Solved under instance ids, as the clustering did (the same weights).
                ids.clear();
                ids.extend(near.iter().map(|&(_, i)| c.samples[i as usize]));
                let pos = |id: u32| positions[id as usize];
                if solver.weights(ids, pos, x, c.radius, true, wt).is_err() {
                    // Ill-conditioned (counted by the clustering): the nearest sample.
                    wt.clear();
                    wt.resize(near.len(), 0.0);
                    wt[0] = 1.0;
                }
                for (j, (&(_, i), &wv)) in near.iter().zip(wt.iter()).enumerate() {
                    nb_out[j] = i;
                    w_out[j] = wv as f32;
                }
            },
        );
    let mut nb = vec![0u32; n * k];
    let mut w = vec![0.0f32; n * k];
    for (z, &i) in order.iter().enumerate() {
        let (src, dst) = (z * k..(z + 1) * k, i as usize * k..(i as usize + 1) * k);
        nb[dst.clone()].copy_from_slice(&nb_z[src.clone()]);
        w[dst].copy_from_slice(&w_z[src]);
    }
    (nb, w)
}

/// Reconstructs every instance (`dim` floats each) from per-instance neighbours (indices into
/// `samples`, k per instance) and weights, as the runtime does with stored weights.
pub fn apply_weights(
    values: &[f32],
    dim: usize,
    samples: &[u32],
    k: usize,
    neighbours: &[u32],
    weights: &[f32],
) -> Vec<f32> {
    let dim1 = dim.max(1);
    // The samples' maps gathered first: a few megabytes in a row instead of rows spread over
    // all instances' maps (one TLB miss per neighbour otherwise).
    let rows: Vec<f32> = samples
        .iter()
        .flat_map(|&s| &values[s as usize * dim1..(s as usize + 1) * dim1])
        .copied()
        .collect();
    apply_weights_rows(&rows, dim, k, neighbours, weights)
}

/// [`apply_weights`] from the samples' values themselves (`rows`: samples × dim).
pub(crate) fn apply_weights_rows(
    rows: &[f32],
    dim: usize,
    k: usize,
    neighbours: &[u32],
    weights: &[f32],
) -> Vec<f32> {
    let (k, dim) = (k.max(1), dim.max(1));
    // Zeroed by writing, on this thread: the first touch of a fresh page faults, and two threads
    // faulting pages into the same mapping mostly wait for each other (measured: the parallel
    // reconstruction of 200,000 maps took 0.175 s with a lazily zeroed output, 0.057 s like this).
    let mut out = Vec::with_capacity(neighbours.len() / k * dim);
    out.resize(neighbours.len() / k * dim, 0.0f32);
    const BLOCK: usize = 256;
    out.par_chunks_mut(dim * BLOCK)
        .zip(
            neighbours
                .par_chunks(k * BLOCK)
                .zip(weights.par_chunks(k * BLOCK)),
        )
        .for_each(|(o, (nb, w))| {
            for (o, (nb, w)) in o.chunks_exact_mut(dim).zip(nb.chunks(k).zip(w.chunks(k))) {
                // f32 sums of k terms, as the runtime (the renderer) forms them from the stored
                // f32 weights; vectorized over the coefficients.
                for (&j, &wj) in nb.iter().zip(w) {
                    let row = &rows[j as usize * dim..(j as usize + 1) * dim];
                    for (a, &v) in o.iter_mut().zip(row) {
                        *a += wj * v;
                    }
                }
            }
        });
    out
}

/// Rotates maps stored in each instance's frame back into the world frame (the inverse of the
/// rotation in `bake::bake_one`): neighbouring instances have unrelated rotations, so only
/// world-frame maps vary smoothly over the terrain and can be clustered and interpolated. The
/// runtime rotates an interpolated map by the instance's own rotation.
pub fn to_world_frame(
    sky: &mut [[[f32; 3]; 16]],
    sun: &mut [[[f32; 3]; 16]],
    rotation_deg: &[f32],
) {
    let rot = |m: &mut [[f32; 3]; 16], deg: f32| {
        *m = crate::sh::ShRadiance { coeffs: *m }
            .rotated_z((deg as f64).to_radians())
            .coeffs;
    };
    sky.par_iter_mut()
        .zip(sun.par_iter_mut())
        .zip(rotation_deg.par_iter())
        .for_each(|((h, s), &deg)| {
            rot(h, deg);
            rot(s, deg);
        });
}

/// The maps of the instances in `range` (a shard; every instance's maps depend on its index
/// and the scene only, so shards concatenate to the maps of the whole range).
pub fn instance_maps(
    scene: &crate::trace::pack_scene::TraceScene,
    light: &crate::lightmap::BakeLight,
    opts: &bake::EnvmapOptions,
    range: std::ops::Range<usize>,
) -> crate::error::Result<Vec<bake::InstanceMaps>> {
    with_envmap_scene(scene, light, opts, |es| {
        bake::bake_envmaps_range(es, opts, range)
    })
}

/// [`instance_maps`] with the half differences (the noise estimate, [`bake::Traced`]).
pub(crate) fn instance_traced(
    scene: &crate::trace::pack_scene::TraceScene,
    light: &crate::lightmap::BakeLight,
    opts: &bake::EnvmapOptions,
    range: std::ops::Range<usize>,
) -> crate::error::Result<bake::Traced> {
    with_envmap_scene(scene, light, opts, |es| {
        bake::trace_envmaps_range(es, opts, range)
    })
}

/// The maps of the instances `subset` of a pack's scene (in that order).
pub(crate) fn instance_maps_subset(
    scene: &crate::trace::pack_scene::TraceScene,
    light: &crate::lightmap::BakeLight,
    opts: &bake::EnvmapOptions,
    subset: &[usize],
) -> crate::error::Result<Vec<bake::InstanceMaps>> {
    with_envmap_scene(scene, light, opts, |es| {
        bake::bake_envmaps_subset(es, opts, subset)
    })
}

/// [`instance_maps_subset`] with the half differences (the noise estimate, [`bake::Traced`]).
pub(crate) fn instance_traced_subset(
    scene: &crate::trace::pack_scene::TraceScene,
    light: &crate::lightmap::BakeLight,
    opts: &bake::EnvmapOptions,
    subset: &[usize],
) -> crate::error::Result<bake::Traced> {
    with_envmap_scene(scene, light, opts, |es| {
        bake::trace_envmaps_subset(es, opts, subset)
    })
}

fn with_envmap_scene<T>(
    scene: &crate::trace::pack_scene::TraceScene,
    light: &crate::lightmap::BakeLight,
    opts: &bake::EnvmapOptions,
    f: impl FnOnce(&bake::EnvmapScene) -> T,
) -> crate::error::Result<T> {
    let probe_height = scene
        .instances
        .items
        .iter()
        .map(|i| 0.5 * scene.model_height[i.model as usize] * i.scale)
        .collect();
    let es = bake::EnvmapScene {
        bvh: scene.tracer(opts.tracer)?,
        count: scene.instance_count,
        probe_height,
        albedo: scene.albedo.clone(),
        sky: light.sky,
        sun: light.sun.map(|(direction, irradiance)| bake::SunLight {
            direction,
            irradiance,
        }),
    };
    Ok(f(&es))
}

/// Compression the stage reaches: the raw maps (`dim` f32 per instance) over the stored samples
/// (position, instance index and `dim` f32 each) and local part; without stored weights, as the
/// section summary counts it.
pub fn compression(z: &Compressed, dim: usize) -> f64 {
    z.compression(dim)
}

/// Compression below which the stage warns.
pub const MIN_COMPRESSION: f64 = 2.0;

/// A warning when the clustering does not compress (below [`MIN_COMPRESSION`]), naming the
/// reason it measures: how much a map differs from the least-squares plane through its 8
/// nearest neighbours' maps ([`cluster::estimate_noise`]'s residual: Monte-Carlo noise and real
/// local differences together), against the error bound (plus the noise allowance, if any). A
/// residual above the bound means no reconstruction from neighbours can meet it (measured on
/// the pipeline's traced maps: docs/PERFORMANCE.md, "Environment-map clustering: the cause").
pub fn compression_warning(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    z: &Compressed,
    opts: &ClusterOptions,
) -> Option<String> {
    let c = &z.clustering;
    let ratio = compression(z, dim);
    if ratio >= MIN_COMPRESSION || positions.is_empty() {
        return None;
    }
    let head = format!(
        "environment maps not compressed: {} clusters for {} instances ({ratio:.2}x, below {MIN_COMPRESSION}x)",
        c.samples.len(),
        positions.len()
    );
    let allowed = ((opts.error as f64).powi(2) + (c.noise as f64).powi(2)).sqrt();
    if positions.len() < 4 * c.k.max(1) {
        return Some(format!(
            "{head}: too few instances ({}) for {} neighbours per reconstruction",
            positions.len(),
            c.k
        ));
    }
    let residual = cluster::estimate_noise(positions, values, dim) as f64;
    Some(if residual > allowed {
        format!(
            "{head}: neighbouring maps differ from the plane through their 8 nearest neighbours by {:.1} % (relative RMS; Monte-Carlo noise and local occlusion together), more than the allowed error {:.1} % (bound {:.1} %, noise allowance {:.1} %), so no reconstruction from neighbours meets the per-instance bound",
            100.0 * residual,
            100.0 * allowed,
            100.0 * opts.error,
            100.0 * c.noise
        )
    } else {
        format!(
            "{head}: the maps are smooth between neighbours ({:.1} % plane residual) but the {}-neighbour multiquadric (R = {:.2} m) does not reach the allowed error {:.1} % with fewer samples",
            100.0 * residual,
            c.k,
            c.radius,
            100.0 * allowed
        )
    })
}

/// The `envmaps` section of every instance's maps, with the noise estimate when every instance
/// has a half difference (summed in fixed blocks of instances: the same bytes whatever the
/// thread count or the shards).
pub fn envmaps_section(traced: &bake::Traced, opts: &bake::EnvmapOptions) -> crate::pack::Section {
    let maps = &traced.maps;
    let noise = (!maps.is_empty() && traced.diffs.len() == maps.len())
        .then(|| section::noise_from_differences(&traced.diffs));
    section::envmaps_to_section_filled(
        "envmaps",
        &envmaps_meta(maps.len(), noise.is_some(), opts),
        maps.len(),
        |out| out.iter_mut().zip(maps).for_each(|(o, m)| *o = m.0),
        |out| out.iter_mut().zip(maps).for_each(|(o, m)| *o = m.1),
        noise.as_ref(),
    )
}

/// The `envmaps` section's metadata for `n` maps, with a noise estimate or without.
pub(crate) fn envmaps_meta(
    n: usize,
    noise: bool,
    opts: &bake::EnvmapOptions,
) -> section::EnvmapsMeta {
    section::EnvmapsMeta {
        instances: n as u64,
        order: 4,
        samples: opts.samples,
        estimator: if noise {
            "spherical Fibonacci rays from a probe at half the model height, two independently rotated halves; one diffuse bounce"
        } else {
            "spherical Fibonacci rays from a probe at half the model height; one diffuse bounce"
        }
        .into(),
        noise_pairs: if noise { n as u64 } else { 0 },
    }
}

/// The clustering stage on a pack with `instances` and `envmaps`: the `clusters` section, whose
/// sample values are in the world frame (see [`to_world_frame`]).
#[cfg(test)]
pub(crate) fn cluster_sections(
    pack: &crate::pack::Pack,
    opts: &ClusterOptions,
    store_weights: bool,
) -> crate::error::Result<(Vec<crate::pack::Section>, Compressed)> {
    cluster_sections_warned(pack, opts, store_weights).map(|(s, c, _)| (s, c))
}

/// [`cluster_sections`] and the stage's warning, if it does not compress
/// ([`compression_warning`]).
pub(crate) fn cluster_sections_warned(
    pack: &crate::pack::Pack,
    opts: &ClusterOptions,
    store_weights: bool,
) -> crate::error::Result<(Vec<crate::pack::Section>, Compressed, Option<String>)> {
    let bad = |e| crate::error::Error::invalid(pack.path(), e);
    let (_, inst) = crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
        .map_err(bad)?;
    let ev = pack.view_named("envmaps")?;
    let (emeta, sky, sun) = section::envmaps_from_section(&ev).map_err(bad)?;
    let noise = section::envmaps_noise_from_section(&ev, &emeta).map_err(bad)?;
    if sky.len() != inst.items.len() {
        return Err(crate::error::Error::invalid_at(
            pack.path(),
            "envmaps",
            "envmaps and instances differ in count",
        ));
    }
    let positions: Vec<[f32; 3]> = inst.items.iter().map(|i| i.position).collect();
    let rotations: Vec<f32> = inst.items.iter().map(|i| i.rotation_deg).collect();
    let (mut sky, mut sun) = (sky, sun);
    to_world_frame(&mut sky, &mut sun, &rotations);
    let values = section::flatten(&sky, &sun);
    let (meta, z, weights) = cluster_and_weigh_noisy(
        &positions,
        &values,
        section::DIM,
        opts,
        store_weights,
        noise.as_ref(),
    );
    let wref = weights.as_ref().map(|(n, w)| (n.as_slice(), w.as_slice()));
    let warning = compression_warning(&positions, &values, section::DIM, &z, opts);
    Ok((
        vec![section::clusters_to_section(
            "clusters", &meta, &z, &positions, &values, wref,
        )],
        z,
        warning,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use cluster::cluster_envmaps;

    #[test]
    fn stored_weights_reproduce_the_interpolator_and_the_clustering_errors() {
        let mut rng = crate::rng::Rng::new(31);
        let pos: Vec<[f32; 3]> = (0..1500)
            .map(|_| [rng.f32() * 200.0, rng.f32() * 200.0, rng.f32()])
            .collect();
        let maps = synthetic::synthetic_envmaps(&pos, &synthetic::bench_terrain_height, 0.0, 3);
        let opts = ClusterOptions {
            error: 0.01,
            ..Default::default()
        };
        let c = cluster_envmaps(&pos, &maps.truth, section::DIM, &opts);
        assert!(c.samples.len() > 20);
        let (nb, w) = instance_weights(&pos, &maps.truth, section::DIM, &c);
        let rec = apply_weights(&maps.truth, section::DIM, &c.samples, c.k, &nb, &w);
        let (pts, vals) = cluster::gather_samples(&pos, &maps.truth, section::DIM, &c.samples);
        let ip = interp::Interpolator::new(&pts, &vals, section::DIM, c.radius, c.k);
        let mut out = vec![0.0; section::DIM];
        for (i, x) in pos.iter().enumerate() {
            ip.reconstruct(*x, &mut out);
            let mine = &rec[i * section::DIM..(i + 1) * section::DIM];
            let own = &maps.truth[i * section::DIM..(i + 1) * section::DIM];
            let mut e = 0.0f64;
            for ((a, b), o) in mine.iter().zip(&out).zip(own) {
                assert!((a - b).abs() < 1e-5 * c.rms, "instance {i}");
                e += ((a - o) as f64).powi(2);
            }
            let rel = (e / section::DIM as f64).sqrt() as f32 / c.rms;
            assert!(
                (rel - c.errors[i]).abs() < 1e-4,
                "instance {i}: {rel} {}",
                c.errors[i]
            );
        }
    }

    #[test]
    fn the_stage_warns_with_the_measured_reason_when_it_does_not_compress() {
        let mut rng = crate::rng::Rng::new(7);
        let pos: Vec<[f32; 3]> = (0..2000)
            .map(|_| [rng.f32() * 300.0, rng.f32() * 300.0, 0.0])
            .collect();
        let opts = ClusterOptions {
            error: 0.02,
            ..Default::default()
        };
        // A smooth field compresses and does not warn.
        let smooth = synthetic::synthetic_envmaps(&pos, &synthetic::bench_terrain_height, 0.0, 3);
        let c = Compressed::shared_only(cluster_envmaps(&pos, &smooth.truth, section::DIM, &opts));
        assert!(compression(&c, section::DIM) >= MIN_COMPRESSION);
        assert_eq!(
            compression_warning(&pos, &smooth.truth, section::DIM, &c, &opts),
            None
        );
        // Maps that differ between neighbours far more than the bound (20 % independent noise)
        // split down to single instances, and the warning names the measured residual.
        let noisy = synthetic::synthetic_envmaps(&pos, &synthetic::bench_terrain_height, 0.2, 3);
        let c = Compressed::shared_only(cluster_envmaps(&pos, &noisy.noisy, section::DIM, &opts));
        let ratio = compression(&c, section::DIM);
        assert!(ratio < MIN_COMPRESSION, "{ratio}");
        let w = compression_warning(&pos, &noisy.noisy, section::DIM, &c, &opts).unwrap();
        assert!(
            w.contains("not compressed") && w.contains("neighbouring maps differ"),
            "{w}"
        );
        let residual = cluster::estimate_noise(&pos, &noisy.noisy, section::DIM);
        assert!(w.contains(&format!("{:.1} %", 100.0 * residual)), "{w}");
        // Raw maps (96 f32 per instance) over the stored samples (3 + 1 + 96 words each).
        let expect = (2000.0 * 96.0) / (c.clustering.samples.len() as f64 * 100.0);
        assert!((ratio - expect).abs() < 1e-9, "{ratio} {expect}");
    }

    #[test]
    fn world_frame_undoes_the_instance_rotation_of_the_bake() {
        // A world-frame map with every band populated, put into an instance's frame the way
        // `bake::bake_one` does (C_local(d) = C_world(Rz(θ)·d)).
        let world: [[f32; 3]; 16] =
            std::array::from_fn(|c| [0.3 + 0.1 * c as f32, (c as f32 * 0.7).sin(), 0.05]);
        let deg = 73.0f32;
        let local = crate::sh::ShRadiance { coeffs: world }
            .rotated_z(-(deg as f64).to_radians())
            .coeffs;
        let d = [0.48f32, -0.6, 0.64];
        let (s, c) = deg.to_radians().sin_cos();
        let rd = [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]];
        let w_at = crate::sh::ShRadiance { coeffs: world }.eval(rd);
        let l_at = crate::sh::ShRadiance { coeffs: local }.eval(d);
        for k in 0..3 {
            assert!((w_at[k] - l_at[k]).abs() < 1e-4, "{w_at:?} {l_at:?}");
        }
        let (mut sky, mut sun) = (vec![local], vec![local]);
        to_world_frame(&mut sky, &mut sun, &[deg]);
        for (a, b) in sky[0].iter().flatten().zip(world.iter().flatten()) {
            assert!((a - b).abs() < 1e-5);
        }
        assert_eq!(sky, sun);
    }

    /// Instances scattered over `side` m × `side` m of the bench terrain, and the smooth field
    /// there (terrain occlusion of sky and sun bounce), with independent noise of relative RMS
    /// `noise` per coefficient (the traced maps' Monte-Carlo noise).
    fn smooth_scene(
        n: usize,
        side: f32,
        noise: f32,
        seed: u64,
    ) -> (Vec<[f32; 3]>, synthetic::SyntheticMaps) {
        let mut rng = crate::rng::Rng::new(seed);
        let pos: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                let (x, y) = (rng.f32() * side, rng.f32() * side);
                [x, y, synthetic::bench_terrain_height(x, y)]
            })
            .collect();
        let maps =
            synthetic::synthetic_envmaps(&pos, &synthetic::bench_terrain_height, noise, seed);
        (pos, maps)
    }

    fn rel_rms(a: &[f32], b: &[f32], rms: f32) -> f64 {
        let e: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
        (e / a.len() as f64).sqrt() / rms as f64
    }

    #[test]
    fn the_stage_recovers_a_smooth_field_under_noise_within_the_bound_at_20x() {
        let (pos, maps) = smooth_scene(6000, 200.0, 0.01, 41);
        let opts = ClusterOptions::DEFAULT;
        let z = compress(&pos, &maps.noisy, section::DIM, &opts);
        let ratio = z.compression(section::DIM);
        assert!(ratio >= 20.0, "{ratio}");
        let rec = reconstruct_all(&pos, &maps.noisy, section::DIM, &z);
        let vs_truth = rel_rms(&rec, &maps.truth, z.clustering.rms);
        assert!(
            vs_truth <= opts.error as f64,
            "{vs_truth} against the noise-free field"
        );
        // The stated error (against the noisy input) is what the reconstruction shows.
        let stated = z.rms_error() as f64;
        let vs_input = rel_rms(&rec, &maps.noisy, z.clustering.rms);
        assert!((stated - vs_input).abs() < 1e-4, "{stated} {vs_input}");
    }

    /// A smooth field plus hard local occlusion: every instance loses up to 60 % of three
    /// directional patterns (a crown or trunk next to it in one of three directions), independent
    /// from instance to instance, and traced noise on top. The reference is the field with the
    /// occlusion and without the noise.
    fn occluded_scene(n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<f32>, Vec<f32>) {
        let (pos, maps) = smooth_scene(n, 200.0, 0.0, seed);
        let dim = section::DIM;
        let rms = (maps.truth.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()
            / maps.truth.len() as f64)
            .sqrt() as f32;
        let dirs = [[0.6f32, 0.0, 0.8], [-0.3, 0.52, 0.8], [0.0, -0.95, 0.31]];
        let patterns: Vec<Vec<f32>> = dirs
            .iter()
            .map(|&d| {
                let y = crate::sh::eval_basis16(d);
                let mut v = vec![0.0f32; dim];
                for c in 0..16 {
                    for k in 0..3 {
                        v[c * 3 + k] = 2.0 * rms * y[c] * [1.0, 1.1, 1.3][k];
                        v[48 + c * 3 + k] = 0.5 * rms * y[c] * [1.0, 0.9, 0.6][k];
                    }
                }
                v
            })
            .collect();
        let mut rng = crate::rng::Rng::new(seed ^ 0x0cc1);
        let mut reference = maps.truth.clone();
        for m in reference.chunks_mut(dim) {
            for p in &patterns {
                let a = 0.6 * rng.f32();
                for (x, y) in m.iter_mut().zip(p) {
                    *x -= a * y;
                }
            }
        }
        let mut noisy = reference.clone();
        for x in noisy.iter_mut() {
            let g = (0..4).map(|_| rng.f32() - 0.5).sum::<f32>() * 3.0f32.sqrt();
            *x += 0.01 * rms * g;
        }
        (pos, noisy, reference)
    }

    #[test]
    fn the_local_part_carries_hard_local_occlusion_within_the_bound_against_the_reference() {
        let (pos, noisy, reference) = occluded_scene(6000, 43);
        let opts = ClusterOptions::DEFAULT;
        let z = compress(&pos, &noisy, section::DIM, &opts);
        assert!(z.compression(section::DIM) >= 20.0);
        let l = z.local.as_ref().expect("a local part");
        assert!(l.components > 0);
        // The shared part alone cannot carry the occlusion ...
        let shared = z.clustering.rms_error();
        assert!(shared > 5.0 * opts.error, "shared part alone: {shared}");
        // ... the local part does: the error against the noise-free reference is within the bound.
        let rec = reconstruct_all(&pos, &noisy, section::DIM, &z);
        let vs_ref = rel_rms(&rec, &reference, z.clustering.rms);
        assert!(
            vs_ref <= opts.error as f64,
            "{vs_ref} against the reference"
        );
        assert!(
            z.rms_error() <= 2.0 * opts.error,
            "{} against the input",
            z.rms_error()
        );
    }

    #[test]
    fn the_compressed_section_is_byte_identical_across_thread_counts() {
        let (pos, noisy, _) = occluded_scene(3000, 47);
        let opts = ClusterOptions::DEFAULT;
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let (meta, z, w) = cluster_and_weigh(&pos, &noisy, section::DIM, &opts, true);
                    let wref = w.as_ref().map(|(n, w)| (n.as_slice(), w.as_slice()));
                    let sec =
                        section::clusters_to_section("clusters", &meta, &z, &pos, &noisy, wref);
                    let mut pw = crate::pack::PackWriter::new();
                    pw.insert(sec);
                    (z, pw.to_bytes().unwrap())
                })
        };
        let (z1, b1) = run(1);
        assert!(z1.local.is_some());
        for t in [2, 5] {
            let (z, b) = run(t);
            assert_eq!(z, z1, "{t} threads");
            assert!(b == b1, "{t} threads: the section's bytes differ");
        }
    }

    #[test]
    fn the_denoised_stage_states_the_noise_is_closer_to_the_reference_and_thread_independent() {
        // Hard local occlusion plus white noise of known σ (1 % of the RMS per coefficient):
        // given that covariance (σ² I, as the tracer's estimate would be), the stage states
        // σ, filters the local part, lands closer to the noise-free maps than without the
        // filter, and writes the same bytes with 1, 2 and 5 threads.
        let (pos, noisy, reference) = occluded_scene(3000, 53);
        let dim = section::DIM;
        let rms = (noisy.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / noisy.len() as f64)
            .sqrt() as f32;
        let truth_rms = (reference.iter().map(|v| (*v as f64).powi(2)).sum::<f64>()
            / reference.len() as f64)
            .sqrt();
        // occluded_scene's noise: 0.01 × the RMS of its smooth field, which is about the
        // reference's RMS; taken from the data: the input minus the reference.
        let var = noisy
            .iter()
            .zip(&reference)
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            / noisy.len() as f64;
        let mut cov = vec![0.0f64; dim * dim];
        for c in 0..dim {
            cov[c * dim + c] = var;
        }
        let nz = section::EnvmapNoise {
            covariance: cov,
            variance: vec![(var * dim as f64) as f32; pos.len()],
        };
        let opts = ClusterOptions::DEFAULT;
        let run = |threads, noise: Option<&section::EnvmapNoise>| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let (meta, z, _) =
                        cluster_and_weigh_noisy(&pos, &noisy, dim, &opts, false, noise);
                    let sec =
                        section::clusters_to_section("clusters", &meta, &z, &pos, &noisy, None);
                    let mut pw = crate::pack::PackWriter::new();
                    pw.insert(sec);
                    (meta, z, pw.to_bytes().unwrap())
                })
        };
        let (meta, z, bytes) = run(1, Some(&nz));
        assert!(meta.denoised && z.local.is_some());
        let stated = meta.input_noise_relative as f64;
        let want = var.sqrt() / rms as f64;
        assert!((stated / want - 1.0).abs() < 1e-3, "{stated} vs {want}");
        let (plain_meta, plain, _) = run(1, None);
        assert!(!plain_meta.denoised && plain_meta.input_noise_relative == 0.0);
        let err = |z: &Compressed| {
            let rec = reconstruct_all(&pos, &noisy, dim, z);
            rel_rms(&rec, &reference, truth_rms as f32)
        };
        let (e_f, e_p) = (err(&z), err(&plain));
        eprintln!("against the noise-free maps: denoised {e_f:.5}, plain {e_p:.5}");
        assert!(e_f <= e_p, "denoised {e_f} vs plain {e_p}");
        for t in [2, 5] {
            let (_, zt, b) = run(t, Some(&nz));
            assert_eq!(zt, z, "{t} threads");
            assert!(b == bytes, "{t} threads: the section's bytes differ");
        }
    }

    #[test]
    fn the_renderer_reconstructs_what_the_stage_measured() {
        // The section read back as the renderer reads it (solved weights + local part) gives
        // the stage's reconstruction, whose errors the section states.
        let (pos, noisy, _) = occluded_scene(2000, 53);
        let (meta, z, _) =
            cluster_and_weigh(&pos, &noisy, section::DIM, &ClusterOptions::DEFAULT, false);
        let sec = section::clusters_to_section("clusters", &meta, &z, &pos, &noisy, None);
        let mut pw = crate::pack::PackWriter::new();
        pw.insert(sec);
        let pack = crate::pack::Pack::from_bytes(&pw.to_bytes().unwrap(), "t.bake").unwrap();
        let v = pack.view_named("clusters").unwrap();
        let m = section::ClustersMeta::decode(&v).unwrap();
        assert_eq!(m, meta);
        let l = section::local_from_section(&v, &m).unwrap().unwrap();
        assert_eq!(Some(&l), z.local.as_ref());
        let stage = reconstruct_all(&pos, &noisy, section::DIM, &z);
        let pts: Vec<[f32; 3]> = v.array_vec("sample_positions").unwrap();
        let vals: Vec<f32> = v.array_vec("sample_values").unwrap();
        let ip = interp::Interpolator::new(&pts, &vals, section::DIM, m.radius, m.k as usize);
        let mut out = vec![0.0f32; section::DIM];
        for (i, x) in pos.iter().enumerate() {
            ip.reconstruct(*x, &mut out);
            l.add_to(i, &mut out);
            for (a, b) in out
                .iter()
                .zip(&stage[i * section::DIM..(i + 1) * section::DIM])
            {
                assert!((a - b).abs() < 1e-4 * z.clustering.rms, "instance {i}");
            }
        }
    }
}
