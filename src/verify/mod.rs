//! `bake verify`: checks a pack against docs/FORMAT.md without trusting any of it.
//!
//! Three layers, each reporting [`Violation`]s with a stable check id, the section and array
//! concerned and the absolute byte offset of the first bad byte (the KTX `validate` model):
//!
//! 1. the container ([`container`]): magic, format version, header fields, reserved bytes, the
//!    file size, the section table (labels, alignment, bounds, unique names), every BLAKE3
//!    checksum, and the gaps between payloads (zero);
//! 2. each section's payload structure ([`container::check_payload`]): sub-header, array
//!    directory, metadata bounds, array alignment, overlaps, zero padding;
//! 3. each section kind's invariants ([`kinds`]): the arrays a kind has (format, components),
//!    its decoder, index ranges, array lengths against counts, finite floats, unit vectors, SH
//!    shapes, references between sections, BitTree decoding, octree and N-tree structure.
//!
//! A section whose checksum or structure fails is not decoded (its bytes are not what the
//! writer wrote), so one flipped bit gives one violation, not a cascade.
#![warn(missing_docs)]

pub mod container;
pub mod kinds;

use crate::error::{Error, ParseError, Result};
use crate::pack::Pack;
use serde::Serialize;
use std::path::Path;

/// One broken rule.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Violation {
    /// Stable id of the rule, e.g. `header.version`, `table.checksum`, `mesh.index_range`.
    pub check: &'static str,
    /// The section's name, when the rule is about one section.
    pub section: Option<String>,
    /// The array's name, when the rule is about one array.
    pub array: Option<String>,
    /// Absolute file offset of the first byte that breaks the rule.
    pub offset: u64,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(s) = &self.section {
            write!(f, "section {s:?}, ")?;
        }
        if let Some(a) = &self.array {
            write!(f, "array {a:?}, ")?;
        }
        write!(f, "byte {}: {} [{}]", self.offset, self.message, self.check)
    }
}

/// What `verify` found.
#[derive(Debug, Clone, Default, Serialize)]
pub struct VerifyReport {
    /// The format version in the header (when the header could be read).
    pub version: Option<u32>,
    /// File size in bytes.
    pub bytes: u64,
    /// Sections in the table.
    pub sections: usize,
    /// Sections whose kind invariants were checked (checksum and structure intact).
    pub decoded: usize,
    /// Every rule broken, in file order.
    pub violations: Vec<Violation>,
}

impl VerifyReport {
    /// Whether no rule is broken.
    pub fn ok(&self) -> bool {
        self.violations.is_empty()
    }
}

/// Collects violations; `base` is the absolute offset added to payload-relative offsets.
#[derive(Debug, Default)]
pub struct Sink {
    /// The violations pushed.
    pub violations: Vec<Violation>,
}

impl Sink {
    /// Records a broken rule: its id, section, array, payload-relative offset and message.
    pub fn push(
        &mut self,
        check: &'static str,
        section: Option<&str>,
        array: Option<&str>,
        offset: u64,
        message: impl Into<String>,
    ) {
        self.violations.push(Violation {
            check,
            section: section.map(str::to_string),
            array: array.map(str::to_string),
            offset,
            message: message.into(),
        });
    }
}

/// Verifies a whole pack held in memory.
pub fn verify_bytes(bytes: &[u8]) -> VerifyReport {
    let mut sink = Sink::default();
    let mut report = VerifyReport {
        bytes: bytes.len() as u64,
        ..Default::default()
    };
    let Some(table) = container::check_container(bytes, &mut sink) else {
        report.version = container::header_version(bytes);
        report.violations = sink.violations;
        return report;
    };
    report.version = Some(table.version);
    report.sections = table.entries.len();
    let intact: Vec<_> = table
        .entries
        .iter()
        .filter(|e| e.intact)
        .filter(|e| container::check_payload(bytes, e, &mut sink))
        .collect();
    report.decoded = intact.len();
    kinds::check_kinds(bytes, &table, &intact, &mut sink);
    report.violations = sink.violations;
    report
}

/// Verifies a pack file (read whole: verify reads every byte anyway).
pub fn verify_file(path: &Path) -> Result<VerifyReport> {
    let bytes = crate::error::read_file(path)?;
    Ok(verify_bytes(&bytes))
}

/// The error `bake verify` exits with: the first violation, naming the pack.
pub fn first_error(path: &Path, report: &VerifyReport) -> Option<Error> {
    let v = report.violations.first()?;
    let mut place = String::new();
    if let Some(s) = &v.section {
        place.push_str(&format!("section {s:?}, "));
    }
    if let Some(a) = &v.array {
        place.push_str(&format!("array {a:?}, "));
    }
    place.push_str(&format!("byte {}", v.offset));
    let more = match report.violations.len() {
        1 => String::new(),
        n => format!(" (and {} more; --json lists all)", n - 1),
    };
    Some(Error::invalid(
        path,
        ParseError::new(place, format!("{} [{}]{more}", v.message, v.check)),
    ))
}

/// Every section of an opened pack through its kind's decoder (the fuzz target and tests use
/// this to hold `verify` to what the readers accept).
pub fn decode_sections(pack: &Pack) -> Vec<Result<(), ParseError>> {
    pack.sections()
        .iter()
        .map(|e| {
            let view = pack
                .view(e)
                .map_err(|err| ParseError::new("section", err.to_string()))?;
            kinds::decode(&e.kind, &view)
        })
        .collect()
}

#[cfg(test)]
mod tests;
