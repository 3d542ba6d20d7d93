//! `bake report PACK -o report.html`: the pack on one self-contained page
//! ([`crate::report::html`]).

use super::{Global, Outcome};
use crate::dump::{DumpOptions, dump_json};
use crate::error::Result;
use crate::pack::Pack;
use crate::report::html::{self, Page, RenderImage, THUMB_SIZE, Thumb};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ReportArgs {
    /// A .bake pack.
    pub pack: PathBuf,
    /// The page to write.
    #[arg(short, long, value_name = "HTML")]
    pub output: PathBuf,
    /// Width of the render of the default view at the top of the page.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Height of that render.
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Leave the render out (no wgpu device is opened).
    #[arg(long)]
    pub no_render: bool,
    /// At most this many thumbnails, in section order (the page says how many were left out).
    #[arg(long, default_value_t = 400)]
    pub max_images: usize,
}

pub(crate) fn run(args: &ReportArgs, _g: &Global) -> Result<Outcome> {
    use rayon::prelude::*;
    let pack = Pack::open(&args.pack)?;
    let dump = dump_json(&pack, &DumpOptions::default())?;
    let blake3 = crate::pack::hex(&crate::pack::hash_file(&args.pack)?);
    let (report, mut notes) = crate::report::find(&pack, &blake3)?;
    let files: Vec<_> = crate::dump::images::section_images(&pack)?
        .into_iter()
        .filter(|f| f.file.ends_with(".png"))
        .collect();
    let shown = files.len().min(args.max_images);
    if shown < files.len() {
        notes.push(format!(
            "{} of {} images shown (--max-images {}); `bake dump {} --png DIR` writes them all",
            shown,
            files.len(),
            args.max_images,
            args.pack.display()
        ));
    }
    let thumbs: Vec<Thumb> = files[..shown]
        .par_iter()
        .map(|f| {
            let mut t = html::thumbnail(&f.bytes, THUMB_SIZE)?;
            t.title = f.file.clone();
            t.caption = format!("{}: {} ({}×{})", f.file, f.what, f.width, f.height);
            Ok(t)
        })
        .collect::<Result<_>>()?;
    let mut warnings = Vec::new();
    let mut render_json = serde_json::Value::Null;
    let render = if args.no_render {
        None
    } else {
        let opts = crate::render::RenderOptions {
            width: args.width,
            height: args.height,
            ..Default::default()
        };
        match crate::render::render_pack(&pack, &opts) {
            Ok(out) => {
                warnings.extend(out.warnings.iter().cloned());
                let s = &out.stats;
                render_json = serde_json::json!({"adapter": out.adapter, "stats": out.stats});
                Some(RenderImage {
                    png: crate::render::encode_png(&out.image)?,
                    width: s.width,
                    height: s.height,
                    caption: format!(
                        "the default view, {}×{} on {}: {} instances of {} models, {} triangles",
                        s.width, s.height, out.adapter, s.instances, s.models, s.triangles
                    ),
                })
            }
            Err(e) => {
                let m = format!("no render: {e}");
                warnings.push(crate::diag::Warning::new(
                    &crate::diag::REPORT_NO_RENDER,
                    "",
                    m.clone(),
                ));
                notes.push(m);
                None
            }
        }
    };
    let bytes = std::fs::metadata(&args.pack)
        .map_err(|e| crate::error::Error::io(&args.pack, e))?
        .len();
    let source = report.as_ref().map(|f| match &f.source {
        crate::report::Source::Embedded => "the pack's build_report section".to_string(),
        crate::report::Source::Sidecar(p) => p.display().to_string(),
    });
    let page = html::page(&Page {
        pack: args.pack.display().to_string(),
        bytes,
        blake3: blake3.clone(),
        dump: &dump,
        report: report
            .as_ref()
            .map(|f| (&f.report, source.clone().unwrap_or_default())),
        notes: &notes,
        render: render.as_ref(),
        thumbs: &thumbs,
    });
    crate::pack::write_atomic(&args.output, page.as_bytes())?;
    let text = format!(
        "{}: {} bytes; {} sections, {} images{}, {}{}\n",
        args.output.display(),
        page.len(),
        dump["sections"].as_array().map_or(0, Vec::len),
        thumbs.len(),
        if render.is_some() {
            " and a render"
        } else {
            ""
        },
        source
            .as_deref()
            .map_or("no build report".to_string(), |s| format!(
                "build report from {s}"
            )),
        notes
            .iter()
            .map(|n| format!("\n  note: {n}"))
            .collect::<String>()
    );
    let json = serde_json::json!({
        "schema": "bake.report/1",
        "output": args.output,
        "bytes": page.len(),
        "pack": args.pack,
        "pack_blake3": blake3,
        "sections": dump["sections"].as_array().map_or(0, Vec::len),
        "images": thumbs.len(),
        "images_left_out": files.len() - shown,
        "build_report": source,
        "render": render_json,
        "notes": notes,
    });
    Ok(Outcome {
        json,
        text,
        warnings,
    })
}
