//! `bake mitsuba PACK -o DIR`: the placed scene of a pack as a Mitsuba 3 scene, the input of the
//! ground-truth harness (scripts/groundtruth/, docs/VALIDATION.md).
//!
//! What is written, all of it from what `bake render` draws (its [`crate::render::scene`] and
//! [`crate::render::resolve_view`]):
//! - `geometry.xml`: the terrain as one PLY mesh (the grid's two triangles per cell split along
//!   the diagonal from sample (i, j) to (i + 1, j + 1), the terrain's normal map as vertex
//!   normals, its colour map as a `diffuse` texture), and every model as a `shapegroup` of one
//!   PLY per material (model space) placed by one `instance` per record of the `instances`
//!   section (the exact placement, not the BitTree's cell centres).
//! - `scene.xml` (all light: the sun-free sky as `envmap`, the extracted sun as `directional`,
//!   `volpath`) and `direct.xml` (the sun alone, `max_depth` 2): the sensor is `bake render`'s
//!   camera (the same eye, target, up, vertical field of view and near plane; a box pixel filter,
//!   as the 4× MSAA resolve averages within the pixel).
//! - `materials.json`: every material's parameters and, for the BSDF check, `SchlickMaterial::eval`
//!   on random direction pairs; `sky_probe.json`: the drawn sky's radiance in random directions.
//!
//! Materials: an alpha-tested material ([`crate::render::scene::MaterialData::alpha_tested`]) is
//! wrapped in Mitsuba's `mask` with its alpha × opacity thresholded at 0.5 into a binary opacity
//! texture, so that Mitsuba's blend equals bake's alpha test. A two-layer Schlick material is the
//! harness' `bakeschlick` plugin (scripts/groundtruth/bakeschlick.py: docs/MATERIALS.md's
//! formulas, two-sided, with translucence); one whose top layer has colour 0 and whose bottom
//! layer is diffuse only, without translucence (an authored colour with spec 0: a Lambertian
//! surface by its source), and a model without a material section are `twosided` `diffuse`.
//! Textures are level 0 of the colour maps, linear RGB in OpenEXR. Normal maps are not exported
//! (their bumps are 1 mm).
//!
//! Conventions: Mitsuba's `envmap` is Y up and reads row j at θ = πj/(H − 1) and column i at
//! u = (i + ½)/W with φ = atan2(x, −z) (local); its `to_world` here is (x, y, z) → (x, −z, y), so
//! its up axis is bake's +Z, and every texel is sampled from the sky cube in its own world
//! direction (no resampling between lat-long conventions). PLY texture coordinates are bake's
//! (row 0 at the top), as Mitsuba's `bitmap` reads them. Every PLY vertex carries `region_x`
//! (1 terrain, 2 opaque model surface, 3 leaves: the regions of `bake render --regions`).

use crate::error::{Error, Result};
use crate::ingest::instances_section::{InstanceRecord, InstancesMeta};
use crate::model::FloatImage;
use crate::pack::Pack;
use crate::render::scene::{MaterialData, ModelData, SceneData, TerrainData};
use crate::render::{RenderOptions, View};
use std::fmt::Write as _;
use std::path::Path;

/// Region codes of the PLY attribute `region_x` (and of the harness' region images).
pub(crate) const REGION_TERRAIN: f32 = 1.0;
pub(crate) const REGION_OPAQUE: f32 = 2.0;
pub(crate) const REGION_LEAVES: f32 = 3.0;

/// Direction pairs per material in `materials.json`'s BSDF check.
pub(crate) const BRDF_PROBES: usize = 64;
/// Directions in `sky_probe.json`.
pub(crate) const SKY_PROBES: usize = 64;

/// What [`export`] wrote.
#[derive(Debug, Clone, serde::Serialize)]
pub(crate) struct ExportSummary {
    pub dir: std::path::PathBuf,
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov_y_deg: f32,
    pub width: u32,
    pub height: u32,
    pub sun_direction: [f32; 3],
    pub sun_irradiance: [f32; 3],
    pub envmap: [u32; 2],
    pub terrain_triangles: u64,
    pub models: usize,
    pub shapes: usize,
    pub instances: u64,
    /// Materials by kind: `bakeschlick`, `diffuse`, and of all those the masked ones.
    pub schlick_materials: usize,
    pub diffuse_materials: usize,
    pub masked_materials: usize,
    pub warnings: Vec<crate::diag::Warning>,
}

/// Options of [`export`] beyond the view.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ExportOptions {
    /// Rows of the envmap (its columns are twice as many, less one); 0: from the sky cube's
    /// face size (4 × face + 1, at most 2049: the horizon of a sky keeps its edge).
    pub envmap_height: u32,
    /// `max_depth` of `scene.xml`'s integrator (a default the harness may override).
    pub max_depth: u32,
    /// Each model as a `shapegroup` placed by one `instance` per record; false: one world-space
    /// mesh per model and material holding every instance (Mitsuba's JIT variants trace each
    /// `instance` into the kernel: 500 instances took 2 minutes before the first sample on
    /// 2 cores, the flattened meshes a few seconds).
    pub instancing: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            envmap_height: 0,
            max_depth: 12,
            instancing: false,
        }
    }
}

/// Writes the Mitsuba scene of `pack` seen with `view_opts` (`bake render`'s camera options)
/// into `dir` (created; files of the same names are replaced).
pub(crate) fn export(
    pack: &Pack,
    view_opts: &RenderOptions,
    opts: &ExportOptions,
    dir: &Path,
) -> Result<ExportSummary> {
    crate::render::check_options(view_opts)?;
    let scene = crate::render::scene::load_scene(pack)?;
    let view = crate::render::resolve_view(pack, &scene, view_opts);
    let mut warnings = scene.warnings.clone();
    for sub in ["meshes", "textures"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(|e| Error::io(dir.join(sub), e))?;
    }
    let mut geo = String::from("<scene version=\"3.0.0\">\n");
    let mut summary = ExportSummary {
        dir: dir.to_path_buf(),
        eye: view.camera.eye.to_array(),
        target: view.camera.target.to_array(),
        up: view.camera.basis().up.to_array(),
        fov_y_deg: view.camera.fov_y_deg,
        width: view_opts.width,
        height: view_opts.height,
        sun_direction: view.lighting.sun_direction,
        sun_irradiance: view.lighting.sun_irradiance,
        envmap: [0, 0],
        terrain_triangles: 0,
        models: 0,
        shapes: 0,
        instances: 0,
        schlick_materials: 0,
        diffuse_materials: 0,
        masked_materials: 0,
        warnings: Vec::new(),
    };
    if let Some(t) = &scene.terrain {
        summary.terrain_triangles = write_terrain(dir, t, &mut geo)?;
        summary.shapes += 1;
    }
    let placed = exact_instances(pack, &scene)?;
    let mut materials_json = Vec::new();
    for (k, m) in scene.models.iter().enumerate() {
        let inst = placed.get(&m.section).unwrap_or(&m.instances);
        if inst.is_empty() {
            continue;
        }
        let (shapes, mats) = write_model(dir, k, m, inst, opts.instancing, &mut geo, &mut summary)?;
        summary.shapes += shapes;
        materials_json.extend(mats);
        summary.models += 1;
        summary.instances += inst.len() as u64;
    }
    geo.push_str("</scene>\n");
    write(dir, "geometry.xml", geo.as_bytes())?;
    let envmap = write_envmap(dir, &scene, opts.envmap_height, &mut warnings)?;
    summary.envmap = envmap;
    for (name, sky, depth) in [
        ("scene.xml", true, opts.max_depth),
        ("direct.xml", false, 2),
    ] {
        let xml = scene_xml(&view, view_opts, sky, depth);
        write(dir, name, xml.as_bytes())?;
    }
    let mats = serde_json::json!({ "materials": materials_json });
    write(
        dir,
        "materials.json",
        serde_json::to_string_pretty(&mats)
            .expect("JSON of plain values")
            .as_bytes(),
    )?;
    write(
        dir,
        "sky_probe.json",
        serde_json::to_string(&sky_probe(&scene))
            .expect("JSON of plain values")
            .as_bytes(),
    )?;
    summary.warnings = warnings;
    let json = serde_json::to_string_pretty(&summary).expect("JSON of plain values");
    write(dir, "export.json", json.as_bytes())?;
    Ok(summary)
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<()> {
    crate::pack::write_atomic(&dir.join(name), bytes)
}

/// The `instances` section's records per model mesh section: the placement as authored (the
/// renderer reads the BitTree's cell centres where the pack has one).
fn exact_instances(
    pack: &Pack,
    scene: &SceneData,
) -> Result<std::collections::HashMap<String, Vec<InstanceRecord>>> {
    let mut out = std::collections::HashMap::new();
    let Some(e) = pack.of_kind(crate::ingest::instances_section::KIND).next() else {
        return Ok(out);
    };
    let v = pack.view(e)?;
    let meta: InstancesMeta = v.meta().map_err(|e| Error::invalid(pack.path(), e))?;
    let list: &[InstanceRecord] = v
        .array("instances")
        .map_err(|e| Error::invalid(pack.path(), e))?;
    for r in list {
        if let Some(section) = meta.mesh_sections.get(r.model as usize) {
            out.entry(section.clone()).or_insert_with(Vec::new).push(*r);
        }
    }
    // Only models the renderer draws.
    out.retain(|s, _| scene.models.iter().any(|m| &m.section == s));
    Ok(out)
}

/// A binary little-endian PLY: positions, normals, texture coordinates, the region code.
fn ply(
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    uvs: &[[f32; 2]],
    region: f32,
    triangles: &[[u32; 3]],
) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property float u\nproperty float v\nproperty float region_x\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        positions.len(),
        triangles.len()
    )
    .into_bytes();
    out.reserve(positions.len() * 36 + triangles.len() * 13);
    for (k, p) in positions.iter().enumerate() {
        let n = normals.get(k).copied().unwrap_or([0.0, 0.0, 1.0]);
        let uv = uvs.get(k).copied().unwrap_or([0.0, 0.0]);
        for v in p.iter().chain(&n).chain(&uv).chain(&[region]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    out
}

fn exr(img: &FloatImage) -> Result<Vec<u8>> {
    crate::dump::images::exr_rgb(img)
        .map_err(|e| Error::runtime(format!("EXR encoding failed: {e}")))
}

fn srgb8_to_linear(t: [u8; 4]) -> [f32; 3] {
    [0, 1, 2].map(|c| crate::color::srgb_to_linear(t[c] as f32 / 255.0))
}

fn write_terrain(dir: &Path, t: &TerrainData, geo: &mut String) -> Result<u64> {
    let (w, h) = (t.meta.width, t.meta.height);
    let [x0, y0] = t.meta.origin;
    let [ew, eh] = t.meta.extent;
    let mut positions = Vec::with_capacity((w * h) as usize);
    let mut normals = Vec::with_capacity((w * h) as usize);
    let mut uvs = Vec::with_capacity((w * h) as usize);
    for j in 0..h {
        for i in 0..w {
            let k = (j * w + i) as usize;
            positions.push([
                x0 + i as f32 * ew / (w - 1) as f32,
                y0 + j as f32 * eh / (h - 1) as f32,
                t.heights[k],
            ]);
            let n = t.normals[k];
            let n = glam::Vec3::new(
                n[0] as f32 / 255.0 * 2.0 - 1.0,
                n[1] as f32 / 255.0 * 2.0 - 1.0,
                n[2] as f32 / 255.0 * 2.0 - 1.0,
            )
            .normalize_or(glam::Vec3::Z);
            normals.push(n.to_array());
            uvs.push([i as f32 / (w - 1) as f32, 1.0 - j as f32 / (h - 1) as f32]);
        }
    }
    let mut tris = Vec::with_capacity(((w - 1) * (h - 1) * 2) as usize);
    for j in 0..h - 1 {
        for i in 0..w - 1 {
            let a = j * w + i;
            let (b, c, d) = (a + 1, a + w + 1, a + w);
            tris.push([a, b, c]);
            tris.push([a, c, d]);
        }
    }
    write(
        dir,
        "meshes/terrain.ply",
        &ply(&positions, &normals, &uvs, REGION_TERRAIN, &tris),
    )?;
    // The renderer's colour map, or its mid grey (sRGB 128) without one.
    let img = match &t.color {
        Some(c) => FloatImage {
            width: c.width,
            height: c.height,
            pixels: c.texels.iter().map(|&p| srgb8_to_linear(p)).collect(),
        },
        None => FloatImage {
            width: 1,
            height: 1,
            pixels: vec![srgb8_to_linear([128, 128, 128, 255])],
        },
    };
    write(dir, "textures/terrain.exr", &exr(&img)?)?;
    let _ = write!(
        geo,
        "  <shape type=\"ply\" id=\"terrain\">\n    <string name=\"filename\" value=\"meshes/terrain.ply\"/>\n    \
         <bsdf type=\"twosided\"><bsdf type=\"diffuse\">{}</bsdf></bsdf>\n  </shape>\n",
        bitmap("reflectance", "textures/terrain.exr", false)
    );
    Ok(tris.len() as u64)
}

fn bitmap(name: &str, file: &str, raw: bool) -> String {
    format!(
        "<texture type=\"bitmap\" name=\"{name}\"><string name=\"filename\" value=\"{file}\"/>\
         <boolean name=\"raw\" value=\"{raw}\"/></texture>"
    )
}

fn rgb(name: &str, c: [f32; 3]) -> String {
    format!(
        "<rgb name=\"{name}\" value=\"{:e}, {:e}, {:e}\"/>",
        c[0], c[1], c[2]
    )
}

fn float(name: &str, v: f32) -> String {
    format!("<float name=\"{name}\" value=\"{v:e}\"/>")
}

/// Level 0 of a material's colour map, linear RGB and alpha (None: no map).
fn color_level0(mat: &MaterialData) -> Option<(u32, u32, Vec<[f32; 4]>)> {
    if let Some(m) = &mat.color_mips {
        let [w, h, _, _] = m.levels[0];
        let px = (0..h)
            .flat_map(|j| (0..w).map(move |i| (i, j)))
            .map(|(i, j)| m.texel(0, i, j))
            .collect();
        return Some((w, h, px));
    }
    mat.color_map.as_ref().map(|c| {
        let px = c
            .texels
            .iter()
            .map(|&t| {
                let l = srgb8_to_linear(t);
                [l[0], l[1], l[2], t[3] as f32 / 255.0]
            })
            .collect();
        (c.width, c.height, px)
    })
}

/// True for a material that is Lambertian by its source: its top layer has colour 0 (an
/// authored colour with spec 0), its bottom layer is diffuse only, and it has no translucence.
pub(crate) fn is_lambertian(m: &crate::material::schlick::SchlickMaterial) -> bool {
    let [top, bottom] = &m.layers;
    top.color == [0.0; 3] && bottom.diffuse == 1.0 && m.translucence == 0.0
}

fn write_model(
    dir: &Path,
    k: usize,
    m: &ModelData,
    instances: &[InstanceRecord],
    instancing: bool,
    geo: &mut String,
    summary: &mut ExportSummary,
) -> Result<(usize, Vec<serde_json::Value>)> {
    let mut shapes = String::new();
    let mut mats = Vec::new();
    let mut count = 0;
    for (i, mat) in m.materials.iter().enumerate() {
        let tris: Vec<[u32; 3]> = m
            .draws
            .iter()
            .filter(|d| d.material as usize == i)
            .flat_map(|d| m.indices[d.first as usize..(d.first + d.count) as usize].iter())
            .copied()
            .collect();
        if tris.is_empty() {
            continue;
        }
        let id = format!("m{k}_{i}");
        let leaves = mat.alpha_tested();
        let region = if leaves { REGION_LEAVES } else { REGION_OPAQUE };
        let bytes = if instancing {
            ply(&m.positions, &m.normals, &m.uvs, region, &tris)
        } else {
            let placed = place(m, &tris, instances);
            ply(&placed.0, &placed.1, &placed.2, region, &placed.3)
        };
        write(dir, &format!("meshes/{id}.ply"), &bytes)?;
        let map = color_level0(mat);
        let opacity = mat.schlick.as_ref().map_or(1.0, |s| s.opacity);
        let (bsdf, json) = material_bsdf(dir, &id, mat, map.as_ref())?;
        if bsdf.starts_with("<bsdf type=\"twosided\"") {
            summary.diffuse_materials += 1;
        } else {
            summary.schlick_materials += 1;
        }
        let bsdf = match (&map, leaves) {
            (Some((w, h, px)), true) => {
                let mask = FloatImage {
                    width: *w,
                    height: *h,
                    pixels: px
                        .iter()
                        .map(|t| [if t[3] * opacity >= 0.5 { 1.0 } else { 0.0 }; 3])
                        .collect(),
                };
                write(dir, &format!("textures/{id}_mask.exr"), &exr(&mask)?)?;
                summary.masked_materials += 1;
                format!(
                    "<bsdf type=\"mask\">{}{bsdf}</bsdf>",
                    bitmap("opacity", &format!("textures/{id}_mask.exr"), true)
                )
            }
            (None, true) => {
                // Opacity below 0.5 without a map: bake's test drops the whole surface.
                summary.masked_materials += 1;
                format!("<bsdf type=\"mask\">{}{bsdf}</bsdf>", float("opacity", 0.0))
            }
            _ => bsdf,
        };
        let _ = write!(
            shapes,
            "  <shape type=\"ply\" id=\"{id}\">\n      <string name=\"filename\" value=\"meshes/{id}.ply\"/>\n      \
             <boolean name=\"face_normals\" value=\"false\"/>\n      {bsdf}\n    </shape>\n"
        );
        let mut json = json;
        json["id"] = id.clone().into();
        json["model"] = m.name.clone().into();
        json["leaves"] = leaves.into();
        mats.push(json);
        count += 1;
    }
    if count == 0 {
        return Ok((0, mats));
    }
    if !instancing {
        geo.push_str(&shapes);
        return Ok((count, mats));
    }
    let _ = writeln!(
        geo,
        "  <shape type=\"shapegroup\" id=\"model{k}\">\n{shapes}  </shape>"
    );
    for r in instances {
        let (s, c) = r.rotation_deg.to_radians().sin_cos();
        let sc = r.scale;
        let p = r.position;
        let _ = writeln!(
            geo,
            "  <shape type=\"instance\"><ref id=\"model{k}\"/><transform name=\"to_world\"><matrix value=\"{:e} {:e} 0 {:e} {:e} {:e} 0 {:e} 0 0 {:e} {:e} 0 0 0 1\"/></transform></shape>",
            c * sc,
            -s * sc,
            p[0],
            s * sc,
            c * sc,
            p[1],
            sc,
            p[2]
        );
    }
    Ok((count, mats))
}

/// The triangles `tris` of model `m` placed at every instance, in world space: positions,
/// normals, texture coordinates and triangles of one mesh (ECO's p = t + R_z(θ)·(s·p_model)).
#[allow(clippy::type_complexity)]
fn place(
    m: &ModelData,
    tris: &[[u32; 3]],
    instances: &[InstanceRecord],
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>) {
    // The vertices these triangles use, renumbered.
    let mut used = vec![u32::MAX; m.positions.len()];
    let mut verts = Vec::new();
    let local: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            t.map(|v| {
                if used[v as usize] == u32::MAX {
                    used[v as usize] = verts.len() as u32;
                    verts.push(v);
                }
                used[v as usize]
            })
        })
        .collect();
    let n = instances.len() * verts.len();
    let (mut ps, mut ns, mut uvs) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let mut out_tris = Vec::with_capacity(instances.len() * local.len());
    for r in instances {
        let (s, c) = r.rotation_deg.to_radians().sin_cos();
        let rot = |v: [f32; 3]| [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]];
        let base = ps.len() as u32;
        for &v in &verts {
            let p = rot(m.positions[v as usize].map(|x| x * r.scale));
            ps.push([
                p[0] + r.position[0],
                p[1] + r.position[1],
                p[2] + r.position[2],
            ]);
            ns.push(rot(m.normals[v as usize]));
            uvs.push(m.uvs[v as usize]);
        }
        out_tris.extend(local.iter().map(|t| t.map(|i| i + base)));
    }
    (ps, ns, uvs, out_tris)
}

/// The BSDF element of a material and its JSON record (parameters and the eval probe).
fn material_bsdf(
    dir: &Path,
    id: &str,
    mat: &MaterialData,
    map: Option<&(u32, u32, Vec<[f32; 4]>)>,
) -> Result<(String, serde_json::Value)> {
    let map_file = format!("textures/{id}_color.exr");
    if let Some((w, h, px)) = map {
        let img = FloatImage {
            width: *w,
            height: *h,
            pixels: px.iter().map(|t| [t[0], t[1], t[2]]).collect(),
        };
        write(dir, &map_file, &exr(&img)?)?;
    }
    // A diffuse reflectance: the colour map times a constant colour (written as its own file
    // where the colour is not white), or the colour alone.
    let texture = |c: [f32; 3]| -> Result<String> {
        let Some((w, h, px)) = map else {
            return Ok(rgb("reflectance", c));
        };
        if c == [1.0; 3] {
            return Ok(bitmap("reflectance", &map_file, false));
        }
        let img = FloatImage {
            width: *w,
            height: *h,
            pixels: px
                .iter()
                .map(|t| [t[0] * c[0], t[1] * c[1], t[2] * c[2]])
                .collect(),
        };
        let f = format!("textures/{id}_reflectance.exr");
        write(dir, &f, &exr(&img)?)?;
        Ok(bitmap("reflectance", &f, false))
    };
    match &mat.schlick {
        Some(s) if !is_lambertian(s) => {
            let [top, bottom] = &s.layers;
            let mut x = String::from("<bsdf type=\"bakeschlick\">");
            for (p, l) in [("top", top), ("bottom", bottom)] {
                x += &float(&format!("{p}_roughness"), l.roughness);
                x += &float(&format!("{p}_isotropy"), l.isotropy);
                x += &float(&format!("{p}_diffuse"), l.diffuse);
                x += &float(&format!("{p}_glossy"), l.glossy);
                x += &float(&format!("{p}_specular"), l.specular);
                x += &rgb(&format!("{p}_color"), l.color);
            }
            x += &float("translucence", s.translucence);
            if map.is_some() {
                x += &bitmap("color_map", &map_file, false);
            }
            x += "</bsdf>";
            Ok((x, schlick_json(s)))
        }
        Some(s) => {
            let b = &s.layers[1];
            let x = format!(
                "<bsdf type=\"twosided\"><bsdf type=\"diffuse\">{}</bsdf></bsdf>",
                texture(b.color)?
            );
            Ok((
                x,
                serde_json::json!({"kind": "diffuse", "reflectance": b.color}),
            ))
        }
        None => {
            let c = [mat.base_color[0], mat.base_color[1], mat.base_color[2]];
            let x = format!(
                "<bsdf type=\"twosided\"><bsdf type=\"diffuse\">{}</bsdf></bsdf>",
                texture(c)?
            );
            Ok((x, serde_json::json!({"kind": "diffuse", "reflectance": c})))
        }
    }
}

/// A material's parameters and `SchlickMaterial::eval` on [`BRDF_PROBES`] random direction
/// pairs (uniform on the sphere, so both sides and translucence are probed) with a random
/// colour-map value.
pub(crate) fn schlick_json(s: &crate::material::schlick::SchlickMaterial) -> serde_json::Value {
    let mut rng = crate::rng::Rng::new(0x6a09e667f3bcc909);
    let mut dir = || loop {
        let v = [0, 1, 2].map(|_| rng.f32() * 2.0 - 1.0);
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.05 && l <= 1.0 {
            break v.map(|c| c / l);
        }
    };
    let mut probes = Vec::with_capacity(BRDF_PROBES);
    for k in 0..BRDF_PROBES {
        let (wi, wo) = (dir(), dir());
        let map = [0.2 + 0.8 * ((k * 7) % 11) as f32 / 10.0, 0.6, 1.0];
        probes.push(serde_json::json!({"wi": wi, "wo": wo, "map": map, "f": s.eval(wi, wo, map)}));
    }
    let layer = |l: &crate::material::schlick::SchlickLayer| {
        serde_json::json!({
            "roughness": l.roughness, "isotropy": l.isotropy, "diffuse": l.diffuse,
            "glossy": l.glossy, "specular": l.specular, "color": l.color,
        })
    };
    serde_json::json!({
        "kind": "bakeschlick",
        "top": layer(&s.layers[0]),
        "bottom": layer(&s.layers[1]),
        "translucence": s.translucence,
        "probes": probes,
    })
}

/// The drawn sky (the sun-free cube, or the lat-long image) in direction `d`.
fn sky_radiance(scene: &SceneData, d: [f64; 3]) -> [f32; 3] {
    match &scene.sky.cube {
        Some(c) => c.sample(d),
        None => {
            // The sky pass reads the lat-long image's nearest texel.
            let (w, h) = (scene.sky.width, scene.sky.height);
            let (x, y) = crate::cube::latlong_coords(d, w, h);
            let i = (x.floor() as i64).rem_euclid(w as i64) as usize;
            let j = (y.floor() as i64).clamp(0, h as i64 - 1) as usize;
            let t = scene.sky.texels[j * w as usize + i];
            [t[0], t[1], t[2]]
        }
    }
}

/// Mitsuba's local envmap direction of texel (i, j) of a `w` × `h` map, in bake's world:
/// local (sin θ sin φ, cos θ, −sin θ cos φ) with θ = πj/(h − 1), φ = 2π(i + ½)/w, turned by
/// the emitter's `to_world` (x, y, z) → (x, −z, y).
pub(crate) fn envmap_direction(i: u32, j: u32, w: u32, h: u32) -> [f64; 3] {
    use std::f64::consts::PI;
    let theta = PI * j as f64 / (h - 1) as f64;
    let phi = 2.0 * PI * (i as f64 + 0.5) / w as f64;
    let local = [
        theta.sin() * phi.sin(),
        theta.cos(),
        -theta.sin() * phi.cos(),
    ];
    [local[0], -local[2], local[1]]
}

fn write_envmap(
    dir: &Path,
    scene: &SceneData,
    height: u32,
    warnings: &mut Vec<crate::diag::Warning>,
) -> Result<[u32; 2]> {
    let h = match (height, &scene.sky.cube) {
        (0, Some(c)) => (4 * c.size + 1).min(2049),
        (0, None) => scene.sky.height + 1,
        (h, _) => h.max(3),
    };
    let w = 2 * (h - 1);
    if !scene.sky.sun_removed && !scene.sky.analytic {
        warnings.push(crate::diag::Warning::new(
            &crate::diag::MITSUBA_SUN_IN_SKY,
            "",
            "the sky is a lat-long image that still holds its sun: the envmap keeps it, and the \
             directional sun (the renderer's own split) counts it twice; run the sky stage",
        ));
    }
    let pixels = (0..h)
        .flat_map(|j| (0..w).map(move |i| (i, j)))
        .map(|(i, j)| sky_radiance(scene, envmap_direction(i, j, w, h)))
        .collect();
    write(
        dir,
        "sky.exr",
        &exr(&FloatImage {
            width: w,
            height: h,
            pixels,
        })?,
    )?;
    Ok([w, h])
}

/// Random directions and the drawn sky's radiance there (the harness checks Mitsuba's envmap).
fn sky_probe(scene: &SceneData) -> serde_json::Value {
    let mut rng = crate::rng::Rng::new(0xbb67ae8584caa73b);
    let mut out = Vec::with_capacity(SKY_PROBES);
    while out.len() < SKY_PROBES {
        let v = [0, 1, 2].map(|_| rng.f32() as f64 * 2.0 - 1.0);
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if !(0.05..=1.0).contains(&l) {
            continue;
        }
        let d = v.map(|c| c / l);
        out.push(serde_json::json!({"d": d, "radiance": sky_radiance(scene, d)}));
    }
    serde_json::json!({ "probes": out })
}

fn scene_xml(view: &View, o: &RenderOptions, sky: bool, max_depth: u32) -> String {
    let cam = &view.camera;
    let up = cam.basis().up;
    let v = |a: glam::Vec3| format!("{:e}, {:e}, {:e}", a.x, a.y, a.z);
    let l = &view.lighting;
    let mut x = String::from("<scene version=\"3.0.0\">\n");
    let _ = writeln!(
        x,
        "  <default name=\"spp\" value=\"64\"/>\n  <default name=\"max_depth\" value=\"{max_depth}\"/>\n  \
         <integrator type=\"volpath\"><integer name=\"max_depth\" value=\"$max_depth\"/>\
         <integer name=\"rr_depth\" value=\"{}\"/></integrator>",
        max_depth.max(5)
    );
    let _ = writeln!(
        x,
        "  <sensor type=\"perspective\">\n    <string name=\"fov_axis\" value=\"y\"/>\n    {}\n    {}\n    \
         <transform name=\"to_world\"><lookat origin=\"{}\" target=\"{}\" up=\"{}\"/></transform>\n    \
         <sampler type=\"independent\"><integer name=\"sample_count\" value=\"$spp\"/></sampler>\n    \
         <film type=\"hdrfilm\"><integer name=\"width\" value=\"{}\"/><integer name=\"height\" value=\"{}\"/>\
         <string name=\"pixel_format\" value=\"rgb\"/><rfilter type=\"box\"/></film>\n  </sensor>",
        float("fov", cam.fov_y_deg),
        float("near_clip", cam.near),
        v(cam.eye),
        v(cam.target),
        v(up),
        o.width,
        o.height
    );
    if sky {
        let _ = writeln!(
            x,
            "  <emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/>\
             <transform name=\"to_world\"><matrix value=\"1 0 0 0 0 0 -1 0 0 1 0 0 0 0 0 1\"/></transform></emitter>"
        );
    }
    let d = l.sun_direction;
    if l.sun_irradiance.iter().any(|&e| e > 0.0) {
        let _ = writeln!(
            x,
            "  <emitter type=\"directional\"><vector name=\"direction\" value=\"{:e}, {:e}, {:e}\"/>{}</emitter>",
            -d[0],
            -d[1],
            -d[2],
            rgb("irradiance", l.sun_irradiance)
        );
    }
    x.push_str("  <include filename=\"geometry.xml\"/>\n</scene>\n");
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn envmap_rows_run_from_the_zenith_to_the_nadir_and_columns_clockwise_from_north() {
        let (w, h) = (64u32, 33u32);
        let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-9);
        // Row 0 is the zenith (+Z), the last row the nadir, the middle row the horizon.
        assert!(near(envmap_direction(5, 0, w, h), [0.0, 0.0, 1.0]));
        assert!(near(envmap_direction(5, h - 1, w, h), [0.0, 0.0, -1.0]));
        for i in 0..w {
            let d = envmap_direction(i, (h - 1) / 2, w, h);
            assert!(d[2].abs() < 1e-9);
            // Mitsuba's φ = atan2(x, −z) (local) is bake's π/2 − φ: u = (i + ½)/w.
            let phi_bake = d[1].atan2(d[0]);
            let u = (std::f64::consts::FRAC_PI_2 - phi_bake) / std::f64::consts::TAU;
            let want = (i as f64 + 0.5) / w as f64;
            assert!(
                (u.rem_euclid(1.0) - want).abs() < 1e-9,
                "{i}: {u} vs {want}"
            );
        }
    }

    #[test]
    fn ply_has_the_header_and_the_records() {
        let p = ply(
            &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            &[[0.0, 0.0, 1.0]; 3],
            &[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            REGION_LEAVES,
            &[[0, 1, 2]],
        );
        let text = String::from_utf8_lossy(&p);
        let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.contains("element vertex 3") && text.contains("property float region_x"));
        assert_eq!(p.len() - header_end, 3 * 9 * 4 + 13);
        let f = |k: usize| {
            f32::from_le_bytes(
                p[header_end + 4 * k..header_end + 4 * k + 4]
                    .try_into()
                    .unwrap(),
            )
        };
        assert_eq!(f(8), REGION_LEAVES);
        assert_eq!(f(9), 1.0);
    }
}
