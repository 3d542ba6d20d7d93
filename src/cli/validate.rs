//! `bake validate PACK`: the runtime check of issue 6 — the compute shaders traverse the pack's
//! `svo`, `svo-scene`, `linespace` and `linespace-scene` sections for a batch of random rays and
//! the answers are compared with
//! the CPU traversal (for `svo` also the level-of-detail traversal of `bake render --view svo`);
//! exits non-zero (runtime error) when they disagree.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::linespace::gpu::validate_linespace;
use crate::pack::Pack;
use crate::render::BackendChoice;
use crate::voxel::gpu::{SvoAgreement, compare_hits, random_rays, trace_svo_cpu};
use crate::voxel::lod_gpu::{LodAgreement, compare_lod_hits, unit_rays, validation_cones};
use crate::voxel::lod_trace::trace_lod;
use serde_json::json;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ValidateArgs {
    /// A .bake pack with an `svo` and/or a `linespace` section.
    pub pack: PathBuf,
    /// Random rays through the octree.
    #[arg(long, default_value_t = 100_000)]
    pub rays: usize,
    /// Random receivers of the soft-shadow queries.
    #[arg(long, default_value_t = 2_000)]
    pub receivers: usize,
    /// Light samples per side (samples² segments per receiver).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub samples: u32,
    /// Seed of the random batches.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Deepest-level refinement of the line-space queries compared (both sides).
    #[arg(long, value_enum, default_value_t = crate::linespace::ntree::Refine::default())]
    pub refine: crate::linespace::ntree::Refine,
    /// Graphics API.
    #[arg(long, value_enum, default_value_t = BackendChoice::Auto)]
    pub backend: BackendChoice,
}

/// Traces the `svo` section: GPU buffers straight from the section's arrays.
fn validate_svo_section(
    gpu: &crate::gpu::Gpu,
    view: &crate::pack::section::SectionView,
    args: &ValidateArgs,
    path: &std::path::Path,
) -> Result<SvoAgreement> {
    let (_, svo) =
        crate::voxel::section::from_section(view).map_err(|e| Error::invalid(path, e))?;
    let nodes: &[[u32; 4]] = view.array("nodes").map_err(|e| Error::invalid(path, e))?;
    let leaves: &[u8] = view.array("leaves").map_err(|e| Error::invalid(path, e))?;
    let dev = crate::voxel::gpu::SvoGpu::from_arrays(
        gpu,
        svo.grid.dims,
        svo.levels,
        bytemuck::cast_slice(nodes),
        leaves,
    )?;
    let rays = random_rays(svo.grid.dims, args.rays, args.seed);
    let t0 = std::time::Instant::now();
    let on_gpu = dev.trace(&rays)?;
    let t1 = std::time::Instant::now();
    let on_cpu: Vec<_> = rays.iter().map(|r| trace_svo_cpu(&svo, r)).collect();
    let t2 = std::time::Instant::now();
    Ok(SvoAgreement {
        gpu_seconds: (t1 - t0).as_secs_f64(),
        cpu_seconds: (t2 - t1).as_secs_f64(),
        ..compare_hits(&on_gpu, &on_cpu)
    })
}

/// The level-of-detail traversal of the `svo` section (`bake render --view svo`'s kernel) on the
/// same random rays with unit directions, at cones that reach each level.
fn validate_svo_lod(
    gpu: &crate::gpu::Gpu,
    view: &crate::pack::section::SectionView,
    args: &ValidateArgs,
    path: &std::path::Path,
) -> Result<Vec<(f32, LodAgreement)>> {
    let (_, svo) =
        crate::voxel::section::from_section(view).map_err(|e| Error::invalid(path, e))?;
    let dev = crate::voxel::lod_gpu::SvoLodGpu::new(gpu, &svo)?;
    let rays = unit_rays(&random_rays(svo.grid.dims, args.rays, args.seed));
    let d = svo.grid.dims.into_iter().max().unwrap_or(1);
    validation_cones(d)
        .into_iter()
        .map(|cone| {
            let on_gpu = dev.trace(&rays, cone)?;
            let on_cpu: Vec<_> = rays.iter().map(|r| trace_lod(&svo, r, cone)).collect();
            Ok((cone, compare_lod_hits(&on_gpu, &on_cpu)))
        })
        .collect()
}

pub(crate) fn run(args: &ValidateArgs, _g: &Global) -> Result<Outcome> {
    let pack = Pack::open(&args.pack)?;
    let svo_entry = pack.of_kind(crate::voxel::section::KIND).next();
    let ls_entry = pack.of_kind(crate::linespace::section::KIND).next();
    let scene_entry = pack.of_kind(crate::voxel::instanced_section::KIND).next();
    let ls_scene_entry = pack
        .of_kind(crate::linespace::instanced_section::KIND)
        .next();
    if svo_entry.is_none()
        && ls_entry.is_none()
        && scene_entry.is_none()
        && ls_scene_entry.is_none()
    {
        return Err(Error::invalid_at(
            &args.pack,
            "section table",
            "no svo, svo-scene, linespace or linespace-scene section to validate (run `bake svo` \
             or `bake linespace`)",
        ));
    }
    let gpu = crate::gpu::init_gpu(args.backend)?;
    let mut json = json!({ "pack": args.pack, "adapter": gpu.adapter });
    let mut text = format!("{}: on {}\n", args.pack.display(), gpu.adapter);
    let mut ok = true;
    if let Some(e) = svo_entry {
        let a = validate_svo_section(&gpu, &pack.view(e)?, args, &args.pack)?;
        ok &= a.agrees();
        text += &format!(
            "svo: {} rays, {} hits, {} voxel mismatches, {} t mismatches (max |Δt| {:.2e})\n",
            a.rays, a.hits, a.voxel_mismatches, a.t_mismatches, a.max_t_error
        );
        json["svo"] = json!(a);
        json["svo"]["agree"] = json!(a.agrees());
        let lod = validate_svo_lod(&gpu, &pack.view(e)?, args, &args.pack)?;
        let mut rows = Vec::new();
        for (cone, a) in &lod {
            ok &= a.agrees();
            text += &format!(
                "svo lod (cone {cone:.4}): {} rays, {} hits, {} disagree (at most {} of the rays may)\n",
                a.rays,
                a.hits,
                a.mismatches(),
                crate::voxel::lod_gpu::LOD_MISMATCH_FRACTION
            );
            rows.push(json!({ "cone": cone, "agreement": a, "agree": a.agrees() }));
        }
        json["svo_lod"] = json!(rows);
    }
    if let Some(e) = scene_entry {
        let (_, scene) = crate::voxel::instanced_section::from_section(&pack.view(e)?)
            .map_err(|err| Error::invalid(&args.pack, err))?;
        let a =
            crate::voxel::instanced_gpu::validate_instanced(&gpu, &scene, args.rays, args.seed)?;
        ok &= a.agrees();
        text += &format!(
            "svo-scene: {} rays, {} hits ({} on instances), {} voxel mismatches, {} t mismatches (max |Δt| {:.2e})\n",
            a.rays, a.hits, a.instance_hits, a.voxel_mismatches, a.t_mismatches, a.max_t_error
        );
        text += &format!(
            "svo-scene lod (cone {:.4}): {} rays, {} hits ({} on top-level aggregates, {} on model nodes), {} disagree (at most {} of the rays may)\n",
            a.lod.cone,
            a.lod.rays,
            a.lod.hits,
            a.lod.aggregate_hits,
            a.lod.node_hits,
            a.lod.mismatches,
            crate::voxel::lod_gpu::LOD_MISMATCH_FRACTION
        );
        json["svo_scene"] = json!(a);
        json["svo_scene"]["agree"] = json!(a.agrees());
    }
    if let Some(e) = ls_entry {
        let (_, mut tree) = crate::linespace::section::from_section(&pack.view(e)?)
            .map_err(|err| Error::invalid(&args.pack, err))?;
        tree.refine = args.refine;
        let a = validate_linespace(&gpu, &tree, args.receivers, args.samples, args.seed)?;
        ok &= a.agrees();
        text += &linespace_line("linespace", &a);
        json["linespace"] = json!(a);
        json["linespace"]["agree"] = json!(a.agrees());
    }
    if let Some(e) = ls_scene_entry {
        let (_, mut scene) = crate::linespace::instanced_section::from_section(&pack.view(e)?)
            .map_err(|err| Error::invalid(&args.pack, err))?;
        scene.set_refine(args.refine);
        let a = crate::linespace::instanced_gpu::validate_scene_linespace(
            &gpu,
            &scene,
            args.receivers,
            args.samples,
            args.seed,
        )?;
        ok &= a.agrees();
        text += &linespace_line("linespace-scene", &a);
        json["linespace_scene"] = json!(a);
        json["linespace_scene"]["agree"] = json!(a.agrees());
    }
    json["agree"] = json!(ok);
    if !ok {
        return Err(Error::runtime(format!(
            "GPU and CPU traversals disagree: {text}{json}"
        )));
    }
    Ok(Outcome {
        json,
        text,
        warnings: Vec::new(),
    })
}

/// The text line of a line-space agreement.
fn linespace_line(kind: &str, a: &crate::linespace::gpu::LinespaceAgreement) -> String {
    format!(
        "{kind} (refine {:?}, {} bytes on the GPU): {} segments ({} occluded), {} mismatches ({} without line spaces); \
         {} receivers × {} samples, {} shadow-fraction mismatches, {} in penumbra{}\n",
        a.refine,
        a.gpu_pool_bytes,
        a.segments,
        a.occluded,
        a.segment_mismatches,
        a.exact_mismatches,
        a.receivers,
        a.samples,
        a.fraction_mismatches,
        a.penumbra,
        if a.edge_segment_mismatches + a.edge_exact_mismatches > 0 {
            format!(
                " ({} and {} of the mismatching segments, {} of the receivers, at a placed \
                 triangle's edge within rounding)",
                a.edge_segment_mismatches, a.edge_exact_mismatches, a.edge_fraction_mismatches
            )
        } else {
            String::new()
        }
    )
}
