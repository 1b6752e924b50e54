//! Free-flight (null-collision) estimators over per-segment majorants, all driven by one loop,
//! [`free_flight`], in the manner of pbrt-v4's `SampleT_maj`.
//!
//! **The driver.** Within each sampled segment `s` the estimator names a control extinction
//! `mu_c` and a tentative-collision rate `r` (the majorant of the residual `mu - mu_c`).
//! Tentative collisions are a Poisson process of rate `r`: `t += -ln(1 - U) / r` until `t`
//! passes `s.t_max`. A segment with `r <= 0` has no collisions (its residual is zero: closed
//! form). Each collision spends one unit of the collision budget ([`Cap`]); the collision at
//! `t` that finds it spent is still taken, and then the sample finishes the rest of its ray
//! deterministically (counted in [`super::Estimate::capped`]): the exact optical depth
//! `tau_rest` of `[t, end]` ([`Extinction::exact`]) takes the place of the collisions not
//! drawn, so the sample scores its running weight times `exp(-tau_rest)` (less the control
//! already applied, see [`Tracker::capped`]). That is the conditional mean of what the walk
//! would have scored from `t` on given its state (ratio and delta weights are products, and
//! `E[W_rest] = T_rest` for the walk from a point), so a capped sample of an unbiased tracker
//! stays unbiased (a Rao-Blackwellised tail), and a capped walk never reports "no
//! attenuation". Each collision reads `mu(t)` once and checks the segment's
//! bounds `mu_min <= mu <= mu_maj`: a value past them by more than float round-off (relative
//! [`BOUND_TOLERANCE`]) is a *majorant violation*, counted in
//! [`super::Estimate::majorant_violations`] (and a `debug_assert!` failure in debug builds) and
//! passed on raw; round-off is clamped to the bound. The estimator is the callback
//! ([`Tracker`]): what happens on entering a segment and at each tentative collision.
//!
//! **The estimators.**
//! - `track_length` (delta tracking): a tentative collision is real with probability
//!   `mu / mu_maj`; the estimate is 1 if no real collision happens before the end. Variance
//!   `T (1 - T)`.
//! - `collision`: delta tracking's first real collision `s`, scored with a linear ramp over the
//!   last `h` world units before the end `b` (0 before `b - h`, 1 at `b`): a kernel estimate of
//!   the free-flight CDF. Biased: its mean is the average of `T` over `[b - h, b]`, so it
//!   overestimates `T` by O(h).
//! - `ratio`: weight `prod (1 - mu / mu_maj)`; the walk stops when the weight is spent (0, or
//!   below the smallest normal `f64`: [`stop_if_spent`]), and a weight below a millionth after
//!   a thousand collisions plays its factors by Russian roulette ([`Weight`], unbiased). `E = exp(-int mu)`;
//!   `Var = T^2 (exp(int mu^2 / mu_maj) - 1)`.
//! - `residual_ratio`: `mu = mu_c + mu_r`; `exp(-int mu_c)` in closed form times ratio tracking
//!   of `mu_r` with rate `r`: minorant control (`r = mu_maj - mu_min`, weights in [0, 1]) or
//!   midpoint control (`r = (mu_maj - mu_min) / 2`, weights in [0, 2]: the estimate can exceed 1;
//!   reported raw, unbiased).
//! - `next_flight`: ratio tracking plus, at every tentative collision, the running weight times
//!   the majorant transmittance to the end: `exp(-tau_maj) + sum_k W_k exp(-tau_maj(t_k, b))`.
//!   Never negative, but a sum of positive terms: one sample can exceed 1 (reported raw).
//! - `decomposition`: the minorant is a homogeneous control medium whose transmittance
//!   `exp(-int mu_min)` is exact; delta tracking only through the residual `mu - mu_min` with
//!   rate `mu_maj - mu_min`. Lookups drop from `int mu_maj` to `int (mu_maj - mu_min)`.

use super::medium::Extinction;
use super::{Cap, Control};
use crate::rng::Rng;
use crate::traverse::Segment;
use std::ops::ControlFlow;

/// Relative slack on a segment's bounds before a lookup counts as a majorant violation: the
/// trilinear lerps are evaluated in `f32`, whose round-off can pass `max(corners)` by an ulp.
pub const BOUND_TOLERANCE: f64 = 1e-5;

/// An estimator driven by [`free_flight`].
pub(crate) trait Tracker {
    /// Control extinction `mu_c` and tentative-collision rate `r` in segment `s`.
    fn rates(&self, s: &Segment) -> (f64, f64);
    /// Entering segment `s` (control `mu_c`), before its collisions; `Break` ends the sample.
    fn enter(&mut self, _s: &Segment, _mu_c: f64) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }
    /// A tentative collision at `t` where the extinction is `mu`; `Break` ends the sample.
    fn collide(
        &mut self,
        s: &Segment,
        t: f64,
        mu: f64,
        mu_c: f64,
        rate: f64,
        rng: &mut Rng,
    ) -> ControlFlow<()>;
    /// The collision budget ran out at `t`: finish the sample with the exact optical depth of
    /// the rest of the ray (see [`Rest`]). A ratio or delta weight `w` becomes
    /// `w exp(-(rest.tau - rest.control))`: the expected value of the walk from `t` on given
    /// its state.
    fn capped(&mut self, rest: Rest);
    /// The sample's value once the walk has ended (passed the end, stopped, or capped).
    fn value(&self) -> f64;
}

/// What is left of a ray when a sample's collision budget runs out at `t` inside segment `s`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rest {
    /// Exact optical depth of `[t, end]`.
    tau: f64,
    /// Control optical depth of `[t, s.t_max]`, already applied on entering `s`.
    control: f64,
    /// Collision-rate optical depth of `[t, s.t_max]` (the majorant for next-flight).
    rate: f64,
}

impl Rest {
    /// `exp(-(tau - control))`, the transmittance of the rest beyond the control already
    /// applied (above 1 where a midpoint control overshot the extinction: the weight the
    /// walk would have regained on average).
    fn factor(self) -> f64 {
        (self.control - self.tau).exp()
    }
}

/// `mu` checked against `[mu_min, mu_maj]`: round-off is clamped, a real violation is counted
/// and returned raw.
#[inline]
fn checked(mu: f64, s: &Segment, cap: &mut Cap) -> f64 {
    if mu > s.mu_maj {
        if mu > s.mu_maj * (1.0 + BOUND_TOLERANCE) {
            debug_assert!(
                false,
                "majorant violation: mu {mu} > mu_maj {} in {s:?}",
                s.mu_maj
            );
            cap.violations += 1;
            return mu;
        }
        return s.mu_maj;
    }
    if mu < s.mu_min {
        if mu < s.mu_min * (1.0 - BOUND_TOLERANCE) {
            debug_assert!(
                false,
                "minorant violation: mu {mu} < mu_min {} in {s:?}",
                s.mu_min
            );
            cap.violations += 1;
            return mu;
        }
        return s.mu_min;
    }
    mu
}

/// Walk the tentative collisions of `tr` through `segs` (see the module docs) and return the
/// sample's value.
pub(crate) fn free_flight(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
    tr: &mut impl Tracker,
) -> f64 {
    'segments: for (i, s) in segs.iter().enumerate() {
        let (mu_c, rate) = tr.rates(s);
        if tr.enter(s, mu_c).is_break() {
            break;
        }
        if rate <= 0.0 {
            continue; // no residual: closed form, no collisions
        }
        let mut t = s.t_min;
        loop {
            t += rng.exponential(rate);
            if t >= s.t_max {
                break;
            }
            let last = !cap.take();
            let mu = checked(m.mu(t), s, cap);
            if tr.collide(s, t, mu, mu_c, rate, rng).is_break() {
                break 'segments;
            }
            if last {
                // The budget ran out here: the rest of the ray in closed form.
                cap.hit = true;
                let mut tau_rest = m.exact(t, s.t_max);
                for later in &segs[i + 1..] {
                    tau_rest += m.exact(later.t_min, later.t_max);
                }
                tr.capped(Rest {
                    tau: tau_rest,
                    control: mu_c * (s.t_max - t),
                    rate: rate * (s.t_max - t),
                });
                break 'segments;
            }
        }
    }
    tr.value()
}

/// Delta tracking: the first real collision (with probability `(mu - mu_c) / rate` per
/// tentative one) ends the walk; `score` turns its position into the sample's value.
struct Delta<F> {
    /// Control extinction is the minorant (decomposition tracking) rather than 0.
    decompose: bool,
    /// Running closed-form control transmittance (decomposition).
    w: f64,
    /// The value once a real collision happened.
    hit: Option<f64>,
    score: F,
}

impl<F: Fn(f64) -> f64> Tracker for Delta<F> {
    fn rates(&self, s: &Segment) -> (f64, f64) {
        if self.decompose {
            (s.mu_min, s.mu_maj - s.mu_min)
        } else {
            (0.0, s.mu_maj)
        }
    }
    fn enter(&mut self, s: &Segment, mu_c: f64) -> ControlFlow<()> {
        if self.decompose {
            self.w *= (-mu_c * s.length()).exp();
        }
        ControlFlow::Continue(())
    }
    fn collide(
        &mut self,
        _s: &Segment,
        t: f64,
        mu: f64,
        mu_c: f64,
        rate: f64,
        rng: &mut Rng,
    ) -> ControlFlow<()> {
        if rng.uniform() * rate < mu - mu_c {
            self.hit = Some((self.score)(t));
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    }
    fn capped(&mut self, rest: Rest) {
        // No real collision yet (a hit ends the walk before the cap): survive the rest.
        self.w *= rest.factor();
    }
    fn value(&self) -> f64 {
        self.hit.unwrap_or(self.w)
    }
}

/// Run delta tracking (`decompose`: through the residual above the minorant, whose
/// transmittance is taken in closed form) and score the first real collision with `score`.
fn delta(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
    decompose: bool,
    score: impl Fn(f64) -> f64,
) -> f64 {
    let mut tr = Delta {
        decompose,
        w: 1.0,
        hit: None,
        score,
    };
    free_flight(segs, m, rng, cap, &mut tr)
}

/// Delta tracking with the track-length estimator.
pub(crate) fn track_length(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    delta(segs, m, rng, cap, false, |_| 0.0)
}

/// Delta tracking scored with a ramp kernel of width `h` before the end.
pub(crate) fn collision(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
    h: f64,
) -> f64 {
    let Some(end) = segs.last().map(|s| s.t_max) else {
        return 1.0;
    };
    delta(segs, m, rng, cap, false, |t| {
        if h > 0.0 {
            ((t - (end - h)) / h).clamp(0.0, 1.0)
        } else {
            0.0
        }
    })
}

/// Decomposition tracking with the minorant as the control medium.
pub(crate) fn decomposition(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    delta(segs, m, rng, cap, true, |_| 0.0)
}

/// Tentative collisions a ratio weight takes deterministically before [`Weight::times`] may
/// play its factors as survival chances.
pub const ROULETTE_AFTER: u32 = 1024;

/// A ratio weight below this (after [`ROULETTE_AFTER`] collisions) has its factors played as
/// survival chances.
pub const ROULETTE_BELOW: f64 = 1e-6;

/// A ratio-tracking weight with its collision count. [`Weight::times`] multiplies it by a
/// collision's factor `f = 1 - (mu - mu_c) / r`, except that a weight already below
/// [`ROULETTE_BELOW`] after more than [`ROULETTE_AFTER`] collisions plays a factor `0 <= f <= 1`
/// as a survival chance (Russian roulette): it stays as it is with probability `f` and is 0
/// otherwise. The expected weight after the collision is `f w` either way, so the estimate
/// stays unbiased; a weight that no longer matters (a millionth of the light) stops after about
/// as many collisions as delta tracking would take, instead of walking on at the majorant's
/// rate until it underflows (a thick voxel under a huge majorant: 28x delta tracking's
/// lookups). Walks with fewer collisions, or weights that still matter, are untouched, bit for
/// bit.
#[derive(Debug, Clone, Copy)]
struct Weight {
    w: f64,
    collisions: u32,
}

impl Weight {
    fn new(w: f64) -> Self {
        Self { w, collisions: 0 }
    }

    /// The weight after a collision of factor `f` (see the type's docs); `Break` once spent.
    #[inline]
    fn times(&mut self, f: f64, rng: &mut Rng) -> ControlFlow<()> {
        self.collisions = self.collisions.saturating_add(1);
        if self.collisions > ROULETTE_AFTER
            && self.w.abs() < ROULETTE_BELOW
            && (0.0..=1.0).contains(&f)
        {
            if rng.uniform() >= f {
                self.w = 0.0;
            }
        } else {
            self.w *= f;
        }
        stop_if_spent(&mut self.w)
    }
}

/// Whether a ratio weight `w` is spent: exactly 0, below the smallest normal `f64`
/// (`2.2e-308`), or not finite. A subnormal weight is set to 0 and ends the walk: there a
/// factor `1 - mu / r` close to 1 rounds back to the same subnormal, so without this the walk
/// would go on through every later collision for nothing (a thick voxel under a huge
/// majorant: millions of lookups for a sample already at 0). Dropping a weight below
/// `2.2e-308` moves the sample by less than that.
#[inline]
fn stop_if_spent(w: &mut f64) -> ControlFlow<()> {
    if w.is_finite() && w.abs() >= f64::MIN_POSITIVE {
        return ControlFlow::Continue(());
    }
    if w.is_finite() {
        *w = 0.0;
    }
    ControlFlow::Break(())
}

/// (Residual) ratio tracking: weight `prod (1 - (mu - mu_c) / r)` times the closed-form control
/// transmittance `exp(-int mu_c)`.
struct RatioTracker {
    control: Option<Control>,
    w: Weight,
}

impl Tracker for RatioTracker {
    fn rates(&self, s: &Segment) -> (f64, f64) {
        match self.control {
            None => (0.0, s.mu_maj),
            Some(Control::Minorant) => (s.mu_min, s.mu_maj - s.mu_min),
            Some(Control::Midpoint) => (0.5 * (s.mu_min + s.mu_maj), 0.5 * (s.mu_maj - s.mu_min)),
        }
    }
    fn enter(&mut self, s: &Segment, mu_c: f64) -> ControlFlow<()> {
        // Control first: a weight that underflows to 0 stops before the residual weights
        // (which reach 2 per collision with the midpoint control) can overflow to inf * 0.
        if mu_c != 0.0 {
            self.w.w *= (-mu_c * s.length()).exp();
        }
        stop_if_spent(&mut self.w.w)
    }
    fn collide(
        &mut self,
        _s: &Segment,
        _t: f64,
        mu: f64,
        mu_c: f64,
        rate: f64,
        rng: &mut Rng,
    ) -> ControlFlow<()> {
        self.w.times(1.0 - (mu - mu_c) / rate, rng)
    }
    fn capped(&mut self, rest: Rest) {
        self.w.w *= rest.factor();
    }
    fn value(&self) -> f64 {
        self.w.w
    }
}

/// Ratio tracking.
pub(crate) fn ratio(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    let mut tr = RatioTracker {
        control: None,
        w: Weight::new(1.0),
    };
    free_flight(segs, m, rng, cap, &mut tr)
}

/// Residual ratio tracking.
pub(crate) fn residual_ratio(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
    control: Control,
) -> f64 {
    let mut tr = RatioTracker {
        control: Some(control),
        w: Weight::new(1.0),
    };
    free_flight(segs, m, rng, cap, &mut tr)
}

/// Next-flight ratio tracking: the ratio weight, plus at every tentative collision the weight
/// times the majorant transmittance to the end.
struct NextFlightTracker {
    w: Weight,
    est: f64,
    /// Majorant optical depth of the segments after the current one, kept by subtraction (no
    /// per-sample table; clamped at 0 against rounding).
    tail: f64,
}

impl Tracker for NextFlightTracker {
    fn rates(&self, s: &Segment) -> (f64, f64) {
        (0.0, s.mu_maj)
    }
    fn enter(&mut self, s: &Segment, _mu_c: f64) -> ControlFlow<()> {
        self.tail = (self.tail - s.mu_maj * s.length()).max(0.0);
        ControlFlow::Continue(())
    }
    fn collide(
        &mut self,
        s: &Segment,
        t: f64,
        mu: f64,
        _mu_c: f64,
        rate: f64,
        rng: &mut Rng,
    ) -> ControlFlow<()> {
        self.w.times(1.0 - mu / rate, rng)?;
        self.est += self.w.w * (-(rate * (s.t_max - t) + self.tail)).exp();
        ControlFlow::Continue(())
    }
    fn capped(&mut self, rest: Rest) {
        // The walk from here would add `w (T_rest - exp(-tau_maj,rest))` on average (its
        // no-collision term is the one already scored at the last collision).
        let maj_rest = self.tail + rest.rate;
        self.est += self.w.w * ((-rest.tau).exp() - (-maj_rest).exp()).max(0.0);
    }
    fn value(&self) -> f64 {
        self.est
    }
}

/// Next-flight ratio tracking.
pub(crate) fn next_flight(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    let tau_maj: f64 = segs.iter().map(|s| s.mu_maj * s.length()).sum();
    let mut tr = NextFlightTracker {
        w: Weight::new(1.0),
        est: (-tau_maj).exp(),
        tail: tau_maj,
    };
    free_flight(segs, m, rng, cap, &mut tr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Cap;
    use crate::estimate::RayMedium;
    use crate::ray::Ray;
    use crate::tree::TreeBuilder;
    use crate::volume::{Interp, Volume};

    /// A 16-voxel slab of density 2 along x, and a segment over it whose "majorant" is a
    /// deliberately wrong 1.
    fn wrong_majorant() -> (Volume, Ray, Segment) {
        let mut b = TreeBuilder::new(0.0);
        for i in 0..16 {
            b.set([i, 0, 0], 2.0);
        }
        let m = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let vol = Volume::from_tree("slab".into(), b.build(), m, 1.0).expect("valid volume");
        let ray = Ray::between([0.0, 0.0, 0.0], [15.0, 0.0, 0.0]).expect("valid ray");
        let seg = Segment {
            t_min: 1.0,
            t_max: 14.0,
            mu_min: 0.0,
            mu_maj: 1.0,
            level: 1,
        };
        (vol, ray, seg)
    }

    #[test]
    #[cfg(not(debug_assertions))]
    fn a_wrong_majorant_is_counted_not_clamped() {
        let (vol, ray, seg) = wrong_majorant();
        let mut m = RayMedium::new(&vol, &ray, Interp::Nearest);
        let mut cap = Cap::new(1_000_000);
        let mut rng = Rng::new(1, 2, 3);
        let w = ratio(&[seg], &mut m, &mut rng, &mut cap);
        assert!(cap.violations > 0, "violations {}", cap.violations);
        // Unclamped: every collision multiplies by 1 - 2/1 = -1, so |w| = 1 (clamping would
        // have given exactly 0).
        assert_eq!(w.abs(), 1.0);
    }

    #[test]
    #[cfg(debug_assertions)]
    #[should_panic(expected = "majorant violation")]
    fn a_wrong_majorant_fails_a_debug_assertion() {
        let (vol, ray, seg) = wrong_majorant();
        let mut m = RayMedium::new(&vol, &ray, Interp::Nearest);
        let mut cap = Cap::new(1_000_000);
        let mut rng = Rng::new(1, 2, 3);
        let _ = ratio(&[seg], &mut m, &mut rng, &mut cap);
    }

    #[test]
    fn roulette_keeps_ratio_tracking_unbiased() {
        // Density 2 under a valid but loose majorant of 1e4 over 1.6 voxels: ~16,000
        // collisions a sample, the weight passes a millionth (tau 13.8) after ~13,800 of them
        // and the roulette plays the rest. Without it every sample would be exactly
        // exp(-3.2) * ... = prod (1 - 2 / 1e4), the same for all: the roulette spreads them.
        let (vol, ray, mut seg) = wrong_majorant();
        seg.t_min = 2.0;
        seg.t_max = 9.0;
        seg.mu_maj = 1e4;
        let mut m = RayMedium::new(&vol, &ray, Interp::Nearest);
        for control in [None, Some(Control::Minorant)] {
            let (n, mut sum, mut sum2, mut zeros) = (2000u64, 0.0, 0.0, 0u64);
            let mut cap = Cap::new(u64::MAX);
            for i in 0..n {
                let mut rng = Rng::new(5, 0, i);
                let w = match control {
                    None => ratio(&[seg], &mut m, &mut rng, &mut cap),
                    Some(c) => residual_ratio(&[seg], &mut m, &mut rng, &mut cap, c),
                };
                sum += w;
                sum2 += w * w;
                zeros += u64::from(w == 0.0);
            }
            // T = exp(-2 * 7) = 8.3e-7 (the weight passes 1e-6 just before the end).
            let exact = (-14.0f64).exp();
            let mean = sum / n as f64;
            let var = (sum2 / n as f64 - mean * mean).max(0.0);
            let se = (var / (n - 1) as f64).sqrt();
            assert!(
                zeros > 0 && zeros < n,
                "{control:?}: roulette fired {zeros} of {n}"
            );
            assert!(
                ((mean - exact) / se).abs() < 4.0,
                "{control:?}: {mean} +- {se} vs {exact}"
            );
            assert_eq!(cap.violations, 0);
        }
    }

    #[test]
    fn a_correct_majorant_has_no_violations() {
        let (vol, ray, mut seg) = wrong_majorant();
        seg.mu_maj = 2.0;
        let mut m = RayMedium::new(&vol, &ray, Interp::Nearest);
        let mut cap = Cap::new(1_000_000);
        for i in 0..100 {
            let mut rng = Rng::new(1, 2, i);
            let _ = next_flight(&[seg], &mut m, &mut rng, &mut cap);
            let _ = decomposition(&[seg], &mut m, &mut rng, &mut cap);
        }
        assert_eq!(cap.violations, 0);
    }
}
