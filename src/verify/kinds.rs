//! Section-kind invariants for `bake verify`, walking the registry of section kinds
//! ([`crate::kinds::all`]: the central kinds and each registered stage's): each section's name against its kind's naming rule, its arrays
//! against the kind's schema, the kind's decoder (which checks lengths against counts and the
//! structure of BitTrees, octrees and N-trees), finite floats, then the kind's own check (unit
//! vectors, index ranges, reserved fields) and the references it names, resolved here against
//! the whole table.

use super::Sink;
use super::container::{Entry, Table};
use crate::kinds::{Finding, Findings, Schema, SectionKind};
use crate::pack::section::{ArrayFormat, SectionView};
use std::collections::HashMap;

use ArrayFormat::{F16, F32};

/// Runs a section through its kind's decoder (which checks lengths against counts and the
/// kind's structure); an unknown kind is an error.
pub fn decode(kind: &str, v: &SectionView) -> Result<(), crate::error::ParseError> {
    crate::kinds::decode(kind, v)
}

/// Every intact section: schema, decoder, floats, kind-specific invariants, references.
pub fn check_kinds(bytes: &[u8], table: &Table, intact: &[&Entry], sink: &mut Sink) {
    let kinds: HashMap<&str, &str> = table
        .entries
        .iter()
        .map(|e| (e.name.as_str(), e.kind.as_str()))
        .collect();
    let views: Vec<(&Entry, SectionView)> = intact
        .iter()
        .filter_map(|e| {
            let p = &bytes[e.offset as usize..(e.offset + e.size) as usize];
            SectionView::parse(p, e.offset as usize)
                .ok()
                .map(|v| (*e, v))
        })
        .collect();
    let vertices: HashMap<&str, u64> = views
        .iter()
        .filter(|(e, _)| e.kind == "mesh")
        .filter_map(|(e, v)| Some((e.name.as_str(), v.info("positions")?.count)))
        .collect();
    let facts = Facts { kinds, vertices };
    for (e, v) in &views {
        let mut c = Check { e, v, sink };
        c.section(&facts);
    }
}

/// What one section's checks may ask about the others.
struct Facts<'a> {
    /// Kind of every section in the table, by name.
    kinds: HashMap<&'a str, &'a str>,
    /// Vertex count of every intact mesh section.
    vertices: HashMap<&'a str, u64>,
}

struct Check<'a, 'b> {
    e: &'a Entry,
    v: &'a SectionView<'a>,
    sink: &'b mut Sink,
}

impl Check<'_, '_> {
    fn fail(&mut self, check: &'static str, array: Option<&str>, offset: u64, msg: String) {
        self.sink
            .push(check, Some(&self.e.name), array, offset, msg);
    }

    fn section(&mut self, facts: &Facts) {
        let Some(kind) = crate::kinds::find(&self.e.kind) else {
            let msg = format!(
                "kind {:?} is not a section kind of docs/FORMAT.md",
                self.e.kind
            );
            self.sink
                .push("kind.unknown", Some(&self.e.name), None, self.e.at, msg);
            return;
        };
        let before = self.sink.violations.len();
        self.check_names(kind);
        self.check_schema(kind.arrays);
        if self.sink.violations.len() > before {
            return;
        }
        if let Err(err) = (kind.decode)(self.v) {
            let msg = format!("{}: {}", err.place, err.message);
            self.fail("kind.decode", None, self.e.offset, msg);
            return;
        }
        self.check_floats();
        if let Some(check) = kind.check {
            let mut found = Findings::default();
            check(self.v, &mut found);
            for f in found.0 {
                self.finding(facts, f);
            }
        }
    }

    /// Section names follow the kind: `mesh:…`, `texture:…`, `material:…`, … or the kind itself.
    fn check_names(&mut self, kind: &SectionKind) {
        let name = self.e.name.as_str();
        if !kind.naming.accepts(kind.kind, name) {
            let msg = format!(
                "a {} section may not be named {name:?} (docs/FORMAT.md, section kinds)",
                kind.kind
            );
            self.fail("kind.name", None, self.e.at + 16, msg);
        }
    }

    /// One finding of the kind's check: a rule broken, or a reference to resolve.
    fn finding(&mut self, facts: &Facts, f: Finding) {
        match f {
            Finding::Rule {
                check,
                array,
                offset,
                message,
            } => self.fail(check, array.as_deref(), self.e.offset + offset, message),
            Finding::Reference {
                field,
                target,
                kind,
            } => self.reference(facts, field, &target, kind),
            Finding::VertexCount { mesh, count, array } => {
                self.vertex_count(facts, &mesh, count, array)
            }
            Finding::BakedFor { mesh, vertices } => self.baked_for(facts, &mesh, vertices),
        }
    }

    fn check_schema(&mut self, schema: Schema) {
        for a in &self.v.arrays {
            let d = self.e.offset; // directory entries are named by the array
            match schema.iter().find(|(n, _, _)| *n == a.name) {
                None => {
                    let msg = format!("a {} section has no array {:?}", self.e.kind, a.name);
                    self.fail("array.unknown", Some(&a.name), d, msg);
                }
                Some((_, formats, comps))
                    if !formats.contains(&a.format) || *comps != a.components =>
                {
                    let msg = format!(
                        "{}×{}, expected {}×{comps}",
                        a.format.name(),
                        a.components,
                        formats[0].name()
                    );
                    self.fail("array.type", Some(&a.name), d, msg);
                }
                _ => {}
            }
        }
    }

    /// Every f32 and f16 scalar is finite.
    fn check_floats(&mut self) {
        for a in &self.v.arrays {
            let Ok(bytes) = self.v.array_bytes(&a.name) else {
                continue;
            };
            let bad = match a.format {
                F32 => bytes
                    .chunks_exact(4)
                    .position(|c| !f32::from_le_bytes(c.try_into().unwrap_or_default()).is_finite())
                    .map(|k| k * 4),
                F16 => bytes
                    .chunks_exact(2)
                    .position(|c| !half::f16::from_le_bytes([c[0], c[1]]).is_finite())
                    .map(|k| k * 2),
                _ => None,
            };
            if let Some(byte) = bad {
                let at = self.e.offset + a.offset + byte as u64;
                let msg = format!("scalar {} is not finite", byte / a.format.size());
                self.fail("float.finite", Some(&a.name), at, msg);
            }
        }
    }

    /// A reference to another section resolves to a section of the expected kind.
    fn reference(&mut self, facts: &Facts, field: &str, target: &str, kind: &str) {
        match facts.kinds.get(target) {
            Some(k) if *k == kind => {}
            found => {
                let what =
                    found.map_or("no such section".to_string(), |k| format!("a {k} section"));
                let msg = format!("{field} names {target:?}: {what}, a {kind} section expected");
                self.fail("reference.dangling", None, self.e.offset, msg);
            }
        }
    }

    /// An array with one element per vertex of the mesh section it belongs to.
    fn vertex_count(&mut self, facts: &Facts, mesh: &str, n: u64, array: &str) {
        if let Some(&v) = facts.vertices.get(mesh)
            && v != n
        {
            let msg = format!("{n} per-vertex entries, but {mesh:?} has {v} vertices");
            self.fail("reference.vertex_count", Some(array), self.e.offset, msg);
        }
    }

    /// A section baked for a mesh of `baked` vertices (`lod`) is stale when the mesh has others.
    fn baked_for(&mut self, facts: &Facts, mesh: &str, baked: u64) {
        if let Some(&v) = facts.vertices.get(mesh)
            && v != baked
        {
            let msg = format!(
                "stale: baked for {baked} vertices, but {mesh:?} has {v} (run `bake lod` again)"
            );
            self.fail(
                "reference.vertex_count",
                Some("vertex_source"),
                self.e.offset,
                msg,
            );
        }
    }
}
