//! `bake lod PACK`: the levels of detail (and impostor atlases) of every mesh of a pack.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::lod::LodOptions;
use crate::pack::Pack;
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LodArgs {
    /// A pack with mesh sections (.bake).
    pub input: PathBuf,
    /// Output pack (default: the input pack itself).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Options of a pipeline preset (default, preview, final, ci) before the flags below.
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Most mesh levels after the full mesh.
    #[arg(long)]
    pub levels: Option<u32>,
    /// First target error, relative to each model's bounding radius.
    #[arg(long)]
    pub base_error: Option<f32>,
    /// Ratio between consecutive target errors.
    #[arg(long)]
    pub ratio: Option<f32>,
    /// Bake the impostor atlas (`--impostor false` to skip it).
    #[arg(long)]
    pub impostor: Option<bool>,
    /// Hemi-octahedral views per atlas side.
    #[arg(long)]
    pub impostor_grid: Option<u32>,
    /// Texels per view side.
    #[arg(long)]
    pub impostor_tile: Option<u32>,
}

/// `bake bench lod PACK`: the options of `bake lod`, nothing is written.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct LodBenchArgs {
    #[command(flatten)]
    pub lod: LodArgs,
}

pub(crate) fn bench(args: &LodBenchArgs, _g: &Global) -> Result<Outcome> {
    let opts = options(&args.lod)?;
    let pack = Pack::open(&args.lod.input)?;
    Ok(crate::bench::lod::bench_lod(&pack, &opts)?.into())
}

fn options(a: &LodArgs) -> Result<LodOptions> {
    let p = crate::graph::preset::Pipeline::preset(&a.preset).ok_or_else(|| {
        Error::usage(format!(
            "--preset {}: expected one of {}",
            a.preset,
            crate::graph::preset::PRESETS.join(", ")
        ))
    })?;
    let d = p.lod;
    let o = LodOptions {
        levels: a.levels.unwrap_or(d.levels),
        base_error: a.base_error.unwrap_or(d.base_error),
        ratio: a.ratio.unwrap_or(d.ratio),
        impostor: a.impostor.unwrap_or(d.impostor),
        impostor_grid: a.impostor_grid.unwrap_or(d.impostor_grid),
        impostor_tile: a.impostor_tile.unwrap_or(d.impostor_tile),
        ..d
    };
    o.check().map_err(Error::usage)?;
    Ok(o)
}

pub(crate) fn run(args: &LodArgs, _g: &Global) -> Result<Outcome> {
    let opts = options(args)?;
    let pack = Pack::open(&args.input)?;
    if pack.of_kind(crate::mesh::section::KIND).next().is_none() {
        return Err(Error::invalid_at(
            &args.input,
            "section table",
            "no mesh section: nothing to build levels of detail for",
        ));
    }
    let t0 = std::time::Instant::now();
    // Every mesh through the registry's `lod` unit (the graph's and `bake unit lod`'s).
    let pipeline = crate::graph::Pipeline {
        lod: opts.clone(),
        ..crate::graph::Pipeline::default()
    };
    let outputs =
        crate::graph::stage::pack_mesh_units("lod", &pack, &args.input, &pipeline, &|_| {})?;
    let mut w = crate::pack::PackWriter::from_pack(&pack);
    let mut reports = Vec::new();
    for o in outputs {
        for s in o.sections {
            w.insert(s);
        }
        reports.push(o.report);
    }
    let seconds = t0.elapsed().as_secs_f64();
    let output = args.output.clone().unwrap_or_else(|| args.input.clone());
    drop(pack); // release the input's memory map before replacing the file
    let bytes = w.to_bytes()?;
    crate::pack::write_atomic(&output, &bytes)?;
    let mut text = String::new();
    for r in &reports {
        let levels = r["levels"].as_array().map_or(&[][..], |l| l.as_slice());
        let tris: Vec<String> = levels.iter().map(|l| l["triangles"].to_string()).collect();
        text.push_str(&format!(
            "{}: {} levels ({} triangles), {} cards{}\n",
            r["section"].as_str().unwrap_or_default(),
            levels.len(),
            tris.join(" / "),
            r["cards"],
            r["impostor_error"]
                .as_f64()
                .map_or(String::new(), |e| format!(", impostor error {e:.3}"))
        ));
    }
    text.push_str(&format!(
        "{}: {} bytes, {} meshes in {seconds:.2} s\n",
        output.display(),
        bytes.len(),
        reports.len()
    ));
    Ok(Outcome {
        json: serde_json::json!({"output": output, "bytes": bytes.len(), "seconds": seconds,
            "options": opts, "meshes": reports}),
        text,
        warnings: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `bake lod` runs the registry's `lod` unit: its sections are the stage function's own,
    /// called directly on the same pack (the oracle), and the rest of the pack is kept.
    #[test]
    fn the_command_writes_what_the_stage_function_computes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("two.bake");
        let mut w = crate::pack::PackWriter::new();
        for (name, hi) in [("a", [2.0, 1.0, 1.0]), ("b", [1.0, 3.0, 2.0])] {
            let mesh = crate::voxel::tests::box_mesh([0.0; 3], hi);
            w.insert(crate::mesh::section::to_section(
                &format!("mesh:{name}"),
                name,
                &mesh,
                &[],
            ));
        }
        w.write(&path).unwrap();
        let args = LodArgs {
            input: path.clone(),
            output: Some(dir.path().join("out.bake")),
            preset: "default".into(),
            levels: None,
            base_error: None,
            ratio: None,
            impostor: Some(false),
            impostor_grid: None,
            impostor_tile: None,
        };
        let out = run(&args, &Global::default()).unwrap();
        assert_eq!(out.json["meshes"].as_array().unwrap().len(), 2);
        let input = Pack::open(&path).unwrap();
        let written = Pack::open(&dir.path().join("out.bake")).unwrap();
        let opts = options(&args).unwrap();
        for m in ["mesh:a", "mesh:b"] {
            let (direct, _) = crate::lod::bake_lod(&input, m, &opts).unwrap();
            let e = written.find(&direct.name).unwrap();
            assert_eq!(written.payload(e), &direct.payload[..], "{m}");
            assert_eq!(
                written.payload(written.find(m).unwrap()),
                input.payload(input.find(m).unwrap())
            );
        }
        assert_eq!(written.sections().len(), 4);
    }
}
