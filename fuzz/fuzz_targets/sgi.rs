//! Fuzz target: SGI images (and, through the same entry point, png/jpg/tga/bmp) must decode or fail,
//! never panic, and a decoded image has width × height pixels.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(img) = bake::ingest::texture::decode(data) {
        assert_eq!(img.pixels.len(), img.width as usize * img.height as usize);
    }
});
