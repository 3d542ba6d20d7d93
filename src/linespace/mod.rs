//! The N-tree with a line space per inner node (seed 002): [`ntree`] builds the tree and its
//! GPU pools, [`shaft`] the exact shaft/box test and the per-child shaft masks, [`linespace`]
//! the bit layout, [`query`] soft-shadow queries, [`section`] the `linespace` pack section,
//! [`accuracy`] line-space against exact area-light visibility, [`dense`] the thesis' dense
//! pools as a reference.
pub mod accuracy;
pub mod dense;
pub mod gpu;
#[allow(clippy::module_inception)]
pub mod linespace;
pub mod ntree;
pub mod query;
pub mod section;
pub mod shaft;

#[cfg(test)]
mod tests;
