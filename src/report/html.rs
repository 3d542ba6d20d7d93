//! `bake report PACK -o report.html`: one self-contained page (every image a `data:` URI, the
//! timeline inline SVG, no script or style from elsewhere) with
//!
//! 1. a render of the pack's default view, at the page's top-left corner at its own pixel size;
//! 2. the pack: file, bytes, BLAKE3, format version;
//! 3. the bake that wrote it (docs/REPORT.md): wall and CPU seconds, peak memory, cache hits,
//!    warnings, a timeline (one lane per stage, a bar per unit from its `start_seconds` for its
//!    `wall_seconds`, coloured by cache hit or miss) and the stages' totals;
//! 4. every section: kind, name, bytes, checksum, summary (as `bake dump`), arrays;
//! 5. thumbnails of the image-like sections (`bake dump --png`'s PNGs, at most
//!    [`THUMB_SIZE`] pixels on the long side).
//!
//! A load handler counts the images the browser decoded into the `data-images` and
//! `data-decoded` attributes of `<body>` and the page's last line. Pure: strings in, a string out.

use crate::error::{Error, Result};
use base64::Engine;
use serde_json::Value;
use std::fmt::Write;

/// Longest side of a thumbnail, in pixels.
pub const THUMB_SIZE: u32 = 192;

/// One thumbnail: an 8-bit PNG and what it shows.
#[derive(Debug, Clone)]
pub struct Thumb {
    /// Its heading.
    pub title: String,
    /// What it shows.
    pub caption: String,
    /// The PNG file's bytes.
    pub png: Vec<u8>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

/// The render at the top of the page.
#[derive(Debug, Clone)]
pub struct RenderImage {
    /// The PNG file's bytes.
    pub png: Vec<u8>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// What it shows (view, renderer).
    pub caption: String,
}

/// What the page shows.
pub struct Page<'a> {
    /// The pack's path as given.
    pub pack: String,
    /// Bytes of the pack file.
    pub bytes: u64,
    /// BLAKE3 of the pack file (hex).
    pub blake3: String,
    /// `bake dump --json`'s document of the pack.
    pub dump: &'a Value,
    /// The build report and where it came from ("the pack's build_report section", a path).
    pub report: Option<(&'a Value, String)>,
    /// Why something is missing (no report, a stale sidecar, images left out, no render).
    pub notes: &'a [String],
    /// The render at the top, if made.
    pub render: Option<&'a RenderImage>,
    /// The section thumbnails.
    pub thumbs: &'a [Thumb],
}

/// `png` scaled down (box filter) to at most `max` pixels on its long side, as 8-bit RGBA PNG.
pub fn thumbnail(png: &[u8], max: u32) -> Result<Thumb> {
    let img = image::load_from_memory_with_format(png, image::ImageFormat::Png)
        .map_err(|e| Error::runtime(format!("thumbnail: {e}")))?
        .to_rgba8();
    let (w, h) = img.dimensions();
    let s = (max as f32 / w.max(h) as f32).min(1.0);
    let (tw, th) = (
        ((w as f32 * s).round() as u32).max(1),
        ((h as f32 * s).round() as u32).max(1),
    );
    let small = if (tw, th) == (w, h) {
        img
    } else {
        image::imageops::thumbnail(&img, tw, th)
    };
    Ok(Thumb {
        title: String::new(),
        caption: String::new(),
        png: encode_png(&small)?,
        width: tw,
        height: th,
    })
}

fn encode_png(img: &image::RgbaImage) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .map_err(|e| Error::runtime(format!("png: {e}")))?;
    Ok(out)
}

/// Text for HTML element content and attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

fn data_uri(png: &[u8]) -> String {
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

const STYLE: &str = "body{margin:0;font:14px/1.4 system-ui,sans-serif;color:#222;background:#fff}
#render{display:block;margin:0}
main{padding:8px 16px 24px}
h1{font-size:20px;margin:8px 0}h2{font-size:16px;margin:20px 0 8px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ddd;padding:2px 6px;text-align:left;vertical-align:top}
td.n{text-align:right;font-variant-numeric:tabular-nums}code{font-size:12px;word-break:break-all}
.note{color:#a40}.grid{display:flex;flex-wrap:wrap;gap:10px}
figure{margin:0;width:200px}figure img{display:block;border:1px solid #ccc;image-rendering:pixelated;max-width:192px}
figcaption{font-size:11px;word-break:break-all}";

const SCRIPT: &str = "window.addEventListener('load',function(){var a=document.images,n=0;
for(var i=0;i<a.length;i++){if(a[i].complete&&a[i].naturalWidth>0)n++;}
document.body.setAttribute('data-images',a.length);document.body.setAttribute('data-decoded',n);
document.getElementById('decoded').textContent=n+' of '+a.length+' images decoded by this browser.';});";

/// The page.
pub fn page(p: &Page) -> String {
    let mut o = String::new();
    let _ = write!(
        o,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>bake report: {}</title><style>{STYLE}</style><script>{SCRIPT}</script></head><body>\n",
        escape(&p.pack)
    );
    if let Some(r) = p.render {
        let _ = writeln!(
            o,
            "<img id=\"render\" src=\"{}\" width=\"{}\" height=\"{}\" alt=\"render of the default view\" title=\"{}\">",
            data_uri(&r.png),
            r.width,
            r.height,
            escape(&r.caption)
        );
    }
    o.push_str("<main>\n");
    let _ = writeln!(o, "<h1>{}</h1>", escape(&p.pack));
    if let Some(r) = p.render {
        let _ = writeln!(o, "<p>Above: {}</p>", escape(&r.caption));
    }
    let _ = writeln!(
        o,
        "<p>{} bytes, {} sections, pack format version {}, BLAKE3 <code>{}</code></p>",
        p.bytes,
        p.dump["sections"].as_array().map_or(0, Vec::len),
        p.dump["version"],
        escape(&p.blake3)
    );
    for n in p.notes {
        let _ = writeln!(o, "<p class=\"note\">{}</p>", escape(n));
    }
    if let Some((r, from)) = &p.report {
        build_section(&mut o, r, from);
    }
    sections(&mut o, p.dump);
    let _ = writeln!(
        o,
        "<h2>Images ({})</h2>\n<div class=\"grid\">",
        p.thumbs.len()
    );
    for t in p.thumbs {
        let _ = writeln!(
            o,
            "<figure><img src=\"{}\" width=\"{}\" height=\"{}\" alt=\"{}\" title=\"{}\"><figcaption>{}</figcaption></figure>",
            data_uri(&t.png),
            t.width,
            t.height,
            escape(&t.title),
            escape(&t.title),
            escape(&t.caption)
        );
    }
    o.push_str("</div>\n<p id=\"decoded\"></p>\n</main></body></html>\n");
    o
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or(0.0)
}

fn build_section(o: &mut String, r: &Value, from: &str) {
    let _ = writeln!(o, "<h2>The bake that wrote it</h2>");
    let _ = writeln!(
        o,
        "<p>From {}; schema <code>{}</code>. {:.2} s wall, {:.2} s CPU, peak memory {:.1} MiB; {} units, {} from the cache ({}); {} models, {} instances, {} triangles.</p>",
        escape(from),
        escape(r["schema"].as_str().unwrap_or("")),
        num(&r["wall_seconds"]),
        num(&r["cpu_seconds"]),
        num(&r["peak_rss_bytes"]) / (1024.0 * 1024.0),
        r["stages"].as_array().map_or(0, Vec::len),
        r["cache_hits"],
        escape(
            &r["cache"]
                .as_str()
                .map_or("no cache".to_string(), |c| format!("cache {c}"))
        ),
        r["models"],
        r["instances"],
        r["triangles"]
    );
    if let Some(w) = r["warnings"].as_array().filter(|w| !w.is_empty()) {
        let _ = writeln!(o, "<p>{} warnings:</p><ul>", w.len());
        for x in w {
            let _ = writeln!(
                o,
                "<li class=\"note\">{}: {}</li>",
                escape(x["place"].as_str().unwrap_or("")),
                escape(x["message"].as_str().unwrap_or(""))
            );
        }
        o.push_str("</ul>\n");
    }
    let stages = r["stages"].as_array().cloned().unwrap_or_default();
    timeline(o, &stages, num(&r["wall_seconds"]));
    // Per stage: units, hits, wall and CPU seconds.
    let mut order: Vec<String> = Vec::new();
    for s in &stages {
        let name = s["stage"].as_str().unwrap_or("").to_string();
        if !order.contains(&name) {
            order.push(name);
        }
    }
    o.push_str("<table><tr><th>stage</th><th>units</th><th>cache hits</th><th>wall s</th><th>CPU s</th></tr>\n");
    for name in &order {
        let of: Vec<&Value> = stages.iter().filter(|s| s["stage"] == *name).collect();
        let _ = writeln!(
            o,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{:.3}</td><td class=\"n\">{:.3}</td></tr>",
            escape(name),
            of.len(),
            of.iter().filter(|s| s["cache"] == "hit").count(),
            of.iter().map(|s| num(&s["wall_seconds"])).sum::<f64>(),
            of.iter().map(|s| num(&s["cpu_seconds"])).sum::<f64>()
        );
    }
    o.push_str("</table>\n");
}

/// Width of the timeline's plot area, in pixels.
const PLOT: f64 = 800.0;
const LANE: f64 = 18.0;
const LABEL: f64 = 90.0;

/// One lane per stage (in order of first appearance), one bar per unit.
fn timeline(o: &mut String, stages: &[Value], total: f64) {
    let mut lanes: Vec<&str> = Vec::new();
    for s in stages {
        let name = s["stage"].as_str().unwrap_or("");
        if !lanes.contains(&name) {
            lanes.push(name);
        }
    }
    let end = stages
        .iter()
        .map(|s| num(&s["start_seconds"]) + num(&s["wall_seconds"]))
        .fold(total, f64::max)
        .max(1e-6);
    let x = |t: f64| LABEL + t / end * PLOT;
    let height = lanes.len() as f64 * LANE + 24.0;
    let _ = writeln!(
        o,
        "<p>Timeline: a bar per unit, <span style=\"color:#2e7d32\">■</span> from the cache, <span style=\"color:#ef6c00\">■</span> computed, <span style=\"color:#757575\">■</span> without a cache.</p>\n<svg id=\"timeline\" width=\"{}\" height=\"{height}\" role=\"img\" font-size=\"11\">",
        LABEL + PLOT + 20.0
    );
    for (i, lane) in lanes.iter().enumerate() {
        let y = i as f64 * LANE;
        let _ = writeln!(
            o,
            "<text x=\"0\" y=\"{:.1}\">{}</text><line x1=\"{LABEL}\" x2=\"{:.1}\" y1=\"{:.1}\" y2=\"{:.1}\" stroke=\"#eee\"/>",
            y + 13.0,
            escape(lane),
            LABEL + PLOT,
            y + LANE,
            y + LANE
        );
    }
    for s in stages {
        let lane = lanes
            .iter()
            .position(|l| s["stage"].as_str() == Some(*l))
            .unwrap_or(0);
        let (t0, w) = (num(&s["start_seconds"]), num(&s["wall_seconds"]));
        let colour = match s["cache"].as_str() {
            Some("hit") => "#2e7d32",
            Some("miss") => "#ef6c00",
            _ => "#757575",
        };
        let _ = writeln!(
            o,
            "<rect x=\"{:.2}\" y=\"{:.1}\" width=\"{:.2}\" height=\"{:.1}\" fill=\"{colour}\"><title>{} {}: {} at {t0:.3} s for {w:.3} s ({:.3} CPU s)</title></rect>",
            x(t0),
            lane as f64 * LANE + 2.0,
            (w / end * PLOT).max(1.0),
            LANE - 4.0,
            escape(s["stage"].as_str().unwrap_or("")),
            escape(s["unit"].as_str().unwrap_or("")),
            escape(s["cache"].as_str().unwrap_or("")),
            num(&s["cpu_seconds"])
        );
    }
    let axis = lanes.len() as f64 * LANE + 16.0;
    for k in 0..=4 {
        let t = end * k as f64 / 4.0;
        let _ = writeln!(
            o,
            "<text x=\"{:.1}\" y=\"{axis:.1}\" text-anchor=\"{}\">{t:.2} s</text>",
            x(t),
            if k == 4 { "end" } else { "middle" }
        );
    }
    o.push_str("</svg>\n");
}

fn sections(o: &mut String, dump: &Value) {
    let list = dump["sections"].as_array().cloned().unwrap_or_default();
    let _ = writeln!(
        o,
        "<h2>Sections ({})</h2>\n<table id=\"sections\"><tr><th>kind</th><th>name</th><th>bytes</th><th>checksum</th><th>summary</th><th>arrays</th></tr>",
        list.len()
    );
    for s in &list {
        let summary: Vec<String> = s["summary"]
            .as_object()
            .map(|m| {
                m.iter()
                    .map(|(k, v)| {
                        let t = v.to_string();
                        let t = if t.len() > 160 {
                            format!("{}…", &t[..t.floor_char_boundary(160)])
                        } else {
                            t
                        };
                        format!("{k}: {t}")
                    })
                    .collect()
            })
            .unwrap_or_default();
        let arrays: Vec<String> = s["arrays"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|a| {
                format!(
                    "{} {}×{}×{}",
                    a["name"].as_str().unwrap_or(""),
                    a["count"],
                    a["format"].as_str().unwrap_or(""),
                    a["components"]
                )
            })
            .collect();
        let _ = writeln!(
            o,
            "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td>{}</td><td><code>{}</code></td><td>{}</td></tr>",
            escape(s["kind"].as_str().unwrap_or("")),
            escape(s["name"].as_str().unwrap_or("")),
            s["bytes"],
            if s["checksum_ok"] == true {
                "ok"
            } else {
                "MISMATCH"
            },
            summary
                .iter()
                .map(|x| escape(x))
                .collect::<Vec<_>>()
                .join("<br>"),
            arrays
                .iter()
                .map(|x| escape(x))
                .collect::<Vec<_>>()
                .join("<br>")
        );
    }
    o.push_str("</table>\n");
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn text_is_escaped_and_the_page_names_every_section_and_unit() {
        assert_eq!(
            escape("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
        let dump = json!({"version": 2, "sections": [
            {"kind": "mesh", "name": "<evil>.obj", "bytes": 10, "checksum_ok": true, "summary": {"vertices": 3}, "arrays": []},
            {"kind": "sky", "name": "sky", "bytes": 20, "checksum_ok": false, "summary": {}, "arrays": []},
        ]});
        let report = json!({"schema": "bake.build/1", "wall_seconds": 2.0, "stages": [
            {"stage": "prt", "unit": "a.txf", "cache": "miss", "start_seconds": 0.5, "wall_seconds": 1.0},
            {"stage": "prt", "unit": "b.txf", "cache": "hit", "start_seconds": 1.5, "wall_seconds": 0.25},
            {"stage": "sky", "unit": "sky", "cache": "miss", "start_seconds": 0.0, "wall_seconds": 0.5},
        ]});
        let html = page(&Page {
            pack: "s.bake".into(),
            bytes: 30,
            blake3: "ab".into(),
            dump: &dump,
            report: Some((&report, "test".into())),
            notes: &[],
            render: None,
            thumbs: &[],
        });
        assert!(html.contains("&lt;evil&gt;.obj") && !html.contains("<evil>"));
        assert!(html.contains("MISMATCH"));
        assert_eq!(html.matches("<rect ").count(), 3);
        // The prt lane's second bar starts at 1.5/2 of the plot; the sky bar is in lane 1.
        let x = LABEL + 0.75 * PLOT;
        assert!(
            html.contains(&format!("<rect x=\"{x:.2}\" y=\"2.0\"")),
            "{html}"
        );
        assert!(html.contains(&format!("<rect x=\"{LABEL:.2}\" y=\"20.0\"")));
        assert!(!html.contains("http://") && !html.contains("https://"));
    }

    #[test]
    fn thumbnails_keep_the_aspect_and_the_mean_colour() {
        let img = image::RgbaImage::from_fn(400, 100, |x, _| {
            if x % 2 == 0 {
                image::Rgba([200, 0, 0, 255])
            } else {
                image::Rgba([0, 0, 100, 255])
            }
        });
        let t = thumbnail(&encode_png(&img).unwrap(), 100).unwrap();
        assert_eq!((t.width, t.height), (100, 25));
        let back = image::load_from_memory(&t.png).unwrap().to_rgba8();
        assert_eq!(back.dimensions(), (100, 25));
        let mean_r = back.pixels().map(|p| p[0] as f64).sum::<f64>() / 2500.0;
        let mean_b = back.pixels().map(|p| p[2] as f64).sum::<f64>() / 2500.0;
        assert!(
            (mean_r - 100.0).abs() < 3.0 && (mean_b - 50.0).abs() < 3.0,
            "{mean_r} {mean_b}"
        );
    }
}
