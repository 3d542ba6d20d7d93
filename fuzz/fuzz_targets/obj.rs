//! Fuzz target: OBJ with an MTL file. The input is split at its first NUL byte: the OBJ text before
//! it, the MTL text (served for every `mtllib` name) after it. No panic; a valid mesh.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    let (obj, mtl) = match data.iter().position(|&b| b == 0) {
        Some(k) => (&data[..k], &data[k + 1..]),
        None => (data, &[][..]),
    };
    if let Ok(mesh) = bake::ingest::obj::parse_with_mtl(obj, mtl) {
        assert_eq!(mesh.validate(), Ok(()));
    }
});
