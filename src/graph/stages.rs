//! The stages of the graph in one list, [`STAGES`] (issue 36, item 1): for each stage its
//! name, version, what one of its units covers, the section kinds it writes and the `bake unit`
//! actions that run it in a build-engine plan. The build key takes the stages' versions from
//! here ([`super::versions::ALL`]); tests hold the graph's unit records, the registry of
//! section kinds ([`crate::kinds::KINDS`]) and `bake unit`'s subcommands to it. What each stage
//! reads and computes is its `impl Stage` in [`super::stage`], whose [`super::stage::REGISTRY`]
//! holds the stages in this order; `graph::build`, `plan::plan_in` and `bake unit`'s stage
//! actions loop over that registry.
//!
//! Not driven by it: the scene's own units (the terrain's and models' sections from the scene
//! plan, the instances, the build record), the sharding of `envmaps` and of the light map's
//! rows and their join actions, and the per-stage subcommands (`bake prt`, `bake lod`, ...),
//! which call their stage's functions directly. `bake unit`'s subcommands of the registered
//! stages are made from the registry (`tests/kinds.rs` holds them to [`STAGES`]).

use super::versions;

/// What one unit of a stage covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Per {
    /// One unit per model file of the scene.
    Model,
    /// The scene's terrain.
    Terrain,
    /// The scene's sky.
    Sky,
    /// The whole scene (its instances, the terrain and the models together).
    Scene,
    /// The scene's instances in shards, joined into one section.
    Shards,
}

/// One stage of the graph.
#[derive(Debug, Clone, Copy)]
pub struct StageDef {
    /// The name of its units in the build report, the cache and `--set stages.NAME`.
    pub name: &'static str,
    /// Bumped when its output changes for the same inputs (the constants of [`versions`]).
    pub version: u32,
    pub per: Per,
    /// The section kinds its units write.
    pub writes: &'static [&'static str],
    /// The `bake unit` subcommands that run it in a plan (a model's ingest and materials are
    /// one action, `model`).
    pub actions: &'static [&'static str],
}

/// Every stage, in the order of the build key (do not reorder: the key hashes this order).
pub const STAGES: [StageDef; 13] = [
    stage(
        "ingest",
        versions::INGEST,
        Per::Model,
        &["mesh", "texture"],
        &["model"],
    ),
    stage(
        "material",
        versions::MATERIAL,
        Per::Model,
        &["material", "texture", "tangents"],
        &["model"],
    ),
    stage(
        "terrain",
        versions::TERRAIN,
        Per::Terrain,
        &["terrain", "texture"],
        &["terrain"],
    ),
    stage(
        "sky",
        versions::SKY,
        Per::Sky,
        &["sky", "sun", "sh"],
        &["sky"],
    ),
    stage("prt", versions::PRT, Per::Model, &["prt"], &["prt"]),
    stage("lod", versions::LOD, Per::Model, &["lod"], &["lod"]),
    stage(
        "lightmap",
        versions::LIGHTMAP,
        Per::Terrain,
        &["lightmap"],
        &["lightmap", "lightmap-join"],
    ),
    stage(
        "atlas",
        versions::ATLAS,
        Per::Scene,
        &["lightmap"],
        &["atlas"],
    ),
    stage(
        "envmaps",
        versions::ENVMAPS,
        Per::Shards,
        &["envmaps"],
        &["envmaps", "envmaps-join"],
    ),
    stage(
        "cluster",
        versions::CLUSTER,
        Per::Scene,
        &["clusters"],
        &["cluster"],
    ),
    stage(
        "bittree",
        versions::BITTREE,
        Per::Scene,
        &["bittree"],
        &["bittree"],
    ),
    stage(
        "svo",
        versions::SVO,
        Per::Scene,
        &["svo", "svo-scene"],
        &["svo"],
    ),
    stage(
        "linespace",
        versions::LINESPACE,
        Per::Scene,
        &["linespace", "linespace-scene"],
        &["linespace"],
    ),
];

/// Section kinds the graph writes itself, not a stage: the scene's instances, the build
/// record, and the embedded build report (`--embed-report`).
pub const GRAPH_WRITES: &[&str] = &["instances", "build", "build_report"];

/// `bake unit` subcommands that belong to no stage: the instances and the build record.
pub const GRAPH_ACTIONS: &[&str] = &["instances", "record"];

const fn stage(
    name: &'static str,
    version: u32,
    per: Per,
    writes: &'static [&'static str],
    actions: &'static [&'static str],
) -> StageDef {
    StageDef {
        name,
        version,
        per,
        writes,
        actions,
    }
}

/// The stage named `name`.
pub fn find(name: &str) -> Option<&'static StageDef> {
    STAGES.iter().find(|s| s.name == name)
}

/// (name, version) of every stage, in order: what the build key hashes.
pub const fn names_and_versions() -> [(&'static str, u32); STAGES.len()] {
    let mut out = [("", 0); STAGES.len()];
    let mut i = 0;
    while i < STAGES.len() {
        out[i] = (STAGES[i].name, STAGES[i].version);
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_a_stage_writes_is_registered_and_every_kind_is_written() {
        for s in &STAGES {
            for k in s.writes {
                assert!(crate::kinds::find(k).is_some(), "{}: kind {k:?}", s.name);
            }
        }
        for k in crate::kinds::KINDS {
            let written =
                STAGES.iter().any(|s| s.writes.contains(&k.kind)) || GRAPH_WRITES.contains(&k.kind);
            assert!(written, "no stage writes kind {:?}", k.kind);
        }
    }

    #[test]
    fn names_are_unique_and_every_stage_has_an_action() {
        for (i, s) in STAGES.iter().enumerate() {
            assert!(STAGES[..i].iter().all(|o| o.name != s.name), "{}", s.name);
            assert!(!s.actions.is_empty(), "{}", s.name);
        }
    }

    #[test]
    fn the_build_key_hashes_the_stages_in_their_old_order() {
        // The order and names the build key had before this list (a change re-keys every
        // pack's `build` record: the golden packs would change).
        let names: Vec<&str> = versions::ALL.iter().map(|(n, _)| *n).collect();
        assert_eq!(
            names,
            [
                "ingest",
                "material",
                "terrain",
                "sky",
                "prt",
                "lod",
                "lightmap",
                "atlas",
                "envmaps",
                "cluster",
                "bittree",
                "svo",
                "linespace"
            ]
        );
    }
}
