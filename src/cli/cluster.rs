//! `bake cluster INPUT`: replaces per-instance environment maps by cluster samples plus
//! multiquadric interpolation (section `clusters`).

use super::{Global, Outcome};
use crate::envmap::cluster::ClusterOptions;
use crate::envmap::section::{self, DIM};
use crate::error::{Error, Result};
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub struct ClusterArgs {
    /// A pack with `instances` and `envmaps` sections.
    pub input: PathBuf,
    /// Output pack (default: the input pack).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Error bound on every instance: RMS error relative to the RMS of all coefficients.
    #[arg(long, default_value_t = 0.02)]
    pub error: f32,
    /// Neighbours per reconstruction (default: chosen by leave-one-out).
    #[arg(long)]
    pub k: Option<usize>,
    /// Multiquadric constant R in metres (default: chosen by leave-one-out).
    #[arg(long)]
    pub radius: Option<f32>,
    /// Also store every instance's neighbours and weights (the runtime need not solve).
    #[arg(long)]
    pub weights: bool,
}

pub fn run(args: &ClusterArgs, _g: &Global) -> Result<Outcome> {
    let (mut w, output) = super::open_or_ingest(&args.input, args.output.clone())?;
    let pack = Pack::open(&args.input)?;
    let bad = |e| Error::invalid(&args.input, e);
    let (_, inst) =
        crate::pack::kinds::instances::from_section(&pack.view_named("instances")?).map_err(bad)?;
    let (_, sky, sun) = section::envmaps_from_section(&pack.view_named("envmaps")?).map_err(bad)?;
    if sky.len() != inst.items.len() {
        return Err(Error::invalid_at(
            &args.input,
            "envmaps",
            "envmaps and instances differ in count",
        ));
    }
    let positions: Vec<[f32; 3]> = inst.items.iter().map(|i| i.position).collect();
    let values = section::flatten(&sky, &sun);
    let opts = ClusterOptions {
        error: args.error,
        k: args.k,
        radius: args.radius,
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let (meta, c, weights) =
        crate::envmap::cluster_and_weigh(&positions, &values, DIM, &opts, args.weights);
    let seconds = start.elapsed().as_secs_f64();
    let wref = weights.as_ref().map(|(n, w)| (n.as_slice(), w.as_slice()));
    w.insert(section::clusters_to_section(
        "clusters", &meta, &c, &positions, &values, wref,
    ));
    let bytes = w.to_bytes()?;
    crate::pack::write_atomic(&output, &bytes)?;
    let out = Pack::from_bytes(&bytes, "out")?;
    let mut doc = section::clusters_summary(&out.view_named("clusters")?)
        .map_err(|e| Error::invalid(&output, e))?;
    doc["seconds"] = seconds.into();
    doc["rounds"] = c.rounds.into();
    Ok(Outcome {
        text: format!("{}: {}\n", output.display(), doc),
        json: doc,
        warnings: Vec::new(),
    })
}
