//! Kind `lightmap`: a surface's irradiance per texel.

use super::{Lightmap, LightmapMode};
use crate::error::ParseError;
use crate::pack::section::SectionView;
use crate::pack::{ArrayFormat, Section, SectionBuilder};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

pub const KIND: &str = "lightmap";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LightmapMeta {
    /// The surface: "terrain" or a mesh section name.
    pub surface: String,
    pub width: u32,
    pub height: u32,
    pub mode: LightmapMode,
    pub samples: u32,
    pub sun_samples: u32,
}

/// The terrain light map's metadata as written since issue 37: [`LightmapMeta`]'s fields, then
/// how the terrain's own occlusion was found. Postcard metadata is read as a prefix, so every
/// reader of [`LightmapMeta`] reads these sections unchanged; an older section has no
/// `visibility` (its map was traced by rays).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerrainLightmapMeta {
    pub surface: String,
    pub width: u32,
    pub height: u32,
    pub mode: LightmapMode,
    pub samples: u32,
    pub sun_samples: u32,
    pub visibility: super::LightmapVisibility,
}

/// The terrain light map's metadata when its part without the direct sun was filtered
/// (`lightmap.filter_range` > 0): [`TerrainLightmapMeta`], then the bilateral filter's radius
/// (texels) and relative range. Read as a prefix, it is a [`TerrainLightmapMeta`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerrainLightmapMetaFiltered {
    pub base: TerrainLightmapMeta,
    pub filter_radius: u32,
    pub filter_range: f32,
}

/// The terrain light map's metadata when its hemisphere rays were traced at every S-th texel of
/// every S-th row (`lightmap.trace_step` = S > 1): [`TerrainLightmapMetaFiltered`]'s fields
/// (radius and range 0 when unfiltered), then the step. Read as a prefix, it is a
/// [`TerrainLightmapMetaFiltered`] and a [`TerrainLightmapMeta`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerrainLightmapMetaStepped {
    pub filtered: TerrainLightmapMetaFiltered,
    pub trace_step: u32,
}

pub fn to_section(name: &str, meta: &LightmapMeta, map: &Lightmap) -> Section {
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(meta)
        .array_fill("irradiance", ArrayFormat::F32, 4, map.texels.len(), |out| {
            rgba_into(out, map.texels.iter().copied())
        });
    b.finish()
}

/// As [`to_section`], plus the `indirect` array: the irradiance without the direct sun (sky and
/// bounced light only, `max(0, E − direct)` ([`indirect_of`]), f32×4 with A = 1), which the
/// renderer's ambient term reads. A section of `n` texels whose two arrays `fill` writes in
/// place, side by side ([`SectionBuilder::array_deferred`]): a map baked band by band goes
/// straight into them, and a map held whole is not held a second time.
pub(crate) fn to_section_filled(
    name: &str,
    meta: &impl Serialize,
    n: usize,
    fill: impl FnOnce(&mut [[f32; 4]], &mut [[f32; 4]]),
) -> Section {
    let mut b = SectionBuilder::new(KIND, name);
    b.meta(meta)
        .array_deferred::<[f32; 4]>("irradiance", ArrayFormat::F32, 4, n)
        .array_deferred::<[f32; 4]>("indirect", ArrayFormat::F32, 4, n);
    b.finish_with(|mut arrays| {
        let indirect = arrays.pop().expect("two deferred arrays");
        let irradiance = arrays.pop().expect("two deferred arrays");
        fill(
            bytemuck::cast_slice_mut(irradiance),
            bytemuck::cast_slice_mut(indirect),
        )
    })
}

/// A texel as RGBA with A = 1.
#[inline]
pub(crate) fn rgba(t: [f32; 3]) -> [f32; 4] {
    [t[0], t[1], t[2], 1.0]
}

/// The irradiance without the direct sun, `max(0, E − direct)` per channel.
#[inline]
pub(crate) fn indirect_of(e: [f32; 3], d: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|c| (e[c] - d[c]).max(0.0))
}

/// Writes RGB texels as RGBA with A = 1.
fn rgba_into(out: &mut [[f32; 4]], texels: impl Iterator<Item = [f32; 3]>) {
    for (o, t) in out.iter_mut().zip(texels) {
        *o = [t[0], t[1], t[2], 1.0];
    }
}

pub fn from_section(v: &SectionView) -> Result<(LightmapMeta, Lightmap), ParseError> {
    let meta: LightmapMeta = v.meta()?;
    let t: Vec<[f32; 4]> = v.array_vec("irradiance")?;
    if t.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err(ParseError::new(
            "lightmap section",
            "texel count does not match width × height",
        ));
    }
    let map = Lightmap {
        width: meta.width,
        height: meta.height,
        texels: t.iter().map(|x| [x[0], x[1], x[2]]).collect(),
    };
    Ok((meta, map))
}

pub fn summary(v: &SectionView) -> Result<Value, ParseError> {
    if super::atlas_section::is_atlas(v) {
        return super::atlas_section::summary(v);
    }
    let (m, map) = from_section(v)?;
    let visibility = v
        .meta::<TerrainLightmapMeta>()
        .map_or(super::LightmapVisibility::Rays, |t| t.visibility);
    let n = map.texels.len().max(1) as f32;
    let mean = map.texels.iter().fold([0.0f32; 3], |a, t| {
        [a[0] + t[0] / n, a[1] + t[1] / n, a[2] + t[2] / n]
    });
    let mut doc = json!({"surface": m.surface, "width": m.width, "height": m.height, "mode": m.mode, "samples": m.samples,
          "sun_samples": m.sun_samples, "visibility": visibility, "mean_irradiance": mean});
    // A filtered terrain map states its filter after the prefix (an unfiltered one's metadata
    // ends before it and does not decode as this).
    if let Ok(f) = v.meta::<TerrainLightmapMetaFiltered>()
        && f.filter_radius > 0
        && f.filter_range > 0.0
    {
        doc["filter_radius"] = f.filter_radius.into();
        doc["filter_range"] = f.filter_range.into();
    }
    if let Ok(s) = v.meta::<TerrainLightmapMetaStepped>() {
        doc["trace_step"] = s.trace_step.into();
    }
    Ok(doc)
}

pub fn data(v: &SectionView) -> Result<Value, ParseError> {
    if super::atlas_section::is_atlas(v) {
        return super::atlas_section::data(v);
    }
    let (_, map) = from_section(v)?;
    Ok(json!({"irradiance": map.texels}))
}
