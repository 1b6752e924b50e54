//! A counter-based random stream: every (seed, ray, sample) triple names its own independent
//! stream, so results do not depend on which thread runs which ray, or in what order.
//!
//! The state is the SplitMix64 mix of the three keys; numbers come from SplitMix64 (Steele,
//! Lea & Flood 2014), which passes BigCrush and is ample for Monte Carlo integration.
//!
//! [`Rng`] implements [`rand_core::RngCore`], so every `rand` distribution samples from it.

/// Deterministic random stream keyed by `(seed, ray, sample)`.
#[derive(Debug, Clone)]
pub struct Rng {
    state: u64,
}

#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// The stream for sample `sample` of ray `ray` under `seed`.
    #[must_use]
    pub fn new(seed: u64, ray: u64, sample: u64) -> Self {
        let k = mix(seed ^ 0x9E37_79B9_7F4A_7C15);
        let k = mix(k ^ ray.wrapping_mul(0xD6E8_FEB8_6659_FD93));
        let k = mix(k ^ sample.wrapping_mul(0xA076_1D64_78BD_642F));
        Self { state: k }
    }

    /// The stream of `block` within this one: a fresh stream (nothing drawn yet) keyed once
    /// more, by the `8^3` block a march's chord lies in, so that the points of one chord do
    /// not depend on the chords before it (a map marched block by block draws the same).
    #[must_use]
    pub fn fork(&self, block: [i64; 3]) -> Self {
        let k = mix(self.state ^ (block[0] as u64).wrapping_mul(0xE703_7ED1_A0B4_28DB));
        let k = mix(k ^ (block[1] as u64).wrapping_mul(0x8EBC_6AF0_9C88_C6E3));
        let k = mix(k ^ (block[2] as u64).wrapping_mul(0x5899_65CC_7537_4CC3));
        Self { state: k }
    }

    /// The stream of sample `sample` of a chord whose block and ray are keyed by `chord`
    /// ([`chord_key`]): one more SplitMix64 mix, so the samples of one chord are drawn side by
    /// side without walking any other stream (a null-collision map swept block by block).
    #[must_use]
    #[inline]
    pub fn of_chord(chord: u64, sample: u64) -> Self {
        Self {
            state: mix(chord ^ sample.wrapping_add(1).wrapping_mul(0xA076_1D64_78BD_642F)),
        }
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.state)
    }

    /// Uniform in `[0, 1)` with 53 random bits.
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Exponential free-flight distance with rate `mu` (> 0): `-ln(1 - u) / mu`.
    #[inline]
    pub fn exponential(&mut self, mu: f64) -> f64 {
        -(1.0 - self.uniform()).ln() / mu
    }
}

/// The key of a block under `seed`: three SplitMix64 mixes of its coordinates, computed once
/// per block and shared by every chord through it ([`chord_key`]).
#[must_use]
pub fn block_key(seed: u64, block: [i64; 3]) -> u64 {
    let k = mix(seed ^ 0x2545_F491_4F6C_DD1D);
    let k = mix(k ^ (block[0] as u64).wrapping_mul(0xE703_7ED1_A0B4_28DB));
    let k = mix(k ^ (block[1] as u64).wrapping_mul(0x8EBC_6AF0_9C88_C6E3));
    mix(k ^ (block[2] as u64).wrapping_mul(0x5899_65CC_7537_4CC3))
}

/// The key of the chord of ray `ray` through the block keyed `block` ([`block_key`]): the
/// samples' streams are [`Rng::of_chord`] of it. A mix is a bijection of 64-bit words and ray
/// ids enter multiplied by an odd constant, so two rays through one block never share a key.
#[must_use]
#[inline]
pub fn chord_key(block: u64, ray: u64) -> u64 {
    mix(block ^ ray.wrapping_mul(0xD6E8_FEB8_6659_FD93))
}

impl rand_core::RngCore for Rng {
    fn next_u32(&mut self) -> u32 {
        (Rng::next_u64(self) >> 32) as u32
    }
    fn next_u64(&mut self) -> u64 {
        Rng::next_u64(self)
    }
    fn fill_bytes(&mut self, dest: &mut [u8]) {
        rand_core::impls::fill_bytes_via_next(self, dest);
    }
    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), rand_core::Error> {
        self.fill_bytes(dest);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rand_distributions_sample_from_the_stream() {
        use rand::distributions::{Distribution, Uniform};
        use rand::Rng as _;
        let mut r = Rng::new(3, 1, 4);
        let d = Uniform::new(10.0f64, 20.0);
        let n = 50_000;
        let m: f64 = (0..n).map(|_| d.sample(&mut r)).sum::<f64>() / f64::from(n);
        assert!((m - 15.0).abs() < 0.05, "{m}");
        let b: u32 = (0..n).map(|_| u32::from(r.gen_bool(0.25))).sum();
        assert!((f64::from(b) / f64::from(n) - 0.25).abs() < 0.01);
        // The same stream through the trait and the inherent method.
        let (mut a, mut c) = (Rng::new(9, 9, 9), Rng::new(9, 9, 9));
        assert_eq!(rand_core::RngCore::next_u64(&mut a), c.next_u64());
    }

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: Vec<u64> = (0..4).map(|_| Rng::new(1, 2, 3).next_u64()).collect();
        assert!(a.windows(2).all(|w| w[0] == w[1]));
        assert_ne!(Rng::new(1, 2, 3).next_u64(), Rng::new(1, 2, 4).next_u64());
        assert_ne!(Rng::new(1, 2, 3).next_u64(), Rng::new(1, 3, 3).next_u64());
    }

    #[test]
    fn forks_are_reproducible_and_distinct() {
        let base = Rng::new(1, 2, 3);
        let draw = |b: [i64; 3]| base.fork(b).next_u64();
        assert_eq!(draw([1, 2, 3]), draw([1, 2, 3]));
        assert_ne!(draw([1, 2, 3]), draw([1, 2, 4]));
        assert_ne!(draw([1, 2, 3]), draw([2, 1, 3]));
        assert_ne!(draw([0, 0, 0]), Rng::new(1, 2, 3).next_u64());
        assert_ne!(draw([-1, 0, 0]), draw([1, 0, 0]));
    }

    #[test]
    fn uniform_mean_and_exponential_mean() {
        let mut r = Rng::new(7, 0, 0);
        let n = 200_000;
        let m: f64 = (0..n).map(|_| r.uniform()).sum::<f64>() / f64::from(n);
        assert!((m - 0.5).abs() < 0.005, "{m}");
        let e: f64 = (0..n).map(|_| r.exponential(2.0)).sum::<f64>() / f64::from(n);
        assert!((e - 0.5).abs() < 0.01, "{e}");
    }
}
