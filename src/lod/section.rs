//! Kind `lod`, section `lod:<model file name>`: the levels of detail of one mesh section (the
//! same suffix as its `mesh:<model file name>`) and, optionally, its impostor atlas.
//!
//! Levels are stored one after the other in shared arrays: `positions` f32×3 and
//! `vertex_source` u32 per LOD vertex (the mesh vertex whose normal, UV, tangent and PRT transfer
//! the LOD vertex takes), `indices` u32×3 per LOD triangle (into its level's vertex range: index +
//! `first_vertex` is the LOD vertex) and `triangle_materials` u32 (each level's triangles sorted by
//! material, so a renderer draws one range per material: [`LodLevel::ranges`]). Level 0 is the full
//! mesh with error 0. The impostor arrays are `impostor_color`, `impostor_normal` (u8×4) and
//! `impostor_depth` (u8), `grid·tile` texels square, row 0 at the top (docs/FORMAT.md, and the
//! view mapping in docs/CONVENTIONS.md).
//!
//! [`read`] borrows the arrays from the pack after checking every range and index against the
//! arrays and the mesh section (a section baked for another vertex count is stale and rejected).

use crate::error::{Error, ParseError, Result};
use crate::model::Mesh;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Pack, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "lod";
/// [`ImpostorMeta::layout`] of the hemi-octahedral atlas.
pub const HEMI_OCTAHEDRAL: &str = "hemi-octahedral";
/// Largest atlas side a reader accepts (texels).
pub const MAX_ATLAS_SIDE: u64 = 16384;

/// `lod:<model>` for `mesh:<model>` (any other name gets `lod:` in front of it).
pub fn lod_section_name(mesh_section: &str) -> String {
    let model = mesh_section.strip_prefix("mesh:").unwrap_or(mesh_section);
    crate::pack::fit_name(format!("lod:{model}"))
}

/// Metadata of a `lod` section (postcard; fields are only ever added at the end).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LodMeta {
    /// The mesh section the levels simplify.
    pub mesh_section: String,
    /// The mesh's vertex count when baked (readers reject a stale section).
    pub mesh_vertices: u32,
    /// Bounding sphere of the mesh, model units.
    pub centre: [f32; 3],
    pub radius: f32,
    /// Level 0 (the full mesh, error 0) first; errors non-decreasing.
    pub levels: Vec<LodLevel>,
    pub impostor: Option<ImpostorMeta>,
    /// The mesh's triangle and material counts when baked.
    pub mesh_triangles: u32,
    pub materials: u32,
    /// The model's own skeleton (TXF line and point arrays), the farthest representation.
    pub skeleton: Option<SkeletonMeta>,
}

/// Metadata of the skeleton representation (arrays `skeleton_lines`, `skeleton_points`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SkeletonMeta {
    pub segments: u32,
    pub points: u32,
    /// The model's mean albedo, sRGB (A = 255): the colour the segments and points are drawn in.
    pub albedo: [u8; 4],
    /// Drawn where the model's bounding sphere projects to at most this radius in pixels
    /// (`lod::select`, [`crate::lod::select::SKELETON_PIXELS`] by default).
    pub pixels: f32,
}

/// One level: ranges into the section's arrays.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LodLevel {
    pub first_vertex: u32,
    pub vertex_count: u32,
    pub first_triangle: u32,
    pub triangle_count: u32,
    /// Geometric error in model units (an upper bound of the distance from the level's surface
    /// to the full mesh's); 0 for level 0.
    pub error: f32,
    /// One range of the level's triangles per material, in material order
    /// (`first_triangle` counts from the start of the section's triangles).
    pub ranges: Vec<MaterialRange>,
    /// Alpha-tested leaf cards kept in this level (0 where the model has none).
    pub cards: u32,
    /// Alpha-tested area of the level over that of level 0 (1 for level 0; 1 where no
    /// triangle is alpha-tested).
    pub coverage: f32,
}

/// The triangles of one material in one level.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MaterialRange {
    pub material: u32,
    pub first_triangle: u32,
    pub triangle_count: u32,
}

/// Metadata of the impostor atlas.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ImpostorMeta {
    /// [`HEMI_OCTAHEDRAL`].
    pub layout: String,
    /// Views per atlas side (N): the atlas holds N × N tiles.
    pub grid: u32,
    /// Texels per tile side.
    pub tile: u32,
    /// Centre of every view (model units).
    pub centre: [f32; 3],
    /// Half size of each view's square, and the depth range ±radius (model units).
    pub radius: f32,
    /// Geometric error of drawing the impostor instead of the mesh (model units).
    pub error: f32,
}

impl ImpostorMeta {
    /// Atlas side in texels (grid · tile).
    pub fn side(&self) -> u64 {
        self.grid as u64 * self.tile as u64
    }
}

/// The arrays of a section being written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LodArrays {
    pub positions: Vec<[f32; 3]>,
    pub vertex_source: Vec<u32>,
    pub indices: Vec<[u32; 3]>,
    pub triangle_materials: Vec<u32>,
    pub impostor: Option<ImpostorAtlas>,
    /// Segment end points (two per segment) and points of the skeleton, model space.
    pub skeleton_lines: Vec<[f32; 3]>,
    pub skeleton_points: Vec<[f32; 3]>,
}

/// The impostor atlas' texels (side × side each, row 0 at the top).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImpostorAtlas {
    /// sRGB albedo, straight alpha (alpha-tested coverage: 255 covered, 0 empty).
    pub color: Vec<[u8; 4]>,
    /// (n+1)/2 of the model-space unit normal, A = 255 where covered.
    pub normal: Vec<[u8; 4]>,
    /// Offset along the view direction, 0..255 over [−radius, +radius]; 255 where empty.
    pub depth: Vec<u8>,
}

/// A decoded section, its arrays borrowed from the pack.
#[derive(Debug, Clone)]
pub struct LodView<'a> {
    pub meta: LodMeta,
    pub positions: &'a [[f32; 3]],
    pub vertex_source: &'a [u32],
    pub indices: &'a [[u32; 3]],
    pub triangle_materials: &'a [u32],
    pub impostor: Option<ImpostorView<'a>>,
    /// Empty where the meta has no skeleton.
    pub skeleton_lines: &'a [[f32; 3]],
    pub skeleton_points: &'a [[f32; 3]],
}

#[derive(Debug, Clone)]
pub struct ImpostorView<'a> {
    pub color: &'a [[u8; 4]],
    pub normal: &'a [[u8; 4]],
    pub depth: &'a [u8],
}

impl LodView<'_> {
    /// The LOD vertices of level `l` (its indices address this slice).
    pub fn level_positions(&self, l: usize) -> &[[f32; 3]] {
        let v = &self.meta.levels[l];
        &self.positions[v.first_vertex as usize..(v.first_vertex + v.vertex_count) as usize]
    }
    /// The triangles of level `l`, and their materials.
    pub fn level_triangles(&self, l: usize) -> (&[[u32; 3]], &[u32]) {
        let v = &self.meta.levels[l];
        let r = v.first_triangle as usize..(v.first_triangle + v.triangle_count) as usize;
        (&self.indices[r.clone()], &self.triangle_materials[r])
    }
}

/// Encodes a section. `name` is normally [`lod_section_name`] of `meta.mesh_section`.
pub fn to_section(name: &str, meta: &LodMeta, a: &LodArrays) -> Section {
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(meta)
        .array("positions", ArrayFormat::F32, 3, &a.positions)
        .array("vertex_source", ArrayFormat::U32, 1, &a.vertex_source)
        .array("indices", ArrayFormat::U32, 3, &a.indices)
        .array(
            "triangle_materials",
            ArrayFormat::U32,
            1,
            &a.triangle_materials,
        );
    if let Some(i) = &a.impostor {
        b.array("impostor_color", ArrayFormat::U8, 4, &i.color)
            .array("impostor_normal", ArrayFormat::U8, 4, &i.normal)
            .array("impostor_depth", ArrayFormat::U8, 1, &i.depth);
    }
    if meta.skeleton.is_some() {
        b.array("skeleton_lines", ArrayFormat::F32, 3, &a.skeleton_lines)
            .array("skeleton_points", ArrayFormat::F32, 3, &a.skeleton_points);
    }
    b.finish()
}

/// The material ranges of triangles `first..first + mats.len()` sorted by material.
pub fn material_ranges(first: u32, mats: &[u32]) -> Vec<MaterialRange> {
    let mut out: Vec<MaterialRange> = Vec::new();
    for (t, &m) in mats.iter().enumerate() {
        match out.last_mut() {
            Some(r) if r.material == m => r.triangle_count += 1,
            _ => out.push(MaterialRange {
                material: m,
                first_triangle: first + t as u32,
                triangle_count: 1,
            }),
        }
    }
    out
}

/// Bounding sphere of points: the box centre and the largest distance from it.
pub fn bounding_sphere(points: &[[f32; 3]]) -> ([f32; 3], f32) {
    let Some((lo, hi)) = crate::model::bounds_of(points) else {
        return ([0.0; 3], 0.0);
    };
    let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    let r2 = points.iter().fold(0.0f32, |r, p| {
        r.max((0..3).map(|k| (p[k] - c[k]) * (p[k] - c[k])).sum())
    });
    // One ulp-scale margin so that every point tests inside after rounding.
    (c, r2.sqrt() * (1.0 + 1e-6))
}

/// The hand-checkable writer: one level, the full mesh with its triangles stably sorted by
/// material, no impostor. The simplifying stage appends coarser levels to the same layout.
pub fn full_mesh_lod(mesh_section: &str, mesh: &Mesh) -> (LodMeta, LodArrays) {
    let mut order: Vec<usize> = (0..mesh.indices.len()).collect();
    order.sort_by_key(|&t| mesh.triangle_materials[t]);
    let indices: Vec<[u32; 3]> = order.iter().map(|&t| mesh.indices[t]).collect();
    let mats: Vec<u32> = order.iter().map(|&t| mesh.triangle_materials[t]).collect();
    let (centre, radius) = bounding_sphere(&mesh.positions);
    let level = LodLevel {
        first_vertex: 0,
        vertex_count: mesh.positions.len() as u32,
        first_triangle: 0,
        triangle_count: indices.len() as u32,
        error: 0.0,
        ranges: material_ranges(0, &mats),
        cards: 0,
        coverage: 1.0,
    };
    let meta = LodMeta {
        mesh_section: mesh_section.to_string(),
        mesh_vertices: mesh.positions.len() as u32,
        centre,
        radius,
        levels: vec![level],
        impostor: None,
        mesh_triangles: mesh.indices.len() as u32,
        materials: mesh.materials.len() as u32,
        skeleton: None,
    };
    let arrays = LodArrays {
        positions: mesh.positions.clone(),
        vertex_source: (0..mesh.positions.len() as u32).collect(),
        indices,
        triangle_materials: mats,
        impostor: None,
        skeleton_lines: Vec::new(),
        skeleton_points: Vec::new(),
    };
    (meta, arrays)
}

/// Decodes a section and checks it on its own (`mesh_vertices`: the mesh section's current
/// vertex count, when known, to reject a stale section).
pub fn from_view<'a>(
    v: &SectionView<'a>,
    mesh_vertices: Option<u32>,
) -> std::result::Result<LodView<'a>, ParseError> {
    let meta: LodMeta = v.meta()?;
    let impostor = match &meta.impostor {
        None => None,
        Some(_) => Some(ImpostorView {
            color: v.array("impostor_color")?,
            normal: v.array("impostor_normal")?,
            depth: v.array("impostor_depth")?,
        }),
    };
    let (skeleton_lines, skeleton_points): (&[[f32; 3]], &[[f32; 3]]) = match &meta.skeleton {
        None => (&[], &[]),
        Some(_) => (v.array("skeleton_lines")?, v.array("skeleton_points")?),
    };
    let view = LodView {
        positions: v.array("positions")?,
        vertex_source: v.array("vertex_source")?,
        indices: v.array("indices")?,
        triangle_materials: v.array("triangle_materials")?,
        impostor,
        skeleton_lines,
        skeleton_points,
        meta,
    };
    if let Some(n) = mesh_vertices
        && n != view.meta.mesh_vertices
    {
        return Err(ParseError::new(
            "lod metadata",
            format!(
                "stale: baked for {} mesh vertices, the mesh section {:?} has {n}; run `bake lod` again",
                view.meta.mesh_vertices, view.meta.mesh_section
            ),
        ));
    }
    check(&view).map_err(|(place, m)| ParseError::new(place, m))?;
    Ok(view)
}

type Check = std::result::Result<(), (String, String)>;

fn fail(place: impl Into<String>, m: impl Into<String>) -> Check {
    Err((place.into(), m.into()))
}

/// Every invariant of a decoded section (arrays, level ranges, indices, materials, atlas).
pub fn check(v: &LodView) -> Check {
    let m = &v.meta;
    let nv = v.positions.len();
    if v.vertex_source.len() != nv {
        return fail(
            "array \"vertex_source\"",
            format!(
                "{} entries, expected one per LOD vertex ({nv})",
                v.vertex_source.len()
            ),
        );
    }
    if let Some(i) = v.vertex_source.iter().position(|&s| s >= m.mesh_vertices) {
        return fail(
            format!("array \"vertex_source\", element {i}"),
            format!(
                "mesh vertex {} past the mesh's {}",
                v.vertex_source[i], m.mesh_vertices
            ),
        );
    }
    if v.triangle_materials.len() != v.indices.len() {
        return fail(
            "array \"triangle_materials\"",
            format!(
                "{} entries, expected one per triangle ({})",
                v.triangle_materials.len(),
                v.indices.len()
            ),
        );
    }
    if !(m.radius.is_finite() && m.radius >= 0.0) || m.centre.iter().any(|c| !c.is_finite()) {
        return fail("lod metadata", "bounding sphere not finite");
    }
    if let Some(i) = v
        .positions
        .iter()
        .position(|p| p.iter().any(|c| !c.is_finite()))
    {
        return fail(format!("array \"positions\", element {i}"), "not finite");
    }
    check_levels(v)?;
    check_impostor(v)?;
    check_skeleton(v)
}

fn check_levels(v: &LodView) -> Check {
    let m = &v.meta;
    if m.levels.is_empty() {
        return fail(
            "lod metadata",
            "no levels (level 0, the full mesh, is required)",
        );
    }
    let mut prev = 0.0f32;
    for (l, lv) in m.levels.iter().enumerate() {
        let place = format!("level {l}");
        if l == 0 && lv.error != 0.0 {
            return fail(
                place,
                format!("error {}, level 0 must have error 0", lv.error),
            );
        }
        if !(lv.error.is_finite() && lv.error >= prev) {
            return fail(
                place,
                format!(
                    "error {} not finite or below the previous level's {prev}",
                    lv.error
                ),
            );
        }
        prev = lv.error;
        let vend = lv.first_vertex as u64 + lv.vertex_count as u64;
        let tend = lv.first_triangle as u64 + lv.triangle_count as u64;
        if vend > v.positions.len() as u64 || tend > v.indices.len() as u64 {
            return fail(
                place,
                format!(
                    "vertices {}..{vend} or triangles {}..{tend} past the arrays ({} vertices, {} triangles)",
                    lv.first_vertex,
                    lv.first_triangle,
                    v.positions.len(),
                    v.indices.len()
                ),
            );
        }
        let r = lv.first_triangle as usize..tend as usize;
        if let Some(t) = v.indices[r.clone()]
            .iter()
            .position(|t| t.iter().any(|&i| i >= lv.vertex_count))
        {
            return fail(
                format!("{place}, triangle {t}"),
                format!("index past the level's {} vertices", lv.vertex_count),
            );
        }
        let mats = &v.triangle_materials[r];
        if let Some(t) = mats.iter().position(|&x| x >= m.materials) {
            return fail(
                format!("{place}, triangle {t}"),
                format!("material {} past the mesh's {}", mats[t], m.materials),
            );
        }
        if material_ranges(lv.first_triangle, mats) != lv.ranges
            || mats.windows(2).any(|w| w[0] > w[1])
        {
            return fail(
                place,
                "triangles not sorted by material, or ranges that do not match them",
            );
        }
    }
    Ok(())
}

/// The skeleton's arrays against its counts; finite positions, a positive pixel threshold.
fn check_skeleton(v: &LodView) -> Check {
    let Some(sk) = &v.meta.skeleton else {
        return Ok(());
    };
    for (name, len, want) in [
        (
            "skeleton_lines",
            v.skeleton_lines.len(),
            2 * sk.segments as u64,
        ),
        ("skeleton_points", v.skeleton_points.len(), sk.points as u64),
    ] {
        if len as u64 != want {
            return fail(
                format!("array {name:?}"),
                format!("{len} positions, the metadata says {want}"),
            );
        }
    }
    let finite = |p: &[f32; 3]| p.iter().all(|c| c.is_finite());
    if !v.skeleton_lines.iter().chain(v.skeleton_points).all(finite) {
        return fail("skeleton", "a position is not finite");
    }
    if !(sk.pixels.is_finite() && sk.pixels > 0.0) {
        return fail(
            "skeleton metadata",
            format!("pixels {} is not positive", sk.pixels),
        );
    }
    Ok(())
}

fn check_impostor(v: &LodView) -> Check {
    let (Some(im), Some(a)) = (&v.meta.impostor, &v.impostor) else {
        return Ok(());
    };
    let place = "impostor metadata";
    if im.layout != HEMI_OCTAHEDRAL {
        return fail(
            place,
            format!("layout {:?}, expected {HEMI_OCTAHEDRAL:?}", im.layout),
        );
    }
    let side = im.side();
    if im.grid == 0 || im.tile == 0 || side > MAX_ATLAS_SIDE {
        return fail(
            place,
            format!(
                "grid {} × tile {}: expected both ≥ 1 and a side ≤ {MAX_ATLAS_SIDE}",
                im.grid, im.tile
            ),
        );
    }
    if !(im.radius.is_finite() && im.radius > 0.0 && im.error.is_finite() && im.error >= 0.0) {
        return fail(place, "radius or error not finite and positive");
    }
    let n = (side * side) as usize;
    for (name, len) in [
        ("impostor_color", a.color.len()),
        ("impostor_normal", a.normal.len()),
        ("impostor_depth", a.depth.len()),
    ] {
        if len != n {
            return fail(
                format!("array {name:?}"),
                format!("{len} texels, expected {side}×{side} = {n}"),
            );
        }
    }
    Ok(())
}

/// The `lod` section of `mesh_section` in `pack`, checked against the arrays and the mesh
/// section's current vertex count; `None` when the pack has none.
pub fn read<'a>(pack: &'a Pack, mesh_section: &str) -> Result<Option<LodView<'a>>> {
    let name = lod_section_name(mesh_section);
    let Some(e) = pack.find(&name) else {
        return Ok(None);
    };
    let place = |err: ParseError| {
        Error::invalid_at(
            pack.path(),
            format!("section {name:?}, {}", err.place),
            err.message,
        )
    };
    let mesh_vertices = match pack.find(mesh_section) {
        Some(me) => pack.view(me)?.info("positions").map(|a| a.count as u32),
        None => None,
    };
    let v = pack.view(e)?;
    from_view(&v, mesh_vertices).map(Some).map_err(place)
}

pub fn summary(v: &SectionView) -> std::result::Result<Value, ParseError> {
    let view = from_view(v, None)?;
    let m = &view.meta;
    let (dist, imp_dist) = super::select::reference_switch_distances(m, super::select::DEFAULT_TAU);
    let levels: Vec<Value> = m
        .levels
        .iter()
        .zip(&dist)
        .map(|(l, d)| {
            json!({"triangles": l.triangle_count, "vertices": l.vertex_count, "error": l.error,
                "switch_distance": d, "cards": l.cards, "coverage": l.coverage,
                "materials": l.ranges.len()})
        })
        .collect();
    let impostor = m.impostor.as_ref().map(|i| {
        json!({"layout": i.layout, "grid": i.grid, "tile": i.tile, "atlas": [i.side(), i.side()],
            "radius": i.radius, "error": i.error, "switch_distance": imp_dist})
    });
    let skeleton = m.skeleton.as_ref().map(|s| {
        json!({"segments": s.segments, "points": s.points, "albedo": s.albedo,
            "pixels": s.pixels,
            "switch_distance": super::select::skeleton_switch_distance(m.radius, s.pixels, 1.0,
                super::select::reference_k())})
    });
    Ok(
        json!({"mesh_section": m.mesh_section, "mesh_vertices": m.mesh_vertices,
        "centre": m.centre, "radius": m.radius, "levels": levels, "impostor": impostor,
        "skeleton": skeleton,
        "switch_view": {"height": super::select::REFERENCE_HEIGHT,
            "fov_y_deg": super::select::REFERENCE_FOV_Y_DEG, "tau": super::select::DEFAULT_TAU}}),
    )
}

pub fn data(v: &SectionView) -> std::result::Result<Value, ParseError> {
    let view = from_view(v, None)?;
    Ok(
        json!({"positions": view.positions, "vertex_source": view.vertex_source,
        "indices": view.indices, "triangle_materials": view.triangle_materials}),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Material;

    /// Two quads of two materials, the second material's triangles first.
    fn mesh() -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 2.0],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 5],
            uvs: vec![[0.0; 2]; 5],
            indices: vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]],
            triangle_materials: vec![1, 0, 1],
            materials: vec![Material::default(), Material::default()],
            ..Mesh::default()
        }
    }

    fn pack_of(meta: &LodMeta, a: &LodArrays, mesh_vertices: usize) -> Vec<u8> {
        let mut m = mesh();
        m.positions.resize(mesh_vertices, [0.0; 3]);
        m.normals.resize(mesh_vertices, [0.0, 0.0, 1.0]);
        m.uvs.resize(mesh_vertices, [0.0; 2]);
        let mut w = crate::pack::PackWriter::new();
        w.insert(crate::mesh::section::to_section(
            "mesh:t.txf",
            "t.txf",
            &m,
            &[],
        ));
        w.insert(to_section(&lod_section_name("mesh:t.txf"), meta, a));
        w.to_bytes().unwrap()
    }

    #[test]
    fn names_follow_the_mesh_section() {
        assert_eq!(lod_section_name("mesh:Acer_001.txf"), "lod:Acer_001.txf");
        assert_eq!(lod_section_name("other"), "lod:other");
    }

    #[test]
    fn full_mesh_level_by_hand() {
        let (meta, a) = full_mesh_lod("mesh:t.txf", &mesh());
        // Material 0 (triangle 1) first, then material 1 (triangles 0 and 2, in order).
        assert_eq!(a.indices, vec![[0, 2, 3], [0, 1, 2], [0, 1, 4]]);
        assert_eq!(a.triangle_materials, vec![0, 1, 1]);
        assert_eq!(
            meta.levels[0].ranges,
            vec![
                MaterialRange {
                    material: 0,
                    first_triangle: 0,
                    triangle_count: 1
                },
                MaterialRange {
                    material: 1,
                    first_triangle: 1,
                    triangle_count: 2
                },
            ]
        );
        // Box (0,0,0)..(1,1,2): centre (0.5, 0.5, 1), radius sqrt(0.25 + 0.25 + 1).
        assert_eq!(meta.centre, [0.5, 0.5, 1.0]);
        assert!((meta.radius - 1.5f32.sqrt()).abs() < 1e-5);
        assert_eq!(a.vertex_source, vec![0, 1, 2, 3, 4]);
    }

    #[test]
    fn round_trip_through_a_pack() {
        let (mut meta, mut a) = full_mesh_lod("mesh:t.txf", &mesh());
        // A coarser level: one triangle over two of its own vertices plus one moved vertex.
        a.positions
            .extend([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.5, 1.0]]);
        a.vertex_source.extend([0, 1, 4]);
        a.indices.push([0, 1, 2]);
        a.triangle_materials.push(1);
        meta.levels.push(LodLevel {
            first_vertex: 5,
            vertex_count: 3,
            first_triangle: 3,
            triangle_count: 1,
            error: 0.25,
            ranges: material_ranges(3, &[1]),
            cards: 0,
            coverage: 1.0,
        });
        meta.impostor = Some(ImpostorMeta {
            layout: HEMI_OCTAHEDRAL.into(),
            grid: 2,
            tile: 3,
            centre: meta.centre,
            radius: meta.radius,
            error: 0.5,
        });
        a.impostor = Some(ImpostorAtlas {
            color: vec![[1, 2, 3, 255]; 36],
            normal: vec![[128, 128, 255, 255]; 36],
            depth: vec![7; 36],
        });
        let bytes = pack_of(&meta, &a, 5);
        let pack = Pack::from_bytes(&bytes, "t.bake").unwrap();
        let v = read(&pack, "mesh:t.txf").unwrap().unwrap();
        assert_eq!(v.meta, meta);
        assert_eq!(v.positions, &a.positions[..]);
        assert_eq!(v.level_positions(1), &a.positions[5..]);
        assert_eq!(v.level_triangles(1), (&[[0u32, 1, 2]][..], &[1u32][..]));
        assert_eq!(v.impostor.as_ref().unwrap().depth, &[7u8; 36][..]);
        assert!(read(&pack, "mesh:other.txf").unwrap().is_none());
        let s = summary(&pack.view_named("lod:t.txf").unwrap()).unwrap();
        assert_eq!(s["levels"][1]["triangles"], 1);
        assert_eq!(s["impostor"]["atlas"][0], 6);
    }

    /// Every broken invariant is an error that names the section and the place.
    #[test]
    fn rejects_broken_sections_with_the_place() {
        let (meta, a) = full_mesh_lod("mesh:t.txf", &mesh());
        let err_of = |meta: &LodMeta, a: &LodArrays, nv: usize| -> String {
            let bytes = pack_of(meta, a, nv);
            let pack = Pack::from_bytes(&bytes, "t.bake").unwrap();
            read(&pack, "mesh:t.txf").unwrap_err().to_string()
        };
        let e = err_of(&meta, &a, 6);
        assert!(e.contains("lod:t.txf") && e.contains("stale"), "{e}");
        let mut b = a.clone();
        b.vertex_source[2] = 9;
        let e = err_of(&meta, &b, 5);
        assert!(
            e.contains("vertex_source") && e.contains("element 2"),
            "{e}"
        );
        let mut b = a.clone();
        b.indices[1][2] = 5;
        let e = err_of(&meta, &b, 5);
        assert!(e.contains("level 0, triangle 1"), "{e}");
        let mut m = meta.clone();
        m.levels[0].triangle_count = 4;
        let e = err_of(&m, &a, 5);
        assert!(
            e.contains("level 0") && e.contains("past the arrays"),
            "{e}"
        );
        let mut m = meta.clone();
        m.levels[0].error = 0.1;
        assert!(err_of(&m, &a, 5).contains("error 0.1"));
        let mut b = a.clone();
        b.triangle_materials.swap(0, 1);
        assert!(err_of(&meta, &b, 5).contains("not sorted by material"));
        let mut m = meta.clone();
        m.materials = 1;
        assert!(err_of(&m, &a, 5).contains("material 1 past"));
        let mut m = meta.clone();
        m.levels.push(LodLevel {
            error: -1.0,
            ..m.levels[0].clone()
        });
        assert!(err_of(&m, &a, 5).contains("level 1"));
        let mut m = meta.clone();
        m.impostor = Some(ImpostorMeta {
            layout: HEMI_OCTAHEDRAL.into(),
            grid: 2,
            tile: 4,
            radius: 1.0,
            ..ImpostorMeta::default()
        });
        let mut b = a.clone();
        b.impostor = Some(ImpostorAtlas {
            color: vec![[0; 4]; 64],
            normal: vec![[0; 4]; 64],
            depth: vec![0; 63],
        });
        let e = err_of(&m, &b, 5);
        assert!(
            e.contains("impostor_depth") && e.contains("8×8 = 64"),
            "{e}"
        );
        // An impostor promised by the metadata but missing its arrays.
        let e = err_of(&m, &a, 5);
        assert!(e.contains("impostor_color"), "{e}");
    }
}
