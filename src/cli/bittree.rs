//! `bake bittree INPUT`: adds a `bittree` section encoding the instances of a scene pack (or ECO),
//! through the registry's `bittree` unit (the graph's and `bake unit bittree`'s): the instances
//! of the `instances` section, over their bounds joined with the scene's area of interest for an
//! ECO input (so the section equals the graph's); a pack records no area of interest, so over a
//! pack alone the area is the instances' bounds.

use super::{Global, Outcome};
use crate::bittree::BitTreeOptions;
use crate::error::{Error, Result};
use crate::graph::stage::{CommandScope, pack_sections, scene_unit};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct BitTreeArgs {
    /// A pack with an `instances` section, or an ECO scene.
    pub input: PathBuf,
    /// Output pack (default: the input pack itself, or <stem>.bake for an ECO file).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Children per level: 4, 16 or 64 (the pipeline's `bittree.children`).
    #[arg(long, default_value_t = 16)]
    pub children: u32,
}

pub(crate) fn run(args: &BitTreeArgs, g: &Global) -> Result<Outcome> {
    let (w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    // An ECO input: its plan, for the area of interest the graph's unit reads too.
    let plan = if super::svo::is_pack(&args.input) {
        None
    } else {
        Some(crate::ingest::eco::scene_plan(
            std::slice::from_ref(&args.input),
            &crate::ingest::IngestOptions::default(),
        )?)
    };
    let bytes = w.to_bytes()?;
    let pack = Pack::from_bytes(&bytes, &args.input.display().to_string())?;
    let pipeline = crate::graph::Pipeline {
        bittree: BitTreeOptions {
            children: args.children,
            ..Default::default()
        },
        ..Default::default()
    };
    let limits = g.ingest_defaults().limits;
    let at = CommandScope {
        input: &args.input,
        limits: &limits,
        plan: plan.as_ref(),
    };
    let o = scene_unit(
        "bittree",
        &at,
        &pack_sections(&pack, "bittree")?,
        &pipeline,
        &|_| {},
    )?;
    // The unit records an instance set it cannot encode as a warning (the graph goes on
    // without the section); here there is nothing else to do: an error.
    if o.sections.is_empty() {
        let why = o
            .warnings
            .first()
            .map_or("no BitTree", |w| w.message.as_str());
        return Err(Error::invalid_at(&args.input, "instances", why));
    }
    let out_bytes = super::write_pack(w, o.sections, &output)?;
    let p2 = Pack::from_bytes(&out_bytes, "out")?;
    let summary = crate::bittree::section::summary(&p2.view_named("bittree")?)
        .map_err(|e| Error::invalid(&output, e))?;
    Ok(Outcome {
        text: format!("{}: bittree {}\n", output.display(), summary),
        json: summary,
        warnings: Vec::new(),
    })
}
