//! Fuzz target: the pack reader: open (header and table), every section kind's decoder, `dump` with
//! all data, and `verify`. The input's checksums are repaired first so payload mutations reach
//! the decoders. No panic; a pack that verifies clean must also open, dump and decode.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    let bytes = bake_fuzz::with_valid_checksums(data);
    let report = bake::verify::verify_bytes(&bytes);
    let Ok(pack) = bake::pack::Pack::from_bytes(&bytes, "fuzz.bake") else {
        assert!(!report.ok());
        return;
    };
    let opts = bake::dump::DumpOptions {
        full: true,
        section: None,
    };
    let dumped = bake::dump::dump_json(&pack, &opts);
    let decoded = bake::verify::decode_sections(&pack);
    if report.ok() {
        assert!(dumped.is_ok(), "verify passed but dump failed: {dumped:?}");
        assert!(decoded.iter().all(|r| r.is_ok()), "verify passed but a decoder failed");
    }
});
