//! Eq. 4.8 per vertex: a model's `prt:<model>` section and its radiance per side under an
//! instance's light (full or packed layout).

use super::*;

/// The `prt:<model>` section of a model, checked against its vertex count.
pub(super) fn load_prt(
    pack: &Pack,
    m: &ModelData,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<PrtData>> {
    let name = crate::prt::pack::section_name(&m.section);
    if pack.find(&name).is_none() {
        return Ok(None);
    }
    let v = pack.view_named(&name)?;
    let (meta, mut t) = crate::prt::pack::from_section(&v).map_err(bad(pack))?;
    // A model drawn with split vertices: the transfer of the mesh vertex each copies.
    let source = m.vertex_source.as_deref();
    let mesh_vertices = source.map_or(m.positions.len(), |_| {
        pack.view_named(&m.section)
            .ok()
            .and_then(|s| s.info("positions").map(|i| i.count as usize))
            .unwrap_or(0)
    });
    if t.vertices as usize != mesh_vertices || meta.mesh != m.section {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::RENDER_PRT_MISMATCH,
            "",
            format!(
                "{name}: {} vertices of {:?} for a mesh {:?} of {}: not used",
                t.vertices, meta.mesh, m.section, mesh_vertices
            ),
        ));
        return Ok(None);
    }
    let mut packed: Vec<[f32; 4]> = match v.info("gpu") {
        Some(_) => v.array_vec("gpu").map_err(bad(pack))?,
        None => crate::prt::transfer::pack_gpu(&t),
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

pub(super) fn dot(p: &[[f32; 3]], c: &Sh16) -> [f32; 3] {
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
    let l0 = crate::color::luminance(b0);
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

/// The (seen, other) sides of `[front, back]` for a viewer on the front side or not.
pub fn seen_other(sides: [[f32; 3]; 2], seen_front: bool) -> ([f32; 3], [f32; 3]) {
    if seen_front {
        (sides[0], sides[1])
    } else {
        (sides[1], sides[0])
    }
}

/// Eq. 4.8 for the side the viewer sees: `L_seen·(1 − t) + L_other·t`, clamped at 0: the
/// runtime's [`super::reflect_ambient`] for a Lambertian surface of albedo 1 and translucence t.
pub fn mix_sides(sides: [[f32; 3]; 2], t: f32, seen_front: bool) -> [f32; 3] {
    let (seen, other) = seen_other(sides, seen_front);
    let layers = super::AmbientLayers {
        translucence: t,
        ..super::AmbientLayers::LAMBERT
    };
    super::reflect_ambient(&layers, [1.0; 3], seen, other, [0.0; 3])
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
