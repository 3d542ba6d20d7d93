//! `bake linespace INPUT`: the N-tree with line spaces of a model or pack, for soft shadows.

use super::svo::load_geometry;
use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::stage::{CommandScope, pack_sections, scene_unit};
use crate::ingest::limits::Limits;
use crate::linespace::ntree::{NTreeOptions, Refine, build_ntree};
use crate::linespace::query::AreaLight;
use crate::linespace::section;
use crate::linespace::shaft::ShaftTable;
use crate::voxel::geometry::SceneStage;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LinespaceArgs {
    /// A model (.txf .3ds .obj .gltf .glb) or a .bake pack with mesh sections or a scene.
    pub input: PathBuf,
    /// Output pack (default: the input pack itself, or <model>.bake).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Children per axis of each node (2..=12).
    #[arg(long, default_value_t = 10)]
    pub n: u32,
    /// Levels below the root.
    #[arg(long, default_value_t = 3)]
    pub depth: u32,
    /// Split each axis of the scene's bounds n^depth times (flat cells for a flat scene)
    /// instead of a cube of its longest extent.
    #[arg(long)]
    pub flat_cells: bool,
}

pub(crate) use crate::linespace::world_triangles;

pub(crate) fn run(args: &LinespaceArgs, g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let limits = g.ingest_defaults().limits;
    let opts = NTreeOptions {
        n: args.n,
        depth: args.depth,
        cubic_cells: !args.flat_cells,
    };
    if super::svo::is_pack(&args.input) {
        return run_pack(args, opts, &limits);
    }
    // A model: its mesh.
    let (geo, pack) = load_geometry(&args.input, SceneStage::Linespace, &limits, &mut warnings)?;
    let tris = world_triangles(&geo.mesh);
    if tris.is_empty() {
        return Err(Error::invalid_at(
            &args.input,
            "geometry",
            "no triangles for the N-tree",
        ));
    }
    let start = std::time::Instant::now();
    let shafts = Arc::new(ShaftTable::build(opts.n));
    let tree = build_ntree(&tris, &opts, &shafts)?;
    let seconds = start.elapsed().as_secs_f64();
    let output = args.output.clone().unwrap_or_else(|| match &pack {
        Some(_) => args.input.clone(),
        None => args.input.with_extension("bake"),
    });
    let mut w = super::svo::start_pack(&args.input, pack.as_ref(), &geo, &mut warnings);
    w.insert(section::to_section(
        "linespace",
        &crate::ingest::confine::SourceNames::first_name(&args.input),
        &tree,
    ));
    w.write(&output)?;
    let mut json = section::summary_of(&tree);
    json["output"] = serde_json::json!(output);
    json["seconds"] = serde_json::json!(seconds);
    let text = format!(
        "{}: N-tree n = {}, depth {}: {} inner nodes, {} leaves, {} bytes (shaft table {}; the dense layout would take {}) ({:.3} s)\n",
        output.display(),
        tree.n,
        tree.depth,
        tree.inner_nodes(),
        tree.leaves(),
        json["bytes"],
        json["shaft_table_bytes"],
        json["dense_bytes"],
        seconds
    );
    Ok(Outcome {
        json,
        text,
        warnings: crate::diag::tagged(&crate::diag::INGEST_READER, warnings),
    })
}

/// A pack: the registry's `linespace` unit (the graph's and `bake unit linespace`'s) over the
/// pack's sections: the flattened `linespace` section of its placed scene's triangles, or the
/// two-level `linespace-scene` where the placed scene exceeds the budget as one mesh.
fn run_pack(args: &LinespaceArgs, opts: NTreeOptions, limits: &Limits) -> Result<Outcome> {
    let pack = crate::pack::Pack::open(&args.input)?;
    let pipeline = crate::graph::Pipeline {
        linespace: opts,
        ..Default::default()
    };
    let at = CommandScope {
        input: &args.input,
        limits,
        plan: None,
    };
    let start = std::time::Instant::now();
    let o = scene_unit(
        "linespace",
        &at,
        &pack_sections(&pack, "linespace")?,
        &pipeline,
        &|_| {},
    )?;
    let seconds = start.elapsed().as_secs_f64();
    let output = args.output.clone().unwrap_or_else(|| args.input.clone());
    let two_level = o
        .sections
        .iter()
        .any(|s| s.kind == crate::linespace::instanced_section::KIND);
    let mut w = crate::pack::PackWriter::from_pack(&pack);
    for s in o.sections {
        w.insert(s);
    }
    w.write(&output)?;
    let mut json = o.report;
    json["output"] = serde_json::json!(output);
    json["seconds"] = serde_json::json!(seconds);
    let text = if two_level {
        format!(
            "{}: linespace-scene (two-level: the placed scene exceeds --max-memory as one mesh) \
             of {} models, {} instances ({} placed triangles), top tree depth {}, {} bytes \
             ({:.3} s)\n",
            output.display(),
            json["models"],
            json["instances"],
            json["placed_triangles"],
            json["top_depth"],
            json["bytes"],
            seconds
        )
    } else {
        format!(
            "{}: N-tree n = {}, depth {}: {} inner nodes, {} leaves, {} bytes (shaft table {}; \
             the dense layout would take {}) ({:.3} s)\n",
            output.display(),
            json["n"],
            json["depth"],
            json["inner_nodes"],
            json["leaves"],
            json["bytes"],
            json["shaft_table_bytes"],
            json["dense_bytes"],
            seconds
        )
    };
    Ok(Outcome {
        json,
        text,
        warnings: o.warnings,
    })
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LinespaceBenchArgs {
    /// Model or pack (default: a procedural 70,000-triangle blob on a ground quad). A pack
    /// with a `linespace-scene` section (the two-level line spaces): soft shadows over its
    /// instances against exact visibility, every refinement (`--receivers`,
    /// `--accuracy-samples`; crate::bench::linespace::bench_scene_accuracy).
    pub model: Option<PathBuf>,
    #[arg(long, default_value_t = 10)]
    pub n: u32,
    #[arg(long, default_value_t = 3)]
    pub depth: u32,
    /// Flat cells (see `bake linespace --flat-cells`).
    #[arg(long)]
    pub flat_cells: bool,
    /// Receivers (points on the geometry); each sends samples² shadow rays.
    #[arg(long, default_value_t = 20000)]
    pub receivers: u32,
    /// Light samples per axis.
    #[arg(long, default_value_t = 2)]
    pub samples: u32,
    /// Runs of each timed query set; the fastest run is reported (the machine is shared).
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// What a full shaft at the deepest level means (shaft: the thesis' hit; cells: a leaf with
    /// geometry on the segment; exact: the triangles of those leaves; near: exact within one
    /// deepest-node side of the receiver, the thesis' hit beyond).
    #[arg(long, value_enum, default_value_t = Refine::default())]
    pub refine: Refine,
    /// Also time the thesis' dense line-space pool (built beside the compact tree; large).
    #[arg(long)]
    pub dense: bool,
    /// Instead of speed: per receiver, line-space visibility against exact visibility from
    /// obvhs rays to the same stratified light points, for every refinement.
    #[arg(long)]
    pub accuracy: bool,
    /// Light points per side for --accuracy (per_side² stratified points).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub accuracy_samples: u32,
    /// Quad light (cx,cy,cz,ux,uy,uz,vx,vy,vz; default: a quad above the scene's box).
    #[arg(long, value_parser = crate::render::soft_shadow::parse_area_light, allow_hyphen_values = true)]
    pub area_light: Option<AreaLight>,
}

/// `bake bench linespace` (crate::bench::linespace): the model, if one is named, is loaded here.
pub(crate) fn bench(a: &LinespaceBenchArgs, g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let limits = g.ingest_defaults().limits;
    // A pack with the two-level line spaces: their accuracy over the instances.
    if let Some(p) = a.model.as_ref().filter(|p| super::svo::is_pack(p)) {
        let pack = crate::pack::Pack::open(p)?;
        if let Some(e) = pack
            .of_kind(crate::linespace::instanced_section::KIND)
            .next()
        {
            let (_, scene) = crate::linespace::instanced_section::from_section(&pack.view(e)?)
                .map_err(|e| Error::invalid(p, e))?;
            let r = crate::bench::linespace::bench_scene_accuracy(
                &scene,
                &p.display().to_string(),
                a.receivers,
                a.accuracy_samples,
                a.refine,
                a.area_light,
            )?;
            return Ok(Outcome {
                json: r.json,
                text: r.text,
                warnings: Vec::new(),
            });
        }
    }
    let scene = match &a.model {
        Some(p) => Some((
            world_triangles(
                &load_geometry(p, SceneStage::Linespace, &limits, &mut warnings)?
                    .0
                    .mesh,
            ),
            p.display().to_string(),
        )),
        None => None,
    };
    let b = crate::bench::linespace::LinespaceBench {
        scene,
        n: a.n,
        depth: a.depth,
        flat_cells: a.flat_cells,
        receivers: a.receivers,
        samples: a.samples,
        repeat: a.repeat,
        refine: a.refine,
        dense: a.dense,
        accuracy: a.accuracy,
        accuracy_samples: a.accuracy_samples,
        area_light: a.area_light,
    };
    let (r, more) = crate::bench::linespace::bench_linespace(&b)?;
    let mut warnings = crate::diag::tagged(&crate::diag::INGEST_READER, warnings);
    warnings.extend(crate::diag::tagged(
        &crate::diag::BENCH_LINESPACE_DISAGREES,
        more,
    ));
    Ok(Outcome {
        json: r.json,
        text: r.text,
        warnings,
    })
}
