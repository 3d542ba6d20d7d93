//! Fuzz target: Radiance RGBE (.hdr) skies must decode or fail, never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    bake_fuzz::init();
    let float = bake::ingest::skyimage::parse_hdr(data);
    if let Ok(img) = &float {
        assert_eq!(img.pixels.len(), img.width as usize * img.height as usize);
    }
    // The sky stage's reader (RGBE kept, pixels decoded on demand) accepts exactly the same
    // files and decodes them to the same bits.
    let rgbe = bake::ingest::skyimage::parse_hdr_rgbe(data.to_vec());
    match (&float, &rgbe) {
        (Ok(f), Ok(r)) => {
            let r = r.to_float_image();
            assert_eq!((f.width, f.height), (r.width, r.height));
            assert!(
                f.pixels.iter().flatten().map(|v| v.to_bits())
                    .eq(r.pixels.iter().flatten().map(|v| v.to_bits())),
                "the RGBE reader decodes other bits"
            );
        }
        (Err(_), Err(_)) => {}
        _ => panic!("the readers disagree: {:?} against {:?}", float.is_ok(), rgbe.is_ok()),
    }
});
