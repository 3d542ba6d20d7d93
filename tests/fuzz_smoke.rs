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

mod common;

/// Rewrites each in-bounds table entry's BLAKE3 to match its payload (as fuzz/src/lib.rs does),
/// so payload mutations reach the section decoders.
fn with_valid_checksums(bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let rd = |b: &[u8], at: usize, n: usize| -> Option<u64> {
        let s = b.get(at..at.checked_add(n)?)?;
        Some(s.iter().rev().fold(0u64, |a, &x| a << 8 | x as u64))
    };
    let (Some(count), Some(table)) = (rd(&b, 16, 4), rd(&b, 24, 8)) else {
        return b;
    };
    for k in 0..count.min(4096) {
        let Some(e) = table
            .checked_add(k * 168)
            .and_then(|e| usize::try_from(e).ok())
        else {
            break;
        };
        let field = |at: usize| e.checked_add(at).and_then(|a| rd(&b, a, 8));
        let (Some(off), Some(size)) = (field(112), field(120)) else {
            break;
        };
        let end = off.saturating_add(size);
        if end <= b.len() as u64 && e.checked_add(168).is_some_and(|x| x <= b.len()) {
            let h = blake3::hash(&b[off as usize..end as usize]);
            b[e + 136..e + 168].copy_from_slice(h.as_bytes());
        }
    }
    b
}

/// Regression (cargo-fuzz pack, crash-c61e4abc): a table offset near the end of the address
/// space overflowed the checksum repair of the fuzz harness (fuzz/src/lib.rs) before bake saw
/// the input; the pack reader and `verify` refuse it.
#[test]
fn crash_c61e4abc_table_offset_near_the_end_of_the_address_space() {
    let data = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/fuzz/pack/crash-c61e4abc6c7d0191015432ecd18df459138f4086"),
    )
    .unwrap();
    pack_entry(&data);
    let r = bake::verify::verify_bytes(&data);
    assert_eq!(r.violations[0].check, "header.version");
    assert!(bake::pack::Pack::from_bytes(&data, "crash").is_err());
}

/// The pack target's checks: a pack `verify` passes must open, dump in full and decode.
fn pack_entry(data: &[u8]) {
    let bytes = with_valid_checksums(data);
    let report = bake::verify::verify_bytes(&bytes);
    let Ok(pack) = bake::pack::Pack::from_bytes(&bytes, "mutant.bake") else {
        assert!(!report.ok(), "verify passed a pack that does not open");
        return;
    };
    let opts = bake::dump::DumpOptions {
        full: true,
        section: None,
    };
    let dumped = bake::dump::dump_json(&pack, &opts);
    let decoded = bake::verify::decode_sections(&pack);
    if report.ok() {
        assert!(dumped.is_ok(), "verify passed, dump failed: {dumped:?}");
        assert!(
            decoded.iter().all(|r| r.is_ok()),
            "verify passed, a decoder failed"
        );
    }
}

/// Every seed of every cargo-fuzz corpus (fuzz/corpus/) with 300 mutants each (or
/// `BAKE_FUZZ_MUTANTS`, from RNG seed `BAKE_FUZZ_SEED`) through its target's entry point: no
/// panic (the coverage-guided campaign is docs/FUZZING.md).
#[test]
fn every_fuzz_corpus_survives_mutations() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let env = |k: &str, d: u64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let mutants = env("BAKE_FUZZ_MUTANTS", 300);
    let mut rng = Rng::new(env("BAKE_FUZZ_SEED", 17));
    for target in common::FUZZ_TARGETS {
        let mut files: Vec<_> = std::fs::read_dir(root.join(target))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        for f in files {
            let seed = std::fs::read(&f).unwrap();
            for _ in 0..mutants {
                let m = mutate(&seed, &mut rng);
                if target == "pack" {
                    pack_entry(&m);
                } else {
                    let _ = common::fuzz_entry(target, &m);
                }
            }
        }
    }
}
