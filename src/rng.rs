//! The one random-number family of the crate: SplitMix64 (a Weyl sequence through a 64-bit
//! finalizer), deterministic and independent of scheduling, for stages, fixtures, benchmarks
//! and tests.
//!
//! Seeding, documented because a changed seed changes baked bytes:
//! - [`Rng::new`]`(seed)` starts the sequence at `seed` itself. Fixtures, generated inputs and
//!   validation batches use it.
//! - [`Rng::hashed`]`(seed)` first passes the seed through [`mix64`], so neighbouring seeds (a
//!   path per vertex, a stream per texel) give unrelated streams. The ray-tracing stages (PRT,
//!   light maps, environment maps) and their tests use it.
//!
//! Both are the same generator: `Rng::hashed(s)` is `Rng::new(mix64(s) + γ)` (γ the Weyl
//! increment), which is the sequence the tracer's generator has always produced.

/// The Weyl increment of SplitMix64 (2⁶⁴ / φ).
const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 finalizer without the increment.
fn finalize(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// SplitMix64 of one value: a strong 64-bit mixer, used to derive per-item seeds.
pub fn mix64(x: u64) -> u64 {
    finalize(x.wrapping_add(GAMMA))
}

/// A small deterministic random stream (SplitMix64); see the module docs for seeding.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// The stream that starts at `seed` itself.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    /// The stream of a hashed seed ([`mix64`]): for per-item streams with neighbouring seeds.
    pub fn hashed(seed: u64) -> Self {
        Rng(mix64(seed).wrapping_add(GAMMA))
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GAMMA);
        finalize(self.0)
    }
    /// Uniform in [0, 1), 24 bits.
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in [0, 1), 53 bits.
    pub fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in 0..n (by remainder; `n` > 0).
    pub fn below(&mut self, n: u32) -> u32 {
        (self.next_u64() % n as u64) as u32
    }
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tracer's original generator: state `mix64(seed)`, each step `mix64(state += γ)`.
    #[test]
    fn hashed_is_the_tracers_sequence() {
        for seed in [0, 1, 7, 0xdead_beef, u64::MAX] {
            let mut state = mix64(seed);
            let mut rng = Rng::hashed(seed);
            for _ in 0..100 {
                state = state.wrapping_add(GAMMA);
                assert_eq!(rng.next_u64(), mix64(state));
            }
        }
    }

    #[test]
    fn new_is_splitmix64_from_the_seed() {
        // Reference values of SplitMix64 seeded with 1234567.
        let mut rng = Rng::new(1_234_567);
        assert_eq!(rng.next_u64(), 6_457_827_717_110_365_317);
        assert_eq!(rng.next_u64(), 3_203_168_211_198_807_973);
        let x = rng.f32();
        assert!((0.0..1.0).contains(&x));
    }
}
