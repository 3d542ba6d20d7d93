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
    /// Principal components of the per-instance local part (`envmap::local`; arrays
    /// `local_basis`, `local_scale`, `local_coeffs`); 0: none. Added in version 3 of the
    /// section (cluster stage version 3); version 2 metadata ends before it and reads as 0.
    pub local_components: u32,
    /// The byte budget the split loop honoured (samples and local part); 0: none.
    pub max_bytes: u64,
    /// RMS error of the shared part alone (before the local part), relative as above.
    pub shared_rms_error_relative: f32,
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
    /// Decodes version 3 metadata, or version 2 (without a local part).
    pub fn decode(v: &SectionView) -> Result<ClustersMeta, ParseError> {
        match v.meta::<ClustersMeta>() {
            Ok(m) => Ok(m),
            Err(e) => {
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
