//! Fuzz target: glTF JSON and GLB (embedded buffers and data URIs only: no files are read). No panic;
//! what is accepted is a valid mesh.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if let Ok(mesh) = bake::ingest::gltf::parse(data) {
        assert_eq!(mesh.validate(), Ok(()));
    }
});
