//! The renderer's ambient term L_ambient (seed 000 4.6, 4.7.2, 4.7.3): everything but the direct
//! sun. Resolved here on the CPU once per pack, then used both by the GPU upload
//! (`shaders/ambient.wgsl` evaluates the same formulas) and by the CPU reference.
//!
//! # Models with a `prt:<model>` section: eq. 4.8 per vertex
//! Per vertex and side s ∈ {F, B}, with the transfer sets 0 (all paths) and 1 (≥ 1 bounce):
//! `L_s = P_s0·C_H + P_s1·C_S` (SH dot products per colour channel), then for the side the
//! viewer sees, `L = L_seen·(1 − t) + L_other·t` (eq. 4.8 for the front, mirrored for the back).
//! - C_H: the instance's sky map, C_S: the instance's sun map, both SH order 4 RGB in the
//!   instance's frame. C_S here is the *sun environment* of the thesis: the SH of the direct sun
//!   (E_sun·y_i(s), the delta towards the sun turned into the instance frame) plus the sun light the
//!   scene reflects towards the instance (the `envmaps`/`clusters` C_S). Only the ≥ 1-bounce set
//!   meets it, so the sun's direct hit on the vertex (the direct term's job, shadow map and all)
//!   is never counted here, while its interreflection and transmission inside the plant are.
//!   Deviation from the thesis' text: it used set 0 for the back side because its direct shader
//!   had no transmission; ours has (src/material/schlick.rs), so eq. 4.8 as printed (set 1 on both
//!   sides) is the one without double counting. Known limit: the direct sun in C_S is not
//!   shadowed per instance (a plant in a terrain shadow keeps its inner sun bounces).
//! - Source of the maps, first found: the `clusters` section (multiquadric interpolation at the
//!   instance position, [`crate::envmap::interp`]), the `envmaps` section, else the sky SH (`sh`
//!   section) turned into the instance frame with no reflected sun.
//! - Frames: the `envmaps` maps are in the instance frame, `C_local(d) = C_world(R_z(θ)·d)`
//!   (`ShRadiance::rotated_z(−θ)`, src/envmap/bake.rs); the `clusters` samples are in the world
//!   frame (only world-frame maps vary smoothly between instances of unrelated rotations), so the
//!   interpolated map is turned into the instance's frame here ([`to_instance_frame`]).
//! - Albedo: the transfer has the receiving vertex's albedo folded in (src/light/prt.rs: the
//!   material's sRGB-decoded diffuse colour × the mean linear colour of its colour map's opaque
//!   texels, and the 1/π). The runtime restores the texture detail by multiplying with
//!   `base_colour × texel / albedo_folded` ([`PrtData::albedo_scale`]), which is 1 on average
//!   over the texture and never applies the albedo twice.
//! - Layout: the full transfer (`transfer`, 192 floats per vertex) by default; the thesis' packed
//!   layout (`gpu`, 5 vec4 per side: band 0 RGB, bands 1–3 luminance, P_S ≈ fraction × P_H) is
//!   decoded by [`decode_packed`] (bands 1–3 take band 0's chromaticity) and its loss measured by
//!   [`packed_layout_error`].
//!
//! # Terrain and models without PRT: irradiance E, `L = albedo·E/π`
//! E from the surface's `lightmap` section when there is one (bilinear, clamped to the edge;
//! texel (i, j) centred at x₀ + (i + ½)·extent/W, row 0 north), else the sky SH irradiance for
//! the facing normal. The light-map stage stores the *total* irradiance, direct sun included;
//! the direct part is taken out again: the `indirect` array the light-map stage now writes beside
//! it, else (older terrain maps) by recomputing exactly what the bake added,
//! `E_sun·max(0, n·s)·V` with the bake's own normals, disc samples and per-texel seeds
//! ([`strip_terrain_direct_sun`]). A mesh light map
//! (atlas) is read generically: an irradiance texture plus per-vertex (or per instance and vertex)
//! light-map UVs (`lightmap_uv` array).

use super::scene::{ModelData, SceneData, SkyData};
use crate::error::{Error, Result};
use crate::light::prt::{COEFFS, GPU_VEC4_PER_SIDE, PER_VERTEX, PrtMaterial, SETS, SIDES};
use crate::pack::Pack;
use crate::pack::kinds::instances::{InstanceRecord, InstancesMeta};
use crate::sh::{ShIrradiance, ShRadiance};
use std::f32::consts::PI;

/// RGB SH coefficients of order 4.
pub type Sh16 = [[f32; 3]; COEFFS];

/// The scene's light from outside: the sun-free sky and the sun.
#[derive(Debug, Clone, PartialEq)]
pub struct SkyLight {
    /// Sun-free sky radiance, world frame.
    pub sky: ShRadiance,
    pub irradiance: ShIrradiance,
    /// Unit direction towards the sun and its irradiance.
    pub sun: Option<([f32; 3], [f32; 3])>,
}

/// One instance's maps in its own frame (see the module doc: `sun` includes the direct sun's SH).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstanceEnv {
    pub sky: Sh16,
    pub sun: Sh16,
}

/// Where the instances' maps came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EnvSource {
    Clusters,
    Envmaps,
    Sky,
}

/// Which PRT layout the runtime evaluates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum PrtLayout {
    /// The full-precision transfer (2 sides × 2 sets × 16 RGB per vertex).
    #[default]
    Full,
    /// The thesis' 5 vec4 per side.
    Packed,
}

/// A model's transfer as the runtime reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct PrtData {
    pub vertices: usize,
    /// `[vertex][side][set][coefficient]` RGB.
    pub transfer: Vec<[f32; 3]>,
    /// `[vertex][side][5]` vec4.
    pub packed: Vec<[f32; 4]>,
    pub materials: Vec<PrtMaterial>,
}

impl PrtData {
    /// Translucence t of a mesh material (0 for materials the bake did not describe).
    pub fn translucence(&self, material: usize) -> f32 {
        self.materials.get(material).map_or(0.0, |m| m.translucence)
    }

    /// `1 / albedo_folded` per channel (0 where the folded albedo is 0): the fragment multiplies
    /// the PRT radiance by `base_colour × texel × albedo_scale`.
    pub fn albedo_scale(&self, material: usize) -> [f32; 3] {
        let a = self.materials.get(material).map_or([0.0; 3], |m| m.albedo);
        a.map(|v| if v > 0.0 { 1.0 / v } else { 0.0 })
    }
}

/// Irradiance per texel (RGB, alpha 1), the direct sun taken out.
#[derive(Debug, Clone, PartialEq)]
pub struct LightTexture {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<[f32; 4]>,
}

impl LightTexture {
    /// Bilinear lookup at texture coordinates (u, v) ∈ [0, 1]² (v = 0 at row 0), texel centres at
    /// (i + ½)/W, clamped to the edge; the same arithmetic as `lightmap_bilinear` in the shader.
    pub fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        let (w, h) = (self.width as i64, self.height as i64);
        super::reference::bilinear_with((self.width, self.height), [u, v], |x, y| {
            let t = self.texels[(y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize];
            [t[0], t[1], t[2]]
        })
    }
}

/// A mesh's light map: the texture and light-map UVs per vertex (`per_instance`: per instance
/// and vertex, instance-major).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshLightmap {
    pub texture: LightTexture,
    pub uvs: Vec<[f32; 2]>,
    pub per_instance: bool,
}

/// The ambient light of one model of [`SceneData::models`].
#[derive(Debug, Clone, PartialEq)]
pub struct ModelAmbient {
    /// Used unless a light map is present.
    pub prt: Option<PrtData>,
    pub lightmap: Option<MeshLightmap>,
    /// One per instance, in [`ModelData::instances`] order.
    pub envs: Vec<InstanceEnv>,
}

/// Everything the ambient term needs, resolved from a pack.
#[derive(Debug, Clone, PartialEq)]
pub struct AmbientScene {
    pub light: SkyLight,
    pub source: EnvSource,
    pub layout: PrtLayout,
    /// The terrain's light map, in its colour map's coordinates.
    pub terrain: Option<LightTexture>,
    pub models: Vec<ModelAmbient>,
    pub warnings: Vec<String>,
}

fn bad(pack: &Pack) -> impl Fn(crate::error::ParseError) -> Error + '_ {
    |e| Error::invalid(pack.path(), e)
}

/// The sun-free sky and the sun: the `sh` and `sun` sections, else the SH projection of the
/// drawn sky (the built-in one has no sun; a pack sky without an `sh` section keeps its sun in
/// the projection, which a warning says).
pub fn sky_light(pack: &Pack, sky: &SkyData, warnings: &mut Vec<String>) -> Result<SkyLight> {
    if pack.find(crate::sky::SH_SECTION).is_some() {
        let l = crate::lightmap::scene_lighting(pack)?;
        return Ok(SkyLight {
            irradiance: l.sky.to_irradiance(),
            sky: l.sky,
            sun: l.sun,
        });
    }
    if !sky.analytic {
        warnings.push("no `sh` section: the ambient light is the SH of the whole sky".into());
    }
    let img = crate::model::FloatImage {
        width: sky.width,
        height: sky.height,
        pixels: sky.texels.iter().map(|t| [t[0], t[1], t[2]]).collect(),
    };
    let sh = crate::sh::project_latlong(&img);
    Ok(SkyLight {
        irradiance: sh.to_irradiance(),
        sky: sh,
        sun: None,
    })
}

/// The SH of the direct sun, `E·y_i(s)`, in a frame turned by `rotation_deg` about +Z.
pub fn sun_sh_local(sun: Option<([f32; 3], [f32; 3])>, rotation_deg: f32) -> Sh16 {
    let Some((s, e)) = sun else {
        return [[0.0; 3]; COEFFS];
    };
    let a = -rotation_deg.to_radians();
    let (sa, ca) = a.sin_cos();
    let local = [ca * s[0] - sa * s[1], sa * s[0] + ca * s[1], s[2]];
    let y = crate::sh::eval_basis16(local);
    std::array::from_fn(|i| e.map(|c| c * y[i]))
}

/// A world-frame map in the frame of an instance turned by `rotation_deg`.
pub fn to_instance_frame(world: &Sh16, rotation_deg: f32) -> Sh16 {
    ShRadiance { coeffs: *world }
        .rotated_z(-(rotation_deg as f64).to_radians())
        .coeffs
}

/// An instance-frame map back in the world frame.
pub fn to_world_frame(local: &Sh16, rotation_deg: f32) -> Sh16 {
    ShRadiance { coeffs: *local }
        .rotated_z((rotation_deg as f64).to_radians())
        .coeffs
}

fn add_sh(a: &Sh16, b: &Sh16) -> Sh16 {
    std::array::from_fn(|i| std::array::from_fn(|c| a[i][c] + b[i][c]))
}

/// Every instance's (C_H, C_S without the direct sun), instance frame, in the `instances`
/// section's order, and where they came from.
pub fn instance_maps(
    pack: &Pack,
    records: &[InstanceRecord],
    light: &SkyLight,
) -> Result<(Vec<(Sh16, Sh16)>, EnvSource)> {
    if pack.find(crate::envmap::section::CLUSTERS_KIND).is_some() {
        return Ok((cluster_maps(pack, records)?, EnvSource::Clusters));
    }
    if pack.find(crate::envmap::section::ENVMAPS_KIND).is_some() {
        let v = pack.view_named(crate::envmap::section::ENVMAPS_KIND)?;
        let (_, sky, sun) = crate::envmap::section::envmaps_from_section(&v).map_err(bad(pack))?;
        if sky.len() != records.len() {
            return Err(Error::invalid_at(
                pack.path(),
                "section \"envmaps\"",
                format!("{} maps for {} instances", sky.len(), records.len()),
            ));
        }
        return Ok((sky.into_iter().zip(sun).collect(), EnvSource::Envmaps));
    }
    let maps = records
        .iter()
        .map(|r| {
            let ch = to_instance_frame(&light.sky.coeffs, r.rotation_deg);
            (ch, [[0.0; 3]; COEFFS])
        })
        .collect();
    Ok((maps, EnvSource::Sky))
}

/// Multiquadric reconstruction of every instance's maps from the `clusters` section (world-frame
/// samples): stored neighbours and weights when present, else solved here with the section's k
/// and R; then turned into each instance's frame.
fn cluster_maps(pack: &Pack, records: &[InstanceRecord]) -> Result<Vec<(Sh16, Sh16)>> {
    use crate::envmap::section::{ClustersMeta, DIM};
    let place = "section \"clusters\"";
    let v = pack.view_named(crate::envmap::section::CLUSTERS_KIND)?;
    let meta: ClustersMeta = v.meta().map_err(bad(pack))?;
    let pts: Vec<[f32; 3]> = v.array_vec("sample_positions").map_err(bad(pack))?;
    let vals: Vec<f32> = v.array_vec("sample_values").map_err(bad(pack))?;
    let owner: Vec<u32> = v.array_vec("sample_instance").map_err(bad(pack))?;
    let invalid = |m: String| Error::invalid_at(pack.path(), place, m);
    if meta.dim as usize != DIM || vals.len() != pts.len() * DIM || owner.len() != pts.len() {
        return Err(invalid(format!(
            "{} samples, {} values, {} owners, dim {}: expected {DIM} values per sample",
            pts.len(),
            vals.len(),
            owner.len(),
            meta.dim
        )));
    }
    if meta.instances as usize != records.len() || pts.is_empty() {
        return Err(invalid(format!(
            "{} instances and {} samples for a scene of {} instances",
            meta.instances,
            pts.len(),
            records.len()
        )));
    }
    // The samples are in the world frame (docs/FORMAT.md); each one's instance must exist.
    if let Some(s) = owner.iter().position(|&i| i as usize >= records.len()) {
        return Err(invalid(format!("sample {s} names instance {}", owner[s])));
    }
    let world = vals;
    let stored = stored_weights(&v, &meta, pts.len(), records.len()).map_err(invalid)?;
    let ip = crate::envmap::interp::Interpolator {
        constant_term: meta.constant_term,
        ..crate::envmap::interp::Interpolator::new(
            &pts,
            &world,
            DIM,
            meta.radius,
            meta.k.max(1) as usize,
        )
    };
    // Per instance in parallel, collected in order: deterministic whatever the thread count.
    use rayon::prelude::*;
    let out = records
        .par_iter()
        .enumerate()
        .map(|(i, r)| {
            let mut buf = vec![0.0f32; DIM];
            match &stored {
                Some((nb, w)) => blend(&world, &nb[i], &w[i], &mut buf),
                None => {
                    ip.reconstruct(r.position, &mut buf);
                }
            }
            let (h, sn) = split_dim(&buf);
            (
                to_instance_frame(&h, r.rotation_deg),
                to_instance_frame(&sn, r.rotation_deg),
            )
        })
        .collect();
    Ok(out)
}

/// Per-instance neighbours and weights of a `clusters` section that stores them.
#[allow(clippy::type_complexity)]
fn stored_weights(
    v: &crate::pack::section::SectionView,
    meta: &crate::envmap::section::ClustersMeta,
    samples: usize,
    instances: usize,
) -> std::result::Result<Option<(Vec<Vec<u32>>, Vec<Vec<f32>>)>, String> {
    if !meta.weights {
        return Ok(None);
    }
    let nb: Vec<u32> = v.array_vec("neighbours").map_err(|e| e.to_string())?;
    let w: Vec<f32> = v.array_vec("weights").map_err(|e| e.to_string())?;
    let k = meta.k as usize;
    if k == 0 || nb.len() != instances * k || w.len() != nb.len() {
        return Err(format!(
            "{} neighbours and {} weights for {instances} instances × k = {k}",
            nb.len(),
            w.len()
        ));
    }
    if let Some(p) = nb.iter().position(|&j| j as usize >= samples) {
        return Err(format!("neighbour {p} names sample {} of {samples}", nb[p]));
    }
    Ok(Some((
        nb.chunks(k).map(<[u32]>::to_vec).collect(),
        w.chunks(k).map(<[f32]>::to_vec).collect(),
    )))
}

fn blend(values: &[f32], nb: &[u32], w: &[f32], out: &mut [f32]) {
    let dim = out.len();
    let mut acc = vec![0.0f64; dim];
    for (&j, &wj) in nb.iter().zip(w) {
        let v = &values[j as usize * dim..(j as usize + 1) * dim];
        for (a, &c) in acc.iter_mut().zip(v) {
            *a += wj as f64 * c as f64;
        }
    }
    for (o, a) in out.iter_mut().zip(acc) {
        *o = a as f32;
    }
}

/// 96 floats (C_H then C_S, `[coefficient][rgb]`) as two maps.
fn split_dim(v: &[f32]) -> (Sh16, Sh16) {
    let m = |o: usize| std::array::from_fn(|i| std::array::from_fn(|c| v[o + i * 3 + c]));
    (m(0), m(COEFFS * 3))
}

/// The `instances` records and, per model of a scene, the indices of its instances among them.
type InstanceLists = (Vec<InstanceRecord>, Vec<Vec<usize>>);

/// Global `instances` indices of each model of `scene` (by its name and mesh section), in
/// [`ModelData::instances`] order; `None` for a pack without an `instances` section.
fn model_instance_indices(pack: &Pack, scene: &SceneData) -> Result<Option<InstanceLists>> {
    let kind = crate::pack::kinds::instances::KIND;
    let Some(e) = pack.of_kind(kind).next() else {
        return Ok(None);
    };
    let v = pack.view(e)?;
    let meta: InstancesMeta = v.meta().map_err(bad(pack))?;
    let recs: Vec<InstanceRecord> = v.array_vec("instances").map_err(bad(pack))?;
    let lists = scene
        .models
        .iter()
        .map(|m| {
            let idx = meta
                .models
                .iter()
                .zip(&meta.mesh_sections)
                .position(|(n, s)| *n == m.name && *s == m.section);
            recs.iter()
                .enumerate()
                .filter(|(_, r)| Some(r.model as usize) == idx)
                .map(|(k, _)| k)
                .collect()
        })
        .collect();
    Ok(Some((recs, lists)))
}

/// The sky light of an explicit [`Lighting`](super::light::Lighting) (`RenderOptions::lighting`):
/// its sun, and a sky whose irradiance is the preview's `E(n) = A·(1 + n_z)/2` for the ambient A
/// (exactly two SH coefficients: band 0 and the z function of band 1).
pub fn lighting_sky(l: &super::light::Lighting) -> SkyLight {
    let y0 = crate::sh::eval_basis16([0.0, 0.0, 1.0]);
    let (b0, b1) = (y0[0], y0[2]);
    let mut irr = [[0.0; 3]; COEFFS];
    irr[0] = l.ambient.map(|a| 0.5 * a / b0);
    irr[2] = l.ambient.map(|a| 0.5 * a / b1);
    let mut rad = [[0.0; 3]; COEFFS];
    rad[0] = irr[0].map(|c| c / PI);
    rad[2] = irr[2].map(|c| c / (2.0 * PI / 3.0));
    let sun = (l.sun_irradiance != [0.0; 3]).then_some((l.sun_direction, l.sun_irradiance));
    SkyLight {
        sky: ShRadiance { coeffs: rad },
        irradiance: ShIrradiance { coeffs: irr },
        sun,
    }
}

/// Resolves the ambient light of `scene` from `pack`. An `explicit` lighting replaces every
/// baked light (sky SH, environment maps, light maps: they were baked for the pack's own sky).
pub fn load_ambient(
    pack: &Pack,
    scene: &SceneData,
    layout: PrtLayout,
    explicit: Option<&super::light::Lighting>,
) -> Result<AmbientScene> {
    let mut warnings = Vec::new();
    let light = match explicit {
        Some(l) => lighting_sky(l),
        None => sky_light(pack, &scene.sky, &mut warnings)?,
    };
    let (maps, source, lists) = match model_instance_indices(pack, scene)? {
        Some((recs, lists)) if explicit.is_some() => {
            let maps = recs
                .iter()
                .map(|r| {
                    (
                        to_instance_frame(&light.sky.coeffs, r.rotation_deg),
                        [[0.0; 3]; 16],
                    )
                })
                .collect();
            (maps, EnvSource::Sky, Some(lists))
        }
        Some((recs, lists)) => {
            let (maps, source) = instance_maps(pack, &recs, &light)?;
            (maps, source, Some(lists))
        }
        None => (Vec::new(), EnvSource::Sky, None),
    };
    let mut models = Vec::with_capacity(scene.models.len());
    for (k, m) in scene.models.iter().enumerate() {
        let envs = match &lists {
            Some(lists) => lists[k]
                .iter()
                .zip(&m.instances)
                .map(|(&g, r)| env_of(&maps[g], r, &light))
                .collect(),
            None => m
                .instances
                .iter()
                .map(|r| {
                    let ch = to_instance_frame(&light.sky.coeffs, r.rotation_deg);
                    env_of(&(ch, [[0.0; 3]; COEFFS]), r, &light)
                })
                .collect(),
        };
        let lightmap = match explicit {
            None => load_mesh_lightmap(pack, m, &mut warnings)?,
            Some(_) => None,
        };
        models.push(ModelAmbient {
            prt: load_prt(pack, m, &mut warnings)?,
            lightmap,
            envs,
        });
    }
    let terrain = match explicit {
        None => load_terrain_lightmap(pack, &light, &mut warnings)?,
        Some(_) => None,
    };
    Ok(AmbientScene {
        light,
        source,
        layout,
        terrain,
        models,
        warnings,
    })
}

fn env_of(maps: &(Sh16, Sh16), r: &InstanceRecord, light: &SkyLight) -> InstanceEnv {
    InstanceEnv {
        sky: maps.0,
        sun: add_sh(&maps.1, &sun_sh_local(light.sun, r.rotation_deg)),
    }
}

/// The `prt:<model>` section of a model, checked against its vertex count.
fn load_prt(pack: &Pack, m: &ModelData, warnings: &mut Vec<String>) -> Result<Option<PrtData>> {
    let name = crate::light::prt_pack::section_name(&m.section);
    if pack.find(&name).is_none() {
        return Ok(None);
    }
    let v = pack.view_named(&name)?;
    let (meta, mut t) = crate::light::prt_pack::from_section(&v).map_err(bad(pack))?;
    // A model drawn with split vertices: the transfer of the mesh vertex each copies.
    let source = m.vertex_source.as_deref();
    let mesh_vertices = source.map_or(m.positions.len(), |_| {
        pack.view_named(&m.section)
            .ok()
            .and_then(|s| s.info("positions").map(|i| i.count as usize))
            .unwrap_or(0)
    });
    if t.vertices as usize != mesh_vertices || meta.mesh != m.section {
        warnings.push(format!(
            "{name}: {} vertices of {:?} for a mesh {:?} of {}: not used",
            t.vertices, meta.mesh, m.section, mesh_vertices
        ));
        return Ok(None);
    }
    let mut packed: Vec<[f32; 4]> = match v.info("gpu") {
        Some(_) => v.array_vec("gpu").map_err(bad(pack))?,
        None => crate::light::prt::pack_gpu(&t),
    };
    if packed.len() != t.vertices as usize * SIDES * GPU_VEC4_PER_SIDE {
        return Err(Error::invalid_at(
            pack.path(),
            format!("section {name:?} array \"gpu\""),
            format!("{} vec4 for {} vertices", packed.len(), t.vertices),
        ));
    }
    if let Some(source) = source {
        packed = gather_rows(&packed, source, SIDES * GPU_VEC4_PER_SIDE);
        let k = t.coeffs.len() / (t.vertices as usize).max(1);
        t.coeffs = gather_rows(&t.coeffs, source, k);
        t.vertices = source.len() as u32;
    }
    Ok(Some(PrtData {
        vertices: t.vertices as usize,
        transfer: t.coeffs,
        packed,
        materials: meta.materials,
    }))
}

/// The radiance of both sides of vertex `v` (front, back) before eq. 4.8's translucence mix:
/// `P_s0·C_H + P_s1·C_S` per side.
pub fn side_radiance(
    prt: &PrtData,
    layout: PrtLayout,
    v: usize,
    env: &InstanceEnv,
) -> [[f32; 3]; 2] {
    std::array::from_fn(|side| {
        let (h, s) = match layout {
            PrtLayout::Full => {
                let at = |set: usize| {
                    let o = ((v * SIDES + side) * SETS + set) * COEFFS;
                    &prt.transfer[o..o + COEFFS]
                };
                (dot(at(0), &env.sky), dot(at(1), &env.sun))
            }
            PrtLayout::Packed => {
                let o = (v * SIDES + side) * GPU_VEC4_PER_SIDE;
                let (p, frac) = decode_packed(&prt.packed[o..o + GPU_VEC4_PER_SIDE]);
                (dot(&p, &env.sky), dot(&p, &env.sun).map(|c| c * frac))
            }
        };
        std::array::from_fn(|c| h[c] + s[c])
    })
}

fn dot(p: &[[f32; 3]], c: &Sh16) -> [f32; 3] {
    let mut out = [0.0f32; 3];
    for (pi, ci) in p.iter().zip(c) {
        for k in 0..3 {
            out[k] += pi[k] * ci[k];
        }
    }
    out
}

/// The thesis' 5 vec4 of one side as an RGB transfer and the indirect fraction: bands 1–3 take
/// band 0's chromaticity (luminance-normalised), grey where band 0 is black.
pub fn decode_packed(p: &[[f32; 4]]) -> ([[f32; 3]; COEFFS], f32) {
    let b0 = [p[0][0], p[0][1], p[0][2]];
    let l0 = crate::light::prt::luminance(b0);
    let chroma = if l0 > 0.0 {
        b0.map(|c| c / l0)
    } else {
        [1.0; 3]
    };
    let mut out = [[0.0; 3]; COEFFS];
    out[0] = b0;
    for i in 1..COEFFS {
        let m = p[1 + (i - 1) / 4][(i - 1) % 4];
        out[i] = chroma.map(|c| c * m);
    }
    (out, p[0][3])
}

/// Eq. 4.8 for the side the viewer sees: `L_seen·(1 − t) + L_other·t`, clamped at 0.
pub fn mix_sides(sides: [[f32; 3]; 2], t: f32, seen_front: bool) -> [f32; 3] {
    let (seen, other) = if seen_front {
        (sides[0], sides[1])
    } else {
        (sides[1], sides[0])
    };
    std::array::from_fn(|c| (seen[c] * (1.0 - t) + other[c] * t).max(0.0))
}

/// Diffuse radiance of a surface of albedo ρ receiving irradiance E: ρ·E/π (E clamped at 0).
pub fn lambert(albedo: [f32; 3], e: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|c| albedo[c] * e[c].max(0.0) / PI)
}

/// Relative RMS difference between the packed and the full layout over every vertex, side and
/// instance of a model: `sqrt(Σ|L_packed − L_full|² / Σ|L_full|²)` of the per-side radiance.
pub fn packed_layout_error(prt: &PrtData, envs: &[InstanceEnv]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for env in envs {
        for v in 0..prt.vertices {
            let f = side_radiance(prt, PrtLayout::Full, v, env);
            let p = side_radiance(prt, PrtLayout::Packed, v, env);
            for side in 0..2 {
                for c in 0..3 {
                    num += ((p[side][c] - f[side][c]) as f64).powi(2);
                    den += (f[side][c] as f64).powi(2);
                }
            }
        }
    }
    if den > 0.0 { (num / den).sqrt() } else { 0.0 }
}

/// Floats per vertex the GPU reads for `layout`.
pub fn floats_per_vertex(layout: PrtLayout) -> usize {
    match layout {
        PrtLayout::Full => PER_VERTEX * 3,
        PrtLayout::Packed => SIDES * GPU_VEC4_PER_SIDE * 4,
    }
}

/// The terrain's `lightmap` section (surface "terrain") with the direct sun taken out.
fn load_terrain_lightmap(
    pack: &Pack,
    light: &SkyLight,
    warnings: &mut Vec<String>,
) -> Result<Option<LightTexture>> {
    let Some((name, meta, mut tex)) = find_lightmap(pack, "terrain")? else {
        return Ok(None);
    };
    let v = pack.view_named(&name)?;
    if let Some(indirect) = indirect_array(&v, &tex).map_err(bad(pack))? {
        tex.texels = indirect;
        return Ok(Some(tex));
    }
    if light.sun.is_some() {
        let scene = crate::tracescene::trace_scene(pack)?;
        match strip_terrain_direct_sun(&mut tex, &meta, &scene, light) {
            Ok(()) => {}
            Err(m) => {
                warnings.push(format!(
                    "{name}: {m}; the sky SH lights the terrain instead"
                ));
                return Ok(None);
            }
        }
    }
    Ok(Some(tex))
}

/// The first `lightmap` section whose surface is `surface`: (name, meta, texture).
fn find_lightmap(
    pack: &Pack,
    surface: &str,
) -> Result<Option<(String, crate::lightmap::section::LightmapMeta, LightTexture)>> {
    for e in pack.of_kind(crate::lightmap::section::KIND) {
        let v = pack.view(e)?;
        let meta: crate::lightmap::section::LightmapMeta = v.meta().map_err(bad(pack))?;
        if meta.surface != surface {
            continue;
        }
        let (meta, map) = crate::lightmap::section::from_section(&v).map_err(bad(pack))?;
        if map.texels.is_empty() {
            return Err(Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                "an empty light map",
            ));
        }
        let tex = LightTexture {
            width: map.width,
            height: map.height,
            texels: map.texels.iter().map(|t| [t[0], t[1], t[2], 1.0]).collect(),
        };
        return Ok(Some((e.name.clone(), meta, tex)));
    }
    Ok(None)
}

/// An `indirect` array (irradiance without the direct sun) if the section has one.
fn indirect_array(
    v: &crate::pack::section::SectionView,
    tex: &LightTexture,
) -> std::result::Result<Option<Vec<[f32; 4]>>, crate::error::ParseError> {
    if v.info("indirect").is_none() {
        return Ok(None);
    }
    let t: Vec<[f32; 4]> = v.array_vec("indirect")?;
    if t.len() != tex.texels.len() {
        return Err(crate::error::ParseError::new(
            "lightmap array \"indirect\"",
            format!("{} texels, expected {}", t.len(), tex.texels.len()),
        ));
    }
    Ok(Some(t.iter().map(|x| [x[0], x[1], x[2], 1.0]).collect()))
}

/// Subtracts from a terrain light map without an `indirect` array (older packs) the direct sun
/// its bake added, recomputed exactly ([`crate::lightmap::terrain_direct_sun`]). `Err` when the
/// map does not fit the scene's terrain.
pub fn strip_terrain_direct_sun(
    tex: &mut LightTexture,
    meta: &crate::lightmap::section::LightmapMeta,
    scene: &crate::tracescene::TraceScene,
    light: &SkyLight,
) -> std::result::Result<(), String> {
    if scene.terrain.is_none() {
        return Err("the pack has no terrain".into());
    }
    if tex.texels.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err("texel count does not match width × height".into());
    }
    let l = crate::lightmap::Lighting {
        sky: light.sky,
        sun: light.sun,
    };
    let direct = crate::lightmap::terrain_direct_sun(scene, &l, meta);
    for (texel, d) in tex.texels.iter_mut().zip(direct) {
        for c in 0..3 {
            texel[c] = (texel[c] - d[c]).max(0.0);
        }
    }
    Ok(())
}

/// A `lightmap` section for a mesh (surface = its mesh section) with light-map UVs
/// (`lightmap_uv`, per vertex or per instance and vertex). Without an `indirect` array the map
/// still holds the direct sun, which a warning says.
fn load_mesh_lightmap(
    pack: &Pack,
    m: &ModelData,
    warnings: &mut Vec<String>,
) -> Result<Option<MeshLightmap>> {
    let Some((name, _, mut texture)) = find_lightmap(pack, &m.section)? else {
        return Ok(None);
    };
    let v = pack.view_named(&name)?;
    let n = m.positions.len();
    let uvs: Vec<[f32; 2]> = match (v.info("lightmap_uv"), &m.vertex_source) {
        (Some(_), _) => v.array_vec("lightmap_uv").map_err(bad(pack))?,
        // The model is drawn with the atlas' split vertices: each tile's UVs of them.
        (None, Some(_)) => split_vertex_uvs(&v, n).map_err(bad(pack))?,
        (None, None) => {
            warnings.push(format!(
                "{name}: no `lightmap_uv` array: light map not used"
            ));
            return Ok(None);
        }
    };
    let per_instance = match uvs.len() {
        l if l == n => false,
        l if l == n * m.instances.len() => true,
        l => {
            return Err(Error::invalid_at(
                pack.path(),
                format!("section {name:?} array \"lightmap_uv\""),
                format!("{l} UVs for {n} vertices × {} instances", m.instances.len()),
            ));
        }
    };
    match indirect_array(&v, &texture).map_err(bad(pack))? {
        Some(t) => texture.texels = t,
        None => warnings.push(format!(
            "{name}: no `indirect` array: the object's light map counts the direct sun twice"
        )),
    }
    Ok(Some(MeshLightmap {
        texture,
        uvs,
        per_instance,
    }))
}

/// Rows of `k` items of `a`, one per entry of `source` (the row it names).
fn gather_rows<T: Copy>(a: &[T], source: &[u32], k: usize) -> Vec<T> {
    source
        .iter()
        .flat_map(|&v| &a[v as usize * k..(v as usize + 1) * k])
        .copied()
        .collect()
}

/// Light-map UVs of an atlas' own vertices (which the model draws when its atlas split mesh
/// vertices), per tile slot: `tiles[s].xy + atlas_uv[v] · tiles[s].zw`.
fn split_vertex_uvs(
    v: &crate::pack::section::SectionView,
    vertices: usize,
) -> std::result::Result<Vec<[f32; 2]>, crate::error::ParseError> {
    let atlas_uv: Vec<[f32; 2]> = v.array_vec("atlas_uv")?;
    let tiles: Vec<[f32; 4]> = v.array_vec("tiles")?;
    if atlas_uv.len() != vertices {
        return Err(crate::error::ParseError::new(
            "lightmap array \"atlas_uv\"",
            format!("{} UVs for {vertices} atlas vertices", atlas_uv.len()),
        ));
    }
    Ok(tiles
        .iter()
        .flat_map(|r| {
            atlas_uv
                .iter()
                .map(move |u| [r[0] + u[0] * r[2], r[1] + u[1] * r[3]])
        })
        .collect())
}

/// What [`AmbientScene`] resolved, for the render statistics.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AmbientSummary {
    /// Where the instances' C_H and C_S came from.
    pub source: EnvSource,
    pub prt_layout: PrtLayout,
    /// Models lit by PRT, by a light map, by the sky irradiance.
    pub prt_models: usize,
    pub lightmap_models: usize,
    pub sky_models: usize,
    pub terrain_light_map: bool,
}

impl AmbientScene {
    pub fn summary(&self) -> AmbientSummary {
        let count = |k| self.models.iter().filter(|m| m.mode() == k).count();
        AmbientSummary {
            source: self.source,
            prt_layout: self.layout,
            prt_models: count(MeshAmbientMode::Prt),
            lightmap_models: count(MeshAmbientMode::Lightmap),
            sky_models: count(MeshAmbientMode::SkyIrradiance),
            terrain_light_map: self.terrain.is_some(),
        }
    }
}

/// What lights a model's surfaces in the ambient term.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshAmbientMode {
    Prt,
    Lightmap,
    SkyIrradiance,
}

impl ModelAmbient {
    /// Light map first (placed once, whole-scene shadows), then PRT, then the sky.
    pub fn mode(&self) -> MeshAmbientMode {
        if self.lightmap.is_some() {
            MeshAmbientMode::Lightmap
        } else if self.prt.is_some() {
            MeshAmbientMode::Prt
        } else {
            MeshAmbientMode::SkyIrradiance
        }
    }
}

/// One hit of a primary ray on an instanced model, as the reference sees it.
#[derive(Debug, Clone, Copy)]
pub struct MeshHit {
    pub model: usize,
    /// Index into the model's instances.
    pub instance: usize,
    /// The triangle's vertex indices and barycentric weights.
    pub vertices: [u32; 3],
    pub barycentrics: [f32; 3],
    pub material: usize,
    /// World-space unit normal facing the viewer.
    pub facing_normal: [f32; 3],
    /// True when the viewer is on the side the interpolated vertex normal points to.
    pub seen_front: bool,
    /// `base_colour × texel` (linear).
    pub albedo: [f32; 3],
}

impl AmbientScene {
    /// L_ambient at a hit on a model (the CPU reference's evaluation of `ambient.wgsl`).
    pub fn mesh_radiance(&self, h: &MeshHit) -> [f32; 3] {
        let m = &self.models[h.model];
        let interp = |f: &dyn Fn(usize) -> [f32; 3]| -> [f32; 3] {
            let mut out = [0.0f32; 3];
            for (&v, &b) in h.vertices.iter().zip(&h.barycentrics) {
                let x = f(v as usize);
                (0..3).for_each(|c| out[c] += b * x[c]);
            }
            out
        };
        match m.mode() {
            MeshAmbientMode::Lightmap => {
                let lm = m.lightmap.as_ref().expect("mode says light map");
                let base = if lm.per_instance {
                    h.instance * (lm.uvs.len() / m.instances_len())
                } else {
                    0
                };
                let uv = interp(&|v| {
                    let t = lm.uvs[base + v];
                    [t[0], t[1], 0.0]
                });
                lambert(h.albedo, lm.texture.sample(uv[0], uv[1]))
            }
            MeshAmbientMode::Prt => {
                let prt = m.prt.as_ref().expect("mode says PRT");
                let env = &m.envs[h.instance];
                let front = interp(&|v| side_radiance(prt, self.layout, v, env)[0]);
                let back = interp(&|v| side_radiance(prt, self.layout, v, env)[1]);
                let l = mix_sides([front, back], prt.translucence(h.material), h.seen_front);
                let k = prt.albedo_scale(h.material);
                std::array::from_fn(|c| l[c] * h.albedo[c] * k[c])
            }
            MeshAmbientMode::SkyIrradiance => {
                lambert(h.albedo, self.light.irradiance.eval(h.facing_normal))
            }
        }
    }

    /// L_ambient on the terrain at world (x, y) with facing normal n and albedo ρ.
    pub fn terrain_radiance(
        &self,
        terrain: &crate::pack::kinds::terrain::TerrainMeta,
        xy: [f32; 2],
        n: [f32; 3],
        albedo: [f32; 3],
    ) -> [f32; 3] {
        match &self.terrain {
            Some(tex) => {
                let u = (xy[0] - terrain.origin[0]) / terrain.extent[0];
                let v = 1.0 - (xy[1] - terrain.origin[1]) / terrain.extent[1];
                lambert(albedo, tex.sample(u, v))
            }
            None => lambert(albedo, self.light.irradiance.eval(n)),
        }
    }
}

impl ModelAmbient {
    fn instances_len(&self) -> usize {
        self.envs.len().max(1)
    }
}

#[cfg(test)]
mod tests;
