//! Precomputed radiance transfer (PRT): per-vertex transfer for plant models ([`transfer`]), its
//! pack section and the pack-level driver ([`pack`]), its error against a reference ([`error`]),
//! the procedural test plant the benchmarks
//! bake ([`plant`]); the ray benchmark is `crate::bench::rays`.

pub mod error;
pub mod pack;
pub mod plant;
pub mod transfer;
