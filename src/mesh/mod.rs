//! A model's mesh: its pack section (kind `mesh`, [`section`]) and the tangent frames of
//! [`crate::model::Mesh`] ([`tangents`]).

pub mod section;
pub mod tangents;
