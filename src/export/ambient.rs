//! `bake export --vertex-ambient`: every model vertex's PRT ambient as `COLOR_0`
//! (docs/MATERIALS.md, "Export to glTF").
//!
//! The value is the renderer's own (src/render/ambient, eq. 4.8): per mesh vertex the two sides'
//! radiance from the model's `prt:` section ([`side_radiance`], both transfer sets, the full
//! layout) under the light the renderer resolves for the model's instances (cluster maps,
//! environment maps or the sky, and the direct sun's SH for the ≥ 1-bounce set), turned into
//! `E/π` by the material's folded albedo ([`PrtData::albedo_scale`]) and mixed per eq. 4.8 with
//! its translucence for a viewer on the front side ([`mix_sides`]): the ambient radiance of a
//! surface of albedo 1 (W/m²/sr). glTF has one colour per vertex, not one per instance, so the
//! light is the mean of the model's instances' (the value is linear in it: the mean of what the
//! renderer computes per instance). The file stores it divided by one scale for the whole file,
//! the largest component of any vertex, so that COLOR_0 ∈ [0, 1].

use crate::error::{Error, Result};
use crate::mesh::section as mesh;
use crate::model::Mesh;
use crate::pack::Pack;
use crate::render::ambient::{
    EnvSource, InstanceEnv, PrtData, PrtLayout, Sh16, load_ambient, mix_sides, side_radiance,
};
use std::collections::HashMap;

/// A model's COLOR_0 values (divided by [`VertexAmbient::scale`]), per mesh vertex.
pub(super) enum Colors {
    /// Every vertex's materials agree: one array for every primitive.
    Shared(Vec<[f32; 3]>),
    /// Some vertex is shared by materials of different folded albedo or translucence: one array
    /// per material (index = mesh material), each valid on that material's vertices.
    PerMaterial(Vec<Vec<[f32; 3]>>),
}

impl Colors {
    /// The array primitive `material` reads.
    pub(super) fn of(&self, material: usize) -> &[[f32; 3]] {
        match self {
            Colors::Shared(c) => c,
            Colors::PerMaterial(m) => &m[material],
        }
    }
}

pub(super) struct ModelColors {
    pub prt_section: String,
    pub instances: usize,
    pub colors: Colors,
}

/// The COLOR_0 of every model that has a usable PRT section, by mesh section.
pub(super) struct VertexAmbient {
    pub models: HashMap<String, ModelColors>,
    /// W/m²/sr: radiance (albedo 1) = COLOR_0 × scale.
    pub scale: f32,
    pub source: EnvSource,
}

/// The mean of instance lights (SH coefficients averaged); `None` for no instance.
pub(super) fn mean_env(envs: &[InstanceEnv]) -> Option<InstanceEnv> {
    if envs.is_empty() {
        return None;
    }
    let n = envs.len() as f64;
    let mean = |f: &dyn Fn(&InstanceEnv) -> &Sh16| -> Sh16 {
        std::array::from_fn(|i| {
            std::array::from_fn(|c| {
                (envs.iter().map(|e| f(e)[i][c] as f64).sum::<f64>() / n) as f32
            })
        })
    };
    Some(InstanceEnv {
        sky: mean(&|e| &e.sky),
        sun: mean(&|e| &e.sun),
    })
}

/// The ambient radiance (W/m²/sr) of an albedo-1 surface at vertex `v` of `prt` on a triangle
/// of material `material`, seen from the front, under `env`: the renderer's
/// [`side_radiance`] (full layout) times the material's `1/albedo_folded`, mixed per eq. 4.8
/// with its translucence ([`mix_sides`]).
pub(super) fn vertex_radiance(
    prt: &PrtData,
    v: usize,
    material: usize,
    env: &InstanceEnv,
) -> [f32; 3] {
    let k = prt.albedo_scale(material);
    let sides =
        side_radiance(prt, PrtLayout::Full, v, env).map(|s| std::array::from_fn(|c| s[c] * k[c]));
    mix_sides(sides, prt.translucence(material), true)
}

/// Resolves the renderer's ambient light for `pack` and evaluates every model's vertices.
/// Fails (invalid input) on a pack without any `prt` section.
pub(super) fn load(pack: &Pack, warnings: &mut Vec<crate::diag::Warning>) -> Result<VertexAmbient> {
    if pack.of_kind(crate::prt::pack::KIND).next().is_none() {
        return Err(Error::invalid_at(
            pack.path(),
            "section table",
            "--vertex-ambient: the pack has no prt section (bake it with the prt stage, e.g. \
             `bake SCENE.eco --pipeline preview`, or `bake prt PACK`)",
        ));
    }
    let scene = crate::render::scene::load_scene(pack)?;
    let amb = load_ambient(pack, &scene, PrtLayout::Full, None)?;
    // Per model, its values before the file's scale is known.
    let mut models: HashMap<String, ModelColors> = HashMap::new();
    let mut peak = 0.0f32;
    for (m, a) in scene.models.iter().zip(&amb.models) {
        let missing = |why: &str| {
            crate::diag::Warning::new(
                &crate::diag::EXPORT_NO_PRT,
                "",
                format!("model {:?}: {why}: exported without COLOR_0", m.name),
            )
        };
        let Some(prt) = &a.prt else {
            warnings.push(missing("no usable prt section"));
            continue;
        };
        let Some(env) = mean_env(&a.envs) else {
            warnings.push(missing("no instance to take the light from"));
            continue;
        };
        let v = pack.view_named(&m.section)?;
        let (_, mesh): (_, Mesh) = mesh::from_section(&v).map_err(|e| {
            Error::invalid_at(
                pack.path(),
                format!("section {:?}", m.section),
                e.to_string(),
            )
        })?;
        let n = mesh.positions.len();
        // The PRT row of every mesh vertex (a model drawn with split vertices has the transfer
        // per drawn vertex, each a copy of its mesh vertex's).
        let row: Vec<Option<usize>> = match &m.vertex_source {
            None => (0..n).map(|i| (i < prt.vertices).then_some(i)).collect(),
            Some(src) => {
                let mut row = vec![None; n];
                for (j, &s) in src.iter().enumerate().rev() {
                    if let Some(r) = row.get_mut(s as usize) {
                        *r = Some(j);
                    }
                }
                row
            }
        };
        let materials = mesh.materials.len();
        let mut per: Vec<Vec<[f32; 3]>> = vec![vec![[0.0; 3]; n]; materials];
        let mut owner = vec![u32::MAX; n];
        let mut conflict = false;
        let mut done = vec![vec![false; n]; materials];
        for (t, &mat) in mesh.indices.iter().zip(&mesh.triangle_materials) {
            let mi = mat as usize;
            if mi >= materials {
                continue;
            }
            for &vi in t {
                let vi = vi as usize;
                if vi >= n || done[mi][vi] {
                    continue;
                }
                done[mi][vi] = true;
                let c = row[vi].map_or([0.0; 3], |r| vertex_radiance(prt, r, mi, &env));
                per[mi][vi] = c;
                peak = c
                    .iter()
                    .fold(peak, |p, &x| if x.is_finite() { p.max(x) } else { p });
                if owner[vi] == u32::MAX {
                    owner[vi] = mat;
                } else if owner[vi] != mat && per[owner[vi] as usize][vi] != c {
                    conflict = true;
                }
            }
        }
        let colors = if !conflict {
            // One array: each vertex's value from the material that uses it.
            Colors::Shared(
                (0..n)
                    .map(|i| match owner[i] {
                        u32::MAX => [0.0; 3],
                        o => per[o as usize][i],
                    })
                    .collect(),
            )
        } else {
            Colors::PerMaterial(per)
        };
        models.insert(
            m.section.clone(),
            ModelColors {
                prt_section: crate::prt::pack::section_name(&m.section),
                instances: a.envs.len(),
                colors,
            },
        );
    }
    let scale = if peak > 0.0 { peak } else { 1.0 };
    let norm = |c: &mut [f32; 3]| {
        *c = c.map(|x| {
            if x.is_finite() {
                (x / scale).clamp(0.0, 1.0)
            } else {
                0.0
            }
        })
    };
    for m in models.values_mut() {
        match &mut m.colors {
            Colors::Shared(c) => c.iter_mut().for_each(norm),
            Colors::PerMaterial(p) => p.iter_mut().flatten().for_each(norm),
        }
    }
    Ok(VertexAmbient {
        models,
        scale,
        source: amb.source,
    })
}
