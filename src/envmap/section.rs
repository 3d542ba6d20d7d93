//! Kinds `envmaps` (per-instance SH environment maps C_H and C_S) and `clusters` (the cluster
//! samples and interpolation parameters that replace them).

use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const ENVMAPS_KIND: &str = "envmaps";
pub const CLUSTERS_KIND: &str = "clusters";
/// SH coefficients per map (order 4).
pub const COEFFS: usize = 16;
/// Floats per instance: two RGB maps of 16 coefficients.
pub const DIM: usize = 2 * COEFFS * 3;

/// Per-instance maps in the instance's frame, `[coefficient][rgb]`, instance order of the
/// `instances` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvmapsMeta {
    pub instances: u64,
    pub order: u32,
    pub samples: u32,
    pub estimator: String,
    /// Instances whose half difference went into the noise estimate (arrays
    /// `noise_covariance`, `noise_variance`); 0: no noise estimate. Added in version 2 of the
    /// section (envmaps stage version 2); version 1 metadata ends before it and reads as 0.
    pub noise_pairs: u64,
}

/// Version 1 of [`EnvmapsMeta`] (no noise estimate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct EnvmapsMetaV1 {
    instances: u64,
    order: u32,
    samples: u32,
    estimator: String,
}

impl EnvmapsMeta {
    /// Decodes version 2 metadata, or version 1 (without a noise estimate).
    pub fn decode(v: &SectionView) -> Result<EnvmapsMeta, ParseError> {
        match v.meta::<EnvmapsMeta>() {
            Ok(m) => Ok(m),
            Err(e) => {
                let o: EnvmapsMetaV1 = v.meta().map_err(|_| e)?;
                Ok(EnvmapsMeta {
                    instances: o.instances,
                    order: o.order,
                    samples: o.samples,
                    estimator: o.estimator,
                    noise_pairs: 0,
                })
            }
        }
    }
}

/// The tracer's noise estimate of the maps (from the two independent half estimates of every
/// instance, `bake::bake_one`).
#[derive(Debug, Clone, PartialEq)]
pub struct EnvmapNoise {
    /// DIM × DIM, row-major: the noise covariance of one instance's map (the mean of the two
    /// halves), averaged over the instances, Σ_i D_i D_iᵀ / (4n) with D_i = A_i − B_i, in the
    /// **world** frame, flattened as [`flatten`].
    pub covariance: Vec<f64>,
    /// Per instance: the trace of its own estimate, |D_i|² / 4 (rotation-invariant).
    pub variance: Vec<f32>,
}

impl EnvmapNoise {
    /// Mean noise variance per coefficient (trace / DIM).
    pub fn mean_variance(&self) -> f64 {
        (0..DIM).map(|i| self.covariance[i * DIM + i]).sum::<f64>() / DIM as f64
    }
}

/// Instances per block of the covariance sum: every block is summed on its own (f64) and the
/// blocks in order, so the result depends on neither the thread count nor the shards.
const NOISE_BLOCK: usize = 1024;

/// The noise estimate from the instances' half differences (world frame, `DIM` each).
pub fn noise_from_differences(diffs: &[[f32; DIM]]) -> EnvmapNoise {
    noise_from(diffs.len(), |i| &diffs[i])
}

/// [`noise_from_differences`] of the `n` differences `diff(0)`, …, `diff(n − 1)`, wherever they
/// lie (the env-map shards' sections, joined without a copy): the same blocks, the same bits.
pub fn noise_from<'a>(n: usize, diff: impl Fn(usize) -> &'a [f32; DIM] + Sync) -> EnvmapNoise {
    use rayon::prelude::*;
    let blocks = n.div_ceil(NOISE_BLOCK);
    let partial: Vec<Vec<f64>> = (0..blocks)
        .into_par_iter()
        .map(|b| {
            let mut m = vec![0.0f64; DIM * DIM];
            for i in b * NOISE_BLOCK..((b + 1) * NOISE_BLOCK).min(n) {
                let d = diff(i);
                for a in 0..DIM {
                    let da = d[a] as f64;
                    if da == 0.0 {
                        continue;
                    }
                    let row = &mut m[a * DIM..(a + 1) * DIM];
                    for (x, &db) in row[a..].iter_mut().zip(&d[a..]) {
                        *x += da * db as f64;
                    }
                }
            }
            m
        })
        .collect();
    let mut m = vec![0.0f64; DIM * DIM];
    for blk in &partial {
        for (a, b) in m.iter_mut().zip(blk) {
            *a += b;
        }
    }
    let scale = 1.0 / (4.0 * n.max(1) as f64);
    for a in 0..DIM {
        for b in a..DIM {
            m[a * DIM + b] *= scale;
            m[b * DIM + a] = m[a * DIM + b];
        }
    }
    let variance = (0..n)
        .into_par_iter()
        .map(|i| (diff(i).iter().map(|&x| x as f64 * x as f64).sum::<f64>() / 4.0) as f32)
        .collect();
    EnvmapNoise {
        covariance: m,
        variance,
    }
}

pub fn envmaps_to_section(
    name: &str,
    meta: &EnvmapsMeta,
    sky: &[[[f32; 3]; COEFFS]],
    sun: &[[[f32; 3]; COEFFS]],
    noise: Option<&EnvmapNoise>,
) -> Section {
    assert_eq!(sky.len(), sun.len(), "as many sun maps as sky maps");
    envmaps_to_section_filled(
        name,
        meta,
        sky.len(),
        |out| out.copy_from_slice(sky),
        |out| out.copy_from_slice(sun),
        noise,
    )
}

/// [`envmaps_to_section`] of `n` instances whose `sky` and `sun` arrays `fill_sky` and
/// `fill_sun` write in place (the join of the env-map shards: no copy of the maps beside the
/// section's own).
pub fn envmaps_to_section_filled(
    name: &str,
    meta: &EnvmapsMeta,
    n: usize,
    fill_sky: impl FnOnce(&mut [[[f32; 3]; COEFFS]]),
    fill_sun: impl FnOnce(&mut [[[f32; 3]; COEFFS]]),
    noise: Option<&EnvmapNoise>,
) -> Section {
    let mut b = SectionBuilder::new(ENVMAPS_KIND, name);
    b.meta(meta)
        .array_fill("sky", ArrayFormat::F32, 48, n, fill_sky)
        .array_fill("sun", ArrayFormat::F32, 48, n, fill_sun);
    if let Some(nz) = noise {
        let cov: Vec<[f32; DIM]> = nz
            .covariance
            .chunks_exact(DIM)
            .map(|r| std::array::from_fn(|c| r[c] as f32))
            .collect();
        b.array("noise_covariance", ArrayFormat::F32, DIM as u32, &cov)
            .array("noise_variance", ArrayFormat::F32, 1, &nz.variance);
    }
    b.finish()
}

/// The section's noise estimate, if it has one (checked against its metadata).
pub fn envmaps_noise_from_section(
    v: &SectionView,
    meta: &EnvmapsMeta,
) -> Result<Option<EnvmapNoise>, ParseError> {
    if meta.noise_pairs == 0 {
        return Ok(None);
    }
    let cov: Vec<[f32; DIM]> = v.array_vec("noise_covariance")?;
    let variance: Vec<f32> = v.array_vec("noise_variance")?;
    let cov: Vec<f32> = cov.concat();
    if cov.len() != DIM * DIM || variance.len() as u64 != meta.instances {
        return Err(ParseError::new(
            "envmaps section",
            format!(
                "noise estimate: {} covariance floats (want {}), {} variances for {} instances",
                cov.len(),
                DIM * DIM,
                variance.len(),
                meta.instances
            ),
        ));
    }
    Ok(Some(EnvmapNoise {
        covariance: cov.iter().map(|&x| x as f64).collect(),
        variance,
    }))
}

/// Where the noise is: the fractions of the noise variance (the covariance's trace) in C_H and
/// C_S, and in SH bands 0..3 (both maps, all colours).
pub fn noise_breakdown(nz: &EnvmapNoise) -> Value {
    let diag: Vec<f64> = (0..DIM).map(|i| nz.covariance[i * DIM + i]).collect();
    let total: f64 = diag.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    let sky: f64 = diag[..DIM / 2].iter().sum();
    let mut bands = [0.0f64; 4];
    for (i, &d) in diag.iter().enumerate() {
        let c = (i % (DIM / 2)) / 3;
        let l = (c as f64).sqrt().floor() as usize;
        bands[l.min(3)] += d;
    }
    json!({
        "sky_fraction": sky / total,
        "sun_fraction": 1.0 - sky / total,
        "band_fractions": bands.map(|b| b / total),
    })
}

/// Decodes to (meta, sky, sun).
#[allow(clippy::type_complexity)]
pub fn envmaps_from_section(
    v: &SectionView,
) -> Result<
    (
        EnvmapsMeta,
        Vec<[[f32; 3]; COEFFS]>,
        Vec<[[f32; 3]; COEFFS]>,
    ),
    ParseError,
> {
    let meta = EnvmapsMeta::decode(v)?;
    let sky: Vec<[[f32; 3]; COEFFS]> = v.array_vec("sky")?;
    let sun: Vec<[[f32; 3]; COEFFS]> = v.array_vec("sun")?;
    if sky.len() as u64 != meta.instances || sun.len() as u64 != meta.instances {
        return Err(ParseError::new(
            "envmaps section",
            "map count differs from the instance count",
        ));
    }
    Ok((meta, sky, sun))
}

/// Flattens to `DIM` floats per instance: C_H then C_S, each `[coefficient][rgb]`.
pub fn flatten(sky: &[[[f32; 3]; COEFFS]], sun: &[[[f32; 3]; COEFFS]]) -> Vec<f32> {
    sky.iter()
        .zip(sun)
        .flat_map(|(a, b)| {
            a.iter()
                .chain(b.iter())
                .flat_map(|c| c.iter().copied())
                .collect::<Vec<f32>>()
        })
        .collect()
}

pub fn envmaps_summary(v: &SectionView) -> Result<Value, ParseError> {
    let m = EnvmapsMeta::decode(v)?;
    let mut doc = json!({"instances": m.instances, "order": m.order, "samples": m.samples,
        "estimator": m.estimator, "noise_pairs": m.noise_pairs});
    if let Some(nz) = envmaps_noise_from_section(v, &m)? {
        let (_, sky, sun) = envmaps_from_section(v)?;
        let values = flatten(&sky, &sun);
        let ms =
            values.iter().map(|&x| x as f64 * x as f64).sum::<f64>() / values.len().max(1) as f64;
        let var = nz.mean_variance();
        doc["noise"] = json!({
            "rms": var.sqrt(),
            "relative": if ms > 0.0 { (var / ms).sqrt() } else { 0.0 },
            "where": noise_breakdown(&nz),
        });
    }
    Ok(doc)
}

pub fn envmaps_data(v: &SectionView) -> Result<Value, ParseError> {
    let (m, sky, sun) = envmaps_from_section(v)?;
    let mut doc = json!({"sky": sky, "sun": sun});
    if let Some(nz) = envmaps_noise_from_section(v, &m)? {
        doc["noise_covariance"] = json!(nz.covariance);
        doc["noise_variance"] = json!(nz.variance);
    }
    Ok(doc)
}

/// What the runtime needs to reconstruct every instance's maps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClustersMeta {
    pub instances: u64,
    pub clusters: u64,
    pub dim: u32,
    pub k: u32,
    pub radius: f32,
    /// The multiquadric system is augmented with a constant term.
    pub constant_term: bool,
    pub error_bound: f32,
    pub rms_error_relative: f32,
    pub max_error_relative: f32,
    pub ill_conditioned: u64,
    /// Per-instance neighbours and weights are stored (else the runtime solves).
    pub weights: bool,
    /// Principal components of the per-instance local part (`envmap::local`; arrays
    /// `local_basis`, `local_scale`, `local_coeffs`); 0: none. Added in version 3 of the
    /// section (cluster stage version 3); version 2 metadata ends before it and reads as 0.
    pub local_components: u32,
    /// The byte budget the split loop honoured (samples and local part); 0: none.
    pub max_bytes: u64,
    /// RMS error of the shared part alone (before the local part), relative as above.
    pub shared_rms_error_relative: f32,
    /// The input maps' Monte-Carlo noise (the `envmaps` section's estimate: √(trace / dim) of
    /// its covariance), relative as above; 0: the input carries no noise estimate. Added in
    /// version 4 of the section (cluster stage version 4); older metadata reads as 0.
    pub input_noise_relative: f32,
    /// The local part was Wiener-filtered with that noise (`local::fit_denoised`).
    pub denoised: bool,
}

/// Version 3 of [`ClustersMeta`] (no noise fields).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ClustersMetaV3 {
    instances: u64,
    clusters: u64,
    dim: u32,
    k: u32,
    radius: f32,
    constant_term: bool,
    error_bound: f32,
    rms_error_relative: f32,
    max_error_relative: f32,
    ill_conditioned: u64,
    weights: bool,
    local_components: u32,
    max_bytes: u64,
    shared_rms_error_relative: f32,
}

/// Version 2 of [`ClustersMeta`] (no local part).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ClustersMetaV2 {
    instances: u64,
    clusters: u64,
    dim: u32,
    k: u32,
    radius: f32,
    constant_term: bool,
    error_bound: f32,
    rms_error_relative: f32,
    max_error_relative: f32,
    ill_conditioned: u64,
    weights: bool,
}

impl ClustersMeta {
    /// Decodes version 4 metadata, or version 3 (without the noise fields) or 2 (without a
    /// local part).
    pub fn decode(v: &SectionView) -> Result<ClustersMeta, ParseError> {
        match v.meta::<ClustersMeta>() {
            Ok(m) => Ok(m),
            Err(e) => {
                if let Ok(o) = v.meta::<ClustersMetaV3>() {
                    return Ok(ClustersMeta {
                        instances: o.instances,
                        clusters: o.clusters,
                        dim: o.dim,
                        k: o.k,
                        radius: o.radius,
                        constant_term: o.constant_term,
                        error_bound: o.error_bound,
                        rms_error_relative: o.rms_error_relative,
                        max_error_relative: o.max_error_relative,
                        ill_conditioned: o.ill_conditioned,
                        weights: o.weights,
                        local_components: o.local_components,
                        max_bytes: o.max_bytes,
                        shared_rms_error_relative: o.shared_rms_error_relative,
                        input_noise_relative: 0.0,
                        denoised: false,
                    });
                }
                let o: ClustersMetaV2 = v.meta().map_err(|_| e)?;
                Ok(ClustersMeta {
                    instances: o.instances,
                    clusters: o.clusters,
                    dim: o.dim,
                    k: o.k,
                    radius: o.radius,
                    constant_term: o.constant_term,
                    error_bound: o.error_bound,
                    rms_error_relative: o.rms_error_relative,
                    max_error_relative: o.max_error_relative,
                    ill_conditioned: o.ill_conditioned,
                    weights: o.weights,
                    local_components: 0,
                    max_bytes: 0,
                    shared_rms_error_relative: o.rms_error_relative,
                    input_noise_relative: 0.0,
                    denoised: false,
                })
            }
        }
    }
}

/// The local part of a `clusters` section, if it has one (checked against its metadata).
pub fn local_from_section(
    v: &SectionView,
    meta: &ClustersMeta,
) -> Result<Option<super::local::LocalPart>, ParseError> {
    let p = meta.local_components as usize;
    if p == 0 {
        return Ok(None);
    }
    let dim = meta.dim as usize;
    let basis: Vec<f32> = v.array_vec("local_basis")?;
    let scale: Vec<f32> = v.array_vec("local_scale")?;
    let coeffs: Vec<u8> = v.array_vec("local_coeffs")?;
    if basis.len() != p * dim
        || scale.len() != p
        || coeffs.len() as u64 != meta.instances * p as u64
    {
        return Err(ParseError::new(
            "clusters section",
            format!(
                "local part: {} basis floats, {} scales, {} coefficients for {p} components × {dim} floats and {} instances",
                basis.len(),
                scale.len(),
                coeffs.len(),
                meta.instances
            ),
        ));
    }
    Ok(Some(super::local::LocalPart {
        components: p,
        dim,
        basis,
        scale,
        coeffs,
    }))
}

/// Encodes the cluster samples (positions and values) and optionally per-instance neighbours and
/// weights (`neighbours[i]` k sample indices, `weights[i]` k floats).
pub fn clusters_to_section(
    name: &str,
    meta: &ClustersMeta,
    z: &super::Compressed,
    positions: &[[f32; 3]],
    values: &[f32],
    weights: Option<(&[u32], &[f32])>,
) -> Section {
    let dim = meta.dim as usize;
    let c = &z.clustering;
    let local = z.local.as_ref();
    let pts: Vec<[f32; 3]> = c.samples.iter().map(|&s| positions[s as usize]).collect();
    let vals = z.sample_rows(values, dim);
    let mut b = SectionBuilder::new(CLUSTERS_KIND, name);
    b.meta(meta)
        .array("sample_positions", ArrayFormat::F32, 3, &pts)
        .array("sample_values", ArrayFormat::F32, 1, &vals)
        .array("sample_instance", ArrayFormat::U32, 1, &c.samples);
    if let Some(l) = local {
        b.array("local_basis", ArrayFormat::F32, 1, &l.basis)
            .array("local_scale", ArrayFormat::F32, 1, &l.scale)
            .array("local_coeffs", ArrayFormat::U8, 1, &l.coeffs);
    }
    if let Some((nb, w)) = weights {
        b.array("neighbours", ArrayFormat::U32, 1, nb)
            .array("weights", ArrayFormat::F32, 1, w);
    }
    b.finish()
}

pub fn clusters_summary(v: &SectionView) -> Result<Value, ParseError> {
    let m = ClustersMeta::decode(v)?;
    let packed: u64 = v.arrays.iter().map(|a| a.byte_len()).sum();
    let raw = m.instances * m.dim as u64 * 4;
    Ok(json!({
        "instances": m.instances, "clusters": m.clusters, "k": m.k, "radius": m.radius,
        "constant_term": m.constant_term, "error_bound": m.error_bound,
        "rms_error_relative": m.rms_error_relative, "max_error_relative": m.max_error_relative,
        "shared_rms_error_relative": m.shared_rms_error_relative,
        "local_components": m.local_components, "max_bytes": m.max_bytes,
        "input_noise_relative": m.input_noise_relative, "denoised": m.denoised,
        "ill_conditioned": m.ill_conditioned, "raw_bytes": raw, "packed_bytes": packed,
        "compression": if packed > 0 { raw as f64 / packed as f64 } else { 0.0 },
    }))
}

pub fn clusters_data(v: &SectionView) -> Result<Value, ParseError> {
    let pts: Vec<[f32; 3]> = v.array_vec("sample_positions")?;
    let inst: Vec<u32> = v.array_vec("sample_instance")?;
    Ok(json!({"sample_positions": pts, "sample_instance": inst}))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn version_2_metadata_reads_as_a_section_without_a_local_part() {
        let old = ClustersMetaV2 {
            instances: 10,
            clusters: 2,
            dim: DIM as u32,
            k: 4,
            radius: 3.0,
            constant_term: true,
            error_bound: 0.02,
            rms_error_relative: 0.01,
            max_error_relative: 0.03,
            ill_conditioned: 0,
            weights: false,
        };
        let mut b = SectionBuilder::new(CLUSTERS_KIND, "clusters");
        b.meta(&old);
        let mut w = crate::pack::PackWriter::new();
        w.insert(b.finish());
        let pack = crate::pack::Pack::from_bytes(&w.to_bytes().unwrap(), "v2.bake").unwrap();
        let v = pack.view_named("clusters").unwrap();
        let m = ClustersMeta::decode(&v).unwrap();
        assert_eq!((m.instances, m.k, m.local_components), (10, 4, 0));
        assert_eq!(m.shared_rms_error_relative, 0.01);
        assert_eq!(local_from_section(&v, &m).unwrap(), None);
    }
}
