//! Mesh processing stages that work on [`crate::model::Mesh`]: tangent frames.

pub mod tangents;
