//! The `envmaps` stage (the instances' environment maps, in shards of instances joined into one
//! section) and the `cluster` stage (their clustering). Their registry lines are in
//! `crate::graph::stage::REGISTRY`.

use crate::diag;
use crate::diag::Diagnostic;
use crate::error::ParseError;
use crate::error::{Error, Result};
use crate::lightmap::stage::Traced;
use crate::pack::section::ArrayFormat::{F32, U8, U32};
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use crate::stage::kind::{Naming, SectionKind};
use crate::stage::{
    LIGHTING, Output, Per, Preset, Reads, Shard, Stage, StageDef, StageKey, UnitCtx, UnitInputs,
    report_of,
};
use serde_json::json;
use std::ops::Range;

/// 2: the rays traced as two independently rotated halves, whose difference is the
/// section's noise estimate (`noise_covariance`, `noise_variance`; issue 20, item 2).
/// 3: the linear albedo and the terrain's drawn albedo (issue 35).
/// 4: a probe's rays ignore the instances that enclose the probe (`trace::SceneBvh::enclosing`)
/// and those whose probe the instance encloses (issue 35).
/// 5: where an instance encloses its own probe, the hit points inside its box are lit as if it
/// were absent (docs/CONVENTIONS.md, "Environment-map probes"; issue 35).
pub const ENVMAPS_VERSION: u32 = 5;
/// 2: the report carries `compression`, and a warning when it is below 2x (issue 20).
/// 3: a byte budget (20x by default), the per-instance local part and split fraction 1.0
/// (issue 20, item 2).
/// 4: the local part Wiener-filtered with the `envmaps` section's noise estimate by default
/// (`denoise`), the metadata states `input_noise_relative` (issue 20, item 2).
pub const CLUSTER_VERSION: u32 = 4;

/// The instances' environment maps (`envmaps`), in shards of instances: each unit writes a
/// cache-only `envmaps-shard` section, joined into `envmaps` ([`join_envmaps`]).
pub struct Envmaps;
impl Stage for Envmaps {
    type Options = crate::envmap::bake::EnvmapOptions;
    fn kinds(&self) -> &'static [SectionKind] {
        ENVMAPS_KINDS
    }
    /// 64 rays in the preview, 1,024 in the final pipeline.
    fn options_in(&self, preset: Preset) -> Self::Options {
        use crate::envmap::bake::EnvmapOptions;
        let d = EnvmapOptions::DEFAULT;
        match preset {
            Preset::Default => d,
            Preset::Preview | Preset::Ci => EnvmapOptions { samples: 64, ..d },
            Preset::Final => EnvmapOptions { samples: 1024, ..d },
        }
    }
    fn needs(&self) -> &'static [&'static str] {
        &["sky"]
    }
    fn check(&self, o: &Self::Options) -> std::result::Result<(), String> {
        o.check()
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "envmaps",
            version: ENVMAPS_VERSION,
            per: Per::Shards,
            writes: &["envmaps"],
            actions: &["envmaps", "envmaps-join"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        LIGHTING
    }
    fn total(&self, u: &UnitInputs) -> Option<u64> {
        match &u.shard {
            Some(Shard::Range(r)) => Some(r.len() as u64),
            _ => None,
        }
    }
    /// The options without the tracer, then the tracer only when not `cpu`.
    fn key(&self, _: &UnitInputs, e: &Self::Options, k: &mut StageKey) -> Result<()> {
        let mut o = report_of(e);
        if let Some(m) = o.as_object_mut() {
            m.remove("tracer");
        }
        crate::trace::keyed_tracer(&mut o, e.tracer);
        k.options(&o).inputs();
        Ok(())
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (ts, light) = cx.traced::<Traced>()?;
        let shard = cx
            .shard
            .as_ref()
            .ok_or_else(|| Error::usage("envmaps: a unit covers one shard of instances"))?;
        let range = shard.range(ts.instances.items.len());
        let m = crate::envmap::instance_traced(ts, light, o, range)?;
        Ok(Output {
            report: json!({"instances": m.maps.len(), "rays": m.maps.len() as u64 * o.samples as u64}),
            sections: vec![shard_section(&m)],
            ..Default::default()
        })
    }
    fn join(&self, parts: Vec<(usize, Vec<Section>)>, o: &Self::Options) -> Result<Vec<Section>> {
        Ok(vec![join_envmaps(&parts, o)?])
    }
    /// The maps of a shard's `envmaps-shard` section (32 a map), checked as the join reads them.
    fn shard_size(&self, shard: &[Section]) -> Result<usize> {
        let n = shard
            .first()
            .and_then(|x| crate::pack::section::SectionView::parse(&x.payload, 0).ok())
            .and_then(|v| v.info("maps").map(|a| a.count as usize / 32))
            .ok_or_else(|| {
                Error::runtime("not the pack of an environment-map shard (bake unit envmaps)")
            })?;
        shard_maps(shard, n)?;
        Ok(n)
    }
}

/// The graph's shards of `n` instances: `per` instances each (one empty shard for none).
pub fn envmap_shards(n: usize, per: usize) -> Vec<Range<usize>> {
    let per = per.max(1);
    (0..n.max(1))
        .step_by(per)
        .map(|start| start..(start + per).min(n))
        .collect()
}

/// The `envmaps` section from its shards' sections, in shard order (each with its number of
/// instances): the bytes of [`crate::envmap::envmaps_section`] over the shards' maps put end
/// to end, written straight from the shards' arrays into the section's (at 200,000 instances
/// the maps and their half differences are 154 MB; copied once more and then once again into
/// the section they made a 0.33 GB spike in the default bake's memory, issue 37).
pub fn join_envmaps(
    shards: &[(usize, Vec<Section>)],
    o: &crate::envmap::bake::EnvmapOptions,
) -> Result<Section> {
    let views = shards
        .iter()
        .map(|(n, s)| shard_view(s, *n))
        .collect::<Result<Vec<_>>>()?;
    // Each shard's first instance, and the total.
    let starts: Vec<usize> = views
        .iter()
        .scan(0, |at, (maps, _)| {
            let start = *at;
            *at += maps.len() / 32;
            Some(start)
        })
        .collect();
    let n: usize = views.iter().map(|(maps, _)| maps.len() / 32).sum();
    // A noise estimate only where every map has its half difference (an empty shard has none
    // to give), as `Traced::extend` then `envmaps_section` decide.
    let diffs: Option<Vec<&[[f32; 96]]>> = views
        .iter()
        .map(|(maps, d)| if maps.is_empty() { Some(&[][..]) } else { *d })
        .collect();
    let noise = diffs.filter(|_| n > 0).map(|diffs| {
        let at = |i: usize| {
            let s = starts.partition_point(|&start| start <= i) - 1;
            &diffs[s][i - starts[s]]
        };
        crate::envmap::section::noise_from(n, at)
    });
    let fill = |half: usize| {
        let views = &views;
        move |out: &mut [[[f32; 3]; 16]]| {
            let mut k = 0;
            for (maps, _) in views {
                for m in maps.chunks_exact(32) {
                    out[k] = std::array::from_fn(|i| m[half * 16 + i]);
                    k += 1;
                }
            }
        }
    };
    Ok(crate::envmap::section::envmaps_to_section_filled(
        "envmaps",
        &crate::envmap::envmaps_meta(n, noise.is_some(), o),
        n,
        fill(0),
        fill(1),
        noise.as_ref(),
    ))
}

/// A shard's maps (32 RGB coefficients per instance: C_H then C_S) and half differences, as
/// views into its `envmaps-shard` section, checked (the entry's kind, the counts).
fn shard_view(sections: &[Section], n: usize) -> Result<ShardView<'_>> {
    let bad = || Error::runtime("environment-map shard: unexpected cache entry contents");
    let s = sections
        .first()
        .filter(|s| s.kind == SHARD_KIND)
        .ok_or_else(bad)?;
    let v = crate::pack::section::SectionView::parse(&s.payload, 0).map_err(|_| bad())?;
    let maps: &[[f32; 3]] = v.array("maps").map_err(|_| bad())?;
    if maps.len() != n * 32 {
        return Err(bad());
    }
    // An empty `noise` array is none (as the shards' writer leaves it out).
    let diffs: Option<&[[f32; 96]]> = match v.info("noise") {
        Some(_) => Some(v.array("noise").map_err(|_| bad())?).filter(|d| !d.is_empty()),
        None => None,
    };
    if diffs.is_some_and(|d| d.len() != n) {
        return Err(bad());
    }
    Ok((maps, diffs))
}

/// A shard's maps and half differences (see [`shard_view`]).
type ShardView<'a> = (&'a [[f32; 3]], Option<&'a [[f32; 96]]>);

/// The instances' clustering (`cluster`) over their environment maps.
pub struct Cluster;
impl Stage for Cluster {
    type Options = crate::envmap::cluster::ClusterOptions;
    fn diagnostics(&self) -> &'static [Diagnostic] {
        CLUSTER_DIAGNOSTICS
    }
    fn kinds(&self) -> &'static [SectionKind] {
        CLUSTER_KINDS
    }
    /// Clustering at 1 % in the final pipeline.
    fn options_in(&self, preset: Preset) -> Self::Options {
        use crate::envmap::cluster::ClusterOptions;
        match preset {
            Preset::Final => ClusterOptions {
                error: 0.01,
                ..ClusterOptions::DEFAULT
            },
            _ => ClusterOptions::DEFAULT,
        }
    }
    fn needs(&self) -> &'static [&'static str] {
        &["envmaps"]
    }
    fn def(&self) -> &'static StageDef {
        static DEF: StageDef = StageDef {
            name: "cluster",
            version: CLUSTER_VERSION,
            per: Per::Scene,
            writes: &["clusters"],
            actions: &["cluster"],
        };
        &DEF
    }
    fn reads(&self) -> Reads {
        Reads {
            kinds: &["instances", "envmaps"],
            ..Reads::default()
        }
    }
    fn run(&self, cx: &UnitCtx, o: &Self::Options) -> Result<Output> {
        let (s, c, w) = crate::envmap::cluster_sections_warned(cx.view(), o, o.weights)?;
        Ok(Output {
            report: json!({"clusters": c.clustering.samples.len(), "rms_error": c.rms_error(), "max_error": c.max_error(),
                "shared_rms_error": c.clustering.rms_error(),
                "rounds": c.clustering.rounds, "noise_relative": c.clustering.noise,
                "local_components": c.local.as_ref().map_or(0, |l| l.components),
                "compression": crate::envmap::compression(&c, crate::envmap::section::DIM)}),
            sections: s,
            warnings: diag::tagged(&CLUSTER_COMPRESSION_LOW, w),
            ..Default::default()
        })
    }
}

/// Kind of the cache-only section that holds one shard's environment maps.
const SHARD_KIND: &str = "envmaps-shard";

pub(crate) fn shard_section(t: &super::bake::Traced) -> Section {
    let flat: Vec<[f32; 3]> = t
        .maps
        .iter()
        .flat_map(|(h, s)| h.iter().chain(s.iter()).copied())
        .collect();
    let mut b = SectionBuilder::new(SHARD_KIND, SHARD_KIND);
    b.array("maps", ArrayFormat::F32, 3, &flat);
    if !t.diffs.is_empty() {
        b.array("noise", ArrayFormat::F32, 96, &t.diffs);
    }
    b.finish()
}

pub(crate) fn shard_maps(sections: &[Section], n: usize) -> Result<super::bake::Traced> {
    let (flat, diffs) = shard_view(sections, n)?;
    let maps = flat
        .chunks_exact(32)
        .map(|c| {
            (
                std::array::from_fn(|i| c[i]),
                std::array::from_fn(|i| c[16 + i]),
            )
        })
        .collect();
    Ok(crate::envmap::bake::Traced {
        maps,
        diffs: diffs.map_or_else(Vec::new, <[_]>::to_vec),
    })
}

/// The section kinds the `envmaps` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const ENVMAPS_KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::envmap::section::ENVMAPS_KIND,
    naming: Naming::Kind,
    arrays: &[
        ("sky", &[F32], 48),
        ("sun", &[F32], 48),
        ("noise_covariance", &[F32], 96),
        ("noise_variance", &[F32], 1),
    ],
    decode: decode_envmaps,
    views: Some((
        crate::envmap::section::envmaps_summary,
        crate::envmap::section::envmaps_data,
    )),
    check: None,
}];

/// The maps, then their noise arrays against the metadata.
fn decode_envmaps(v: &SectionView) -> Result<(), ParseError> {
    let (m, _, _) = crate::envmap::section::envmaps_from_section(v)?;
    crate::envmap::section::envmaps_noise_from_section(v, &m).map(drop)
}

/// The section kinds the `cluster` stage defines (docs/FORMAT.md): what `bake dump` and `bake
/// verify` know of them, reached through the stage's registry line.
const CLUSTER_KINDS: &[SectionKind] = &[SectionKind {
    kind: crate::envmap::section::CLUSTERS_KIND,
    naming: Naming::Kind,
    arrays: &[
        ("sample_positions", &[F32], 3),
        ("sample_values", &[F32], 1),
        ("sample_instance", &[U32], 1),
        ("local_basis", &[F32], 1),
        ("local_scale", &[F32], 1),
        ("local_coeffs", &[U8], 1),
        ("neighbours", &[U32], 1),
        ("weights", &[F32], 1),
    ],
    decode: |v| crate::envmap::section::clusters_summary(v).map(drop),
    views: Some((
        crate::envmap::section::clusters_summary,
        crate::envmap::section::clusters_data,
    )),
    check: None,
}];

/// `cluster.compression-low`.
pub const CLUSTER_COMPRESSION_LOW: Diagnostic = Diagnostic::warning(
    "cluster.compression-low",
    "the env-map clusters compress the maps less than 2×",
);

/// The warnings the `cluster` stage gives (docs/DIAGNOSTICS.md), reached through its registry line.
const CLUSTER_DIAGNOSTICS: &[Diagnostic] = &[CLUSTER_COMPRESSION_LOW];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::bake::{EnvmapOptions, Traced};

    /// `n` instances' maps and half differences, every value distinct (from `seed`).
    fn traced(n: usize, seed: u32, noise: bool) -> Traced {
        let v =
            |i: usize, k: usize| ((seed as usize * 7919 + i * 131 + k) % 1009) as f32 * 0.37 - 90.0;
        Traced {
            maps: (0..n)
                .map(|i| {
                    (
                        std::array::from_fn(|c| std::array::from_fn(|k| v(i, c * 3 + k))),
                        std::array::from_fn(|c| std::array::from_fn(|k| v(i, 48 + c * 3 + k))),
                    )
                })
                .collect(),
            diffs: match noise {
                true => (0..n)
                    .map(|i| std::array::from_fn(|k| v(i, 96 + k)))
                    .collect(),
                false => Vec::new(),
            },
        }
    }

    #[test]
    fn the_shards_joined_in_place_give_the_bytes_of_their_maps_put_end_to_end() {
        // Oracle: `envmaps_section` of the shards' maps concatenated (the join before it wrote
        // the section from the shards' arrays). Shards of 1,500 and 700 instances cross the
        // covariance's blocks of 1,024; an empty shard in the middle gives no difference and
        // takes no noise estimate away; a shard without differences does.
        let o = EnvmapOptions::default();
        for (sizes, noise) in [
            (vec![1500, 0, 700, 1], vec![true, false, true, true]),
            (vec![3, 5], vec![true, false]),
            (vec![0], vec![false]),
            (vec![2048], vec![true]),
        ] {
            let parts: Vec<Traced> = sizes
                .iter()
                .zip(&noise)
                .enumerate()
                .map(|(s, (&n, &z))| traced(n, s as u32, z))
                .collect();
            let shards: Vec<(usize, Vec<Section>)> = parts
                .iter()
                .map(|t| (t.maps.len(), vec![shard_section(t)]))
                .collect();
            let mut all = Traced::default();
            for t in parts {
                all.extend(t);
            }
            let want = crate::envmap::envmaps_section(&all, &o);
            let got = join_envmaps(&shards, &o).unwrap();
            assert!(got.payload == want.payload, "{sizes:?} {noise:?}");
            let v = crate::pack::section::SectionView::parse(&got.payload, 0).unwrap();
            let with_noise = v.info("noise_covariance").is_some();
            assert_eq!(
                with_noise,
                sizes.iter().sum::<usize>() > 0
                    && sizes.iter().zip(&noise).all(|(&n, &z)| n == 0 || z),
                "{sizes:?} {noise:?}"
            );
        }
    }
}
