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

/// One registry line: its name, the stage's module (`None`: the graph's own `ingest`), type, and
/// what of the pipeline it has (`always`, `switch`, `switch, options`, `switch, options = x`).
#[derive(Debug)]
struct Line {
    name: String,
    module: Option<String>,
    ty: String,
    what: String,
}

/// The lines of the `registry! { ... }` invocation of `src/graph/stage.rs`.
fn registry(src: &str) -> Vec<Line> {
    let start = src.find("\nregistry! {\n").expect("the registry");
    let body = &src[start + "\nregistry! {\n".len()..];
    let end = body.find("\n}\n").expect("the registry's end");
    body[..end]
        .lines()
        .map(|l| {
            let l = l.trim();
            let form = format!("a registry entry is one line `name: path [what];`: {l:?}");
            let (name, rest) = l.split_once(": ").expect(&form);
            let (path, what) = rest.split_once(" [").expect(&form);
            let what = what.strip_suffix("];").expect(&form);
            let (module, ty) = match path.strip_prefix("crate::") {
                Some(rest) => {
                    let parts: Vec<&str> = rest.split("::").collect();
                    assert_eq!(parts.len(), 3, "crate::<module>::stage::<Type>: {path}");
                    assert_eq!(parts[1], "stage", "{path}");
                    (Some(parts[0].to_string()), parts[2].to_string())
                }
                None => (None, path.to_string()),
            };
            Line {
                name: name.to_string(),
                module,
                ty,
                what: what.to_string(),
            }
        })
        .collect()
}

/// The library part of a file under `src/`.
fn source(root: &Path, rel: &str) -> String {
    let s = std::fs::read_to_string(root.join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"));
    library_part(&s).to_string()
}

/// The `impl Stage for <ty>` block of `src`.
fn impl_block<'a>(src: &'a str, ty: &str, file: &str) -> &'a str {
    let at = src
        .find(&format!("impl Stage for {ty} {{"))
        .unwrap_or_else(|| panic!("{file}: no `impl Stage for {ty}`"));
    let body = &src[at..];
    &body[..body.find("\n}\n").expect("the impl's end")]
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
            "fn options_in(",
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
        assert_eq!(name, l.name, "{}: the registry line's name", file.display());
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
            // (The registry's line names it once.)
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
            ("envmaps", 5),
            ("cluster", 4),
            ("bittree", 3),
            ("svo", 4),
            ("linespace", 2)
        ]
    );
    let from_registry: Vec<(&str, u32)> = bake::graph::stage::REGISTRY
        .iter()
        .map(|s| (s.def().name, s.def().version))
        .collect();
    assert_eq!(got, from_registry);
}

/// The part of issue 36's rule that a stage's options, kinds and warnings are declared in its
/// own folder: its `impl Stage` names its options type and its presets' values (`options_in`);
/// the pipeline's structs, presets and checks (`src/graph/preset.rs`, `src/graph/mod.rs`,
/// `src/graph/stage.rs` outside the registry's lines) name no stage's options type; the central
/// lists of section kinds (`src/kinds/`) and of warnings (`diag::DIAGNOSTICS`) hold no stage's
/// rows. (At run time the registry carries them: `kinds::all`, `graph::stage::diagnostics`.)
#[test]
fn a_stage_s_options_kinds_and_warnings_are_declared_in_its_folder() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let graph_stage = source(root, "src/graph/stage.rs");
    let lines = registry(&graph_stage);
    // The registry's lines themselves are the one place outside the folder.
    let block_start = graph_stage.find("\nregistry! {\n").unwrap();
    let block_end = block_start + graph_stage[block_start..].find("\n}\n").unwrap();
    let graph_stage_rest = format!(
        "{}{}",
        &graph_stage[..block_start],
        &graph_stage[block_end..]
    );
    let central: Vec<(&str, String)> = vec![
        ("src/graph/stage.rs", graph_stage_rest),
        ("src/graph/preset.rs", source(root, "src/graph/preset.rs")),
        ("src/graph/mod.rs", source(root, "src/graph/mod.rs")),
        ("src/graph/stages.rs", source(root, "src/graph/stages.rs")),
        ("src/kinds/mod.rs", source(root, "src/kinds/mod.rs")),
        ("src/kinds/checks.rs", source(root, "src/kinds/checks.rs")),
        ("src/diag.rs", source(root, "src/diag.rs")),
    ];
    let mut checked = 0;
    for l in &lines {
        let Some(module) = &l.module else { continue };
        let file = format!("src/{module}/stage.rs");
        let src = source(root, &file);
        let body = impl_block(&src, &l.ty, &file);
        let opt = body
            .split("type Options = ")
            .nth(1)
            .and_then(|s| s.split(';').next())
            .unwrap_or_else(|| panic!("{file}: {} names no options type", l.ty))
            .trim();
        match l.what.as_str() {
            "switch, options" => {
                assert_ne!(opt, "()", "{file}: {} has a table but no options", l.ty);
                let ty = opt.rsplit("::").next().unwrap();
                for (f, text) in &central {
                    assert!(
                        !text.contains(ty),
                        "{f} names {ty}, the options of stage {}: a stage's options are \
                         declared in its folder (its `impl Stage`) and reach the pipeline \
                         through its registry line",
                        l.name
                    );
                }
                checked += 1;
            }
            "switch" | "always" => assert_eq!(opt, "()", "{file}: {}", l.ty),
            shared => {
                let other = shared
                    .strip_prefix("switch, options = ")
                    .unwrap_or_else(|| panic!("{}: unknown registry form {shared:?}", l.name));
                let o = lines
                    .iter()
                    .find(|o| o.name == other)
                    .expect("its table's stage");
                assert_eq!(
                    o.what, "switch, options",
                    "{}: {other} has no table",
                    l.name
                );
            }
        }
        // The central kind lists name no module of a registered stage: its kinds are its own.
        for f in ["src/kinds/mod.rs", "src/kinds/checks.rs"] {
            let text = &central.iter().find(|c| c.0 == f).unwrap().1;
            assert!(
                !text.contains(&format!("crate::{module}::")),
                "{f} names crate::{module}::, the folder of stage {}: its section kinds are \
                 declared in {file} (`Stage::kinds`)",
                l.name
            );
        }
    }
    assert!(checked >= 9, "{checked} stages with options");

    // At run time: each registered stage's kinds and warnings come from its registry line, and
    // the central lists hold none of a stage's.
    let stages: Vec<&str> = bake::graph::stage::REGISTRY
        .iter()
        .filter(|s| s.def().name != "ingest")
        .map(|s| s.def().name)
        .collect();
    for d in bake::diag::DIAGNOSTICS {
        let prefix = d.id.split('.').next().unwrap();
        assert!(
            !stages.contains(&prefix),
            "diag::DIAGNOSTICS lists {}: a stage's warnings are declared in its folder \
             (`Stage::diagnostics`)",
            d.id
        );
    }
    for s in bake::graph::stage::REGISTRY {
        for d in s.diagnostics() {
            assert!(
                d.id.starts_with(&format!("{}.", s.def().name)),
                "stage {} declares {}",
                s.def().name,
                d.id
            );
        }
        for k in s.kinds() {
            assert!(
                s.def().writes.contains(&k.kind),
                "stage {} declares kind {} but does not write it",
                s.def().name,
                k.kind
            );
        }
    }
    for k in bake::kinds::KINDS {
        assert!(
            !bake::graph::stage::REGISTRY
                .iter()
                .any(|s| s.kinds().iter().any(|o| o.kind == k.kind)),
            "{} is both central and a stage's",
            k.kind
        );
    }
}
