//! What the renderer draws, read from a pack on the CPU and checked before anything touches the
//! GPU: the terrain (heights and colour map), every model with its materials and instances, and
//! the sky. Arrays are borrowed from the pack (memory map) so they go to GPU buffers unchanged.

use super::light;
use crate::error::{Error, Result};
use crate::ingest::instances_section as instances;
use crate::ingest::instances_section::{InstanceRecord, InstancesMeta};
use crate::mesh::section as mesh;
use crate::mesh::section::MeshMeta;
use crate::pack::Pack;
use crate::sky::source_section as sky;
use crate::sky::source_section::SkyMeta;
use crate::terrain::source_section as terrain;
use crate::terrain::source_section::TerrainMeta;
use crate::texture::source_section::TextureMeta;
use std::borrow::Cow;

/// Size of the analytic sky used when the pack has none.
pub const ANALYTIC_SKY_SIZE: (u32, u32) = (128, 64);

/// An RGBA8 image borrowed from a texture section (sRGB-encoded, row 0 at the top).
#[derive(Debug, Clone, Copy)]
pub struct ImageData<'a> {
    pub width: u32,
    pub height: u32,
    pub texels: &'a [[u8; 4]],
}

/// The terrain grid: heights row-major, row 0 south (corner-aligned samples).
#[derive(Debug, Clone)]
pub struct TerrainData<'a> {
    pub meta: TerrainMeta,
    pub heights: &'a [f32],
    pub min_height: f32,
    pub max_height: f32,
    /// Colour map, row 0 north.
    pub color: Option<ImageData<'a>>,
    /// World-space normal map, one texel per grid sample, row 0 south, `(n + 1)/2` in RGB: the
    /// prepared section's `normals` array, or computed here for an unprepared terrain.
    pub normals: Cow<'a, [[u8; 4]]>,
    /// The chunked LOD grid, from the prepared section's min/max quadtree (built here from the
    /// heights for an unprepared terrain: one O(samples) pass).
    pub chunks: super::terrain_lod::ChunkGrid,
}

/// One material as the preview shades it.
#[derive(Debug, Clone)]
pub struct MaterialData<'a> {
    /// Linear RGB ([`crate::material::convert::diffuse_albedo`]), alpha 1.
    pub base_color: [f32; 4],
    pub color_map: Option<ImageData<'a>>,
    /// The colour map's mip chain where the material stage processed it: drawn trilinear in
    /// place of `color_map` (whose alpha test the CPU reference's rays keep).
    pub color_mips: Option<ColorMips<'a>>,
    /// The two-layer Schlick material of the `material:<model>/<i>` section; `None`: Lambert.
    pub schlick: Option<crate::material::schlick::SchlickMaterial>,
    /// The tangent-space normal map's mip chain (`normal` array of the processed texture):
    /// `(n + 1)/2` in RGB, the filtered normal's length |n̄| in alpha (the Toksvig input).
    pub normal_map: Option<NormalMips<'a>>,
    /// The colour map's mean-colour height chain (half floats in [0, 1], the colour chain's
    /// level table): parallax mapping's input.
    pub height_mips: Option<HeightMips<'a>>,
}

impl MaterialData<'_> {
    /// True where the alpha test at 0.5 cuts the surface: some texel of the colour map's level
    /// 0 has alpha × opacity below 0.5 (a leaf card). The region pass (`bake render
    /// --regions`) counts such surfaces as leaves, and `bake mitsuba` gives them an opacity mask.
    pub fn alpha_tested(&self) -> bool {
        let opacity = self.schlick.as_ref().map_or(1.0, |m| m.opacity);
        if opacity < 0.5 {
            return true;
        }
        match (&self.color_mips, &self.color_map) {
            (Some(mips), _) => {
                let [w, h, _, _] = mips.levels[0];
                (0..h).any(|j| (0..w).any(|i| mips.texel(0, i, j)[3] * opacity < 0.5))
            }
            (None, Some(img)) => img
                .texels
                .iter()
                .any(|t| t[3] as f32 / 255.0 * opacity < 0.5),
            (None, None) => false,
        }
    }
}

impl ModelData<'_> {
    /// True where one of the model's materials is [`MaterialData::alpha_tested`].
    pub fn has_leaves(&self) -> bool {
        self.materials.iter().any(|m| m.alpha_tested())
    }
}

/// A processed texture's mip chain (docs/FORMAT.md, `texture` processed by `bake material`):
/// level 0 first, each level's (width, height, first texel, texel count) and the concatenated
/// texels.
#[derive(Debug, Clone)]
pub struct Mips<'a, T> {
    pub levels: Vec<[u32; 4]>,
    pub texels: &'a [T],
}

/// A colour map's chain: linear RGB with straight alpha scaled per level to keep the
/// alpha-tested coverage, as half floats.
pub type ColorMips<'a> = Mips<'a, [u16; 4]>;

/// A normal map's chain: `(n + 1)/2` of the renormalized filtered normal in RGB and its length
/// before renormalizing in alpha (255 at level 0), 8-bit unorm.
pub type NormalMips<'a> = Mips<'a, [u8; 4]>;

/// A height chain: one half float per texel.
pub type HeightMips<'a> = Mips<'a, u16>;

impl HeightMips<'_> {
    /// Texel (i, j) of `level`, widened to f32 (in R).
    pub fn texel(&self, level: usize, i: u32, j: u32) -> [f32; 4] {
        let [w, _, first, _] = self.levels[level];
        let h = half::f16::from_bits(self.texels[(first + j * w + i) as usize]).to_f32();
        [h, 0.0, 0.0, 1.0]
    }
}

impl ColorMips<'_> {
    /// Texel (i, j) of `level`, widened to f32.
    pub fn texel(&self, level: usize, i: u32, j: u32) -> [f32; 4] {
        let [w, _, first, _] = self.levels[level];
        self.texels[(first + j * w + i) as usize].map(|b| half::f16::from_bits(b).to_f32())
    }
}

impl NormalMips<'_> {
    /// Level 0 as an image.
    pub fn level0(&self) -> ImageData<'_> {
        let [width, height, first, count] = self.levels[0];
        ImageData {
            width,
            height,
            texels: &self.texels[first as usize..(first + count) as usize],
        }
    }

    /// Texel (i, j) of `level` as an `Rgba8Unorm` sampler reads it: each byte / 255.
    pub fn texel(&self, level: usize, i: u32, j: u32) -> [f32; 4] {
        let [w, _, first, _] = self.levels[level];
        self.texels[(first + j * w + i) as usize].map(|b| b as f32 / 255.0)
    }
}

/// A run of triangles sharing a material: triangles `first..first + count` of the index buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DrawRange {
    pub material: u32,
    pub first: u32,
    pub count: u32,
}

/// One model: vertex arrays straight from its mesh section, and its instances.
#[derive(Debug, Clone)]
pub struct ModelData<'a> {
    pub name: String,
    pub section: String,
    pub positions: Cow<'a, [[f32; 3]]>,
    pub normals: Cow<'a, [[f32; 3]]>,
    pub uvs: Cow<'a, [[f32; 2]]>,
    /// Where the mesh's light-map atlas splits vertices at chart borders, the model is drawn
    /// with the atlas' vertices and triangles: this is the mesh vertex of every drawn vertex
    /// (None: the mesh's own vertices are drawn).
    pub vertex_source: Option<Vec<u32>>,
    /// Per-vertex tangent `[x, y, z, w]` (bitangent `w·(n × t)`): the `tangents:<model>`
    /// section, or any tangent orthogonal to the normal where the pack has none.
    pub tangents: Cow<'a, [[f32; 4]]>,
    /// The section's indices, or a copy regrouped by material when its triangles were interleaved.
    pub indices: Cow<'a, [[u32; 3]]>,
    pub draws: Vec<DrawRange>,
    pub materials: Vec<MaterialData<'a>>,
    pub instances: Vec<InstanceRecord>,
    /// Model-space bounds.
    pub bounds: ([f32; 3], [f32; 3]),
    /// Model-space bounding sphere (culling and the LOD distance).
    pub sphere: super::cull::Sphere,
    /// The simplified levels 1.. of the `lod:<model>` section (empty: full detail only).
    pub lod_levels: Vec<LodLevelData>,
    /// The `lod:<model>` section's metadata (the selection rule reads it); `None`: full detail.
    pub lod: Option<crate::lod::section::LodMeta>,
    /// The `lod:<model>` section's impostor atlas, drawn where the rule chooses it
    /// ([`super::impostor`]); `None`: the model has none.
    pub impostor: Option<ImpostorData>,
    /// The model's skeleton (`lod` section), drawn past the impostor (src/render/skeleton.rs).
    pub skeleton: Option<SkeletonData>,
}

/// A model's skeleton as the `lod` section stores it (model space).
#[derive(Debug, Clone, PartialEq)]
pub struct SkeletonData {
    /// Segment end points, two per segment.
    pub lines: Vec<[f32; 3]>,
    pub points: Vec<[f32; 3]>,
    /// sRGB, A = 255.
    pub albedo: [u8; 4],
}

/// A model's impostor atlas as the `lod` section stores it (`grid·tile` texels square, row 0 at
/// the top; docs/CONVENTIONS.md "Impostors").
#[derive(Debug, Clone, PartialEq)]
pub struct ImpostorData {
    pub meta: crate::lod::section::ImpostorMeta,
    /// sRGB albedo, straight alpha (0 or 255).
    pub color: Vec<[u8; 4]>,
    /// Model-space normal, (n + 1)/2.
    pub normal: Vec<[u8; 4]>,
    /// Depth code along the view (src/lod/octa.rs `depth_code`).
    pub depth: Vec<u8>,
}

/// One simplified level of a model: its own vertices, each a copy of mesh vertex `source[i]`
/// (normal, UV, tangent and, in the ambient term, PRT transfer gathered from it).
#[derive(Debug, Clone, PartialEq)]
pub struct LodLevelData {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub tangents: Vec<[f32; 4]>,
    pub source: Vec<u32>,
    /// Triangles grouped by material, indices into this level's vertices.
    pub indices: Vec<[u32; 3]>,
    pub draws: Vec<DrawRange>,
    /// Geometric error in model units.
    pub error: f32,
}

/// The sky: a lat-long RGBA float image and, for the sky stage's cube, the cube itself.
#[derive(Debug, Clone)]
pub struct SkyData<'a> {
    pub width: u32,
    pub height: u32,
    /// The lat-long image: the sky pass draws it where there is no cube, and the light of a
    /// pack without an `sh` section is estimated from it.
    pub texels: Cow<'a, [[f32; 4]]>,
    /// The sky stage's cube map (faces of `src/cube.rs`): the sky pass samples it as a cube
    /// texture (`Rgba16Float`, bilinear, seamless) with the world direction.
    pub cube: Option<crate::cube::CubeMap>,
    /// True when the pack had no sky and the analytic one is used.
    pub analytic: bool,
    /// True for the sky stage's cube, whose sun was taken out (the sky pass draws it as a
    /// disc, [`super::light::Lighting::sun_solid_angle`]).
    pub sun_removed: bool,
}

/// Where a scene's instance positions, scales, rotations and models were read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum InstanceSource {
    /// The `instances` section's records (or one instance per mesh without one).
    #[default]
    Instances,
    /// The `bittree` section: positions (x, y) from the leaf cells and their residuals on the
    /// terrain, quantized rotations (see [`bittree_instances`]).
    Bittree,
}

/// Everything a frame needs.
#[derive(Debug, Clone)]
pub struct SceneData<'a> {
    pub terrain: Option<TerrainData<'a>>,
    pub models: Vec<ModelData<'a>>,
    pub sky: SkyData<'a>,
    /// Where the instances' positions came from.
    pub instance_source: InstanceSource,
    /// What was skipped (missing textures, unusable sections).
    pub warnings: Vec<crate::diag::Warning>,
}

/// Reads and checks everything the renderer draws from `pack`.
pub fn load_scene(pack: &Pack) -> Result<SceneData<'_>> {
    let mut warnings = Vec::new();
    let terrain = match pack.of_kind(terrain::KIND).next() {
        Some(e) => load_terrain(pack, &e.name, &mut warnings)?,
        None => None,
    };
    let (models, instance_source) = load_models(pack, terrain.as_ref(), &mut warnings)?;
    let sky = load_sky(pack, &mut warnings)?;
    Ok(SceneData {
        terrain,
        models,
        sky,
        instance_source,
        warnings,
    })
}

fn invalid(pack: &Pack, section: &str, message: impl Into<String>) -> Error {
    Error::invalid_at(pack.path(), format!("section {section:?}"), message)
}

fn load_terrain<'a>(
    pack: &'a Pack,
    name: &str,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<TerrainData<'a>>> {
    let v = pack.view_named(name)?;
    let meta: TerrainMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
    let heights: &[f32] = v
        .array("heights")
        .map_err(|e| Error::invalid(pack.path(), e))?;
    if heights.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(invalid(
            pack,
            name,
            format!(
                "{} heights for a {}×{} grid",
                heights.len(),
                meta.width,
                meta.height
            ),
        ));
    }
    if meta.width < 2 || meta.height < 2 {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_TERRAIN_TOO_SMALL,
            "",
            format!(
                "terrain {name:?} is {}×{}: fewer than 2×2 samples, not drawn",
                meta.width, meta.height
            ),
        ));
        return Ok(None);
    }
    let (min_height, max_height) = heights
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &h| {
            (lo.min(h), hi.max(h))
        });
    if !min_height.is_finite() || !max_height.is_finite() {
        return Err(invalid(pack, name, "heights are not finite"));
    }
    let color = match &meta.color_section {
        Some(s) => load_image(pack, s, warnings)?,
        None => None,
    };
    let normals = terrain_normals(&v, &meta, heights);
    let tree = match crate::terrain::section::is_prepared(&v) {
        true => crate::terrain::section::quadtree_from_section(&v)
            .map_err(|e| Error::invalid(pack.path(), e))?,
        false => crate::terrain::MinMaxQuadtree::build(heights, meta.width, meta.height),
    };
    let l0 = tree.level(0);
    if (l0.width, l0.height) != (meta.width - 1, meta.height - 1) {
        return Err(invalid(
            pack,
            name,
            format!(
                "quadtree level 0 is {}×{} nodes for {}×{} cells",
                l0.width,
                l0.height,
                meta.width - 1,
                meta.height - 1
            ),
        ));
    }
    let chunks = super::terrain_lod::ChunkGrid::new(
        &tree,
        (meta.width, meta.height),
        [meta.origin[0], meta.origin[1]],
        meta.extent,
    );
    Ok(Some(TerrainData {
        chunks,
        meta,
        heights,
        min_height,
        max_height,
        color,
        normals,
    }))
}

/// The prepared terrain's normal map, else one computed from the heights (the terrain stage's
/// own function, so both agree).
fn terrain_normals<'a>(
    v: &crate::pack::section::SectionView<'a>,
    meta: &TerrainMeta,
    heights: &[f32],
) -> Cow<'a, [[u8; 4]]> {
    if let Ok(n) = v.array::<[u8; 4]>("normals")
        && n.len() == heights.len()
    {
        return Cow::Borrowed(n);
    }
    let t = crate::model::Terrain {
        width: meta.width,
        height: meta.height,
        heights: heights.to_vec(),
        origin: meta.origin,
        extent: meta.extent,
        color: None,
    };
    Cow::Owned(crate::terrain::prepare::terrain_normal_map(&t))
}

/// A texture section as an image; a missing section is a warning (drawn untextured).
fn load_image<'a>(
    pack: &'a Pack,
    name: &str,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<ImageData<'a>>> {
    if pack.find(name).is_none() {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_TEXTURE_MISSING,
            "",
            format!("texture section {name:?} is missing: drawn untextured"),
        ));
        return Ok(None);
    }
    let v = pack.view_named(name)?;
    let meta: TextureMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
    let texels: &[[u8; 4]] = v
        .array("texels")
        .map_err(|e| Error::invalid(pack.path(), e))?;
    if texels.len() as u64 != meta.width as u64 * meta.height as u64 || texels.is_empty() {
        return Err(invalid(
            pack,
            name,
            format!("{} texels for {}×{}", texels.len(), meta.width, meta.height),
        ));
    }
    Ok(Some(ImageData {
        width: meta.width,
        height: meta.height,
        texels,
    }))
}

/// The mip chain of texture section `name` where the material stage processed it (format
/// `rgba16f_linear`), `None` for an ingested texture; a chain that does not match its table is
/// an invalid pack.
#[allow(clippy::type_complexity)]
fn load_color_mips<'a>(
    pack: &'a Pack,
    name: &str,
) -> Result<Option<(ColorMips<'a>, HeightMips<'a>)>> {
    let v = pack.view_named(name)?;
    let meta: TextureMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
    if meta.format != crate::texture::section::FORMAT_COLOR {
        return Ok(None);
    }
    let bad = |e: crate::error::ParseError| invalid(pack, name, e.to_string());
    let levels = crate::texture::section::levels(&v, &meta, "color").map_err(bad)?;
    crate::texture::section::levels(&v, &meta, "height").map_err(bad)?;
    let texels: &[[u16; 4]] = v.array("color").map_err(bad)?;
    let heights: &[u16] = v.array("height").map_err(bad)?;
    Ok(Some((
        ColorMips {
            levels: levels.clone(),
            texels,
        },
        HeightMips {
            levels,
            texels: heights,
        },
    )))
}

/// Every model of the `instances` section with its instances; without an `instances` section
/// (a pack from `bake ingest model.txf`) every mesh section is drawn once at the origin.
///
/// With a `bittree` section the instances are decoded from it ([`bittree_instances`]).
fn load_models<'a>(
    pack: &'a Pack,
    terrain: Option<&TerrainData>,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<(Vec<ModelData<'a>>, InstanceSource)> {
    let mut out: Vec<ModelData<'a>> = Vec::new();
    let mut source = InstanceSource::Instances;
    if let Some(e) = pack.of_kind(instances::KIND).next() {
        let v = pack.view(e)?;
        let meta: InstancesMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
        let list: &[InstanceRecord] = v
            .array("instances")
            .map_err(|e| Error::invalid(pack.path(), e))?;
        let decoded = match pack.of_kind(crate::bittree::section::KIND).next() {
            Some(b) => {
                source = InstanceSource::Bittree;
                Some(bittree_instances(pack, &b.name, list, terrain)?)
            }
            None => None,
        };
        let recs = decoded.as_deref().unwrap_or(list);
        if meta.mesh_sections.len() != meta.models.len() {
            return Err(invalid(
                pack,
                &e.name,
                format!(
                    "{} models but {} mesh sections",
                    meta.models.len(),
                    meta.mesh_sections.len()
                ),
            ));
        }
        let mut per_model: Vec<Vec<InstanceRecord>> = vec![Vec::new(); meta.models.len()];
        for (k, r) in recs.iter().enumerate() {
            let list = per_model.get_mut(r.model as usize).ok_or_else(|| {
                invalid(
                    pack,
                    &e.name,
                    format!(
                        "instance {k}: model index {} past {}",
                        r.model,
                        meta.models.len()
                    ),
                )
            })?;
            list.push(*r);
        }
        for ((name, section), inst) in meta.models.iter().zip(&meta.mesh_sections).zip(per_model) {
            if inst.is_empty() {
                continue;
            }
            if pack.find(section).is_none() {
                warnings.push(crate::diag::Warning::new(
                    &crate::diag::RENDER_MESH_MISSING,
                    "",
                    format!(
                        "model {name:?}: mesh section {section:?} missing, {} instances not drawn",
                        inst.len()
                    ),
                ));
                continue;
            }
            out.push(load_model(pack, name, section, inst, warnings)?);
        }
    }
    if pack.of_kind(instances::KIND).next().is_none() {
        for e in pack.of_kind(mesh::KIND) {
            let origin = InstanceRecord {
                position: [0.0; 3],
                scale: 1.0,
                rotation_deg: 0.0,
                model: 0,
                layer: 0,
                reserved: 0,
            };
            let name = e.name.trim_start_matches("mesh:").to_string();
            out.push(load_model(pack, &name, &e.name, vec![origin], warnings)?);
        }
    }
    Ok((out, source))
}

/// The instances as the `bittree` section `name` holds them (seed 000 §5.1.1), in the order of
/// the `instances` section's `list`: x and y from the instance's deepest cell and its residual
/// (within cell/2¹⁷ of its position, docs/FORMAT.md; the cell centre in packs without
/// residuals), z the terrain's height there (the list's z without a terrain),
/// scale, rotation (to 2⁻¹⁶ of a turn), model and layer from the arrays beside the bits.
///
/// The per-instance caches (env maps, clusters, light-map UVs) are indexed by the list, so each
/// decoded instance is paired with its list entry through the leaf order of the list's
/// positions ([`crate::bittree::leaf_order`], the encoder's order). The pairing is checked: a
/// pair must share its cell and its model, else the section is stale or foreign and the pack is
/// refused.
pub fn bittree_instances(
    pack: &Pack,
    name: &str,
    list: &[InstanceRecord],
    terrain: Option<&TerrainData>,
) -> Result<Vec<InstanceRecord>> {
    let v = pack.view_named(name)?;
    let d = crate::bittree::section::from_section(&v)
        .map_err(|e| invalid(pack, name, e.to_string()))?;
    if d.positions.len() != list.len() {
        return Err(invalid(
            pack,
            name,
            format!(
                "{} instances, the instances section has {}",
                d.positions.len(),
                list.len()
            ),
        ));
    }
    let (area, children, levels) = (d.meta.area, d.meta.children, d.meta.levels);
    let xy: Vec<[f32; 2]> = list
        .iter()
        .map(|r| [r.position[0], r.position[1]])
        .collect();
    let order = crate::bittree::leaf_order(&xy, &area, children, levels);
    let mut out = list.to_vec();
    for (k, &i) in order.iter().enumerate() {
        let i = i as usize;
        let p = d.positions[k];
        let cell = |p| crate::bittree::leaf_cell(p, &area, children, levels);
        if cell(p) != cell(xy[i]) || d.model[k] as u32 != list[i].model {
            return Err(invalid(
                pack,
                name,
                format!(
                    "decoded instance {k} (model {} at {:?}) is not instance {i} of the \
                     instances section (model {} at {:?}): the BitTree is stale",
                    d.model[k], p, list[i].model, xy[i]
                ),
            ));
        }
        let z = terrain.map_or(list[i].position[2], |t| {
            crate::model::bilinear_height(
                t.heights,
                (t.meta.width, t.meta.height),
                t.meta.origin,
                t.meta.extent,
                p[0],
                p[1],
            )
        });
        out[i] = InstanceRecord {
            position: [p[0], p[1], z],
            scale: d.scale[k],
            rotation_deg: d.rotation_deg[k],
            model: d.model[k] as u32,
            layer: d.layer[k] as i32,
            reserved: 0,
        };
    }
    Ok(out)
}

fn load_model<'a>(
    pack: &'a Pack,
    name: &str,
    section: &str,
    instances: Vec<InstanceRecord>,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<ModelData<'a>> {
    let v = pack.view_named(section)?;
    let bad = |e| Error::invalid(pack.path(), e);
    let meta: MeshMeta = v.meta().map_err(bad)?;
    let positions: &[[f32; 3]] = v.array("positions").map_err(bad)?;
    let normals: &[[f32; 3]] = v.array("normals").map_err(bad)?;
    let uvs: &[[f32; 2]] = v.array("uvs").map_err(bad)?;
    let indices: &[[u32; 3]] = v.array("indices").map_err(bad)?;
    let tri_mats: &[u32] = v.array("triangle_materials").map_err(bad)?;
    let n = positions.len();
    if normals.len() != n || uvs.len() != n || tri_mats.len() != indices.len() {
        return Err(invalid(
            pack,
            section,
            "vertex or triangle arrays differ in length",
        ));
    }
    if let Some(t) = indices
        .iter()
        .position(|t| t.iter().any(|&i| i as usize >= n))
    {
        return Err(invalid(
            pack,
            section,
            format!("triangle {t} refers to a vertex past {n}"),
        ));
    }
    let materials = load_materials(pack, section, &meta, warnings)?;
    let tangents = load_tangents(pack, section, normals, warnings);
    if let Some(t) = tri_mats.iter().position(|&m| m as usize >= materials.len()) {
        return Err(invalid(
            pack,
            section,
            format!(
                "triangle {t}: material {} past {}",
                tri_mats[t],
                materials.len()
            ),
        ));
    }
    let bounds = crate::model::bounds_of(positions).unwrap_or(([0.0; 3], [0.0; 3]));
    let mut model = ModelData {
        name: name.to_string(),
        section: section.to_string(),
        positions: Cow::Borrowed(positions),
        normals: Cow::Borrowed(normals),
        uvs: Cow::Borrowed(uvs),
        vertex_source: None,
        tangents,
        indices: Cow::Borrowed(indices),
        draws: Vec::new(),
        materials,
        instances,
        bounds,
        sphere: super::cull::Sphere::around(positions),
        lod_levels: Vec::new(),
        lod: None,
        impostor: None,
        skeleton: None,
    };
    if let Some((source, atlas_indices)) = atlas_split(pack, section, n, indices.len())? {
        model.split_vertices(source, atlas_indices);
    } else {
        load_lod(pack, section, &mut model)?;
    }
    let (grouped, draws) = group_by_material(&model.indices, tri_mats);
    let grouped = Cow::Owned(grouped.into_owned());
    (model.indices, model.draws) = (grouped, draws);
    Ok(model)
}

/// The `lod:<model>` section's simplified levels (its level 0 is the mesh itself, drawn from
/// the mesh section) with normals, UVs and tangents gathered through `vertex_source`, and its
/// bounding sphere. A model drawn with a light-map atlas' split vertices keeps full detail (its
/// light-map UVs belong to atlas vertices, which a LOD vertex does not name): the caller skips it.
fn load_lod(pack: &Pack, section: &str, model: &mut ModelData) -> Result<()> {
    let Some(view) = crate::lod::section::read(pack, section)? else {
        return Ok(());
    };
    let materials = model.materials.len() as u32;
    let name = crate::lod::section::lod_section_name(section);
    let mut levels = Vec::with_capacity(view.meta.levels.len().saturating_sub(1));
    for l in 1..view.meta.levels.len() {
        let first = view.meta.levels[l].first_vertex as usize;
        let positions = view.level_positions(l);
        let source = &view.vertex_source[first..first + positions.len()];
        let (tris, mats) = view.level_triangles(l);
        if let Some(t) = mats.iter().position(|&m| m >= materials) {
            return Err(invalid(
                pack,
                &name,
                format!(
                    "level {l} triangle {t}: material {} past {materials}",
                    mats[t]
                ),
            ));
        }
        let gather = |a: &[[f32; 3]]| source.iter().map(|&v| a[v as usize]).collect();
        let (grouped, draws) = group_by_material(tris, mats);
        levels.push(LodLevelData {
            positions: positions.to_vec(),
            normals: gather(&model.normals),
            uvs: source.iter().map(|&v| model.uvs[v as usize]).collect(),
            tangents: source.iter().map(|&v| model.tangents[v as usize]).collect(),
            source: source.to_vec(),
            indices: grouped.into_owned(),
            draws,
            error: view.meta.levels[l].error,
        });
    }
    if view.meta.radius.is_finite() && view.meta.radius > 0.0 {
        model.sphere = super::cull::Sphere {
            centre: view.meta.centre,
            radius: view.meta.radius,
        };
    }
    model.impostor = match (&view.meta.impostor, &view.impostor) {
        (Some(meta), Some(a)) => Some(ImpostorData {
            meta: meta.clone(),
            color: a.color.to_vec(),
            normal: a.normal.to_vec(),
            depth: a.depth.to_vec(),
        }),
        _ => None,
    };
    model.skeleton = view.meta.skeleton.as_ref().map(|sk| SkeletonData {
        lines: view.skeleton_lines.to_vec(),
        points: view.skeleton_points.to_vec(),
        albedo: sk.albedo,
    });
    model.lod_levels = levels;
    model.lod = Some(view.meta);
    Ok(())
}

impl ModelData<'_> {
    /// Draws the model with split vertices: vertex i becomes a copy of mesh vertex `source[i]`,
    /// and `indices` (one triangle per mesh triangle, same order) replace the mesh's.
    fn split_vertices(&mut self, source: Vec<u32>, indices: Vec<[u32; 3]>) {
        fn gather<T: Copy>(a: &[T], source: &[u32]) -> Vec<T> {
            source.iter().map(|&v| a[v as usize]).collect()
        }
        self.positions = Cow::Owned(gather(&self.positions, &source));
        self.normals = Cow::Owned(gather(&self.normals, &source));
        self.uvs = Cow::Owned(gather(&self.uvs, &source));
        self.tangents = Cow::Owned(gather(&self.tangents, &source));
        self.indices = Cow::Owned(indices);
        self.vertex_source = Some(source);
    }
}

/// The mesh vertex of every atlas vertex, and the atlas' triangles.
type AtlasSplit = (Vec<u32>, Vec<[u32; 3]>);

/// The atlas vertex list of the light map of `section` where it splits mesh vertices (an atlas
/// section without `lightmap_uv`, made for this mesh of `vertices` vertices and `triangles`
/// triangles): (mesh vertex of every atlas vertex, atlas triangles). None where the mesh has no
/// atlas, or its atlas keeps the mesh's vertices.
fn atlas_split(
    pack: &Pack,
    section: &str,
    vertices: usize,
    triangles: usize,
) -> Result<Option<AtlasSplit>> {
    use crate::lightmap::atlas_section::{AtlasMeta, is_atlas};
    for e in pack.of_kind(crate::lightmap::section::KIND) {
        let v = pack.view(e)?;
        if !is_atlas(&v) || v.info("lightmap_uv").is_some() {
            continue;
        }
        let meta: AtlasMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
        if meta.surface != section || meta.mesh_vertices as usize != vertices {
            continue;
        }
        let bad = |e| Error::invalid(pack.path(), e);
        let source: Vec<u32> = v.array_vec("vertex_source").map_err(bad)?;
        let indices: Vec<[u32; 3]> = v.array_vec("indices").map_err(bad)?;
        if let Some(i) = source.iter().position(|&s| s as usize >= vertices) {
            return Err(invalid(
                pack,
                &e.name,
                format!(
                    "atlas vertex {i}: mesh vertex {} past {vertices}",
                    source[i]
                ),
            ));
        }
        if indices.len() != triangles {
            return Err(invalid(
                pack,
                &e.name,
                format!(
                    "{} atlas triangles for {triangles} mesh triangles",
                    indices.len()
                ),
            ));
        }
        if let Some(t) = indices
            .iter()
            .position(|t| t.iter().any(|&i| i as usize >= source.len()))
        {
            return Err(invalid(
                pack,
                &e.name,
                format!(
                    "atlas triangle {t} refers to a vertex past {}",
                    source.len()
                ),
            ));
        }
        return Ok(Some((source, indices)));
    }
    Ok(None)
}

/// The preview's view of each material: its linear diffuse albedo
/// ([`crate::material::convert::diffuse_albedo`], the tracer's), colour map section.
/// A mesh without materials gets the OpenGL default one.
fn load_materials<'a>(
    pack: &'a Pack,
    section: &str,
    meta: &MeshMeta,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Vec<MaterialData<'a>>> {
    if meta.materials.is_empty() {
        let d = crate::material::convert::diffuse_albedo(&crate::model::Material::default());
        return Ok(vec![MaterialData {
            base_color: [d[0], d[1], d[2], 1.0],
            color_map: None,
            color_mips: None,
            schlick: None,
            normal_map: None,
            height_mips: None,
        }]);
    }
    let mut out = Vec::with_capacity(meta.materials.len());
    for m in &meta.materials {
        let entry = m.color_map.and_then(|i| meta.textures.get(i as usize));
        let color_map = match entry {
            Some(t) => match &t.section {
                Some(s) => load_image(pack, s, warnings)?,
                None => {
                    warnings.push(crate::diag::Warning::new(
                        &crate::diag::RENDER_TEXTURE_UNDECODED,
                        "",
                        format!(
                            "{section}: texture {:?} was not decoded: drawn untextured",
                            t.name
                        ),
                    ));
                    None
                }
            },
            None => None,
        };
        let (color_mips, height_mips) = match (&color_map, entry.and_then(|t| t.section.as_deref()))
        {
            (Some(_), Some(s)) => load_color_mips(pack, s)?.unzip(),
            _ => (None, None),
        };
        let d = crate::material::convert::diffuse_albedo(m);
        let (schlick, normal_map) = load_schlick(pack, section, out.len(), warnings)?;
        out.push(MaterialData {
            base_color: [d[0], d[1], d[2], 1.0],
            color_map,
            color_mips,
            schlick,
            normal_map,
            height_mips,
        });
    }
    Ok(out)
}

/// The model name the material stage uses in its section names.
fn model_of(mesh_section: &str) -> &str {
    mesh_section.strip_prefix("mesh:").unwrap_or(mesh_section)
}

/// The Schlick material `index` of a mesh section and level 0 of its normal map; `(None, None)`
/// when the material stage has not run (the mesh is shaded with Lambert).
fn load_schlick<'a>(
    pack: &'a Pack,
    mesh_section: &str,
    index: usize,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<(
    Option<crate::material::schlick::SchlickMaterial>,
    Option<NormalMips<'a>>,
)> {
    use crate::material::section as ms;
    let name = ms::material_section_name(model_of(mesh_section), index);
    if pack.find(&name).is_none() {
        return Ok((None, None));
    }
    let v = pack.view_named(&name)?;
    let meta = ms::from_section(&v).map_err(|e| Error::invalid(pack.path(), e))?;
    if meta.mesh_section != mesh_section || meta.index as usize != index {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_MATERIAL_MISMATCH,
            "",
            format!(
                "{name:?} belongs to {:?} material {}: shaded with Lambert",
                meta.mesh_section, meta.index
            ),
        ));
        return Ok((None, None));
    }
    let normal_map = match &meta.normal_map {
        Some(s) => load_normal_map(pack, s, warnings)?,
        None => None,
    };
    Ok((Some(meta.material), normal_map))
}

/// The mip chain of a processed texture's `normal` array; a chain that does not match its
/// `levels` table is an invalid pack.
fn load_normal_map<'a>(
    pack: &'a Pack,
    name: &str,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<NormalMips<'a>>> {
    let v = match pack.find(name) {
        Some(_) => pack.view_named(name)?,
        None => {
            warnings.push(crate::diag::Warning::new(
                &crate::diag::RENDER_NORMAL_MAP_MISSING,
                "",
                format!("normal map {name:?} is missing: drawn flat"),
            ));
            return Ok(None);
        }
    };
    let meta: TextureMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
    let Ok(texels) = v.array::<[u8; 4]>("normal") else {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_NORMAL_MAP_MISSING,
            "",
            format!("texture {name:?} has no normal array: drawn flat"),
        ));
        return Ok(None);
    };
    let bad = |e: crate::error::ParseError| invalid(pack, name, e.to_string());
    let levels = crate::texture::section::levels(&v, &meta, "normal").map_err(bad)?;
    Ok(Some(NormalMips { levels, texels }))
}

/// The `tangents:<model>` section's frames when they match the mesh's vertices, else any unit
/// tangent orthogonal to each normal (Frisvad), so every model has a frame to shade in.
fn load_tangents<'a>(
    pack: &'a Pack,
    mesh_section: &str,
    normals: &[[f32; 3]],
    warnings: &mut Vec<crate::diag::Warning>,
) -> Cow<'a, [[f32; 4]]> {
    let name = crate::mesh::tangents::tangents_section_name(model_of(mesh_section));
    if let Some(v) = pack.find(&name).and_then(|_| pack.view_named(&name).ok()) {
        match v.array::<[f32; 4]>("tangents") {
            Ok(t) if t.len() == normals.len() => return Cow::Borrowed(t),
            _ => warnings.push(crate::diag::Warning::new(
                &crate::diag::RENDER_TANGENTS_MISMATCH,
                "",
                format!(
                    "{name:?} does not match the vertices of {mesh_section:?}: tangents made up"
                ),
            )),
        }
    }
    Cow::Owned(normals.iter().map(|&n| any_tangent(n)).collect())
}

/// A unit vector orthogonal to `n` (Frisvad's construction) with w = +1.
pub fn any_tangent(n: [f32; 3]) -> [f32; 4] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = if l > 0.0 {
        n.map(|c| c / l)
    } else {
        [0.0, 0.0, 1.0]
    };
    if n[2] < -0.999_999 {
        return [0.0, -1.0, 0.0, 1.0];
    }
    let a = 1.0 / (1.0 + n[2]);
    let b = -n[0] * n[1] * a;
    [1.0 - n[0] * n[0] * a, b, -n[0], 1.0]
}

/// Runs of equal material. When a mesh interleaves materials (more runs than materials), the
/// triangles are regrouped, stably, so each material is one draw call.
pub fn group_by_material<'a>(
    indices: &'a [[u32; 3]],
    tri_mats: &[u32],
) -> (Cow<'a, [[u32; 3]]>, Vec<DrawRange>) {
    let runs = material_runs(tri_mats);
    let distinct = {
        let mut m: Vec<u32> = tri_mats.to_vec();
        m.sort_unstable();
        m.dedup();
        m.len()
    };
    if runs.len() <= distinct {
        return (Cow::Borrowed(indices), runs);
    }
    let mut order: Vec<u32> = (0..indices.len() as u32).collect();
    order.sort_by_key(|&t| tri_mats[t as usize]);
    let regrouped: Vec<[u32; 3]> = order.iter().map(|&t| indices[t as usize]).collect();
    let mats: Vec<u32> = order.iter().map(|&t| tri_mats[t as usize]).collect();
    (Cow::Owned(regrouped), material_runs(&mats))
}

fn material_runs(tri_mats: &[u32]) -> Vec<DrawRange> {
    let mut runs: Vec<DrawRange> = Vec::new();
    for (t, &m) in tri_mats.iter().enumerate() {
        match runs.last_mut() {
            Some(r) if r.material == m => r.count += 1,
            _ => runs.push(DrawRange {
                material: m,
                first: t as u32,
                count: 1,
            }),
        }
    }
    runs
}

fn load_sky<'a>(pack: &'a Pack, warnings: &mut Vec<crate::diag::Warning>) -> Result<SkyData<'a>> {
    if let Some(e) = pack.of_kind(sky::KIND).next() {
        let v = pack.view(e)?;
        let meta: SkyMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
        if meta.layout == "cube" {
            // The sky stage's cube map (sun removed): drawn as a cube texture; its lat-long
            // resampling only estimates the light where the pack has no `sh` section.
            let (_, mut cube) = crate::sky::section::cube_from_section(&v)
                .map_err(|e| Error::invalid(pack.path(), e))?;
            // Half floats that are not radiance (NaN, ±∞, negative) as the GPU path clamps
            // them, so both renderers read the same texels.
            for t in &mut cube.texels {
                *t = t.map(|v| {
                    if v.is_nan() {
                        0.0
                    } else {
                        v.clamp(0.0, 65504.0)
                    }
                });
            }
            let (w, h) = ANALYTIC_SKY_SIZE;
            let img = crate::sky::cube_to_latlong(&cube, w, h);
            let texels = img.pixels.iter().map(|p| [p[0], p[1], p[2], 1.0]).collect();
            return Ok(SkyData {
                width: w,
                height: h,
                texels: Cow::Owned(texels),
                cube: Some(cube),
                analytic: false,
                sun_removed: true,
            });
        }
        let texels: &[[f32; 4]] = v
            .array("texels")
            .map_err(|e| Error::invalid(pack.path(), e))?;
        if texels.len() as u64 != meta.width as u64 * meta.height as u64 || texels.is_empty() {
            return Err(invalid(
                pack,
                &e.name,
                "texel count does not match width × height",
            ));
        }
        if meta.layout == "latlong" {
            return Ok(SkyData {
                width: meta.width,
                height: meta.height,
                texels: Cow::Borrowed(texels),
                cube: None,
                analytic: false,
                sun_removed: false,
            });
        }
        warnings.push(crate::diag::Warning::new(&crate::diag::RENDER_SKY_LAYOUT, "", format!(
            "sky {:?} has layout {:?}; the preview reads lat-long only and uses the analytic sky",
            e.name, meta.layout
        )));
    }
    let (w, h) = ANALYTIC_SKY_SIZE;
    Ok(SkyData {
        width: w,
        height: h,
        texels: Cow::Owned(light::analytic_sky(w, h)),
        cube: None,
        analytic: true,
        sun_removed: false,
    })
}

pub use crate::color::srgb_to_linear;

impl SceneData<'_> {
    /// Bounds of what the default camera frames: every instance's model bounds (turned about Z,
    /// so x and y grow by the model's horizontal radius), else the terrain, else the unit cube.
    pub fn focus_bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for m in &self.models {
            let (a, b) = m.bounds;
            let r_xy = [a[0], b[0]]
                .iter()
                .flat_map(|x| [a[1], b[1]].map(|y| x.hypot(y)))
                .fold(0.0f32, f32::max);
            for i in &m.instances {
                let s = i.scale.abs();
                let p = i.position;
                let (z0, z1) = (p[2] + a[2] * i.scale, p[2] + b[2] * i.scale);
                let ext = [
                    (p[0] - r_xy * s, p[0] + r_xy * s),
                    (p[1] - r_xy * s, p[1] + r_xy * s),
                    (z0.min(z1), z0.max(z1)),
                ];
                for (k, (l, h)) in ext.into_iter().enumerate() {
                    lo[k] = lo[k].min(l);
                    hi[k] = hi[k].max(h);
                }
            }
        }
        if lo.iter().chain(&hi).all(|v| v.is_finite()) {
            return (lo, hi);
        }
        if let Some(t) = &self.terrain {
            let o = t.meta.origin;
            let e = t.meta.extent;
            return (
                [o[0], o[1], t.min_height],
                [o[0] + e[0], o[1] + e[1], t.max_height],
            );
        }
        ([-0.5; 3], [0.5; 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contiguous_materials_keep_the_section_indices() {
        let idx = [[0u32, 1, 2], [2, 1, 3], [3, 4, 5]];
        let (i, d) = group_by_material(&idx, &[1, 1, 0]);
        assert!(matches!(i, Cow::Borrowed(_)));
        assert_eq!(
            d,
            vec![
                DrawRange {
                    material: 1,
                    first: 0,
                    count: 2
                },
                DrawRange {
                    material: 0,
                    first: 2,
                    count: 1
                }
            ]
        );
    }

    #[test]
    fn interleaved_materials_are_regrouped_stably() {
        let idx = [[0u32, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]];
        let (i, d) = group_by_material(&idx, &[1, 0, 1, 0]);
        assert_eq!(&*i, &[[1, 1, 1], [3, 3, 3], [0, 0, 0], [2, 2, 2]]);
        assert_eq!(d.len(), 2);
        assert_eq!(
            d[1],
            DrawRange {
                material: 1,
                first: 2,
                count: 2
            }
        );
    }

    #[test]
    fn srgb_decoding_matches_the_standard() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
    }
}
