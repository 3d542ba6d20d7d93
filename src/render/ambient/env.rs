//! The light each instance sees: the sky's SH light, the sun's SH in an instance's frame, and the
//! per-instance environment maps from the `clusters` section (stored weights, or the
//! multiquadric solved at load).

use super::*;

pub(super) fn bad(pack: &Pack) -> impl Fn(crate::error::ParseError) -> Error + '_ {
    |e| Error::invalid(pack.path(), e)
}

/// The sun-free sky and the sun: the `sh` and `sun` sections, else the SH projection of the
/// drawn sky (the built-in one has no sun; a pack sky without an `sh` section keeps its sun in
/// the projection, which a warning says).
pub fn sky_light(
    pack: &Pack,
    sky: &SkyData,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<SkyLight> {
    if pack.find(crate::sky::SH_SECTION).is_some() {
        let l = crate::lightmap::scene_lighting(pack)?;
        return Ok(SkyLight {
            irradiance: l.sky.to_irradiance(),
            sky: l.sky,
            sun: l.sun,
        });
    }
    if !sky.analytic {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_SH_MISSING,
            "",
            "no `sh` section: the ambient light is the SH of the whole sky",
        ));
    }
    let img = crate::model::FloatImage {
        width: sky.width,
        height: sky.height,
        pixels: sky.texels.iter().map(|t| [t[0], t[1], t[2]]).collect(),
    };
    let sh = crate::sh::project_latlong(&img);
    Ok(SkyLight {
        irradiance: sh.to_irradiance(),
        sky: sh,
        sun: None,
    })
}

/// The SH of the direct sun, `E·y_i(s)`, in a frame turned by `rotation_deg` about +Z.
pub fn sun_sh_local(sun: Option<([f32; 3], [f32; 3])>, rotation_deg: f32) -> Sh16 {
    let Some((s, e)) = sun else {
        return [[0.0; 3]; COEFFS];
    };
    let a = -rotation_deg.to_radians();
    let (sa, ca) = a.sin_cos();
    let local = [ca * s[0] - sa * s[1], sa * s[0] + ca * s[1], s[2]];
    let y = crate::sh::eval_basis16(local);
    std::array::from_fn(|i| e.map(|c| c * y[i]))
}

/// A world-frame map in the frame of an instance turned by `rotation_deg`.
pub fn to_instance_frame(world: &Sh16, rotation_deg: f32) -> Sh16 {
    ShRadiance { coeffs: *world }
        .rotated_z(-(rotation_deg as f64).to_radians())
        .coeffs
}

/// An instance-frame map back in the world frame.
pub fn to_world_frame(local: &Sh16, rotation_deg: f32) -> Sh16 {
    ShRadiance { coeffs: *local }
        .rotated_z((rotation_deg as f64).to_radians())
        .coeffs
}

pub(super) fn add_sh(a: &Sh16, b: &Sh16) -> Sh16 {
    std::array::from_fn(|i| std::array::from_fn(|c| a[i][c] + b[i][c]))
}

/// Every instance's (C_H, C_S without the direct sun), instance frame, in the `instances`
/// section's order, and where they came from.
pub fn instance_maps(
    pack: &Pack,
    records: &[InstanceRecord],
    light: &SkyLight,
) -> Result<(Vec<(Sh16, Sh16)>, EnvSource)> {
    if pack.find(crate::envmap::section::CLUSTERS_KIND).is_some() {
        return Ok((cluster_maps(pack, records)?, EnvSource::Clusters));
    }
    if pack.find(crate::envmap::section::ENVMAPS_KIND).is_some() {
        let v = pack.view_named(crate::envmap::section::ENVMAPS_KIND)?;
        let (_, sky, sun) = crate::envmap::section::envmaps_from_section(&v).map_err(bad(pack))?;
        if sky.len() != records.len() {
            return Err(Error::invalid_at(
                pack.path(),
                "section \"envmaps\"",
                format!("{} maps for {} instances", sky.len(), records.len()),
            ));
        }
        return Ok((sky.into_iter().zip(sun).collect(), EnvSource::Envmaps));
    }
    let maps = records
        .iter()
        .map(|r| {
            let ch = to_instance_frame(&light.sky.coeffs, r.rotation_deg);
            (ch, [[0.0; 3]; COEFFS])
        })
        .collect();
    Ok((maps, EnvSource::Sky))
}

/// Multiquadric reconstruction of every instance's maps from the `clusters` section (world-frame
/// samples): stored neighbours and weights when present, else solved here with the section's k
/// and R; then turned into each instance's frame.
pub(super) fn cluster_maps(pack: &Pack, records: &[InstanceRecord]) -> Result<Vec<(Sh16, Sh16)>> {
    use crate::envmap::section::{ClustersMeta, DIM};
    let place = "section \"clusters\"";
    let v = pack.view_named(crate::envmap::section::CLUSTERS_KIND)?;
    let meta = ClustersMeta::decode(&v).map_err(bad(pack))?;
    let pts: Vec<[f32; 3]> = v.array_vec("sample_positions").map_err(bad(pack))?;
    let vals: Vec<f32> = v.array_vec("sample_values").map_err(bad(pack))?;
    let owner: Vec<u32> = v.array_vec("sample_instance").map_err(bad(pack))?;
    let invalid = |m: String| Error::invalid_at(pack.path(), place, m);
    if meta.dim as usize != DIM || vals.len() != pts.len() * DIM || owner.len() != pts.len() {
        return Err(invalid(format!(
            "{} samples, {} values, {} owners, dim {}: expected {DIM} values per sample",
            pts.len(),
            vals.len(),
            owner.len(),
            meta.dim
        )));
    }
    if records.is_empty() && meta.instances == 0 {
        // A scene of a terrain alone: no instance has a map.
        return Ok(Vec::new());
    }
    if meta.instances as usize != records.len() || pts.is_empty() {
        return Err(invalid(format!(
            "{} instances and {} samples for a scene of {} instances",
            meta.instances,
            pts.len(),
            records.len()
        )));
    }
    // The samples are in the world frame (docs/FORMAT.md); each one's instance must exist.
    if let Some(s) = owner.iter().position(|&i| i as usize >= records.len()) {
        return Err(invalid(format!("sample {s} names instance {}", owner[s])));
    }
    let world = vals;
    let stored = stored_weights(&v, &meta, pts.len(), records.len()).map_err(invalid)?;
    // The per-instance local part (issue 20): added to the interpolated world-frame map, the
    // same sum the stage formed its errors with (`envmap::local`).
    let local = crate::envmap::section::local_from_section(&v, &meta).map_err(bad(pack))?;
    let ip = crate::envmap::interp::Interpolator {
        constant_term: meta.constant_term,
        ..crate::envmap::interp::Interpolator::new(
            &pts,
            &world,
            DIM,
            meta.radius,
            meta.k.max(1) as usize,
        )
    };
    // Per instance in parallel, collected in order: deterministic whatever the thread count.
    use rayon::prelude::*;
    let out = records
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let mut buf = vec![0.0f32; DIM];
            match &stored {
                Some((nb, w)) => blend(&world, &nb[i], &w[i], &mut buf),
                None => {
                    ip.reconstruct(r.position, &mut buf);
                }
            }
            if let Some(l) = &local {
                l.add_to(i, &mut buf);
            }
            let (h, sn) = split_dim(&buf);
            (
                to_instance_frame(&h, r.rotation_deg),
                to_instance_frame(&sn, r.rotation_deg),
            )
        })
        .collect();
    Ok(out)
}

/// Per-instance neighbours and weights of a `clusters` section that stores them.
#[allow(clippy::type_complexity)]
pub(super) fn stored_weights(
    v: &crate::pack::section::SectionView,
    meta: &crate::envmap::section::ClustersMeta,
    samples: usize,
    instances: usize,
) -> std::result::Result<Option<(Vec<Vec<u32>>, Vec<Vec<f32>>)>, String> {
    if !meta.weights {
        return Ok(None);
    }
    let nb: Vec<u32> = v.array_vec("neighbours").map_err(|e| e.to_string())?;
    let w: Vec<f32> = v.array_vec("weights").map_err(|e| e.to_string())?;
    let k = meta.k as usize;
    if k == 0 || nb.len() != instances * k || w.len() != nb.len() {
        return Err(format!(
            "{} neighbours and {} weights for {instances} instances × k = {k}",
            nb.len(),
            w.len()
        ));
    }
    if let Some(p) = nb.iter().position(|&j| j as usize >= samples) {
        return Err(format!("neighbour {p} names sample {} of {samples}", nb[p]));
    }
    Ok(Some((
        nb.chunks(k).map(<[u32]>::to_vec).collect(),
        w.chunks(k).map(<[f32]>::to_vec).collect(),
    )))
}

pub(super) fn blend(values: &[f32], nb: &[u32], w: &[f32], out: &mut [f32]) {
    let dim = out.len();
    let mut acc = vec![0.0f64; dim];
    for (&j, &wj) in nb.iter().zip(w) {
        let v = &values[j as usize * dim..(j as usize + 1) * dim];
        for (a, &c) in acc.iter_mut().zip(v) {
            *a += wj as f64 * c as f64;
        }
    }
    for (o, a) in out.iter_mut().zip(acc) {
        *o = a as f32;
    }
}

/// 96 floats (C_H then C_S, `[coefficient][rgb]`) as two maps.
pub(super) fn split_dim(v: &[f32]) -> (Sh16, Sh16) {
    let m = |o: usize| std::array::from_fn(|i| std::array::from_fn(|c| v[o + i * 3 + c]));
    (m(0), m(COEFFS * 3))
}

/// The `instances` records and, per model of a scene, the indices of its instances among them.
pub(super) type InstanceLists = (Vec<InstanceRecord>, Vec<Vec<usize>>);

/// Global `instances` indices of each model of `scene` (by its name and mesh section), in
/// [`ModelData::instances`] order; `None` for a pack without an `instances` section.
pub(super) fn model_instance_indices(
    pack: &Pack,
    scene: &SceneData,
) -> Result<Option<InstanceLists>> {
    let kind = crate::ingest::instances_section::KIND;
    let Some(e) = pack.of_kind(kind).next() else {
        return Ok(None);
    };
    let v = pack.view(e)?;
    let meta: InstancesMeta = v.meta().map_err(bad(pack))?;
    let recs: Vec<InstanceRecord> = v.array_vec("instances").map_err(bad(pack))?;
    let lists = scene
        .models
        .iter()
        .map(|m| {
            let idx = meta
                .models
                .iter()
                .zip(&meta.mesh_sections)
                .position(|(n, s)| *n == m.name && *s == m.section);
            recs.iter()
                .enumerate()
                .filter(|(_, r)| Some(r.model as usize) == idx)
                .map(|(k, _)| k)
                .collect()
        })
        .collect();
    Ok(Some((recs, lists)))
}

/// The sky light of an explicit [`Lighting`](crate::render::light::Lighting) (`RenderOptions::lighting`):
/// its sun, and a sky whose irradiance is the preview's `E(n) = A·(1 + n_z)/2` for the ambient A
/// (exactly two SH coefficients: band 0 and the z function of band 1).
pub fn lighting_sky(l: &crate::render::light::Lighting) -> SkyLight {
    let y0 = crate::sh::eval_basis16([0.0, 0.0, 1.0]);
    let (b0, b1) = (y0[0], y0[2]);
    let mut irr = [[0.0; 3]; COEFFS];
    irr[0] = l.ambient.map(|a| 0.5 * a / b0);
    irr[2] = l.ambient.map(|a| 0.5 * a / b1);
    let mut rad = [[0.0; 3]; COEFFS];
    rad[0] = irr[0].map(|c| c / PI);
    rad[2] = irr[2].map(|c| c / (2.0 * PI / 3.0));
    let sun = (l.sun_irradiance != [0.0; 3]).then_some((l.sun_direction, l.sun_irradiance));
    SkyLight {
        sky: ShRadiance { coeffs: rad },
        irradiance: ShIrradiance { coeffs: irr },
        sun,
    }
}
