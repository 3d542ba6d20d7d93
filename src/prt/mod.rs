//! Precomputed radiance transfer (PRT): per-vertex transfer for plant models ([`transfer`]), its
//! pack section and the pack-level driver ([`pack`]), its error against a reference ([`error`]),
//! a spatial filter the error benchmark measures ([`filter`]), the same estimator as a wgpu compute
//! shader ([`gpu`], `prt.tracer = "gpu"`), the procedural test plant the
//! benchmarks bake ([`plant`]); the benchmarks are `crate::bench::rays` and
//! `crate::bench::prt_error`.

pub mod error;
pub mod filter;
pub mod gpu;
pub mod pack;
pub mod plant;
pub mod stage;
pub mod transfer;
