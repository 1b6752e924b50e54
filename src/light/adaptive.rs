//! How many directions a receiver toward a light with extent traces, and its answer and error
//! bar from them.
//!
//! **The answer and its error bar** ([`SoftRays::combine`]). The mean over every direction
//! (weighted for an area light); `std_err = s_R / sqrt(R)`, `s_R` the standard deviation of the
//! `R` replicate means. Each replicate is an independently rotated lattice, so the replicate
//! means are independent and unbiased for `T_L`; under normality the mean is beyond 4 error
//! bars 0.12% of the time at `R = 16` ([`REPLICATES`]). With at least [`MIN_POINTS`] points per
//! replicate they are close enough to normal (docs/lights.md). Two floors:
//! - every direction gave exactly the same `T0`: the spread is 0 and could hide a feature
//!   between the points. A fraction `p <= min(1, 3 / N)` of the cone (the rule of three, as for
//!   independent points) may differ by up to `max(T0, 1 - T0)`: `std_err = max(T0, 1 - T0)
//!   sqrt(p / N)`, never 0;
//! - the spread is below the rounding of each direction's `T` ([`ROUNDING`] of the answer): it
//!   measures the arithmetic, not the light, and the error bar is that rounding.
//!
//! **The count: Stein's two-stage rule** ([`final_points`]). Stopping when an error bar looks
//! small biases it low; so a pilot of `R x n0` points ([`PILOT_POINTS`], its own rotations)
//! only chooses the count, and `R` fresh replicates of `n` points each give the answer and its
//! error bar (the pilot is not mixed in: the error bar is the fresh replicates', unbiased).
//! With the pilot's error bar `e0`, taking the variance of a replicate mean to fall as
//! `n^-a` ([`VARIANCE_RATE`] `a = 1.5`: indicator-like integrands, a cone crossed by density
//! edges), the final error bar is about `e0 (n0 / n)^(a / 2)` times the square root of an
//! `F(R - 1, R - 1)` variable (the ratio of two independent variance estimates). So
//! `n = ceil(n0 (F99 e0^2 / E^2)^(1 / a))` puts `>= 99%` of final error bars at or below
//! the target `E` where the rate holds ([`SAFETY`] is `F_0.99(15, 15)`); the error bar itself is
//! the fresh replicates', honest whatever `n` the rate chose. Clamped to `[MIN_POINTS, cap]`; a
//! receiver whose `n` the cap cut is counted ([`super::SoftAnswer::light_capped`]). A pilot whose
//! directions all agree exactly, or half of whose directions sit exactly at one end of its
//! range (rays that meet no density give exactly 1), asks for at least the `N` at which the
//! final stage's rule-of-three floor, should its directions all agree, is `E`:
//! `N >= sqrt(3) max(T0, 1 - T0) / E`.

use super::extent::{SoftRays, MIN_POINTS, REPLICATES};
use crate::scene::SceneEstimate;

/// Points per replicate of the pilot stage.
pub const PILOT_POINTS: u32 = 4;
/// The fewest directions a receiver toward a light with extent can take under a target error:
/// the pilot and the least final stage.
pub const LEAST_ADAPTIVE: u32 = REPLICATES * (PILOT_POINTS + MIN_POINTS);
/// `F_0.99(R - 1, R - 1)` at `R = 16`: the 99th percentile of the ratio of two independent
/// 15-degree-of-freedom variance estimates.
pub const SAFETY: f64 = 3.52;
/// The rate the variance of a replicate mean of `n` points is taken to fall at, `n^-1.5` (a
/// rotated lattice over a cone crossed by density edges: indicator-like integrands, docs/lights.md).
pub const VARIANCE_RATE: f64 = 1.5;
/// The relative rounding of a direction's `T` below which a spread is not a measurement:
/// `2^-40`.
pub const ROUNDING: f64 = 1.0 / 1_099_511_627_776.0;

/// The points per replicate of the final stage after the pilot `per` (its directions'
/// estimates) whose answer is `pilot`, to reach `target` (module docs), at most `cap`; and
/// whether the cap cut it.
#[must_use]
pub fn final_points(
    per: &[SceneEstimate],
    pilot: &SceneEstimate,
    channels: usize,
    target: f64,
    cap: u32,
) -> (u32, bool) {
    let r = f64::from(REPLICATES);
    let mut need = f64::from(MIN_POINTS);
    for c in 0..channels.clamp(1, 3) {
        let (lo, hi) = per
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
                (a.min(e.value[c]), b.max(e.value[c]))
            });
        let t = pilot.value[c];
        // At least half the pilot's directions exactly at one end (rays that meet no density
        // give exactly 1): the final stage may agree exactly, and its rule-of-three floor must
        // then be at the target too.
        let at = |x: f64| per.iter().filter(|e| e.value[c] == x).count();
        let ties = 2 * at(lo).max(at(hi)) >= per.len();
        let floor = crate::estimate::error_bar::RULE_OF_THREE.sqrt() * t.max(1.0 - t) / target;
        let floor = (floor / r).ceil();
        let spread = (f64::from(PILOT_POINTS)
            * (SAFETY * (pilot.std_err[c] / target).powi(2)).powf(VARIANCE_RATE.recip()))
        .ceil();
        let n = match (lo == hi, ties) {
            (true, _) => floor,
            (false, true) => spread.max(floor),
            (false, false) => spread,
        };
        // NaN (a NaN estimate) asks for the cap.
        need = if n.is_nan() {
            f64::INFINITY
        } else {
            need.max(n)
        };
    }
    let cap = cap.max(MIN_POINTS);
    if need > f64::from(cap) {
        (cap, true)
    } else {
        // `need` is a whole number in [MIN_POINTS, cap]: the cast is exact.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        (need as u32, false)
    }
}

impl SoftRays {
    /// The answer at one receiver from its directions' estimates, in the order of
    /// [`SoftRays::rays`]: per channel the mean over every direction, the error bar from the
    /// replicates' spread with its floors (module docs). No direction: the cone missed everything, `T = 1`.
    #[must_use]
    pub fn combine(&self, channels: usize, per: &[SceneEstimate]) -> SceneEstimate {
        let mut out = SceneEstimate::exact(channels, [0.0; 3], 0, 0);
        out.tau = None;
        if per.is_empty() {
            out.value = [1.0; 3];
            return out;
        }
        let n = per.len();
        let weight = |i: usize| self.weights.get(i).copied().unwrap_or(1.0);
        for c in 0..3 {
            // Per replicate: the weighted sum of T and the weights' sum.
            let mut start = 0;
            let mut sums = Vec::with_capacity(self.ends.len());
            for &end in &self.ends {
                let end = end.min(n);
                let (wt, w) = (start..end).fold((0.0, 0.0), |(wt, w), i| {
                    (wt + weight(i) * per[i].value[c], w + weight(i))
                });
                sums.push((wt, w));
                start = end;
            }
            let total = sums.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            let means: Vec<f64> = sums
                .iter()
                .filter(|(_, w)| *w > 0.0)
                .map(|(wt, w)| wt / w)
                .collect();
            let mean = if self.weights.is_empty() {
                // Equal replicates: the mean of their means.
                means.iter().sum::<f64>() / means.len().max(1) as f64
            } else {
                total.0 / total.1
            };
            let r = means.len() as f64;
            let centre = means.iter().sum::<f64>() / r.max(1.0);
            let var = means.iter().map(|x| (x - centre).powi(2)).sum::<f64>() / (r - 1.0).max(1.0);
            let (lo, hi) = per
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
                    (a.min(e.value[c]), b.max(e.value[c]))
                });
            out.value[c] = mean;
            out.std_err[c] = if lo == hi {
                let p = (crate::estimate::error_bar::RULE_OF_THREE / n as f64).min(1.0);
                mean.max(1.0 - mean) * (p / n as f64).sqrt()
            } else if means.len() < 2 {
                // One replicate saw the light: no spread to measure, the widest bar.
                mean.max(1.0 - mean)
            } else {
                (var / r).sqrt().max(ROUNDING * mean.abs())
            };
        }
        out.lookups = per.iter().map(|e| e.lookups).sum();
        out.segments = per.iter().map(|e| e.segments).sum();
        out.samples = per.iter().map(|e| e.samples).max().unwrap_or(1);
        out.capped = per.iter().map(|e| e.capped).sum();
        out.majorant_violations = per.iter().map(|e| e.majorant_violations).sum();
        out
    }
}
