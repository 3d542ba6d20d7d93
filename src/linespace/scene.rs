//! The linespace stage on a pack: the flattened `linespace` section where the placed scene fits
//! the memory budget, else the two-level `linespace-scene` (issue 39). Above `voxel`, whose
//! placed-scene readers and size check ([`crate::voxel::geometry`]) it uses.

use crate::error::Result;
use crate::ingest::limits::Limits;
use crate::pack::Pack;
use crate::voxel::geometry::{
    SceneStage, pack_placed_models, pack_terrain, pack_world_triangles, placed_size,
};
use std::path::Path;

/// The two-level line spaces of a pack's scene (terrain, models, instances), each model read
/// once.
pub fn pack_scene_linespace(
    pack: &Pack,
    opts: &crate::linespace::ntree::NTreeOptions,
) -> Result<crate::linespace::instanced::SceneLinespace> {
    let terrain = pack_terrain(pack)?;
    let (models, inst) = pack_placed_models(pack, |s, g| {
        (s.to_string(), crate::linespace::world_triangles(&g.mesh))
    })?
    .ok_or_else(|| {
        crate::error::Error::Runtime("the two-level line spaces need an instances section".into())
    })?;
    let shafts = std::sync::Arc::new(crate::linespace::shaft::ShaftTable::build(opts.n));
    crate::linespace::instanced::SceneLinespace::build(
        terrain.as_ref(),
        &models,
        &inst.items,
        opts,
        &shafts,
    )
}

/// The linespace stage on a pack: the flattened `linespace` section where the placed scene
/// fits the budget, else the two-level `linespace-scene` section (refused when neither fits,
/// and when the pack has no triangle), with the section's summary.
pub fn pack_linespace_section(
    pack: &Pack,
    opts: &crate::linespace::ntree::NTreeOptions,
    limits: &Limits,
    file: &Path,
    source: &str,
) -> Result<(crate::pack::Section, serde_json::Value)> {
    use crate::linespace::{instanced_section, section};
    let size = placed_size(pack)?;
    size.check(SceneStage::Linespace, limits, file)?;
    if size.linespace_two_level(limits) {
        let two = pack_scene_linespace(pack, opts)?;
        let sec = instanced_section::to_section(instanced_section::KIND, source, &two);
        return Ok((sec, instanced_section::summary_of(&two)));
    }
    let tris = pack_world_triangles(pack)?;
    if tris.is_empty() {
        return Err(crate::error::Error::invalid_at(
            file,
            "geometry",
            "no triangles for the N-tree",
        ));
    }
    let shafts = std::sync::Arc::new(crate::linespace::shaft::ShaftTable::build(opts.n));
    let tree = crate::linespace::ntree::build_ntree(&tris, opts, &shafts)?;
    Ok((
        section::to_section(section::KIND, source, &tree),
        section::summary_of(&tree),
    ))
}
