//! The in-memory model every reader fills and every stage reads.
//!
//! Conventions (docs/CONVENTIONS.md): right-handed, Z up, metres; colours linear Rec. 709 unless a
//! field says otherwise; texture coordinates with v = 0 at the top row of the image (OpenGL
//! readers flip on ingest, see each reader).

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where a material came from; kept so the material stage can tell a default OpenGL material
/// from an authored one and map glTF metallic-roughness separately.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub enum MaterialSource {
    /// OpenGL fixed-function parameters (TXF `<Colors>`, 3DS materials, OBJ/MTL).
    #[default]
    FixedFunction,
    /// glTF 2.0 metallic-roughness.
    MetallicRoughness { metallic: f32, roughness: f32 },
}

/// A material as the input described it (OpenGL parameters), before conversion to the
/// two-layer Schlick material.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Material {
    pub name: String,
    /// RGBA, as written in the input (for TXF/3DS/MTL these are display values, 0..1).
    pub diffuse: [f32; 4],
    pub ambient: [f32; 4],
    pub specular: [f32; 4],
    pub emission: [f32; 4],
    /// OpenGL shininess exponent (0..128).
    pub shininess: f32,
    /// 0 = opaque, 1 = fully transparent (3DS 0xA050, MTL `d` inverted).
    pub transparency: f32,
    /// Translucence from the TXF set header, if any.
    pub translucence: Option<f32>,
    /// Index into [`Mesh::textures`] of the colour map.
    pub color_map: Option<u32>,
    /// Index into [`Mesh::textures`] of a normal map, if the input had one.
    pub normal_map: Option<u32>,
    pub source: MaterialSource,
    /// Whether both faces of the surface are seen (glTF `doubleSided`; true for every other
    /// input: TXF leaves are seen from both sides, OBJ/MTL and 3DS carry no reliable flag).
    /// A one-sided (opaque, closed) surface is only ever seen from the front: the PRT stage
    /// skips its back side under `prt.sides = "auto"`. Not in the serde form (the mesh
    /// section's postcard metadata is unchanged): the mesh section stores the one-sided
    /// materials in its own array, `one_sided_materials`.
    #[serde(skip, default = "double_sided_default")]
    pub double_sided: bool,
}

fn double_sided_default() -> bool {
    true
}

impl Default for Material {
    /// The OpenGL default material (glMaterial defaults).
    fn default() -> Self {
        Material {
            name: String::new(),
            diffuse: [0.8, 0.8, 0.8, 1.0],
            ambient: [0.2, 0.2, 0.2, 1.0],
            specular: [0.0, 0.0, 0.0, 1.0],
            emission: [0.0, 0.0, 0.0, 1.0],
            shininess: 0.0,
            transparency: 0.0,
            translucence: None,
            color_map: None,
            normal_map: None,
            source: MaterialSource::FixedFunction,
            double_sided: true,
        }
    }
}

/// A texture the mesh refers to: the name as written and the path it resolved to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TextureRef {
    /// The name as written in the input file.
    pub name: String,
    /// The resolved path (relative names are resolved against the referring file's folder).
    pub path: PathBuf,
}

/// An indexed triangle mesh in model space with per-triangle materials.
///
/// All vertex arrays have the same length. `normals` and `uvs` are always present: readers
/// fill missing normals with face normals and missing UVs with zeros (and say so in `warnings`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    /// One entry per triangle, index into `materials`.
    pub triangle_materials: Vec<u32>,
    pub materials: Vec<Material>,
    pub textures: Vec<TextureRef>,
    /// Names of the objects the mesh was merged from (3DS objects, glTF nodes...).
    pub objects: Vec<String>,
    /// What the reader dropped or repaired (counted, reported by the CLI).
    pub warnings: Vec<String>,
    /// The model's own far representations where its format has them (TXF's line and point
    /// arrays), model space; empty otherwise.
    pub skeleton: Skeleton,
}

/// Xfrog's LOD representations of a plant (TXF `<line_array>`, `<point_array>`): line segments
/// (the branch skeleton) and points, in model space. The `lod` stage keeps them as the farthest
/// representations (docs/CONVENTIONS.md "Skeletons").
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Skeleton {
    /// Segments, two end points each.
    pub lines: Vec<[[f32; 3]; 2]>,
    pub points: Vec<[f32; 3]>,
}

impl Skeleton {
    pub fn is_empty(&self) -> bool {
        self.lines.is_empty() && self.points.is_empty()
    }
}

impl Mesh {
    /// The corner positions of every triangle, in index order.
    pub fn triangle_positions(&self) -> Vec<[[f32; 3]; 3]> {
        self.indices
            .iter()
            .map(|t| t.map(|i| self.positions[i as usize]))
            .collect()
    }

    /// Axis-aligned bounds of the positions, or `None` for an empty mesh.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        bounds_of(&self.positions)
    }

    /// Appends `other`, offsetting its indices, materials and textures.
    pub fn append(&mut self, other: Mesh) {
        let v0 = self.positions.len() as u32;
        let m0 = self.materials.len() as u32;
        let t0 = self.textures.len() as u32;
        self.positions.extend(other.positions);
        self.normals.extend(other.normals);
        self.uvs.extend(other.uvs);
        self.indices.extend(
            other
                .indices
                .iter()
                .map(|t| [t[0] + v0, t[1] + v0, t[2] + v0]),
        );
        self.triangle_materials
            .extend(other.triangle_materials.iter().map(|m| m + m0));
        self.materials
            .extend(other.materials.into_iter().map(|mut m| {
                m.color_map = m.color_map.map(|i| i + t0);
                m.normal_map = m.normal_map.map(|i| i + t0);
                m
            }));
        self.textures.extend(other.textures);
        self.objects.extend(other.objects);
        self.warnings.extend(other.warnings);
        self.skeleton.lines.extend(other.skeleton.lines);
        self.skeleton.points.extend(other.skeleton.points);
    }

    /// Checks the structural invariants every stage relies on.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.positions.len();
        if self.normals.len() != n || self.uvs.len() != n {
            return Err(format!(
                "vertex arrays differ in length: {} positions, {} normals, {} uvs",
                n,
                self.normals.len(),
                self.uvs.len()
            ));
        }
        if self.triangle_materials.len() != self.indices.len() {
            return Err("triangle_materials and indices differ in length".into());
        }
        for (t, tri) in self.indices.iter().enumerate() {
            if tri.iter().any(|&i| i as usize >= n) {
                return Err(format!("triangle {t} refers to a vertex past {n}"));
            }
        }
        if let Some(m) = self
            .triangle_materials
            .iter()
            .find(|&&m| m as usize >= self.materials.len())
        {
            return Err(format!("material index {m} past {}", self.materials.len()));
        }
        Ok(())
    }
}

/// Bounds of a point set.
pub fn bounds_of(points: &[[f32; 3]]) -> Option<([f32; 3], [f32; 3])> {
    let first = *points.first()?;
    Some(points.iter().fold((first, first), |(mut lo, mut hi), p| {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
        (lo, hi)
    }))
}

/// An 8-bit RGBA image as decoded from a file (values as stored: usually sRGB-encoded).
#[derive(Debug, Clone, PartialEq)]
pub struct Rgba8Image {
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 at the top.
    pub pixels: Vec<[u8; 4]>,
}

/// A linear float RGB image (HDR skies).
#[derive(Debug, Clone, PartialEq)]
pub struct FloatImage {
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 at the top, linear RGB radiance.
    pub pixels: Vec<[f32; 3]>,
}

/// A height-map terrain (RAW).
///
/// Samples are corner-aligned: sample (i, j) lies at x = origin.x + i·extent.x/(width−1),
/// y = origin.y + j·extent.y/(height−1); row 0 is the southern edge (y = origin.y).
#[derive(Debug, Clone, PartialEq)]
pub struct Terrain {
    pub width: u32,
    pub height: u32,
    /// Heights in metres, row-major, row 0 south.
    pub heights: Vec<f32>,
    pub origin: [f32; 2],
    pub extent: [f32; 2],
    /// The colour map, row 0 at the top (north), as an image file stores it.
    pub color: Option<Rgba8Image>,
}

/// The grid cell holding world (x, y) of a height grid of `width × height` samples (row-major,
/// row 0 at `origin[1]`) spanning `extent`, clamped to the grid's edge: its corner heights
/// `[h(i, j), h(i+1, j), h(i, j+1), h(i+1, j+1)]` and the position (tx, ty) in [0, 1]² within it.
fn grid_cell(
    heights: &[f32],
    (width, height): (u32, u32),
    origin: [f32; 2],
    extent: [f32; 2],
    x: f32,
    y: f32,
) -> ([f32; 4], f32, f32) {
    let w = width.max(1);
    let h = height.max(1);
    let grid = |v: f32, o: f32, e: f32, n: u32| {
        if n > 1 {
            ((v - o) / e * (n - 1) as f32).clamp(0.0, (n - 1) as f32)
        } else {
            0.0
        }
    };
    let fx = grid(x, origin[0], extent[0], w);
    let fy = grid(y, origin[1], extent[1], h);
    // fx, fy ≥ 0 (or NaN, which both give 0): truncation is the floor, without a libm call.
    let i0 = (fx as u32).min(w.saturating_sub(2));
    let j0 = (fy as u32).min(h.saturating_sub(2));
    let i1 = (i0 + 1).min(w - 1);
    let j1 = (j0 + 1).min(h - 1);
    let at = |i: u32, j: u32| heights[(j * width + i) as usize];
    (
        [at(i0, j0), at(i1, j0), at(i0, j1), at(i1, j1)],
        fx - i0 as f32,
        fy - j0 as f32,
    )
}

/// Bilinear height at world (x, y) of a height grid of `width × height` samples (row-major,
/// row 0 at `origin[1]`) spanning `extent`, clamped to the grid's edge ([`Terrain::height_at`]).
pub fn bilinear_height(
    heights: &[f32],
    size: (u32, u32),
    origin: [f32; 2],
    extent: [f32; 2],
    x: f32,
    y: f32,
) -> f32 {
    let ([h00, h10, h01, h11], tx, ty) = grid_cell(heights, size, origin, extent, x, y);
    let a = h00 * (1.0 - tx) + h10 * tx;
    let b = h01 * (1.0 - tx) + h11 * tx;
    a * (1.0 - ty) + b * ty
}

/// Height at world (x, y) on the drawn and traced terrain surface: two triangles per grid cell,
/// split along the diagonal from sample (i, j) to (i + 1, j + 1) (`trace::heightfield`,
/// `render::terrain_lod`), clamped to the terrain's edge. It differs from [`bilinear_height`]
/// inside a cell by up to a quarter of the cell's twist `|h00 − h10 − h01 + h11|`; a point at the
/// bilinear height of a concave cell lies below the triangles.
pub fn mesh_height(
    heights: &[f32],
    size: (u32, u32),
    origin: [f32; 2],
    extent: [f32; 2],
    x: f32,
    y: f32,
) -> f32 {
    let ([h00, h10, h01, h11], tx, ty) = grid_cell(heights, size, origin, extent, x, y);
    if tx >= ty {
        // Triangle (i, j) (i+1, j) (i+1, j+1).
        h00 + tx * (h10 - h00) + ty * (h11 - h10)
    } else {
        // Triangle (i, j) (i+1, j+1) (i, j+1).
        h00 + ty * (h01 - h00) + tx * (h11 - h01)
    }
}

impl Terrain {
    /// Height at world (x, y) on the two-triangle surface that is drawn and traced
    /// ([`mesh_height`]).
    pub fn mesh_height_at(&self, x: f32, y: f32) -> f32 {
        mesh_height(
            &self.heights,
            (self.width, self.height),
            self.origin,
            self.extent,
            x,
            y,
        )
    }

    /// Height at grid sample (i, j).
    pub fn sample(&self, i: u32, j: u32) -> f32 {
        self.heights[(j * self.width + i) as usize]
    }

    /// Bilinear height at world (x, y), clamped to the terrain's edge.
    pub fn height_at(&self, x: f32, y: f32) -> f32 {
        bilinear_height(
            &self.heights,
            (self.width, self.height),
            self.origin,
            self.extent,
            x,
            y,
        )
    }

    /// World position of grid sample (i, j).
    pub fn position(&self, i: u32, j: u32) -> [f32; 3] {
        let sx = if self.width > 1 {
            self.extent[0] / (self.width - 1) as f32
        } else {
            0.0
        };
        let sy = if self.height > 1 {
            self.extent[1] / (self.height - 1) as f32
        } else {
            0.0
        };
        [
            self.origin[0] + i as f32 * sx,
            self.origin[1] + j as f32 * sy,
            self.sample(i, j),
        ]
    }

    /// (min, max) height.
    pub fn height_range(&self) -> (f32, f32) {
        self.heights
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &h| {
                (lo.min(h), hi.max(h))
            })
    }
}

/// One placed model of a scene.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Instance {
    /// Index into [`Instances::models`].
    pub model: u32,
    /// World position (x, y on the AoI, z on the terrain).
    pub position: [f32; 3],
    pub scale: f32,
    /// Rotation about +Z in degrees.
    pub rotation_deg: f32,
    pub layer: i32,
}

impl Instance {
    /// A model placed at `position`, scaled, turned about +Z, on layer 0.
    pub fn new(model: u32, position: [f32; 3], scale: f32, rotation_deg: f32) -> Instance {
        Instance {
            model,
            position,
            scale,
            rotation_deg,
            layer: 0,
        }
    }
}

/// The instances of a scene and the model names they refer to.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Instances {
    /// Model names as resolved (file names relative to the model search path).
    pub models: Vec<String>,
    pub items: Vec<Instance>,
}

/// A rectangle in world x/y: origin and extent in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Rect {
    pub origin: [f32; 2],
    pub extent: [f32; 2],
}

/// A loaded model: its name in the scene and its mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub name: String,
    pub path: PathBuf,
    pub mesh: Mesh,
}

/// A whole scene: terrain, models, instances and sky.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Scene {
    pub terrain: Option<Terrain>,
    pub models: Vec<Model>,
    pub instances: Instances,
    /// Area of interest from GEOREF.
    pub aoi: Rect,
    pub sky: Option<FloatImage>,
    /// Warnings collected while reading (dropped data, clamped values).
    pub warnings: Vec<String>,
}
