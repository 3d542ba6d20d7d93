//! Fuzz target: the 3DS chunk reader must never panic, and what it accepts must be a valid mesh.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(mesh) = bake::ingest::max3ds::parse(data) {
        assert_eq!(mesh.validate(), Ok(()));
    }
});
