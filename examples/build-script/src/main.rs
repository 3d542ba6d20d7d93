//! Prints where the build script put the baked pack and how many sections it has; the pack's
//! bytes are embedded, so the program checks the file it was built with is still the same.

const PACK: &[u8] = include_bytes!(env!("SCENE_PACK"));

fn main() {
    let sections: usize = env!("SCENE_SECTIONS").parse().unwrap();
    assert_eq!(&PACK[..8], b"BAKEPAK\0", "the embedded file is a bake pack");
    let count = u32::from_le_bytes(PACK[16..20].try_into().unwrap()) as usize;
    assert_eq!(
        count, sections,
        "section count of the header and of the build report"
    );
    println!(
        "{}: {} bytes, {sections} sections of the kinds {}",
        env!("SCENE_PACK"),
        PACK.len(),
        env!("SCENE_KINDS")
    );
}
