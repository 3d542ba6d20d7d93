//! Which level of a model an instance draws: the `lod` section's rule
//! ([`crate::lod::select::choose`]) where the model has one, else full detail. Bucket levels
//! `0..=lod_levels.len()` are the mesh levels; a model with an impostor atlas has one more,
//! `lod_levels.len() + 1`, drawn by [`super::impostor`]; a model with a skeleton one more after
//! that, drawn by [`super::skeleton`].

use super::scene::ModelData;

/// The level rule of one model for one view: `k` pixels per unit at distance 1 and the pixel
/// threshold `tau`.
pub struct ModelRule<'a> {
    model: &'a ModelData<'a>,
    k: f32,
    tau: f32,
}

impl<'a> ModelRule<'a> {
    pub fn new(model: &'a ModelData<'a>, k: f32, tau: f32) -> Self {
        ModelRule { model, k, tau }
    }
}

impl super::cull::LevelRule for ModelRule<'_> {
    fn levels(&self) -> usize {
        1 + self.model.lod_levels.len()
            + self.model.impostor.is_some() as usize
            + self.model.skeleton.is_some() as usize
    }

    fn level(&self, scale: f32, distance: f32) -> usize {
        use crate::lod::select::{Choice, choose};
        match &self.model.lod {
            None => 0,
            Some(meta) => match choose(meta, scale, distance, self.k, self.tau) {
                Choice::Mesh(l) => l,
                // Without an atlas in the pack, the coarsest mesh level stands in.
                Choice::Impostor => {
                    self.model.lod_levels.len() + self.model.impostor.is_some() as usize
                }
                // The section's meta has a skeleton exactly when the scene's model has one.
                Choice::Skeleton => {
                    1 + self.model.lod_levels.len() + self.model.impostor.is_some() as usize
                }
            },
        }
    }
}
