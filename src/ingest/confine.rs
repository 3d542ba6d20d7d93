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
