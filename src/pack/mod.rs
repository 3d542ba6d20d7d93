//! The pack: one file per bake, sections of POD arrays plus postcard metadata, read in place
//! through a memory map. The byte layout is documented in docs/FORMAT.md; keep them in step.
//!
//! ```text
//! header (64 B) | section table (count × 168 B) | pad | section 0 (256-aligned) | pad | section 1 ...
//! section: sub-header (16 B) | array directory (n × 48 B) | metadata (postcard) | pad | arrays (16-aligned)
//! ```
//! Writes are atomic: the whole file goes to a temporary file in the target folder, which is
//! renamed over the target only when complete, so a failed bake never leaves a broken pack and
//! never destroys the previous one.

use crate::error::{Error, ParseError, Result};
use memmap2::Mmap;
use serde::{Serialize, de::DeserializeOwned};
use std::io::Write;
use std::path::{Path, PathBuf};

pub mod kinds;
pub mod section;
pub use section::{ArrayFormat, SectionBuilder};

/// File magic, 8 bytes.
pub const MAGIC: [u8; 8] = *b"BAKEPAK\0";
/// Format version; bumped on any layout change.
pub const VERSION: u32 = 1;
/// Size of the file header.
pub const HEADER_SIZE: usize = 64;
/// Size of one section-table entry.
pub const ENTRY_SIZE: usize = 168;
/// Alignment of every section payload in the file (fits GPU upload and mmap slicing).
pub const SECTION_ALIGN: usize = 256;
/// Bytes reserved for a section kind.
pub const KIND_LEN: usize = 16;
/// Bytes reserved for a section name.
pub const NAME_LEN: usize = 96;

/// One encoded section, ready to be written.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    pub kind: String,
    pub name: String,
    /// The encoded payload (sub-header, directory, metadata, arrays).
    pub payload: Vec<u8>,
}

/// Collects sections and writes a pack atomically.
#[derive(Debug, Default, Clone)]
pub struct PackWriter {
    sections: Vec<Section>,
}

impl PackWriter {
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts from every section of an existing pack (stages that read a pack and add to it).
    pub fn from_pack(pack: &Pack) -> Self {
        let sections = pack
            .sections()
            .iter()
            .map(|s| Section {
                kind: s.kind.clone(),
                name: s.name.clone(),
                payload: pack.payload(s).to_vec(),
            })
            .collect();
        Self { sections }
    }

    /// Adds a section, replacing any section of the same name (keeping its position).
    pub fn insert(&mut self, section: Section) {
        match self.sections.iter_mut().find(|s| s.name == section.name) {
            Some(s) => *s = section,
            None => self.sections.push(section),
        }
    }

    /// Removes every section of the given kind.
    pub fn remove_kind(&mut self, kind: &str) {
        self.sections.retain(|s| s.kind != kind);
    }

    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// Encodes the whole file in memory.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        for s in &self.sections {
            check_label(&s.kind, KIND_LEN, "kind")?;
            check_label(&s.name, NAME_LEN, "name")?;
        }
        let table_end = HEADER_SIZE + self.sections.len() * ENTRY_SIZE;
        let mut offsets = Vec::with_capacity(self.sections.len());
        let mut cursor = table_end;
        for s in &self.sections {
            cursor = align_up(cursor, SECTION_ALIGN);
            offsets.push(cursor);
            cursor += s.payload.len();
        }
        let file_size = cursor;
        let mut out = vec![0u8; file_size];
        out[0..8].copy_from_slice(&MAGIC);
        put_u32(&mut out, 8, VERSION);
        put_u32(&mut out, 12, 0);
        put_u32(&mut out, 16, self.sections.len() as u32);
        put_u32(&mut out, 20, HEADER_SIZE as u32);
        put_u64(&mut out, 24, HEADER_SIZE as u64);
        put_u32(&mut out, 32, ENTRY_SIZE as u32);
        put_u64(&mut out, 40, file_size as u64);
        for (k, (s, &off)) in self.sections.iter().zip(&offsets).enumerate() {
            let e = HEADER_SIZE + k * ENTRY_SIZE;
            out[e..e + s.kind.len()].copy_from_slice(s.kind.as_bytes());
            out[e + 16..e + 16 + s.name.len()].copy_from_slice(s.name.as_bytes());
            put_u64(&mut out, e + 112, off as u64);
            put_u64(&mut out, e + 120, s.payload.len() as u64);
            put_u32(&mut out, e + 128, SECTION_ALIGN as u32);
            out[e + 136..e + 168].copy_from_slice(blake3::hash(&s.payload).as_bytes());
            out[off..off + s.payload.len()].copy_from_slice(&s.payload);
        }
        Ok(out)
    }

    /// Writes the pack to `path` atomically (temporary file in the same folder, then rename).
    pub fn write(&self, path: &Path) -> Result<()> {
        let bytes = self.to_bytes()?;
        write_atomic(path, &bytes)
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut tmp = tempfile::Builder::new()
        .prefix(".bake-tmp-")
        .tempfile_in(&dir)
        .map_err(|e| Error::io(&dir, e))?;
    tmp.write_all(bytes).map_err(|e| Error::io(tmp.path(), e))?;
    tmp.as_file()
        .sync_all()
        .map_err(|e| Error::io(tmp.path(), e))?;
    set_output_permissions(tmp.as_file(), path);
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Temporary files are created 0600; give the output the permissions of the file it replaces,
/// or the usual 0644 for a new file.
#[cfg(unix)]
fn set_output_permissions(file: &std::fs::File, target: &Path) {
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(target)
        .map(|m| m.permissions().mode())
        .unwrap_or(0o644);
    let _ = file.set_permissions(std::fs::Permissions::from_mode(mode));
}
#[cfg(not(unix))]
fn set_output_permissions(_file: &std::fs::File, _target: &Path) {}

fn check_label(s: &str, max: usize, what: &str) -> Result<()> {
    if s.len() > max || s.as_bytes().contains(&0) {
        return Err(Error::runtime(format!(
            "section {what} {s:?} is longer than {max} bytes or contains NUL"
        )));
    }
    Ok(())
}

pub(crate) fn align_up(x: usize, a: usize) -> usize {
    x.div_ceil(a) * a
}
pub(crate) fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
pub(crate) fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
pub(crate) fn get_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
pub(crate) fn get_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// One entry of the section table.
#[derive(Debug, Clone, PartialEq)]
pub struct SectionEntry {
    pub kind: String,
    pub name: String,
    pub offset: u64,
    pub size: u64,
    pub alignment: u32,
    pub checksum: [u8; 32],
}

enum Storage {
    Mapped(Mmap),
    /// Owned bytes, kept in a u128 buffer so payloads stay 16-byte aligned.
    Owned(Vec<u128>, usize),
}

/// A pack opened for reading; payloads are borrowed from the memory map.
pub struct Pack {
    path: PathBuf,
    storage: Storage,
    version: u32,
    entries: Vec<SectionEntry>,
}

impl std::fmt::Debug for Pack {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pack")
            .field("path", &self.path)
            .field("sections", &self.entries)
            .finish()
    }
}

impl Pack {
    /// Opens and validates a pack file (header and table; checksums are checked on demand).
    pub fn open(path: &Path) -> Result<Pack> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        // SAFETY: the map is read-only; bake never modifies a pack in place (writes go through
        // a temporary file and a rename, which leaves existing maps on the old inode).
        let map = unsafe { Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
        let (version, entries) = parse_table(&map).map_err(|e| Error::invalid(path, e))?;
        Ok(Pack {
            path: path.to_path_buf(),
            storage: Storage::Mapped(map),
            version,
            entries,
        })
    }

    /// Parses a pack held in memory (tests, fuzzing).
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<Pack> {
        let mut buf = vec![0u128; bytes.len().div_ceil(16)];
        bytemuck::cast_slice_mut::<u128, u8>(&mut buf)[..bytes.len()].copy_from_slice(bytes);
        let (version, entries) = parse_table(bytes).map_err(|e| Error::invalid(name, e))?;
        Ok(Pack {
            path: PathBuf::from(name),
            storage: Storage::Owned(buf, bytes.len()),
            version,
            entries,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
    pub fn version(&self) -> u32 {
        self.version
    }
    pub fn sections(&self) -> &[SectionEntry] {
        &self.entries
    }

    fn bytes(&self) -> &[u8] {
        match &self.storage {
            Storage::Mapped(m) => m,
            Storage::Owned(v, n) => &bytemuck::cast_slice(v)[..*n],
        }
    }

    /// The raw payload of a section.
    pub fn payload(&self, e: &SectionEntry) -> &[u8] {
        &self.bytes()[e.offset as usize..(e.offset + e.size) as usize]
    }

    /// Whether the payload's BLAKE3 matches the table.
    pub fn checksum_ok(&self, e: &SectionEntry) -> bool {
        blake3::hash(self.payload(e)).as_bytes() == &e.checksum
    }

    /// The first section with this name.
    pub fn find(&self, name: &str) -> Option<&SectionEntry> {
        self.entries.iter().find(|e| e.name == name)
    }

    /// All sections of a kind, in file order.
    pub fn of_kind<'a>(&'a self, kind: &'a str) -> impl Iterator<Item = &'a SectionEntry> + 'a {
        self.entries.iter().filter(move |e| e.kind == kind)
    }

    /// A decoded view of a section (verifies its checksum and directory).
    pub fn view(&self, e: &SectionEntry) -> Result<section::SectionView<'_>> {
        if !self.checksum_ok(e) {
            return Err(Error::invalid_at(
                &self.path,
                format!("section {:?} at byte {}", e.name, e.offset),
                "checksum mismatch: the pack is corrupt",
            ));
        }
        section::SectionView::parse(self.payload(e), e.offset as usize)
            .map_err(|err| Error::invalid(&self.path, err))
    }

    /// View of the section with this name; an error naming the pack if it is missing.
    pub fn view_named(&self, name: &str) -> Result<section::SectionView<'_>> {
        let e = self.find(name).ok_or_else(|| {
            Error::invalid_at(
                &self.path,
                "section table",
                format!("no section named {name:?}"),
            )
        })?;
        self.view(e)
    }
}

fn parse_table(b: &[u8]) -> Result<(u32, Vec<SectionEntry>), ParseError> {
    if b.len() < HEADER_SIZE {
        return Err(ParseError::at_byte(
            0,
            format!(
                "file is {} bytes, shorter than the {HEADER_SIZE}-byte pack header",
                b.len()
            ),
        ));
    }
    if b[0..8] != MAGIC {
        return Err(ParseError::at_byte(
            0,
            "not a bake pack (magic \"BAKEPAK\\0\" expected)",
        ));
    }
    let version = get_u32(b, 8);
    if version != VERSION {
        return Err(ParseError::at_byte(
            8,
            format!("pack format version {version}, this bake reads version {VERSION}"),
        ));
    }
    let count = get_u32(b, 16) as usize;
    let table = get_u64(b, 24) as usize;
    let entry_size = get_u32(b, 32) as usize;
    if entry_size != ENTRY_SIZE {
        return Err(ParseError::at_byte(
            32,
            format!("section entry size {entry_size}, expected {ENTRY_SIZE}"),
        ));
    }
    let table_end = count
        .checked_mul(ENTRY_SIZE)
        .and_then(|n| n.checked_add(table));
    if table_end.is_none_or(|end| end > b.len()) {
        return Err(ParseError::at_byte(
            16,
            format!(
                "section table of {count} entries at byte {table} runs past the end of the file ({} bytes)",
                b.len()
            ),
        ));
    }
    let mut entries = Vec::with_capacity(count);
    for k in 0..count {
        let e = table + k * ENTRY_SIZE;
        let kind = label(&b[e..e + KIND_LEN], e)?;
        let name = label(&b[e + 16..e + 16 + NAME_LEN], e + 16)?;
        let offset = get_u64(b, e + 112);
        let size = get_u64(b, e + 120);
        let alignment = get_u32(b, e + 128);
        if offset
            .checked_add(size)
            .is_none_or(|end| end > b.len() as u64)
        {
            return Err(ParseError::at_byte(
                e + 112,
                format!(
                    "section {name:?} (offset {offset}, size {size}) runs past the end of the file ({} bytes)",
                    b.len()
                ),
            ));
        }
        if alignment == 0
            || !alignment.is_power_of_two()
            || !offset.is_multiple_of(alignment as u64)
            || alignment < 16
        {
            return Err(ParseError::at_byte(
                e + 128,
                format!(
                    "section {name:?} offset {offset} is not aligned to a power of two of at least 16 (alignment {alignment})"
                ),
            ));
        }
        let checksum = b[e + 136..e + 168].try_into().unwrap();
        entries.push(SectionEntry {
            kind,
            name,
            offset,
            size,
            alignment,
            checksum,
        });
    }
    Ok((version, entries))
}

fn label(bytes: &[u8], at: usize) -> Result<String, ParseError> {
    let end = bytes.iter().position(|&c| c == 0).unwrap_or(bytes.len());
    String::from_utf8(bytes[..end].to_vec())
        .map_err(|_| ParseError::at_byte(at, "section label is not UTF-8"))
}

/// Serializes metadata with postcard.
pub fn encode_meta<T: Serialize>(meta: &T) -> Vec<u8> {
    postcard::to_stdvec(meta).expect("postcard serialization of plain structs cannot fail")
}

/// Deserializes postcard metadata.
pub fn decode_meta<T: DeserializeOwned>(bytes: &[u8], at: usize) -> Result<T, ParseError> {
    postcard::from_bytes(bytes)
        .map_err(|e| ParseError::at_byte(at, format!("section metadata does not decode: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> PackWriter {
        let mut w = PackWriter::new();
        let mut s = SectionBuilder::new("mesh", "mesh:a");
        s.meta(&("hello".to_string(), 3u32));
        s.array(
            "positions",
            ArrayFormat::F32,
            3,
            &[[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]],
        );
        s.array("indices", ArrayFormat::U32, 3, &[[0u32, 1, 1]]);
        w.insert(s.finish());
        let mut t = SectionBuilder::new("sky", "sky");
        t.array("texels", ArrayFormat::U8, 1, &[7u8; 5]);
        w.insert(t.finish());
        w
    }

    #[test]
    fn round_trip_in_memory_and_on_disk() {
        let bytes = sample().to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.bake");
        sample().write(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        for pack in [
            Pack::from_bytes(&bytes, "mem").unwrap(),
            Pack::open(&path).unwrap(),
        ] {
            assert_eq!(pack.sections().len(), 2);
            let e = pack.find("mesh:a").unwrap();
            assert_eq!(e.offset % 256, 0);
            assert!(pack.checksum_ok(e));
            let v = pack.view(e).unwrap();
            let meta: (String, u32) = v.meta().unwrap();
            assert_eq!(meta, ("hello".to_string(), 3));
            let p: &[[f32; 3]] = v.array("positions").unwrap();
            assert_eq!(p, &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
            assert!(v.array::<[f32; 2]>("positions").is_err());
            assert!(
                v.array::<u8>("texels")
                    .unwrap_err()
                    .to_string()
                    .contains("no array")
            );
            let s = pack.view_named("sky").unwrap();
            assert_eq!(s.array::<u8>("texels").unwrap(), &[7u8; 5]);
        }
    }

    #[test]
    fn corrupt_payload_fails_checksum_and_truncation_is_rejected() {
        let mut bytes = sample().to_bytes().unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        let pack = Pack::from_bytes(&bytes, "mem").unwrap();
        let e = pack.find("sky").unwrap().clone();
        assert!(!pack.checksum_ok(&e));
        assert!(pack.view(&e).unwrap_err().to_string().contains("checksum"));
        for cut in [0, 10, 63, 64 + 100, bytes.len() - 1] {
            assert!(Pack::from_bytes(&bytes[..cut], "mem").is_err(), "cut {cut}");
        }
    }

    #[test]
    fn huge_counts_do_not_allocate() {
        let mut bytes = sample().to_bytes().unwrap();
        put_u32(&mut bytes, 16, u32::MAX);
        let err = Pack::from_bytes(&bytes, "mem").unwrap_err().to_string();
        assert!(err.contains("runs past the end"), "{err}");
    }

    #[test]
    fn failed_write_keeps_previous_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.bake");
        sample().write(&path).unwrap();
        let before = std::fs::read(&path).unwrap();
        let mut bad = PackWriter::new();
        bad.insert(SectionBuilder::new("k", &"n".repeat(200)).finish());
        assert!(bad.write(&path).is_err());
        assert_eq!(std::fs::read(&path).unwrap(), before);
        let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(leftovers.len(), 1);
    }
}
