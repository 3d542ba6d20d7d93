//! Fuzz target: the ECO scene reader must never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(eco) = bake::ingest::eco::parse(data) {
        assert!(eco.terrain.width >= 2 && eco.terrain.height >= 2);
    }
});
