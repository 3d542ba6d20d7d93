//! Fuzz target: the ECO scene reader must never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = bake::ingest::eco::parse(data);
});
