//! Fuzz target: the TXF reader (text with binary blocks) must never panic, and what it accepts must be
//! a valid mesh.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(mesh) = bake::ingest::txf::parse(data) {
        assert_eq!(mesh.validate(), Ok(()));
    }
});
