//! The N-tree with a line space per inner node (seed 002): [`ntree`] builds the tree and its
//! GPU pools, [`shaft`] the exact shaft/box test and the per-child shaft masks, [`layout`]
//! the line-space bit layout, [`query`] soft-shadow queries, [`section`] the `linespace` pack section,
//! [`accuracy`] line-space against exact area-light visibility, [`dense`] the thesis' dense
//! pools as a reference; [`instanced`] the two-level form over a placed scene's instances
//! (section [`instanced_section`], `linespace-scene`; on the GPU [`instanced_gpu`]); [`scene`] the stage on a pack (either
//! form, by the memory budget).
pub mod accuracy;
pub mod dense;
pub mod gpu;
pub mod instanced;
pub mod instanced_gpu;
pub mod instanced_section;
pub mod layout;
pub mod ntree;
pub mod query;
pub mod scene;
pub mod section;
pub mod shaft;
pub mod stage;

/// World-space triangles of a mesh ([`crate::model::Mesh::triangle_positions`]).
pub fn world_triangles(m: &crate::model::Mesh) -> Vec<[[f32; 3]; 3]> {
    m.triangle_positions()
}

#[cfg(test)]
mod tests;
