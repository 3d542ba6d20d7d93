//! The light maps the ambient term reads: the terrain's (direct sun taken out) and each
//! model's atlas, with vertices split where one position has several light-map texels.

use super::*;

/// The terrain's `lightmap` section (surface "terrain") with the direct sun taken out.
pub(super) fn load_terrain_lightmap(
    pack: &Pack,
    light: &SkyLight,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<LightTexture>> {
    let Some((name, meta, v)) = find_lightmap(pack, "terrain")? else {
        return Ok(None);
    };
    // Only the array drawn is read: a 4097² map is 268 MB per array.
    if v.info("indirect").is_some() {
        return Ok(Some(
            light_texture(&v, &meta, "indirect").map_err(bad(pack))?,
        ));
    }
    // An older map without `indirect` holds the direct sun too. Taking it out again
    // ([`strip_terrain_direct_sun`]) would build the scene's BVH and trace shadow rays at render
    // time, bake work the renderer does not do (issue 14): the sky SH lights the terrain.
    if light.sun.is_some() {
        warnings.push(crate::diag::Warning::new(&crate::diag::RENDER_LIGHTMAP_WITHOUT_INDIRECT, "", format!(
            "{name}: no `indirect` array (an older pack): its irradiance includes the direct sun; \
             the sky SH lights the terrain instead (re-run `bake lightmap` to use the map)"
        )));
        return Ok(None);
    }
    Ok(Some(
        light_texture(&v, &meta, "irradiance").map_err(bad(pack))?,
    ))
}

/// The first `lightmap` section whose surface is `surface`: (name, meta, view). Its arrays are
/// not read here.
pub(super) fn find_lightmap<'a>(
    pack: &'a Pack,
    surface: &str,
) -> Result<
    Option<(
        String,
        crate::lightmap::section::LightmapMeta,
        crate::pack::section::SectionView<'a>,
    )>,
> {
    for e in pack.of_kind(crate::lightmap::section::KIND) {
        let v = pack.view(e)?;
        let meta: crate::lightmap::section::LightmapMeta = v.meta().map_err(bad(pack))?;
        if meta.surface != surface {
            continue;
        }
        if meta.width == 0 || meta.height == 0 {
            return Err(Error::invalid_at(
                pack.path(),
                format!("section {:?}", e.name),
                "an empty light map",
            ));
        }
        return Ok(Some((e.name.clone(), meta, v)));
    }
    Ok(None)
}

/// A light map's array `array` (`irradiance`, or `indirect`: the irradiance without the direct
/// sun) as a texture with A = 1, read in place from the pack and copied once.
pub(super) fn light_texture(
    v: &crate::pack::section::SectionView,
    meta: &crate::lightmap::section::LightmapMeta,
    array: &str,
) -> std::result::Result<LightTexture, crate::error::ParseError> {
    let t: &[[f32; 4]] = v.array(array)?;
    let want = meta.width as u64 * meta.height as u64;
    if t.len() as u64 != want {
        return Err(crate::error::ParseError::new(
            format!("lightmap array {array:?}"),
            format!(
                "{} texels, expected {}×{} = {want}",
                t.len(),
                meta.width,
                meta.height
            ),
        ));
    }
    Ok(LightTexture {
        width: meta.width,
        height: meta.height,
        texels: t.iter().map(|x| [x[0], x[1], x[2], 1.0]).collect(),
    })
}

/// Subtracts from a terrain light map without an `indirect` array (older packs) the direct sun
/// its bake added, recomputed exactly ([`crate::lightmap::terrain_direct_sun`]). `Err` when the
/// map does not fit the scene's terrain.
pub fn strip_terrain_direct_sun(
    tex: &mut LightTexture,
    meta: &crate::lightmap::section::LightmapMeta,
    scene: &crate::trace::pack_scene::TraceScene,
    light: &SkyLight,
) -> std::result::Result<(), String> {
    if scene.terrain.is_none() {
        return Err("the pack has no terrain".into());
    }
    if tex.texels.len() as u64 != meta.width as u64 * meta.height as u64 {
        return Err("texel count does not match width × height".into());
    }
    let l = crate::lightmap::BakeLight {
        sky: light.sky,
        sun: light.sun,
    };
    // A map without `indirect` predates the horizon estimator: its sun was traced by rays.
    let direct = crate::lightmap::terrain_direct_sun(
        scene,
        &l,
        meta,
        crate::lightmap::LightmapVisibility::Rays,
    );
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
pub(super) fn load_mesh_lightmap(
    pack: &Pack,
    m: &ModelData,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<Option<MeshLightmap>> {
    let Some((name, meta, v)) = find_lightmap(pack, &m.section)? else {
        return Ok(None);
    };
    let n = m.positions.len();
    let uvs: Vec<[f32; 2]> = match (v.info("lightmap_uv"), &m.vertex_source) {
        (Some(_), _) => v.array_vec("lightmap_uv").map_err(bad(pack))?,
        // The model is drawn with the atlas' split vertices: each tile's UVs of them.
        (None, Some(_)) => split_vertex_uvs(&v, n).map_err(bad(pack))?,
        (None, None) => {
            warnings.push(crate::diag::Warning::new(
                &crate::diag::RENDER_ATLAS_WITHOUT_UVS,
                "",
                format!("{name}: no `lightmap_uv` array: light map not used"),
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
    let array = match v.info("indirect") {
        Some(_) => "indirect",
        None => {
            warnings.push(crate::diag::Warning::new(&crate::diag::RENDER_LIGHTMAP_WITHOUT_INDIRECT, "", format!(
                "{name}: no `indirect` array: the object's light map counts the direct sun twice"
            )));
            "irradiance"
        }
    };
    let texture = light_texture(&v, &meta, array).map_err(bad(pack))?;
    Ok(Some(MeshLightmap {
        texture,
        uvs,
        per_instance,
    }))
}

/// Rows of `k` items of `a`, one per entry of `source` (the row it names).
pub(super) fn gather_rows<T: Copy>(a: &[T], source: &[u32], k: usize) -> Vec<T> {
    source
        .iter()
        .flat_map(|&v| &a[v as usize * k..(v as usize + 1) * k])
        .copied()
        .collect()
}

/// Light-map UVs of an atlas' own vertices (which the model draws when its atlas split mesh
/// vertices), per tile slot: `tiles[s].xy + atlas_uv[v] · tiles[s].zw`.
pub(super) fn split_vertex_uvs(
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
