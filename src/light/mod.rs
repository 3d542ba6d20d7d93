//! Precomputed light transport: per-vertex PRT for plant models ([`prt`]), its pack section and
//! the pack-level driver ([`prt_pack`]), and the procedural test plant the benchmarks bake
//! ([`plant`]).

pub mod plant;
pub mod prt;
pub mod prt_pack;
