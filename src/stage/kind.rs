//! A section kind's entry (issue 36, item 2): what `bake dump` and `bake verify` know of a
//! kind ([`SectionKind`]: its naming, arrays, decoder, views and invariants) and what its check
//! records ([`Findings`]). A stage declares the kinds it defines beside itself
//! ([`super::Stage::kinds`]); the kinds no stage defines are listed in `crate::kinds`, and
//! `crate::kinds::all` walks both.

use crate::error::ParseError;
use crate::pack::section::{ArrayFormat, ArrayInfo, SectionView};
use serde_json::Value;

/// A `bake dump` view of a section: its summary or its full data, as JSON.
pub type ViewFn = fn(&SectionView) -> Result<Value, ParseError>;
/// A kind's decoder run for its errors only (lengths against counts, structure).
pub type DecodeFn = fn(&SectionView) -> Result<(), ParseError>;
/// A kind's invariants beyond its decoder, on a section the decoder accepted.
pub type CheckFn = fn(&SectionView, &mut Findings);
/// Arrays a kind may have: name, scalar format(s), components. Decoders say which are required.
pub type Schema = &'static [(&'static str, &'static [ArrayFormat], u32)];

/// How a kind's sections are named (docs/FORMAT.md, the "name" column).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Naming {
    /// The kind itself: `terrain`, `sky`, `instances`.
    Kind,
    /// `<kind>:<something>`, the something not empty: `mesh:plant.txf`.
    Qualified,
    /// Starts with `<kind>:`: `lightmap:terrain`, `lightmap:<mesh section>`.
    Prefixed,
}

impl Naming {
    /// Whether `name` is a valid name of a section of `kind`.
    pub fn accepts(self, kind: &str, name: &str) -> bool {
        match self {
            Naming::Kind => name == kind,
            Naming::Qualified => name
                .strip_prefix(kind)
                .is_some_and(|r| r.len() > 1 && r.starts_with(':')),
            Naming::Prefixed => name.strip_prefix(kind).is_some_and(|r| r.starts_with(':')),
        }
    }
}

/// One kind of section: everything `dump` and `verify` know of it.
#[derive(Debug, Clone, Copy)]
pub struct SectionKind {
    /// The kind label of the section table.
    pub kind: &'static str,
    /// How its sections are named.
    pub naming: Naming,
    /// Every array a section of the kind may have.
    pub arrays: Schema,
    /// Its decoder, run for its errors only.
    pub decode: DecodeFn,
    /// `bake dump`'s summary and full-data views; `None`: listed with its arrays only.
    pub views: Option<(ViewFn, ViewFn)>,
    /// Invariants past the decoder (unit vectors, reserved fields, references to other
    /// sections); `None`: the decoder says it all.
    pub check: Option<CheckFn>,
}

/// One thing a kind's check found, or asks `verify` to look up in the other sections.
#[derive(Debug, Clone, PartialEq)]
pub enum Finding {
    /// A broken rule: check id, array, offset from the payload's start, message.
    Rule {
        /// The rule's stable id.
        check: &'static str,
        /// The array, when the rule is about one.
        array: Option<String>,
        /// Offset of the first offending byte from the payload's start.
        offset: u64,
        /// What is wrong.
        message: String,
    },
    /// `field` names section `target`, which must be of kind `kind`.
    Reference {
        /// The metadata field that names the section.
        field: &'static str,
        /// The section it names.
        target: String,
        /// The kind the named section must have.
        kind: &'static str,
    },
    /// `array` has `count` entries per vertex of mesh section `mesh`.
    VertexCount {
        /// The mesh section.
        mesh: String,
        /// Entries per vertex.
        count: u64,
        /// The array.
        array: &'static str,
    },
    /// A section baked for a mesh of `vertices` vertices (`lod`): stale when the mesh differs.
    BakedFor {
        /// The mesh section.
        mesh: String,
        /// Its vertex count when the section was baked.
        vertices: u64,
    },
}

/// What a kind's check found in one section, in order.
#[derive(Debug, Default)]
pub struct Findings(pub Vec<Finding>);

impl Findings {
    /// Records a broken rule.
    pub fn rule(&mut self, check: &'static str, array: Option<&str>, offset: u64, message: String) {
        self.0.push(Finding::Rule {
            check,
            array: array.map(str::to_string),
            offset,
            message,
        });
    }

    /// Records a reference to another section, which `verify` resolves.
    pub fn reference(&mut self, field: &'static str, target: &str, kind: &'static str) {
        self.0.push(Finding::Reference {
            field,
            target: target.to_string(),
            kind,
        });
    }

    /// Lengths within 1e-3 of 1 (normals are stored normalised).
    pub fn unit_vectors(&mut self, a: &ArrayInfo, vs: impl Iterator<Item = [f32; 3]>) {
        let bad = vs.enumerate().find(|(_, n)| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            (len - 1.0).abs() > 1e-3
        });
        if let Some((k, n)) = bad {
            let msg = format!("vector {k} {n:?} is not of unit length (tolerance 1e-3)");
            self.rule("vector.unit", Some(&a.name), at(a, k as u64), msg);
        }
    }
}

/// Offset of element `k` of an array from the payload's start.
pub fn at(a: &ArrayInfo, k: u64) -> u64 {
    a.offset + k * a.components as u64 * a.format.size() as u64
}

/// The array `name` of `v` as `N`-vectors with its info, if it decodes.
pub fn f32s<const N: usize>(v: &SectionView, name: &str) -> Option<(ArrayInfo, Vec<[f32; N]>)> {
    Some((v.info(name)?.clone(), v.array_vec(name).ok()?))
}
