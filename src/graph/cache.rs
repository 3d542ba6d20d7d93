//! The content-addressed stage cache: one file per stage unit, named by the unit's key.
//!
//! A key is the BLAKE3 hash of the bake version, the stage's name and version constant, the
//! unit's name, the canonical (JSON) form of the options the unit reads and the content hashes
//! of exactly the inputs it reads ([`KeyBuilder`]). An entry is a small pack (docs/FORMAT.md)
//! holding the unit's output sections plus one `entry` section with its report, warnings and
//! the files it read; it is written to a temporary file and renamed, so two bakes sharing a
//! cache never see half an entry, and every payload's checksum is checked when it is read (a
//! corrupt entry is a miss plus a warning, and is removed).

use crate::error::{Error, Result};
use crate::pack::{ArrayFormat, Pack, Section, SectionBuilder, StreamWriter};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Layout version of the cache folder (bumped when entries change shape).
pub const CACHE_LAYOUT: &str = "v1";
/// Kind and name of the section that describes an entry.
const ENTRY_KIND: &str = "entry";
const ENTRY_NAME: &str = "entry:meta";

pub use crate::stage::{Key, KeyBuilder};

/// A warning of a stage, as a record (id, severity, place, message; `crate::diag`).
pub use crate::diag::Warning;

pub use crate::stage::FileDep;

/// What an entry stores besides its sections.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EntryMeta {
    /// The stage that made the entry.
    pub stage: String,
    /// The unit (a model's name, `terrain`, `scene`, a shard).
    pub unit: String,
    /// The stage's report for the unit.
    pub report: serde_json::Value,
    /// The unit's warnings.
    pub warnings: Vec<Warning>,
    /// Files read beyond those in the key (textures found while reading a model).
    pub files: Vec<FileDep>,
    /// Names of the sections, in order.
    pub sections: Vec<String>,
}

/// A cache hit: the sections (mapped from the entry file) and the entry's record.
pub struct Entry {
    /// The unit's sections.
    pub sections: Vec<Section>,
    /// The entry's record.
    pub meta: EntryMeta,
}

/// What a lookup found.
pub enum Lookup {
    /// Found and intact.
    Hit(Entry),
    /// Not in the cache.
    Miss,
    /// An entry exists but is damaged (it has been removed); the message says how.
    Corrupt(String),
}

/// Entry count and size of a cache folder.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CacheStats {
    /// The cache folder.
    pub dir: PathBuf,
    /// Entries.
    pub entries: u64,
    /// Bytes of the entries.
    pub bytes: u64,
    /// Temporary files left by killed bakes.
    pub stale_temporaries: u64,
}

/// A cache folder.
#[derive(Debug, Clone)]
pub struct Cache {
    dir: PathBuf,
}

/// The default cache folder: `$BAKE_CACHE`, else `$XDG_CACHE_HOME/bake`, else `~/.cache/bake`,
/// else `.bake-cache` beside the output.
pub fn default_dir(output: &Path) -> PathBuf {
    if let Some(d) = std::env::var_os("BAKE_CACHE").filter(|d| !d.is_empty()) {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("bake");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(h).join(".cache").join("bake");
    }
    output
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default()
        .join(".bake-cache")
}

impl Cache {
    /// The cache in folder `dir` (created when first stored to).
    pub fn new(dir: impl Into<PathBuf>) -> Cache {
        Cache { dir: dir.into() }
    }

    /// The cache's folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn root(&self) -> PathBuf {
        self.dir.join(CACHE_LAYOUT)
    }

    /// Where the entry of `key` lives.
    pub fn entry_path(&self, key: &Key) -> PathBuf {
        let h = key.hex();
        self.root().join(&h[..2]).join(format!("{h}.bake"))
    }

    /// Looks `key` up; every payload's checksum is verified before a hit is returned.
    pub fn get(&self, key: &Key) -> Lookup {
        let path = self.entry_path(key);
        if !path.is_file() {
            return Lookup::Miss;
        }
        match read_entry(&path) {
            Ok(e) => {
                touch(&path);
                Lookup::Hit(e)
            }
            Err(why) => {
                let _ = std::fs::remove_file(&path);
                Lookup::Corrupt(format!(
                    "cache entry {} is damaged ({why}); recomputed",
                    path.display()
                ))
            }
        }
    }

    /// Stores the sections and record of a unit (atomically: temporary file, then rename).
    pub fn put(&self, key: &Key, sections: &[Section], meta: &EntryMeta) -> Result<()> {
        let path = self.entry_path(key);
        let mut w = StreamWriter::create(&path)?;
        for s in sections {
            w.push(s)?;
        }
        let json = serde_json::to_vec(meta)
            .map_err(|e| Error::runtime(format!("cache entry record: {e}")))?;
        let mut b = SectionBuilder::new(ENTRY_KIND, ENTRY_NAME);
        b.array("json", ArrayFormat::U8, 1, &json);
        w.push(&b.finish())?;
        w.finish()
    }

    /// Entries, bytes and stale temporary files.
    pub fn stats(&self) -> CacheStats {
        let mut s = CacheStats {
            dir: self.dir.clone(),
            ..Default::default()
        };
        for (_, len, _, tmp) in self.files() {
            if tmp {
                s.stale_temporaries += 1;
            } else {
                s.entries += 1;
                s.bytes += len;
            }
        }
        s
    }

    /// Removes stale temporary files (those no live write holds locked) and then the least recently used entries until the cache holds at most `max_bytes`.
    pub fn gc(&self, max_bytes: u64) -> CacheStats {
        // Temporary files whose lock is free were left by killed bakes (pack::StreamWriter).
        if let Ok(dirs) = std::fs::read_dir(self.root()) {
            for d in dirs.filter_map(|d| d.ok()) {
                crate::pack::remove_stale_temporaries(&d.path());
            }
        }
        let mut files = self.files();
        files.retain(|f| !f.3);
        // Oldest first; ties by path so that the order is the same on every run.
        files.sort_by(|a, b| a.2.cmp(&b.2).then_with(|| a.0.cmp(&b.0)));
        let mut total: u64 = files.iter().map(|f| f.1).sum();
        for (p, len, _, _) in &files {
            if total <= max_bytes {
                break;
            }
            if std::fs::remove_file(p).is_ok() {
                total -= len;
            }
        }
        self.stats()
    }

    /// (path, size, modified, is temporary) of every file under the cache's layout folder.
    fn files(&self) -> Vec<(PathBuf, u64, std::time::SystemTime, bool)> {
        let mut out = Vec::new();
        let Ok(dirs) = std::fs::read_dir(self.root()) else {
            return out;
        };
        for d in dirs.filter_map(|d| d.ok()) {
            let Ok(files) = std::fs::read_dir(d.path()) else {
                continue;
            };
            for f in files.filter_map(|f| f.ok()) {
                let Ok(m) = f.metadata() else { continue };
                if !m.is_file() {
                    continue;
                }
                let name = f.file_name().to_string_lossy().into_owned();
                let tmp = name.starts_with(crate::pack::TMP_PREFIX);
                let t = m.modified().unwrap_or(std::time::UNIX_EPOCH);
                out.push((f.path(), m.len(), t, tmp));
            }
        }
        out
    }
}

/// Marks an entry as used (its modification time orders `gc`).
fn touch(path: &Path) {
    if let Ok(f) = std::fs::File::options().append(true).open(path) {
        let _ = f.set_modified(std::time::SystemTime::now());
    }
}

fn read_entry(path: &Path) -> std::result::Result<Entry, String> {
    let pack = Pack::open(path).map_err(|e| e.to_string())?;
    let mut sections = pack.checked_sections().map_err(|e| e.to_string())?;
    let last = sections
        .pop()
        .filter(|s| s.kind == ENTRY_KIND && s.name == ENTRY_NAME)
        .ok_or("no entry record")?;
    let v =
        crate::pack::section::SectionView::parse(&last.payload, 0).map_err(|e| e.to_string())?;
    let json: &[u8] = v.array("json").map_err(|e| e.to_string())?;
    let meta: EntryMeta = serde_json::from_slice(json).map_err(|e| format!("entry record: {e}"))?;
    let names: Vec<&str> = sections.iter().map(|s| s.name.as_str()).collect();
    if names != meta.sections.iter().map(String::as_str).collect::<Vec<_>>() {
        return Err("sections differ from the entry record".into());
    }
    Ok(Entry { sections, meta })
}

pub use crate::pack::hash_file;

#[cfg(test)]
mod tests {
    use super::*;

    fn section(name: &str, fill: u8) -> Section {
        let mut b = SectionBuilder::new("test", name);
        b.array("bytes", ArrayFormat::U8, 1, &[fill; 1000]);
        b.finish()
    }

    fn meta(sections: &[Section]) -> EntryMeta {
        EntryMeta {
            stage: "test".into(),
            unit: "u".into(),
            report: serde_json::json!({"n": 1}),
            warnings: vec![],
            files: vec![],
            sections: sections.iter().map(|s| s.name.clone()).collect(),
        }
    }

    #[test]
    fn keys_depend_on_every_part() {
        let base = || {
            let mut k = KeyBuilder::new("1.0", "prt", 1, "tree.txf");
            k.options(&serde_json::json!({"samples": 64}));
            k.input("mesh:tree.txf", &[1; 32]);
            k
        };
        let k0 = base().finish();
        assert_eq!(k0, base().finish());
        let mut variants = vec![
            KeyBuilder::new("1.1", "prt", 1, "tree.txf"),
            KeyBuilder::new("1.0", "prt", 2, "tree.txf"),
            KeyBuilder::new("1.0", "prt", 1, "bush.txf"),
        ];
        for v in &mut variants {
            v.options(&serde_json::json!({"samples": 64}));
            v.input("mesh:tree.txf", &[1; 32]);
        }
        let mut o = KeyBuilder::new("1.0", "prt", 1, "tree.txf");
        o.options(&serde_json::json!({"samples": 65}));
        o.input("mesh:tree.txf", &[1; 32]);
        variants.push(o);
        let mut i = KeyBuilder::new("1.0", "prt", 1, "tree.txf");
        i.options(&serde_json::json!({"samples": 64}));
        i.input("mesh:tree.txf", &[2; 32]);
        variants.push(i);
        for v in variants {
            assert_ne!(v.finish(), k0);
        }
    }

    #[test]
    fn entries_round_trip_and_damage_is_a_miss() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path());
        let key = Key([7; 32]);
        assert!(matches!(cache.get(&key), Lookup::Miss));
        let secs = vec![section("a", 1), section("b", 2)];
        cache.put(&key, &secs, &meta(&secs)).unwrap();
        match cache.get(&key) {
            Lookup::Hit(e) => {
                assert_eq!(e.sections, secs);
                assert_eq!(e.meta, meta(&secs));
            }
            _ => panic!("expected a hit"),
        }
        assert_eq!(cache.stats().entries, 1);
        // Flip one byte inside the first payload: the checksum catches it.
        let path = cache.entry_path(&key);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[256 + 200] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        match cache.get(&key) {
            Lookup::Corrupt(m) => assert!(m.contains("checksum"), "{m}"),
            _ => panic!("expected a corrupt entry"),
        }
        assert!(!path.exists(), "a damaged entry is removed");
        assert!(matches!(cache.get(&key), Lookup::Miss));
        // A truncated entry is damaged too.
        cache.put(&key, &secs, &meta(&secs)).unwrap();
        let len = std::fs::metadata(&path).unwrap().len();
        std::fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_len(len / 2)
            .unwrap();
        assert!(matches!(cache.get(&key), Lookup::Corrupt(_)));
    }

    #[test]
    fn gc_keeps_the_newest_entries_within_the_size() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path());
        for k in 0..4u8 {
            let secs = vec![section("a", k)];
            cache.put(&Key([k; 32]), &secs, &meta(&secs)).unwrap();
            let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(1_000_000 + k as u64);
            std::fs::File::options()
                .append(true)
                .open(cache.entry_path(&Key([k; 32])))
                .unwrap()
                .set_modified(t)
                .unwrap();
        }
        let one = cache.stats().bytes / 4;
        let after = cache.gc(2 * one);
        assert_eq!(after.entries, 2);
        assert!(!cache.entry_path(&Key([0; 32])).exists());
        assert!(!cache.entry_path(&Key([1; 32])).exists());
        assert!(cache.entry_path(&Key([3; 32])).exists());
    }
}
