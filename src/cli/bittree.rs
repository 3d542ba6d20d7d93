//! `bake bittree INPUT`: adds a `bittree` section encoding the instances of a scene pack (or ECO).

use super::{Global, Outcome};
use crate::bittree::BitTreeOptions;
use crate::error::{Error, Result};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct BitTreeArgs {
    /// A pack with an `instances` section, or an ECO scene.
    pub input: PathBuf,
    /// Output pack (default: the input pack itself, or <stem>.bake for an ECO file).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Children per level: 4, 16 or 64.
    #[arg(long, default_value_t = 16)]
    pub children: u32,
}

pub(crate) fn run(args: &BitTreeArgs, _g: &Global) -> Result<Outcome> {
    let (mut w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let bytes = w.to_bytes()?;
    let pack = Pack::from_bytes(&bytes, &args.input.display().to_string())?;
    let v = pack.view_named("instances")?;
    let (_, inst) = crate::ingest::instances_section::from_section(&v)
        .map_err(|e| Error::invalid(&args.input, e))?;
    let area = instance_area(&inst);
    let opts = BitTreeOptions {
        children: args.children,
        ..Default::default()
    };
    let section = crate::bittree::section::to_section("bittree", &inst, area, &opts)
        .map_err(|e| Error::invalid_at(&args.input, "instances", e))?;
    w.insert(section);
    let out_bytes = w.to_bytes()?;
    crate::pack::write_atomic(&output, &out_bytes)?;
    let p2 = Pack::from_bytes(&out_bytes, "out")?;
    let summary = crate::bittree::section::summary(&p2.view_named("bittree")?)
        .map_err(|e| Error::invalid(&output, e))?;
    Ok(Outcome {
        text: format!("{}: bittree {}\n", output.display(), summary),
        json: summary,
        warnings: Vec::new(),
    })
}

/// The area the BitTree discretizes: the instances' x/y bounds, widened by a millimetre so the
/// maximum lies inside.
fn instance_area(inst: &crate::model::Instances) -> crate::model::Rect {
    let pts: Vec<[f32; 3]> = inst.items.iter().map(|i| i.position).collect();
    let (lo, hi) = crate::model::bounds_of(&pts).unwrap_or(([0.0; 3], [1.0; 3]));
    let pad = 1e-3;
    crate::model::Rect {
        origin: [lo[0] - pad, lo[1] - pad],
        extent: [hi[0] - lo[0] + 2.0 * pad, hi[1] - lo[1] + 2.0 * pad],
    }
}
