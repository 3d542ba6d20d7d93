//! `bake bench ambient`: the load-time cost of the ambient term on a generated scene of many
//! instances: per-instance C_H/C_S from the `clusters` section (multiquadric reconstruction,
//! solved here or from stored weights, then turned into each instance's frame) and the PRT
//! evaluation of eq. 4.8 per vertex as the CPU reference does it.

use super::Report;
use crate::envmap::section::{self as es, DIM};
use crate::error::Result;
use crate::ingest::instances_section::InstanceRecord;
use crate::pack::{Pack, PackWriter};
use crate::render::ambient::{InstanceEnv, PrtData, PrtLayout, instance_maps, side_radiance};
use serde_json::json;

fn scene(n: usize) -> (Vec<InstanceRecord>, Vec<f32>) {
    let mut rng = crate::rng::Rng::new(2005);
    let recs: Vec<InstanceRecord> = (0..n)
        .map(|_| {
            let (x, y) = (rng.f32() * 1024.0, rng.f32() * 1024.0);
            InstanceRecord {
                position: [x, y, crate::envmap::synthetic::bench_terrain_height(x, y)],
                scale: 1.0,
                rotation_deg: rng.f32() * 360.0,
                model: 0,
                layer: 0,
                reserved: 0,
            }
        })
        .collect();
    let pos: Vec<[f32; 3]> = recs.iter().map(|r| r.position).collect();
    let h = crate::envmap::synthetic::bench_terrain_height;
    // World-frame maps (the `clusters` section's frame), 1 % noise.
    let maps = crate::envmap::synthetic::synthetic_envmaps(&pos, &h, 0.01, 2005);
    (recs, maps.noisy)
}

fn pack_of(recs: &[InstanceRecord], values: &[f32], error: f32, weights: bool) -> Result<Pack> {
    let pos: Vec<[f32; 3]> = recs.iter().map(|r| r.position).collect();
    let opts = crate::envmap::cluster::ClusterOptions {
        error,
        ..Default::default()
    };
    let (meta, c, w) = crate::envmap::cluster_and_weigh(&pos, values, DIM, &opts, weights);
    let wref = w.as_ref().map(|(n, w)| (n.as_slice(), w.as_slice()));
    let mut pw = PackWriter::new();
    pw.insert(es::clusters_to_section(
        "clusters", &meta, &c, &pos, values, wref,
    ));
    Pack::from_bytes(&pw.to_bytes()?, "bench.bake")
}

/// Times the cluster reconstruction (solved and stored weights) and eq. 4.8 per vertex.
pub fn bench_ambient(instances: usize, error: f32) -> Result<Report> {
    let (recs, values) = scene(instances.max(2));
    let light = crate::render::ambient::SkyLight {
        sky: crate::sh::ShRadiance {
            coeffs: [[1.0; 3]; 16],
        },
        irradiance: crate::sh::ShIrradiance {
            coeffs: [[1.0; 3]; 16],
        },
        sun: None,
    };
    let mut doc = json!({"instances": recs.len()});
    for weights in [false, true] {
        let t = std::time::Instant::now();
        let pack = pack_of(&recs, &values, error, weights)?;
        let bake = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let (maps, _) = instance_maps(&pack, &recs, &light)?;
        let secs = t.elapsed().as_secs_f64();
        let key = if weights { "stored_weights" } else { "solved" };
        doc[key] = json!({"seconds": secs, "bake_seconds": bake, "maps": maps.len()});
    }
    // Eq. 4.8 for a 10,000-vertex transfer under 100 instances' maps (the reference's work).
    let mut rng = crate::rng::Rng::new(7);
    let v = 10_000usize;
    let prt = PrtData {
        vertices: v,
        transfer: (0..v * crate::prt::transfer::PER_VERTEX)
            .map(|_| [rng.f32(), rng.f32(), rng.f32()])
            .collect(),
        packed: vec![[0.5; 4]; v * 10],
        materials: Vec::new(),
    };
    let env = InstanceEnv {
        sky: [[0.5; 3]; 16],
        sun: [[0.25; 3]; 16],
    };
    for layout in [PrtLayout::Full, PrtLayout::Packed] {
        let t = std::time::Instant::now();
        let mut acc = 0.0f32;
        for _ in 0..100 {
            for k in 0..v {
                acc += side_radiance(&prt, layout, k, &env)[0][0];
            }
        }
        let secs = t.elapsed().as_secs_f64();
        doc[format!("eq48_{layout:?}").to_lowercase()] = json!({
            "vertex_sides_per_second": (2 * 100 * v) as f64 / secs, "checksum": acc,
        });
    }
    Ok(Report {
        text: format!("{doc:#}\n"),
        json: doc,
    })
}
