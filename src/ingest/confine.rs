//! Path confinement: every file a scene reads must lie inside one of its roots.
//!
//! The roots are the folder of the (first) ECO file or of the single input file, every
//! `--models` folder and every `--allow-path` folder. A referenced name (a model in an ECO
//! file, a texture in a TXF/3DS/MTL/glTF file, an MTL library, a glTF buffer, the terrain and
//! its colour map, a further ECO file) is joined to its referring file's folder and resolved
//! with symlinks followed (`std::fs::canonicalize`; the part of a path that does not exist yet
//! is normalised lexically); the result must start with a canonical root. Absolute names and
//! `..` escapes are refused with exit 4, naming the referring file, the place of the reference
//! (line, or byte offset in a binary file) and the resolved path. The check runs before the
//! file is opened, so a refused file is never read. glTF `data:` URIs read no file and are not
//! affected.
//!
//! Files named on the command line (`--sky`, `--color-map`, the input itself) are the user's
//! choice and are not checked.
//!
//! The same roots, labelled, name files in packs and cache keys ([`SourceNames`]).

use crate::error::{Error, ParseError, Result};
use std::path::{Component, Path, PathBuf};

/// The folders a scene may read from (canonical).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Roots {
    dirs: Vec<PathBuf>,
}

impl Roots {
    /// Roots from folders; folders that do not exist are dropped (they hold nothing to read).
    pub fn new<'a>(dirs: impl IntoIterator<Item = &'a Path>) -> Roots {
        let mut out: Vec<PathBuf> = Vec::new();
        for d in dirs {
            let d = if d.as_os_str().is_empty() {
                Path::new(".")
            } else {
                d
            };
            if let Ok(c) = std::fs::canonicalize(d)
                && !out.contains(&c)
            {
                out.push(c);
            }
        }
        Roots { dirs: out }
    }

    /// The folder of `file` plus `extra` folders.
    pub fn around(file: &Path, extra: &[PathBuf]) -> Roots {
        let dir = file.parent().unwrap_or(Path::new(""));
        Roots::new(std::iter::once(dir).chain(extra.iter().map(PathBuf::as_path)))
    }

    pub fn dirs(&self) -> &[PathBuf] {
        &self.dirs
    }

    /// Whether `path` (after symlinks) lies inside a root; returns the resolved path either way.
    pub fn resolve(&self, path: &Path) -> (bool, PathBuf) {
        let resolved = resolve(path);
        let inside = self.dirs.iter().any(|d| resolved.starts_with(d));
        (inside, resolved)
    }

    /// Refuses `path` (referenced as `name` by `referrer`) unless it lies inside a root. The
    /// place of the reference is looked up in the referrer's bytes only when refusing.
    pub fn check(&self, referrer: &Path, what: &str, name: &str, path: &Path) -> Result<()> {
        let (inside, resolved) = self.resolve(path);
        if inside {
            return Ok(());
        }
        let place = std::fs::read(referrer)
            .ok()
            .and_then(|b| place_of(&b, name, is_binary(referrer)))
            .unwrap_or_else(|| "reference".to_string());
        Err(self.refusal(referrer, place, what, name, &resolved))
    }

    /// The exit-4 error for a reference outside the roots.
    pub fn refusal(
        &self,
        referrer: &Path,
        place: String,
        what: &str,
        name: &str,
        resolved: &Path,
    ) -> Error {
        let roots: Vec<String> = self.dirs.iter().map(|d| d.display().to_string()).collect();
        let why = if Path::new(name).is_absolute() {
            "an absolute path"
        } else {
            "outside the scene's folders"
        };
        Error::invalid(
            referrer,
            ParseError::new(
                place,
                format!(
                    "{what} {name:?} resolves to {}, {why} ({}); pass --allow-path DIR to read it",
                    resolved.display(),
                    roots.join(", ")
                ),
            ),
        )
    }
}

/// Location-independent names of the files a scene reads, what sections, cache keys and the
/// build record store instead of paths (docs/FORMAT.md, "Source names"), so that the same scene
/// bakes to the same bytes from any folder, by any spelling of its path.
///
/// A file inside a root is named by the root's label and its path inside the root (after
/// symlinks are resolved, `/`-separated): `scene:terrain.raw` (the folder of the first ECO file,
/// or of a command's single input), `models/0:tree.txf` (the i-th `--models` folder, 0-based in
/// command-line order), `allow/1:tex/bark.png` (the i-th `--allow-path` folder). Where roots
/// nest, the first in that order names the file. A file outside every root (a `--sky` or
/// `--color-map` file elsewhere, a pipeline file) is named by its file name and the first 16 hex
/// digits of its contents' BLAKE3 hash: `outside:sky.hdr@1f0e2d3c4b5a6978`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SourceNames {
    /// (label, canonical folder); folders that do not exist are left out (their labels keep
    /// their numbers).
    roots: Vec<(String, PathBuf)>,
}

/// Label of a name outside every root.
pub const OUTSIDE: &str = "outside";

impl SourceNames {
    /// The roots of a scene whose first ECO file (or single input) is `first`.
    pub fn new(first: &Path, model_dirs: &[PathBuf], allow_paths: &[PathBuf]) -> SourceNames {
        let dir = first.parent().unwrap_or(Path::new(""));
        let labelled = std::iter::once(("scene".to_string(), dir))
            .chain(
                model_dirs
                    .iter()
                    .enumerate()
                    .map(|(i, d)| (format!("models/{i}"), d.as_path())),
            )
            .chain(
                allow_paths
                    .iter()
                    .enumerate()
                    .map(|(i, d)| (format!("allow/{i}"), d.as_path())),
            );
        let roots = labelled
            .filter_map(|(label, d)| {
                let d = if d.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    d
                };
                std::fs::canonicalize(d).ok().map(|c| (label, c))
            })
            .collect();
        SourceNames { roots }
    }

    /// The name of the scene's first ECO file (or a command's single input), `scene:<file
    /// name>`: by its place, so it needs no file system (a plan's action that reads only packs
    /// names its scene as the bake does).
    pub fn first_name(first: &Path) -> String {
        format!("scene:{}", file_name(first))
    }

    /// The roots of a single input file (its folder).
    pub fn around(file: &Path) -> SourceNames {
        SourceNames::new(file, &[], &[])
    }

    /// `label:path` of a file inside a root, `None` outside every root.
    pub fn inside(&self, path: &Path) -> Option<String> {
        let resolved = resolve(path);
        self.roots.iter().find_map(|(label, dir)| {
            let rel = resolved.strip_prefix(dir).ok()?;
            let parts: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            Some(format!("{label}:{}", parts.join("/")))
        })
    }

    /// The name of `path` whose contents hash to `hash` (used only outside every root).
    pub fn name_hashed(&self, path: &Path, hash: &[u8; 32]) -> String {
        self.inside(path)
            .unwrap_or_else(|| outside_name(path, hash))
    }

    /// [`SourceNames::name_hashed`] with the hash in hex (as [`crate::pack::hex`] writes it).
    pub fn name_hex(&self, path: &Path, hex: &str) -> String {
        self.inside(path).unwrap_or_else(|| {
            format!(
                "{OUTSIDE}:{}@{}",
                file_name(path),
                hex.get(..16).unwrap_or(hex)
            )
        })
    }

    /// The name of `path`; a file outside every root is read for its hash (an unreadable one
    /// is named by its file name alone).
    pub fn name(&self, path: &Path) -> String {
        if let Some(n) = self.inside(path) {
            return n;
        }
        match std::fs::read(path) {
            Ok(bytes) => outside_name(path, blake3::hash(&bytes).as_bytes()),
            Err(_) => format!("{OUTSIDE}:{}", file_name(path)),
        }
    }

    /// The real (canonical) path a root-relative name stands for; `None` for an `outside:`
    /// name, an unknown label or a path that would leave its root.
    pub fn path_of(&self, name: &str) -> Option<PathBuf> {
        let (label, rel) = name.split_once(':')?;
        let (_, dir) = self.roots.iter().find(|(l, _)| l == label)?;
        let mut out = dir.clone();
        for part in rel.split('/').filter(|p| !p.is_empty()) {
            if part == "." || part == ".." {
                return None;
            }
            out.push(part);
        }
        Some(out)
    }

    /// Each root's label and its place relative to the scene's folder (lexically, between
    /// canonical folders): what decides whether a reference from one root reaches another, and
    /// the same wherever the whole tree lies. Part of the ingest units' cache keys.
    pub fn layout(&self) -> Vec<(String, String)> {
        let Some((_, base)) = self.roots.first() else {
            return Vec::new();
        };
        self.roots
            .iter()
            .map(|(label, dir)| (label.clone(), relative_between(dir, base)))
            .collect()
    }
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn outside_name(path: &Path, hash: &[u8; 32]) -> String {
    let hex: String = hash[..8].iter().map(|b| format!("{b:02x}")).collect();
    format!("{OUTSIDE}:{}@{hex}", file_name(path))
}

/// `path` relative to `base` (both canonical), `/`-separated, `.` for the same folder.
fn relative_between(path: &Path, base: &Path) -> String {
    let p: Vec<Component> = path.components().collect();
    let b: Vec<Component> = base.components().collect();
    let common = p.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut parts: Vec<String> = vec!["..".into(); b.len() - common];
    parts.extend(
        p[common..]
            .iter()
            .map(|c| c.as_os_str().to_string_lossy().into_owned()),
    );
    if parts.is_empty() {
        ".".into()
    } else {
        parts.join("/")
    }
}

/// 3DS and GLB references are reported by byte offset, text files by line.
fn is_binary(path: &Path) -> bool {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    ext.eq_ignore_ascii_case("3ds") || ext.eq_ignore_ascii_case("glb")
}

/// Where `needle` first occurs in a file: `line N` (text) or `byte N` (binary).
pub fn place_of(bytes: &[u8], needle: &str, binary: bool) -> Option<String> {
    let n = needle.as_bytes();
    if n.is_empty() {
        return None;
    }
    let at = bytes.windows(n.len()).position(|w| w == n)?;
    Some(if binary {
        format!("byte {at}")
    } else {
        let line = bytes[..at].iter().filter(|&&c| c == b'\n').count() + 1;
        format!("line {line}")
    })
}

/// Canonical form of a path that may not exist: components are followed one by one, each
/// existing prefix canonicalized (symlinks resolved, so `..` after it is the real parent);
/// from the first missing component on, `.` is dropped and `..` applied lexically.
pub fn resolve(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let mut out = PathBuf::new();
    let mut exists = true;
    for c in abs.components() {
        match c {
            Component::Prefix(_) | Component::RootDir => out.push(c),
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            Component::Normal(n) => {
                out.push(n);
                if exists {
                    match std::fs::canonicalize(&out) {
                        Ok(p) => out = p,
                        Err(_) => exists = false,
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_absolute_paths_and_symlinks_are_outside() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene");
        let outside = dir.path().join("outside");
        std::fs::create_dir_all(scene.join("sub")).unwrap();
        std::fs::create_dir_all(&outside).unwrap();
        std::fs::write(outside.join("secret.txf"), b"x").unwrap();
        std::fs::write(scene.join("sub/ok.txf"), b"x").unwrap();
        let roots = Roots::new([scene.as_path()]);
        assert!(roots.resolve(&scene.join("sub/ok.txf")).0);
        assert!(roots.resolve(&scene.join("sub/../sub/ok.txf")).0);
        assert!(roots.resolve(&scene.join("missing/../x.png")).0);
        let (inside, resolved) = roots.resolve(&scene.join("../outside/secret.txf"));
        assert!(!inside);
        assert_eq!(
            resolved,
            std::fs::canonicalize(outside.join("secret.txf")).unwrap()
        );
        assert!(!roots.resolve(&scene.join("nothere/../../outside/x.png")).0);
        assert!(!roots.resolve(Path::new("/etc/passwd")).0);
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(outside.join("secret.txf"), scene.join("link.txf")).unwrap();
            assert!(!roots.resolve(&scene.join("link.txf")).0);
            let more = Roots::new([scene.as_path(), outside.as_path()]);
            assert!(more.resolve(&scene.join("link.txf")).0);
        }
    }

    #[test]
    fn source_names_are_relative_to_the_roots_wherever_the_scene_lies() {
        let dir = tempfile::tempdir().unwrap();
        for tree in ["a", "b/deeper"] {
            let top = dir.path().join(tree);
            std::fs::create_dir_all(top.join("scene/sub")).unwrap();
            std::fs::create_dir_all(top.join("lib")).unwrap();
            std::fs::write(top.join("scene/sub/t.png"), b"t").unwrap();
            std::fs::write(top.join("lib/tree.txf"), b"x").unwrap();
        }
        let names = |top: &Path| {
            SourceNames::new(
                &top.join("scene/scene.eco"),
                &[top.join("lib"), top.join("missing")],
                &[top.join("scene/sub")],
            )
        };
        let (a, b) = (
            names(&dir.path().join("a")),
            names(&dir.path().join("b/deeper")),
        );
        for (n, top) in [
            (&a, dir.path().join("a")),
            (&b, dir.path().join("b/deeper")),
        ] {
            assert_eq!(
                n.name(&top.join("scene/sub/../sub/t.png")),
                "scene:sub/t.png"
            );
            assert_eq!(n.name(&top.join("lib/tree.txf")), "models/0:tree.txf");
            assert_eq!(n.name(&top.join("scene/scene.eco")), "scene:scene.eco");
            assert_eq!(
                n.path_of("models/0:tree.txf").unwrap(),
                std::fs::canonicalize(top.join("lib/tree.txf")).unwrap()
            );
            assert_eq!(n.path_of("models/1:x"), None);
            assert_eq!(n.path_of("scene:../x"), None);
        }
        assert_eq!(a.layout(), b.layout());
        assert_eq!(
            a.layout()[1],
            ("models/0".to_string(), "../lib".to_string())
        );
        assert_eq!(a.layout()[2], ("allow/0".to_string(), "sub".to_string()));
        // Outside every root: the file name and the contents' hash, the same in both trees.
        std::fs::write(dir.path().join("sky.hdr"), b"sky").unwrap();
        let outside = a.name(&dir.path().join("sky.hdr"));
        assert!(outside.starts_with("outside:sky.hdr@"), "{outside}");
        assert_eq!(outside.len(), "outside:sky.hdr@".len() + 16);
        assert_eq!(outside, b.name(&dir.path().join("sky.hdr")));
        assert_eq!(a.path_of(&outside), None);
    }

    #[test]
    fn places_are_lines_or_bytes() {
        assert_eq!(
            place_of(b"a\nb\nleaf.png\n", "leaf.png", false).as_deref(),
            Some("line 3")
        );
        assert_eq!(
            place_of(b"\0\0leaf", "leaf", true).as_deref(),
            Some("byte 2")
        );
        assert_eq!(place_of(b"abc", "zzz", false), None);
    }
}
