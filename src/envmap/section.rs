//! Kinds `envmaps` (per-instance SH environment maps C_H and C_S) and `clusters` (the cluster
//! samples and interpolation parameters that replace them).

use super::cluster::Clustering;
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
}

pub fn envmaps_to_section(
    name: &str,
    meta: &EnvmapsMeta,
    sky: &[[[f32; 3]; COEFFS]],
    sun: &[[[f32; 3]; COEFFS]],
) -> Section {
    let mut b = SectionBuilder::new(ENVMAPS_KIND, name);
    b.meta(meta)
        .array("sky", ArrayFormat::F32, 48, sky)
        .array("sun", ArrayFormat::F32, 48, sun);
    b.finish()
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
    let meta: EnvmapsMeta = v.meta()?;
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
    let m: EnvmapsMeta = v.meta()?;
    Ok(
        json!({"instances": m.instances, "order": m.order, "samples": m.samples, "estimator": m.estimator}),
    )
}

pub fn envmaps_data(v: &SectionView) -> Result<Value, ParseError> {
    let (_, sky, sun) = envmaps_from_section(v)?;
    Ok(json!({"sky": sky, "sun": sun}))
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
}

/// Encodes the cluster samples (positions and values) and optionally per-instance neighbours and
/// weights (`neighbours[i]` k sample indices, `weights[i]` k floats).
pub fn clusters_to_section(
    name: &str,
    meta: &ClustersMeta,
    c: &Clustering,
    positions: &[[f32; 3]],
    values: &[f32],
    weights: Option<(&[u32], &[f32])>,
) -> Section {
    let dim = meta.dim as usize;
    let (pts, vals) = super::cluster::gather_samples(positions, values, dim, &c.samples);
    let mut b = SectionBuilder::new(CLUSTERS_KIND, name);
    b.meta(meta)
        .array("sample_positions", ArrayFormat::F32, 3, &pts)
        .array("sample_values", ArrayFormat::F32, 1, &vals)
        .array("sample_instance", ArrayFormat::U32, 1, &c.samples);
    if let Some((nb, w)) = weights {
        b.array("neighbours", ArrayFormat::U32, 1, nb)
            .array("weights", ArrayFormat::F32, 1, w);
    }
    b.finish()
}

pub fn clusters_summary(v: &SectionView) -> Result<Value, ParseError> {
    let m: ClustersMeta = v.meta()?;
    let packed: u64 = v.arrays.iter().map(|a| a.byte_len()).sum();
    let raw = m.instances * m.dim as u64 * 4;
    Ok(json!({
        "instances": m.instances, "clusters": m.clusters, "k": m.k, "radius": m.radius,
        "constant_term": m.constant_term, "error_bound": m.error_bound,
        "rms_error_relative": m.rms_error_relative, "max_error_relative": m.max_error_relative,
        "ill_conditioned": m.ill_conditioned, "raw_bytes": raw, "packed_bytes": packed,
        "compression": if packed > 0 { raw as f64 / packed as f64 } else { 0.0 },
    }))
}

pub fn clusters_data(v: &SectionView) -> Result<Value, ParseError> {
    let pts: Vec<[f32; 3]> = v.array_vec("sample_positions")?;
    let inst: Vec<u32> = v.array_vec("sample_instance")?;
    Ok(json!({"sample_positions": pts, "sample_instance": inst}))
}
