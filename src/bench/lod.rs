//! `bake bench lod PACK`: the `lod` stage over every mesh of a pack (through the registry, in
//! parallel, as `bake lod` runs it), wall and CPU time of the whole, the per-model simplification and impostor times
//! summed over the models, and the triangles of every level.

use super::{Report, time_once};
use crate::error::Result;
use crate::lod::LodOptions;
use crate::pack::Pack;
use serde_json::json;

pub fn bench_lod(pack: &Pack, opts: &LodOptions) -> Result<Report> {
    let pipeline = crate::graph::Pipeline {
        lod: opts.clone(),
        ..crate::graph::Pipeline::default()
    };
    let (t, out) = time_once(|| {
        crate::graph::stage::pack_mesh_units("lod", pack, pack.path(), &pipeline, &|_| {})
    });
    let reports = out?
        .into_iter()
        .map(|o| serde_json::from_value::<crate::lod::LodReport>(o.report))
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|e| crate::error::Error::runtime(format!("lod report: {e}")))?;
    let simplify: f64 = reports.iter().map(|r| r.simplify_seconds).sum();
    let impostor: f64 = reports.iter().map(|r| r.impostor_seconds).sum();
    let full: u64 = reports.iter().map(|r| r.levels[0].triangles as u64).sum();
    let coarsest: u64 = reports
        .iter()
        .map(|r| r.levels.last().map_or(0, |l| l.triangles as u64))
        .sum();
    let mut text = format!(
        "{} meshes: {:.2} s wall, {} CPU; simplification {simplify:.2} s and impostors {impostor:.2} s summed over the models\n\
         triangles: {full} at level 0, {coarsest} at the coarsest levels ({:.1}x fewer)\n",
        reports.len(),
        t.wall,
        t.cpu.map_or("n/a".into(), |c| format!("{c:.2} s")),
        full as f64 / coarsest.max(1) as f64,
    );
    for r in &reports {
        let tris: Vec<String> = r.levels.iter().map(|l| l.triangles.to_string()).collect();
        text.push_str(&format!(
            "  {}: {} ({} cards), {:.3} s + {:.3} s\n",
            r.mesh,
            tris.join(" / "),
            r.cards,
            r.simplify_seconds,
            r.impostor_seconds
        ));
    }
    Ok(Report {
        json: json!({"meshes": reports.len(), "wall_seconds": t.wall, "cpu_seconds": t.cpu,
            "simplify_seconds": simplify, "impostor_seconds": impostor,
            "triangles_full": full, "triangles_coarsest": coarsest, "options": opts,
            "models": reports}),
        text,
    })
}
