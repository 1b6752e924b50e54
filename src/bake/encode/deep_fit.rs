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

use std::cell::Cell;

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
    let e = |v: f64| (-v).exp();
    gap_exact(t1 - t0, (a0, a1), (b0, b1), (e(a0), e(a1)), (e(b0), e(b1)))
}

/// A bound on the largest `|exp(-a(t)) - exp(-b(t))|` over an interval where `a` and `b` are
/// linear and non-decreasing, from their end values alone: no transcendentals.
///
/// By the mean value theorem `|exp(-a) - exp(-b)| <= exp(-min(a, b)) |a - b|` at each depth;
/// `a - b` is linear, so `|a - b| <= d = max(|a0 - b0|, |a1 - b1|)`, and `min(a, b) >=
/// min(a0, b0)`. Two bounds on `exp(-min(a0, b0))` follow: `decay = exp(-floor)` for a `floor`
/// at or below `min(a0, b0)` (the chord's start, one `exp` per chord), and `exp(-b0) exp(|a0 -
/// b0|) <= eb0 / (1 - |a0 - b0|)` (true for `|a0 - b0| < 1`, taken for `< 0.5`; `eb0 =
/// exp(-b0)` is stored with the profile), which is far tighter deep inside a thick span.
/// `None` when neither applies.
fn gap_bound(
    (a0, a1): (f64, f64),
    (b0, b1): (f64, f64),
    eb0: f64,
    (floor, decay): (f64, f64),
) -> Option<f64> {
    let (d0, d1) = ((a0 - b0).abs(), (a1 - b1).abs());
    let d = d0.max(d1);
    let mut best = f64::INFINITY;
    if a0.min(b0) >= floor {
        best = decay * d;
    }
    if d0 < 0.5 {
        best = best.min(eb0 * d / (1.0 - d0));
    }
    best.is_finite().then_some(best)
}

/// The largest `|exp(-a(t)) - exp(-b(t))|` over an interval of length `len` where `a` and `b`
/// are linear, given their end values and those values' `exp(-.)`: at the ends, or where the
/// derivative `b' exp(-b) - a' exp(-a)` vanishes, which (as `a - b` is linear) it does at
/// most once, at `a - b = ln(a' / b')`, and only where it changes sign between the ends.
fn gap_exact(
    len: f64,
    (a0, a1): (f64, f64),
    (b0, b1): (f64, f64),
    (ea0, ea1): (f64, f64),
    (eb0, eb1): (f64, f64),
) -> f64 {
    let mut worst = (ea0 - eb0).abs().max((ea1 - eb1).abs());
    if len > 0.0 {
        let (da, db) = ((a1 - a0) / len, (b1 - b0) / len);
        if da > 0.0 && db > 0.0 && da != db {
            let (h0, h1) = (db * eb0 - da * ea0, db * eb1 - da * ea1);
            if (h0 < 0.0) != (h1 < 0.0) {
                let target = (da / db).ln();
                let s = (target - (a0 - b0)) / (da - db); // distance from t0
                if s > 0.0 && s < len {
                    let (a, b) = (a0 + da * s, b0 + db * s);
                    worst = worst.max(((-a).exp() - (-b).exp()).abs());
                }
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
    let p = Prepared::new(t, taus)?;
    Ok(greedy_fit(&p, max_error, usize::MAX)
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

/// A profile [`check_profile`] accepted, ready for [`greedy_fit`]: its depths, its channels'
/// optical depths, and each channel's `T = exp(-tau)` at every breakpoint (computed once
/// however many fits are made).
pub(crate) struct Prepared<'a> {
    t: &'a [f64],
    taus: &'a [&'a [f64]],
    trans: Vec<Vec<f64>>,
}

impl<'a> Prepared<'a> {
    /// Check and prepare a profile.
    ///
    /// # Errors
    /// As [`check_profile`].
    pub(crate) fn new(t: &'a [f64], taus: &'a [&'a [f64]]) -> Result<Self> {
        check_profile(t, taus)?;
        let trans = taus
            .iter()
            .map(|tau| tau.iter().map(|v| (-v).exp()).collect())
            .collect();
        Ok(Self { t, taus, trans })
    }

    /// The profile's depths.
    pub(crate) fn depths(&self) -> &'a [f64] {
        self.t
    }

    /// The profile's channels' optical depths.
    pub(crate) fn channels(&self) -> &'a [&'a [f64]] {
        self.taus
    }

    /// Whether the chord from breakpoint `i` to `j` fits every channel within `max_error` on
    /// every interval between: `Ok` with the largest gap checked, or `Err` with the first gap
    /// over `max_error` (+inf for a NaN). A gap whose [`gap_bound`] is at most `cheap_below`
    /// is taken as that bound; the others are exact ([`gap_exact`]).
    fn chord(
        &self,
        i: usize,
        j: usize,
        max_error: f64,
        cheap_below: f64,
    ) -> std::result::Result<f64, f64> {
        let t = self.t;
        let span = (t[j] - t[i]).max(f64::MIN_POSITIVE);
        let mut level = 0.0f64;
        for (tau, trans) in self.taus.iter().zip(&self.trans) {
            let slope = (tau[j] - tau[i]) / span;
            // Chord and profile both start at tau[i] and never decrease.
            let floor = (tau[i], trans[i]);
            // The chord at the interval's start, and its exp(-.) when the last interval
            // computed it.
            let (mut a0, mut ea_start) = (tau[i], Some(trans[i]));
            let (ts, bs, es) = (&t[i..=j], &tau[i..=j], &trans[i..=j]);
            for ((tw, bw), ew) in ts.windows(2).zip(bs.windows(2)).zip(es.windows(2)) {
                let a1 = tau[i] + slope * (tw[1] - t[i]);
                let (a, b) = ((a0, a1), (bw[0], bw[1]));
                a0 = a1;
                let g = match gap_bound(a, b, ew[0], floor) {
                    Some(g) if g <= cheap_below => {
                        ea_start = None;
                        g
                    }
                    _ => {
                        let ea0 = ea_start.unwrap_or_else(|| (-a.0).exp());
                        let ea1 = (-a.1).exp();
                        ea_start = Some(ea1);
                        gap_exact(tw[1] - tw[0], a, b, (ea0, ea1), (ew[0], ew[1]))
                    }
                };
                if g.is_nan() {
                    return Err(f64::INFINITY);
                }
                if g > max_error {
                    return Err(g);
                }
                level = level.max(g);
            }
        }
        Ok(level)
    }

    /// The largest `|T_fit(z) - T(z)|` over the profile's depths for the reconstruction that
    /// is linear in `tau` between the sorted breakpoints `nodes` (constant outside them), or
    /// +inf for a NaN: exact, chord by chord.
    pub(crate) fn nodes_error(&self, nodes: &[usize]) -> f64 {
        let mut worst = 0.0f64;
        for w in nodes.windows(2) {
            if w[1] > w[0] {
                match self.chord(w[0], w[1], f64::INFINITY, -1.0) {
                    Ok(g) => worst = worst.max(g),
                    Err(_) => return f64::INFINITY,
                }
            }
        }
        // Before the first node tau is 0, after the last it stays: the profile is monotone
        // between breakpoints, so the gap there is largest at one.
        let (first, last) = match (nodes.first(), nodes.last()) {
            (Some(&f), Some(&l)) => (f, l),
            _ => (self.t.len(), self.t.len()),
        };
        for trans in &self.trans {
            for &x in &trans[..first] {
                worst = worst.max((1.0 - x).abs());
            }
            if let Some(&end) = trans.get(last) {
                for &x in &trans[last..] {
                    worst = worst.max((x - end).abs());
                }
            }
        }
        worst
    }
}

/// A greedy fit ([`greedy_fit`]): its spans, and the largest gap any accepted chord check
/// returned.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GreedyFit {
    /// The samples as breakpoint index pairs, as [`fit_spans`] returns them.
    pub(crate) spans: Vec<(usize, usize)>,
    /// The largest gap (or bound on it, [`gap_bound`]) an accepted check returned. Every check
    /// the fit made has the same outcome for any bound in `[level, max_error]`, so the fit at
    /// such a bound is this one (a rejected check's gap was computed exactly and exceeds
    /// `max_error`; an accepted one's is at most `level`).
    pub(crate) level: f64,
}

impl GreedyFit {
    /// The fit's nodes, sorted: each span's two ends, shared where spans touch (what
    /// [`greedy_fit`]'s `max_nodes` counts).
    pub(crate) fn nodes(&self) -> Vec<usize> {
        let mut out: Vec<usize> = Vec::with_capacity(2 * self.spans.len());
        for &(i, j) in &self.spans {
            if out.last() != Some(&i) {
                out.push(i);
            }
            out.push(j);
        }
        out
    }
}

/// A greedy fit ([`greedy_fit`]) that needed more nodes than it was allowed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Refused {
    /// The largest gap an accepted check returned.
    pub(crate) level: f64,
    /// The smallest gap over the bound a rejected check met (+inf for none, or for a NaN).
    /// Every check the fit made has the same outcome for any bound in `[level, ceiling)`, so
    /// the fit is refused at every such bound too.
    pub(crate) ceiling: f64,
}

/// The greedy chord fit of [`fit_spans`] on a profile [`Prepared`] (`max_error` in `(0, 1)`),
/// or [`Refused`] as soon as its nodes (each span's two ends, shared where spans touch)
/// exceed `max_nodes`.
pub(crate) fn greedy_fit(
    p: &Prepared<'_>,
    max_error: f64,
    max_nodes: usize,
) -> std::result::Result<GreedyFit, Refused> {
    let (t, taus) = (p.t, p.taus);
    let n = t.len();
    let flat = |k: usize| taus.iter().all(|tau| tau[k + 1] == tau[k]);
    let (level, ceiling) = (Cell::new(0.0f64), Cell::new(f64::INFINITY));
    let check = |i: usize, j: usize| match p.chord(i, j, max_error, max_error) {
        Ok(l) => {
            level.set(level.get().max(l));
            true
        }
        Err(g) => {
            ceiling.set(ceiling.get().min(g));
            false
        }
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
            return Err(Refused {
                level: level.get(),
                ceiling: ceiling.get(),
            });
        }
        out.push((i, j));
        i = j;
    }
    Ok(GreedyFit {
        spans: out,
        level: level.get(),
    })
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
                let chans = [tau.as_slice()];
                let p = Prepared::new(&t, &chans).unwrap();
                let f = greedy_fit(&p, e, usize::MAX).unwrap();
                assert_eq!(f.spans, fit_spans(&t, &[&tau], e).unwrap());
                assert!(f.level <= e);
                let mid = (f.level.max(1e-9) * e).sqrt().max(f.level);
                for e2 in [f.level.max(1e-9), mid] {
                    let g = greedy_fit(&p, e2, usize::MAX).unwrap();
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
                assert!(greedy_fit(&p, e, nodes).is_ok());
                if nodes > 0 {
                    assert!(greedy_fit(&p, e, nodes - 1).is_err());
                }
            }
        }
    }

    #[test]
    fn the_cheap_bound_bounds_the_gap() {
        // Random non-decreasing linear pairs: the bound never falls below a dense maximum.
        let (t, tau) = profile(11, 4000);
        let top = tau[tau.len() - 1];
        let tau: Vec<f64> = tau.iter().map(|v| v * 8.0 / top).collect();
        for w in tau.windows(4).step_by(3) {
            let (a, b) = ((w[0], w[0] + 1.7 * (w[2] - w[0])), (w[1].min(w[0]), w[3]));
            let floor = a.0.min(b.0);
            let Some(bound) = gap_bound(a, b, (-b.0).exp(), (floor, (-floor).exp())) else {
                continue;
            };
            let dense = (0..=200)
                .map(|q| {
                    let s = f64::from(q) / 200.0;
                    let (x, y) = (a.0 + s * (a.1 - a.0), b.0 + s * (b.1 - b.0));
                    ((-x).exp() - (-y).exp()).abs()
                })
                .fold(0.0f64, f64::max);
            assert!(
                bound >= dense * (1.0 - 1e-12),
                "{bound} < {dense} for {a:?} {b:?}"
            );
            let exact = max_gap(0.0, 1.0, a, b);
            assert!(exact >= dense - 1e-12 && exact - dense < 1e-3 && bound >= exact - 1e-12);
        }
        assert!(t.len() == 4000);
    }

    #[test]
    fn refused_fits_are_refused_up_to_their_ceiling_and_node_errors_are_exact() {
        for seed in 0..20 {
            let (t, tau) = profile(seed, 300);
            let chans = [tau.as_slice()];
            let p = Prepared::new(&t, &chans).unwrap();
            for e in [0.05, 0.01, 1e-3] {
                let Err(r) = greedy_fit(&p, e, 6) else {
                    continue;
                };
                assert!(r.level <= e && e < r.ceiling, "{r:?} at {e}");
                let below = (r.level * r.ceiling).sqrt().max(r.level);
                if below < r.ceiling {
                    assert!(greedy_fit(&p, below, 6).is_err());
                }
            }
            // The exact error of a node set against a dense evaluation of both.
            let f = greedy_fit(&p, 0.01, usize::MAX).unwrap();
            let nodes = f.nodes();
            let got = p.nodes_error(&nodes);
            assert!(got <= f.level + 1e-12 && got <= 0.01);
            let nt: Vec<f64> = nodes.iter().map(|&i| t[i]).collect();
            let nv: Vec<f64> = nodes.iter().map(|&i| tau[i]).collect();
            let end = *t.last().unwrap();
            let dense = (0..=20_000)
                .map(|q| {
                    let z = end * f64::from(q) / 20_000.0;
                    let rec = if z < nt[0] {
                        0.0
                    } else {
                        linear_at(&nt, &nv, z)
                    };
                    ((-rec).exp() - exact(&t, &tau, z)).abs()
                })
                .fold(0.0f64, f64::max);
            assert!(
                dense <= got + 1e-9 && got - dense < 2e-3,
                "seed {seed}: {got} vs {dense}"
            );
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
