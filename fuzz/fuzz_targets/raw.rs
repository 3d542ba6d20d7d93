//! Fuzz target: RAW height maps. The first 4 bytes give the declared size (u16 width, u16 height, as an
//! ECO terrain line would), the rest is the file. No panic; one height per sample.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    if data.len() < 4 {
        return;
    }
    let spec = bake::ingest::raw::RawSpec {
        width: u16::from_le_bytes([data[0], data[1]]) as u32,
        height: u16::from_le_bytes([data[2], data[3]]) as u32,
        scale: 0.05,
        origin: [0.0, 0.0],
        extent: [1.0, 1.0],
    };
    if let Ok(h) = bake::ingest::raw::parse(&data[4..], &spec) {
        assert_eq!(h.len(), spec.width as usize * spec.height as usize);
    }
});
