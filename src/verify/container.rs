//! The container rules of docs/FORMAT.md: header, section table, checksums, payload layout, and
//! each payload's sub-header and array directory. Works on raw bytes; trusts no field before it
//! has been checked against the file.

use super::Sink;
use crate::pack::section::{ARRAY_ALIGN, ARRAY_NAME_LEN, ArrayFormat, DIR_ENTRY, SUB_HEADER};
use crate::pack::{
    ENTRY_SIZE, HEADER_SIZE, KIND_LEN, MAGIC, NAME_LEN, READ_VERSIONS, SECTION_ALIGN,
};

/// One section-table entry as read, with what the container checks concluded.
#[derive(Debug, Clone)]
pub struct Entry {
    /// Its index in the table.
    pub index: usize,
    /// Absolute offset of the table entry.
    pub at: u64,
    /// The section's kind.
    pub kind: String,
    /// The section's name.
    pub name: String,
    /// Byte offset of its payload.
    pub offset: u64,
    /// Bytes of its payload.
    pub size: u64,
    /// Inside the file, aligned and with a matching checksum: its payload can be read.
    pub intact: bool,
}

/// The table, once the header could be trusted enough to find it.
#[derive(Debug, Clone)]
pub struct Table {
    /// The container's format version.
    pub version: u32,
    /// The table's entries.
    pub entries: Vec<Entry>,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap_or_default())
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap_or_default())
}

/// The header's version field, if the file is long enough to have one.
pub fn header_version(b: &[u8]) -> Option<u32> {
    (b.len() >= 12 && b[0..8] == MAGIC).then(|| u32_at(b, 8))
}

/// Offset of the first non-zero byte in `b[from..to]`, if any.
fn first_nonzero(b: &[u8], from: usize, to: usize) -> Option<usize> {
    b.get(from..to)?
        .iter()
        .position(|&c| c != 0)
        .map(|k| from + k)
}

/// Checks the header and the table; `None` when the table cannot be located or trusted.
pub fn check_container(b: &[u8], sink: &mut Sink) -> Option<Table> {
    let (version, table) = check_header(b, sink)?;
    let count = u32_at(b, 16) as usize;
    let end = count
        .checked_mul(ENTRY_SIZE)
        .and_then(|n| n.checked_add(table));
    if end.is_none_or(|e| e > b.len()) {
        sink.push(
            "table.bounds",
            None,
            None,
            16,
            format!(
                "section table of {count} entries at byte {table} runs past the end of the file ({} bytes)",
                b.len()
            ),
        );
        return None;
    }
    let entries: Vec<Entry> = (0..count).map(|k| read_entry(b, table, k, sink)).collect();
    check_names_unique(&entries, sink);
    check_layout(b, (table, table + count * ENTRY_SIZE), &entries, sink);
    Some(Table { version, entries })
}

/// The 64-byte header; returns the version and the table offset when the table can be located
/// (version 1: right after the header; version 2: last, at a multiple of 16).
fn check_header(b: &[u8], sink: &mut Sink) -> Option<(u32, usize)> {
    if b.len() < HEADER_SIZE {
        sink.push(
            "header.truncated",
            None,
            None,
            b.len() as u64,
            format!(
                "file is {} bytes, shorter than the {HEADER_SIZE}-byte pack header",
                b.len()
            ),
        );
        return None;
    }
    if b[0..8] != MAGIC {
        let at = (0..8).find(|&k| b[k] != MAGIC[k]).unwrap_or(0);
        sink.push(
            "header.magic",
            None,
            None,
            at as u64,
            "not a bake pack (magic \"BAKEPAK\\0\" expected)",
        );
        return None;
    }
    let version = u32_at(b, 8);
    if !READ_VERSIONS.contains(&version) {
        let (first, last) = (READ_VERSIONS[0], READ_VERSIONS[READ_VERSIONS.len() - 1]);
        sink.push(
            "header.version",
            None,
            None,
            8,
            format!("pack format version {version}, this bake reads versions {first} to {last}"),
        );
        return None;
    }
    let fields: [(&'static str, usize, u64, u64); 3] = [
        ("header.flags", 12, u32_at(b, 12) as u64, 0),
        (
            "header.header_size",
            20,
            u32_at(b, 20) as u64,
            HEADER_SIZE as u64,
        ),
        ("header.file_size", 40, u64_at(b, 40), b.len() as u64),
    ];
    for (check, at, got, want) in fields {
        if got != want {
            sink.push(
                check,
                None,
                None,
                at as u64,
                format!("field is {got}, expected {want}"),
            );
        }
    }
    for (from, to) in [(36, 40), (48, 64)] {
        if let Some(at) = first_nonzero(b, from, to) {
            sink.push(
                "header.reserved",
                None,
                None,
                at as u64,
                format!("reserved header bytes {from}..{to} are not zero"),
            );
        }
    }
    let entry_size = u32_at(b, 32) as usize;
    if entry_size != ENTRY_SIZE {
        sink.push(
            "header.entry_size",
            None,
            None,
            32,
            format!("section entry size {entry_size}, expected {ENTRY_SIZE}"),
        );
        return None;
    }
    let table = u64_at(b, 24);
    let ok = match version {
        1 => table == HEADER_SIZE as u64,
        _ => table >= HEADER_SIZE as u64 && table.is_multiple_of(16),
    };
    if !ok || table > b.len() as u64 {
        sink.push(
            "header.table_offset",
            None,
            None,
            24,
            format!(
                "section table at byte {table}: version {version} puts it {}",
                if version == 1 {
                    "right after the header (64)"
                } else {
                    "last, at a multiple of 16 inside the file"
                }
            ),
        );
        return None;
    }
    Some((version, table as usize))
}

/// A NUL-padded UTF-8 label: non-empty, valid, zero after the first NUL.
fn check_label(
    bytes: &[u8],
    at: usize,
    what: &str,
    section: Option<&str>,
    sink: &mut Sink,
) -> String {
    let end = bytes.iter().position(|&c| c == 0).unwrap_or(bytes.len());
    let text = match std::str::from_utf8(&bytes[..end]) {
        Ok(s) => s.to_string(),
        Err(e) => {
            sink.push(
                "label.utf8",
                section,
                None,
                (at + e.valid_up_to()) as u64,
                format!("{what} is not UTF-8"),
            );
            String::from_utf8_lossy(&bytes[..end]).into_owned()
        }
    };
    if text.is_empty() {
        sink.push(
            "label.empty",
            section,
            None,
            at as u64,
            format!("{what} is empty"),
        );
    }
    if let Some(k) = bytes[end..].iter().position(|&c| c != 0) {
        sink.push(
            "label.padding",
            section,
            None,
            (at + end + k) as u64,
            format!("{what} {text:?} is followed by non-zero padding"),
        );
    }
    text
}

fn read_entry(b: &[u8], table: usize, k: usize, sink: &mut Sink) -> Entry {
    let e = table + k * ENTRY_SIZE;
    let kind = check_label(&b[e..e + KIND_LEN], e, "section kind", None, sink);
    let name = check_label(
        &b[e + 16..e + 16 + NAME_LEN],
        e + 16,
        "section name",
        None,
        sink,
    );
    let s = Some(name.as_str());
    let offset = u64_at(b, e + 112);
    let size = u64_at(b, e + 120);
    let alignment = u32_at(b, e + 128);
    let mut intact = true;
    if offset
        .checked_add(size)
        .is_none_or(|end| end > b.len() as u64)
    {
        sink.push(
            "table.bounds",
            s,
            None,
            (e + 112) as u64,
            format!(
                "payload (offset {offset}, size {size}) runs past the end of the file ({} bytes)",
                b.len()
            ),
        );
        intact = false;
    }
    if alignment != SECTION_ALIGN as u32 {
        sink.push(
            "table.alignment",
            s,
            None,
            (e + 128) as u64,
            format!("alignment {alignment}, expected {SECTION_ALIGN}"),
        );
    }
    if !offset.is_multiple_of(SECTION_ALIGN as u64) {
        sink.push(
            "table.offset_alignment",
            s,
            None,
            (e + 112) as u64,
            format!("payload offset {offset} is not a multiple of {SECTION_ALIGN}"),
        );
        intact = false;
    }
    if let Some(at) = first_nonzero(b, e + 132, e + 136) {
        sink.push(
            "table.reserved",
            s,
            None,
            at as u64,
            "reserved entry bytes 132..136 are not zero",
        );
    }
    if intact {
        let payload = &b[offset as usize..(offset + size) as usize];
        if blake3::hash(payload).as_bytes()[..] != b[e + 136..e + 168] {
            sink.push(
                "table.checksum",
                s,
                None,
                offset,
                "BLAKE3 of the payload does not match the table: the section is corrupt",
            );
            intact = false;
        }
    }
    Entry {
        index: k,
        at: e as u64,
        kind,
        name,
        offset,
        size,
        intact,
    }
}

fn check_names_unique(entries: &[Entry], sink: &mut Sink) {
    let mut seen = std::collections::HashSet::new();
    for e in entries {
        if !seen.insert(e.name.as_str()) {
            sink.push(
                "table.duplicate_name",
                Some(&e.name),
                None,
                e.at + 16,
                "a second section has this name",
            );
        }
    }
}

/// Header, table and payloads do not overlap; every gap between them is zero (and nothing but
/// zeros follows the last); in version 2 the table comes after every payload.
fn check_layout(b: &[u8], table: (usize, usize), entries: &[Entry], sink: &mut Sink) {
    let mut spans: Vec<(u64, u64, Option<&Entry>)> = entries
        .iter()
        .filter(|e| {
            e.offset
                .checked_add(e.size)
                .is_some_and(|end| end <= b.len() as u64)
        })
        .map(|e| (e.offset, e.offset + e.size, Some(e)))
        .collect();
    let last_payload = spans.iter().map(|s| s.1).max().unwrap_or(0);
    if table.0 > HEADER_SIZE && last_payload > table.0 as u64 {
        sink.push(
            "layout.table_last",
            None,
            None,
            24,
            format!(
                "a payload ends at byte {last_payload}, after the table (byte {})",
                table.0
            ),
        );
    }
    spans.push((0, HEADER_SIZE as u64, None));
    spans.push((table.0 as u64, table.1 as u64, None));
    spans.sort_by_key(|s| (s.0, s.2.map_or(0, |e| e.index + 1)));
    let mut cursor = 0u64;
    for (start, end, e) in spans {
        let name = e.map(|e| e.name.as_str());
        if start < cursor && start != end {
            sink.push(
                "layout.overlap",
                name,
                None,
                start,
                format!("bytes {start}..{end} overlap the header, the table or another payload (ends at {cursor})"),
            );
        } else if let Some(at) = first_nonzero(b, cursor as usize, start as usize) {
            sink.push(
                "layout.gap",
                name,
                None,
                at as u64,
                "padding before this part of the file is not zero",
            );
        }
        cursor = cursor.max(end);
    }
    if let Some(at) = first_nonzero(b, cursor as usize, b.len()) {
        sink.push(
            "layout.trailing",
            None,
            None,
            at as u64,
            "bytes after the last payload or the table are not zero",
        );
    }
}

/// Checks one intact payload's sub-header and array directory; true when its arrays and
/// metadata can be read.
pub fn check_payload(b: &[u8], e: &Entry, sink: &mut Sink) -> bool {
    let p = &b[e.offset as usize..(e.offset + e.size) as usize];
    let base = e.offset;
    let s = Some(e.name.as_str());
    if p.len() < SUB_HEADER {
        sink.push(
            "payload.truncated",
            s,
            None,
            base,
            "payload shorter than its 16-byte sub-header",
        );
        return false;
    }
    let meta_off = u32_at(p, 0) as u64;
    let meta_len = u32_at(p, 4) as u64;
    let count = u32_at(p, 8) as u64;
    let before = sink.violations.len();
    if let Some(at) = first_nonzero(p, 12, 16) {
        sink.push(
            "payload.reserved",
            s,
            None,
            base + at as u64,
            "reserved sub-header bytes 12..16 are not zero",
        );
    }
    let dir_end = SUB_HEADER as u64 + count.saturating_mul(DIR_ENTRY as u64);
    if dir_end > p.len() as u64 {
        sink.push(
            "payload.directory",
            s,
            None,
            base + 8,
            format!(
                "array directory of {count} entries runs past the payload ({} bytes)",
                p.len()
            ),
        );
        return false;
    }
    if meta_off < dir_end || meta_off + meta_len > p.len() as u64 {
        sink.push(
            "payload.metadata",
            s,
            None,
            base,
            format!(
                "metadata (offset {meta_off}, {meta_len} bytes) overlaps the directory (ends at {dir_end}) or runs past the payload ({} bytes)",
                p.len()
            ),
        );
        return false;
    }
    let mut regions = vec![(0, dir_end, None), (meta_off, meta_off + meta_len, None)];
    let mut names = std::collections::HashSet::new();
    for k in 0..count as usize {
        let d = SUB_HEADER + k * DIR_ENTRY;
        let Some(r) = check_dir_entry(p, d, base, s, sink) else {
            continue;
        };
        if !names.insert(r.2.clone().unwrap_or_default()) {
            sink.push(
                "array.duplicate_name",
                s,
                r.2.as_deref(),
                base + d as u64,
                "a second array has this name",
            );
        }
        regions.push(r);
    }
    check_regions(p, base, s, regions, sink);
    sink.violations.len() == before
}

type Region = (u64, u64, Option<String>);

/// One directory entry: name, known format, aligned and inside the payload.
fn check_dir_entry(
    p: &[u8],
    d: usize,
    base: u64,
    s: Option<&str>,
    sink: &mut Sink,
) -> Option<Region> {
    let name = check_label(
        &p[d..d + ARRAY_NAME_LEN],
        base as usize + d,
        "array name",
        s,
        sink,
    );
    let a = Some(name.as_str());
    let code = u32_at(p, d + 24);
    let Some(format) = ArrayFormat::from_u32(code) else {
        sink.push(
            "array.format",
            s,
            a,
            base + d as u64 + 24,
            format!("unknown scalar format code {code}"),
        );
        return None;
    };
    let components = u32_at(p, d + 28) as u64;
    let count = u64_at(p, d + 32);
    let offset = u64_at(p, d + 40);
    if components == 0 {
        sink.push(
            "array.components",
            s,
            a,
            base + d as u64 + 28,
            "zero components per element",
        );
    }
    let len = count
        .checked_mul(components)
        .and_then(|n| n.checked_mul(format.size() as u64));
    let end = len.and_then(|l| l.checked_add(offset));
    if end.is_none_or(|e| e > p.len() as u64) {
        sink.push(
            "array.bounds",
            s,
            a,
            base + d as u64 + 32,
            format!(
                "{count} elements at payload offset {offset} run past the payload ({} bytes)",
                p.len()
            ),
        );
        return None;
    }
    if !offset.is_multiple_of(ARRAY_ALIGN as u64) {
        sink.push(
            "array.alignment",
            s,
            a,
            base + d as u64 + 40,
            format!("payload offset {offset} is not a multiple of {ARRAY_ALIGN}"),
        );
        return None;
    }
    Some((offset, end.unwrap_or(offset), Some(name)))
}

/// Directory, metadata and arrays do not overlap; the bytes between and after them are zero.
fn check_regions(p: &[u8], base: u64, s: Option<&str>, mut regions: Vec<Region>, sink: &mut Sink) {
    regions.sort_by_key(|r| (r.0, r.1));
    let mut cursor = 0u64;
    for (start, end, array) in regions {
        if start == end {
            continue;
        }
        if start < cursor {
            sink.push(
                "payload.overlap",
                s,
                array.as_deref(),
                base + start,
                format!("bytes {start}..{end} overlap the previous part of the payload (ends at {cursor})"),
            );
        } else if let Some(at) = first_nonzero(p, cursor as usize, start as usize) {
            sink.push(
                "payload.gap",
                s,
                array.as_deref(),
                base + at as u64,
                "padding before this part of the payload is not zero",
            );
        }
        cursor = cursor.max(end);
    }
    if let Some(at) = first_nonzero(p, cursor as usize, p.len()) {
        sink.push(
            "payload.trailing",
            s,
            None,
            base + at as u64,
            "bytes after the last array are not zero",
        );
    }
}
