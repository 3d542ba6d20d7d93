//! A `cargo test` stand-in for the cargo-fuzz targets (fuzz/, docs/FUZZING.md): deterministic
//! mutations (byte flips, random 32-bit words — which hit chunk lengths and counts —, insertions,
//! deletions, truncations) of the project's fixtures, and of the assimp corpus's 3DS files when
//! `scripts/assimp-corpus.sh` has fetched them, fed to the byte-level readers. A reader must
//! return `Ok` or `Err`, never panic, and what it accepts must be a valid mesh.

use bake::fixtures::Rng;
use std::path::Path;

/// One random mutation of `base`.
fn mutate(base: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = base.to_vec();
    let at = |rng: &mut Rng, len: usize| (rng.next_u64() % len.max(1) as u64) as usize;
    for _ in 0..1 + rng.next_u64() % 3 {
        match rng.next_u64() % 5 {
            0 if !b.is_empty() => {
                let k = at(rng, b.len());
                b[k] = rng.next_u64() as u8;
            }
            1 if b.len() >= 4 => {
                let k = at(rng, b.len() - 3);
                let word = match rng.next_u64() % 4 {
                    0 => 0,
                    1 => u32::MAX,
                    2 => rng.next_u64() as u32 % 64,
                    _ => rng.next_u64() as u32,
                };
                b[k..k + 4].copy_from_slice(&word.to_le_bytes());
            }
            2 => {
                let k = at(rng, b.len() + 1);
                b.insert(k.min(b.len()), rng.next_u64() as u8);
            }
            3 if !b.is_empty() => {
                let k = at(rng, b.len());
                b.remove(k);
            }
            _ => {
                let k = at(rng, b.len() + 1);
                b.truncate(k);
            }
        }
    }
    b
}

fn corpus_3ds() -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("target/assimp-corpus/root/usr/share/assimp/models/3DS");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("3ds")))
        .collect();
    files.sort();
    files.iter().filter_map(|p| std::fs::read(p).ok()).collect()
}

#[test]
fn max3ds_survives_mutations() {
    let mut seeds = vec![bake::fixtures::object3ds::bench_3ds()];
    seeds.extend(corpus_3ds());
    let mut rng = Rng::new(3);
    let mut accepted = 0;
    for seed in &seeds {
        assert!(bake::ingest::max3ds::parse(seed).is_ok());
        for _ in 0..4000 {
            if let Ok(m) = bake::ingest::max3ds::parse(&mutate(seed, &mut rng)) {
                assert_eq!(m.validate(), Ok(()));
                accepted += 1;
            }
        }
    }
    // Mutations inside vertex data keep the file readable: the harness must exercise both paths.
    assert!(accepted > 0 && accepted < seeds.len() * 4000, "{accepted}");
}

#[test]
fn eco_survives_mutations() {
    let seed = bake::fixtures::scene::scene_eco().into_bytes();
    assert!(bake::ingest::eco::parse(&seed).is_ok());
    let mut rng = Rng::new(5);
    for _ in 0..3000 {
        let _ = bake::ingest::eco::parse(&mutate(&seed, &mut rng));
    }
}

#[test]
fn txf_survives_mutations() {
    let (_, seed) = bake::fixtures::plant::plant_files()
        .into_iter()
        .find(|(name, _)| name.ends_with(".txf"))
        .expect("the plant fixture has a TXF file");
    assert!(bake::ingest::txf::parse(&seed).is_ok());
    let mut rng = Rng::new(11);
    for _ in 0..3000 {
        if let Ok(m) = bake::ingest::txf::parse(&mutate(&seed, &mut rng)) {
            assert_eq!(m.validate(), Ok(()));
        }
    }
}
