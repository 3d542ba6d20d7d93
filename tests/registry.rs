//! Adding a stage touches its own folder and one registry line (issue 36, "Done when";
//! docs/ARCHITECTURE.md, "Adding a stage").
//!
//! The test reads the sources: the registry (`pub static REGISTRY` in `src/graph/stage.rs`) has
//! one line per stage, and each line names the stage's type in its own folder
//! (`crate::<module>::stage::<Type>`). That folder's `stage.rs` holds the whole `impl Stage`
//! (its `def`, with name and version, `reads`, `run`), no other file names the type but the
//! registry's line, every `impl Stage` of the library is a registered one, and the graph's
//! version list holds no constant of its own (the build key takes the versions from the
//! registry). What the registry drives at run time (the graph, the plans, `bake unit`) is
//! tested by the toy stage of `plan::registry_tests`, registered there by one line.

use std::path::{Path, PathBuf};

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The text before the first `#[cfg(test)]` (the library code of a file; test modules come
/// last in this crate).
fn library_part(src: &str) -> &str {
    src.find("#[cfg(test)]").map_or(src, |i| &src[..i])
}

/// One registry line: the stage's module (`None`: the graph's own `ingest`) and type.
#[derive(Debug)]
struct Line {
    module: Option<String>,
    ty: String,
}

fn registry(src: &str) -> Vec<Line> {
    let start = src
        .find("pub static REGISTRY: &[&dyn AnyStage] = &[")
        .expect("the registry");
    let body = &src[start..];
    let end = body.find("\n];").expect("the registry's end");
    body[..end]
        .lines()
        .skip(1)
        .map(|l| {
            let l = l.trim();
            assert!(
                l.starts_with("&Registered { stage: ") && l.ends_with("},"),
                "a registry entry is one line: {l:?}"
            );
            let path = l["&Registered { stage: ".len()..]
                .split(',')
                .next()
                .unwrap()
                .trim();
            match path.strip_prefix("crate::") {
                Some(rest) => {
                    let parts: Vec<&str> = rest.split("::").collect();
                    assert_eq!(parts.len(), 3, "crate::<module>::stage::<Type>: {path}");
                    assert_eq!(parts[1], "stage", "{path}");
                    Line {
                        module: Some(parts[0].to_string()),
                        ty: parts[2].to_string(),
                    }
                }
                None => Line {
                    module: None,
                    ty: path.to_string(),
                },
            }
        })
        .collect()
}

#[test]
fn every_stage_lives_in_its_own_folder_and_is_named_by_one_registry_line() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let graph_stage = std::fs::read_to_string(root.join("src/graph/stage.rs")).unwrap();
    let lines = registry(&graph_stage);
    assert!(lines.len() >= 13, "{lines:?}");
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    let sources: Vec<(PathBuf, String)> = files
        .iter()
        .map(|f| (f.clone(), std::fs::read_to_string(f).unwrap()))
        .collect();

    // The one exception: `ingest` is written by the graph (its module is the input layer,
    // below the stage interface, and it writes through `pipeline::add_mesh`).
    let own: Vec<&Line> = lines.iter().filter(|l| l.module.is_none()).collect();
    assert_eq!(own.len(), 1, "{own:?}");
    assert_eq!(own[0].ty, "Ingest");
    assert!(library_part(&graph_stage).contains("impl Stage for Ingest {"));

    let mut names = Vec::new();
    for l in lines.iter().filter(|l| l.module.is_some()) {
        let module = l.module.as_deref().unwrap();
        let file = root.join("src").join(module).join("stage.rs");
        let src =
            std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let src = library_part(&src);
        // The whole `impl Stage` is in the folder: its entry (name, version), reads and run.
        let at = src
            .find(&format!("impl Stage for {} {{", l.ty))
            .unwrap_or_else(|| panic!("{}: no `impl Stage for {}`", file.display(), l.ty));
        let body = &src[at..];
        let body = &body[..body.find("\n}\n").expect("the impl's end")];
        for part in [
            "fn def(",
            "static DEF: StageDef",
            "version:",
            "fn reads(",
            "fn run(",
        ] {
            assert!(
                body.contains(part),
                "{}: {} lacks {part}",
                file.display(),
                l.ty
            );
        }
        let name = body
            .split("name: \"")
            .nth(1)
            .and_then(|s| s.split('"').next())
            .expect("the stage's name");
        names.push(name.to_string());
        // The version is a constant of the folder, not of the graph.
        let version = body
            .split("version: ")
            .nth(1)
            .and_then(|s| s.split(',').next())
            .unwrap()
            .trim();
        assert!(
            version.chars().all(|c| c.is_ascii_uppercase() || c == '_')
                && src.contains(&format!("pub const {version}: u32 = ")),
            "{}: {}'s version {version:?} is not a constant of its folder",
            file.display(),
            l.ty
        );
        // No file outside the folder names the type, but the registry's line.
        let path = format!("{module}::stage::{}", l.ty);
        for (f, s) in &sources {
            if f.starts_with(root.join("src").join(module)) {
                continue;
            }
            let n = library_part(s).matches(&path).count();
            let allowed = usize::from(f.ends_with("src/graph/stage.rs"));
            assert_eq!(n, allowed, "{} names {path} {n} times", f.display());
        }
    }
    // Unique names, as the build key hashes them.
    let mut sorted = names.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), names.len(), "{names:?}");

    // Every `impl Stage` of the library is a registered one.
    for (f, s) in &sources {
        for (i, _) in library_part(s).match_indices("impl Stage for ") {
            let ty = library_part(s)[i + "impl Stage for ".len()..]
                .split(|c: char| !c.is_alphanumeric())
                .next()
                .unwrap();
            let registered = lines.iter().any(|l| {
                l.ty == ty
                    && match &l.module {
                        Some(m) => f.ends_with(format!("src/{m}/stage.rs")),
                        None => f.ends_with("src/graph/stage.rs"),
                    }
            });
            assert!(
                registered,
                "{}: `impl Stage for {ty}` is not registered",
                f.display()
            );
        }
    }

    // The graph keeps no version constant: the build key's list comes from the registry.
    let graph = std::fs::read_to_string(root.join("src/graph/mod.rs")).unwrap();
    let versions = &graph[graph.find("pub mod versions {").expect("graph::versions")..];
    let versions = &versions[..versions.find("\n}\n").unwrap()];
    assert!(!versions.contains("pub const"), "{versions}");
    assert!(versions.contains("stages::all()"), "{versions}");
}

#[test]
fn the_registry_gives_the_build_key_its_names_and_versions() {
    // The names and versions the build key hashes, from the registry's entries (pinned: a
    // change re-keys every pack's `build` record and the golden packs).
    let got: Vec<(&str, u32)> = bake::graph::versions::all();
    assert_eq!(
        got,
        [
            ("ingest", 4),
            ("material", 2),
            ("terrain", 1),
            ("sky", 3),
            ("prt", 5),
            ("lod", 5),
            ("lightmap", 3),
            ("atlas", 2),
            ("envmaps", 3),
            ("cluster", 4),
            ("bittree", 3),
            ("svo", 3),
            ("linespace", 2)
        ]
    );
    let from_registry: Vec<(&str, u32)> = bake::graph::stage::REGISTRY
        .iter()
        .map(|s| (s.def().name, s.def().version))
        .collect();
    assert_eq!(got, from_registry);
}
