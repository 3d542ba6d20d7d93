//! `bake unit ACTION ...`: one unit of the stage graph as an action with explicit inputs and
//! outputs (what `bake plan` writes for Ninja and Bazel; [`crate::plan::actions`]). Every unit
//! takes the scene's arguments of `bake SCENE.eco` (scenes, `--sky`, `--models`, `--color-map`,
//! `--pipeline`/`--set`/`--preview`) so that its options are the graph's.
//!
//! The registered stages' subcommands come from the stage registry
//! ([`crate::graph::stage::REGISTRY`]): one per stage (but the source stages, which the
//! `terrain` and `model` units run), named by its first action, taking `--name` for a per-model
//! stage, `--in` for a stage that reads sections and `--shard` for a sharded one, and a sharded
//! stage's join, named by its second action ([`StageUnit`]). The scene's own units, the light
//! map's join of row shards and the record are written here.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::stage::{AnyStage, Phase, REGISTRY};
use crate::graph::stages::Per;
use crate::plan::actions::{self, SceneArgs, UnitReport};
use std::path::PathBuf;

/// The arguments of `bake SCENE.eco` that every unit shares, and the unit's pack.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct UnitFlags {
    #[command(flatten)]
    pub flags: super::scene::SceneFlags,
    /// The unit's pack.
    #[arg(short, long, required = true)]
    pub output: PathBuf,
}

impl UnitFlags {
    fn scene(&self, g: &Global) -> Result<SceneArgs> {
        let (pipeline, pipeline_file) = self.flags.pipeline()?;
        Ok(SceneArgs {
            scenes: self.flags.scenes.clone(),
            sky: self.flags.sky.clone(),
            ingest: self.flags.ingest(g),
            pipeline,
            pipeline_file,
        })
    }
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct UnitArgs {
    #[command(subcommand)]
    pub unit: Unit,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub(crate) enum Unit {
    /// The terrain's sections and the prepared terrain.
    Terrain(UnitFlags),
    /// One model: ingest and materials; also writes the files it read (`--deps`).
    Model {
        #[command(flatten)]
        scene: UnitFlags,
        /// The model's name in the scene (its file name).
        #[arg(long)]
        name: String,
        /// The model file, as the scene resolves it.
        #[arg(long)]
        path: PathBuf,
        /// JSON record of the files read and the triangle count (for `bake unit record`).
        #[arg(long, required = true)]
        deps: PathBuf,
    },
    /// The scene's `instances` section.
    Instances(UnitFlags),
    /// The terrain light map from its row shards' packs (in shard order).
    LightmapJoin(WithPacks),
    /// The `build` record over the models' records (`--deps`).
    Record {
        #[command(flatten)]
        scene: UnitFlags,
        #[arg(long = "deps", value_name = "JSON")]
        deps: Vec<PathBuf>,
    },
    /// A registered stage's unit (one subcommand per stage, from the registry).
    #[command(flatten)]
    Stage(StageUnit),
}

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct WithPacks {
    #[command(flatten)]
    pub scene: UnitFlags,
    /// The packs the unit reads, in the graph's order (repeatable).
    #[arg(long = "in", value_name = "PACK", required = true)]
    pub inputs: Vec<PathBuf>,
}

/// The unit of a registered stage: its action's name and its flags.
#[derive(Debug, Clone)]
pub(crate) struct StageUnit {
    pub action: String,
    pub flags: StageAction,
}

/// A registered stage's action: its unit, or a sharded stage's join (its second action).
#[derive(Debug, Clone)]
pub(crate) enum StageAction {
    /// The stage's unit.
    Unit(StageFlags),
    /// The join of a sharded stage's shards.
    Join(WithPacks),
}

/// The flags of a registered stage's unit (those a stage has no use for are hidden and
/// refused).
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct StageFlags {
    #[command(flatten)]
    pub scene: UnitFlags,
    /// The model's name in the scene (its file name).
    #[arg(long)]
    pub name: Option<String>,
    /// The packs the unit reads, in the graph's order (repeatable).
    #[arg(long = "in", value_name = "PACK")]
    pub inputs: Vec<PathBuf>,
    /// Which shard: I of N (1-based).
    #[arg(long, value_parser = actions::parse_shard)]
    pub shard: Option<(usize, usize)>,
    /// Which shard of the light map's rows: I of N (1-based), joined by `lightmap-join`.
    #[arg(long, value_parser = actions::parse_shard)]
    pub rows: Option<(usize, usize)>,
}

/// The stages `bake unit` runs through [`StageUnit`]: all but the source stages.
fn unit_stages() -> impl Iterator<Item = &'static dyn AnyStage> {
    REGISTRY
        .iter()
        .copied()
        .filter(|s| s.phase() != Phase::Source)
}

/// The subcommand of one registered stage.
fn stage_command(st: &dyn AnyStage) -> clap::Command {
    use clap::Args;
    let d = st.def();
    let r = st.reads();
    let (per_model, sharded, packs) = (
        d.per == Per::Model,
        d.per == Per::Shards,
        !r.kinds.is_empty(),
    );
    let mut about = format!("The `{}` stage's unit", d.name);
    if per_model {
        about.push_str(" of one model (`--name`)");
    }
    if sharded {
        about.push_str(", one shard (`--shard I/N`)");
    }
    if packs {
        about.push_str(&format!(
            " over the packs holding its inputs (`--in`: {})",
            r.kinds.join(", ")
        ));
    }
    if r.scene {
        about.push_str(" over the scene");
    }
    about.push_str(&format!(": writes {}", d.writes.join(", ")));
    if d.name == "lightmap" {
        about.push_str(" (with `--rows I/N`: one shard of its rows, joined by `lightmap-join`)");
    }
    // (After the flags: they would set the struct's doc comment as the about.)
    StageFlags::augment_args(clap::Command::new(d.actions[0]))
        .about(about)
        .mut_arg("name", |a| a.required(per_model).hide(!per_model))
        .mut_arg("inputs", |a| a.required(packs).hide(!packs))
        .mut_arg("shard", |a| a.required(sharded).hide(!sharded))
        .mut_arg("rows", |a| a.hide(d.name != "lightmap"))
}

/// The join subcommand of a sharded stage (its second action).
fn join_command(st: &dyn AnyStage) -> Option<clap::Command> {
    use clap::Args;
    let d = st.def();
    (d.per == Per::Shards).then(|| {
        WithPacks::augment_args(clap::Command::new(d.actions[1])).about(format!(
            "The `{}` stage's {} from its shards' packs (`--in`, in shard order)",
            d.name,
            d.writes.join(", ")
        ))
    })
}

/// The registered stage whose join action is `action`.
fn join_stage(action: &str) -> Option<&'static dyn AnyStage> {
    unit_stages().find(|s| s.def().per == Per::Shards && s.def().actions.get(1) == Some(&action))
}

impl clap::FromArgMatches for StageUnit {
    fn from_arg_matches(m: &clap::ArgMatches) -> std::result::Result<Self, clap::Error> {
        Self::from_arg_matches_mut(&mut m.clone())
    }

    fn from_arg_matches_mut(m: &mut clap::ArgMatches) -> std::result::Result<Self, clap::Error> {
        use clap::Subcommand;
        use clap::error::ErrorKind;
        match m.remove_subcommand() {
            Some((action, mut sub)) if join_stage(&action).is_some() => Ok(StageUnit {
                flags: StageAction::Join(WithPacks::from_arg_matches_mut(&mut sub)?),
                action,
            }),
            Some((action, mut sub)) if Self::has_subcommand(&action) => Ok(StageUnit {
                flags: StageAction::Unit(StageFlags::from_arg_matches_mut(&mut sub)?),
                action,
            }),
            Some((action, _)) => Err(clap::Error::raw(
                ErrorKind::InvalidSubcommand,
                format!("no registered stage runs the unit {action:?}\n"),
            )),
            None => Err(clap::Error::raw(
                ErrorKind::MissingSubcommand,
                "a unit is required\n",
            )),
        }
    }

    fn update_from_arg_matches(
        &mut self,
        m: &clap::ArgMatches,
    ) -> std::result::Result<(), clap::Error> {
        *self = Self::from_arg_matches(m)?;
        Ok(())
    }
}

impl clap::Subcommand for StageUnit {
    fn augment_subcommands(cmd: clap::Command) -> clap::Command {
        unit_stages().fold(cmd, |c, s| {
            let c = c.subcommand(stage_command(s));
            match join_command(s) {
                Some(j) => c.subcommand(j),
                None => c,
            }
        })
    }

    fn augment_subcommands_for_update(cmd: clap::Command) -> clap::Command {
        Self::augment_subcommands(cmd)
    }

    fn has_subcommand(name: &str) -> bool {
        unit_stages().any(|s| s.def().actions.first() == Some(&name)) || join_stage(name).is_some()
    }
}

/// A registered stage's unit ([`actions::stage_unit`]; with `--rows`, a shard of the light
/// map's rows).
fn stage_unit(u: &StageUnit, g: &Global) -> Result<UnitReport> {
    let f = match &u.flags {
        StageAction::Unit(f) => f,
        StageAction::Join(w) => {
            let st = join_stage(&u.action)
                .ok_or_else(|| Error::usage(format!("no registered stage joins {:?}", u.action)))?;
            return actions::stage_join(st, &w.scene.scene(g)?, &w.inputs, &w.scene.output);
        }
    };
    let st = actions::stage_of_action(&u.action)?;
    let d = st.def();
    if f.name.is_some() && d.per != Per::Model {
        return Err(Error::usage(format!(
            "--name: the {} unit is not per model",
            d.name
        )));
    }
    if f.shard.is_some() && d.per != Per::Shards {
        return Err(Error::usage(format!(
            "--shard: the {} unit has no shards",
            d.name
        )));
    }
    let scene = f.scene.scene(g)?;
    match f.rows {
        Some(r) if d.name == "lightmap" => {
            actions::lightmap_rows(&scene, &f.inputs, r, &f.scene.output)
        }
        Some(_) => Err(Error::usage(format!(
            "--rows: the {} unit has no row shards",
            d.name
        ))),
        None => actions::stage_unit(
            st,
            &scene,
            f.name.as_deref(),
            &f.inputs,
            f.shard,
            &f.scene.output,
        ),
    }
}

pub(crate) fn run(args: &UnitArgs, g: &Global) -> Result<Outcome> {
    let r: UnitReport = match &args.unit {
        Unit::Terrain(f) => actions::terrain(&f.scene(g)?, &f.output)?,
        Unit::Model {
            scene,
            name,
            path,
            deps,
        } => actions::model(&scene.scene(g)?, name, path, &scene.output, deps)?,
        Unit::Instances(f) => actions::instances(&f.scene(g)?, &f.output)?,
        Unit::LightmapJoin(w) => {
            actions::lightmap_join(&w.scene.scene(g)?, &w.inputs, &w.scene.output)?
        }
        Unit::Record { scene, deps } => actions::record(&scene.scene(g)?, deps, &scene.output)?,
        Unit::Stage(u) => stage_unit(u, g)?,
    };
    Ok(outcome(r))
}

pub(crate) fn outcome(r: UnitReport) -> Outcome {
    Outcome {
        json: serde_json::to_value(&r).unwrap_or_default(),
        text: format!(
            "{}: {} ({} sections)\n",
            r.output.display(),
            r.unit,
            r.sections.len()
        ),
        warnings: r.warnings,
    }
}

/// `bake merge A.bake B.bake ... -o OUT.bake`.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct MergeArgs {
    /// The packs, in the order their sections go into the output.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[arg(short, long, required = true)]
    pub output: PathBuf,
}

pub(crate) fn run_merge(args: &MergeArgs, _g: &Global) -> Result<Outcome> {
    Ok(outcome(actions::merge(&args.inputs, &args.output)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{FromArgMatches, Subcommand};

    fn parse(args: &[&str]) -> std::result::Result<Unit, clap::Error> {
        let cmd = Unit::augment_subcommands(clap::Command::new("unit"));
        let mut m = cmd.try_get_matches_from(args)?;
        Unit::from_arg_matches_mut(&mut m)
    }

    /// `bake unit`'s subcommands are the actions of the listed stages and the graph's own (moved
    /// from tests/kinds.rs when the command line became internal).
    #[test]
    fn bake_unit_runs_the_actions_of_the_listed_stages() {
        let cmd = Unit::augment_subcommands(clap::Command::new("unit"));
        use std::collections::BTreeSet;
        let subcommands: BTreeSet<String> = cmd
            .get_subcommands()
            .map(|c| c.get_name().to_string())
            .collect();
        let mut listed: BTreeSet<String> = crate::graph::stages::all()
            .flat_map(|s| s.actions.iter().map(|a| a.to_string()))
            .collect();
        listed.extend(
            crate::graph::stages::GRAPH_ACTIONS
                .iter()
                .map(|a| a.to_string()),
        );
        assert_eq!(subcommands, listed);
    }

    #[test]
    fn every_registered_stage_but_the_source_stages_is_a_subcommand_with_its_flags() {
        let cmd = Unit::augment_subcommands(clap::Command::new("unit"));
        for st in REGISTRY.iter() {
            let d = st.def();
            // (The source stages run inside the hand-written `terrain` and `model` units.)
            if st.phase() == Phase::Source {
                assert!(!StageUnit::has_subcommand(d.actions[0]), "{}", d.name);
                continue;
            }
            let sub = cmd.find_subcommand(d.actions[0]).expect(d.name);
            let required = |id: &str| {
                sub.get_arguments()
                    .find(|a| a.get_id() == id)
                    .is_some_and(|a| a.is_required_set())
            };
            assert_eq!(required("name"), d.per == Per::Model, "{}", d.name);
            assert_eq!(required("shard"), d.per == Per::Shards, "{}", d.name);
            assert_eq!(
                required("inputs"),
                !st.reads().kinds.is_empty(),
                "{}",
                d.name
            );
        }
    }

    #[test]
    fn a_stage_unit_parses_to_its_action_and_missing_or_foreign_flags_are_refused() {
        let base = ["unit", "prt", "s.eco", "-o", "p.bake", "--in", "m.bake"];
        let Unit::Stage(u) = parse(&[&base[..], &["--name", "a.txf"]].concat()).unwrap() else {
            panic!("not a stage unit")
        };
        assert_eq!(u.action, "prt");
        let StageAction::Unit(f) = &u.flags else {
            panic!("not a unit")
        };
        assert_eq!(f.name.as_deref(), Some("a.txf"));
        assert_eq!(f.inputs, [PathBuf::from("m.bake")]);
        // A per-model unit without its model, a sharded one without its shard.
        assert!(parse(&base).is_err());
        assert!(parse(&["unit", "envmaps", "s.eco", "-o", "e.bake", "--in", "i.bake"]).is_err());
        let Unit::Stage(u) = parse(&[
            "unit", "envmaps", "s.eco", "-o", "e.bake", "--in", "i.bake", "--shard", "2/3",
        ])
        .unwrap() else {
            panic!("not a stage unit")
        };
        let StageAction::Unit(f) = &u.flags else {
            panic!("not a unit")
        };
        assert_eq!(f.shard, Some((1, 3)));
        // A sharded stage's join: its second action, over the shards' packs.
        let Unit::Stage(u) = parse(&[
            "unit",
            "envmaps-join",
            "s.eco",
            "-o",
            "e.bake",
            "--in",
            "1.bake",
            "--in",
            "2.bake",
        ])
        .unwrap() else {
            panic!("not a stage unit")
        };
        let StageAction::Join(w) = &u.flags else {
            panic!("not a join")
        };
        assert_eq!(w.inputs, [PathBuf::from("1.bake"), PathBuf::from("2.bake")]);
        assert!(
            parse(&[
                "unit",
                "envmaps-join",
                "s.eco",
                "-o",
                "e.bake",
                "--shard",
                "1/2"
            ])
            .is_err()
        );
        // Flags the stage has no use for: refused before anything is read.
        let g = Global::default();
        for args in [
            &["unit", "sky", "s.eco", "-o", "s.bake", "--name", "x"][..],
            &[
                "unit", "cluster", "s.eco", "-o", "c.bake", "--in", "i.bake", "--shard", "1/2",
            ],
            &[
                "unit", "atlas", "s.eco", "-o", "a.bake", "--in", "i.bake", "--rows", "1/2",
            ],
        ] {
            let Unit::Stage(u) = parse(args).unwrap() else {
                panic!("not a stage unit")
            };
            let e = stage_unit(&u, &g).expect_err("refused").to_string();
            assert!(e.contains("--"), "{args:?}: {e}");
        }
    }
}
