//! What the voxelizer and the N-tree read: one triangle mesh in world space with its decoded
//! colour maps, from a model, or from a pack (its meshes, or a whole scene: the terrain as a
//! triangulated height field plus every instance's mesh placed on it).

use crate::error::{Error, ParseError, Result};
use crate::ingest::limits::{Limits, human};
use crate::model::{Instance, Material, Mesh, Rgba8Image, Terrain};
use crate::pack::Pack;
use std::path::Path;

/// A world-space mesh and the decoded images of its `textures` (same indices; None = missing).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Geometry {
    pub mesh: Mesh,
    pub textures: Vec<Option<Rgba8Image>>,
}

impl Geometry {
    /// Appends another geometry (indices, materials and textures offset).
    pub fn append(&mut self, other: Geometry) {
        self.mesh.append(other.mesh);
        self.textures.extend(other.textures);
    }
}

/// The terrain as two triangles per grid cell, with its colour map as material 0's colour map.
pub fn terrain_mesh(t: &Terrain) -> Geometry {
    let (w, h) = (t.width.max(1), t.height.max(1));
    let mesh = terrain_tile_mesh(t, [0, w.saturating_sub(1)], [0, h.saturating_sub(1)]);
    let textures = if t.color.is_some() {
        vec![t.color.clone()]
    } else {
        Vec::new()
    };
    Geometry { mesh, textures }
}

/// The cells `i0..i1` × `j0..j1` of the terrain (columns, rows; samples i0..=i1 × j0..=j1) as
/// [`terrain_mesh`] makes them: the same positions, texture coordinates, triangles and material,
/// the cells in the same order (row by row), so a voxel that only these triangles touch gets the
/// same bits. Its colour map is texture 0 (pass the terrain's image beside it).
pub fn terrain_tile_mesh(t: &Terrain, [i0, i1]: [u32; 2], [j0, j1]: [u32; 2]) -> Mesh {
    let (w, h) = (t.width.max(1), t.height.max(1));
    let mut mesh = Mesh::default();
    for j in j0..=j1.min(h - 1) {
        for i in i0..=i1.min(w - 1) {
            mesh.positions.push(t.position(i, j));
            mesh.normals.push([0.0, 0.0, 1.0]);
            let u = if w > 1 {
                i as f32 / (w - 1) as f32
            } else {
                0.5
            };
            // Row 0 of the colour image is the northern edge (largest y).
            let v = if h > 1 {
                1.0 - j as f32 / (h - 1) as f32
            } else {
                0.5
            };
            mesh.uvs.push([u, v]);
        }
    }
    let tw = i1.min(w - 1) - i0 + 1;
    for j in 0..j1.min(h - 1) - j0 {
        for i in 0..tw - 1 {
            let a = j * tw + i;
            mesh.indices.push([a, a + 1, a + tw + 1]);
            mesh.indices.push([a, a + tw + 1, a + tw]);
        }
    }
    mesh.triangle_materials = vec![0; mesh.indices.len()];
    let textured = t.color.is_some();
    mesh.materials.push(Material {
        name: "terrain".into(),
        diffuse: [1.0, 1.0, 1.0, 1.0],
        color_map: textured.then_some(0),
        ..Material::default()
    });
    mesh.objects.push("terrain".into());
    if textured {
        mesh.textures.push(crate::model::TextureRef {
            name: "terrain color".into(),
            path: "terrain".into(),
        });
    }
    mesh
}

/// The placement of an instance as a function of a model point: scaled, rotated about +Z,
/// translated (what [`place_instance`] does to every vertex).
pub fn instance_placement(inst: &Instance) -> impl Fn([f32; 3]) -> [f32; 3] + '_ {
    let (s, c) = inst.rotation_deg.to_radians().sin_cos();
    move |p: [f32; 3]| {
        let q = p.map(|x| x * inst.scale);
        let r = [c * q[0] - s * q[1], s * q[0] + c * q[1], q[2]];
        [0, 1, 2].map(|k| r[k] + inst.position[k])
    }
}

/// A model's mesh placed by an instance: scaled, rotated about +Z, translated.
pub fn place_instance(model: &Geometry, inst: &Instance) -> Geometry {
    let (s, c) = inst.rotation_deg.to_radians().sin_cos();
    let rot = |p: [f32; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
    let place = instance_placement(inst);
    let mut g = model.clone();
    for p in &mut g.mesh.positions {
        *p = place(*p);
    }
    for n in &mut g.mesh.normals {
        *n = rot(*n);
    }
    g
}

pub(crate) fn invalid(pack: &Pack, e: ParseError) -> crate::error::Error {
    crate::error::Error::invalid(pack.path(), e)
}

/// A mesh section and its texture sections.
pub fn mesh_from_pack(pack: &Pack, name: &str) -> Result<Geometry> {
    let view = pack.view_named(name)?;
    let (meta, mesh) = crate::mesh::section::from_section(&view).map_err(|e| invalid(pack, e))?;
    let mut textures = Vec::with_capacity(meta.textures.len());
    for t in &meta.textures {
        let img = match &t.section {
            Some(s) if pack.find(s).is_some() => {
                let v = pack.view_named(s)?;
                Some(
                    crate::texture::source_section::from_section(&v)
                        .map_err(|e| invalid(pack, e))?
                        .1,
                )
            }
            _ => None,
        };
        textures.push(img);
    }
    Ok(Geometry { mesh, textures })
}

/// With an `instances` section: each model's mesh section read once (`keep` of its name and
/// geometry; None for a model without one) and the instances.
pub(crate) fn pack_placed_models<T>(
    pack: &Pack,
    keep: impl Fn(&str, Geometry) -> T,
) -> Result<Option<(Vec<Option<T>>, crate::model::Instances)>> {
    let Some(e) = pack.of_kind(crate::ingest::instances_section::KIND).next() else {
        return Ok(None);
    };
    let view = pack.view(e)?;
    let (meta, inst) =
        crate::ingest::instances_section::from_section(&view).map_err(|e| invalid(pack, e))?;
    let models = meta
        .mesh_sections
        .iter()
        .map(|s| {
            pack.find(s)
                .map(|_| mesh_from_pack(pack, s).map(|g| keep(s, g)))
                .transpose()
        })
        .collect::<Result<_>>()?;
    Ok(Some((models, inst)))
}

/// All geometry of a pack: with an `instances` section, the scene (terrain plus placed
/// instances); otherwise every mesh section (and the terrain, if any) as it is.
pub fn pack_geometry(pack: &Pack) -> Result<Geometry> {
    let mut g = Geometry::default();
    if let Some(t) = pack_terrain(pack)? {
        g.append(terrain_mesh(&t));
    }
    if let Some((models, inst)) = pack_placed_models(pack, |_, g| g)? {
        for i in &inst.items {
            if let Some(Some(m)) = models.get(i.model as usize) {
                g.append(place_instance(m, i));
            }
        }
    } else {
        let names: Vec<String> = pack
            .of_kind(crate::mesh::section::KIND)
            .map(|e| e.name.clone())
            .collect();
        for n in names {
            g.append(mesh_from_pack(pack, &n)?);
        }
    }
    Ok(g)
}

/// The world triangles of [`pack_geometry`]'s mesh (`Mesh::triangle_positions` of it: the
/// same values in the same order) without building the mesh: no normals, texture coordinates,
/// materials or per-instance copies of the textures (at 20,000 instances the whole mesh took
/// 13 GB where its triangles take 1.5 GB).
pub fn pack_world_triangles(pack: &Pack) -> Result<Vec<[[f32; 3]; 3]>> {
    let mut out = Vec::new();
    if let Some(t) = pack_terrain(pack)? {
        let (w, h) = (t.width.max(1), t.height.max(1));
        let m = terrain_tile_mesh(&t, [0, w.saturating_sub(1)], [0, h.saturating_sub(1)]);
        out.extend(m.triangle_positions());
    }
    if let Some((models, inst)) = pack_placed_models(pack, |_, g| g.mesh)? {
        for i in &inst.items {
            if let Some(Some(m)) = models.get(i.model as usize) {
                let place = instance_placement(i);
                let placed: Vec<[f32; 3]> = m.positions.iter().map(|&p| place(p)).collect();
                out.extend(m.indices.iter().map(|t| t.map(|v| placed[v as usize])));
            }
        }
    } else {
        let names: Vec<String> = pack
            .of_kind(crate::mesh::section::KIND)
            .map(|e| e.name.clone())
            .collect();
        for n in names {
            out.extend(mesh_from_pack(pack, &n)?.mesh.triangle_positions());
        }
    }
    Ok(out)
}

/// A stage that reads the whole placed scene as one mesh ([`pack_geometry`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneStage {
    Svo,
    Linespace,
}

impl SceneStage {
    pub fn name(self) -> &'static str {
        match self {
            SceneStage::Svo => "svo",
            SceneStage::Linespace => "linespace",
        }
    }

    /// Bytes the stage keeps per triangle besides the mesh: the voxelizer's set-up and bucket
    /// entry, or the N-tree's world-space corners, its cell set-up (the same test) and one
    /// (leaf, triangle) pair while they are sorted (236 B: the 20,000-instance scene's 41 M
    /// triangles peaked at 10.4 GB, 254 B each with the pack).
    pub fn bytes_per_triangle(self) -> u64 {
        let setup = std::mem::size_of::<super::voxelize::TriSetup>();
        match self {
            SceneStage::Svo => (setup + 16) as u64,
            SceneStage::Linespace => (std::mem::size_of::<[[f32; 3]; 3]>() + setup + 16) as u64,
        }
    }
}

/// The size of the placed scene as one mesh, known before it is built: the terrain's grid
/// plus every instance's model (the counts [`pack_geometry`] produces).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlacedSize {
    /// Instances placed (those whose model is known and has a mesh) …
    pub instances: u64,
    /// … of the scene's instances.
    pub scene_instances: u64,
    pub vertices: u64,
    pub triangles: u64,
    /// What the two-level SVO needs at least ([`super::instanced::build_bytes`]); `u64::MAX`
    /// without instances (a pack of bare meshes has no instanced form).
    pub two_level_bytes: u64,
    /// What the two-level line spaces need at least ([`linespace_scene_bytes`]); `u64::MAX`
    /// without instances.
    pub linespace_two_level_bytes: u64,
}

impl PlacedSize {
    /// From a terrain grid (width, height), each model's (vertices, triangles) (None: not
    /// placed, as [`pack_geometry`] skips a model without a mesh) and the instances.
    pub fn of_scene(
        terrain: Option<(u32, u32)>,
        models: &[Option<(u64, u64)>],
        instances: &[Instance],
    ) -> PlacedSize {
        let mut size = PlacedSize {
            scene_instances: instances.len() as u64,
            ..PlacedSize::default()
        };
        let mut terrain_size = (0, 0);
        if let Some((w, h)) = terrain {
            let (w, h) = (w.max(1) as u64, h.max(1) as u64);
            size.vertices = w * h;
            size.triangles = 2 * (w - 1) * (h - 1);
            terrain_size = (size.vertices, size.triangles);
        }
        let mut pack_placed_models = vec![false; models.len()];
        for i in instances {
            if let Some(Some((v, t))) = models.get(i.model as usize) {
                size.instances += 1;
                size.vertices = size.vertices.saturating_add(*v);
                size.triangles = size.triangles.saturating_add(*t);
                pack_placed_models[i.model as usize] = true;
            }
        }
        let model_sizes: Vec<(u64, u64)> = models
            .iter()
            .zip(&pack_placed_models)
            .filter_map(|(m, &p)| m.filter(|_| p))
            .collect();
        size.two_level_bytes =
            super::instanced::build_bytes(terrain_size, &model_sizes, size.instances);
        size.linespace_two_level_bytes =
            linespace_scene_bytes(terrain_size.0, &model_sizes, size.instances);
        size
    }

    /// Bytes of the mesh itself: position, normal and texture coordinate per vertex (32 B),
    /// indices and a material per triangle (16 B).
    pub fn mesh_bytes(&self) -> u64 {
        self.vertices
            .saturating_mul(32)
            .saturating_add(self.triangles.saturating_mul(16))
    }

    /// What `stage` needs at least: the mesh and its own per-triangle data.
    pub fn stage_bytes(&self, stage: SceneStage) -> u64 {
        self.mesh_bytes()
            .saturating_add(self.triangles.saturating_mul(stage.bytes_per_triangle()))
    }

    /// Refuses (exit 4, naming `file`) a placed scene that `stage` could not hold within the
    /// memory budget, before anything is allocated.
    /// For the svo stage a scene that does not fit as one mesh passes when its two-level form
    /// fits ([`Self::svo_two_level`]).
    pub fn check(&self, stage: SceneStage, limits: &Limits, file: &Path) -> Result<()> {
        let bytes = self.stage_bytes(stage);
        if bytes <= limits.max_memory || self.two_level_of(stage) <= limits.max_memory {
            return Ok(());
        }
        let placed = if self.instances == self.scene_instances {
            format!("{} instances", self.instances)
        } else {
            format!(
                "{} of its {} instances (those of the models read so far)",
                self.instances, self.scene_instances
            )
        };
        Err(crate::error::Error::invalid(
            file,
            ParseError::new(
                "instances",
                format!(
                    "the {stage} stage reads the placed scene as one mesh: {placed}, {} \
                     vertices and {} triangles with the terrain, at least {}, more than the {} \
                     budget (--max-memory){two}; turn the stage off (--set \
                     stages.{stage}=false), place fewer instances, or raise --max-memory",
                    self.vertices,
                    self.triangles,
                    human(bytes),
                    human(limits.max_memory),
                    stage = stage.name(),
                    two = match (stage, self.two_level_of(stage)) {
                        (_, u64::MAX) => String::new(),
                        (SceneStage::Svo, b) => format!(
                            ", and its two-level form (one octree per model) needs at least {}",
                            human(b)
                        ),
                        (SceneStage::Linespace, b) => format!(
                            ", and its two-level form (one N-tree per model) needs at least {}",
                            human(b)
                        ),
                    },
                ),
            ),
        ))
    }
}

impl PlacedSize {
    /// Whether the svo stage builds the two-level SVO: the flattened scene exceeds the budget
    /// (and [`Self::check`] passed, so the two-level form fits it).
    pub fn svo_two_level(&self, limits: &Limits) -> bool {
        self.stage_bytes(SceneStage::Svo) > limits.max_memory
            && self.two_level_bytes <= limits.max_memory
    }

    /// Whether the linespace stage builds the two-level line spaces (`linespace-scene`): the
    /// flattened scene exceeds the budget and the two-level form fits it.
    pub fn linespace_two_level(&self, limits: &Limits) -> bool {
        self.stage_bytes(SceneStage::Linespace) > limits.max_memory
            && self.linespace_two_level_bytes <= limits.max_memory
    }

    /// What `stage`'s two-level form needs at least (`u64::MAX`: it has none).
    pub fn two_level_of(&self, stage: SceneStage) -> u64 {
        match stage {
            SceneStage::Svo => self.two_level_bytes,
            SceneStage::Linespace => self.linespace_two_level_bytes,
        }
    }
}

/// What the two-level line spaces (`linespace-scene`) need at least, as
/// `crate::linespace::instanced::build_bytes` documents it (it re-exports this): here, beside
/// [`PlacedSize`], so that the size check needs no line-space code (the layer order).
pub fn linespace_scene_bytes(terrain_samples: u64, models: &[(u64, u64)], instances: u64) -> u64 {
    let model = |(v, t): (u64, u64)| {
        v.saturating_mul(32)
            .saturating_add(t.saturating_mul(16 + 36 + 4 * 20))
    };
    models
        .iter()
        .fold(terrain_samples.saturating_mul(12), |a, &m| {
            a.saturating_add(model(m))
        })
        .saturating_add(instances.saturating_mul(32 + 24 + 27 * 20))
}

/// The terrain of a pack, with its colour map (None: no terrain section).
pub fn pack_terrain(pack: &Pack) -> Result<Option<Terrain>> {
    let Some(e) = pack.of_kind(crate::terrain::source_section::KIND).next() else {
        return Ok(None);
    };
    let view = pack.view(e)?;
    let (meta, mut t) =
        crate::terrain::source_section::from_section(&view).map_err(|e| invalid(pack, e))?;
    if let Some(cs) = meta
        .color_section
        .as_deref()
        .filter(|s| pack.find(s).is_some())
    {
        let v = pack.view_named(cs)?;
        t.color = Some(
            crate::texture::source_section::from_section(&v)
                .map_err(|e| invalid(pack, e))?
                .1,
        );
    }
    Ok(Some(t))
}

/// The two-level SVO of a pack's scene (terrain, models, instances), each model read once.
pub fn pack_instanced_svo(
    pack: &Pack,
    opts: &super::voxelize::VoxelizeOptions,
) -> Result<super::instanced::InstancedSvo> {
    let terrain = pack_terrain(pack)?;
    let (models, inst) = pack_placed_models(pack, |s, g| (s.to_string(), g))?.ok_or_else(|| {
        crate::error::Error::Runtime("the two-level SVO needs an instances section".into())
    })?;
    super::instanced::InstancedSvo::build(terrain.as_ref(), &models, &inst.items, opts)
}

/// What the flattened voxelization left out (the `svo.*` warnings of `bake svo` and the graph's
/// `svo` unit): triangles that left no voxel, and, for a solid fill, the columns that crossed
/// the surface an odd number of times. Zero for the two-level section.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SvoLeftOut {
    pub skipped_triangles: usize,
    pub open_columns: usize,
}

/// The svo stage on a pack: the flattened `svo` section where the placed scene fits the
/// budget, else the two-level `svo-scene` section (refused when neither fits, and when the
/// pack has no triangle), with the section's summary (and the flattened scene's `triangles`)
/// and what the voxelization left out.
pub fn pack_svo_section(
    pack: &Pack,
    opts: &super::voxelize::VoxelizeOptions,
    limits: &Limits,
    file: &Path,
    source: &str,
) -> Result<(crate::pack::Section, serde_json::Value, SvoLeftOut)> {
    let size = placed_size(pack)?;
    size.check(SceneStage::Svo, limits, file)?;
    if size.svo_two_level(limits) {
        let two = pack_instanced_svo(pack, opts)?;
        let sec = super::instanced_section::to_section(
            super::instanced_section::KIND,
            source,
            &two,
            opts.solid,
        );
        let report = super::instanced_section::summary_of(&two);
        return Ok((sec, report, SvoLeftOut::default()));
    }
    let geo = pack_geometry(pack)?;
    if geo.mesh.indices.is_empty() {
        return Err(Error::invalid_at(
            file,
            "geometry",
            "no triangles to voxelize",
        ));
    }
    let v = super::voxelize::mesh_to_voxels(&geo.mesh, &geo.textures, opts)?;
    let svo = super::svo::voxels_to_svo(&v);
    let sec = super::section::to_section(super::section::KIND, source, &svo, opts.solid);
    let left = SvoLeftOut {
        skipped_triangles: v.skipped_triangles,
        open_columns: v.open_columns,
    };
    let mut report = super::section::summary_of(&svo);
    report["triangles"] = serde_json::json!(geo.mesh.indices.len());
    Ok((sec, report, left))
}

/// [`PlacedSize`] of what [`pack_geometry`] would build from `pack`, from the sections'
/// headers and the instance records (no mesh is decoded).
pub fn placed_size(pack: &Pack) -> Result<PlacedSize> {
    let terrain = match pack.of_kind(crate::terrain::source_section::KIND).next() {
        Some(e) => {
            let meta: crate::terrain::source_section::TerrainMeta =
                pack.view(e)?.meta().map_err(|e| invalid(pack, e))?;
            Some((meta.width, meta.height))
        }
        None => None,
    };
    let Some(e) = pack.of_kind(crate::ingest::instances_section::KIND).next() else {
        // Without instances every mesh is taken once.
        let mut size = PlacedSize::of_scene(terrain, &[], &[]);
        size.two_level_bytes = u64::MAX;
        size.linespace_two_level_bytes = u64::MAX;
        let names: Vec<String> = pack
            .of_kind(crate::mesh::section::KIND)
            .map(|e| e.name.clone())
            .collect();
        for n in names {
            let (v, t) = mesh_counts(pack, &n)?;
            size.vertices = size.vertices.saturating_add(v);
            size.triangles = size.triangles.saturating_add(t);
        }
        return Ok(size);
    };
    let view = pack.view(e)?;
    let (meta, inst) =
        crate::ingest::instances_section::from_section(&view).map_err(|e| invalid(pack, e))?;
    let models: Vec<Option<(u64, u64)>> = meta
        .mesh_sections
        .iter()
        .map(|s| pack.find(s).map(|_| mesh_counts(pack, s)).transpose())
        .collect::<Result<_>>()?;
    Ok(PlacedSize::of_scene(terrain, &models, &inst.items))
}

/// (vertices, triangles) of a mesh section, from its array headers.
fn mesh_counts(pack: &Pack, name: &str) -> Result<(u64, u64)> {
    let view = pack.view_named(name)?;
    let count = |array: &str| view.info(array).map_or(0, |a| a.count);
    Ok((count("positions"), count("indices")))
}

/// A closed, bumpy, scan-like procedural surface of `2 · cols · rows` triangles (a sphere
/// displaced by a few sine waves), for benchmarks where no scanned mesh is at hand.
pub fn procedural_blob(cols: u32, rows: u32) -> Mesh {
    let (cols, rows) = (cols.max(3), rows.max(2));
    let mut mesh = Mesh::default();
    for j in 0..=rows {
        let theta = std::f32::consts::PI * j as f32 / rows as f32;
        for i in 0..cols {
            let phi = std::f32::consts::TAU * i as f32 / cols as f32;
            let bump = 1.0
                + 0.12 * (5.0 * phi).sin() * (3.0 * theta).sin()
                + 0.05 * (17.0 * phi + 2.0 * theta).sin() * theta.sin()
                + 0.02 * (41.0 * theta).sin();
            let d = [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ];
            mesh.positions.push(d.map(|x| x * bump));
            mesh.normals.push(d);
            mesh.uvs
                .push([i as f32 / cols as f32, j as f32 / rows as f32]);
        }
    }
    for j in 0..rows {
        for i in 0..cols {
            let a = j * cols + i;
            let b = j * cols + (i + 1) % cols;
            mesh.indices.push([a, b, b + cols]);
            mesh.indices.push([a, b + cols, a + cols]);
        }
    }
    mesh.triangle_materials = vec![0; mesh.indices.len()];
    mesh.materials.push(Material::default());
    mesh.objects.push("procedural blob".into());
    mesh
}
