//! Levels of detail (kind `lod`, `bake lod`): per model a chain of simplified meshes at
//! screen-space error targets, and an impostor atlas for the far field.
//!
//! - [`section`]: the `lod` section (metadata, arrays, the checked reader [`section::read`]).
//! - [`select`]: the selection rule [`select::choose`], shared by the renderer, `bake dump` and
//!   the tests.
//! - [`octa`]: the hemi-octahedral view mapping of the impostor atlas.
//! - [`simplify`]: the mesh levels (meshopt) and the leaf-card thinning.
//! - [`impostor`]: the impostor atlas (one ray per texel into the model's BVH).
pub mod impostor;
pub mod octa;
pub mod section;
pub mod select;
pub mod simplify;
pub mod stage;
#[cfg(test)]
mod tests;

pub use simplify::LodOptions;

use crate::error::{Error, Result};
use crate::model::Rgba8Image;
use crate::pack::{Pack, Section};
use serde::{Deserialize, Serialize};

/// One level in the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LevelReport {
    pub triangles: u32,
    pub vertices: u32,
    pub error: f32,
    pub cards: u32,
    pub coverage: f32,
}

/// What `bake lod` did for one mesh.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LodReport {
    pub mesh: String,
    pub section: String,
    pub radius: f32,
    pub cards: usize,
    pub levels: Vec<LevelReport>,
    pub impostor_error: Option<f32>,
    /// Segments and points of the skeleton (0 and 0 without one).
    pub skeleton: [u32; 2],
    pub simplify_seconds: f64,
    pub impostor_seconds: f64,
}

/// The decoded textures of a mesh section (`None` where a texture has no readable section).
fn mesh_textures(
    pack: &Pack,
    meta: &crate::mesh::section::MeshMeta,
) -> Result<Vec<Option<Rgba8Image>>> {
    meta.textures
        .iter()
        .map(|t| match &t.section {
            None => Ok(None),
            Some(s) => match pack.find(s) {
                None => Ok(None),
                Some(e) => {
                    let v = pack.view(e)?;
                    let (_, img) = crate::texture::source_section::from_section(&v)
                        .map_err(|err| Error::invalid(pack.path(), err))?;
                    Ok(Some(img))
                }
            },
        })
        .collect()
}

/// The `lod` stage for one mesh section of `pack`: level 0 (the full mesh), the simplified
/// levels (src/lod/simplify.rs) and, with `opts.impostor`, the impostor atlas.
pub fn bake_lod(
    pack: &Pack,
    mesh_section: &str,
    opts: &LodOptions,
) -> Result<(Section, LodReport)> {
    let t0 = std::time::Instant::now();
    let view = pack.view_named(mesh_section)?;
    let (meta, mesh) = crate::mesh::section::from_section(&view)
        .map_err(|err| Error::invalid(pack.path(), err))?;
    let textures = mesh_textures(pack, &meta)?;
    let masks = simplify::alpha_masks(&mesh, &textures);
    let (mut lod, mut arrays) = section::full_mesh_lod(mesh_section, &mesh);
    let impostor_error = opts
        .impostor
        .then(|| impostor_error(lod.radius, opts.impostor_grid, opts.impostor_tile));
    let (levels, cards) = simplify::simplify_chain(&mesh, &masks, lod.radius, impostor_error, opts);
    lod.levels[0].cards = cards as u32;
    simplify::append_levels(&levels, &mut lod.levels, &mut arrays);
    let simplify_seconds = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    if let Some(error) = impostor_error {
        // The atlas' views are centred on the bounding sphere and span its radius.
        let (im, atlas) = impostor::bake_impostor(
            &mesh,
            &textures,
            &masks,
            lod.centre,
            lod.radius,
            opts.impostor_grid,
            opts.impostor_tile,
            error,
        )?;
        lod.impostor = Some(im);
        arrays.impostor = Some(atlas);
    }
    let impostor_seconds = t1.elapsed().as_secs_f64();
    // The model's own line and point arrays, kept as the farthest representation.
    if !mesh.skeleton.is_empty() {
        let (lines, points) = reduce_skeleton(&mesh.skeleton);
        lod.skeleton = Some(section::SkeletonMeta {
            segments: lines.len() as u32,
            points: points.len() as u32,
            albedo: impostor::mean_albedo(&mesh, &textures),
            pixels: select::SKELETON_PIXELS,
        });
        arrays.skeleton_lines = lines.iter().flatten().copied().collect();
        arrays.skeleton_points = points;
    }
    let name = section::lod_section_name(mesh_section);
    let report = LodReport {
        mesh: mesh_section.to_string(),
        section: name.clone(),
        radius: lod.radius,
        cards,
        levels: lod
            .levels
            .iter()
            .map(|l| LevelReport {
                triangles: l.triangle_count,
                vertices: l.vertex_count,
                error: l.error,
                cards: l.cards,
                coverage: l.coverage,
            })
            .collect(),
        impostor_error,
        skeleton: lod
            .skeleton
            .as_ref()
            .map_or([0, 0], |s| [s.segments, s.points]),
        simplify_seconds,
        impostor_seconds,
    };
    Ok((section::to_section(&name, &lod, &arrays), report))
}

/// Segments and points a skeleton keeps (a model drawn as its skeleton covers a pixel or two:
/// more cannot show, and each costs a line or a point per instance).
pub const MAX_SKELETON_SEGMENTS: usize = 16;
pub const MAX_SKELETON_POINTS: usize = 16;

/// The skeleton the `lod` stage keeps: the [`MAX_SKELETON_SEGMENTS`] longest segments (ties to
/// the earlier) and [`MAX_SKELETON_POINTS`] points evenly spaced in file order (point
/// `⌊i·n/max⌋`), both in their original order.
pub fn reduce_skeleton(sk: &crate::model::Skeleton) -> (Vec<[[f32; 3]; 2]>, Vec<[f32; 3]>) {
    let len = |s: &[[f32; 3]; 2]| (0..3).map(|c| (s[1][c] - s[0][c]).powi(2)).sum::<f32>();
    let mut order: Vec<usize> = (0..sk.lines.len()).collect();
    order.sort_by(|&a, &b| {
        len(&sk.lines[b])
            .total_cmp(&len(&sk.lines[a]))
            .then(a.cmp(&b))
    });
    order.truncate(MAX_SKELETON_SEGMENTS);
    order.sort_unstable();
    let lines = order.iter().map(|&i| sk.lines[i]).collect();
    let n = sk.points.len();
    let points = if n <= MAX_SKELETON_POINTS {
        sk.points.clone()
    } else {
        (0..MAX_SKELETON_POINTS)
            .map(|i| sk.points[i * n / MAX_SKELETON_POINTS])
            .collect()
    };
    (lines, points)
}

/// The geometric error of the impostor: a point within `radius` of the centre, seen from a
/// direction θ away from its tile's view direction, lands up to radius·sin θ from where the
/// tile shows it; θ_max is measured over a 256² grid of the hemi-octahedral square (every
/// direction of the upper hemisphere has coordinates in it), and half a texel diagonal,
/// radius·√2/tile, is added for the texel size.
pub fn impostor_error(radius: f32, grid: u32, tile: u32) -> f32 {
    let n = 256;
    let mut cos_min = 1.0f32;
    for j in 0..n {
        for i in 0..n {
            let w = octa::direction((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            let (ti, tj) = octa::tile_of(w, grid.max(1));
            cos_min = cos_min.min(w.dot(octa::tile_direction(ti, tj, grid.max(1))));
        }
    }
    let sin = (1.0 - cos_min.clamp(-1.0, 1.0).powi(2)).sqrt();
    radius * (sin + std::f32::consts::SQRT_2 / tile.max(1) as f32)
}
