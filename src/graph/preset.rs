//! Pipeline files (`pipelines/*.toml`): which stages a bake runs and every option of each.
//!
//! A file is the TOML form of [`Pipeline`]: a `[stages]` table of switches and one table per
//! stage holding that stage's option struct. Unknown keys and wrong types are errors that name
//! the file, the line and the key; a key left out takes the default pipeline's value. The
//! structs are written by the stage registry (`graph::stage::REGISTRY`): each stage declares its
//! options type and its switch and options in each preset in its own folder (`Stage::on_in`,
//! `Stage::options_in`); `pipelines/{default,preview,final,ci}.toml` spell the presets out and
//! a test keeps the two equal.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use super::stage::{Pipeline, Stages};
pub use crate::stage::Preset;

impl Default for Stages {
    fn default() -> Self {
        Pipeline::default_pipeline().stages
    }
}

/// How the graph splits the per-scene work into cache units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Units {
    /// Instances per environment-map shard (one cache unit each; the maps do not depend on it).
    pub envmap_shard_instances: u32,
}

impl Default for Units {
    fn default() -> Self {
        Pipeline::default_pipeline().units
    }
}

impl Units {
    /// The preset's units: 25,000 instances per env-map shard, 64 in `ci` (so that the cache
    /// is exercised unit by unit).
    pub fn of_preset(preset: Preset) -> Units {
        Units {
            envmap_shard_instances: match preset {
                Preset::Ci => 64,
                _ => 25_000,
            },
        }
    }
}

impl Default for Pipeline {
    fn default() -> Self {
        Pipeline::default_pipeline()
    }
}

/// The names of the presets, in the order `bake pipeline --list` shows them.
pub const PRESETS: [&str; 4] = ["default", "preview", "final", "ci"];

impl Pipeline {
    /// `pipelines/default.toml`: every lighting stage at the stages' default quality; SVO and
    /// line space off.
    pub fn default_pipeline() -> Pipeline {
        Pipeline::of_preset(Preset::Default)
    }

    /// `pipelines/preview.toml` (`--preview`): quick, noisy lighting (each stage's preview
    /// options: PRT 64 paths, 64 environment-map rays, 16 light-map rays with 4 sun rays, the
    /// terrain's light map at most 1025² texels).
    pub fn preview() -> Pipeline {
        Pipeline::of_preset(Preset::Preview)
    }

    /// `pipelines/final.toml`: each stage's final options (PRT 1,024 paths and 4 bounces, 256
    /// light-map rays at every texel, 1,024 environment-map rays, clustering at 1 %); SVO and
    /// line space on.
    pub fn final_quality() -> Pipeline {
        Pipeline::of_preset(Preset::Final)
    }

    /// `pipelines/ci.toml`: the preview's quality with the stages a CI job checks each commit
    /// (all but the optional SVO and line space), the env maps in small shards so that the
    /// cache is exercised unit by unit.
    pub fn ci() -> Pipeline {
        Pipeline::of_preset(Preset::Ci)
    }

    /// A preset by name.
    pub fn preset(name: &str) -> Option<Pipeline> {
        Preset::named(name).map(Pipeline::of_preset)
    }

    /// Reads a pipeline file; errors name the file, the line and the key.
    pub fn load(path: &Path) -> Result<Pipeline> {
        let bytes = crate::error::read_file(path)?;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            Error::invalid_at(
                path,
                format!("byte {}", e.valid_up_to()),
                "a pipeline file is UTF-8 TOML",
            )
        })?;
        Pipeline::parse(text, &path.display().to_string())
    }

    /// Parses pipeline TOML; `name` is the file named in errors.
    pub fn parse(text: &str, name: &str) -> Result<Pipeline> {
        let p: Pipeline = toml::from_str(text).map_err(|e| toml_error(name, text, &e))?;
        p.check()
            .map_err(|m| Error::invalid_at(name, "[stages]", m))?;
        Ok(p)
    }

    /// The TOML text of this pipeline (every option; `None` options are left out).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a pipeline serializes to TOML")
    }

    /// Applies `--set KEY=VALUE` (KEY a dotted path such as `prt.samples`; VALUE a TOML value,
    /// or a bare word taken as a string).
    pub fn set(&mut self, assignment: &str) -> Result<()> {
        let bad = |m: String| Error::usage(format!("--set {assignment}: {m}"));
        let (key, value) = assignment
            .split_once('=')
            .ok_or_else(|| bad("expected KEY=VALUE, e.g. prt.samples=256".into()))?;
        let key = key.trim();
        let value = value.trim();
        let parsed: toml::Value = toml::from_str::<toml::Table>(&format!("v = {value}"))
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or_else(|| toml::Value::String(value.to_string()));
        let mut root = toml::Value::try_from(&*self).map_err(|e| bad(e.to_string()))?;
        let parts: Vec<&str> = key.split('.').collect();
        let (last, path) = parts.split_last().ok_or_else(|| bad("empty key".into()))?;
        let mut node = &mut root;
        for (depth, p) in path.iter().enumerate() {
            let table = node
                .as_table_mut()
                .ok_or_else(|| bad(format!("{} is not a table", parts[..depth].join("."))))?;
            node = table
                .entry(p.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        }
        node.as_table_mut()
            .ok_or_else(|| bad(format!("{} is not a table", path.join("."))))?
            .insert(last.to_string(), parsed);
        let p: Pipeline = root
            .try_into()
            .map_err(|e: toml::de::Error| bad(e.message().to_string()))?;
        p.check().map_err(bad)?;
        *self = p;
        Ok(())
    }

    /// Every stage's inputs are switched on (each stage's [`Stage::needs`](crate::stage::Stage::needs)),
    /// then every stage's options pass its check, in registry order.
    pub fn check(&self) -> std::result::Result<(), String> {
        self.check_in(super::stage::REGISTRY)
    }

    /// [`Pipeline::check`] over the registry `registry` (a test's toy registry too).
    pub(crate) fn check_in(
        &self,
        registry: &[&dyn super::stage::AnyStage],
    ) -> std::result::Result<(), String> {
        for st in registry {
            if !st.on(self) {
                continue;
            }
            for what in st.needs() {
                let input_on = registry
                    .iter()
                    .find(|s| s.def().name == *what)
                    .is_some_and(|s| s.on(self));
                if !input_on {
                    return Err(format!(
                        "stage {} is on but reads the output of {what}, which is off",
                        st.def().name
                    ));
                }
            }
        }
        for st in registry {
            st.check(self)?;
        }
        if self.units.envmap_shard_instances == 0 {
            return Err("units.envmap_shard_instances must be at least 1".into());
        }
        Ok(())
    }
}

/// A TOML error as the project's invalid-input error: file, line and column, the line's text
/// (which names the key) and what was expected.
fn toml_error(name: &str, text: &str, e: &toml::de::Error) -> Error {
    let (place, line_text) = match e.span() {
        Some(span) => {
            let start = span.start.min(text.len());
            let line = text[..start].matches('\n').count() + 1;
            let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
            let col = text[line_start..start].chars().count() + 1;
            let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
            (
                format!("line {line}, column {col}"),
                text[line_start..line_end].trim().to_string(),
            )
        }
        None => ("pipeline".to_string(), String::new()),
    };
    let msg = e.message().trim().to_string();
    let msg = if line_text.is_empty() {
        msg
    } else {
        format!("{msg} (at `{line_text}`)")
    };
    Error::invalid_at(name, place, msg)
}

/// The pipeline of `--pipeline`/`--preview`/`--set`, and the file it came from.
pub fn resolve(
    pipeline: Option<&str>,
    preview: bool,
    set: &[String],
) -> Result<(Pipeline, Option<std::path::PathBuf>)> {
    let (mut p, file) = match (pipeline, preview) {
        (_, true) => (Pipeline::preview(), None),
        (None, false) => (Pipeline::default_pipeline(), None),
        (Some(name), false) => match Pipeline::preset(name) {
            Some(p) if !std::path::Path::new(name).exists() => (p, None),
            _ => {
                let path = std::path::PathBuf::from(name);
                if !path.exists() {
                    return Err(Error::usage(format!(
                        "--pipeline {name}: no such file, and not a preset (one of {})",
                        PRESETS.join(", ")
                    )));
                }
                (Pipeline::load(&path)?, Some(path))
            }
        },
    };
    for s in set {
        p.set(s)?;
    }
    Ok((p, file))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lightmap::LightmapOptions;
    use crate::prt::transfer::PrtOptions;

    /// `prt.tracer` is spelled out, enters the PRT stage's key through its options, and a
    /// backend the binary lacks is refused (never a silent fallback).
    #[test]
    fn prt_tracer_is_spelled_keyed_and_checked() {
        use crate::prt::transfer::PrtTracer;
        let mut p = Pipeline::default_pipeline();
        assert!(p.to_toml().contains("tracer = \"cpu\""), "{}", p.to_toml());
        let key = |o: &PrtOptions| {
            let mut k = crate::graph::cache::KeyBuilder::new("0", "prt", 1, "m");
            k.options(o);
            k.finish()
        };
        let embree = PrtOptions {
            tracer: PrtTracer::Embree,
            ..p.prt.clone()
        };
        assert_ne!(key(&p.prt), key(&embree));
        let r = p.set("prt.tracer=embree");
        if cfg!(feature = "embree") {
            r.unwrap();
            assert_eq!(p.prt.tracer, PrtTracer::Embree);
        } else {
            let e = r.unwrap_err().to_string();
            assert!(e.contains("--features embree"), "{e}");
            assert_eq!(p.prt.tracer, PrtTracer::Cpu);
        }
        assert!(p.set("prt.tracer=optix").is_err());
    }

    /// `lightmap.tracer` and `envmaps.tracer` are spelled out in every preset, parse with the
    /// PRT's spelling, and a backend the binary lacks is refused naming the option and the
    /// feature.
    #[test]
    fn lighting_tracers_are_spelled_and_checked() {
        use crate::trace::Tracer;
        for name in PRESETS {
            let p = Pipeline::preset(name).unwrap();
            let toml = p.to_toml();
            assert_eq!(
                toml.matches("tracer = \"cpu\"").count(),
                3,
                "{name}: {toml}"
            );
        }
        for key in ["lightmap.tracer", "envmaps.tracer"] {
            let mut p = Pipeline::default_pipeline();
            let r = p.set(&format!("{key}=embree"));
            if cfg!(feature = "embree") {
                r.unwrap();
                assert_eq!(
                    (p.lightmap.tracer == Tracer::Embree) as u8
                        + (p.envmaps.tracer == Tracer::Embree) as u8,
                    1
                );
            } else {
                let e = r.unwrap_err().to_string();
                assert!(e.contains(key) && e.contains("--features embree"), "{e}");
                assert_eq!(p, Pipeline::default_pipeline());
            }
            assert!(p.set(&format!("{key}=optix")).is_err());
        }
    }

    fn repo_file(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("pipelines")
            .join(format!("{name}.toml"))
    }

    #[test]
    fn pipeline_files_equal_the_code_presets() {
        for name in PRESETS {
            let file = Pipeline::load(&repo_file(name)).unwrap();
            let code = Pipeline::preset(name).unwrap();
            // The tables that differ, as the registry's preset spells them (a new stage's
            // table missing from the file shows here: paste it from `bake pipeline show`).
            let (f, c) = (
                toml::Value::try_from(&file).unwrap(),
                toml::Value::try_from(&code).unwrap(),
            );
            let differ: Vec<String> = c
                .as_table()
                .unwrap()
                .iter()
                .filter(|(k, v)| f.get(k.as_str()) != Some(v))
                .map(|(k, v)| format!("[{k}]\n{}", toml::to_string(v).unwrap_or_default()))
                .collect();
            assert_eq!(
                file,
                code,
                "pipelines/{name}.toml differs from the registry's preset {name:?} \
                 (`bake pipeline show {name}`) in:\n{}",
                differ.join("\n")
            );
        }
        assert_ne!(Pipeline::preview(), Pipeline::default_pipeline());
        assert_ne!(Pipeline::final_quality(), Pipeline::default_pipeline());
        assert!(Pipeline::final_quality().stages.svo && !Pipeline::default_pipeline().stages.svo);
    }

    #[test]
    fn the_presets_are_the_registry_s() {
        let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
        assert_eq!(names, PRESETS);
        // The values the presets had before they moved beside the stages (issue 36).
        let f = Pipeline::final_quality();
        assert_eq!((f.prt.samples, f.prt.bounces), (1024, 4));
        assert_eq!(
            (
                f.lightmap.samples,
                f.lightmap.sun_samples,
                f.lightmap.trace_step
            ),
            (256, 32, 1)
        );
        assert_eq!((f.envmaps.samples, f.cluster.error), (1024, 0.01));
        assert!(f.stages.svo && f.stages.linespace);
        let v = Pipeline::preview();
        assert_eq!(v.prt, PrtOptions::preview());
        assert_eq!(
            (
                v.lightmap.max_resolution,
                v.lightmap.samples,
                v.lightmap.sun_samples,
                v.lightmap.horizon_lattice
            ),
            (Some(1025), 16, 4, 2)
        );
        assert_eq!(v.envmaps.samples, 64);
        assert!(!v.stages.svo && !v.stages.linespace);
        let c = Pipeline::ci();
        assert_eq!(c.units.envmap_shard_instances, 64);
        assert_eq!(
            Pipeline {
                units: v.units,
                ..c
            },
            v
        );
        assert_eq!(
            Pipeline::default_pipeline().units.envmap_shard_instances,
            25_000
        );
    }

    #[test]
    fn serialized_presets_read_back_equal() {
        for name in PRESETS {
            let p = Pipeline::preset(name).unwrap();
            assert_eq!(Pipeline::parse(&p.to_toml(), name).unwrap(), p, "{name}");
        }
    }

    #[test]
    fn an_unknown_key_names_the_file_line_and_key() {
        let text = "[stages]\nprt = true\n\n[prt]\nsamples = 64\nsampels = 3\n";
        let e = Pipeline::parse(text, "my.toml").unwrap_err().to_string();
        assert!(e.contains("my.toml"), "{e}");
        assert!(e.contains("line 6"), "{e}");
        assert!(e.contains("sampels"), "{e}");
        assert_eq!(
            Error::exit_code(&Pipeline::parse(text, "x").unwrap_err()),
            4
        );
    }

    #[test]
    fn a_wrong_type_names_the_file_line_and_key() {
        let text = "[lightmap]\nsamples = \"many\"\n";
        let e = Pipeline::parse(text, "p.toml").unwrap_err().to_string();
        assert!(
            e.contains("p.toml") && e.contains("line 2") && e.contains("samples"),
            "{e}"
        );
        let text = "[stages]\nsky = 3\n";
        let e = Pipeline::parse(text, "p.toml").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("sky"), "{e}");
    }

    #[test]
    fn a_missing_key_takes_the_default_and_set_overrides() {
        let p = Pipeline::parse("[prt]\nsamples = 32\n", "p.toml").unwrap();
        assert_eq!(p.prt.samples, 32);
        assert_eq!(p.prt.bounces, PrtOptions::standard().bounces);
        assert_eq!(p.lightmap, LightmapOptions::DEFAULT);
        let mut q = p.clone();
        q.set("prt.samples=256").unwrap();
        q.set("lightmap.mode=Thesis").unwrap();
        q.set("lightmap.resolution = 129").unwrap();
        q.set("stages.svo=true").unwrap();
        assert_eq!(q.prt.samples, 256);
        assert_eq!(q.lightmap.mode, crate::lightmap::LightmapMode::Thesis);
        assert_eq!(q.lightmap.resolution, Some(129));
        assert!(q.stages.svo);
        for bad in [
            "prt.sampels=3",
            "prt.samples=many",
            "prt",
            "stages.cluster=1",
        ] {
            let e = q.clone().set(bad).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}: {e}");
        }
    }

    #[test]
    fn a_stage_without_its_input_is_refused() {
        let text = "[stages]\nenvmaps = false\n";
        let e = Pipeline::parse(text, "p.toml").unwrap_err().to_string();
        assert!(e.contains("cluster") && e.contains("envmaps"), "{e}");
    }
}
