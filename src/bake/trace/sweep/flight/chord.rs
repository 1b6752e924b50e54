//! One chord's flight: the tentative collisions of all its samples as one Poisson process,
//! each point's factor into its sample's product (see the module docs of [`super`]).

use super::Rule;
use crate::regular::kernel::{point, BLOCK};
use crate::rng::Rng;

/// One chord's flight: the block, the chord (block-centred entry `e`, lookup direction `d`,
/// world length `len`) and the block's bounds, control and rate.
pub(super) struct Chord<'b> {
    pub(super) rule: Rule,
    pub(super) block: &'b [f32; BLOCK],
    pub(super) e: [f64; 3],
    pub(super) d: [f64; 3],
    pub(super) len: f64,
    pub(super) lo: f64,
    pub(super) hi: f64,
    pub(super) mu_c: f64,
    pub(super) rate: f64,
    pub(super) scale: f64,
}

/// Where a chord's samples keep their state: the product of their chord factors and the
/// collisions they spent, sample `i` at `base + i per`; the budget of collisions per estimate,
/// and what the chord's flight did: the collisions it evaluated, whether a sample was capped.
pub(super) struct Estimates<'a> {
    pub(super) prod: &'a mut [f64],
    pub(super) spent: &'a mut [u32],
    pub(super) base: usize,
    pub(super) per: usize,
    pub(super) samples: usize,
    pub(super) budget: u32,
    pub(super) evaluated: u64,
    pub(super) capped: bool,
}

/// Largest expected point count of a chord (`samples x r x L`) drawn by inverting the Poisson
/// distribution; above it the points are drawn as exponential gaps.
const POISSON_INVERSION: f64 = 30.0;

impl Chord<'_> {
    /// Fly every sample through the chord with the stream `rng` (see the module docs): the
    /// tentative collisions of all samples as one Poisson process of rate `samples x r`, each
    /// point given to a uniform sample. A sample already at 0 stays there; one whose
    /// collisions reach the budget stops.
    pub(super) fn fly(&self, mut rng: Rng, est: &mut Estimates<'_>) {
        let samples = est.samples as f64;
        let lambda = self.rate * self.len * samples;
        let u = rng.uniform();
        // No point when `u <= exp(-lambda)`; `1 - lambda <= exp(-lambda)` decides most chords
        // without an exponential.
        if u <= 1.0 - lambda {
            return;
        }
        if lambda <= POISSON_INVERSION {
            // The count by inversion, then that many uniform points (their order does not
            // matter: a product of factors, or any real collision, is the same in any order).
            let (mut k, mut p) = (0u32, (-lambda).exp());
            let mut cdf = p;
            while u > cdf && k < 1000 {
                k += 1;
                p *= lambda / f64::from(k);
                cdf += p;
            }
            for _ in 0..k {
                // One draw gives both: the sample `floor(S x)` and `t = L frac(S x)`.
                let m = u128::from(rng.next_u64()) * est.samples as u128;
                let frac = (m as u64) as f64 * (1.0 / 18_446_744_073_709_551_616.0);
                let i = (m >> 64) as usize;
                self.collide(frac * self.len, i, &mut rng, est);
            }
            return;
        }
        // Many points: exponential gaps `E / (S r)`, `E = -ln(1 - u) >= u` (past the end when
        // `u` is).
        let total = self.rate * samples;
        let inv_total = 1.0 / total;
        let mut t = 0.0f64;
        loop {
            let u = rng.uniform();
            if u >= total * (self.len - t) {
                break;
            }
            t -= (1.0 - u).ln() * inv_total;
            if t >= self.len {
                break;
            }
            let i = ((u128::from(rng.next_u64()) * est.samples as u128) >> 64) as usize;
            self.collide(t, i, &mut rng, est);
        }
    }

    /// A tentative collision of sample `i` at `t`: its factor into the sample's product
    /// (nothing for a sample already at 0; none past the budget, which marks it capped).
    #[inline]
    fn collide(&self, t: f64, i: usize, rng: &mut Rng, est: &mut Estimates<'_>) {
        let at = est.base + i * est.per;
        if est.prod[at] == 0.0 {
            return;
        }
        if est.spent[at] >= est.budget {
            est.capped = true;
            return;
        }
        est.spent[at] += 1;
        est.evaluated += 1;
        let p = [0, 1, 2].map(|a| self.e[a] + self.d[a] * t);
        // `scale > 0` here (a zero scale has rate 0 and no collisions).
        let v = self.scale * point(self.block, p);
        let mu = if v > self.hi {
            self.hi
        } else if v < self.lo {
            self.lo
        } else {
            v
        } - self.mu_c;
        match self.rule {
            Rule::Ratio => {
                // A spent weight (below the smallest normal f64) is 0 and spends nothing more
                // (as the ray path's `stop_if_spent`).
                let w = est.prod[at] * (1.0 - mu / self.rate);
                est.prod[at] = if w.abs() < f64::MIN_POSITIVE { 0.0 } else { w };
            }
            Rule::Delta => {
                if rng.uniform() * self.rate < mu {
                    est.prod[at] = 0.0;
                }
            }
        }
    }
}
