//! ECO scenes: a terrain line, `<GEOREF>`, then `<ECO>` with `<LAYER>`, `<TILING>` and instance
//! lines `model u v scale rotation_deg` (u, v relative to the area of interest).
//!
//! A scene may consist of several ECO files: they must name the same terrain; each places its
//! instances in its own area of interest. Models are loaded once each (in parallel) and
//! instanced.

use super::IngestOptions;
use super::raw::RawSpec;
use crate::error::{Error, ParseError, Result};
use crate::model::{Instance, Instances, Model, Rect, Scene};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The terrain line: `file width height unused scale`.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainLine {
    pub file: String,
    pub width: u32,
    pub height: u32,
    pub unused: f32,
    pub scale: f32,
}

/// `<GEOREF> x0 y0 ex ey ax ay aex aey`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Georef {
    pub terrain: Rect,
    pub aoi: Rect,
}

/// One instance line as written.
#[derive(Debug, Clone, PartialEq)]
pub struct EcoInstance {
    pub model: String,
    pub u: f32,
    pub v: f32,
    pub scale: f32,
    pub rotation_deg: f32,
    pub layer: i32,
    /// 1-based line number, for messages.
    pub line: usize,
}

/// A parsed ECO file.
#[derive(Debug, Clone, PartialEq)]
pub struct EcoFile {
    pub terrain: TerrainLine,
    pub georef: Georef,
    pub instances: Vec<EcoInstance>,
    pub warnings: Vec<String>,
}

fn fields(line: &str) -> Vec<&str> {
    let line = match line.find('#') {
        Some(k) => &line[..k],
        None => line,
    };
    line.split_whitespace().collect()
}

fn num<T: std::str::FromStr>(
    f: &[&str],
    k: usize,
    line: usize,
    what: &str,
) -> Result<T, ParseError> {
    let s = f
        .get(k)
        .ok_or_else(|| ParseError::at_line(line, format!("missing {what} (field {})", k + 1)))?;
    s.parse::<T>().map_err(|_| {
        ParseError::at_line(
            line,
            format!("{what} (field {}) is {s:?}, not a number", k + 1),
        )
    })
}

fn finite(v: f32, line: usize, what: &str) -> Result<f32, ParseError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ParseError::at_line(line, format!("{what} is not finite")))
    }
}

/// Parses an ECO file's text.
pub fn parse(bytes: &[u8]) -> Result<EcoFile, ParseError> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
            + 1;
        ParseError::at_line(line, "not ASCII/UTF-8 text")
    })?;
    let mut terrain = None;
    let mut georef = None;
    let mut in_eco = false;
    let mut layer = 0i32;
    let mut instances = Vec::new();
    let mut warnings = Vec::new();
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let f = fields(raw);
        let Some(&head) = f.first() else { continue };
        if head.starts_with('<') {
            match head.to_ascii_uppercase().as_str() {
                "<GEOREF>" => {
                    let mut v = [0f32; 8];
                    for (i, x) in v.iter_mut().enumerate() {
                        *x = finite(num(&f, i + 1, line, "GEOREF value")?, line, "GEOREF value")?;
                    }
                    if v[2] <= 0.0 || v[3] <= 0.0 {
                        return Err(ParseError::at_line(line, "terrain extent must be positive"));
                    }
                    georef = Some(Georef {
                        terrain: Rect {
                            origin: [v[0], v[1]],
                            extent: [v[2], v[3]],
                        },
                        aoi: Rect {
                            origin: [v[4], v[5]],
                            extent: [v[6], v[7]],
                        },
                    });
                }
                "<ECO>" => {
                    if georef.is_none() {
                        return Err(ParseError::at_line(
                            line,
                            "<ECO> before <GEOREF>: the area of interest is not known",
                        ));
                    }
                    in_eco = true;
                }
                "<LAYER>" => layer = num(&f, 1, line, "layer number")?,
                "<TILING>" => {}
                _ => {
                    return Err(ParseError::at_line(
                        line,
                        format!(
                            "unknown tag {head}; expected <GEOREF>, <ECO>, <LAYER> or <TILING>"
                        ),
                    ));
                }
            }
            continue;
        }
        if terrain.is_none() {
            if f.len() < 5 {
                return Err(ParseError::at_line(
                    line,
                    "terrain line needs 5 fields: file width height unused scale",
                ));
            }
            let t = TerrainLine {
                file: f[0].to_string(),
                width: num(&f, 1, line, "terrain width")?,
                height: num(&f, 2, line, "terrain height")?,
                unused: num(&f, 3, line, "third terrain value")?,
                scale: finite(num(&f, 4, line, "terrain scale")?, line, "terrain scale")?,
            };
            if t.width < 2 || t.height < 2 || t.width > 65536 || t.height > 65536 {
                return Err(ParseError::at_line(
                    line,
                    format!("terrain size {}×{} outside 2..65536", t.width, t.height),
                ));
            }
            terrain = Some(t);
            continue;
        }
        if !in_eco {
            return Err(ParseError::at_line(
                line,
                format!("unexpected line {:?} before <ECO>", raw.trim()),
            ));
        }
        if f.len() != 5 {
            return Err(ParseError::at_line(
                line,
                format!(
                    "instance line has {} fields, expected 5: model u v scale rotation",
                    f.len()
                ),
            ));
        }
        let inst = EcoInstance {
            model: f[0].to_string(),
            u: finite(num(&f, 1, line, "u position")?, line, "u position")?,
            v: finite(num(&f, 2, line, "v position")?, line, "v position")?,
            scale: finite(num(&f, 3, line, "scale")?, line, "scale")?,
            rotation_deg: finite(num(&f, 4, line, "rotation")?, line, "rotation")?,
            layer,
            line,
        };
        if !(0.0..=1.0).contains(&inst.u) || !(0.0..=1.0).contains(&inst.v) {
            warnings.push(format!(
                "line {line}: position ({}, {}) lies outside the area of interest [0,1]²",
                inst.u, inst.v
            ));
        }
        instances.push(inst);
    }
    let terrain = terrain.ok_or_else(|| {
        ParseError::at_line(1, "no terrain line (file width height unused scale)")
    })?;
    let georef = georef
        .ok_or_else(|| ParseError::at_line(text.lines().count().max(1), "no <GEOREF> line"))?;
    Ok(EcoFile {
        terrain,
        georef,
        instances,
        warnings,
    })
}

/// Resolves a model name to a file: `name.txf` when it has no known model extension, searched
/// in the ECO file's folder, then in each `--models` folder.
pub fn resolve_model(
    name: &str,
    eco_dir: &Path,
    model_dirs: &[PathBuf],
) -> std::result::Result<PathBuf, Vec<PathBuf>> {
    let has_ext = matches!(
        super::InputKind::of(Path::new(name)),
        Some(
            super::InputKind::Txf
                | super::InputKind::Max3ds
                | super::InputKind::Obj
                | super::InputKind::Gltf
        )
    );
    let candidates: Vec<String> = if has_ext {
        vec![name.to_string()]
    } else {
        vec![format!("{name}.txf"), format!("{name}.TXF")]
    };
    let mut tried = Vec::new();
    for dir in std::iter::once(eco_dir).chain(model_dirs.iter().map(PathBuf::as_path)) {
        for c in &candidates {
            let p = dir.join(c);
            if p.is_file() {
                return Ok(p);
            }
            tried.push(p);
        }
    }
    Err(tried)
}

/// Reads one or more ECO files into a scene: terrain, models (loaded once), instances.
pub fn load_scene(paths: &[PathBuf], opts: &IngestOptions) -> Result<Scene> {
    let plan = scene_plan(paths, opts)?;
    let policy = scene_policy(&paths[0], opts);
    let meshes: Vec<Result<crate::model::Mesh>> = plan
        .models
        .par_iter()
        .map(|(_, path)| super::load_mesh_in(path, &policy))
        .collect();
    let mut scene = plan.scene;
    for ((name, path), mesh) in plan.models.iter().zip(meshes) {
        let mesh = mesh?;
        scene.warnings.extend(
            mesh.warnings
                .iter()
                .map(|w| format!("{}: {w}", path.display())),
        );
        scene.models.push(Model {
            name: name.clone(),
            path: path.clone(),
            mesh,
        });
    }
    Ok(scene)
}

/// A scene before its models are read: the terrain, the instances and the resolved model files
/// (name, path) in order of first appearance (`scene.models` is empty).
#[derive(Debug, Clone)]
pub struct ScenePlan {
    pub scene: Scene,
    pub models: Vec<(String, PathBuf)>,
    /// Every ECO file, the RAW file and the colour map read.
    pub files: Vec<PathBuf>,
}

/// Reads the ECO files and the terrain and resolves every model name, without reading models.
pub fn scene_plan(paths: &[PathBuf], opts: &IngestOptions) -> Result<ScenePlan> {
    let first = paths
        .first()
        .ok_or_else(|| Error::usage("no ECO file given"))?;
    let policy = scene_policy(first, opts);
    check_further_eco_files(&paths[1..], &policy.roots)?;
    let mut files = Vec::new();
    for p in paths {
        let eco = parse(&crate::error::read_file(p)?).map_err(|e| Error::invalid(p, e))?;
        files.push((p.clone(), eco));
    }
    let (_, head) = &files[0];
    for (p, eco) in &files[1..] {
        if eco.terrain != head.terrain || eco.georef.terrain != head.georef.terrain {
            return Err(Error::invalid_at(
                p,
                "terrain line",
                format!(
                    "names terrain {:?} {:?}, but {} names {:?} {:?}; one scene has one terrain",
                    eco.terrain,
                    eco.georef.terrain,
                    first.display(),
                    head.terrain,
                    head.georef.terrain
                ),
            ));
        }
    }
    let dir = |p: &Path| p.parent().map(Path::to_path_buf).unwrap_or_default();
    let spec = RawSpec {
        width: head.terrain.width,
        height: head.terrain.height,
        scale: head.terrain.scale,
        origin: head.georef.terrain.origin,
        extent: head.georef.terrain.extent,
    };
    let terrain = load_terrain(first, &head.terrain.file, &spec, opts, &policy)?;

    // Resolve every model name once, in order of first appearance.
    let mut index: HashMap<PathBuf, u32> = HashMap::new();
    let mut model_paths: Vec<(String, PathBuf)> = Vec::new();
    let mut items = Vec::new();
    let mut aoi: Option<Rect> = None;
    let mut warnings = Vec::new();
    for (p, eco) in &files {
        warnings.extend(eco.warnings.iter().map(|w| format!("{}: {w}", p.display())));
        let a = eco.georef.aoi;
        aoi = Some(match aoi {
            None => a,
            Some(b) => union(a, b),
        });
        for inst in &eco.instances {
            if items.len() as u64 >= policy.limits.max_instances {
                return Err(Error::invalid_at(
                    p,
                    format!("line {}", inst.line),
                    format!(
                        "more than {} instances in the scene (the limit)",
                        policy.limits.max_instances
                    ),
                ));
            }
            let path = resolve_model(&inst.model, &dir(p), &opts.model_dirs).map_err(|tried| {
                let list: Vec<String> = tried.iter().map(|t| t.display().to_string()).collect();
                Error::invalid_at(
                    p,
                    format!("line {}", inst.line),
                    format!(
                        "model {:?} not found; looked for {}",
                        inst.model,
                        list.join(", ")
                    ),
                )
            })?;
            let (inside, resolved) = policy.roots.resolve(&path);
            if !inside {
                let place = format!("line {}", inst.line);
                return Err(policy
                    .roots
                    .refusal(p, place, "model", &inst.model, &resolved));
            }
            let next = model_paths.len() as u32;
            let model = *index.entry(path.clone()).or_insert_with(|| {
                let name = path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                model_paths.push((name, path.clone()));
                next
            });
            let x = a.origin[0] + inst.u * a.extent[0];
            let y = a.origin[1] + inst.v * a.extent[1];
            let position = [x, y, terrain.height_at(x, y)];
            items.push(Instance {
                model,
                position,
                scale: inst.scale,
                rotation_deg: inst.rotation_deg,
                layer: inst.layer,
            });
        }
    }
    let names = model_paths.iter().map(|m| m.0.clone()).collect();
    let raw = dir(first).join(&head.terrain.file);
    let mut read: Vec<PathBuf> = paths.to_vec();
    if let Some(c) = opts
        .color_map
        .clone()
        .or_else(|| super::raw::find_color_map(&raw))
    {
        read.push(raw);
        read.push(c);
    } else {
        read.push(raw);
    }
    Ok(ScenePlan {
        scene: Scene {
            terrain: Some(terrain),
            models: Vec::new(),
            instances: Instances {
                models: names,
                items,
            },
            aoi: aoi.unwrap_or_default(),
            sky: None,
            warnings,
        },
        models: model_paths,
        files: read,
    })
}

/// The roots of a scene: the first ECO file's folder, the `--models` and `--allow-path`
/// folders; and the limits.
pub fn scene_policy(first: &Path, opts: &IngestOptions) -> super::ReadPolicy {
    let extra: Vec<PathBuf> = opts
        .model_dirs
        .iter()
        .chain(&opts.allow_paths)
        .cloned()
        .collect();
    super::ReadPolicy {
        roots: super::confine::Roots::around(first, &extra),
        limits: opts.limits,
    }
}

/// The location-independent names of a scene's files ([`super::confine::SourceNames`]): its
/// roots as [`scene_policy`] has them, labelled.
pub fn scene_names(first: &Path, opts: &IngestOptions) -> super::confine::SourceNames {
    super::confine::SourceNames::new(first, &opts.model_dirs, &opts.allow_paths)
}

/// The further ECO files of a scene lie inside its roots too.
fn check_further_eco_files(paths: &[PathBuf], roots: &super::confine::Roots) -> Result<()> {
    for p in paths {
        let (inside, resolved) = roots.resolve(p);
        if !inside {
            let name = p.display().to_string();
            return Err(roots.refusal(
                p,
                "command line".into(),
                "further ECO file",
                &name,
                &resolved,
            ));
        }
    }
    Ok(())
}

/// The terrain named by the ECO file, and its colour map (given, or found beside it), inside
/// the roots and within the memory budget.
fn load_terrain(
    eco: &Path,
    name: &str,
    spec: &RawSpec,
    opts: &IngestOptions,
    policy: &super::ReadPolicy,
) -> Result<crate::model::Terrain> {
    let dir = eco.parent().map(Path::to_path_buf).unwrap_or_default();
    let path = dir.join(name);
    policy.roots.check(eco, "terrain", name, &path)?;
    let decoded = spec.width as u64 * spec.height as u64 * 4;
    policy
        .limits
        .check_memory(eco, "terrain line", "the terrain", decoded)?;
    let color = match &opts.color_map {
        Some(c) => Some(c.clone()),
        None => super::raw::find_color_map(&path),
    };
    if let Some(c) = &color {
        if opts.color_map.is_none() {
            let (inside, resolved) = policy.roots.resolve(c);
            if !inside {
                let c_name = c.file_name().map(|f| f.to_string_lossy().into_owned());
                let place =
                    super::confine::place_of(&std::fs::read(eco).unwrap_or_default(), name, false);
                return Err(policy.roots.refusal(
                    eco,
                    place.unwrap_or_else(|| "terrain line".into()),
                    "terrain colour map",
                    &c_name.unwrap_or_default(),
                    &resolved,
                ));
            }
        }
        super::check_image_header(c, "colour map", &policy.limits)?;
    }
    super::raw::load(&path, spec, color.as_deref())
}

fn union(a: Rect, b: Rect) -> Rect {
    let lo = [a.origin[0].min(b.origin[0]), a.origin[1].min(b.origin[1])];
    let hi = [
        (a.origin[0] + a.extent[0]).max(b.origin[0] + b.extent[0]),
        (a.origin[1] + a.extent[1]).max(b.origin[1] + b.extent[1]),
    ];
    Rect {
        origin: lo,
        extent: [hi[0] - lo[0], hi[1] - lo[1]],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const THESIS: &str = "beispiel.RAW 1024 1024 1 0.05\n<GEOREF> 0 0 200.0 200.0 10.0 110.0 40.0 50.0\n<ECO>\n<LAYER> 1\n<TILING> 0\nAnthriscus_sylvestris_001 0.499 0.471 1.3 10.0\n<LAYER> 2\n  tree.3ds 0 1 2 350\n";

    #[test]
    fn parses_the_thesis_example() {
        let e = parse(THESIS.as_bytes()).unwrap();
        assert_eq!(
            e.terrain,
            TerrainLine {
                file: "beispiel.RAW".into(),
                width: 1024,
                height: 1024,
                unused: 1.0,
                scale: 0.05
            }
        );
        assert_eq!(
            e.georef.terrain,
            Rect {
                origin: [0.0, 0.0],
                extent: [200.0, 200.0]
            }
        );
        assert_eq!(
            e.georef.aoi,
            Rect {
                origin: [10.0, 110.0],
                extent: [40.0, 50.0]
            }
        );
        assert_eq!(e.instances.len(), 2);
        assert_eq!(e.instances[0].model, "Anthriscus_sylvestris_001");
        assert_eq!(
            (
                e.instances[0].u,
                e.instances[0].v,
                e.instances[0].scale,
                e.instances[0].rotation_deg
            ),
            (0.499, 0.471, 1.3, 10.0)
        );
        assert_eq!((e.instances[0].layer, e.instances[1].layer), (1, 2));
        assert_eq!(e.instances[1].line, 8);
        assert!(e.warnings.is_empty());
    }

    #[test]
    fn errors_name_the_line() {
        let cases = [
            (
                "t.raw 4 4 1 1\n<GEOREF> 0 0 1 1 0 0 1 1\n<ECO>\nm 0.5 x 1 0\n",
                "line 4",
                "v position",
            ),
            (
                "t.raw 4 4 1 1\n<GEOREF> 0 0 1 1 0 0 1 1\n<ECO>\nm 0.5 0.5 1\n",
                "line 4",
                "expected 5",
            ),
            (
                "t.raw 4 4 1 1\n<GEOREF> 0 0 1 1 0 0 1 1\n<FOO>\n",
                "line 3",
                "unknown tag",
            ),
            ("t.raw 4 4 1 1\n<ECO>\n", "line 2", "before <GEOREF>"),
            ("t.raw 4 4\n", "line 1", "5 fields"),
            ("t.raw 4 4 1 1\nm 0 0 1 0\n", "line 2", "before <ECO>"),
            (
                "t.raw 4 4 1 1\n<GEOREF> 0 0 1 1 0 0 1 NaN\n",
                "line 2",
                "not finite",
            ),
            ("t.raw 99999999 4 1 1\n", "line 1", "outside"),
        ];
        for (text, place, msg) in cases {
            let e = parse(text.as_bytes()).unwrap_err();
            assert_eq!(e.place, place, "{text}");
            assert!(e.message.contains(msg), "{text}: {}", e.message);
        }
    }

    #[test]
    fn outside_positions_warn() {
        let e = parse(b"t.raw 4 4 1 1\n<GEOREF> 0 0 1 1 0 0 1 1\n<ECO>\nm 1.5 0.5 1 0\n").unwrap();
        assert_eq!(e.warnings.len(), 1);
    }
}
