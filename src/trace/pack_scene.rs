//! The ray-tracing scene of a scene pack, shared by the light-map and environment-map stages:
//! one alpha-tested BVH per model, the instances placed by their transforms, and the terrain as
//! one more (opaque) instance: traced through its min/max quadtree ([`TerrainMode::Heightfield`],
//! the default) or as a BVH over its triangle mesh ([`TerrainMode::Mesh`], kept for comparison;
//! both give the same hits, see `trace::heightfield`).

use crate::error::{Error, Result};
use crate::model::{Instances, Mesh, Rgba8Image, Terrain};
use crate::pack::Pack;
use crate::trace::{
    BuildPreset, Heightfield, InstanceTransform, ModelBvh, SceneBvh, SceneTracer, Tracer,
};
use std::sync::Arc;

/// How the terrain is traced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TerrainMode {
    /// The height grid through its min/max quadtree (no triangle BVH).
    #[default]
    Heightfield,
    /// A BVH over the two triangles per cell (the previous path).
    Mesh,
}

/// A traceable scene and what the lighting stages need to know about its surfaces.
pub struct TraceScene {
    pub bvh: SceneBvh,
    /// Instances of the `instances` section come first, in order; the terrain (if any) is last.
    pub instance_count: usize,
    pub terrain: Option<Terrain>,
    /// Mean diffuse albedo (linear RGB) of every BVH instance.
    pub albedo: Vec<[f32; 3]>,
    /// Height of each model's bounds (model units), for probe placement.
    pub model_height: Vec<f32>,
    pub instances: Instances,
    /// The same scene on Embree, built on first use ([`TraceScene::tracer`]).
    embree: std::sync::OnceLock<Box<dyn SceneTracer>>,
}

impl TraceScene {
    /// The scene on a ray-tracing backend: `cpu` is [`TraceScene::bvh`]; `embree` (cargo
    /// feature `embree`) is its Embree twin, built on the first call and kept. Without the
    /// feature `embree` is refused, naming it.
    pub fn tracer(&self, t: Tracer) -> Result<&dyn SceneTracer> {
        match t {
            Tracer::Cpu => Ok(&self.bvh),
            Tracer::Embree => self.embree(),
        }
    }

    #[cfg(feature = "embree")]
    fn embree(&self) -> Result<&dyn SceneTracer> {
        if self.embree.get().is_none() {
            let e = crate::trace::EmbreeSceneBvh::build(&self.bvh)?;
            let _ = self.embree.set(Box::new(e));
        }
        Ok(&**self.embree.get().expect("set above"))
    }

    #[cfg(not(feature = "embree"))]
    fn embree(&self) -> Result<&dyn SceneTracer> {
        let _ = &self.embree;
        Err(Error::usage(
            Tracer::Embree
                .available_as("tracer")
                .expect_err("no embree feature"),
        ))
    }
}

/// The terrain grid as a triangle mesh in world space (two triangles per cell).
pub fn terrain_mesh(t: &Terrain) -> Mesh {
    let (w, h) = (t.width, t.height);
    let mut mesh = Mesh::default();
    for j in 0..h {
        for i in 0..w {
            mesh.positions.push(t.position(i, j));
            mesh.normals.push(terrain_normal(t, i, j));
            mesh.uvs.push([
                i as f32 / (w - 1).max(1) as f32,
                1.0 - j as f32 / (h - 1).max(1) as f32,
            ]);
        }
    }
    for j in 0..h.saturating_sub(1) {
        for i in 0..w.saturating_sub(1) {
            let a = j * w + i;
            let (b, c, d) = (a + 1, a + w, a + w + 1);
            mesh.indices.push([a, b, d]);
            mesh.indices.push([a, d, c]);
        }
    }
    mesh.triangle_materials = vec![0; mesh.indices.len()];
    mesh.materials.push(crate::model::Material::default());
    mesh
}

/// Normal of the height field at grid sample (i, j) by central differences.
pub fn terrain_normal(t: &Terrain, i: u32, j: u32) -> [f32; 3] {
    let sx = t.extent[0] / (t.width - 1).max(1) as f32;
    let sy = t.extent[1] / (t.height - 1).max(1) as f32;
    let (i0, i1) = (i.saturating_sub(1), (i + 1).min(t.width - 1));
    let (j0, j1) = (j.saturating_sub(1), (j + 1).min(t.height - 1));
    let dzdx = (t.sample(i1, j) - t.sample(i0, j)) / (sx * (i1 - i0).max(1) as f32);
    let dzdy = (t.sample(i, j1) - t.sample(i, j0)) / (sy * (j1 - j0).max(1) as f32);
    let n = glam::Vec3::new(-dzdx, -dzdy, 1.0).normalize();
    n.to_array()
}

/// Mean linear colour of an sRGB image, weighting by coverage (alpha ≥ 0.5).
pub fn mean_linear(img: &Rgba8Image) -> [f32; 3] {
    let mut s = [0.0f64; 3];
    let mut n = 0u64;
    for p in img.pixels.iter().filter(|p| p[3] >= 128) {
        for k in 0..3 {
            s[k] += crate::color::srgb_to_linear(p[k] as f32 / 255.0) as f64;
        }
        n += 1;
    }
    if n == 0 {
        [0.5; 3]
    } else {
        s.map(|v| (v / n as f64) as f32)
    }
}

/// Builds the scene of a pack with `instances` (and optionally `terrain`) sections.
pub fn trace_scene(pack: &Pack) -> Result<TraceScene> {
    trace_scene_with(pack, TerrainMode::default())
}

/// [`trace_scene`] with a choice of terrain tracing.
fn trace_scene_with(pack: &Pack, mode: TerrainMode) -> Result<TraceScene> {
    let bad = |e| Error::invalid(pack.path(), e);
    let (imeta, instances) =
        crate::ingest::instances_section::from_section(&pack.view_named("instances")?)
            .map_err(bad)?;
    let mut models = Vec::new();
    let mut albedo_of_model = Vec::new();
    let mut model_height = Vec::new();
    for name in &imeta.mesh_sections {
        let (meta, mesh) =
            crate::mesh::section::from_section(&pack.view_named(name)?).map_err(bad)?;
        let textures: Vec<Option<Rgba8Image>> = meta
            .textures
            .iter()
            .map(|t| {
                t.section
                    .as_ref()
                    .and_then(|s| pack.view_named(s).ok())
                    .and_then(|v| crate::texture::source_section::from_section(&v).ok())
                    .map(|(_, img)| img)
            })
            .collect();
        let masks = crate::trace::materials::alpha_masks(&mesh, &textures);
        let mats = crate::trace::materials::prt_materials(&mesh, &textures, 0.3);
        let n = mats.len().max(1) as f32;
        albedo_of_model.push(mats.iter().fold([0.0; 3], |a, m| {
            [
                a[0] + m.albedo[0] / n,
                a[1] + m.albedo[1] / n,
                a[2] + m.albedo[2] / n,
            ]
        }));
        let (lo, hi) = mesh.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
        model_height.push(hi[2] - lo[2].min(0.0));
        models.push(Arc::new(ModelBvh::build(
            &mesh,
            &masks,
            BuildPreset::Medium,
        )?));
    }
    let mut transforms: Vec<InstanceTransform> = instances
        .items
        .iter()
        .map(InstanceTransform::from_instance)
        .collect();
    let mut albedo: Vec<[f32; 3]> = instances
        .items
        .iter()
        .map(|i| albedo_of_model[i.model as usize])
        .collect();
    let mut heightfield = None;
    let terrain = match pack.find("terrain") {
        Some(e) => {
            let view = pack.view(e)?;
            let (tmeta, t) = crate::terrain::source_section::from_section(&view).map_err(bad)?;
            let color = tmeta
                .color_section
                .as_ref()
                .and_then(|s| pack.view_named(s).ok())
                .and_then(|v| crate::texture::source_section::from_section(&v).ok());
            albedo.push(color.map_or(crate::terrain::default_albedo(), |(_, img)| {
                mean_linear(&img)
            }));
            match mode {
                TerrainMode::Heightfield => {
                    // The terrain stage's quadtree when the section has one.
                    let stored = crate::terrain::section::is_prepared(&view)
                        .then(|| crate::terrain::section::quadtree_from_section(&view))
                        .transpose()
                        .map_err(bad)?;
                    heightfield = Some(Arc::new(match stored {
                        Some(tree) => Heightfield::with_quadtree(&t, tree)?,
                        None => Heightfield::new(&t)?,
                    }));
                }
                TerrainMode::Mesh => {
                    models.push(Arc::new(ModelBvh::build(
                        &terrain_mesh(&t),
                        &[],
                        BuildPreset::Medium,
                    )?));
                    transforms.push(InstanceTransform {
                        model: (models.len() - 1) as u32,
                        translation: [0.0; 3],
                        scale: 1.0,
                        rotation_deg: 0.0,
                    });
                }
            }
            Some(t)
        }
        None => None,
    };
    let instance_count = instances.items.len();
    let mut bvh = SceneBvh::build(models, transforms)?;
    if let Some(h) = heightfield {
        bvh = bvh.with_terrain(h);
    }
    Ok(TraceScene {
        bvh,
        instance_count,
        terrain,
        albedo,
        model_height,
        instances,
        embree: std::sync::OnceLock::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Instance, Material};
    use crate::pack::PackWriter;
    use crate::trace::{Ray, Rng};
    use glam::Vec3A;

    /// A pack with one box-ish model, 12 instances and a rough 30×20 terrain; with `prepared`
    /// the terrain section carries the terrain stage's quadtree.
    fn pack(prepared: bool) -> Pack {
        let mut rng = Rng::hashed(3);
        let t = Terrain {
            width: 30,
            height: 20,
            heights: (0..600).map(|_| rng.f32() * 2.0).collect(),
            origin: [-5.0, -5.0],
            extent: [40.0, 30.0],
            color: None,
        };
        let mut mesh = Mesh {
            materials: vec![Material::default()],
            ..Mesh::default()
        };
        for k in 0..40u32 {
            for _ in 0..3 {
                mesh.positions.push([rng.f32(), rng.f32(), rng.f32() * 3.0]);
                mesh.normals.push([0.0, 0.0, 1.0]);
                mesh.uvs.push([0.0, 0.0]);
            }
            mesh.indices.push([3 * k, 3 * k + 1, 3 * k + 2]);
            mesh.triangle_materials.push(0);
        }
        let instances = Instances {
            models: vec!["blob".into()],
            items: (0..12)
                .map(|_| Instance {
                    model: 0,
                    position: [rng.f32() * 30.0 - 5.0, rng.f32() * 20.0 - 5.0, 1.0],
                    scale: 1.0 + rng.f32(),
                    rotation_deg: rng.f32() * 360.0,
                    layer: 0,
                })
                .collect(),
        };
        let mut w = PackWriter::new();
        w.insert(crate::mesh::section::to_section(
            "mesh.blob",
            "blob.obj",
            &mesh,
            &[],
        ));
        w.insert(crate::ingest::instances_section::to_section(
            "instances",
            &instances,
            vec!["mesh.blob".into()],
        ));
        let terrain = if prepared {
            let meta = crate::terrain::source_section::TerrainMeta {
                width: t.width,
                height: t.height,
                origin: t.origin,
                extent: t.extent,
                color_section: None,
                source: "test".into(),
            };
            let p = crate::terrain::prepare_terrain(&t).unwrap();
            crate::terrain::section::to_section("terrain", &meta, &t, &p).unwrap()
        } else {
            crate::terrain::source_section::to_section("terrain", "test", &t, None)
        };
        w.insert(terrain);
        Pack::from_bytes(&w.to_bytes().unwrap(), "test.bake").unwrap()
    }

    #[test]
    fn heightfield_and_mesh_terrain_modes_trace_the_same_scene() {
        for prepared in [false, true] {
            let p = pack(prepared);
            let hf = trace_scene(&p).unwrap();
            let mesh = trace_scene_with(&p, TerrainMode::Mesh).unwrap();
            assert_eq!(hf.instance_count, 12);
            assert_eq!(hf.bvh.terrain_instance(), Some(12));
            assert_eq!(
                mesh.bvh.instances().len(),
                13,
                "the mesh terrain is the last instance"
            );
            assert_eq!(hf.albedo, mesh.albedo);
            let mut rng = Rng::hashed(9);
            let mut terrain_hits = 0;
            for _ in 0..2000 {
                let o = Vec3A::new(
                    rng.f32() * 40.0 - 5.0,
                    rng.f32() * 30.0 - 5.0,
                    rng.f32() * 6.0,
                );
                let d = Vec3A::new(rng.f32() - 0.5, rng.f32() - 0.5, -rng.f32());
                let r = Ray::new(o, d.normalize_or(Vec3A::NEG_Z), 1e-4);
                let (a, b) = (hf.bvh.closest_hit(&r), mesh.bvh.closest_hit(&r));
                assert_eq!(
                    a.map(|h| (h.instance, h.hit.t)),
                    b.map(|h| (h.instance, h.hit.t)),
                    "{r:?}"
                );
                assert_eq!(hf.bvh.any_hit(&r), mesh.bvh.any_hit(&r));
                if let (Some(a), Some(b)) = (a, b) {
                    let (sa, sb) = (hf.bvh.surface(&a), mesh.bvh.surface(&b));
                    assert!((sa.position - sb.position).length() < 1e-4);
                    assert!((sa.shading_normal - sb.shading_normal).length() < 1e-4);
                    terrain_hits += (a.instance == 12) as u32;
                }
            }
            assert!(terrain_hits > 500, "{terrain_hits}");
        }
    }
}
