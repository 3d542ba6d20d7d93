//! Section-kind invariants for `bake verify`: the arrays each kind of docs/FORMAT.md has, its
//! decoder (which checks lengths against counts and the structure of BitTrees, octrees and
//! N-trees), finite floats, unit vectors, index ranges and the references between sections.

use super::Sink;
use super::container::{Entry, Table};
use crate::pack::section::{ArrayFormat, ArrayInfo, SectionView};
use std::collections::HashMap;

use ArrayFormat::{F16, F32, U8, U16, U32};

/// Arrays a kind may have: name, scalar format(s), components. Decoders say which are required.
type Schema = &'static [(&'static str, &'static [ArrayFormat], u32)];

const MESH: Schema = &[
    ("positions", &[F32], 3),
    ("normals", &[F32], 3),
    ("uvs", &[F32], 2),
    ("indices", &[U32], 3),
    ("triangle_materials", &[U32], 1),
    ("one_sided_materials", &[U32], 1),
    ("skeleton_lines", &[F32], 3),
    ("skeleton_points", &[F32], 3),
];
const TERRAIN: Schema = &[
    ("heights", &[F32], 1),
    ("four_tap", &[F32], 4),
    ("normals", &[U8], 4),
    ("quadtree", &[F32], 2),
    ("quadtree_levels", &[U32], 4),
];
const TEXTURE: Schema = &[
    ("texels", &[U8], 4),
    ("levels", &[U32], 4),
    ("color", &[F16], 4),
    ("coverage", &[F32], 1),
    ("alpha_scale", &[F32], 1),
    ("normal", &[U8], 4),
    ("height", &[F16], 1),
];
const LIGHTMAP: Schema = &[
    ("irradiance", &[F32], 4),
    ("indirect", &[F32], 4),
    ("coverage", &[U8], 1),
    ("tiles", &[F32], 4),
    ("atlas_uv", &[F32], 2),
    ("vertex_source", &[U32], 1),
    ("indices", &[U32], 3),
    ("triangle_chart", &[U32], 1),
    ("charts", &[U32], 4),
    ("lightmap_uv", &[F32], 2),
];
const CLUSTERS: Schema = &[
    ("sample_positions", &[F32], 3),
    ("sample_values", &[F32], 1),
    ("sample_instance", &[U32], 1),
    ("local_basis", &[F32], 1),
    ("local_scale", &[F32], 1),
    ("local_coeffs", &[U8], 1),
    ("neighbours", &[U32], 1),
    ("weights", &[F32], 1),
];
const BITTREE: Schema = &[
    ("bits", &[U8], 1),
    ("scale", &[F32], 1),
    ("rotation", &[U16], 1),
    ("model", &[U16], 1),
    ("layer", &[U16], 1),
    ("residual", &[U16], 2),
    ("shared", &[U32], 1),
];
const SVO: Schema = &[
    ("nodes", &[U32], 4),
    ("leaves", &[U8], 1),
    ("voxel_colors", &[U32], 1),
    ("node_colors", &[U32], 1),
    ("voxel_normals", &[U32], 1),
    ("node_normals", &[U32], 1),
];
const LOD: Schema = &[
    ("positions", &[F32], 3),
    ("vertex_source", &[U32], 1),
    ("indices", &[U32], 3),
    ("triangle_materials", &[U32], 1),
    ("impostor_color", &[U8], 4),
    ("impostor_normal", &[U8], 4),
    ("impostor_depth", &[U8], 1),
    ("skeleton_lines", &[F32], 3),
    ("skeleton_points", &[F32], 3),
];
const LINESPACE: Schema = &[
    ("nodes", &[U32], 2),
    ("linespaces", &[U32], 1),
    ("tri_indices", &[U32], 1),
    ("triangles", &[F32], 9),
];

/// The schema of every kind this bake writes; `None` for an unknown kind.
fn schema(kind: &str) -> Option<Schema> {
    Some(match kind {
        "mesh" => MESH,
        "terrain" => TERRAIN,
        "instances" => &[("instances", &[U32], 8)],
        "texture" => TEXTURE,
        "sky" => &[("texels", &[F32, F16], 4)],
        "sun" => &[],
        "sh" => &[("radiance", &[F32], 3), ("irradiance", &[F32], 3)],
        "material" => &[("params", &[F32], 24)],
        "tangents" => &[("tangents", &[F32], 4)],
        "lightmap" => LIGHTMAP,
        "envmaps" => &[
            ("sky", &[F32], 48),
            ("sun", &[F32], 48),
            ("noise_covariance", &[F32], 96),
            ("noise_variance", &[F32], 1),
        ],
        "clusters" => CLUSTERS,
        "bittree" => BITTREE,
        "prt" => &[("transfer", &[F32], 3), ("gpu", &[F32], 4)],
        "lod" => LOD,
        "svo" => SVO,
        "linespace" => LINESPACE,
        "build" => &[],
        "build_report" => &[("json", &[U8], 1)],
        _ => return None,
    })
}

/// Runs a section through its kind's decoder (which checks lengths against counts and the
/// kind's structure); an unknown kind is an error.
pub fn decode(kind: &str, v: &SectionView) -> Result<(), crate::error::ParseError> {
    match kind {
        "mesh" => crate::mesh::section::from_section(v).map(drop),
        "terrain" if crate::terrain::section::is_prepared(v) => {
            crate::terrain::section::from_section(v).map(drop)
        }
        "terrain" => crate::terrain::source_section::from_section(v).map(drop),
        "instances" => crate::ingest::instances_section::from_section(v).map(drop),
        "texture" => {
            let meta: crate::texture::source_section::TextureMeta = v.meta()?;
            if crate::texture::section::is_processed(&meta.format) {
                crate::texture::section::from_section(v).map(drop)
            } else {
                crate::texture::source_section::from_section(v).map(drop)
            }
        }
        "sky" if crate::sky::source_section::is_cube(v)? => {
            crate::sky::section::cube_from_section(v).map(drop)
        }
        "sky" => crate::sky::source_section::from_section(v).map(drop),
        "sun" => crate::sky::section::sun_from_section(v).map(drop),
        "sh" => crate::sky::section::sh_from_section(v).map(drop),
        "material" => crate::material::section::from_section(v).map(drop),
        "tangents" => crate::mesh::tangents::from_section(v).map(drop),
        "lightmap" if v.info("vertex_source").is_some() => {
            crate::lightmap::atlas_section::from_section(v).map(drop)
        }
        "lightmap" => crate::lightmap::section::from_section(v).map(drop),
        "envmaps" => crate::envmap::section::envmaps_from_section(v).and_then(|(m, _, _)| {
            crate::envmap::section::envmaps_noise_from_section(v, &m).map(drop)
        }),
        "clusters" => crate::envmap::section::clusters_summary(v).map(drop),
        "bittree" => crate::bittree::section::from_section(v).map(drop),
        "prt" => crate::prt::pack::from_section(v).map(drop),
        "lod" => crate::lod::section::from_view(v, None).map(drop),
        "svo" => crate::voxel::section::from_section(v).map(drop),
        "linespace" => crate::linespace::section::from_section(v).map(drop),
        "build" => crate::graph::check_build_section(v),
        "build_report" => crate::report::from_section(v).map(drop),
        other => Err(crate::error::ParseError::new(
            "section kind",
            format!("unknown kind {other:?}"),
        )),
    }
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

    /// Absolute offset of element `k` of an array.
    fn at(&self, a: &ArrayInfo, k: u64) -> u64 {
        self.e.offset + a.offset + k * a.components as u64 * a.format.size() as u64
    }

    fn section(&mut self, facts: &Facts) {
        let Some(schema) = schema(&self.e.kind) else {
            let msg = format!(
                "kind {:?} is not a section kind of docs/FORMAT.md",
                self.e.kind
            );
            self.sink
                .push("kind.unknown", Some(&self.e.name), None, self.e.at, msg);
            return;
        };
        let before = self.sink.violations.len();
        self.check_names();
        self.check_schema(schema);
        if self.sink.violations.len() > before {
            return;
        }
        if let Err(err) = decode(&self.e.kind, self.v) {
            let msg = format!("{}: {}", err.place, err.message);
            self.fail("kind.decode", None, self.e.offset, msg);
            return;
        }
        self.check_floats();
        match self.e.kind.as_str() {
            "mesh" => self.mesh(facts),
            "terrain" => self.terrain(facts),
            "instances" => self.instances(facts),
            "material" => self.material(facts),
            "tangents" => self.tangents(facts),
            "prt" => self.prt(facts),
            "lod" => self.lod(facts),
            "lightmap" => self.lightmap(facts),
            _ => {}
        }
    }

    /// Section names follow the kind: `mesh:…`, `texture:…`, `material:…`, … or the kind itself.
    fn check_names(&mut self) {
        let (kind, name) = (self.e.kind.as_str(), self.e.name.as_str());
        let ok = match kind {
            "mesh" | "texture" | "material" | "tangents" | "prt" | "lod" => name
                .strip_prefix(kind)
                .is_some_and(|r| r.len() > 1 && r.starts_with(':')),
            "lightmap" => name.starts_with("lightmap:"),
            _ => name == kind,
        };
        if !ok {
            let msg = format!(
                "a {kind} section may not be named {name:?} (docs/FORMAT.md, section kinds)"
            );
            self.fail("kind.name", None, self.e.at + 16, msg);
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

    fn f32s<const N: usize>(&self, name: &str) -> Option<(ArrayInfo, Vec<[f32; N]>)> {
        Some((self.v.info(name)?.clone(), self.v.array_vec(name).ok()?))
    }

    fn mesh(&mut self, facts: &Facts) {
        let Ok((meta, _)) = crate::mesh::section::from_section(self.v) else {
            return;
        };
        if let Some((a, normals)) = self.f32s::<3>("normals") {
            self.unit_vectors(&a, normals.iter().map(|n| [n[0], n[1], n[2]]));
        }
        for t in &meta.textures {
            if let Some(s) = &t.section {
                self.reference(facts, "textures[].section", s, "texture");
            }
        }
        for (k, m) in meta.materials.iter().enumerate() {
            let n = meta.textures.len() as u32;
            if m.color_map.is_some_and(|i| i >= n) || m.normal_map.is_some_and(|i| i >= n) {
                let msg = format!("material {k}'s map index is past the {n} textures");
                self.fail("mesh.texture_index", None, self.e.offset, msg);
            }
        }
    }

    /// Lengths within 1e-3 of 1 (normals are stored normalised).
    fn unit_vectors(&mut self, a: &ArrayInfo, vs: impl Iterator<Item = [f32; 3]>) {
        let bad = vs.enumerate().find(|(_, n)| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            (len - 1.0).abs() > 1e-3
        });
        if let Some((k, n)) = bad {
            let at = self.at(a, k as u64);
            let msg = format!("vector {k} {n:?} is not of unit length (tolerance 1e-3)");
            self.fail("vector.unit", Some(&a.name), at, msg);
        }
    }

    fn terrain(&mut self, facts: &Facts) {
        let Ok(meta) = self.v.meta::<crate::terrain::source_section::TerrainMeta>() else {
            return;
        };
        if let Some(s) = &meta.color_section {
            self.reference(facts, "color_section", s, "texture");
        }
    }

    fn instances(&mut self, facts: &Facts) {
        let Ok((meta, _)) = crate::ingest::instances_section::from_section(self.v) else {
            return;
        };
        if meta.mesh_sections.len() != meta.models.len() {
            let msg = format!(
                "{} mesh_sections for {} models",
                meta.mesh_sections.len(),
                meta.models.len()
            );
            self.fail("instances.models", None, self.e.offset, msg);
        }
        for s in &meta.mesh_sections {
            self.reference(facts, "mesh_sections", s, "mesh");
        }
        type Rec = crate::ingest::instances_section::InstanceRecord;
        let (Some(a), Ok(recs)) = (
            self.v.info("instances").cloned(),
            self.v.array_vec::<Rec>("instances"),
        ) else {
            return;
        };
        if let Some(k) = recs.iter().position(|r| r.reserved != 0) {
            let at = self.at(&a, k as u64) + 28;
            self.fail(
                "instances.reserved",
                Some("instances"),
                at,
                format!("record {k}: reserved field is not zero"),
            );
        }
    }

    fn material(&mut self, facts: &Facts) {
        let Ok(meta) = crate::material::section::from_section(self.v) else {
            return;
        };
        self.reference(facts, "mesh_section", &meta.mesh_section, "mesh");
        for m in [&meta.color_map, &meta.normal_map].into_iter().flatten() {
            self.reference(facts, "color_map/normal_map", m, "texture");
        }
    }

    fn tangents(&mut self, facts: &Facts) {
        let Ok((meta, t)) = crate::mesh::tangents::from_section(self.v) else {
            return;
        };
        self.reference(facts, "mesh_section", &meta.mesh_section, "mesh");
        let a = self.v.info("tangents").cloned();
        if let Some(a) = &a {
            self.unit_vectors(a, t.iter().map(|t| [t[0], t[1], t[2]]));
        }
        self.vertex_count(facts, &meta.mesh_section, t.len() as u64, "tangents");
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

    fn prt(&mut self, facts: &Facts) {
        let Ok(meta) = self.v.meta::<crate::prt::pack::PrtMeta>() else {
            return;
        };
        self.reference(facts, "mesh", &meta.mesh, "mesh");
        self.vertex_count(facts, &meta.mesh, meta.vertices as u64, "transfer");
    }

    fn lod(&mut self, facts: &Facts) {
        let Ok(meta) = self.v.meta::<crate::lod::section::LodMeta>() else {
            return;
        };
        self.reference(facts, "mesh_section", &meta.mesh_section, "mesh");
        if let Some(&v) = facts.vertices.get(meta.mesh_section.as_str())
            && v != meta.mesh_vertices as u64
        {
            let msg = format!(
                "stale: baked for {} vertices, but {:?} has {v} (run `bake lod` again)",
                meta.mesh_vertices, meta.mesh_section
            );
            self.fail(
                "reference.vertex_count",
                Some("vertex_source"),
                self.e.offset,
                msg,
            );
        }
    }

    fn lightmap(&mut self, facts: &Facts) {
        let Ok(meta) = self.v.meta::<crate::lightmap::section::LightmapMeta>() else {
            return;
        };
        if meta.surface != "terrain" {
            self.reference(facts, "surface", &meta.surface, "mesh");
        } else {
            self.reference(facts, "surface", "terrain", "terrain");
        }
    }
}
