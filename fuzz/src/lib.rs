//! What the fuzz targets share: an allocator that treats one allocation over 2 GiB as a bug
//! (issue 13 counts those with crashes and hangs), and the checksum repair that lets the pack
//! target reach the section decoders behind the BLAKE3 check.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;

/// The largest single allocation a reader may make on any input.
pub const MAX_ALLOC: usize = 2 << 30;

struct Guard;

fn check(size: usize) {
    if size > MAX_ALLOC {
        // No formatting that allocates: write a fixed message, then abort so libFuzzer saves
        // the input as a crash.
        let _ = std::io::stderr().write_all(b"bake-fuzz: allocation over 2 GiB\n");
        std::process::abort();
    }
}

// SAFETY: every call is forwarded unchanged to the system allocator after the size check.
unsafe impl GlobalAlloc for Guard {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        check(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Guard = Guard;

/// Links this crate (and so its allocator) into a target.
pub fn init() {}

/// Rewrites every in-bounds section-table entry's BLAKE3 to match its payload, so mutations
/// of a payload reach the section decoders instead of stopping at the checksum.
pub fn with_valid_checksums(bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let u32_at = |b: &[u8], at: usize| b.get(at..at.checked_add(4)?).map(|s| u32::from_le_bytes(s.try_into().unwrap()));
    let u64_at = |b: &[u8], at: usize| b.get(at..at.checked_add(8)?).map(|s| u64::from_le_bytes(s.try_into().unwrap()));
    let (Some(count), Some(table)) = (u32_at(&b, 16), u64_at(&b, 24)) else {
        return b;
    };
    for k in 0..count.min(4096) as u64 {
        // Checked: a mutated table offset may put an entry anywhere (regression test
        // tests/fuzz_smoke.rs `crash_c61e4abc_table_offset_near_the_end_of_the_address_space`).
        let Some(e) = table.checked_add(k * 168).and_then(|e| usize::try_from(e).ok()) else {
            break;
        };
        let (Some(off), Some(size)) = (
            e.checked_add(112).and_then(|a| u64_at(&b, a)),
            e.checked_add(120).and_then(|a| u64_at(&b, a)),
        ) else {
            break;
        };
        let end = off.saturating_add(size);
        if end > b.len() as u64 || e.checked_add(168).is_none_or(|x| x > b.len()) {
            continue;
        }
        let hash = blake3::hash(&b[off as usize..end as usize]);
        b[e + 136..e + 168].copy_from_slice(hash.as_bytes());
    }
    b
}
