//! Per-instance environment maps (seed 000, 4.6.3): clustering and multiquadric interpolation.
pub mod cluster;
pub mod interp;
pub mod kdtree;
