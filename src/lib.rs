//! `bake`: an asset-baking pipeline for interactive landscape rendering.
//!
//! Data flow (see ../shared/brief/BRIEF.md and docs/): [`ingest`] reads every input into the
//! [`model`]; stages turn the model into GPU-ready data; [`pack`] stores it; [`dump`] shows it;
//! `render` proves it with wgpu. [`graph`] is the orchestrator, [`cli`] the subcommands; the
//! layers and what may import what: docs/ARCHITECTURE.md.
pub mod bench;
pub mod bittree;
pub mod cli;
pub mod color;
pub mod cube;
pub mod diag;
pub mod dump;
pub mod envmap;
pub mod error;
pub(crate) mod export;
pub mod fixtures;
pub mod gpu;
pub mod graph;
pub mod ingest;
pub(crate) mod kdtree;
pub mod kinds;
pub mod lightmap;
pub mod linespace;
pub mod lod;
pub mod material;
pub mod mesh;
pub(crate) mod mitsuba;
pub mod model;
pub mod pack;
pub mod pipeline;
pub mod plan;
pub mod prt;
pub mod render;
pub mod report;
pub mod rng;
pub mod sh;
pub mod sky;
pub mod stage;
pub mod terrain;
pub mod texture;
pub mod trace;
pub mod verify;
pub mod voxel;
