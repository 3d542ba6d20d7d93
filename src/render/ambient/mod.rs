//! The renderer's ambient term L_ambient (seed 000 4.6, 4.7.2, 4.7.3): everything but the direct
//! sun. Resolved here on the CPU once per pack, then used both by the GPU upload
//! (`shaders/ambient.wgsl` evaluates the same formulas) and by the CPU reference.
//! The light per instance is in `env.rs`, eq. 4.8 per vertex in `prt_eval.rs`, the light maps
//! in `lightmaps.rs`.
//!
//! # Models with a `prt:<model>` section: eq. 4.8 per vertex
//! Per vertex and side s ∈ {F, B}, with the transfer sets 0 (all paths) and 1 (≥ 1 bounce):
//! `L_s = P_s0·(C_H + C_S) + P_s1·S` (SH dot products per colour channel), then for the side the
//! viewer sees, `L = L_seen·(1 − t) + L_other·t` (eq. 4.8 for the front, mirrored for the back).
//! - C_H: the instance's sky map, C_S: the instance's sun map (the sunlight the terrain and the
//!   other instances reflect towards it, src/envmap/bake.rs), both SH order 4 RGB in the
//!   instance's frame and both incident radiance, so both meet the all-paths set. S is the SH of
//!   the direct sun (E_sun·y_i(s), the delta towards the sun turned into the instance frame): only
//!   the ≥ 1-bounce set meets it, so the sun's direct hit on the vertex (the direct term's job,
//!   shadow map and all) is never counted here, while its interreflection and transmission inside
//!   the plant are. (Until issue 35 C_S met the ≥ 1-bounce set too, which dropped the reflected
//!   sunlight's first hit: a house wall facing sunlit ground got 0.57 of the path-traced ambient,
//!   docs/VALIDATION.md.)
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
//! - Albedo: the transfer has the receiving vertex's albedo folded in (src/prt/transfer.rs: the
//!   material's sRGB-decoded diffuse colour × the mean linear colour of its colour map's opaque
//!   texels, and the 1/π). The runtime restores the texture detail by multiplying with
//!   `base_colour × texel / albedo_folded` ([`PrtData::albedo_scale`]), which is 1 on average
//!   over the texture and never applies the albedo twice.
//! - Layout: the full transfer (`transfer`, 192 floats per vertex) by default; the thesis' packed
//!   layout (`gpu`, 5 vec4 per side: band 0 RGB, bands 1–3 luminance, P_S ≈ fraction × P_H) is
//!   decoded by [`decode_packed`] (bands 1–3 take band 0's chromaticity) and its loss measured by
//!   [`packed_layout_error`].
//!
//! - Material: a material section's layers turn the mixed irradiance into reflected light and add
//!   the top layer's gloss times the instance's maps in the view's mirror direction
//!   ([`reflect_ambient`], `gloss.rs`); a spec-0 colour is exactly the formula above.
//!
//! # Terrain and models without PRT: irradiance E, `L = albedo·E/π`
//! (Models with a material section: through the layers and with the sky's SH as the mirrored
//! environment, `gloss.rs`; a light map scales it by its share of the open sky's irradiance.)
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
use crate::ingest::instances_section::{InstanceRecord, InstancesMeta};
use crate::pack::Pack;
use crate::prt::transfer::{COEFFS, GPU_VEC4_PER_SIDE, PER_VERTEX, PrtMaterial, SETS, SIDES};
use crate::sh::{ShIrradiance, ShRadiance};
use std::f32::consts::PI;

mod env;
mod gloss;
mod lightmaps;
mod prt_eval;
#[cfg(test)]
mod tests;

pub use env::*;
pub use gloss::*;
pub use lightmaps::*;
pub use prt_eval::*;

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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
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
        crate::render::sample::bilinear_with((self.width, self.height), [u, v], |x, y| {
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
    pub warnings: Vec<crate::diag::Warning>,
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

/// The light the all-paths set meets (`sky`: C_H plus the scene's reflected sunlight C_S, both
/// incident radiance at the instance) and the light only the ≥ 1-bounce set meets (`sun`: the
/// direct sun's SH, whose first hit is the direct term's).
fn env_of(maps: &(Sh16, Sh16), r: &InstanceRecord, light: &SkyLight) -> InstanceEnv {
    InstanceEnv {
        sky: add_sh(&maps.0, &maps.1),
        sun: sun_sh_local(light.sun, r.rotation_deg),
    }
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
    /// The material's factors for the view ([`ambient_layers`]; [`AmbientLayers::LAMBERT`]
    /// for a model without a material section).
    pub layers: AmbientLayers,
    /// Per vertex of the triangle: the unit world direction mirroring the view about the vertex
    /// normal turned towards the viewer (the GPU's vertex shader evaluates the environment there
    /// and interpolates the radiance, so the reference does the same).
    pub mirror: [[f32; 3]; 3],
    /// The instance's rotation about +Z in degrees (into its maps' frame).
    pub rotation_deg: f32,
}

impl AmbientScene {
    /// L_ambient at a hit on a model (the CPU reference's evaluation of `ambient.wgsl`): the
    /// irradiance of the mode (PRT, light map, sky) through the material's layers
    /// ([`reflect_ambient`]), plus the top layer's gloss times the environment in the mirror
    /// direction: the instance's maps (C_H + C_S) for PRT, the sky's SH otherwise, there
    /// scaled by the light map's share of the open sky's irradiance (its occlusion).
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
        let corner = |f: &dyn Fn([f32; 3]) -> [f32; 3]| -> [f32; 3] {
            let mut out = [0.0f32; 3];
            for (d, &b) in h.mirror.iter().zip(&h.barycentrics) {
                let x = f(*d);
                (0..3).for_each(|c| out[c] += b * x[c]);
            }
            out
        };
        let sky_mirror = || corner(&|d| self.light.sky.eval(d));
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
                let e = lm.texture.sample(uv[0], uv[1]);
                let open = self.light.irradiance.eval(h.facing_normal);
                let k = occlusion(e, open);
                let e = e.map(|c| c.max(0.0) / PI);
                let l_r = sky_mirror().map(|c| c * k);
                reflect_ambient(&h.layers, h.albedo, e, e, l_r)
            }
            MeshAmbientMode::Prt => {
                let prt = m.prt.as_ref().expect("mode says PRT");
                let env = &m.envs[h.instance];
                let front = interp(&|v| side_radiance(prt, self.layout, v, env)[0]);
                let back = interp(&|v| side_radiance(prt, self.layout, v, env)[1]);
                let (seen, other) = seen_other([front, back], h.seen_front);
                // The transfer has the folded albedo in; `k` turns it into E/π.
                let k = prt.albedo_scale(h.material);
                let layers = AmbientLayers {
                    translucence: prt.translucence(h.material),
                    ..h.layers
                };
                let turn = -(h.rotation_deg as f64).to_radians();
                let (c, s) = (turn.cos() as f32, turn.sin() as f32);
                let l_r = corner(&|d| {
                    let local = [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]];
                    ShRadiance { coeffs: env.sky }.eval(local)
                });
                let seen = std::array::from_fn(|i| seen[i] * k[i]);
                let other = std::array::from_fn(|i| other[i] * k[i]);
                reflect_ambient(&layers, h.albedo, seen, other, l_r)
            }
            MeshAmbientMode::SkyIrradiance => {
                let e = self
                    .light
                    .irradiance
                    .eval(h.facing_normal)
                    .map(|c| c.max(0.0) / PI);
                reflect_ambient(&h.layers, h.albedo, e, e, sky_mirror())
            }
        }
    }

    /// L_ambient on the terrain at world (x, y) with facing normal n and albedo ρ.
    pub fn terrain_radiance(
        &self,
        terrain: &crate::terrain::source_section::TerrainMeta,
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

/// The share of the open sky's irradiance that reaches a surface, `E/E_sky` in luminance,
/// clamped to [0, 1]: the environment seen in the mirror direction is scaled by it where only
/// irradiance is known (a light map).
pub fn occlusion(e: [f32; 3], open: [f32; 3]) -> f32 {
    let (e, open) = (crate::color::luminance(e), crate::color::luminance(open));
    if open > 0.0 {
        (e / open).clamp(0.0, 1.0)
    } else {
        1.0
    }
}

impl ModelAmbient {
    fn instances_len(&self) -> usize {
        self.envs.len().max(1)
    }
}
