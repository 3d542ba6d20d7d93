//! The light maps the ambient term reads: the terrain's (direct sun taken out) and each
//! model's atlas, with vertices split where one position has several light-map texels.

use super::*;

/// The terrain's `lightmap` section (surface "terrain") with the direct sun taken out.
pub(super) fn load_terrain_lightmap(
    pack: &Pack,
    light: &SkyLight,
    warnings: &mut Vec<String>,
) -> Result<Option<LightTexture>> {
    let Some((name, _, mut tex)) = find_lightmap(pack, "terrain")? else {
        return Ok(None);
    };
    let v = pack.view_named(&name)?;
    if let Some(indirect) = indirect_array(&v, &tex).map_err(bad(pack))? {
        tex.texels = indirect;
        return Ok(Some(tex));
    }
    // An older map without `indirect` holds the direct sun too. Taking it out again
    // ([`strip_terrain_direct_sun`]) would build the scene's BVH and trace shadow rays at render
    // time, bake work the renderer does not do (issue 14): the sky SH lights the terrain.
    if light.sun.is_some() {
        warnings.push(format!(
            "{name}: no `indirect` array (an older pack): its irradiance includes the direct sun; \
             the sky SH lights the terrain instead (re-run `bake lightmap` to use the map)"
        ));
        return Ok(None);
    }
    Ok(Some(tex))
}

/// The first `lightmap` section whose surface is `surface`: (name, meta, texture).
pub(super) fn find_lightmap(
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
pub(super) fn indirect_array(
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
pub(super) fn load_mesh_lightmap(
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
