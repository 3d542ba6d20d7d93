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
#![warn(missing_docs)]

use crate::error::{Error, ParseError, Result};
use memmap2::Mmap;
use serde::{Serialize, de::DeserializeOwned};
use std::io::Write;
use std::path::{Path, PathBuf};

pub mod section;
pub use section::{ArrayFormat, SectionBuilder};

/// File magic, 8 bytes.
pub const MAGIC: [u8; 8] = *b"BAKEPAK\0";
/// Format version written; bumped on any layout change (2: the table follows the payloads).
pub const VERSION: u32 = 2;
/// Versions this bake reads (1 had the table right after the header; the reader follows the
/// header's table offset either way).
pub const READ_VERSIONS: [u32; 2] = [1, 2];
/// Alignment of the section table.
pub const TABLE_ALIGN: usize = 16;
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
    /// The section's kind (docs/FORMAT.md, "Section kinds").
    pub kind: String,
    /// The section's name, unique in a pack.
    pub name: String,
    /// The encoded payload (sub-header, directory, metadata, arrays).
    pub payload: Payload,
}

/// A section payload: 16-byte aligned bytes in memory or mapped from a file, shared (a clone
/// is a reference count), with its BLAKE3 hash computed once when it is made.
#[derive(Clone)]
pub struct Payload {
    data: std::sync::Arc<PayloadData>,
    hash: [u8; 32],
}

enum PayloadData {
    /// Owned bytes in a u128 buffer so that arrays stay 16-byte aligned.
    Owned(Vec<u128>, usize),
    /// `len` bytes at `start` of a shared map (a pack file, a cache entry, a streamed output).
    Mapped(std::sync::Arc<Mmap>, usize, usize),
}

impl Payload {
    /// Copies `bytes` into aligned memory and hashes them.
    pub fn from_slice(bytes: &[u8]) -> Payload {
        let mut buf = vec![0u128; bytes.len().div_ceil(16)];
        bytemuck::cast_slice_mut::<u128, u8>(&mut buf)[..bytes.len()].copy_from_slice(bytes);
        Payload::from_aligned(buf, bytes.len())
    }

    /// Takes an aligned buffer holding `len` bytes.
    pub fn from_aligned(buf: Vec<u128>, len: usize) -> Payload {
        let hash = hash_bytes(&bytemuck::cast_slice::<u128, u8>(&buf)[..len]);
        Payload {
            data: std::sync::Arc::new(PayloadData::Owned(buf, len)),
            hash,
        }
    }

    /// `len` bytes at `start` of `map` whose BLAKE3 is already known to be `hash`.
    pub(crate) fn mapped(
        map: std::sync::Arc<Mmap>,
        start: usize,
        len: usize,
        hash: [u8; 32],
    ) -> Payload {
        Payload {
            data: std::sync::Arc::new(PayloadData::Mapped(map, start, len)),
            hash,
        }
    }

    /// Whether the bytes are mapped from a file (not held in memory).
    pub fn is_mapped(&self) -> bool {
        matches!(*self.data, PayloadData::Mapped(..))
    }

    /// The BLAKE3 hash of the bytes.
    pub fn hash(&self) -> &[u8; 32] {
        &self.hash
    }
}

impl std::ops::Deref for Payload {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match &*self.data {
            PayloadData::Owned(v, n) => &bytemuck::cast_slice(v)[..*n],
            PayloadData::Mapped(m, start, len) => &m[*start..*start + *len],
        }
    }
}

impl From<Vec<u8>> for Payload {
    fn from(v: Vec<u8>) -> Payload {
        Payload::from_slice(&v)
    }
}

impl PartialEq for Payload {
    fn eq(&self, other: &Payload) -> bool {
        self.hash == other.hash && **self == **other
    }
}

impl std::fmt::Debug for Payload {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Payload({} bytes, blake3 {})",
            self.len(),
            hex(&self.hash[..8])
        )
    }
}

/// BLAKE3 of `bytes`, on all threads for large inputs (the same hash either way).
pub fn hash_bytes(bytes: &[u8]) -> [u8; 32] {
    if bytes.len() > (1 << 20) {
        *blake3::Hasher::new()
            .update_rayon(bytes)
            .finalize()
            .as_bytes()
    } else {
        *blake3::hash(bytes).as_bytes()
    }
}

/// BLAKE3 of a file's bytes (memory-mapped; hashed on all threads for large files).
pub fn hash_file(path: &Path) -> Result<[u8; 32]> {
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    if len == 0 {
        return Ok(hash_bytes(&[]));
    }
    // SAFETY: read-only map of an input file; a file changed under the bake is the user's
    // race, and the hash then simply describes neither version.
    let map = unsafe { memmap2::Mmap::map(&f) }.map_err(|e| Error::io(path, e))?;
    Ok(hash_bytes(&map))
}

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Collects sections and writes a pack atomically.
#[derive(Debug, Default, Clone)]
pub struct PackWriter {
    sections: Vec<Section>,
}

impl PackWriter {
    /// An empty pack.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts from every section of an existing pack (stages that read a pack and add to it);
    /// the payloads stay shared with `pack`'s memory map.
    pub fn from_pack(pack: &Pack) -> Self {
        let sections = pack
            .sections()
            .iter()
            .map(|s| Section {
                kind: s.kind.clone(),
                name: s.name.clone(),
                payload: pack.shared_payload(s),
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

    /// The sections, in pack order.
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// A pack view of the sections so far, sharing their payloads (no copy, no encoding).
    pub fn view(&self, name: &str) -> Pack {
        Pack::from_sections(&self.sections, name)
    }

    /// Encodes the whole file in memory (the same bytes [`StreamWriter`] writes).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let layout = Layout::of(
            self.sections
                .iter()
                .map(|s| (s.kind.as_str(), s.name.as_str(), s.payload.len())),
        )?;
        let mut out = vec![0u8; layout.file_size];
        for (s, &off) in self.sections.iter().zip(&layout.offsets) {
            out[off..off + s.payload.len()].copy_from_slice(&s.payload);
        }
        let entries: Vec<TableEntry> = self
            .sections
            .iter()
            .zip(&layout.offsets)
            .map(|(s, &off)| TableEntry::of(s, off as u64))
            .collect();
        let (head, table) = header_and_table(&entries, layout.table, layout.file_size);
        out[..HEADER_SIZE].copy_from_slice(&head);
        out[layout.table..].copy_from_slice(&table);
        Ok(out)
    }

    /// Writes the pack to `path` atomically (temporary file in the same folder, then rename).
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut s = StreamWriter::create(path)?;
        for sec in &self.sections {
            s.push(sec)?;
        }
        s.finish()
    }
}

/// Where the payloads and the table of a file go (format version 2: payloads first, each
/// 256-aligned from byte 256, the table after the last payload, 16-aligned).
struct Layout {
    offsets: Vec<usize>,
    table: usize,
    file_size: usize,
}

impl Layout {
    fn of<'a>(sections: impl Iterator<Item = (&'a str, &'a str, usize)>) -> Result<Layout> {
        let mut offsets = Vec::new();
        let mut cursor = HEADER_SIZE;
        for (kind, name, len) in sections {
            check_label(kind, KIND_LEN, "kind")?;
            check_label(name, NAME_LEN, "name")?;
            cursor = align_up(cursor, SECTION_ALIGN);
            offsets.push(cursor);
            cursor += len;
        }
        let table = align_up(cursor, TABLE_ALIGN);
        let file_size = table + offsets.len() * ENTRY_SIZE;
        Ok(Layout {
            offsets,
            table,
            file_size,
        })
    }
}

/// One row of the section table, as written.
struct TableEntry {
    kind: String,
    name: String,
    offset: u64,
    size: u64,
    hash: [u8; 32],
}

impl TableEntry {
    fn of(s: &Section, offset: u64) -> TableEntry {
        TableEntry {
            kind: s.kind.clone(),
            name: s.name.clone(),
            offset,
            size: s.payload.len() as u64,
            hash: *s.payload.hash(),
        }
    }
}

/// The 64-byte header and the encoded table.
fn header_and_table(
    entries: &[TableEntry],
    table: usize,
    file_size: usize,
) -> ([u8; HEADER_SIZE], Vec<u8>) {
    let mut head = [0u8; HEADER_SIZE];
    head[0..8].copy_from_slice(&MAGIC);
    put_u32(&mut head, 8, VERSION);
    put_u32(&mut head, 12, 0);
    put_u32(&mut head, 16, entries.len() as u32);
    put_u32(&mut head, 20, HEADER_SIZE as u32);
    put_u64(&mut head, 24, table as u64);
    put_u32(&mut head, 32, ENTRY_SIZE as u32);
    put_u64(&mut head, 40, file_size as u64);
    let mut out = vec![0u8; entries.len() * ENTRY_SIZE];
    for (k, s) in entries.iter().enumerate() {
        let e = k * ENTRY_SIZE;
        out[e..e + s.kind.len()].copy_from_slice(s.kind.as_bytes());
        out[e + 16..e + 16 + s.name.len()].copy_from_slice(s.name.as_bytes());
        put_u64(&mut out, e + 112, s.offset);
        put_u64(&mut out, e + 120, s.size);
        put_u32(&mut out, e + 128, SECTION_ALIGN as u32);
        out[e + 136..e + 168].copy_from_slice(&s.hash);
    }
    (head, out)
}

/// Writes a pack section by section into a temporary file beside the target: each payload goes
/// to disk as soon as it is pushed (and can be read back through a memory map of that file, so
/// a bake holds no finished section in memory), the table last, then the rename. Dropping the
/// writer without [`StreamWriter::finish`] removes the temporary file; the previous target
/// survives either way.
pub struct StreamWriter {
    target: PathBuf,
    tmp: tempfile::NamedTempFile,
    cursor: u64,
    entries: Vec<TableEntry>,
}

impl StreamWriter {
    /// Opens the temporary file in `target`'s folder (created if missing).
    pub fn create(target: &Path) -> Result<StreamWriter> {
        let dir = parent_dir(target);
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        let tmp = new_temporary(&dir)?;
        remove_stale_temporaries(&dir);
        Ok(StreamWriter {
            target: target.to_path_buf(),
            tmp,
            cursor: HEADER_SIZE as u64,
            entries: Vec::new(),
        })
    }

    /// Appends one section's payload (a section of the same name pushed before is an error:
    /// the streamed file cannot replace it).
    pub fn push(&mut self, s: &Section) -> Result<()> {
        self.push_at(s).map(|_| ())
    }

    /// [`StreamWriter::push`], returning the payload's offset in the file.
    fn push_at(&mut self, s: &Section) -> Result<u64> {
        use std::io::{Seek, SeekFrom};
        check_label(&s.kind, KIND_LEN, "kind")?;
        check_label(&s.name, NAME_LEN, "name")?;
        if self.entries.iter().any(|e| e.name == s.name) {
            return Err(Error::runtime(format!(
                "section {:?} written twice to {}",
                s.name,
                self.target.display()
            )));
        }
        let off = align_up(self.cursor as usize, SECTION_ALIGN) as u64;
        let path = self.tmp.path().to_path_buf();
        let f = self.tmp.as_file_mut();
        f.seek(SeekFrom::Start(off))
            .map_err(|e| Error::io(&path, e))?;
        f.write_all(&s.payload).map_err(|e| Error::io(&path, e))?;
        self.cursor = off + s.payload.len() as u64;
        self.entries.push(TableEntry::of(s, off));
        Ok(off)
    }

    /// Appends `s` and returns it with its payload mapped from the written file instead of
    /// memory (the owned copy can then be dropped).
    pub fn push_mapped(&mut self, s: Section) -> Result<Section> {
        let off = self.push_at(&s)? as usize;
        map_back(self.tmp.as_file(), self.tmp.path(), off, s)
    }

    /// Names of the sections written so far.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.entries.iter().map(|e| e.name.as_str())
    }

    /// Bytes the finished file will have.
    pub fn file_size(&self) -> u64 {
        (align_up(self.cursor as usize, TABLE_ALIGN) + self.entries.len() * ENTRY_SIZE) as u64
    }

    /// Writes the table and the header, syncs and renames over the target.
    pub fn finish(mut self) -> Result<()> {
        use std::io::{Seek, SeekFrom};
        let table = align_up(self.cursor as usize, TABLE_ALIGN);
        let file_size = table + self.entries.len() * ENTRY_SIZE;
        let (head, tab) = header_and_table(&self.entries, table, file_size);
        let path = self.tmp.path().to_path_buf();
        let f = self.tmp.as_file_mut();
        let io = |e| Error::io(&path, e);
        f.seek(SeekFrom::Start(table as u64)).map_err(io)?;
        f.write_all(&tab).map_err(io)?;
        f.seek(SeekFrom::Start(0)).map_err(io)?;
        f.write_all(&head).map_err(io)?;
        f.set_len(file_size as u64).map_err(io)?;
        f.sync_all().map_err(io)?;
        set_output_permissions(self.tmp.as_file(), &self.target);
        self.tmp
            .persist(&self.target)
            .map_err(|e| Error::io(&self.target, e.error))?;
        Ok(())
    }
}

/// Name prefix of the temporary files a write goes through.
pub const TMP_PREFIX: &str = ".bake-tmp-";

/// Takes an exclusive advisory lock on `f` (held until the file is closed): blocking, or
/// returns whether it was free. Every temporary file of a write in progress is locked, so one
/// that can be locked was left by a killed bake.
#[cfg(unix)]
fn lock(f: &std::fs::File, block: bool) -> bool {
    use std::os::unix::io::AsRawFd;
    let op = if block {
        libc::LOCK_EX
    } else {
        libc::LOCK_EX | libc::LOCK_NB
    };
    // SAFETY: flock on a file descriptor this process holds open.
    unsafe { libc::flock(f.as_raw_fd(), op) == 0 }
}
#[cfg(not(unix))]
fn lock(_f: &std::fs::File, _block: bool) -> bool {
    false
}

/// A locked temporary file in `dir`. Between its creation and its lock the file is briefly
/// unlocked, so it is created under a shared lock of the folder, which
/// [`remove_stale_temporaries`] takes exclusively: a cleaner never sees a live temporary
/// before its lock (two bakes writing into one folder once removed each other's file there).
fn new_temporary(dir: &Path) -> Result<tempfile::NamedTempFile> {
    let _guard = lock_dir(dir, false);
    let tmp = tempfile::Builder::new()
        .prefix(TMP_PREFIX)
        .tempfile_in(dir)
        .map_err(|e| Error::io(dir, e))?;
    lock(tmp.as_file(), true);
    Ok(tmp)
}

/// A blocking advisory lock on a folder (shared or exclusive), held until the value is dropped;
/// `None` where the folder cannot be opened or locked (the file locks alone then guard).
#[cfg(unix)]
fn lock_dir(dir: &Path, exclusive: bool) -> Option<std::fs::File> {
    use std::os::unix::io::AsRawFd;
    let f = std::fs::File::open(dir).ok()?;
    let op = if exclusive {
        libc::LOCK_EX
    } else {
        libc::LOCK_SH
    };
    // SAFETY: flock on a file descriptor this process holds open.
    (unsafe { libc::flock(f.as_raw_fd(), op) } == 0).then_some(f)
}
#[cfg(not(unix))]
fn lock_dir(_dir: &Path, _exclusive: bool) -> Option<std::fs::File> {
    None
}

/// Removes the temporary files of killed bakes in `dir`: those whose lock is free. Returns how
/// many were removed.
pub fn remove_stale_temporaries(dir: &Path) -> usize {
    let _guard = lock_dir(dir, true);
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.filter_map(|e| e.ok()) {
        if !e.file_name().to_string_lossy().starts_with(TMP_PREFIX) {
            continue;
        }
        let path = e.path();
        if let Ok(f) = std::fs::File::open(&path)
            && lock(&f, false)
            && std::fs::remove_file(&path).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// `s` with its payload mapped from `file`, where it was written at `off`.
fn map_back(file: &std::fs::File, path: &Path, off: usize, s: Section) -> Result<Section> {
    let len = s.payload.len();
    if len == 0 {
        return Ok(s);
    }
    let page = page_size();
    let start = off / page * page;
    // SAFETY: the mapped range is never written again (sections are appended after it and
    // the table after the last one), and the file is only renamed, never truncated.
    let map = unsafe {
        memmap2::MmapOptions::new()
            .offset(start as u64)
            .len(off - start + len)
            .map(file)
    }
    .map_err(|e| Error::io(path, e))?;
    let payload = Payload::mapped(
        std::sync::Arc::new(map),
        off - start,
        len,
        *s.payload.hash(),
    );
    Ok(Section {
        kind: s.kind,
        name: s.name,
        payload,
    })
}

/// Sections parked on disk until they can go into a pack: an anonymous temporary file in a
/// folder (it has no name, so the system removes it when the process ends, killed or not),
/// each payload written once and mapped back, so that a bake does not hold sections in memory
/// that wait for others (the per-model units' sections wait for the light map). A parked
/// section's pages are read from the file when it is read, and leave the process when the
/// section is dropped.
pub struct Spool {
    file: std::fs::File,
    dir: PathBuf,
    cursor: u64,
}

impl Spool {
    /// An empty spool in folder `dir` (which exists).
    pub fn create(dir: &Path) -> Result<Spool> {
        let file = tempfile::tempfile_in(dir).map_err(|e| Error::io(dir, e))?;
        Ok(Spool {
            file,
            dir: dir.to_path_buf(),
            cursor: 0,
        })
    }

    /// The spool of the pack `target` will be: in its folder, on the same disk.
    pub fn beside(target: &Path) -> Result<Spool> {
        Spool::create(&parent_dir(target))
    }

    /// `s` written to the spool and mapped back (its bytes, name and hash unchanged); a section
    /// mapped from a file already is returned as it is.
    pub fn park(&mut self, s: Section) -> Result<Section> {
        use std::io::{Seek, SeekFrom};
        if s.payload.is_mapped() {
            return Ok(s);
        }
        let off = align_up(self.cursor as usize, SECTION_ALIGN) as u64;
        let io = |e| Error::io(&self.dir, e);
        self.file.seek(SeekFrom::Start(off)).map_err(io)?;
        self.file.write_all(&s.payload).map_err(io)?;
        self.cursor = off + s.payload.len() as u64;
        map_back(&self.file, &self.dir, off as usize, s)
    }
}

fn page_size() -> usize {
    // Every platform bake runs on maps at 4 KiB or a multiple of it; 64 KiB covers them all.
    65536
}

/// The folder `path` lies in (`.` for a bare file name).
pub(crate) fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = parent_dir(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let mut tmp = new_temporary(&dir)?;
    tmp.write_all(bytes).map_err(|e| Error::io(tmp.path(), e))?;
    tmp.as_file()
        .sync_all()
        .map_err(|e| Error::io(tmp.path(), e))?;
    set_output_permissions(tmp.as_file(), path);
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// As [`write_atomic`], the bytes written by `write` (through a buffer) instead of a slice: an
/// output larger than memory is streamed. Returns what `write` returns; on its error the
/// temporary file is removed and `path` is untouched.
pub(crate) fn write_atomic_with<T>(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<T>,
) -> Result<T> {
    let dir = parent_dir(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let tmp = new_temporary(&dir)?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, tmp);
    let value = write(&mut out)?;
    let tmp = out
        .into_inner()
        .map_err(|e| Error::io(path, e.into_error()))?;
    tmp.as_file()
        .sync_all()
        .map_err(|e| Error::io(tmp.path(), e))?;
    set_output_permissions(tmp.as_file(), path);
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(value)
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
    /// The section's kind.
    pub kind: String,
    /// The section's name.
    pub name: String,
    /// Byte offset of the payload in the file.
    pub offset: u64,
    /// Bytes of the payload.
    pub size: u64,
    /// Alignment of the payload in the file.
    pub alignment: u32,
    /// BLAKE3 of the payload.
    pub checksum: [u8; 32],
}

enum Storage {
    Mapped(std::sync::Arc<Mmap>),
    /// Owned bytes, kept in a u128 buffer so payloads stay 16-byte aligned.
    Owned(Vec<u128>, usize),
    /// Sections of a pack being built, not encoded as a file: entry `k` has offset `k` and its
    /// payload is `sections[k]` (checksums were computed when the payloads were made).
    Sections(Vec<Payload>),
}

/// A pack opened for reading; payloads are borrowed from the memory map.
pub struct Pack {
    path: PathBuf,
    storage: Storage,
    version: u32,
    entries: Vec<SectionEntry>,
    /// Per entry, whether its checksum was found to match, once computed: a section is hashed
    /// once however often it is viewed (a reader scanning every light map for its surface would
    /// otherwise hash a 537 MB terrain map once per model).
    verified: Vec<std::sync::OnceLock<bool>>,
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
            storage: Storage::Mapped(std::sync::Arc::new(map)),
            version,
            verified: unchecked(entries.len()),
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
            verified: unchecked(entries.len()),
            entries,
        })
    }

    /// A view of sections in memory (a pack being built): no encoding, payloads shared. Names
    /// should be unique (a [`PackWriter`] keeps them so); lookups find the first.
    pub fn from_sections(sections: &[Section], name: &str) -> Pack {
        let entries: Vec<SectionEntry> = sections
            .iter()
            .enumerate()
            .map(|(k, s)| SectionEntry {
                kind: s.kind.clone(),
                name: s.name.clone(),
                offset: k as u64,
                size: s.payload.len() as u64,
                alignment: SECTION_ALIGN as u32,
                checksum: *s.payload.hash(),
            })
            .collect();
        Pack {
            path: PathBuf::from(name),
            storage: Storage::Sections(sections.iter().map(|s| s.payload.clone()).collect()),
            version: VERSION,
            verified: unchecked(entries.len()),
            entries,
        }
    }

    /// The section as a [`Section`] sharing this pack's memory (map or buffers), its hash taken
    /// from the table (check it with [`Pack::checksum_ok`] first where the file is untrusted).
    pub fn shared_payload(&self, e: &SectionEntry) -> Payload {
        match &self.storage {
            Storage::Sections(v) => v[e.offset as usize].clone(),
            Storage::Mapped(m) => {
                Payload::mapped(m.clone(), e.offset as usize, e.size as usize, e.checksum)
            }
            Storage::Owned(..) => Payload::from_slice(self.payload(e)),
        }
    }

    /// Every section whose payload matches its table checksum, sharing this pack's memory;
    /// an error naming the first that does not.
    pub fn checked_sections(&self) -> Result<Vec<Section>> {
        self.entries
            .iter()
            .map(|e| {
                if !self.checksum_ok(e) {
                    return Err(Error::invalid_at(
                        &self.path,
                        format!("section {:?} at byte {}", e.name, e.offset),
                        "checksum mismatch: the pack is corrupt",
                    ));
                }
                Ok(Section {
                    kind: e.kind.clone(),
                    name: e.name.clone(),
                    payload: self.shared_payload(e),
                })
            })
            .collect()
    }

    /// The file the pack was read from (or the name it was given).
    pub fn path(&self) -> &Path {
        &self.path
    }
    /// The container's format version.
    pub fn version(&self) -> u32 {
        self.version
    }
    /// The section table, in pack order.
    pub fn sections(&self) -> &[SectionEntry] {
        &self.entries
    }

    fn bytes(&self) -> &[u8] {
        match &self.storage {
            Storage::Mapped(m) => m,
            Storage::Owned(v, n) => &bytemuck::cast_slice(v)[..*n],
            Storage::Sections(_) => &[],
        }
    }

    /// The raw payload of a section.
    pub fn payload(&self, e: &SectionEntry) -> &[u8] {
        match &self.storage {
            Storage::Sections(v) => &v[e.offset as usize],
            _ => &self.bytes()[e.offset as usize..(e.offset + e.size) as usize],
        }
    }

    /// Whether the payload's BLAKE3 matches the table (computed once per entry of this pack).
    pub fn checksum_ok(&self, e: &SectionEntry) -> bool {
        let compute = || match &self.storage {
            Storage::Sections(v) => v[e.offset as usize].hash() == &e.checksum,
            _ => hash_bytes(self.payload(e)) == e.checksum,
        };
        // The memo only for this pack's own entries (found by address, not by value).
        match self.entries.iter().position(|x| std::ptr::eq(x, e)) {
            Some(k) => *self.verified[k].get_or_init(compute),
            None => compute(),
        }
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
        let base = match self.storage {
            Storage::Sections(_) => 0,
            _ => e.offset as usize,
        };
        section::SectionView::parse(self.payload(e), base)
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

/// One empty verification memo per section.
fn unchecked(n: usize) -> Vec<std::sync::OnceLock<bool>> {
    (0..n).map(|_| std::sync::OnceLock::new()).collect()
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
    if !READ_VERSIONS.contains(&version) {
        return Err(ParseError::at_byte(
            8,
            format!(
                "pack format version {version}, this bake reads versions {} to {VERSION}",
                READ_VERSIONS[0]
            ),
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

/// Truncates a section name to what the table holds, keeping it unique with a hash suffix.
pub fn fit_name(name: String) -> String {
    if name.len() <= NAME_LEN {
        return name;
    }
    let hash = blake3::hash(name.as_bytes()).to_hex();
    let mut cut = NAME_LEN - 9;
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}~{}", &name[..cut], &hash[..8])
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
    fn a_checksum_is_remembered_per_entry_and_a_foreign_entry_is_hashed() {
        let bytes = sample().to_bytes().unwrap();
        let mut bad = bytes.clone();
        let pack = Pack::from_bytes(&bytes, "x.bake").unwrap();
        let e = &pack.sections()[0];
        assert!(pack.checksum_ok(e) && pack.checksum_ok(e));
        assert!(pack.verified[0].get() == Some(&true));
        // An entry that is not this pack's own (a copy with another checksum) is not memoised.
        let mut other = e.clone();
        other.checksum[0] ^= 1;
        assert!(!pack.checksum_ok(&other));
        // A corrupt payload in another pack is still found.
        let at = e.offset as usize + e.size as usize - 1;
        bad[at] ^= 0xff;
        let corrupt = Pack::from_bytes(&bad, "y.bake").unwrap();
        assert!(!corrupt.checksum_ok(&corrupt.sections()[0]));
        assert!(corrupt.view(&corrupt.sections()[0]).is_err());
    }

    #[test]
    fn an_array_filled_in_place_encodes_as_the_copied_array() {
        let data: Vec<[f32; 3]> = (0..37).map(|k| [k as f32, 0.5, -(k as f32)]).collect();
        let mut copied = SectionBuilder::new("mesh", "m");
        copied
            .meta(&7u32)
            .array("tail", ArrayFormat::U8, 1, &[1u8, 2, 3])
            .array("p", ArrayFormat::F32, 3, &data);
        let mut filled = SectionBuilder::new("mesh", "m");
        filled
            .meta(&7u32)
            .array("tail", ArrayFormat::U8, 1, &[1u8, 2, 3])
            .array_fill(
                "p",
                ArrayFormat::F32,
                3,
                data.len(),
                |out: &mut [[f32; 3]]| {
                    assert!(
                        out.iter().all(|v| *v == [0.0; 3]),
                        "the slice starts zeroed"
                    );
                    out.copy_from_slice(&data)
                },
            );
        let (a, b) = (copied.finish(), filled.finish());
        assert_eq!(&a.payload[..], &b.payload[..]);
    }

    #[test]
    fn deferred_arrays_filled_side_by_side_encode_as_the_copied_arrays() {
        let a: Vec<[f32; 4]> = (0..37).map(|k| [k as f32, 0.5, -(k as f32), 1.0]).collect();
        let b: Vec<u32> = (0..11).map(|k| k * 7 + 1).collect();
        let mut copied = SectionBuilder::new("mesh", "m");
        copied
            .meta(&7u32)
            .array("a", ArrayFormat::F32, 4, &a)
            .array("tail", ArrayFormat::U8, 1, &[1u8, 2, 3])
            .array("b", ArrayFormat::U32, 1, &b);
        let mut deferred = SectionBuilder::new("mesh", "m");
        deferred
            .meta(&7u32)
            .array_deferred::<[f32; 4]>("a", ArrayFormat::F32, 4, a.len())
            .array("tail", ArrayFormat::U8, 1, &[1u8, 2, 3])
            .array_deferred::<u32>("b", ArrayFormat::U32, 1, b.len());
        let d = deferred.finish_with(|slices| {
            assert_eq!(slices.len(), 2);
            let mut it = slices.into_iter();
            let (sa, sb) = (it.next().unwrap(), it.next().unwrap());
            assert_eq!((sa.len(), sb.len()), (37 * 16, 11 * 4));
            assert!(sa.iter().chain(sb.iter()).all(|&x| x == 0), "zeroed");
            // Both slices written in one pass, interleaved.
            let (sa, sb): (&mut [[f32; 4]], &mut [u32]) =
                (bytemuck::cast_slice_mut(sa), bytemuck::cast_slice_mut(sb));
            for k in 0..37 {
                sa[k] = a[k];
                if k < 11 {
                    sb[k] = b[k];
                }
            }
        });
        assert_eq!(&copied.finish().payload[..], &d.payload[..]);
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

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// The streamed file (payloads written one by one, read back through maps, table last)
        /// has exactly the bytes of the in-memory encoder, and reads back.
        #[test]
        fn streamed_packs_equal_the_in_memory_encoding(
            sizes in proptest::collection::vec(0usize..3000, 0..12),
            seed in 0u8..255,
        ) {
            let mut w = PackWriter::new();
            for (k, n) in sizes.iter().enumerate() {
                let mut b = SectionBuilder::new("test", &format!("s{k}"));
                let data: Vec<u8> = (0..*n).map(|i| (i as u8).wrapping_mul(seed).wrapping_add(k as u8)).collect();
                b.meta(&(k as u32, "meta".to_string()));
                b.array("data", ArrayFormat::U8, 1, &data);
                w.insert(b.finish());
            }
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("s.bake");
            let mut s = StreamWriter::create(&path).unwrap();
            let mut mapped = Vec::new();
            for sec in w.sections() {
                mapped.push(s.push_mapped(sec.clone()).unwrap());
            }
            let size = s.file_size();
            s.finish().unwrap();
            let bytes = std::fs::read(&path).unwrap();
            proptest::prop_assert_eq!(bytes.len() as u64, size);
            proptest::prop_assert!(bytes == w.to_bytes().unwrap());
            proptest::prop_assert_eq!(&mapped, &w.sections().to_vec());
            let pack = Pack::open(&path).unwrap();
            proptest::prop_assert_eq!(pack.checked_sections().unwrap(), w.sections().to_vec());
            // The in-memory view reads the same sections without encoding.
            let view = w.view("mem");
            for e in view.sections() {
                proptest::prop_assert_eq!(view.payload(e), pack.payload(pack.find(&e.name).unwrap()));
            }
        }
    }

    #[test]
    fn parked_sections_keep_their_bytes_and_leave_no_file_behind() {
        // Parked in a spool, then streamed into a pack: the same pack as the in-memory
        // encoding, every parked payload read from the spool's file, and the folder holds the
        // pack alone (the spool's file has no name).
        let w = sample();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.bake");
        let mut out = StreamWriter::create(&path).unwrap();
        let mut spool = Spool::beside(&path).unwrap();
        let parked: Vec<Section> = w
            .sections()
            .iter()
            .map(|s| spool.park(s.clone()).unwrap())
            .collect();
        for (p, s) in parked.iter().zip(w.sections()) {
            assert!(p.payload.is_mapped() && !s.payload.is_mapped());
            assert_eq!(
                (&p.kind, &p.name, &p.payload),
                (&s.kind, &s.name, &s.payload)
            );
            assert_eq!(p.payload.hash(), s.payload.hash());
            // A mapped section is not parked again.
            assert!(spool.park(p.clone()).unwrap().payload.is_mapped());
        }
        for p in parked {
            out.push_mapped(p).unwrap();
        }
        out.finish().unwrap();
        drop(spool);
        assert_eq!(std::fs::read(&path).unwrap(), w.to_bytes().unwrap());
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("p.bake")]);
    }

    #[test]
    fn version_1_packs_with_the_table_after_the_header_still_read() {
        // Rewrite a version-2 pack into the version-1 layout: table at 64, payloads after it.
        let w = sample();
        let v2 = w.to_bytes().unwrap();
        let p2 = Pack::from_bytes(&v2, "v2").unwrap();
        let n = p2.sections().len();
        let mut out = vec![0u8; 64 + n * ENTRY_SIZE];
        out[..64].copy_from_slice(&v2[..64]);
        put_u32(&mut out, 8, 1);
        put_u64(&mut out, 24, 64);
        let mut cursor = out.len();
        for (k, e) in p2.sections().iter().enumerate() {
            cursor = align_up(cursor, SECTION_ALIGN);
            out.resize(cursor, 0);
            let t = 64 + k * ENTRY_SIZE;
            let row = &v2[get_u64(&v2, 24) as usize + k * ENTRY_SIZE..][..ENTRY_SIZE];
            out[t..t + ENTRY_SIZE].copy_from_slice(row);
            put_u64(&mut out, t + 112, cursor as u64);
            out.extend_from_slice(p2.payload(e));
            cursor = out.len();
        }
        let len = out.len() as u64;
        put_u64(&mut out, 40, len);
        let p1 = Pack::from_bytes(&out, "v1").unwrap();
        assert_eq!(p1.version(), 1);
        assert_eq!(
            p1.checked_sections().unwrap(),
            p2.checked_sections().unwrap()
        );
        put_u32(&mut out, 8, 3);
        let e = Pack::from_bytes(&out, "v3").unwrap_err().to_string();
        assert!(
            e.contains("version 3") && e.contains("versions 1 to 2"),
            "{e}"
        );
    }

    #[test]
    fn cleaners_never_remove_a_live_writers_temporary_file() {
        // Writers creating temporaries in one folder while others clean it: a temporary is
        // unlocked for an instant after its creation; without the folder lock a cleaner took
        // it for a killed bake's and removed it, and the writer's rename failed (ENOENT).
        let dir = tempfile::tempdir().unwrap();
        let done = std::sync::atomic::AtomicBool::new(false);
        std::thread::scope(|scope| {
            for _ in 0..2 {
                scope.spawn(|| {
                    while !done.load(std::sync::atomic::Ordering::Relaxed) {
                        remove_stale_temporaries(dir.path());
                    }
                });
            }
            let writers: Vec<_> = (0..4)
                .map(|t| {
                    let path = dir.path().join(format!("w{t}.bin"));
                    scope.spawn(move || {
                        (0..300)
                            .filter(|i| write_atomic(&path, &[*i as u8; 64]).is_err())
                            .count()
                    })
                })
                .collect();
            let failed: usize = writers.into_iter().map(|w| w.join().unwrap()).sum();
            done.store(true, std::sync::atomic::Ordering::Relaxed);
            assert_eq!(failed, 0, "writes lost their temporary file to a cleaner");
        });
    }

    #[test]
    fn a_killed_writers_temporary_file_is_removed_by_the_next_write() {
        let dir = tempfile::tempdir().unwrap();
        // A temporary file nobody holds (as a killed bake leaves it) and one a live writer holds.
        std::fs::write(dir.path().join(".bake-tmp-killed"), b"half a pack").unwrap();
        let live = StreamWriter::create(&dir.path().join("a.bake")).unwrap();
        let names = || -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        assert_eq!(
            names().len(),
            1,
            "the stale file is gone, the live one stays: {:?}",
            names()
        );
        let mut other = StreamWriter::create(&dir.path().join("b.bake")).unwrap();
        assert_eq!(
            names().len(),
            2,
            "a live writer's file survives another writer"
        );
        other.push(&sample().sections()[0]).unwrap();
        other.finish().unwrap();
        live.finish().unwrap();
        assert_eq!(names(), vec!["a.bake".to_string(), "b.bake".to_string()]);
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
