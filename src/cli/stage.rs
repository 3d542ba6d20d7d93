//! `bake stage NAME INPUT [-o OUT] [--pipeline P] [--set KEY=VALUE]...`: any registered stage's
//! units over a pack, made from the stage registry (`graph::stage::REGISTRY`, issue 36) and run
//! through the graph's one entry (`graph::stage::run_unit`, by `pack_unit_of`): a per-model
//! stage once per mesh section, a sharded stage as one shard of every instance joined by the
//! stage's own join, any other stage once over the pack. The stage's options are the
//! pipeline's (`--pipeline`, default `default`, then `--set`), as `bake SCENE.eco` would give
//! them; the stage runs whatever its switch says. The hand-written `bake <stage>` commands are
//! friendlier aliases with the stage's options as flags.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::stage::{AnyStage, CommandScope, Phase, REGISTRY, Shard};
use crate::stage::Per;
use serde_json::json;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct StageArgs {
    /// The registered stage (`bake stage --list` names them all).
    #[arg(required_unless_present = "list")]
    pub stage: Option<String>,
    /// A pack (or a model or other input file, ingested first).
    #[arg(required_unless_present = "list")]
    pub input: Option<PathBuf>,
    /// Output pack (default: the input pack itself; `<stem>.bake` beside another input).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// The pipeline whose options the stage takes: a preset name or a TOML file (default:
    /// `default`).
    #[arg(long, value_name = "FILE|PRESET")]
    pub pipeline: Option<String>,
    /// Override one pipeline option (repeatable), e.g. `--set prt.samples=256`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// List the registered stages (name, version, what a unit covers, the kinds it writes).
    #[arg(long)]
    pub list: bool,
}

pub(crate) fn run(args: &StageArgs, g: &Global) -> Result<Outcome> {
    run_in(REGISTRY, args, g)
}

/// [`run`] over the registry `registry` (a test's registry with its toy stage too).
pub(crate) fn run_in(
    registry: &[&'static dyn AnyStage],
    args: &StageArgs,
    g: &Global,
) -> Result<Outcome> {
    let names: Vec<&str> = registry.iter().map(|s| s.def().name).collect();
    if args.list {
        let stages: Vec<_> = registry
            .iter()
            .map(|s| {
                let d = s.def();
                json!({"name": d.name, "version": d.version, "per": format!("{:?}", d.per).to_lowercase(), "writes": d.writes})
            })
            .collect();
        let text = registry
            .iter()
            .map(|s| {
                let d = s.def();
                format!(
                    "{:<10} v{:<3} per {:<8} writes {}\n",
                    d.name,
                    d.version,
                    format!("{:?}", d.per).to_lowercase(),
                    d.writes.join(", ")
                )
            })
            .collect();
        return Ok(Outcome {
            json: json!({ "stages": stages }),
            text,
            warnings: Vec::new(),
        });
    }
    let (Some(name), Some(input)) = (&args.stage, &args.input) else {
        return Err(Error::usage("bake stage NAME INPUT: both are required"));
    };
    let st = registry
        .iter()
        .copied()
        .find(|s| s.def().name == name)
        .ok_or_else(|| {
            Error::usage(format!(
                "no registered stage {name:?} (one of {})",
                names.join(", ")
            ))
        })?;
    if st.reads().model_file {
        return Err(Error::usage(format!(
            "stage {name} reads a model file, not a pack: `bake ingest FILE` runs it"
        )));
    }
    let (p, _) = crate::graph::preset::resolve(args.pipeline.as_deref(), false, &args.set)?;
    let (w, output) = super::open_or_ingest(input, args.output.clone())?;
    let limits = g.ingest_defaults().limits;
    let at = CommandScope {
        input,
        limits: &limits,
        plan: None,
    };
    let meshes: Vec<String> = w
        .sections()
        .iter()
        .filter(|s| s.kind == crate::mesh::section::KIND)
        .map(|s| s.name.clone())
        .collect();
    let bar = g.progress(0, name);
    let progress = |n: u64| bar.inc(n);
    let candidates = w.sections().to_vec();
    let unit = |mesh: Option<&str>, shard: Option<Shard>| {
        crate::graph::stage::pack_unit_of(st, &at, &candidates, &p, mesh, shard, &progress)
    };
    let (mut sections, mut reports, mut warnings) = (Vec::new(), Vec::new(), Vec::new());
    let mut units = Vec::new();
    match (st.def().per, st.phase()) {
        (Per::Model, Phase::Model) => {
            for m in &meshes {
                let o = unit(Some(m), None)?;
                units.push(st.unit_name(m.strip_prefix("mesh:"), None));
                sections.extend(o.sections);
                reports.push(o.report);
                warnings.extend(o.warnings);
            }
        }
        (Per::Shards, _) => {
            let shard = Shard::Of(0, 1);
            units.push(st.unit_name(None, Some(&shard)));
            let o = unit(None, Some(shard))?;
            let n = st.shard_size(&o.sections)?;
            sections = st.join(vec![(n, o.sections)], &p)?;
            reports.push(o.report);
            warnings.extend(o.warnings);
        }
        _ => {
            units.push(st.unit_name(None, None));
            let o = unit(None, None)?;
            sections = o.sections;
            reports.push(o.report);
            warnings.extend(o.warnings);
        }
    }
    bar.finish_and_clear();
    let written: Vec<String> = sections.iter().map(|s| s.name.clone()).collect();
    drop(candidates);
    let bytes = super::write_pack(w, sections, &output)?;
    let json = json!({
        "stage": name,
        "version": st.def().version,
        "units": units,
        "reports": reports,
        "sections": written,
        "output": output,
        "bytes": bytes.len(),
    });
    let text = format!(
        "{}: stage {name}, {} unit(s), {} section(s) written ({} bytes)\n",
        output.display(),
        units.len(),
        written.len(),
        bytes.len()
    );
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}
