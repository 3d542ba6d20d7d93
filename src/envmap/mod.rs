//! Per-instance environment maps (seed 000, 4.6.3): clustering and multiquadric interpolation.
pub mod bake;
pub mod cluster;
pub mod interp;
pub mod kdtree;
pub mod section;
pub mod synthetic;

use cluster::{ClusterOptions, Clustering, cluster_envmaps};
use interp::Interpolator;
use rayon::prelude::*;
use section::ClustersMeta;

/// Per-instance neighbour indices and weights (k each, padded with sample 0 / weight 0).
pub type NeighbourWeights = (Vec<u32>, Vec<f32>);

/// Clusters the maps and, if asked, computes every instance's interpolation weights.
pub fn cluster_and_weigh(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    opts: &ClusterOptions,
    store_weights: bool,
) -> (ClustersMeta, Clustering, Option<NeighbourWeights>) {
    let c = cluster_envmaps(positions, values, dim, opts);
    let weights = store_weights.then(|| instance_weights(positions, values, dim, &c));
    let meta = ClustersMeta {
        instances: positions.len() as u64,
        clusters: c.samples.len() as u64,
        dim: dim as u32,
        k: c.k as u32,
        radius: c.radius,
        constant_term: true,
        error_bound: opts.error,
        rms_error_relative: c.rms_error(),
        max_error_relative: c.max_error(),
        ill_conditioned: c.ill_conditioned as u64,
        weights: store_weights,
    };
    (meta, c, weights)
}

/// The k sample neighbours and multiquadric weights of every instance.
pub fn instance_weights(
    positions: &[[f32; 3]],
    values: &[f32],
    dim: usize,
    c: &Clustering,
) -> NeighbourWeights {
    let (pts, vals) = cluster::gather_samples(positions, values, dim, &c.samples);
    let ip = Interpolator::new(&pts, &vals, dim, c.radius, c.k);
    let k = c.k;
    let rows: Vec<(Vec<u32>, Vec<f32>)> = positions
        .par_iter()
        .map(|&x| {
            let (mut nb, mut w) = (Vec::new(), Vec::new());
            ip.weights(x, &mut nb, &mut w);
            let mut idx: Vec<u32> = nb.iter().map(|&(_, i)| i).collect();
            let mut wf: Vec<f32> = w.iter().map(|&v| v as f32).collect();
            idx.resize(k, 0);
            wf.resize(k, 0.0);
            (idx, wf)
        })
        .collect();
    let mut nb = Vec::with_capacity(positions.len() * k);
    let mut w = Vec::with_capacity(positions.len() * k);
    for (i, wr) in rows {
        nb.extend(i);
        w.extend(wr);
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
    neighbours
        .par_chunks(k.max(1))
        .zip(weights.par_chunks(k.max(1)))
        .flat_map_iter(|(nb, w)| {
            let mut acc = vec![0.0f64; dim];
            for (&j, &wj) in nb.iter().zip(w) {
                let s = samples[j as usize] as usize;
                for (a, &v) in acc.iter_mut().zip(&values[s * dim..(s + 1) * dim]) {
                    *a += wj as f64 * v as f64;
                }
            }
            acc.into_iter().map(|a| a as f32)
        })
        .collect()
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

/// The environment-map stage on a pack: an `envmaps` section for the scene's instances.
pub fn envmap_sections(
    pack: &crate::pack::Pack,
    opts: &bake::EnvmapOptions,
) -> crate::error::Result<Vec<crate::pack::Section>> {
    let light = crate::lightmap::scene_lighting(pack)?;
    let scene = crate::tracescene::trace_scene(pack)?;
    let probe_height = scene
        .instances
        .items
        .iter()
        .map(|i| 0.5 * scene.model_height[i.model as usize] * i.scale)
        .collect();
    let es = bake::EnvmapScene {
        bvh: &scene.bvh,
        count: scene.instance_count,
        probe_height,
        albedo: scene.albedo.clone(),
        sky: light.sky,
        sun: light.sun.map(|(direction, irradiance)| bake::SunLight {
            direction,
            irradiance,
        }),
    };
    let maps = bake::bake_envmaps(&es, opts);
    let sky: Vec<[[f32; 3]; 16]> = maps.iter().map(|m| m.0).collect();
    let sun: Vec<[[f32; 3]; 16]> = maps.iter().map(|m| m.1).collect();
    let meta = section::EnvmapsMeta {
        instances: maps.len() as u64,
        order: 4,
        samples: opts.samples,
        estimator:
            "spherical Fibonacci rays from a probe at half the model height; one diffuse bounce"
                .into(),
    };
    Ok(vec![section::envmaps_to_section(
        "envmaps", &meta, &sky, &sun,
    )])
}

/// The clustering stage on a pack with `instances` and `envmaps`: the `clusters` section, whose
/// sample values are in the world frame (see [`to_world_frame`]).
pub fn cluster_sections(
    pack: &crate::pack::Pack,
    opts: &ClusterOptions,
    store_weights: bool,
) -> crate::error::Result<(Vec<crate::pack::Section>, Clustering)> {
    let bad = |e| crate::error::Error::invalid(pack.path(), e);
    let (_, inst) =
        crate::pack::kinds::instances::from_section(&pack.view_named("instances")?).map_err(bad)?;
    let (_, sky, sun) = section::envmaps_from_section(&pack.view_named("envmaps")?).map_err(bad)?;
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
    let (meta, c, weights) =
        cluster_and_weigh(&positions, &values, section::DIM, opts, store_weights);
    let wref = weights.as_ref().map(|(n, w)| (n.as_slice(), w.as_slice()));
    Ok((
        vec![section::clusters_to_section(
            "clusters", &meta, &c, &positions, &values, wref,
        )],
        c,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
