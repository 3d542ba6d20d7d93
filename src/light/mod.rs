//! Precomputed light transport: per-vertex PRT for plant models ([`prt`]), its pack section and
//! the pack-level driver ([`prt_pack`]), the procedural test plant the benchmarks bake
//! ([`plant`]) and the ray benchmark ([`bench`]).

pub mod bench;
pub mod plant;
pub mod prt;
pub mod prt_pack;
