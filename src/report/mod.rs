//! The record of the bake that wrote a pack, and `bake report`'s page of it.
//!
//! Every `bake SCENE.eco` that writes its pack also writes the build report (`--json`'s object,
//! docs/REPORT.md) beside it as `PACK.report.json`, atomically, after the pack: its
//! `pack_blake3` names the pack bytes it describes, so a report of another bake is recognized
//! as stale. The pack itself stays byte-identical across runs (the report holds wall times);
//! `--embed-report` also stores the report in the pack as a `build_report` section, for users
//! who want one file and can give up that determinism. [`html`] makes the page.
#![warn(missing_docs)]

pub mod html;
pub mod record;

use crate::error::{Error, ParseError, Result};
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Pack, PackWriter, Section, SectionBuilder};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

/// Kind and name of the embedded report's section.
pub const KIND: &str = "build_report";

/// Largest sidecar read (a report of 200,000 instances and 300 models is well under 1 MB).
pub const MAX_SIDECAR_BYTES: u64 = 64 << 20;

/// The sidecar of `pack`: `scene.bake` → `scene.bake.report.json`.
pub fn sidecar_path(pack: &Path) -> PathBuf {
    let mut name = pack.file_name().unwrap_or_default().to_os_string();
    name.push(".report.json");
    pack.with_file_name(name)
}

/// The `build_report` section: the report's JSON text as one u8 array `json`.
pub fn to_section(report: &Value) -> Section {
    let text = serde_json::to_vec(report).unwrap_or_default();
    let mut b = SectionBuilder::new(KIND, KIND);
    b.array("json", ArrayFormat::U8, 1, &text);
    b.finish()
}

/// The report held by a `build_report` section: a JSON object with a `bake.build/` schema.
pub fn from_section(v: &SectionView) -> Result<Value, ParseError> {
    let text = v.array::<u8>("json")?;
    parse(text).map_err(|m| ParseError::new("array \"json\"", m))
}

/// A report's JSON text: an object whose `schema` is `bake.build/N`.
fn parse(text: &[u8]) -> std::result::Result<Value, String> {
    let v: Value = serde_json::from_slice(text).map_err(|e| format!("not JSON: {e}"))?;
    match v.get("schema").and_then(Value::as_str) {
        Some(s) if s.starts_with("bake.build/") => Ok(v),
        Some(s) => Err(format!("schema {s:?}, expected bake.build/N")),
        None => Err("no \"schema\" field: not a build report".into()),
    }
}

/// The `build_report` section's summary for `bake dump`.
pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    let r = from_section(v)?;
    Ok(json!({
        "schema": r["schema"], "wall_seconds": r["wall_seconds"], "cpu_seconds": r["cpu_seconds"],
        "units": r["stages"].as_array().map_or(0, Vec::len),
        "cache_hits": r["cache_hits"], "pack_blake3": r["pack_blake3"],
    }))
}

/// The `build_report` section's data for `bake dump --full`.
pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    from_section(v)
}

/// Writes `report` as the sidecar of its pack (atomically).
pub fn write_sidecar(report: &Value, pack: &Path) -> Result<PathBuf> {
    let path = sidecar_path(pack);
    let mut text = serde_json::to_vec_pretty(report).unwrap_or_default();
    text.push(b'\n');
    crate::pack::write_atomic(&path, &text)?;
    Ok(path)
}

/// Rewrites `pack` (atomically) with `report` as its `build_report` section.
pub fn embed(report: &Value, pack: &Path) -> Result<()> {
    let p = Pack::open(pack)?;
    let mut w = PackWriter::from_pack(&p);
    w.insert(to_section(report));
    w.write(pack)
}

/// Where the report of a pack came from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// The pack's `build_report` section.
    Embedded,
    /// The sidecar file, whose `pack_blake3` matches the pack.
    Sidecar(PathBuf),
}

/// A pack's build report and where it came from.
#[derive(Debug, Clone)]
pub struct Found {
    /// The build report (docs/REPORT.md).
    pub report: Value,
    /// Where it came from.
    pub source: Source,
}

/// The build report of `pack`: its section, else a sidecar that names these bytes. A sidecar
/// of other bytes (the pack was rewritten since) or one that does not parse is left out with a
/// note saying why (the page says it too); no report at all is `Ok(None)`.
///
/// `pack_blake3` is the pack file's hash (hex), which the caller computes once.
pub fn find(pack: &Pack, pack_blake3: &str) -> Result<(Option<Found>, Vec<String>)> {
    if let Some(e) = pack.of_kind(KIND).next() {
        let v = pack.view(e)?;
        let r = from_section(&v).map_err(|err| {
            Error::invalid(
                pack.path(),
                ParseError::new(format!("section {:?}, {}", e.name, err.place), err.message),
            )
        })?;
        return Ok((
            Some(Found {
                report: r,
                source: Source::Embedded,
            }),
            Vec::new(),
        ));
    }
    let path = sidecar_path(pack.path());
    if let Ok(m) = std::fs::metadata(&path)
        && m.len() > MAX_SIDECAR_BYTES
    {
        return Ok((
            None,
            vec![format!(
                "{}: {} bytes, more than a build report's {MAX_SIDECAR_BYTES}: left out",
                path.display(),
                m.len()
            )],
        ));
    }
    let text = match std::fs::read(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Ok((
                None,
                vec![format!(
                    "{}: no build report (the pack was not written by `bake SCENE.eco`, or its report was removed)",
                    path.display()
                )],
            ));
        }
        Err(e) => return Err(Error::io(&path, e)),
    };
    let r = match parse(&text) {
        Ok(r) => r,
        Err(m) => return Ok((None, vec![format!("{}: {m}; left out", path.display())])),
    };
    let want = pack_blake3;
    if r["pack_blake3"].as_str() != Some(want) {
        return Ok((
            None,
            vec![format!(
                "{}: describes other pack bytes (pack_blake3 {}, the pack's is {want}): stale, left out",
                path.display(),
                r["pack_blake3"]
            )],
        ));
    }
    Ok((
        Some(Found {
            report: r,
            source: Source::Sidecar(path),
        }),
        Vec::new(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sidecar_sits_beside_the_pack() {
        assert_eq!(
            sidecar_path(Path::new("out/scene.bake")),
            PathBuf::from("out/scene.bake.report.json")
        );
        assert_eq!(sidecar_path(Path::new("x")), PathBuf::from("x.report.json"));
    }

    #[test]
    fn a_report_section_round_trips_and_other_json_is_refused() {
        let r =
            json!({"schema": "bake.build/1", "stages": [{"stage": "prt"}], "wall_seconds": 1.5});
        let s = to_section(&r);
        let v = SectionView::parse(&s.payload, 0).unwrap();
        assert_eq!(from_section(&v).unwrap(), r);
        for bad in [json!({"schema": "other/1"}), json!([1, 2])] {
            let s = to_section(&bad);
            let v = SectionView::parse(&s.payload, 0).unwrap();
            assert!(from_section(&v).is_err(), "{bad}");
        }
    }
}
