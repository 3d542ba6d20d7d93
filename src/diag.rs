//! Diagnostics: every warning bake gives, listed once (in [`DIAGNOSTICS`], or beside the stage
//! that gives it, `Stage::diagnostics`; `crate::graph::stage::diagnostics` walks both) with its stable id, its
//! severity and what it means (the model: KTX's `tools/ktx/validation_messages.h`). A warning
//! as raised is a [`Warning`] record: that id, the place (a model, a section, the scene) and the
//! message. `--warnings-as-errors` takes ids from this table; the build report carries them
//! (docs/REPORT.md); docs/DIAGNOSTICS.md lists the table (a test keeps the two equal).
//!
//! Ids are `<stage or command>.<what>` in lower case with dashes. An id, once given, names the
//! same condition for good: a test pins the list, so renaming one fails until the pin (and the
//! docs) change with it.
#![warn(missing_docs)]

use serde::{Deserialize, Serialize};

/// How bad a diagnostic is. Warnings report dropped or repaired data: the command goes on and
/// exits 0 unless `--warnings-as-errors` names them; errors are `crate::error::Error`s with their
/// exit codes, not diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Dropped or repaired data; the command goes on.
    Warning,
}

impl Severity {
    /// Its name in the docs and the report (`warning`).
    pub fn name(self) -> &'static str {
        match self {
            Severity::Warning => "warning",
        }
    }
}

/// One kind of diagnostic: its stable id, severity, and what it means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Diagnostic {
    /// The stable id, `<stage or command>.<what>`.
    pub id: &'static str,
    /// How bad it is.
    pub severity: Severity,
    /// When it is given and what was done instead (one line, for docs/DIAGNOSTICS.md).
    pub meaning: &'static str,
}

impl Diagnostic {
    /// A warning's row: its id and meaning.
    pub const fn warning(id: &'static str, meaning: &'static str) -> Diagnostic {
        Diagnostic {
            id,
            severity: Severity::Warning,
            meaning,
        }
    }
}

const fn warning(id: &'static str, meaning: &'static str) -> Diagnostic {
    Diagnostic::warning(id, meaning)
}

/// `ingest.eco-outside-area`.
pub const INGEST_ECO_OUTSIDE_AREA: Diagnostic = warning(
    "ingest.eco-outside-area",
    "an ECO placement lies outside the area of interest [0,1]²; kept where it is",
);
/// `ingest.reader`.
pub const INGEST_READER: Diagnostic = warning(
    "ingest.reader",
    "a model reader (TXF, 3DS, OBJ, glTF) dropped or repaired data, or a texture of the model did not read; the message names the file and what was done",
);
/// `cache.corrupt-entry`.
pub const CACHE_CORRUPT_ENTRY: Diagnostic = warning(
    "cache.corrupt-entry",
    "a stage-cache entry does not read; the unit is computed again",
);
/// `cache.write-failed`.
pub const CACHE_WRITE_FAILED: Diagnostic = warning(
    "cache.write-failed",
    "a unit's result could not be stored in the stage cache; the bake goes on",
);
/// `render.terrain-too-small`.
pub const RENDER_TERRAIN_TOO_SMALL: Diagnostic = warning(
    "render.terrain-too-small",
    "a terrain of fewer than 2×2 samples; not drawn",
);
/// `render.texture-missing`.
pub const RENDER_TEXTURE_MISSING: Diagnostic = warning(
    "render.texture-missing",
    "a texture section a mesh names is missing; drawn untextured",
);
/// `render.texture-undecoded`.
pub const RENDER_TEXTURE_UNDECODED: Diagnostic = warning(
    "render.texture-undecoded",
    "a texture of a mesh was not decoded into the pack; drawn untextured",
);
/// `render.mesh-missing`.
pub const RENDER_MESH_MISSING: Diagnostic = warning(
    "render.mesh-missing",
    "a model's mesh section is missing; its instances are not drawn",
);
/// `render.material-mismatch`.
pub const RENDER_MATERIAL_MISMATCH: Diagnostic = warning(
    "render.material-mismatch",
    "a material section belongs to another mesh or index; shaded with Lambert",
);
/// `render.normal-map-missing`.
pub const RENDER_NORMAL_MAP_MISSING: Diagnostic = warning(
    "render.normal-map-missing",
    "a normal map section is missing or has no normal array; drawn flat",
);
/// `render.tangents-mismatch`.
pub const RENDER_TANGENTS_MISMATCH: Diagnostic = warning(
    "render.tangents-mismatch",
    "a tangents section does not match its mesh's vertices; tangents made up",
);
/// `render.sky-layout`.
pub const RENDER_SKY_LAYOUT: Diagnostic = warning(
    "render.sky-layout",
    "a sky of a layout the preview does not read; the analytic sky is used",
);
/// `render.prt-mismatch`.
pub const RENDER_PRT_MISMATCH: Diagnostic = warning(
    "render.prt-mismatch",
    "a PRT section does not match its mesh's vertices; not used",
);
/// `render.lightmap-without-indirect`.
pub const RENDER_LIGHTMAP_WITHOUT_INDIRECT: Diagnostic = warning(
    "render.lightmap-without-indirect",
    "a light map without its indirect array (an older pack): the terrain is lit by the sky SH instead, an object's map counts the sun twice",
);
/// `render.atlas-without-uvs`.
pub const RENDER_ATLAS_WITHOUT_UVS: Diagnostic = warning(
    "render.atlas-without-uvs",
    "an object light map without lightmap_uv; not used",
);
/// `render.sh-missing`.
pub const RENDER_SH_MISSING: Diagnostic = warning(
    "render.sh-missing",
    "no sh section; the ambient light is the SH of the whole sky",
);
/// `export.texture-missing`.
pub const EXPORT_TEXTURE_MISSING: Diagnostic = warning(
    "export.texture-missing",
    "a texture section is missing; exported untextured",
);
/// `export.material-missing`.
pub const EXPORT_MATERIAL_MISSING: Diagnostic = warning(
    "export.material-missing",
    "a material has no material section; exported with its diffuse colour",
);
/// `export.terrain-too-small`.
pub const EXPORT_TERRAIN_TOO_SMALL: Diagnostic = warning(
    "export.terrain-too-small",
    "a terrain of fewer than 2×2 samples; not exported",
);
/// `export.mesh-missing`.
pub const EXPORT_MESH_MISSING: Diagnostic = warning(
    "export.mesh-missing",
    "a model's mesh section is missing; not exported",
);
/// `export.model-without-instances`.
pub const EXPORT_MODEL_WITHOUT_INSTANCES: Diagnostic = warning(
    "export.model-without-instances",
    "a model without instances; its mesh is exported without a node",
);
/// `export.no-light-map`.
pub const EXPORT_NO_LIGHT_MAP: Diagnostic = warning(
    "export.no-light-map",
    "`--bake-light` without a terrain light map in the pack; the terrain is exported lit",
);
/// `export.no-prt`.
pub const EXPORT_NO_PRT: Diagnostic = warning(
    "export.no-prt",
    "`--vertex-ambient`: a model without a usable prt section; exported without COLOR_0",
);
/// `mitsuba.sun-in-sky`.
pub const MITSUBA_SUN_IN_SKY: Diagnostic = warning(
    "mitsuba.sun-in-sky",
    "a lat-long sky that still holds its sun: the sun counts twice (run the sky stage)",
);
/// `report.no-render`.
pub const REPORT_NO_RENDER: Diagnostic = warning(
    "report.no-render",
    "`bake report` could not render the pack; the page has no picture",
);
/// `bench.linespace-disagrees`.
pub const BENCH_LINESPACE_DISAGREES: Diagnostic = warning(
    "bench.linespace-disagrees",
    "`bake bench linespace`: the traversals disagree with each other or with obvhs",
);

/// The diagnostics no stage gives (the readers, the cache, the commands), grouped by command;
/// each stage lists its own beside it (`Stage::diagnostics`), and
/// `crate::graph::stage::diagnostics` walks both in the order of docs/DIAGNOSTICS.md.
pub const DIAGNOSTICS: &[Diagnostic] = &[
    INGEST_ECO_OUTSIDE_AREA,
    INGEST_READER,
    CACHE_CORRUPT_ENTRY,
    CACHE_WRITE_FAILED,
    RENDER_TERRAIN_TOO_SMALL,
    RENDER_TEXTURE_MISSING,
    RENDER_TEXTURE_UNDECODED,
    RENDER_MESH_MISSING,
    RENDER_MATERIAL_MISMATCH,
    RENDER_NORMAL_MAP_MISSING,
    RENDER_TANGENTS_MISMATCH,
    RENDER_SKY_LAYOUT,
    RENDER_PRT_MISMATCH,
    RENDER_LIGHTMAP_WITHOUT_INDIRECT,
    RENDER_ATLAS_WITHOUT_UVS,
    RENDER_SH_MISSING,
    EXPORT_TEXTURE_MISSING,
    EXPORT_MATERIAL_MISSING,
    EXPORT_TERRAIN_TOO_SMALL,
    EXPORT_MESH_MISSING,
    EXPORT_MODEL_WITHOUT_INSTANCES,
    EXPORT_NO_LIGHT_MAP,
    EXPORT_NO_PRT,
    MITSUBA_SUN_IN_SKY,
    REPORT_NO_RENDER,
    BENCH_LINESPACE_DISAGREES,
];

/// A warning as raised: its id (from [`DIAGNOSTICS`]), severity, place and message.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Warning {
    /// The diagnostic's id ([`Diagnostic::id`]).
    pub id: String,
    #[serde(default = "default_severity")]
    /// Its severity.
    pub severity: Severity,
    /// Where: a model file, a section, `terrain`, `scene`; empty where the message says it.
    pub place: String,
    /// What happened and what was done instead.
    pub message: String,
}

fn default_severity() -> Severity {
    Severity::Warning
}

impl Warning {
    /// A warning of `d` at `place`.
    pub fn new(d: &Diagnostic, place: impl Into<String>, message: impl Into<String>) -> Warning {
        Warning {
            id: d.id.to_string(),
            severity: d.severity,
            place: place.into(),
            message: message.into(),
        }
    }

    /// The line a person reads on stderr: the message and the id (`--warnings-as-errors=ID`).
    pub fn line(&self) -> String {
        format!("{} [{}]", self.message, self.id)
    }
}

/// `messages` as warnings of `d`, the place left to the caller (the graph fills in the unit).
pub fn tagged(d: &Diagnostic, messages: impl IntoIterator<Item = String>) -> Vec<Warning> {
    messages
        .into_iter()
        .map(|m| Warning::new(d, "", m))
        .collect()
}

/// docs/DIAGNOSTICS.md's table of `diagnostics` (every diagnostic:
/// `crate::graph::stage::diagnostics`), as the test compares it.
pub fn markdown_table<'a>(diagnostics: impl IntoIterator<Item = &'a Diagnostic>) -> String {
    let mut s = String::from("| id | severity | meaning |\n|---|---|---|\n");
    for d in diagnostics {
        s += &format!("| `{}` | {} | {} |\n", d.id, d.severity.name(), d.meaning);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every diagnostic, the central ones and the stages' (through the registry).
    fn all() -> Vec<&'static Diagnostic> {
        crate::graph::stage::diagnostics().collect()
    }

    /// The ids as given. A changed, removed or reordered id fails here: ids are a contract
    /// (scripts match them, `--warnings-as-errors` takes them); change this list only with
    /// docs/DIAGNOSTICS.md and a note why.
    const PINNED: &[&str] = &[
        "ingest.eco-outside-area",
        "ingest.reader",
        "cache.corrupt-entry",
        "cache.write-failed",
        "render.terrain-too-small",
        "render.texture-missing",
        "render.texture-undecoded",
        "render.mesh-missing",
        "render.material-mismatch",
        "render.normal-map-missing",
        "render.tangents-mismatch",
        "render.sky-layout",
        "render.prt-mismatch",
        "render.lightmap-without-indirect",
        "render.atlas-without-uvs",
        "render.sh-missing",
        "export.texture-missing",
        "export.material-missing",
        "export.terrain-too-small",
        "export.mesh-missing",
        "export.model-without-instances",
        "export.no-light-map",
        "export.no-prt",
        "mitsuba.sun-in-sky",
        "report.no-render",
        "bench.linespace-disagrees",
        // The stages' own, in registry order (declared in their folders).
        "material.texture-missing",
        "terrain.none",
        "sky.sun-clipped",
        "sky.radiance-clamped",
        "prt.triangles-non-finite",
        "prt.texture-unreadable",
        "prt.texture-missing",
        "cluster.compression-low",
        "bittree.not-encoded",
        "svo.triangles-without-voxel",
        "svo.mesh-not-closed",
    ];

    #[test]
    fn ids_are_pinned() {
        let ids: Vec<&str> = all().iter().map(|d| d.id).collect();
        assert_eq!(ids, PINNED);
    }

    #[test]
    fn ids_are_unique_and_well_formed() {
        let all = all();
        for (i, d) in all.iter().enumerate() {
            assert!(all[..i].iter().all(|o| o.id != d.id), "{}", d.id);
            let (stage, what) = d.id.split_once('.').expect("<stage>.<what>");
            let ok = |s: &str| {
                !s.is_empty()
                    && s.bytes()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == b'-')
            };
            assert!(ok(stage) && ok(what), "{}", d.id);
            assert!(!d.meaning.is_empty(), "{}", d.id);
        }
    }

    #[test]
    fn docs_list_equals_the_table() {
        let doc = include_str!("../docs/DIAGNOSTICS.md");
        let table = markdown_table(all());
        assert!(
            doc.contains(&table),
            "docs/DIAGNOSTICS.md does not hold the table of diag::DIAGNOSTICS; paste:\n{table}"
        );
        // Nothing listed there that the table lacks (a removed id left in the docs).
        let rows = doc.lines().filter(|l| l.starts_with("| `")).count();
        assert_eq!(rows, all().len());
    }

    #[test]
    fn a_warning_record_reads_without_severity() {
        // Cache entries written before severities existed hold {id, place, message}.
        let w: Warning =
            serde_json::from_str(r#"{"id":"prt.texture-missing","place":"a","message":"m"}"#)
                .unwrap();
        assert_eq!(w.severity, Severity::Warning);
    }
}
