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
//! **The count: Stein's two-stage rule** ([`replicates_for`], [`stein`]). Stopping when an
//! error bar looks small biases it low; Stein's rule (1945) does not. Every replicate of a
//! target error's stage is the same 4-point lattice ([`PILOT_POINTS`]) under an independent
//! rotation, so replicate means are independent and identically distributed. The pilot's `R0
//! = 16` replicates give `s0`, the standard deviation of their means; the receiver then takes
//! `n = max(R0, ceil(s0^2 / E^2))` replicates in all (the pilot's and `n - R0` more), and
//! reports the mean of all `n` with the error bar `s0 / sqrt(n)`: at or below the target `E`
//! by construction. Under normality `(mean - T_L) / (s0 / sqrt(n))` is exactly Student's `t`
//! with 15 degrees of freedom whatever `n` the pilot chose (the pilot's mean and its `s0` are
//! independent, and the extra replicates are independent of both), so the answer is beyond 4
//! error bars 0.12% of the time; the error bar is never re-estimated from the replicates the
//! count chose. A receiver whose pilot already meets the target traces the pilot alone (64
//! directions). Capped at `light-max-samples / 4` replicates; a receiver whose `n` the cap cut
//! is counted ([`super::SoftAnswer::light_capped`]), its error bar still `s0 / sqrt(n)`. A pilot
//! that is not normal ([`normal`]: its directions all agree exactly; or half of them sit
//! exactly at one end of its range, rays that meet no density giving exactly 1; or one
//! replicate holds more than half of the replicates' sum of squares, a cone whose few bright
//! directions fell in one replicate: a spread of outliers, far from normal) asks for at least
//! the `N` at which the rule-of-three floor is `E`: `N >= sqrt(3) max(T0, 1 - T0) / E`
//! directions. Its `s0` is not trusted: its answer's error bar is the spread of all `n`
//! replicates (or, if they all agree too, the rule-of-three floor over every direction), `n`
//! being at least that floor's count, which depends on `T0` alone. When that spread puts the
//! error bar above `E`, the pilot and its extras together (`n1` replicates, at least the
//! floor's count, where the mean of replicates is much nearer normal) are the pilot of one
//! more Stein stage ([`stein_again`]): `n2 = ceil(n1 s1^2 / E^2)` replicates in all, the error
//! bar `s1 / sqrt(n2)` (`s1` the spread of the `n1`), so a receiver ends above the target only
//! when the cap cut its count, and is then counted.

use super::extent::{SoftRays, REPLICATES};
use crate::scene::SceneEstimate;

/// Points per replicate under a target error (the pilot's and every extra replicate's).
pub const PILOT_POINTS: u32 = 4;
/// The fewest directions a receiver toward a light with extent can take under a target error:
/// the pilot.
pub const LEAST_ADAPTIVE: u32 = REPLICATES * PILOT_POINTS;
/// The relative rounding of a direction's `T` below which a spread is not a measurement:
/// `2^-40`.
pub const ROUNDING: f64 = 1.0 / 1_099_511_627_776.0;

/// A receiver's directions' estimates, in the order traced, and where each replicate ends
/// among them (a replicate of an area light may hold fewer than [`PILOT_POINTS`]: points
/// facing away are dropped).
#[derive(Debug, Clone, Copy)]
pub struct Traced<'a> {
    per: &'a [SceneEstimate],
    ends: &'a [usize],
}

impl<'a> Traced<'a> {
    /// The estimates `per` whose replicates end at `ends` (indices past `per` are ignored).
    #[must_use]
    pub fn new(per: &'a [SceneEstimate], ends: &'a [usize]) -> Self {
        Self { per, ends }
    }

    /// The first `k` directions and the replicates that end within them.
    #[must_use]
    pub fn head(self, k: usize) -> Self {
        let k = k.min(self.per.len());
        let n = self.ends.iter().take_while(|&&e| e <= k).count();
        Self {
            per: &self.per[..k],
            ends: &self.ends[..n],
        }
    }

    /// The directions' estimates.
    #[must_use]
    pub fn per(self) -> &'a [SceneEstimate] {
        self.per
    }

    /// Channel `c`'s unweighted mean of each replicate that holds a direction.
    fn means(self, c: usize) -> Vec<f64> {
        replicate_sums(self.per, self.ends, c, |_| 1.0)
            .into_iter()
            .filter(|(_, w)| *w > 0.0)
            .map(|(wt, w)| wt / w)
            .collect()
    }
}

/// Per replicate of `per` (ending at `ends`; indices past `per` are ignored), channel `c`'s
/// weighted sum of `T` and the sum of its weights (`weight(i)` of direction `i`).
fn replicate_sums(
    per: &[SceneEstimate],
    ends: &[usize],
    c: usize,
    weight: impl Fn(usize) -> f64,
) -> Vec<(f64, f64)> {
    let mut start = 0;
    let mut sums = Vec::with_capacity(ends.len());
    for &end in ends {
        let end = end.min(per.len());
        let (wt, w) = (start..end).fold((0.0, 0.0), |(wt, w), i| {
            (wt + weight(i) * per[i].value[c], w + weight(i))
        });
        sums.push((wt, w));
        start = end;
    }
    sums
}

/// The replicates in all (the pilot's included, at least `r0`) a receiver takes after the
/// pilot `traced` (its directions' estimates, `r0` replicates) whose answer is `pilot`, to
/// reach `target` (module docs), at most `cap`; and whether the cap cut it.
#[must_use]
pub fn replicates_for(
    traced: Traced<'_>,
    (pilot, r0): (&SceneEstimate, u32),
    channels: usize,
    target: f64,
    cap: u32,
) -> (u32, bool) {
    let r = f64::from(r0);
    let mut need = r;
    for c in 0..channels.clamp(1, 3) {
        let (lo, hi) = span(traced.per, c);
        let t = pilot.value[c];
        // A pilot that is not normal: the rule-of-three count at the least.
        let lumpy = !normal(traced, c);
        let floor = crate::estimate::error_bar::RULE_OF_THREE.sqrt() * t.max(1.0 - t) / target;
        let floor = (floor / f64::from(PILOT_POINTS)).ceil();
        // `s0^2 / E^2` with `s0 = sqrt(R0) e0`.
        let spread = (r * (pilot.std_err[c] / target).powi(2)).ceil();
        let n = match (lo == hi, lumpy) {
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
    let cap = cap.max(r0);
    if need > f64::from(cap) {
        (cap, true)
    } else {
        // `need` is a whole number in [REPLICATES, cap]: the cast is exact.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        (need as u32, false)
    }
}

/// The lowest and highest value of channel `c` over `per`.
fn span(per: &[SceneEstimate], c: usize) -> (f64, f64) {
    per.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
            (a.min(e.value[c]), b.max(e.value[c]))
        })
}

/// Stein's answer (module docs): `all`, the combined answer of every replicate (the pilot's
/// `r0` and the `n - r0` extra), keeps its mean; its error bar becomes the pilot's `s0 /
/// sqrt(n)` (`pilot` is the pilot's answer, `pilot_traced` its directions' estimates), never
/// below the rounding of the answer. A channel whose pilot was not [`normal`] keeps `all`'s
/// own (the spread of every replicate).
#[must_use]
pub fn stein(
    pilot_traced: Traced<'_>,
    pilot: (&SceneEstimate, u32),
    all: SceneEstimate,
    n: u32,
) -> SceneEstimate {
    scaled(pilot_traced, pilot, all, n, normal)
}

/// Stein's answer of a second stage ([`stein`]), whose pilot is every replicate the first
/// stage took (at least the rule-of-three count, module docs): its spread scales the error bar
/// wherever its directions disagree, normal or not.
#[must_use]
pub fn stein_again(
    pilot_traced: Traced<'_>,
    pilot: (&SceneEstimate, u32),
    all: SceneEstimate,
    n: u32,
) -> SceneEstimate {
    scaled(pilot_traced, pilot, all, n, spread)
}

/// `all` with the error bar `s0 / sqrt(n)` of the pilot on the channels `fit` accepts.
fn scaled(
    pilot_traced: Traced<'_>,
    (pilot, r0): (&SceneEstimate, u32),
    mut all: SceneEstimate,
    n: u32,
    fit: fn(Traced<'_>, usize) -> bool,
) -> SceneEstimate {
    let scale = (f64::from(r0) / f64::from(n.max(r0))).sqrt();
    for c in 0..3 {
        if fit(pilot_traced, c) {
            all.std_err[c] = (pilot.std_err[c] * scale).max(ROUNDING * all.value[c].abs());
        }
    }
    all
}

/// True when the directions of `traced` disagree on channel `c`.
#[must_use]
pub fn spread(traced: Traced<'_>, c: usize) -> bool {
    let (lo, hi) = span(traced.per, c);
    lo < hi
}

/// The share of the replicates' sum of squares one replicate may hold before a pilot is
/// called lumpy: `G^2 / (R - 1)` for Grubbs' statistic `G = max |m_i - m| / s`; at `R = 16`,
/// 0.5 is `G = 2.74`, which normal replicate means pass about 98% of the time.
pub const OUTLIER_SHARE: f64 = 0.5;

/// True when the replicates of `traced` are fit for Stein's rule on channel `c`: their
/// directions disagree, fewer than half of them sit exactly at one end of their range (rays
/// that meet no density give exactly 1), and no replicate mean (unweighted: a test, not an
/// estimate) holds more than [`OUTLIER_SHARE`] of the replicates' sum of squares (a cone whose
/// few bright or dark directions fell in one replicate: a spread of outliers, far from normal,
/// which Student's `t` does not cover). A pilot that is not normal takes at least the
/// rule-of-three count, and its error bar is the spread of every replicate it took (module
/// docs).
#[must_use]
pub fn normal(traced: Traced<'_>, c: usize) -> bool {
    let per = traced.per;
    let (lo, hi) = span(per, c);
    if lo >= hi {
        return false;
    }
    let at = |x: f64| per.iter().filter(|e| e.value[c] == x).count();
    if 2 * at(lo).max(at(hi)) >= per.len() {
        return false;
    }
    let means = traced.means(c);
    let m = means.iter().sum::<f64>() / means.len().max(1) as f64;
    let (most, all) = means.iter().fold((0.0f64, 0.0), |(most, all), x| {
        let d = (x - m).powi(2);
        (most.max(d), all + d)
    });
    most <= OUTLIER_SHARE * all
}

/// True when some channel of `answer` (`channels` of them) whose pilot `pilot_traced` was
/// not [`normal`] has an error bar above `target`: the spread of all its replicates asks
/// for a stage more (module docs).
#[must_use]
pub fn recount(
    pilot_traced: Traced<'_>,
    answer: &SceneEstimate,
    channels: usize,
    target: f64,
) -> bool {
    (0..channels.clamp(1, 3)).any(|c| !normal(pilot_traced, c) && answer.std_err[c] > target)
}

impl SoftRays {
    /// The answer at one receiver from its directions' estimates, in the order of
    /// [`SoftRays::rays`]: per channel the mean over every direction, the error bar from the
    /// replicates' spread with its floors (module docs). No direction: the cone missed everything, `T = 1`.
    #[must_use]
    pub fn combine(&self, channels: usize, per: &[SceneEstimate]) -> SceneEstimate {
        combine(&self.weights, &self.ends, channels, per)
    }
}

/// [`SoftRays::combine`] of directions whose weights are `weights` (empty: all equal) and
/// whose replicates end at `ends` in `per`.
#[must_use]
pub fn combine(
    weights: &[f64],
    ends: &[usize],
    channels: usize,
    per: &[SceneEstimate],
) -> SceneEstimate {
    let mut out = SceneEstimate::exact(channels, [0.0; 3], 0, 0);
    out.tau = None;
    if per.is_empty() {
        out.value = [1.0; 3];
        return out;
    }
    let n = per.len();
    let weight = |i: usize| weights.get(i).copied().unwrap_or(1.0);
    for c in 0..3 {
        // Per replicate: the weighted sum of T and the weights' sum.
        let sums = replicate_sums(per, ends, c, weight);
        let total = sums.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        let means: Vec<f64> = sums
            .iter()
            .filter(|(_, w)| *w > 0.0)
            .map(|(wt, w)| wt / w)
            .collect();
        let mean = if weights.is_empty() {
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
