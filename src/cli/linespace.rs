//! `bake linespace INPUT`: the N-tree with line spaces of a model or pack, for soft shadows.

use super::svo::load_geometry;
use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::linespace::ntree::{NTree, NTreeOptions, build_ntree};
use crate::linespace::query::{AreaLight, ExactShadow, QueryStats, Segment};
use crate::linespace::section;
use crate::linespace::shaft::{ChildMasks, ShaftCells};
use crate::model::Mesh;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct LinespaceArgs {
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
}

/// World-space triangles of a mesh.
pub fn world_triangles(m: &Mesh) -> Vec<[[f32; 3]; 3]> {
    m.indices
        .iter()
        .map(|t| t.map(|i| m.positions[i as usize]))
        .collect()
}

pub fn run(args: &LinespaceArgs, _g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let (geo, pack) = load_geometry(&args.input, &mut warnings)?;
    let tris = world_triangles(&geo.mesh);
    if tris.is_empty() {
        return Err(Error::invalid_at(
            &args.input,
            "geometry",
            "no triangles for the N-tree",
        ));
    }
    let opts = NTreeOptions {
        n: args.n,
        depth: args.depth,
    };
    let start = std::time::Instant::now();
    let masks = ChildMasks::build(opts.n);
    let tree = build_ntree(&tris, &opts, &masks)?;
    let seconds = start.elapsed().as_secs_f64();
    let output = args.output.clone().unwrap_or_else(|| match &pack {
        Some(_) => args.input.clone(),
        None => args.input.with_extension("bake"),
    });
    let mut w = super::svo::start_pack(&args.input, pack.as_ref(), &geo, &mut warnings);
    w.insert(section::to_section(
        "linespace",
        &args.input.display().to_string(),
        &tree,
    ));
    w.write(&output)?;
    let mut json = section::summary_of(&tree);
    json["output"] = serde_json::json!(output);
    json["seconds"] = serde_json::json!(seconds);
    let text = format!(
        "{}: N-tree n = {}, depth {}: {} inner nodes, {} bits per line space, {} bytes ({:.3} s)\n",
        output.display(),
        tree.n,
        tree.depth,
        tree.inner_nodes(),
        tree.layout().bits(),
        json["bytes"],
        seconds
    );
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}

#[derive(Debug, Clone, clap::Args)]
pub struct LinespaceBenchArgs {
    /// Model or pack (default: a procedural 70,000-triangle blob on a ground quad).
    pub model: Option<PathBuf>,
    #[arg(long, default_value_t = 10)]
    pub n: u32,
    #[arg(long, default_value_t = 3)]
    pub depth: u32,
    /// Receivers (points on the geometry); each sends samples² shadow rays.
    #[arg(long, default_value_t = 20000)]
    pub receivers: u32,
    /// Light samples per axis.
    #[arg(long, default_value_t = 2)]
    pub samples: u32,
    /// Runs of each timed query set; the fastest run is reported (the machine is shared).
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
}

/// The default benchmark scene: the blob standing on a ground quad.
fn bench_scene() -> Vec<[[f32; 3]; 3]> {
    let mut tris = world_triangles(&crate::voxel::geometry::procedural_blob(250, 140));
    let g = [
        [-3.0, -3.0, -1.3],
        [3.0, -3.0, -1.3],
        [3.0, 3.0, -1.3],
        [-3.0, 3.0, -1.3],
    ];
    tris.push([g[0], g[1], g[2]]);
    tris.push([g[0], g[2], g[3]]);
    tris
}

/// Receivers: deterministic points on the triangles (area-uniform by rejection-free picking
/// of triangle then barycentrics), lifted off the surface along the normal.
fn receivers(tris: &[[[f32; 3]; 3]], count: u32) -> Vec<[f32; 3]> {
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..count)
        .map(|_| {
            let t = &tris[((next() * tris.len() as f32) as usize).min(tris.len() - 1)];
            let (mut a, mut b) = (next(), next());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            [0, 1, 2].map(|k| t[0][k] + a * (t[1][k] - t[0][k]) + b * (t[2][k] - t[0][k]))
        })
        .collect()
}

/// Runs `f` once and returns its result with the wall time in seconds.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = std::time::Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64())
}

/// Runs `f` `runs` times (at least once); the last result and the fastest wall time.
fn best_of<T>(runs: u32, mut f: impl FnMut() -> T) -> (T, f64) {
    let (mut out, mut best) = timed(&mut f);
    for _ in 1..runs {
        let (o, t) = timed(&mut f);
        (out, best) = (o, best.min(t));
    }
    (out, best)
}

/// Segments lit by `a` but blocked by `b` (`a` claims lit where `b` finds a blocker).
fn lit_but_blocked(a: &[bool], b: &[bool]) -> usize {
    a.iter().zip(b).filter(|(x, y)| !**x && **y).count()
}

/// The benchmark's scene, tree, light and receivers.
struct BenchSetup {
    name: String,
    tris: Vec<[[f32; 3]; 3]>,
    tree: NTree,
    masks: ChildMasks,
    build_seconds: f64,
    light: AreaLight,
    offset: f32,
    receivers: Vec<[f32; 3]>,
}

fn bench_setup(a: &LinespaceBenchArgs, warnings: &mut Vec<String>) -> Result<BenchSetup> {
    let (tris, name) = match &a.model {
        Some(p) => (
            world_triangles(&load_geometry(p, warnings)?.0.mesh),
            p.display().to_string(),
        ),
        None => (
            bench_scene(),
            "procedural blob (70,000 triangles) on a ground quad".to_string(),
        ),
    };
    let opts = NTreeOptions {
        n: a.n,
        depth: a.depth,
    };
    let ((masks, tree), build_seconds) = timed(|| {
        let masks = ChildMasks::build(opts.n);
        let tree = build_ntree(&tris, &opts, &masks);
        (masks, tree)
    });
    let tree = tree?;
    let (_, size) = crate::linespace::gpu::root_box(&tree);
    let light = crate::linespace::gpu::light_above(&tree, a.samples.max(1));
    let offset = 1e-4 * size.iter().cloned().fold(0.0, f32::max);
    let receivers = receivers(&tris, a.receivers);
    Ok(BenchSetup {
        name,
        tris,
        tree,
        masks,
        build_seconds,
        light,
        offset,
        receivers,
    })
}

/// `bake bench linespace`: the same shadow segments through exact obvhs any-hit rays, the
/// per-segment line-space query (reading the line-space pool, then the shared shaft table);
/// single-threaded timings.
pub fn bench(a: &LinespaceBenchArgs, _g: &Global) -> Result<Outcome> {
    let mut warnings = Vec::new();
    let BenchSetup {
        name,
        tris,
        mut tree,
        masks,
        build_seconds,
        light,
        offset,
        receivers,
    } = bench_setup(a, &mut warnings)?;
    let exact = ExactShadow::new(&tris);
    let segs: Vec<Segment> = receivers
        .iter()
        .flat_map(|&p| {
            (0..light.samples.pow(2)).map(move |i| Segment::between(p, light.sample(i), offset))
        })
        .collect();
    let runs = a.repeat;
    let (exact_hits, exact_seconds) = best_of(runs, || {
        segs.iter()
            .map(|s| exact.occluded(s))
            .collect::<Vec<bool>>()
    });
    let mut stats = QueryStats::default();
    let (pool_hits, pool_seconds) = best_of(runs, || {
        stats = QueryStats::default();
        segs.iter()
            .map(|s| tree.segment_occluded(s, &mut stats))
            .collect::<Vec<bool>>()
    });
    let (table, table_build_seconds) = timed(|| ShaftCells::from_masks(&masks));
    drop(masks);
    tree.use_shaft_table(std::sync::Arc::new(table))?;
    let mut table_stats = QueryStats::default();
    let (table_hits, table_seconds) = best_of(runs, || {
        table_stats = QueryStats::default();
        segs.iter()
            .map(|s| tree.segment_occluded(s, &mut table_stats))
            .collect::<Vec<bool>>()
    });
    if table_hits != pool_hits {
        warnings.push(
            "per-segment answers differ between the line-space pool and the shaft table".into(),
        );
    }
    let mut floor_stats = QueryStats::default();
    let (_, floor_seconds) = best_of(runs, || {
        floor_stats = QueryStats::default();
        segs.iter()
            .filter(|s| tree.start_node_occluded(s, &mut floor_stats))
            .count()
    });
    let mut exact_stats = QueryStats::default();
    let (tree_exact, ntree_exact_seconds) = best_of(runs, || {
        exact_stats = QueryStats::default();
        segs.iter()
            .map(|s| tree.segment_occluded_exact(s, &mut exact_stats))
            .collect::<Vec<bool>>()
    });
    if tree_exact != exact_hits {
        let d = tree_exact
            .iter()
            .zip(&exact_hits)
            .filter(|(a, b)| a != b)
            .count();
        warnings.push(format!(
            "{d} rays: exact N-tree traversal and obvhs disagree"
        ));
    }
    let per = |x: f64| exact_seconds / x.max(1e-12);
    let (lit_blocked, over) = (
        lit_but_blocked(&table_hits, &exact_hits),
        lit_but_blocked(&exact_hits, &table_hits),
    );
    let json = serde_json::json!({
        "model": name, "triangles": tris.len(), "n": tree.n, "depth": tree.depth,
        "inner_nodes": tree.inner_nodes(), "build_seconds": build_seconds,
        "receivers": receivers.len(), "samples_per_receiver": light.samples.pow(2),
        "rays": segs.len(), "exact_seconds": exact_seconds,
        "linespace_seconds": table_seconds, "speedup": per(table_seconds),
        "method": "per segment, line-space bits from the shared shaft table",
        "lit_but_shadowed": lit_blocked, "shadowed_but_lit": over,
        "pool_seconds": pool_seconds, "pool_speedup": per(pool_seconds),
        "shaft_table_seconds": table_build_seconds,
        "shaft_table_bytes": 8 * tree.shafts.as_ref().map_or(0, |t| t.cells.len()),
        "linespace_pool_bytes": 4 * tree.linespaces.len(),
        "ntree_exact_seconds": ntree_exact_seconds,
        "start_node_seconds": floor_seconds,
        "start_node_triangle_tests": floor_stats.exact_triangle_tests,
        "speedup_vs_ntree_triangle_tests": ntree_exact_seconds / table_seconds.max(1e-12),
        "exact_occluded": exact_hits.iter().filter(|h| **h).count(),
        "linespace_lookups": stats.linespace_lookups, "exact_triangle_tests": stats.exact_triangle_tests,
        "dda_steps": stats.dda_steps, "nodes_visited": stats.nodes_visited,
    });
    let text = format!(
        "{name}: {} triangles, n = {} depth {} ({} inner nodes, built in {:.2} s)\n{} rays ({} receivers × {}): exact obvhs {:.3} s; line space {:.3} s ({:.2}×; reading the line-space pool: {:.3} s, {:.2}×); N-tree with exact triangle tests {:.3} s; the exact tests in the start node alone {:.3} s; lit but shadowed {}, over-occluded {}\n",
        tris.len(),
        tree.n,
        tree.depth,
        tree.inner_nodes(),
        build_seconds,
        segs.len(),
        receivers.len(),
        light.samples.pow(2),
        exact_seconds,
        table_seconds,
        per(table_seconds),
        pool_seconds,
        per(pool_seconds),
        ntree_exact_seconds,
        floor_seconds,
        lit_blocked,
        over,
    );
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}
