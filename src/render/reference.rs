//! The CPU reference of the renderer: a ray caster that draws the same view of a pack as the
//! wgpu path, from the same [`SceneData`] and [`View`], with the same Rust shading functions
//! (`SchlickMaterial::eval`, the tone map), so a GPU image can be checked pixel by pixel.
//!
//! One primary ray per pixel centre (the rasterizer samples there too) through a two-level BVH
//! (src/trace: one alpha-tested BVH per model, the terrain as one more instance built by
//! [`crate::trace::pack_scene::terrain_mesh`]); the hit becomes a [`HitRecord`] (instance, model,
//! triangle, barycentrics, world position, interpolated normal/tangent/uv, material) and is
//! shaded by the terms of the shading contract: [`Reference::direct_term`] (sun irradiance ×
//! an exact shadow ray × BRDF × cos) and [`Reference::ambient_term`]. Misses show the sky,
//! looked up like shaders/sky.wgsl does. Textures are read like the GPU samplers read them:
//! bilinear between texel centres, sRGB decoded before filtering, repeat on models and clamp
//! on the terrain. Rows are shaded in parallel and collected in order (deterministic).

use super::camera::Camera;
use super::sample::bilinear_with;
use super::scene::{ImageData, ModelData, SceneData, TerrainData};
use super::{RenderOptions, Terms, View};
use crate::color::srgb_to_linear;
use crate::error::Result;
use crate::model::{Material, Mesh, Rgba8Image, Terrain};
use crate::pack::Pack;
use crate::trace::{AlphaMask, BuildPreset, InstanceTransform, ModelBvh, Ray, SceneBvh};
use glam::{Vec3, Vec3A};
use rayon::prelude::*;
use std::f32::consts::PI;
use std::sync::Arc;

/// What a primary ray hit, with every attribute the shading needs (world space).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HitRecord {
    /// Index of the instance in the BVH: the models' instances in [`SceneData`] order, then
    /// the terrain.
    pub instance: u32,
    /// Index into `SceneData::models`; `None` for the terrain.
    pub model: Option<u32>,
    /// Triangle of the model's (regrouped) index list, or of the terrain mesh.
    pub triangle: u32,
    /// Weights of the triangle's three vertices.
    pub barycentrics: [f32; 3],
    /// Ray parameter (the primary ray's direction is unit: metres from the eye).
    pub t: f32,
    pub position: Vec3,
    /// Unit normal of the triangle's plane.
    pub geometric_normal: Vec3,
    /// Interpolated vertex normal, normalized.
    pub normal: Vec3,
    /// Interpolated vertex tangent (xyz normalized) and the bitangent sign w.
    pub tangent: [f32; 4],
    pub uv: [f32; 2],
    /// Material index of the model (0 for the terrain).
    pub material: u32,
    /// World-space gradients of u and of v on a model triangle's plane (zero on the terrain):
    /// with the neighbouring pixels' rays they give the texture footprint (mip level).
    pub uv_gradient: [Vec3; 2],
    /// Texture footprint of the pixel, (∂u/∂x, ∂v/∂x, ∂u/∂y, ∂v/∂y) per pixel, set by
    /// [`Reference::sample`] (zero: level 0).
    pub uv_derivatives: [f32; 4],
}

/// A scene prepared for ray casting.
pub struct Reference<'s, 'a> {
    pub scene: &'s SceneData<'a>,
    bvh: SceneBvh,
    /// The same scene for primary rays where some colour map has mips: those models without
    /// their level-0 alpha masks, the alpha test done per hit at the pixel's mip level as the
    /// GPU does ([`Reference::trace_primary`]).
    primary: Option<SceneBvh>,
    /// Per BVH instance: the model index (`u32::MAX` for the terrain).
    owner: Vec<u32>,
    /// Per BVH instance: its index in `ModelData::instances` of its model.
    slot: Vec<u32>,
    /// Per model, per triangle of `ModelData::indices`: the material.
    triangle_materials: Vec<Vec<u32>>,
    terrain_model: Option<Terrain>,
    /// The ambient term's light (src/render/ambient.rs); without it, the sky's horizontal
    /// irradiance × (1 + n_z)/2 stands in.
    pub ambient: Option<super::ambient::AmbientScene>,
    /// Trace shadow rays (on by default; off gives the unshadowed image a test can hold
    /// against a bound to show the bound detects missing shadows).
    pub shadows: bool,
    /// Toksvig's roughness from the normal map's filtered length (on by default, like
    /// [`RenderOptions::toksvig`]).
    pub toksvig: bool,
    /// Parallax mapping from the colour maps' height chains (off by default, like
    /// [`RenderOptions::parallax`]).
    pub parallax: bool,
}

/// The reference image of a view.
#[derive(Debug, Clone)]
pub struct ReferenceOutput {
    /// sRGB-encoded, row 0 at the top, alpha 255 (like the GPU output).
    pub image: Rgba8Image,
    /// Linear radiance per pixel before the tone map.
    pub radiance: Vec<[f32; 3]>,
    pub view: View,
    pub seconds: f64,
}

/// Renders the view `opts` of `pack` on the CPU (the same defaults as [`super::render_pack`]).
pub fn render_reference(pack: &Pack, opts: &RenderOptions) -> Result<ReferenceOutput> {
    super::check_options(opts)?;
    let t0 = std::time::Instant::now();
    let scene = super::scene::load_scene(pack)?;
    let view = super::resolve_view(pack, &scene, opts);
    let mut r = Reference::build(&scene)?;
    r.toksvig = opts.toksvig;
    r.parallax = opts.parallax;
    r.ambient = Some(super::ambient::load_ambient(
        pack,
        &scene,
        opts.prt_layout,
        opts.lighting.as_ref(),
    )?);
    let radiance =
        r.radiance_image_sampled(&view, (opts.width, opts.height), opts.terms, opts.msaa);
    let image = tone_map_image_encoded(
        &radiance,
        view.exposure,
        (opts.width, opts.height),
        opts.encoding,
    );
    Ok(ReferenceOutput {
        image,
        radiance,
        view,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The model as a `Mesh` for the BVH builder (materials only count; the shading reads
/// [`ModelData`]), and its triangles' materials in the order of `m.indices`.
fn model_mesh(m: &ModelData) -> (Mesh, Vec<u32>) {
    let mut tri_mats = vec![0u32; m.indices.len()];
    for d in &m.draws {
        tri_mats[d.first as usize..(d.first + d.count) as usize].fill(d.material);
    }
    let mesh = Mesh {
        positions: m.positions.to_vec(),
        normals: m.normals.to_vec(),
        uvs: m.uvs.to_vec(),
        indices: m.indices.to_vec(),
        triangle_materials: tri_mats.clone(),
        materials: vec![Material::default(); m.materials.len().max(1)],
        ..Default::default()
    };
    (mesh, tri_mats)
}

/// Alpha masks of a model's materials: the colour map's alpha times the material's opacity,
/// tested at 0.5 (nearest texel; the GPU filters bilinearly, which moves edges by < 1 texel).
fn model_masks(m: &ModelData) -> Vec<Option<AlphaMask>> {
    m.materials
        .iter()
        .map(|mat| {
            let img = mat.color_map.as_ref()?;
            let opacity = mat.schlick.map_or(1.0, |s| s.opacity);
            let pixels = img
                .texels
                .iter()
                .map(|p| [p[0], p[1], p[2], (p[3] as f32 * opacity).round() as u8])
                .collect();
            Some(AlphaMask::from_rgba8(&Rgba8Image {
                width: img.width,
                height: img.height,
                pixels,
            }))
        })
        .collect()
}

/// The terrain of the scene as the model type the mesh builder reads.
fn terrain_model(t: &TerrainData) -> Terrain {
    Terrain {
        width: t.meta.width,
        height: t.meta.height,
        heights: t.heights.to_vec(),
        origin: t.meta.origin,
        extent: t.meta.extent,
        color: None,
    }
}

impl<'s, 'a> Reference<'s, 'a> {
    /// Builds the BVHs of every model and of the terrain.
    pub fn build(scene: &'s SceneData<'a>) -> Result<Self> {
        let mut models = Vec::new();
        let mut transforms = Vec::new();
        let mut owner = Vec::new();
        let mut slot = Vec::new();
        let mut triangle_materials = Vec::new();
        let mut unmasked = Vec::new();
        for (k, m) in scene.models.iter().enumerate() {
            let (mesh, tri_mats) = model_mesh(m);
            let masks = model_masks(m);
            let bvh = Arc::new(ModelBvh::build(&mesh, &masks, BuildPreset::Medium)?);
            let mipped = m.materials.iter().any(|x| x.color_mips.is_some());
            unmasked.push(if mipped && masks.iter().any(|x| x.is_some()) {
                Some(Arc::new(ModelBvh::build(&mesh, &[], BuildPreset::Medium)?))
            } else {
                None
            });
            models.push(bvh);
            triangle_materials.push(tri_mats);
            for (j, i) in m.instances.iter().enumerate() {
                slot.push(j as u32);
                transforms.push(InstanceTransform {
                    model: k as u32,
                    translation: i.position,
                    scale: i.scale,
                    rotation_deg: i.rotation_deg,
                });
                owner.push(k as u32);
            }
        }
        let terrain_model = scene.terrain.as_ref().map(terrain_model);
        if let Some(t) = &terrain_model {
            let mesh = crate::trace::pack_scene::terrain_mesh(t);
            models.push(Arc::new(ModelBvh::build(&mesh, &[], BuildPreset::Medium)?));
            transforms.push(InstanceTransform {
                model: (models.len() - 1) as u32,
                translation: [0.0; 3],
                scale: 1.0,
                rotation_deg: 0.0,
            });
            owner.push(u32::MAX);
            slot.push(0);
        }
        let primary = if unmasked.iter().any(|u| u.is_some()) {
            let list = models
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    unmasked
                        .get(k)
                        .cloned()
                        .flatten()
                        .unwrap_or_else(|| m.clone())
                })
                .collect();
            Some(SceneBvh::build(list, transforms.clone())?)
        } else {
            None
        };
        Ok(Reference {
            scene,
            bvh: SceneBvh::build(models, transforms)?,
            primary,
            owner,
            slot,
            triangle_materials,
            terrain_model,
            ambient: None,
            shadows: true,
            toksvig: true,
            parallax: false,
        })
    }

    /// The instance record a hit belongs to (`None` for the terrain): position, scale, rotation
    /// of the model instance, as `SceneData::models[model].instances` holds it.
    pub fn instance_record(
        &self,
        hit: &HitRecord,
    ) -> Option<&crate::ingest::instances_section::InstanceRecord> {
        let m = self.scene.models.get(hit.model? as usize)?;
        m.instances.get(self.slot[hit.instance as usize] as usize)
    }

    /// The closest hit along `ray` with its attributes.
    pub fn trace(&self, ray: &Ray) -> Option<HitRecord> {
        let h = self.bvh.closest_hit(ray)?;
        Some(self.record(&self.bvh, &h))
    }

    /// The closest hit of a primary ray, alpha-tested as the GPU tests it: where the hit's
    /// colour map has mips, the alpha of the pixel's mip level (trilinear, the footprint that
    /// `footprint` sets) times the opacity against 0.5, blended towards the map's level-0
    /// coverage past its 4×4 level and tested with the ray's `test`
    /// ([`super::coverage::AlphaTest`]); the ray goes on past a rejected hit.
    pub fn trace_primary(
        &self,
        ray: &Ray,
        test: super::coverage::AlphaTest,
        footprint: impl Fn(&mut HitRecord),
    ) -> Option<HitRecord> {
        let Some(bvh) = &self.primary else {
            let mut hit = self.trace(ray)?;
            footprint(&mut hit);
            return Some(hit);
        };
        let mut r = *ray;
        // Each rejected hit moves t_min past it; a bound on the layers of leaves a ray crosses.
        for _ in 0..256 {
            let h = bvh.closest_hit(&r)?;
            let mut hit = self.record(bvh, &h);
            footprint(&mut hit);
            let Some(k) = hit.model else {
                return Some(hit);
            };
            let mat = &self.scene.models[k as usize].materials[hit.material as usize];
            let Some(mips) = &mat.color_mips else {
                return Some(hit);
            };
            let opacity = mat.schlick.map_or(1.0, |s| s.opacity);
            let alpha = trilinear(mips, hit.uv, hit.uv_derivatives)[3] * opacity;
            let [w, h, ..] = mips.levels[0];
            let lambda = super::coverage::mip_lambda((w, h), hit.uv_derivatives);
            let t = super::coverage::far_weight(mips.levels.len(), lambda);
            // Far away the ray's own alpha test at the card's point it meets (level 0).
            let far = if t > 0.0 {
                let a = lookup_at_level(&mips.levels, hit.uv, 0.0, |l, i, j| mips.texel(l, i, j));
                if a[3] * opacity >= 0.5 { 1.0 } else { 0.0 }
            } else {
                0.0
            };
            let distance = (Vec3A::from(hit.position) - ray.origin).length();
            if test.passes_at(alpha, far, t, Some(distance)) {
                return Some(hit);
            }
            r = Ray::new(r.origin, r.dir, hit.t * (1.0 + 1e-6) + 1e-6);
        }
        None
    }

    /// The attributes of BVH hit `h`.
    fn record(&self, bvh: &SceneBvh, h: &crate::trace::scene::SceneHit) -> HitRecord {
        let sp = bvh.surface(h);
        let inst = bvh.instances()[h.instance as usize];
        let (u, v) = (h.hit.u, h.hit.v);
        let bary = [1.0 - u - v, u, v];
        let owner = self.owner[h.instance as usize];
        let mut rec = HitRecord {
            instance: h.instance,
            model: None,
            triangle: h.hit.triangle,
            barycentrics: bary,
            t: h.hit.t,
            position: Vec3::from(sp.position),
            geometric_normal: Vec3::from(sp.geometric_normal),
            normal: Vec3::from(sp.shading_normal),
            tangent: [1.0, 0.0, 0.0, 1.0],
            uv: sp.uv,
            material: 0,
            uv_gradient: [Vec3::ZERO; 2],
            uv_derivatives: [0.0; 4],
        };
        if owner != u32::MAX {
            let m = &self.scene.models[owner as usize];
            let tri = m.indices[h.hit.triangle as usize];
            let t = tri.iter().zip(bary).fold(Vec3::ZERO, |acc, (&i, w)| {
                acc + Vec3::from_slice(&m.tangents[i as usize][..3]) * w
            });
            let t = Vec3::from(inst.normal_to_world(Vec3A::from(t))).normalize_or_zero();
            let w = if m.tangents[tri[0] as usize][3] < 0.0 {
                -1.0
            } else {
                1.0
            };
            rec.model = Some(owner);
            rec.tangent = [t.x, t.y, t.z, w];
            let p =
                tri.map(|i| Vec3::from(inst.point_to_world(Vec3A::from(m.positions[i as usize]))));
            let uv = tri.map(|i| m.uvs[i as usize]);
            rec.uv_gradient = [0, 1].map(|k| plane_gradient(p, [uv[0][k], uv[1][k], uv[2][k]]));
            rec.material = self.triangle_materials[owner as usize][h.hit.triangle as usize];
        }
        rec
    }

    /// Whether nothing blocks the sun seen from `hit` (an exact shadow ray, alpha-tested). The
    /// ray starts on the sun's side of the surface (the side the interpolated normal says, as
    /// the GPU's lookup does; winding orders are not consistent in the inputs), pushed off the
    /// triangle's plane by a few ulps of the position.
    pub fn sun_visible(&self, hit: &HitRecord, sun: Vec3) -> bool {
        if !self.shadows {
            return true;
        }
        let mut ng = hit.geometric_normal;
        if ng.dot(hit.normal) < 0.0 {
            ng = -ng;
        }
        let side = if hit.normal.dot(sun) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let eps = 2e-5 * (1.0 + hit.position.abs().max_element());
        let origin = hit.position + ng * (side * eps);
        !self
            .bvh
            .any_hit(&Ray::new(Vec3A::from(origin), Vec3A::from(sun), eps))
    }

    /// Linear radiance of every pixel of a `size` image of `view`.
    pub fn radiance_image(&self, view: &View, size: (u32, u32), terms: Terms) -> Vec<[f32; 3]> {
        self.radiance_image_sampled(view, size, terms, 1)
    }

    /// Linear radiance of every pixel as the mean of `samples` rays (1: the centre; 4: the
    /// standard 4× sample positions of Vulkan, D3D and Metal, those the GPU's MSAA resolves).
    pub fn radiance_image_sampled(
        &self,
        view: &View,
        size: (u32, u32),
        terms: Terms,
        samples: u32,
    ) -> Vec<[f32; 3]> {
        let (w, h) = size;
        let offsets: &[[f32; 2]] = if samples >= 4 {
            &STANDARD_4X
        } else {
            &[[0.5, 0.5]]
        };
        let n = offsets.len() as f32;
        (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..w).map(move |x| {
                    let mut l = [0.0f32; 3];
                    for (k, &[ox, oy]) in offsets.iter().enumerate() {
                        // The alpha test of each sample: the pixel's dither value shifted by
                        // k/4 under MSAA (the sample mask `mesh.wgsl` writes).
                        let thr = super::coverage::AlphaTest {
                            dither: super::coverage::bayer4(x, y),
                            sample: (offsets.len() > 1).then_some((k as u32, offsets.len() as u32)),
                        };
                        let p = (x as f32 + ox, y as f32 + oy);
                        let s = self.sample_with(view, size, terms, p, thr);
                        l = [l[0] + s[0], l[1] + s[1], l[2] + s[2]];
                    }
                    l.map(|c| c / n)
                })
            })
            .collect::<Vec<_>>()
    }

    /// Radiance of pixel (x, y): the ray through its centre.
    pub fn pixel(&self, view: &View, size: (u32, u32), terms: Terms, x: u32, y: u32) -> [f32; 3] {
        self.sample(view, size, terms, (x as f32 + 0.5, y as f32 + 0.5))
    }

    /// Radiance of the ray through image point `(px, py)` (pixels from the top-left corner),
    /// alpha-tested with the pixel's dither threshold (as without MSAA).
    pub fn sample(
        &self,
        view: &View,
        size: (u32, u32),
        terms: Terms,
        (px, py): (f32, f32),
    ) -> [f32; 3] {
        let thr = super::coverage::AlphaTest {
            dither: super::coverage::bayer4(px.max(0.0) as u32, py.max(0.0) as u32),
            sample: None,
        };
        self.sample_with(view, size, terms, (px, py), thr)
    }

    /// [`Reference::sample`] with the alpha test given.
    fn sample_with(
        &self,
        view: &View,
        (w, h): (u32, u32),
        terms: Terms,
        (px, py): (f32, f32),
        threshold: super::coverage::AlphaTest,
    ) -> [f32; 3] {
        let cam: &Camera = &view.camera;
        let d = cam.pixel_ray((px, py), (w, h));
        let ray = Ray::new(Vec3A::from(cam.eye), Vec3A::from(d), cam.near);
        let ray_at = |px: f32, py: f32| cam.pixel_ray((px, py), (w, h));
        // The footprint: where the next pixel's rays (right, down) meet the hit's plane.
        let footprint = |hit: &mut HitRecord| {
            let n = hit.geometric_normal;
            let [gu, gv] = hit.uv_gradient;
            let mut dd = [0.0f32; 4];
            for (k, d2) in [ray_at(px + 1.0, py), ray_at(px, py + 1.0)]
                .into_iter()
                .enumerate()
            {
                let den = d2.dot(n);
                if den.abs() > 1e-12 {
                    let q = cam.eye + d2 * ((hit.position - cam.eye).dot(n) / den);
                    let delta = q - hit.position;
                    dd[2 * k] = gu.dot(delta);
                    dd[2 * k + 1] = gv.dot(delta);
                }
            }
            hit.uv_derivatives = dd;
        };
        match self.trace_primary(&ray, threshold, footprint) {
            None => {
                let s = sky_radiance(self.scene, d);
                let disc = sun_disc(&view.lighting, d);
                [s[0] + disc[0], s[1] + disc[1], s[2] + disc[2]]
            }
            Some(hit) => {
                let wo = -d;
                let [kd, ka] = terms.weights();
                let mut l = [0.0f32; 3];
                if kd > 0.0 {
                    l = self.direct_term(&hit, wo, view);
                }
                if ka > 0.0 {
                    let a = self.ambient_term(&hit, wo, view);
                    l = [l[0] + a[0], l[1] + a[1], l[2] + a[2]];
                }
                // Emission: full renders only (kd · ka), both faces (docs/CONVENTIONS.md).
                if kd * ka > 0.0
                    && let Brdf::Schlick(m) = &self.surface(&hit, wo).brdf
                {
                    l = [0, 1, 2].map(|k| l[k] + kd * ka * m.emission[k]);
                }
                l
            }
        }
    }

    /// The sun's contribution at `hit` seen from `wo` (unit, towards the eye): E_sun ×
    /// visibility × BRDF × cos. Terrain: Lambert with its colour map and normal map. Models
    /// with a Schlick material: `SchlickMaterial::eval` in the normal-mapped tangent frame,
    /// two-sided (|cos|). Models without: Lambert on the side facing the viewer.
    pub fn direct_term(&self, hit: &HitRecord, wo: Vec3, view: &View) -> [f32; 3] {
        let e = view.lighting.sun_irradiance;
        let sun = Vec3::from(view.lighting.sun_direction).normalize_or_zero();
        if e.iter().all(|&c| c <= 0.0) || sun == Vec3::ZERO {
            return [0.0; 3];
        }
        let surface = self.surface(hit, wo);
        let f_cos = match &surface.brdf {
            Brdf::Schlick(m) => {
                let (t, b, n) = surface.frame;
                let local = |d: Vec3| [d.dot(t), d.dot(b), d.dot(n)];
                let wi = local(sun);
                let f = m.eval(wi, local(wo), surface.map);
                f.map(|c| c * wi[2].abs())
            }
            Brdf::Lambert(albedo) => {
                let c = surface.frame.2.dot(sun).max(0.0) / PI;
                albedo.map(|a| a * c)
            }
        };
        if f_cos.iter().all(|&c| c <= 0.0) || !self.sun_visible(hit, sun) {
            return [0.0; 3];
        }
        [0, 1, 2].map(|k| e[k] * f_cos[k])
    }

    /// L_ambient at `hit` (src/render/ambient.rs, the evaluation `shaders/ambient.wgsl` does):
    /// models by PRT (eq. 4.8), light map or sky irradiance with albedo = base colour × colour
    /// map (what the PRT bake folds in); the terrain by its light map or the sky irradiance.
    pub fn ambient_term(&self, hit: &HitRecord, wo: Vec3, view: &View) -> [f32; 3] {
        let s = self.surface(hit, wo);
        let n = facing(hit.normal, wo);
        let Some(amb) = &self.ambient else {
            let albedo = match &s.brdf {
                Brdf::Schlick(m) => m.bottom_color(s.map),
                Brdf::Lambert(a) => *a,
            };
            let k = (0.5 + 0.5 * n.z) / PI;
            return [0, 1, 2].map(|c| albedo[c] * view.lighting.ambient[c] * k);
        };
        let Some(k) = hit.model else {
            let Some(t) = &self.scene.terrain else {
                return [0.0; 3];
            };
            let n = facing(s.frame.2, wo);
            let p = [hit.position.x, hit.position.y];
            return amb.terrain_radiance(&t.meta, p, n.to_array(), s.map);
        };
        let k = k as usize;
        let m = &self.scene.models[k];
        let mat = &m.materials[hit.material as usize];
        let c = mat.base_color;
        let slot = self.slot[hit.instance as usize] as usize;
        let inst = &m.instances[slot];
        let tri = m.indices[hit.triangle as usize];
        let eye = view.camera.eye;
        let (sa, ca) = inst.rotation_deg.to_radians().sin_cos();
        let turn = |v: [f32; 3]| Vec3::new(ca * v[0] - sa * v[1], sa * v[0] + ca * v[1], v[2]);
        // Per vertex, as mesh.wgsl's vertex shader: the view mirrored about the vertex normal
        // turned towards the eye.
        let mirror = tri.map(|i| {
            let p = m.positions[i as usize].map(|x| x * inst.scale);
            let world = turn(p) + Vec3::from_array(inst.position);
            let wo = (eye - world).normalize_or_zero();
            let nv = turn(m.normals[i as usize]);
            let n = if nv.length_squared() < 1e-12 {
                wo
            } else {
                facing(nv.normalize(), wo)
            };
            (2.0 * n.dot(wo) * n - wo).to_array()
        });
        let layers = match &mat.schlick {
            Some(sm) => super::ambient::ambient_layers(sm, n.dot(wo).clamp(0.0, 1.0)),
            None => super::ambient::AmbientLayers::LAMBERT,
        };
        let h = super::ambient::MeshHit {
            model: k,
            instance: slot,
            vertices: tri,
            barycentrics: hit.barycentrics,
            material: hit.material as usize,
            facing_normal: n.to_array(),
            seen_front: hit.normal.dot(wo) >= 0.0,
            albedo: [c[0] * s.map[0], c[1] * s.map[1], c[2] * s.map[2]],
            layers,
            mirror,
            rotation_deg: inst.rotation_deg,
        };
        amb.mesh_radiance(&h)
    }

    /// The shading inputs at a hit: BRDF, colour-map value and shading frame.
    pub fn surface(&self, hit: &HitRecord, wo: Vec3) -> Surface {
        let Some(k) = hit.model else {
            return self.terrain_surface(hit);
        };
        let m = &self.scene.models[k as usize];
        let mat = &m.materials[hit.material as usize];
        let uv = match (&mat.height_mips, &mat.schlick) {
            (Some(h), Some(s)) if self.parallax => parallax_uv(hit, h, s.bump_height, wo),
            _ => hit.uv,
        };
        let texel = match (&mat.color_mips, &mat.color_map) {
            (Some(mips), _) => trilinear(mips, uv, hit.uv_derivatives),
            (None, Some(img)) => sample_srgb(img, uv, true),
            (None, None) => [1.0; 4],
        };
        let map = [texel[0], texel[1], texel[2]];
        match &mat.schlick {
            Some(s) => {
                // The normal map at the pixel's levels: direction, and |n̄| for Toksvig.
                let (n, s) = match &mat.normal_map {
                    Some(nm) => {
                        let t = trilinear_with(&nm.levels, uv, hit.uv_derivatives, |l, i, j| {
                            nm.texel(l, i, j)
                        });
                        let n = perturb(hit, decode_normal_texel(t).to_array());
                        let s = if self.toksvig {
                            s.with_toksvig(t[3])
                        } else {
                            *s
                        };
                        (n, s)
                    }
                    None => (hit.normal, *s),
                };
                Surface {
                    brdf: Brdf::Schlick(s),
                    map,
                    frame: tangent_frame(n, Vec3::from_slice(&hit.tangent[..3])),
                }
            }
            None => {
                let c = mat.base_color;
                let n = facing(hit.normal, wo);
                Surface {
                    brdf: Brdf::Lambert([c[0] * map[0], c[1] * map[1], c[2] * map[2]]),
                    map,
                    frame: tangent_frame(n, Vec3::from_slice(&hit.tangent[..3])),
                }
            }
        }
    }

    fn terrain_surface(&self, hit: &HitRecord) -> Surface {
        let (Some(t), Some(tm)) = (&self.scene.terrain, &self.terrain_model) else {
            return Surface {
                brdf: Brdf::Lambert([0.0; 3]),
                map: [1.0; 3],
                frame: tangent_frame(hit.normal, Vec3::X),
            };
        };
        let (w, h) = (tm.width, tm.height);
        let (ox, oy) = (tm.origin[0], tm.origin[1]);
        let (ex, ey) = (tm.extent[0], tm.extent[1]);
        let p = hit.position;
        let uv = [(p.x - ox) / ex, 1.0 - (p.y - oy) / ey];
        // Without a colour map the terrain is sRGB 128 grey, like the GPU upload.
        let d = crate::terrain::default_albedo();
        let grey = [d[0], d[1], d[2], 1.0];
        let c = t
            .color
            .as_ref()
            .map_or(grey, |img| sample_srgb(img, uv, false));
        // The normal map has one texel per grid sample, row 0 south: texel centres sit on the
        // samples, so the bilinear lookup interpolates the sample normals.
        let gx = (p.x - ox) / ex * (w - 1) as f32;
        let gy = (p.y - oy) / ey * (h - 1) as f32;
        let nimg = ImageData {
            width: w,
            height: h,
            texels: &t.normals,
        };
        let nuv = [(gx + 0.5) / w as f32, (gy + 0.5) / h as f32];
        let n = decode_normal_texel(bilinear(&nimg, nuv, false, unorm));
        Surface {
            brdf: Brdf::Lambert([c[0], c[1], c[2]]),
            map: [c[0], c[1], c[2]],
            frame: tangent_frame(n, Vec3::X),
        }
    }
}

/// How a surface reflects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Brdf {
    Schlick(crate::material::schlick::SchlickMaterial),
    /// Diffuse albedo, linear RGB.
    Lambert([f32; 3]),
}

/// Shading inputs at a hit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    pub brdf: Brdf,
    /// The colour map's linear RGB at the hit (1 without a map).
    pub map: [f32; 3],
    /// Tangent, bitangent, normal (orthonormal; the normal is normal-mapped).
    pub frame: (Vec3, Vec3, Vec3),
}

/// `n` turned towards the viewer (`wo` points to the eye); a degenerate `n` becomes `wo`.
fn facing(n: Vec3, wo: Vec3) -> Vec3 {
    if n.length_squared() < 1e-12 {
        return wo;
    }
    if n.dot(wo) < 0.0 { -n } else { n }
}

/// An orthonormal frame around `n` with the tangent as close to `t` as possible (Gram–Schmidt;
/// any orthogonal tangent where `t` is parallel to `n`). The bitangent's sign does not matter to
/// the BRDF (the anisotropy reads cos² of the azimuth).
pub fn tangent_frame(n: Vec3, t: Vec3) -> (Vec3, Vec3, Vec3) {
    let n = n.normalize_or(Vec3::Z);
    let mut tt = t - n * n.dot(t);
    if tt.length_squared() < 1e-12 {
        let a = super::scene::any_tangent(n.to_array());
        tt = Vec3::new(a[0], a[1], a[2]);
    }
    let tt = tt.normalize();
    (tt, n.cross(tt), n)
}

/// The interpolated normal bent by a tangent-space normal `ts` (+X = tangent, +Y = bitangent
/// `w·(n × t)`, +Z = normal).
fn perturb(hit: &HitRecord, ts: [f32; 3]) -> Vec3 {
    let n = hit.normal;
    let t = Vec3::from_slice(&hit.tangent[..3]);
    let b = n.cross(t) * hit.tangent[3];
    (t * ts[0] + b * ts[1] + n * ts[2]).normalize_or(n)
}

fn unorm(p: &[u8; 4]) -> [f32; 4] {
    p.map(|c| c as f32 / 255.0)
}

fn srgb(p: &[u8; 4]) -> [f32; 4] {
    [
        srgb_to_linear(p[0] as f32 / 255.0),
        srgb_to_linear(p[1] as f32 / 255.0),
        srgb_to_linear(p[2] as f32 / 255.0),
        p[3] as f32 / 255.0,
    ]
}

fn decode_normal_texel(c: [f32; 4]) -> Vec3 {
    Vec3::new(c[0] * 2.0 - 1.0, c[1] * 2.0 - 1.0, c[2] * 2.0 - 1.0).normalize_or(Vec3::Z)
}

/// A tangent-space normal from a normal map (bilinear on the encoded values, as the GPU does).
/// The gradient on a triangle's plane of the value `f` given at its corners `p`: the vector g
/// in the plane with g·(p1 − p0) = f1 − f0 and g·(p2 − p0) = f2 − f0 (zero for a degenerate
/// triangle).
fn plane_gradient(p: [Vec3; 3], f: [f32; 3]) -> Vec3 {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a * c - b * b;
    if det.abs() <= 1e-20 * (a * c).max(f32::MIN_POSITIVE) {
        return Vec3::ZERO;
    }
    let (f1, f2) = (f[1] - f[0], f[2] - f[0]);
    let x = (c * f1 - b * f2) / det;
    let y = (a * f2 - b * f1) / det;
    e1 * x + e2 * y
}

/// Parallax mapping with offset limiting (shaders/mesh.wgsl `parallax_uv`): the height h at the
/// hit's texture point and level, d = (2h − 1)·bump metres along the normal, the tangent-plane
/// offset o = d·(V − n(n·V)) towards the viewer `wo`, and uv + (∇u·o, ∇v·o) with the
/// triangle's uv gradients.
pub fn parallax_uv(
    hit: &HitRecord,
    heights: &super::scene::HeightMips,
    bump: f32,
    wo: Vec3,
) -> [f32; 2] {
    let h = trilinear_with(&heights.levels, hit.uv, hit.uv_derivatives, |l, i, j| {
        heights.texel(l, i, j)
    })[0];
    let d = (2.0 * h - 1.0) * bump;
    let n = hit.normal;
    let v = wo.normalize_or_zero();
    let o = d * (v - n * n.dot(v));
    [
        hit.uv[0] + hit.uv_gradient[0].dot(o),
        hit.uv[1] + hit.uv_gradient[1].dot(o),
    ]
}

/// Trilinear lookup in a processed colour map's mips with repeat addressing, the level from the
/// footprint as the Vulkan spec writes it (§ "Scale Factor Operation"): ρ = max(|∂(u·w, v·h)/∂x|,
/// |∂(u·w, v·h)/∂y|) at level 0's size, λ = log₂ ρ clamped to the chain, the two nearest levels
/// bilinear and blended by λ's fraction.
pub fn trilinear(mips: &super::scene::ColorMips, uv: [f32; 2], d: [f32; 4]) -> [f32; 4] {
    trilinear_with(&mips.levels, uv, d, |l, i, j| mips.texel(l, i, j))
}

/// [`trilinear`] over any mip chain of level table `levels` (width, height, first, count),
/// `texel(level, i, j)` reading one texel of a level.
pub fn trilinear_with(
    levels: &[[u32; 4]],
    uv: [f32; 2],
    d: [f32; 4],
    texel: impl Fn(usize, u32, u32) -> [f32; 4],
) -> [f32; 4] {
    let [w, h, ..] = levels[0];
    lookup_at_level(levels, uv, super::coverage::mip_lambda((w, h), d), texel)
}

/// The lookup of [`trilinear_with`] at level `lambda` (clamped to the chain): the two nearest
/// levels bilinear with repeat addressing, blended by `lambda`'s fraction (a shader's
/// `textureSampleLevel`).
pub fn lookup_at_level(
    levels: &[[u32; 4]],
    uv: [f32; 2],
    lambda: f32,
    texel: impl Fn(usize, u32, u32) -> [f32; 4],
) -> [f32; 4] {
    let top = (levels.len() - 1) as f32;
    let lambda = lambda.clamp(0.0, top);
    let l0 = lambda.floor() as usize;
    let l1 = (l0 + 1).min(levels.len() - 1);
    let f = lambda - l0 as f32;
    let level = |l: usize| {
        let [lw, lh, ..] = levels[l];
        bilinear_with((lw, lh), uv, |i, j| {
            texel(
                l,
                i.rem_euclid(lw as i64) as u32,
                j.rem_euclid(lh as i64) as u32,
            )
        })
    };
    let a = level(l0);
    if f == 0.0 || l1 == l0 {
        return a;
    }
    let b = level(l1);
    [0, 1, 2, 3].map(|k| a[k] + (b[k] - a[k]) * f)
}

/// A colour map texel as the `Rgba8UnormSrgb` sampler returns it: linear RGB, alpha.
fn sample_srgb(img: &ImageData, uv: [f32; 2], repeat: bool) -> [f32; 4] {
    bilinear(img, uv, repeat, srgb)
}

/// Bilinear filtering between texel centres, like a `Linear` sampler at level 0: repeat or
/// clamp-to-edge addressing, `decode` applied to each texel before the weights.
pub fn bilinear(
    img: &ImageData,
    uv: [f32; 2],
    repeat: bool,
    decode: fn(&[u8; 4]) -> [f32; 4],
) -> [f32; 4] {
    let (w, h) = (img.width as i64, img.height as i64);
    let wrap = |i: i64, n: i64| {
        if repeat {
            i.rem_euclid(n)
        } else {
            i.clamp(0, n - 1)
        }
    };
    bilinear_with((img.width, img.height), uv, |i, j| {
        decode(&img.texels[(wrap(j, h) * w + wrap(i, w)) as usize])
    })
}

/// The sky along unit `d` (shaders/sky.wgsl `sky_radiance`): the sky stage's cube, bilinear and
/// seamless ([`crate::cube::CubeMap::sample`], the section's half floats that the GPU holds);
/// else the lat-long image, bilinear with wrap in u and clamp in v.
pub fn sky_radiance(scene: &SceneData, d: Vec3) -> [f32; 3] {
    let sky = &scene.sky;
    if let Some(cube) = &sky.cube {
        return cube.sample([d.x as f64, d.y as f64, d.z as f64]);
    }
    let (w, h) = (sky.width as i64, sky.height as i64);
    let theta = d.z.clamp(-1.0, 1.0).acos();
    let mut phi = d.y.atan2(d.x);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let uv = [phi / (2.0 * PI), theta / PI];
    bilinear_with((sky.width, sky.height), uv, |i, j| {
        let t = sky.texels[(j.clamp(0, h - 1) * w + i.rem_euclid(w)) as usize];
        [t[0], t[1], t[2]]
    })
}

/// The sun's disc seen along `d`: radiance E/Ω inside the cap cos ρ = 1 − Ω/2π around the sun
/// (as shaders/sky.wgsl draws it), zero outside or without a disc.
pub fn sun_disc(l: &super::Lighting, d: Vec3) -> [f32; 3] {
    let omega = l.sun_solid_angle;
    if omega <= 0.0 || d.dot(Vec3::from(l.sun_direction)) < 1.0 - omega / (2.0 * PI) {
        return [0.0; 3];
    }
    l.sun_irradiance.map(|e| e / omega)
}

pub use crate::color::linear_to_srgb;

/// The display value of radiance `l`: `1 − exp(−L·s)`, sRGB-encoded, rounded to 8 bits (what
/// the tone-map pass writes into the `Rgba8UnormSrgb` target).
pub fn tone_map(l: f32, exposure: f32) -> u8 {
    tone_map_encoded(l, exposure, super::Encoding::Srgb)
}

/// The display value of radiance `l` under `encoding`: `1 − exp(−L·s)`, then sRGB or the
/// thesis' power L_s^γ, rounded to 8 bits.
pub fn tone_map_encoded(l: f32, exposure: f32, encoding: super::Encoding) -> u8 {
    let v = (1.0 - (-l.max(0.0) * exposure).exp()).clamp(0.0, 1.0);
    let e = match encoding {
        super::Encoding::Srgb => linear_to_srgb(v),
        super::Encoding::Gamma(g) => v.powf(g),
    };
    (e * 255.0).round() as u8
}

/// Tone-maps a radiance image into an sRGB RGBA8 image.
pub fn tone_map_image(radiance: &[[f32; 3]], exposure: f32, size: (u32, u32)) -> Rgba8Image {
    tone_map_image_encoded(radiance, exposure, size, super::Encoding::Srgb)
}

/// Tone-maps a radiance image into an RGBA8 image with `encoding`.
pub fn tone_map_image_encoded(
    radiance: &[[f32; 3]],
    exposure: f32,
    (w, h): (u32, u32),
    encoding: super::Encoding,
) -> Rgba8Image {
    Rgba8Image {
        width: w,
        height: h,
        pixels: radiance
            .iter()
            .map(|l| {
                let [r, g, b] = l.map(|c| tone_map_encoded(c, exposure, encoding));
                [r, g, b, 255]
            })
            .collect(),
    }
}

/// The standard 4× sample positions within a pixel (x right, y down, in pixels), as Vulkan
/// (`VkPhysicalDeviceLimits::standardSampleLocations`), D3D and Metal define them.
pub const STANDARD_4X: [[f32; 2]; 4] = [
    [0.375, 0.125],
    [0.875, 0.375],
    [0.125, 0.625],
    [0.625, 0.875],
];

/// How far two images of the same size are apart (RGB only).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ImageDifference {
    /// Mean absolute difference over pixels and channels, in 8-bit steps.
    pub mad: f64,
    /// Fraction of pixels where some channel differs by more than `threshold`.
    pub fraction_over: f64,
    pub threshold: u8,
    /// Largest difference of any channel.
    pub max: u8,
}

/// Compares two images (`None` when their sizes differ).
pub fn image_difference(a: &Rgba8Image, b: &Rgba8Image, threshold: u8) -> Option<ImageDifference> {
    if (a.width, a.height) != (b.width, b.height) || a.pixels.len() != b.pixels.len() {
        return None;
    }
    let (mut sum, mut over, mut max) = (0u64, 0u64, 0u8);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        let d = [0, 1, 2].map(|k| p[k].abs_diff(q[k]));
        sum += d.iter().map(|&x| x as u64).sum::<u64>();
        let m = d.into_iter().max().unwrap_or(0);
        over += u64::from(m > threshold);
        max = max.max(m);
    }
    let n = a.pixels.len().max(1) as f64;
    Some(ImageDifference {
        mad: sum as f64 / (3.0 * n),
        fraction_over: over as f64 / n,
        threshold,
        max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_map_matches_the_formula() {
        // 1 − exp(−L s) = 0.5 at L s = ln 2; sRGB(0.5) = 0.7354 → 188.
        assert_eq!(tone_map(std::f32::consts::LN_2, 1.0), 188);
        assert_eq!(tone_map(0.0, 3.0), 0);
        assert_eq!(tone_map(1e9, 1.0), 255);
    }

    #[test]
    fn the_gamma_encoding_is_the_plain_power_of_the_tone_mapped_value() {
        use crate::render::Encoding;
        // L s = −ln 0.4: L_s = 0.6; 0.6^1 → 153, 0.6^(1/2.2) = 0.7927 → 202.
        let l = -(0.4f32.ln());
        assert_eq!(tone_map_encoded(l, 1.0, Encoding::Gamma(1.0)), 153);
        assert_eq!(tone_map_encoded(l, 1.0, Encoding::Gamma(1.0 / 2.2)), 202);
        assert_eq!(tone_map_encoded(l, 1.0, Encoding::Srgb), tone_map(l, 1.0));
        assert_eq!(tone_map_encoded(1e9, 1.0, Encoding::Gamma(3.0)), 255);
    }

    #[test]
    fn bilinear_interpolates_between_texel_centres() {
        let texels = [[0u8, 0, 0, 0], [255, 0, 0, 0]];
        let img = ImageData {
            width: 2,
            height: 1,
            texels: &texels,
        };
        // u = 0.5 lies halfway between the centres 0.25 and 0.75.
        let c = bilinear(&img, [0.5, 0.5], false, unorm);
        assert!((c[0] - 0.5).abs() < 1e-6);
        // Clamped beyond the last centre, wrapped when repeating.
        assert_eq!(bilinear(&img, [1.0, 0.5], false, unorm)[0], 1.0);
        assert!((bilinear(&img, [1.0, 0.5], true, unorm)[0] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn tangent_frame_is_orthonormal_and_keeps_the_tangent_direction() {
        let n = Vec3::new(0.2, -0.3, 0.9).normalize();
        let (t, b, nn) = tangent_frame(n, Vec3::new(1.0, 0.1, 0.0));
        assert!((t.length() - 1.0).abs() < 1e-5 && (b.length() - 1.0).abs() < 1e-5);
        assert!(t.dot(nn).abs() < 1e-5 && b.dot(nn).abs() < 1e-5 && t.dot(b).abs() < 1e-5);
        assert!(t.x > 0.9);
    }

    #[test]
    fn image_difference_counts_pixels_over_the_threshold() {
        let a = Rgba8Image {
            width: 2,
            height: 1,
            pixels: vec![[10, 10, 10, 255], [100, 100, 100, 255]],
        };
        let mut b = a.clone();
        b.pixels[1] = [100, 130, 100, 255];
        let d = image_difference(&a, &b, 24).unwrap();
        assert_eq!(d.max, 30);
        assert!((d.mad - 30.0 / 6.0).abs() < 1e-12);
        assert!((d.fraction_over - 0.5).abs() < 1e-12);
    }
}
