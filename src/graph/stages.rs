//! What the stage registry says of each stage besides its code: [`StageDef`] (name, version,
//! what one of its units covers, the section kinds it writes and the `bake unit` actions that
//! run it in a build-engine plan; defined in [`crate::stage`]), one per `impl Stage` in the
//! stages' folders, listed by
//! [`all`] in the order of [`super::stage::REGISTRY`] (issue 36, item 1). The build key takes
//! the stages' names and versions from there ([`super::versions::all`]); tests hold the
//! graph's unit records, the registry of section kinds ([`crate::kinds::all`]) and `bake
//! unit`'s subcommands to it. `graph::build`, `plan::plan_in` and `bake unit`'s stage actions
//! loop over the registry.
//!
//! Not driven by it: the scene's own units (the terrain's and models' sections from the scene
//! plan, the instances, the build record), the number of `envmaps` shards, the light map's
//! row shards and their join (`lightmap-join`), and the stage commands that do more than a unit (`bake sky`;
//! `bake svo` and `bake linespace` over a model file). The other stage commands run their
//! stage's unit ([`super::stage::pack_unit`], [`super::stage::scene_unit`]).

pub use crate::stage::{Per, StageDef};

/// Section kinds the graph writes itself, not a stage: the scene's instances, the build
/// record, and the embedded build report (`--embed-report`).
pub const GRAPH_WRITES: &[&str] = &["instances", "build", "build_report"];

/// `bake unit` subcommands that belong to no stage: the instances and the build record.
pub const GRAPH_ACTIONS: &[&str] = &["instances", "record"];

/// Every stage's entry, in registry order ([`super::stage::REGISTRY`]: the order of the build
/// key).
pub fn all() -> impl Iterator<Item = &'static StageDef> {
    super::stage::REGISTRY.iter().map(|s| s.def())
}

/// The stage named `name`.
pub fn find(name: &str) -> Option<&'static StageDef> {
    all().find(|s| s.name == name)
}

#[cfg(test)]
mod tests {
    use super::super::versions;
    use super::*;

    #[test]
    fn every_kind_a_stage_writes_is_registered_and_every_kind_is_written() {
        for s in all() {
            for k in s.writes {
                assert!(crate::kinds::find(k).is_some(), "{}: kind {k:?}", s.name);
            }
        }
        for k in crate::kinds::all() {
            let written =
                all().any(|s| s.writes.contains(&k.kind)) || GRAPH_WRITES.contains(&k.kind);
            assert!(written, "no stage writes kind {:?}", k.kind);
        }
    }

    #[test]
    fn names_are_unique_and_every_stage_has_an_action() {
        let stages: Vec<&StageDef> = all().collect();
        for (i, s) in stages.iter().enumerate() {
            assert!(stages[..i].iter().all(|o| o.name != s.name), "{}", s.name);
            assert!(!s.actions.is_empty(), "{}", s.name);
        }
    }

    #[test]
    fn the_build_key_hashes_the_stages_in_their_old_order() {
        // The order and names the build key had before this list (a change re-keys every
        // pack's `build` record: the golden packs would change).
        let names: Vec<&str> = versions::all().iter().map(|(n, _)| *n).collect();
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
