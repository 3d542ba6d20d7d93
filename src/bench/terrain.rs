//! `bake bench terrain`: preparation time of a generated height grid (goal: 4096² in under 2 s
//! on the 2-core build machine).

use super::Report;
use crate::error::Result;
use crate::model::Terrain;
use std::time::Instant;

/// A generated terrain: rolling hills plus per-sample noise, 1 m spacing.
pub fn generated_terrain(size: u32) -> Terrain {
    let mut rng = crate::rng::Rng::new(4096);
    let heights = (0..size as u64 * size as u64)
        .map(|k| {
            let (x, y) = ((k % size as u64) as f32, (k / size as u64) as f32);
            30.0 * (x * 0.004).sin() * (y * 0.003).cos()
                + 5.0 * (x * 0.031 + y * 0.017).sin()
                + rng.f32()
        })
        .collect();
    Terrain {
        width: size,
        height: size,
        heights,
        origin: [0.0, 0.0],
        extent: [(size - 1) as f32, (size - 1) as f32],
        color: None,
    }
}

/// Prepares a generated `size`² terrain `repeat` times and encodes its section.
pub fn bench_terrain(size: u32, repeat: u32) -> Result<Report> {
    let size = size.max(2);
    let t = generated_terrain(size);
    let meta = crate::terrain::source_section::TerrainMeta {
        width: size,
        height: size,
        origin: t.origin,
        extent: t.extent,
        color_section: None,
        source: "bench".into(),
    };
    let reps = repeat.max(1);
    let (mut t_prep, mut t_enc, mut levels) = (0.0, 0.0, 0);
    for _ in 0..reps {
        let t0 = Instant::now();
        let p = crate::terrain::prepare_terrain(&t).map_err(crate::error::Error::runtime)?;
        let t1 = Instant::now();
        let s = crate::terrain::section::to_section("terrain", &meta, &t, &p)
            .map_err(crate::error::Error::runtime)?;
        let t2 = Instant::now();
        levels = p.quadtree.levels();
        std::hint::black_box(s);
        t_prep += (t1 - t0).as_secs_f64();
        t_enc += (t2 - t1).as_secs_f64();
    }
    let (tp, te) = (t_prep / reps as f64, t_enc / reps as f64);
    let doc = serde_json::json!({"size": size, "samples": size as u64 * size as u64, "prepare_seconds": tp,
        "encode_seconds": te, "quadtree_levels": levels, "threads": rayon::current_num_threads()});
    let text = format!(
        "{size}×{size} terrain: prepare {:.3} s (four-tap, normals, quadtree of {levels} levels), section encoding {:.3} s\n",
        tp, te
    );
    Ok(Report { json: doc, text })
}
