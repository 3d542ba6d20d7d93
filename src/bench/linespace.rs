//! `bake bench linespace`: shadow segments through exact obvhs any-hit rays and through the
//! line-space N-tree in every refinement (and the thesis' dense pool), single-threaded; with
//! `accuracy`, line-space visibility against exact visibility per receiver.

use super::Report;
use crate::error::{Error, Result};
use crate::linespace::accuracy::{
    Visibilities, compare, exact_visibility, linespace_visibility, stratified_points,
};
use crate::linespace::dense::build_dense;
use crate::linespace::ntree::{NTree, NTreeOptions, Refine, build_ntree};
use crate::linespace::query::{AreaLight, ExactShadow, QueryStats, Segment};
use crate::linespace::section;
use crate::linespace::shaft::{ChildMasks, ShaftTable};
use crate::linespace::world_triangles;
use std::sync::Arc;

/// What `bake bench linespace` measures (the command-line arguments, the model loaded).
#[derive(Debug, Clone)]
pub struct LinespaceBench {
    /// World triangles and their name; None: a procedural blob on a ground quad.
    pub scene: Option<(Vec<[[f32; 3]; 3]>, String)>,
    pub n: u32,
    pub depth: u32,
    pub flat_cells: bool,
    pub receivers: u32,
    pub samples: u32,
    pub repeat: u32,
    pub refine: Refine,
    pub dense: bool,
    pub accuracy: bool,
    pub accuracy_samples: u32,
    pub area_light: Option<AreaLight>,
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
    build_seconds: f64,
    light: AreaLight,
    offset: f32,
    receivers: Vec<[f32; 3]>,
}

fn bench_setup(a: &LinespaceBench) -> Result<BenchSetup> {
    let (tris, name) = match &a.scene {
        Some((tris, name)) => (tris.clone(), name.clone()),
        None => (
            bench_scene(),
            "procedural blob (70,000 triangles) on a ground quad".to_string(),
        ),
    };
    if tris.is_empty() {
        return Err(Error::runtime(
            "bench linespace: the model has no triangles",
        ));
    }
    let opts = NTreeOptions {
        n: a.n,
        depth: a.depth,
        cubic_cells: !a.flat_cells,
    };
    let (tree, build_seconds) =
        timed(|| build_ntree(&tris, &opts, &Arc::new(ShaftTable::build(opts.n))));
    let mut tree = tree?;
    tree.refine = a.refine;
    let (_, size) = crate::linespace::gpu::root_box(&tree);
    let light = match a.area_light {
        Some(l) => AreaLight {
            samples: a.samples.max(1),
            ..l
        },
        None => crate::linespace::gpu::light_above(&tree, a.samples.max(1)),
    };
    let offset = 1e-4 * size.iter().cloned().fold(0.0, f32::max);
    let receivers = receivers(&tris, a.receivers);
    Ok(BenchSetup {
        name,
        tris,
        tree,
        build_seconds,
        light,
        offset,
        receivers,
    })
}

/// Timed answers of every segment through `tree` (single thread, fastest of `runs`).
fn time_queries(tree: &NTree, segs: &[Segment], runs: u32) -> (Vec<bool>, f64, QueryStats) {
    let mut stats = QueryStats::default();
    let (hits, seconds) = best_of(runs, || {
        stats = QueryStats::default();
        segs.iter()
            .map(|s| tree.segment_occluded(s, &mut stats))
            .collect::<Vec<bool>>()
    });
    (hits, seconds, stats)
}

/// `bake bench linespace`: the same shadow segments through exact obvhs any-hit rays and the
/// per-segment line-space query in every refinement (compact storage; with `--dense` also
/// reading the thesis' dense line-space pool); single-threaded timings. With `--accuracy`, the
/// visibility comparison of [`bench_accuracy`] instead.
/// Returns the report and its warnings (answers that differ between the storages).
pub fn bench_linespace(a: &LinespaceBench) -> Result<(Report, Vec<String>)> {
    let setup = bench_setup(a)?;
    let mut warnings = Vec::new();
    if a.accuracy {
        return bench_accuracy(a, setup);
    }
    let BenchSetup {
        name,
        tris,
        mut tree,
        build_seconds,
        light,
        offset,
        receivers,
    } = setup;
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
    let per = |x: f64| exact_seconds / x.max(1e-12);
    let mut modes = Vec::new();
    let mut chosen = None;
    for refine in [Refine::Shaft, Refine::Cells, Refine::Near, Refine::Exact] {
        tree.refine = refine;
        let (hits, seconds, stats) = time_queries(&tree, &segs, runs);
        let lit_blocked = lit_but_blocked(&hits, &exact_hits);
        if lit_blocked > 0 {
            warnings.push(format!(
                "{refine:?}: {lit_blocked} rays lit that obvhs finds blocked"
            ));
        }
        modes.push(serde_json::json!({
            "refine": refine, "seconds": seconds, "speedup": per(seconds),
            "lit_but_shadowed": lit_blocked,
            "over_occluded": lit_but_blocked(&exact_hits, &hits),
            "linespace_lookups": stats.linespace_lookups,
            "exact_triangle_tests": stats.exact_triangle_tests,
            "dda_steps": stats.dda_steps, "nodes_visited": stats.nodes_visited,
        }));
        if refine == a.refine {
            chosen = Some((hits, seconds, stats));
        }
    }
    tree.refine = a.refine;
    let (hits, seconds, stats) = chosen.unwrap_or_default();
    let mut dense_json = serde_json::Value::Null;
    if a.dense {
        let opts = NTreeOptions {
            n: tree.n,
            depth: tree.depth,
            cubic_cells: !a.flat_cells,
        };
        let (d, dense_build) = timed(|| build_dense(&tris, &opts, &ChildMasks::build(tree.n)));
        let d = d?;
        let mut reference = tree.clone();
        reference.dense_linespaces = Some(Arc::new(d.linespaces));
        let (dense_hits, dense_seconds, _) = time_queries(&reference, &segs, runs);
        if dense_hits != hits {
            warnings.push("answers differ between the dense pool and the shaft table".into());
        }
        let (node_bytes, _) = (8 * d.nodes.len(), 0);
        dense_json = serde_json::json!({
            "seconds": dense_seconds, "speedup": per(dense_seconds), "build_seconds": dense_build,
            "node_bytes": node_bytes, "linespace_bytes": 4 * reference.dense_linespaces.as_ref().map_or(0, |p| p.len()),
        });
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
    let (lit_blocked, over) = (
        lit_but_blocked(&hits, &exact_hits),
        lit_but_blocked(&exact_hits, &hits),
    );
    let json = serde_json::json!({
        "model": name, "triangles": tris.len(), "n": tree.n, "depth": tree.depth,
        "inner_nodes": tree.inner_nodes(), "leaves": tree.leaves(), "build_seconds": build_seconds,
        "bytes": tree.bytes(), "shaft_table_bytes": tree.shafts.bytes(),
        "dense_bytes": section::dense_bytes(&tree),
        "receivers": receivers.len(), "samples_per_receiver": light.samples.pow(2),
        "rays": segs.len(), "exact_seconds": exact_seconds,
        "refine": a.refine, "linespace_seconds": seconds, "speedup": per(seconds),
        "method": "per segment, compact tree, line-space bits from the shared shaft table",
        "lit_but_shadowed": lit_blocked, "shadowed_but_lit": over,
        "modes": modes, "dense": dense_json,
        "ntree_exact_seconds": ntree_exact_seconds,
        "start_node_seconds": floor_seconds,
        "start_node_triangle_tests": floor_stats.exact_triangle_tests,
        "speedup_vs_ntree_triangle_tests": ntree_exact_seconds / seconds.max(1e-12),
        "exact_occluded": exact_hits.iter().filter(|h| **h).count(),
        "linespace_lookups": stats.linespace_lookups, "exact_triangle_tests": stats.exact_triangle_tests,
        "dda_steps": stats.dda_steps, "nodes_visited": stats.nodes_visited,
    });
    let mut text = format!(
        "{name}: {} triangles, n = {} depth {} ({} inner nodes, {} bytes, built in {:.2} s)\n{} rays ({} receivers × {}): exact obvhs {:.3} s; N-tree with exact triangle tests {:.3} s; the exact tests in the start node alone {:.3} s\n",
        tris.len(),
        tree.n,
        tree.depth,
        tree.inner_nodes(),
        tree.bytes(),
        build_seconds,
        segs.len(),
        receivers.len(),
        light.samples.pow(2),
        exact_seconds,
        ntree_exact_seconds,
        floor_seconds,
    );
    for m in &json["modes"].as_array().cloned().unwrap_or_default() {
        text += &format!(
            "  line space, refine {}: {:.3} s ({:.2}× obvhs), lit but shadowed {}, over-occluded {}\n",
            m["refine"].as_str().unwrap_or("?"),
            m["seconds"].as_f64().unwrap_or(0.0),
            m["speedup"].as_f64().unwrap_or(0.0),
            m["lit_but_shadowed"],
            m["over_occluded"]
        );
    }
    Ok((Report { json, text }, warnings))
}

/// `bake bench linespace --accuracy`: per receiver, the line-space visibility (each
/// refinement) against exact obvhs visibility to the same `accuracy_samples²` stratified light
/// points ([`crate::linespace::accuracy`]); both sides on all threads.
fn bench_accuracy(a: &LinespaceBench, setup: BenchSetup) -> Result<(Report, Vec<String>)> {
    let warnings = Vec::new();
    let BenchSetup {
        name,
        tris,
        mut tree,
        build_seconds,
        light,
        offset,
        receivers,
    } = setup;
    let exact = ExactShadow::new(&tris);
    let points = stratified_points(&light, a.accuracy_samples, 0x5eed);
    let (exact_fractions, exact_seconds) = exact_visibility(&exact, &receivers, &points, offset);
    let mut modes = Vec::new();
    let mut headline = serde_json::Value::Null;
    for refine in [Refine::Shaft, Refine::Cells, Refine::Near, Refine::Exact] {
        tree.refine = refine;
        let (linespace, linespace_seconds, stats) =
            linespace_visibility(&tree, &receivers, &points, offset);
        let v = Visibilities {
            linespace,
            exact: exact_fractions.clone(),
            linespace_seconds,
            exact_seconds,
            stats,
        };
        let r = compare(&v, points.len());
        let mut m = serde_json::json!(r);
        m["refine"] = serde_json::json!(refine);
        m["linespace_seconds"] = serde_json::json!(v.linespace_seconds);
        m["exact_seconds"] = serde_json::json!(v.exact_seconds);
        m["time_ratio_vs_exact"] =
            serde_json::json!(v.linespace_seconds / v.exact_seconds.max(1e-12));
        m["segments"] = serde_json::json!(receivers.len() * points.len());
        if refine == a.refine {
            headline = m.clone();
        }
        modes.push(m);
    }
    let mut json = headline;
    json["model"] = serde_json::json!(name);
    json["triangles"] = serde_json::json!(tris.len());
    json["n"] = serde_json::json!(tree.n);
    json["depth"] = serde_json::json!(tree.depth);
    json["bytes"] = serde_json::json!(tree.bytes());
    json["build_seconds"] = serde_json::json!(build_seconds);
    json["threads"] = serde_json::json!(rayon::current_num_threads());
    json["light"] =
        serde_json::json!({"corner": light.corner, "edge_u": light.edge_u, "edge_v": light.edge_v});
    json["modes"] = serde_json::json!(modes);
    let mut text = format!(
        "{name}: n = {} depth {}, {} receivers × {} stratified light points, exact obvhs as reference\n",
        tree.n,
        tree.depth,
        receivers.len(),
        points.len()
    );
    for m in &modes {
        text += &format!(
            "  refine {}: mean |error| {:.4}, darker than exact by > 0.1: {:.2} %, brighter than exact: {}; {:.2} s ({:.2}× the exact rays' {:.2} s)\n",
            m["refine"].as_str().unwrap_or("?"),
            m["mean_abs_error"].as_f64().unwrap_or(0.0),
            100.0 * m["darker_share"].as_f64().unwrap_or(0.0),
            m["brighter_than_exact"],
            m["linespace_seconds"].as_f64().unwrap_or(0.0),
            m["time_ratio_vs_exact"].as_f64().unwrap_or(0.0),
            m["exact_seconds"].as_f64().unwrap_or(0.0),
        );
    }
    Ok((Report { json, text }, warnings))
}

/// `bake bench linespace PACK` on a pack with a `linespace-scene` section (issue 39): soft
/// shadows of the two-level line spaces against exact visibility over the instances
/// ([`crate::linespace::instanced::ExactInstances`]: the terrain's exact any-hit and every
/// instance whose placed bounds a segment meets, brute force over its placed triangles). The
/// light is a `light_side`-metre square `light_height` metres above each receiver (a distant
/// area light, the same points relative to every receiver; `light` instead: its corner and
/// edges relative to each receiver); receivers are on the terrain
/// within 4 m of `receivers` instances (picked with a fixed seed) and, every third, inside
/// their model's bounds. Both sides on all threads.
pub fn bench_scene_accuracy(
    scene: &crate::linespace::instanced::SceneLinespace,
    name: &str,
    receivers: u32,
    per_side: u32,
    main: Refine,
    light: Option<AreaLight>,
) -> Result<Report> {
    use crate::linespace::instanced::ExactInstances;
    use rayon::prelude::*;
    let Some(terrain) = scene.terrain.as_ref() else {
        return Err(Error::runtime(
            "bench linespace: the scene has no terrain to place receivers on",
        ));
    };
    if scene.instances.is_empty() {
        return Err(Error::runtime(
            "bench linespace: the scene has no instances",
        ));
    }
    let mut rng = crate::rng::Rng::new(0x11_5ce9e);
    let pts: Vec<[f32; 3]> = (0..receivers)
        .map(|k| {
            let i = &scene.instances
                [(rng.f32() * scene.instances.len() as f32) as usize % scene.instances.len()];
            let (a, d) = (rng.f32() * std::f32::consts::TAU, 4.0 * rng.f32());
            let (x, y) = (i.position[0] + d * a.cos(), i.position[1] + d * a.sin());
            let z = terrain.terrain.mesh_height_at(x, y);
            if k % 3 == 2 {
                // Inside the instance's model bounds, above the ground (in its crown).
                let t = &scene.models[i.model as usize].tree;
                let (lo, ext) = crate::linespace::gpu::root_box(t);
                let h = (0.5 + 0.4 * rng.f32()) * ext[2] + lo[2];
                [x, y, i.position[2] + h * i.scale.abs()]
            } else {
                [x, y, z]
            }
        })
        .collect();
    let (side, height) = (20.0f32, 60.0f32);
    let light = light.unwrap_or(AreaLight {
        corner: [-side / 2.0, -side / 2.0 + 25.0, height],
        edge_u: [side, 0.0, 0.0],
        edge_v: [0.0, side, 0.0],
        samples: 1,
    });
    let rel = stratified_points(&light, per_side, 0x5eed);
    let offset = 1e-3f32;
    let fractions = |occluded: &(dyn Fn(&Segment, &mut QueryStats) -> bool + Sync)| {
        let t0 = std::time::Instant::now();
        let per: Vec<(f32, QueryStats)> = pts
            .par_iter()
            .map(|&p| {
                let mut st = QueryStats::default();
                let lit = rel
                    .iter()
                    .filter(|q| {
                        let to = [p[0] + q[0], p[1] + q[1], p[2] + q[2]];
                        !occluded(&Segment::between(p, to, offset), &mut st)
                    })
                    .count();
                (lit as f32 / rel.len() as f32, st)
            })
            .collect();
        let stats: QueryStats = per.iter().map(|(_, s)| *s).sum();
        let f: Vec<f32> = per.into_iter().map(|(f, _)| f).collect();
        (f, t0.elapsed().as_secs_f64(), stats)
    };
    let brute = ExactInstances::new(scene);
    let (exact, exact_seconds, _) = fractions(&|s, _| brute.occluded(s));
    let mut modes = Vec::new();
    let mut headline = serde_json::Value::Null;
    let mut scene = scene.clone();
    for refine in [Refine::Shaft, Refine::Cells, Refine::Near, Refine::Exact] {
        scene.set_refine(refine);
        let (ls, seconds, stats) = fractions(&|s, st| scene.segment_occluded(s, st));
        let v = Visibilities {
            linespace: ls,
            exact: exact.clone(),
            linespace_seconds: seconds,
            exact_seconds,
            stats,
        };
        let mut m = serde_json::json!(compare(&v, rel.len()));
        m["refine"] = serde_json::json!(refine);
        m["linespace_seconds"] = serde_json::json!(seconds);
        m["exact_seconds"] = serde_json::json!(exact_seconds);
        m["segments"] = serde_json::json!(pts.len() * rel.len());
        m["stats"] = serde_json::json!({
            "linespace_lookups": stats.linespace_lookups,
            "exact_triangle_tests": stats.exact_triangle_tests,
            "nodes_visited": stats.nodes_visited,
        });
        if refine == main {
            headline = m.clone();
        }
        modes.push(m);
    }
    let mut json = headline;
    json["scene"] = serde_json::json!(name);
    json["instances"] = serde_json::json!(scene.instances.len());
    json["models"] = serde_json::json!(scene.models.len());
    json["threads"] = serde_json::json!(rayon::current_num_threads());
    json["light_relative"] =
        serde_json::json!({"corner": light.corner, "edge_u": light.edge_u, "edge_v": light.edge_v});
    json["near_distance"] = serde_json::json!(scene.near_distance());
    json["modes"] = serde_json::json!(modes);
    let mut text = format!(
        "{name}: two-level line spaces, {} instances of {} models; {} receivers × {} light \
         points (a quad at {:?} + s·{:?} + t·{:?} from each receiver), exact visibility over \
         the instances as reference ({exact_seconds:.2} s)\n",
        scene.instances.len(),
        scene.models.len(),
        pts.len(),
        rel.len(),
        light.corner,
        light.edge_u,
        light.edge_v,
    );
    for m in &modes {
        text += &format!(
            "  refine {}: mean |error| {:.4}, max {:.4}, brighter than exact: {}; {:.2} s\n",
            m["refine"].as_str().unwrap_or("?"),
            m["mean_abs_error"].as_f64().unwrap_or(0.0),
            m["max_abs_error"].as_f64().unwrap_or(0.0),
            m["brighter_than_exact"],
            m["linespace_seconds"].as_f64().unwrap_or(0.0),
        );
    }
    Ok(Report { json, text })
}
