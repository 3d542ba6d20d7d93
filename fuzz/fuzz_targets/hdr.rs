//! Fuzz target: Radiance RGBE (.hdr) skies must decode or fail, never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(img) = bake::ingest::skyimage::parse_hdr(data) {
        assert_eq!(img.pixels.len(), img.width as usize * img.height as usize);
    }
});
