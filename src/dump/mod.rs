//! `bake dump`: what a pack holds, as text for people or JSON for scripts.
//!
//! Each section is shown through its kind in the registry of section kinds
//! ([`crate::kinds::all`]: the central kinds and each registered stage's): its summary and, with `--full`, its data; kinds without views and
//! unknown kinds are listed with their size, checksum and arrays only.
#![warn(missing_docs)]

pub mod images;

use crate::error::{ParseError, Result};
use crate::pack::Pack;
use serde_json::{Value, json};

/// Options of `bake dump`.
#[derive(Debug, Clone, Default)]
pub struct DumpOptions {
    /// Include each section's `data`.
    pub full: bool,
    /// Only the section with this name.
    pub section: Option<String>,
}

/// The JSON document of `bake dump --json`.
pub fn dump_json(pack: &Pack, opts: &DumpOptions) -> Result<Value> {
    let mut sections = Vec::new();
    let mut found = false;
    for e in pack.sections() {
        if opts.section.as_ref().is_some_and(|s| s != &e.name) {
            continue;
        }
        found = true;
        let checksum_ok = pack.checksum_ok(e);
        let mut obj = json!({
            "name": e.name, "kind": e.kind, "bytes": e.size, "offset": e.offset, "checksum_ok": checksum_ok,
        });
        if checksum_ok {
            let view = pack.view(e)?;
            obj["arrays"] = view
                .arrays
                .iter()
                .map(|a| json!({"name": a.name, "format": a.format.name(), "components": a.components, "count": a.count}))
                .collect();
            if let Some((summary, data)) = crate::kinds::find(&e.kind).and_then(|k| k.views) {
                let place = |err: ParseError| {
                    crate::error::Error::invalid(
                        pack.path(),
                        ParseError::new(
                            format!("section {:?}: {}", e.name, err.place),
                            err.message,
                        ),
                    )
                };
                obj["summary"] = summary(&view).map_err(place)?;
                if opts.full {
                    obj["data"] = data(&view).map_err(place)?;
                }
            } else {
                obj["summary"] = json!({});
            }
        } else {
            obj["summary"] = json!({});
        }
        sections.push(obj);
    }
    if let Some(name) = &opts.section
        && !found
    {
        return Err(crate::error::Error::usage(format!(
            "{}: no section named {name:?}",
            pack.path().display()
        )));
    }
    Ok(
        json!({ "file": pack.path().display().to_string(), "version": pack.version(), "sections": sections }),
    )
}

/// The text view: one block per section.
pub fn dump_text(doc: &Value) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{} (pack format version {})",
        doc["file"].as_str().unwrap_or(""),
        doc["version"]
    );
    for s in doc["sections"].as_array().into_iter().flatten() {
        let ok = if s["checksum_ok"].as_bool() == Some(true) {
            "ok"
        } else {
            "CHECKSUM MISMATCH"
        };
        let _ = writeln!(
            out,
            "\n[{}] {}  {} bytes, checksum {ok}",
            s["kind"].as_str().unwrap_or(""),
            s["name"].as_str().unwrap_or(""),
            s["bytes"]
        );
        if let Some(map) = s["summary"].as_object() {
            for (k, v) in map {
                let _ = writeln!(out, "  {k:<16} {}", compact(v));
            }
        }
        for a in s["arrays"].as_array().into_iter().flatten() {
            let _ = writeln!(
                out,
                "  array {:<16} {} × {}{}",
                a["name"].as_str().unwrap_or(""),
                a["count"],
                a["format"].as_str().unwrap_or(""),
                if a["components"] == 1 {
                    String::new()
                } else {
                    format!("×{}", a["components"])
                }
            );
        }
        if let Some(d) = s.get("data") {
            let _ = writeln!(out, "  data {}", d);
        }
    }
    out
}

fn compact(v: &Value) -> String {
    let s = v.to_string();
    if s.len() > 200 {
        format!("{}…", &s[..s.floor_char_boundary(200)])
    } else {
        s
    }
}
