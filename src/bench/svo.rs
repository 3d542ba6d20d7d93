//! `bake bench svo`: voxelization and the octree build of one model, best of `repeat`, with
//! the octree's bytes per voxel beside the ESVO and 64-bit brick-mask layouts.

use super::Report;
use crate::error::{Error, Result};
use crate::voxel::geometry::Geometry;
use crate::voxel::svo::voxels_to_svo;
use crate::voxel::voxelize::{VoxelizeOptions, mesh_to_voxels};

/// Voxelizes `geo` (named `name` in the report) at `resolution` voxels along its longest axis.
pub fn bench_svo(geo: &Geometry, name: &str, resolution: u32, repeat: u32) -> Result<Report> {
    let opts = VoxelizeOptions::surface(resolution);
    let (mut best_vox, mut best_total) = (f64::INFINITY, f64::INFINITY);
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t0 = std::time::Instant::now();
        let voxels = mesh_to_voxels(&geo.mesh, &geo.textures, &opts)?;
        let t1 = t0.elapsed().as_secs_f64();
        let svo = voxels_to_svo(&voxels);
        let t2 = t0.elapsed().as_secs_f64();
        best_vox = best_vox.min(t1);
        best_total = best_total.min(t2);
        last = Some(svo);
    }
    let svo = last.ok_or_else(|| Error::Runtime("no run".into()))?;
    let st = svo.stats();
    let per = |b: u64| b as f64 / st.voxels.max(1) as f64;
    let json = serde_json::json!({
        "model": name,
        "triangles": geo.mesh.indices.len(),
        "resolution": resolution,
        "grid": svo.grid.dims,
        "threads": rayon::current_num_threads(),
        "seconds": best_total,
        "voxelize_seconds": best_vox,
        "voxels": st.voxels,
        "nodes": st.nodes,
        "topology_bytes_per_voxel": per(st.topology_bytes),
        "esvo_topology_bytes_per_voxel": per(st.esvo_topology_bytes),
        "mask64_topology_bytes_per_voxel": per(st.mask64_topology_bytes),
        "bytes_per_voxel": per(st.topology_bytes + st.attribute_bytes),
    });
    let text = format!(
        "{name}: {} triangles at {}³ → {} voxels in {:.3} s (voxelize {:.3} s); topology {:.3} B/voxel (ESVO descriptors {:.3}, u64 brick masks {:.3}), total {:.2} B/voxel\n",
        geo.mesh.indices.len(),
        resolution,
        st.voxels,
        best_total,
        best_vox,
        per(st.topology_bytes),
        per(st.esvo_topology_bytes),
        per(st.mask64_topology_bytes),
        per(st.topology_bytes + st.attribute_bytes)
    );
    Ok(Report { json, text })
}
