//! The error bar of a transmittance estimate: the one function every path reports `std_err`
//! through ([`super::estimate`], the scene path, adaptive map pixels and the object-order
//! sweep's null-collision maps), so that a query and a map pixel of the same samples agree.
//!
//! **Why the sample variance is not enough.** The standard error of a mean of `n` samples is
//! `sqrt(s^2 / n)`, `s^2 = m2 / (n - 1)` the sample variance. Null-collision samples are a
//! mixture of rare events: a ratio-tracking sample is exactly `exp(-tau_known)` unless a
//! tentative collision happens (chance `1 - exp(-sum mu_maj len)`, small in a thin medium), a
//! delta-tracking sample is 0 or `exp(-tau_known)`. When `n` samples all miss the rare outcome
//! they agree, `s = 0`, and an error bar of 0 claims an exact answer that is off by the mass of
//! the event they missed; when they see it once or twice, `s` understates the spread in the same
//! way (a Poisson count `k` has the error bar `sqrt(k)`, which is 0 at `k = 0` and too small
//! when `k` fell short of its mean).
//!
//! **What the walk bounds.** Before sampling, the walk knows the closed-form optical depth
//! `tau_known` and, over the sampled segments, `tau_min = sum mu_min len` and
//! `tau_maj = sum mu_maj len`, so `T` lies in `[L, U] = [exp(-(tau_known + tau_maj)),
//! exp(-(tau_known + tau_min))]` ([`Bounds`]). It also knows where one sample can lie,
//! `[a, b]` ([`sample_range`]): `[0, exp(-tau_known)]` for ratio and delta tracking,
//! `[0, U]` for the minorant-controlled trackers, `[L, ...)` for next-flight.
//!
//! **The error bar.** Let the `n` samples have mean `x`, sample variance `s^2` (0 for `n =
//! 1`) and extremes `x_lo <= x_hi`. What `n` samples cannot see is an outcome of probability
//! `p` they all missed; they miss it with chance `(1 - p)^n ~ exp(-n p)`, so at the 95 % level
//! `p <= c / n` with `c = 3` (the rule of three; `p <= 1` always). Such an outcome lies
//! beyond the extremes seen (within them the samples already show their spread): below, by at
//! most `D- = x_lo - a`; above, by at most `D+ = b - x_hi`. It adds `p D^2` to the variance
//! of one sample and moves the mean by `p D`, which cannot take the mean past the walk's bounds:
//! `p D- <= x - L`, `p D+ <= U - x`. So the variance the samples may hide is at most
//!
//! ```text
//! V_hid = max( D- min(x - L, min(1, c/n) D-),  D+ min(U - x, min(1, c/n) D+) )   (each >= 0)
//! ```
//!
//! (`p D^2 = (p D) D` with `p D` bounded both ways), and the reported error bar is
//!
//! ```text
//! std_err = sqrt((s^2 + V_hid) / n).
//! ```
//!
//! Where the samples all agree at the top of their range (`x = b`: ratio tracking that never
//! collided) and `p D- >= x - L` (a thin medium), `V_hid = (b - a)(b - L)`, at least the
//! Bhatia–Davis bound `(b - T)(T - a)` on the variance of a variable in `[a, b]` with the
//! furthest mean the walk allows, `T = L`: for ratio tracking that is `known^2 (1 -
//! exp(-tau_maj))`, about `tau_maj`, the true variance when every collision kills the weight.
//! The first bound keeps the error bar of a well-spread sample from being inflated: the hidden
//! part adds at most `c D^2 / n^2` to the squared error bar, a `1 / n` term beside the
//! `1 / sqrt(n)` of `s`, and it vanishes when the samples reach the ends of their range.
//! A mean of samples that all agree on the exact answer (`x = L = U`) keeps an error bar of 0.
//!
//! **Guarantees.** For the unbiased trackers whose samples are proven to lie in `[a, b]`
//! (`ratio`, `residual-ratio`, `track-length`, `decomposition`): the error bar is 0 only when
//! `T` is known exactly (`L = U`, or every sample at a range end that is also a walk bound),
//! and when every sample agrees it is at least the Bhatia–Davis bound above. The signed
//! estimators (`next-flight`, `residual-ratio-midpoint`, `unbiased-raymarch`) have no bound on
//! one sample above (and `unbiased-raymarch` none below): their range is a heuristic
//! ([`sample_range`]) widened to the extremes seen. The biased estimators' error bar
//! (`collision`, `jackknife`) is that of their noise, not of their bias; `jackknife` (fixed
//! cost, every sample averaging the whole ray, no rare outcome) gets the floor only when all
//! its samples agree (clamped at 0 or 1). Marchers (`mc`, `jittered`) have no rare outcome
//! to miss and report the sample standard error alone (noise, not bias); deterministic ones
//! (`regular`, `riemann`) report 0. On a moving volume the marchers' values are shutter times,
//! which can miss a passing feature: there they get the range `[L, U]` and the floor too
//! (`super::blur`), and one time in all reports an unknown (NaN) error bar.

use super::{Algo, Control, Estimator};
use crate::traverse::Segment;

/// The confidence constant `c`: an outcome that `n` samples all missed has probability at most
/// `c / n` at the 95 % level (the rule of three: `(1 - 3 / n)^n ~ exp(-3) = 0.05`).
pub const RULE_OF_THREE: f64 = 3.0;

/// The interval `[L, U]` the walk bounds the transmittance in: `L = exp(-(tau_known +
/// tau_maj))`, `U = exp(-(tau_known + tau_min))`, with `tau_maj = sum mu_maj len` and
/// `tau_min = sum mu_min len` over the sampled segments; `known = exp(-tau_known)`.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Bounds {
    /// `L`: `T` is at least this.
    pub lo: f64,
    /// `U`: `T` is at most this.
    pub hi: f64,
    /// `exp(-tau_known)`, the closed-form part's transmittance.
    pub known: f64,
}

impl Bounds {
    /// The bounds of a ray whose closed-form optical depth is `tau_known`, with the sampled
    /// part's minorant and majorant optical depths `tau_min <= tau_maj`.
    #[must_use]
    pub fn new(tau_known: f64, tau_min: f64, tau_maj: f64) -> Self {
        Self {
            lo: (-(tau_known + tau_maj)).exp(),
            hi: (-(tau_known + tau_min)).exp(),
            known: (-tau_known).exp(),
        }
    }

    /// The bounds of a ray whose closed-form optical depth is `tau_known` and whose sampled
    /// segments are `segs`.
    #[must_use]
    pub fn of_segments(tau_known: f64, segs: &[Segment]) -> Self {
        let (lo, hi) = depths(segs);
        Self::new(tau_known, lo, hi)
    }
}

/// The minorant and majorant optical depths `(sum mu_min len, sum mu_maj len)` of `segs`.
#[must_use]
pub fn depths(segs: &[Segment]) -> (f64, f64) {
    segs.iter().fold((0.0, 0.0), |(lo, hi), s| {
        (lo + s.mu_min * s.length(), hi + s.mu_maj * s.length())
    })
}

/// Where one sample of an estimator lies, `[a, b]`, and whether its samples are a mixture of
/// rare outcomes (null collisions, a power series' random order) that `n` samples can miss.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SampleRange {
    /// Lowest value of one sample.
    pub a: f64,
    /// Highest value of one sample.
    pub b: f64,
    /// The floor applies however the samples spread (`true`), or only when they all agree
    /// (`false`: a fixed-cost estimator whose every sample averages the whole ray).
    pub rare: bool,
}

/// Where one sample of `est` lies on a ray with bounds `w` (see the module docs): `None` for
/// the marchers and deterministic estimators (no floor: their error bar is the sample's).
/// Proven for ratio, delta and decomposition tracking, residual ratio with the minorant
/// control and jackknife (clamped to `[0, 1]`, its optical depths within the bounds);
/// heuristic for the signed estimators, widened to the samples' extremes: next-flight
/// `[L, L + known]` (a walk without collisions scores `L`, one collision adds at most
/// `known`), the midpoint control and unbiased ray marching `[0, known]`.
#[must_use]
pub fn sample_range(est: &Estimator, w: Bounds) -> Option<SampleRange> {
    let r = |a, b, rare| Some(SampleRange { a, b, rare });
    match est.algo().0 {
        Algo::Regular | Algo::Riemann | Algo::Mc | Algo::Jittered => None,
        Algo::Ratio | Algo::TrackLength | Algo::Collision => r(0.0, w.known, true),
        Algo::ResidualRatio(Control::Minorant) | Algo::Decomposition => r(0.0, w.hi, true),
        Algo::Jackknife => r(0.0, w.hi, false),
        Algo::ResidualRatio(Control::Midpoint) | Algo::UnbiasedRaymarch => r(0.0, w.known, true),
        Algo::NextFlight => r(w.lo, w.lo + w.known, true),
    }
}

/// The running statistics of one ray's samples (Welford: count, mean, sum of squared
/// deviations, extremes) with what the walk bounds, from which [`Spread::std_err`] makes the
/// error bar (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Spread {
    /// Samples seen.
    pub n: u64,
    /// Their mean.
    pub mean: f64,
    /// Sum of squared deviations from the mean.
    pub m2: f64,
    /// Smallest sample.
    pub min: f64,
    /// Largest sample.
    pub max: f64,
    /// Where one sample lies ([`sample_range`]; `None`: no floor).
    pub range: Option<SampleRange>,
    /// Where `T` lies.
    pub bounds: Bounds,
}

impl Default for Spread {
    fn default() -> Self {
        Self::new(None, Bounds::default())
    }
}

impl Spread {
    /// No samples yet, for samples in `range` of a ray with `bounds`.
    #[must_use]
    pub fn new(range: Option<SampleRange>, bounds: Bounds) -> Self {
        Self {
            n: 0,
            mean: 0.0,
            m2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            range,
            bounds,
        }
    }

    /// No samples yet, of `est` on a ray with `bounds`.
    #[must_use]
    pub fn of(est: &Estimator, bounds: Bounds) -> Self {
        Self::new(sample_range(est, bounds), bounds)
    }

    /// Add one sample (Welford's update: `delta = x - mean`, `mean += delta / n`,
    /// `m2 += delta (x - mean)`).
    pub fn push(&mut self, x: f64) {
        self.n += 1;
        let delta = x - self.mean;
        self.mean += delta / self.n as f64;
        self.m2 += delta * (x - self.mean);
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }

    /// The extremes of `other` added to these (an adaptive pixel's batches; count, mean and
    /// `m2` are merged by the caller).
    pub fn widen(&mut self, other: &Spread) {
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }

    /// The sample standard error `sqrt(m2 / (n - 1) / n)` (0 for fewer than 2 samples): the
    /// spread the samples show, without the floor.
    #[must_use]
    pub fn sample_std_err(&self) -> f64 {
        if self.n > 1 {
            (self.m2 / (self.n - 1) as f64 / self.n as f64).sqrt()
        } else {
            0.0
        }
    }

    /// The variance one sample may hide beyond the extremes seen, `V_hid` (module docs).
    #[must_use]
    pub fn hidden_variance(&self) -> f64 {
        let Some(SampleRange { a, b, rare }) = self.range else {
            return 0.0;
        };
        if self.n == 0 || !(self.min.is_finite() && self.max.is_finite()) {
            return 0.0;
        }
        if !rare && self.min != self.max {
            return 0.0;
        }
        let p = (RULE_OF_THREE / self.n as f64).min(1.0);
        let (a, b) = (a.min(self.min), b.max(self.max));
        let side = |d: f64, room: f64| {
            let (d, room) = (d.max(0.0), room.max(0.0));
            d * room.min(p * d)
        };
        let below = side(self.min - a, self.mean - self.bounds.lo);
        let above = side(b - self.max, self.bounds.hi - self.mean);
        below.max(above)
    }

    /// The error bar: `sqrt((s^2 + V_hid) / n)` (module docs); 0 without samples.
    #[must_use]
    pub fn std_err(&self) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let n = self.n as f64;
        let s2 = if self.n > 1 { self.m2 / (n - 1.0) } else { 0.0 };
        ((s2 + self.hidden_variance()) / n).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spread(xs: &[f64], range: (f64, f64), lo: f64, hi: f64) -> Spread {
        let mut s = Spread::new(
            Some(SampleRange {
                a: range.0,
                b: range.1,
                rare: true,
            }),
            Bounds {
                lo,
                hi,
                known: range.1,
            },
        );
        xs.iter().for_each(|&x| s.push(x));
        s
    }

    #[test]
    fn agreeing_samples_get_the_bhatia_davis_bound() {
        // 64 ratio samples with no collision (all 1); T in [0.99, 1].
        let s = spread(&[1.0; 64], (0.0, 1.0), 0.99, 1.0);
        assert_eq!(s.sample_std_err(), 0.0);
        let want = ((1.0 * 0.01f64.min(3.0 / 64.0)) / 64.0).sqrt();
        assert!((s.std_err() - want).abs() < 1e-15, "{}", s.std_err());
    }

    #[test]
    fn an_exact_answer_keeps_a_zero_error_bar() {
        let s = spread(&[0.5; 16], (0.0, 0.5), 0.5, 0.5);
        assert_eq!(s.std_err(), 0.0);
        // Delta tracking that always survives where T = known exactly (no extinction left).
        let s = spread(&[1.0; 16], (0.0, 1.0), 1.0, 1.0);
        assert_eq!(s.std_err(), 0.0);
    }

    #[test]
    fn samples_reaching_both_ends_are_not_inflated() {
        let xs: Vec<f64> = (0..64).map(|i| f64::from(i % 2)).collect();
        let s = spread(&xs, (0.0, 1.0), 0.0, 1.0);
        assert_eq!(s.std_err(), s.sample_std_err());
    }

    #[test]
    fn no_range_is_the_sample_standard_error() {
        let mut s = Spread::new(None, Bounds::new(0.0, 0.0, 1.0));
        [0.3, 0.5, 0.4].iter().for_each(|&x| s.push(x));
        assert_eq!(s.std_err(), s.sample_std_err());
        assert!(s.std_err() > 0.0);
    }

    #[test]
    fn the_floor_is_a_one_over_n_term_for_spread_samples() {
        // Samples spread over [0.2, 0.8] of [0, 1]: the hidden variance is at most c D^2 / n.
        let xs: Vec<f64> = (0..64).map(|i| 0.2 + 0.6 * f64::from(i) / 63.0).collect();
        let s = spread(&xs, (0.0, 1.0), 0.0, 1.0);
        let bound = RULE_OF_THREE * 0.2f64.powi(2) / 64.0;
        assert!(s.hidden_variance() <= bound + 1e-15);
        assert!(s.std_err() < 1.1 * s.sample_std_err());
    }
}
