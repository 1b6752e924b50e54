//! Deep shadow samples from an optical-depth profile: the piecewise fit of Lokovic and Veach
//! (2000), in optical depth, for OpenEXR volumetric deep samples.
//!
//! An OpenEXR volumetric sample `[Z, ZBack]` with alpha `A` lets light through as
//! `T(z) = (1 - A)^((z - Z) / (ZBack - Z))` inside it ("Interpreting OpenEXR Deep Pixels"):
//! optical depth grows **linearly** across it, `tau(z) = tau0 + (tau1 - tau0) (z - Z) /
//! (ZBack - Z)` with `A = 1 - exp(-(tau1 - tau0))`, samples composite front to back, and T is
//! constant between samples. So a pixel's deep data is a continuous, piecewise-linear
//! `tau_fit(z)`, and a fit is good when `|exp(-tau_fit(z)) - exp(-tau(z))| <= E` at **every**
//! depth.
//!
//! [`fit_profile`] takes the exact profile as breakpoints `(t_k, tau_k)` with `tau` linear
//! between them (exact for nearest lookups, where each voxel is a constant extinction; finer
//! breakpoints approximate trilinear cells) and greedily makes each sample as long as it can:
//! from breakpoint `i` it extends the chord to the farthest breakpoint `j` for which the error
//! stays within `E` on every interval `[t_k, t_k+1]` in between. On one interval both
//! `tau_fit` (slope `a'`) and `tau` (slope `b'`) are linear, so `g = exp(-tau_fit) -
//! exp(-tau)` has at most one interior extremum, where `a' exp(-tau_fit) = b' exp(-tau)`, i.e.
//! `tau_fit - tau = ln(a' / b')`: the check at both ends and there is exact, not sampled.
//! Intervals where `tau` does not grow need no sample. Samples share their end points with the
//! profile, so the fit is continuous and never drifts.

use crate::error::{Error, Result};

/// One volumetric deep sample: optical depth grows linearly from `tau0` at depth `z0` to
/// `tau1` at `z1` (alpha `1 - exp(-(tau1 - tau0))`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeepSample {
    /// Front depth (`Z`).
    pub z0: f64,
    /// Back depth (`ZBack`).
    pub z1: f64,
    /// Optical depth from the ray's start to `z0`.
    pub tau0: f64,
    /// Optical depth from the ray's start to `z1`.
    pub tau1: f64,
}

impl DeepSample {
    /// The sample's OpenEXR alpha, `1 - exp(-(tau1 - tau0))`.
    #[must_use]
    pub fn alpha(&self) -> f64 {
        -(-(self.tau1 - self.tau0)).exp_m1()
    }
}

/// The transmittance the samples describe at depth `z`: `exp(-tau_fit(z))`, with `tau_fit`
/// linear inside each sample and constant between them (0 before the first).
#[must_use]
pub fn fitted_transmittance(samples: &[DeepSample], z: f64) -> f64 {
    (-samples_tau(samples.iter().map(|s| (s.z0, s.z1, s.tau0, s.tau1)), z)).exp()
}

/// `tau_fit(z)` of sorted samples `(z0, z1, tau0, tau1)`: linear inside each, constant between
/// them, 0 before the first (what [`fitted_transmittance`] exponentiates).
pub(crate) fn samples_tau(samples: impl Iterator<Item = (f64, f64, f64, f64)>, z: f64) -> f64 {
    let mut tau = 0.0;
    for (z0, z1, tau0, tau1) in samples {
        if z >= z1 {
            tau = tau1;
        } else if z > z0 {
            tau = tau0 + (tau1 - tau0) * (z - z0) / (z1 - z0);
            break;
        } else {
            break;
        }
    }
    tau
}

/// `y` at `x` on the breakpoints `(xs_k, ys_k)` (`xs` sorted): linear between them, constant
/// outside; at a repeated breakpoint (a jump) the value after it.
pub(crate) fn linear_at(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    let n = xs.len();
    let k = xs.partition_point(|&v| v <= x);
    if n == 0 {
        return 0.0;
    }
    if k == 0 {
        return ys[0];
    }
    if k == n {
        return ys[n - 1];
    }
    let (x0, x1) = (xs[k - 1], xs[k]);
    let w = if x1 > x0 {
        ((x - x0) / (x1 - x0)).clamp(0.0, 1.0)
    } else {
        1.0
    };
    ys[k - 1] + (ys[k] - ys[k - 1]) * w
}

/// The largest `|exp(-a(t)) - exp(-b(t))|` over `[t0, t1]` for `a` linear from `a0` to `a1`
/// and `b` linear from `b0` to `b1`: at the ends, or where the derivative vanishes.
/// The default bound on `|T_deep(z) - T(z)|` (`--deep-error`).
pub const DEFAULT_DEEP_ERROR: f64 = 0.002;

/// Check a deep error bound.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `deep-error`) outside `(0, 1)`.
pub fn check_deep_error(max_error: f64) -> Result<()> {
    if max_error > 0.0 && max_error < 1.0 {
        return Ok(());
    }
    Err(Error::InvalidArgument {
        name: "deep-error".into(),
        reason: format!("{max_error}: an error bound between 0 and 1 (in T)"),
    })
}

#[cfg(test)]
fn max_gap(t0: f64, t1: f64, (a0, a1): (f64, f64), (b0, b1): (f64, f64)) -> f64 {
    gap_within(t0, t1, (a0, a1), (b0, b1), 0.0, (0.0, 1.0))
}

/// [`max_gap`], or a bound on it no larger than `enough` when that settles the question
/// without transcendentals: with `a, b >= floor` on the interval, `|exp(-a) - exp(-b)| <=
/// exp(-floor) |a - b|`, and `a - b` is linear, so largest at an end. `decay` is
/// `exp(-floor)`, computed once per chord by the caller.
fn gap_within(
    t0: f64,
    t1: f64,
    (a0, a1): (f64, f64),
    (b0, b1): (f64, f64),
    enough: f64,
    (floor, decay): (f64, f64),
) -> f64 {
    let cheap = decay * (a0 - b0).abs().max((a1 - b1).abs());
    if cheap <= enough && a0.min(a1).min(b0).min(b1) >= floor {
        return cheap;
    }
    let g = |a: f64, b: f64| ((-a).exp() - (-b).exp()).abs();
    let mut worst = g(a0, b0).max(g(a1, b1));
    let len = t1 - t0;
    if len > 0.0 {
        let (da, db) = ((a1 - a0) / len, (b1 - b0) / len);
        // a' exp(-a) = b' exp(-b)  <=>  a - b = ln(a' / b'), with a - b linear in t.
        if da > 0.0 && db > 0.0 && da != db {
            let target = (da / db).ln();
            let s = (target - (a0 - b0)) / (da - db); // distance from t0
            if s > 0.0 && s < len {
                worst = worst.max(g(a0 + da * s, b0 + db * s));
            }
        }
    }
    worst
}

/// Fit deep samples to the profile `tau(t_k) = tau[k]` (see the module docs): the fewest the
/// greedy chord rule gives with `|T_fit(z) - T(z)| <= max_error` at every depth `z` in
/// `[t_0, t_n]`.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `deep-error`) for `max_error` outside `(0, 1)`, (name
/// `deep`) for profiles of different lengths, non-finite values, depths that decrease or
/// optical depths that do.
pub fn fit_profile(t: &[f64], tau: &[f64], max_error: f64) -> Result<Vec<DeepSample>> {
    Ok(fit_spans(t, &[tau], max_error)?
        .into_iter()
        .map(|(i, j)| DeepSample {
            z0: t[i],
            z1: t[j],
            tau0: tau[i],
            tau1: tau[j],
        })
        .collect())
}

/// [`fit_profile`] for several channels sharing the depths `t` (R, G, B and A of a colour
/// map): the samples as breakpoint index pairs `(i, j)` (sample `[t_i, t_j]`, each channel's
/// optical depth linear from `taus[c][i]` to `taus[c][j]`), every channel within
/// `max_error` at every depth. A span ends where every channel is flat.
///
/// The search for a sample's end gallops (`j = i + 1, i + 2, i + 4, ...` while the chord
/// fits), then bisects between the last fit and the first miss, so a sample of `L`
/// breakpoints costs `O(L log L)` checks; each accepted chord is checked on every interval it
/// spans.
///
/// # Errors
/// As [`fit_profile`], for any channel; also (name `deep`) for no channel.
pub fn fit_spans(t: &[f64], taus: &[&[f64]], max_error: f64) -> Result<Vec<(usize, usize)>> {
    check_deep_error(max_error)?;
    check_profile(t, taus)?;
    Ok(greedy_fit(t, taus, max_error, usize::MAX)
        .map(|f| f.spans)
        .unwrap_or_default())
}

/// Check a profile for [`fit_spans`].
///
/// # Errors
/// As [`fit_profile`] (name `deep`), for any channel; also for no channel.
pub(crate) fn check_profile(t: &[f64], taus: &[&[f64]]) -> Result<()> {
    let bad = |reason: &str| Error::InvalidArgument {
        name: "deep".into(),
        reason: reason.into(),
    };
    if taus.is_empty() {
        return Err(bad("a profile needs at least one channel"));
    }
    for tau in taus {
        if t.len() != tau.len() {
            return Err(bad(
                "the profile's depths and optical depths differ in number",
            ));
        }
        if t.iter().chain(tau.iter()).any(|v| !v.is_finite()) {
            return Err(bad("the profile holds a value that is not finite"));
        }
        if t.windows(2).any(|w| w[1] < w[0]) || tau.windows(2).any(|w| w[1] < w[0]) {
            return Err(bad(
                "the profile's depths and optical depths must not decrease",
            ));
        }
    }
    Ok(())
}

/// A greedy fit ([`greedy_fit`]): its spans, and the largest gap any accepted chord check
/// returned.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GreedyFit {
    /// The samples as breakpoint index pairs, as [`fit_spans`] returns them.
    pub(crate) spans: Vec<(usize, usize)>,
    /// The largest value an accepted check's [`gap_within`] returned. Every check the fit
    /// made has the same outcome for any bound in `[level, max_error]`, so the fit at such a
    /// bound is this one (a rejected check's gap was computed exactly and exceeds
    /// `max_error`; an accepted one's is at most `level`).
    pub(crate) level: f64,
}

/// The greedy chord fit of [`fit_spans`] on a profile [`check_profile`] accepted, `max_error`
/// in `(0, 1)`; `None` as soon as its nodes (each span's two ends, shared where spans touch)
/// exceed `max_nodes`.
pub(crate) fn greedy_fit(
    t: &[f64],
    taus: &[&[f64]],
    max_error: f64,
    max_nodes: usize,
) -> Option<GreedyFit> {
    let n = t.len();
    let flat = |k: usize| taus.iter().all(|tau| tau[k + 1] == tau[k]);
    // The chord from breakpoint i to j fits when every channel does on every interval: the
    // largest gap checked, or None.
    let fits = |i: usize, j: usize| -> Option<f64> {
        let span = (t[j] - t[i]).max(f64::MIN_POSITIVE);
        let mut level = 0.0f64;
        for tau in taus {
            let slope = (tau[j] - tau[i]) / span;
            let chord = |x: f64| tau[i] + slope * (x - t[i]);
            // Chord and profile both start at tau[i] and never decrease.
            let floor = (tau[i], (-tau[i]).exp());
            for k in i..j {
                let g = gap_within(
                    t[k],
                    t[k + 1],
                    (chord(t[k]), chord(t[k + 1])),
                    (tau[k], tau[k + 1]),
                    max_error,
                    floor,
                );
                // A NaN gap fails, as it always has.
                if g.is_nan() || g > max_error {
                    return None;
                }
                level = level.max(g);
            }
        }
        Some(level)
    };
    let mut level = 0.0f64;
    let mut check = |i: usize, j: usize| match fits(i, j) {
        Some(l) => {
            level = level.max(l);
            true
        }
        None => false,
    };
    let mut out: Vec<(usize, usize)> = Vec::new();
    let mut nodes = 0usize;
    let mut i = 0;
    while i + 1 < n {
        if flat(i) {
            i += 1;
            continue;
        }
        // Gallop: `good` fits (a single interval always does: the chord is the profile),
        // `bad` (if any) does not.
        let (mut good, mut step) = (i + 1, 1);
        let mut miss = None;
        while good + 1 < n {
            let j = (good + step).min(n - 1);
            if check(i, j) {
                good = j;
                step *= 2;
            } else {
                miss = Some(j);
                break;
            }
        }
        if let Some(mut hi) = miss {
            while hi - good > 1 {
                let mid = good + (hi - good) / 2;
                if check(i, mid) {
                    good = mid;
                } else {
                    hi = mid;
                }
            }
        }
        // Trailing flat intervals belong to no sample when the steeper chord still fits.
        let mut j = good;
        while j > i + 1 && taus.iter().all(|tau| tau[j] == tau[j - 1]) {
            j -= 1;
        }
        if j < good && !check(i, j) {
            j = good;
        }
        nodes += if out.last().is_some_and(|s| s.1 == i) {
            1
        } else {
            2
        };
        if nodes > max_nodes {
            return None;
        }
        out.push((i, j));
        i = j;
    }
    Some(GreedyFit { spans: out, level })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A random non-decreasing profile with flat gaps, thick and thin stretches.
    fn profile(seed: u64, n: usize) -> (Vec<f64>, Vec<f64>) {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut t, mut tau) = (vec![0.0], vec![0.0]);
        for _ in 1..n {
            let dt = 0.05 + next();
            let r = next();
            let mu = if r < 0.3 {
                0.0
            } else if r < 0.9 {
                0.5 * next()
            } else {
                8.0 * next()
            };
            t.push(t.last().unwrap() + dt);
            tau.push(tau.last().unwrap() + mu * dt);
        }
        (t, tau)
    }

    /// The exact T of the profile at `z` (linear tau between breakpoints).
    fn exact(t: &[f64], tau: &[f64], z: f64) -> f64 {
        let k = t.partition_point(|x| *x <= z).clamp(1, t.len() - 1);
        let f = ((z - t[k - 1]) / (t[k] - t[k - 1])).clamp(0.0, 1.0);
        (-(tau[k - 1] + f * (tau[k] - tau[k - 1]))).exp()
    }

    #[test]
    fn fits_stay_within_the_bound_at_every_depth() {
        for seed in 0..40 {
            let (t, tau) = profile(seed, 200);
            for e in [0.02, 0.002, 1e-4] {
                let s = fit_profile(&t, &tau, e).unwrap();
                let end = *t.last().unwrap();
                for q in 0..=20_000 {
                    let z = end * f64::from(q) / 20_000.0;
                    let d = (fitted_transmittance(&s, z) - exact(&t, &tau, z)).abs();
                    assert!(
                        d <= e * (1.0 + 1e-9) + 1e-15,
                        "seed {seed} E {e}: {d} at {z}"
                    );
                }
                // The end and every sample boundary lie on the profile.
                assert!(
                    (fitted_transmittance(&s, end) - (-tau.last().unwrap()).exp()).abs() < 1e-15
                );
                assert!(s.windows(2).all(|w| w[0].z1 <= w[1].z0));
            }
        }
    }

    #[test]
    fn greedy_fits_are_the_same_fit_between_their_level_and_their_bound() {
        for seed in 0..20 {
            let (t, tau) = profile(seed, 300);
            for e in [0.3, 0.05, 0.01, 1e-3] {
                let f = greedy_fit(&t, &[&tau], e, usize::MAX).unwrap();
                assert_eq!(f.spans, fit_spans(&t, &[&tau], e).unwrap());
                assert!(f.level <= e);
                let mid = (f.level.max(1e-9) * e).sqrt().max(f.level);
                for e2 in [f.level.max(1e-9), mid] {
                    let g = greedy_fit(&t, &[&tau], e2, usize::MAX).unwrap();
                    assert_eq!(g.spans, f.spans, "seed {seed} e {e} -> {e2}");
                }
                // A cap below the fit's nodes refuses it; at its nodes it passes.
                let mut nodes = 0;
                for (k, s) in f.spans.iter().enumerate() {
                    nodes += if k > 0 && f.spans[k - 1].1 == s.0 {
                        1
                    } else {
                        2
                    };
                }
                assert!(greedy_fit(&t, &[&tau], e, nodes).is_some());
                if nodes > 0 {
                    assert!(greedy_fit(&t, &[&tau], e, nodes - 1).is_none());
                }
            }
        }
    }

    #[test]
    fn looser_bounds_need_fewer_samples() {
        // Thin enough that light reaches the end (T about 0.2 there), so every stretch counts.
        let (t, tau) = profile(7, 400);
        let tau: Vec<f64> = tau.iter().map(|v| v * 1.6 / tau[tau.len() - 1]).collect();
        let counts: Vec<usize> = [1e-5, 1e-3, 0.01, 0.1]
            .iter()
            .map(|e| fit_profile(&t, &tau, *e).unwrap().len())
            .collect();
        assert!(counts.windows(2).all(|w| w[1] <= w[0]), "{counts:?}");
        assert!(counts[3] < counts[0] / 4, "{counts:?}");
        // Never more samples than intervals where tau grows.
        let growing = tau.windows(2).filter(|w| w[1] > w[0]).count();
        assert!(counts[0] <= growing);
    }

    #[test]
    fn simple_profiles() {
        // Nothing in the way: no samples.
        assert!(fit_profile(&[0.0, 1.0, 2.0], &[0.0, 0.0, 0.0], 0.002)
            .unwrap()
            .is_empty());
        // A homogeneous slab: one sample, whatever its depth.
        let t: Vec<f64> = (0..50).map(f64::from).collect();
        let tau: Vec<f64> = t.iter().map(|x| 0.3 * x).collect();
        let s = fit_profile(&t, &tau, 1e-6).unwrap();
        assert_eq!(s.len(), 1);
        assert!((s[0].alpha() - (1.0 - (-0.3f64 * 49.0).exp())).abs() < 1e-12);
        // Two slabs with air between: two samples, none in the gap.
        let s = fit_profile(&[0.0, 1.0, 5.0, 6.0], &[0.0, 2.0, 2.0, 2.5], 1e-6).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!((s[0].z0, s[0].z1, s[1].z0, s[1].z1), (0.0, 1.0, 5.0, 6.0));
        // Refusals.
        assert!(fit_profile(&[0.0, 1.0], &[0.0, 1.0], 0.0).is_err());
        assert!(fit_profile(&[0.0, 1.0], &[1.0, 0.5], 0.01).is_err());
        assert!(fit_profile(&[1.0, 0.0], &[0.0, 0.5], 0.01).is_err());
        assert!(fit_profile(&[0.0, 1.0], &[0.0], 0.01).is_err());
        assert!(fit_profile(&[0.0, f64::NAN], &[0.0, 1.0], 0.01).is_err());
    }

    #[test]
    fn the_interior_extremum_is_found() {
        // Chord and profile agree at both ends of the interval but not inside it.
        let worst = max_gap(0.0, 1.0, (0.0, 2.0), (0.0, 2.0));
        assert!(worst < 1e-15);
        let (a, b) = ((0.0, 1.0), (0.0, 1.0));
        assert!(max_gap(0.0, 1.0, a, b) < 1e-15);
        // A two-piece profile (steep then flat) against its chord: the gap peaks inside.
        let chord_mid: f64 = 1.0;
        let exact_mid: f64 = 2.0;
        let g_mid = ((-chord_mid).exp() - (-exact_mid).exp()).abs();
        let worst = max_gap(0.0, 1.0, (0.0, chord_mid), (0.0, exact_mid));
        assert!(worst >= g_mid - 1e-15);
        let dense = (0..=10_000)
            .map(|q| {
                let s = f64::from(q) / 10_000.0;
                ((-chord_mid * s).exp() - (-exact_mid * s).exp()).abs()
            })
            .fold(0.0f64, f64::max);
        assert!((worst - dense).abs() < 1e-7, "{worst} vs {dense}");
        assert!(worst > g_mid, "the interior maximum exceeds both ends");
    }
}
