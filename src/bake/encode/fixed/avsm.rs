//! Adaptive volumetric shadow maps (Salvi et al. 2010): `K` nodes `(u_i, tau_i)` per texel.
//!
//! Salvi et al. insert a ray's samples into `K` nodes on the fly and, when full, remove the node
//! whose removal changes the area under `T` least: the order a GPU meets fragments in. Offline the
//! whole profile is known, so the nodes are placed by a minimax fit instead: the smallest error
//! `E` for which the greedy chord fit of [`crate::bake::fit_spans`] covers the profile within
//! `E` in `T` at every depth using at most `K` nodes (each sample's two ends, shared where
//! samples touch). Between nodes `tau` is linear, as inside an OpenEXR volumetric deep sample,
//! which is exact for a homogeneous slab; before the first node `tau = 0`, after the last it
//! stays. Unused nodes repeat the last one. The stored `u` and `tau` are rounded to f32, which
//! keeps both sorted, so the reconstruction never lightens with depth; two nodes at one depth
//! are a jump (an opaque depth).
//!
//! **The search** ([`search`]). A texel's profile has a few hundred breakpoints, and each
//! candidate `E` costs a whole greedy fit; the search for `E` runs on a *decimated* profile
//! instead: the breakpoints a greedy fit at a small `delta` keeps (its nodes, a subset of the
//! profile's, within `delta` of it). Nodes chosen there are the profile's own, and their error
//! against the profile is at most the decimated error plus `delta`. `delta` starts at
//! [`DELTA`] and shrinks to a tenth of the error found while the error is below ten times it
//! (a profile eight nodes almost fit). The greedy fit is not monotone in `E`, so one
//! decimation can be unlucky: where the error found is [`SECOND_FROM`] or more, a second search
//! on the profile decimated at a third of it gives a second set of nodes, and the texel keeps
//! the set whose exact error against the whole profile ([`Prepared::nodes_error`]) is smaller.
//! Against the plain bisection over the whole profile it replaced (about ten whole fits a
//! texel, 2.5x slower), on three assets at 128 px: the RMS error is lower on two and 3 % higher
//! on one, the worst texel's error 2 % lower on one and 9-10 % higher on two (docs/performance.md).

use super::NormProfile;
use crate::bake::encode::deep_fit::{greedy_fit, GreedyFit, Prepared};

/// The first decimation's bound (in `T`).
const DELTA: f64 = 1e-3;
/// The decimation is refined while the error found is below this many times its bound; the
/// refined bound is the error over this.
const REFINE: f64 = 10.0;
/// The second decimation's bound is the first search's error over this.
const SECOND: f64 = 3.0;
/// The second search runs where the first found an error of at least this (in `T`): the
/// texels that decide a map's worst error. Below it a second search moved the smoke's RMS
/// error by 0.3 % and cost a tenth of the encoding time.
const SECOND_FROM: f64 = 0.02;

/// The nodes for profile `(u, tau)` with `k` nodes, as the module docs describe (`None` for a
/// profile the fit refuses).
fn search(u: &[f64], tau: &[f64], k: usize) -> Option<Vec<usize>> {
    let chans = [tau];
    let p = Prepared::new(u, &chans).ok()?;
    if let Ok(f) = greedy_fit(&p, FLOOR, k) {
        return Some(f.nodes());
    }
    let mut delta = DELTA;
    for _ in 0..3 {
        let Some((first, e)) = decimated(&p, k, (delta, CEILING)) else {
            break;
        };
        if e < REFINE * delta && delta > FLOOR {
            delta = (e / REFINE).max(delta / 1000.0).max(FLOOR);
            continue;
        }
        if e < SECOND_FROM {
            return Some(first);
        }
        let Some((second, _)) = decimated(&p, k, (e / SECOND, (2.0 * e).min(CEILING))) else {
            return Some(first);
        };
        let better = p.nodes_error(&second) < p.nodes_error(&first);
        return Some(if better { second } else { first });
    }
    search_on(&p, k, (FLOOR, CEILING)).map(|(n, _)| n)
}

/// The nodes [`search_on`] finds (between `delta` and `top`) on profile `p` decimated at
/// `delta` (as indices into `p`), and their error against the decimated profile; `None` where
/// decimating does not halve the breakpoints (the whole profile is searched then) or the fit
/// refuses.
fn decimated(p: &Prepared<'_>, k: usize, (delta, top): (f64, f64)) -> Option<(Vec<usize>, f64)> {
    let (u, tau) = (p.depths(), p.channels().first()?);
    let keep = greedy_fit(p, delta, usize::MAX).ok()?.nodes();
    if keep.len() <= k {
        return Some((keep, delta));
    }
    if keep.len() * 2 > u.len() {
        return None;
    }
    let du: Vec<f64> = keep.iter().map(|&i| u[i]).collect();
    let dt: Vec<f64> = keep.iter().map(|&i| tau[i]).collect();
    let dchans = [dt.as_slice()];
    let d = Prepared::new(&du, &dchans).ok()?;
    let (idx, e) = search_on(&d, k, (delta, top))?;
    Some((idx.into_iter().map(|i| keep[i]).collect(), e))
}

/// The smallest error the greedy fit of profile `p` meets with `k` nodes, to [`PRECISION`],
/// searched between `floor` and `top` (or, if no fit below `top` succeeds, the fit at
/// [`CEILING`]): its nodes and that error.
///
/// A fit that succeeds at `e` is the fit at every bound in `[level, e]`
/// ([`GreedyFit::level`]); one refused at `e` is refused at every bound in `[level, ceiling)`
/// ([`crate::bake::encode::deep_fit::Refused`]). So the search keeps `lo`, below which every
/// bound is taken as refused (the fit is assumed monotone, as any bisection does), and the
/// best fit, whose error is its `level`, and probes the geometric mean of the two (never below
/// `lo`, itself the next bound where some check changes its outcome) until they are within
/// [`PRECISION`].
fn search_on(p: &Prepared<'_>, k: usize, (floor, top): (f64, f64)) -> Option<(Vec<usize>, f64)> {
    let fit = |e: f64| greedy_fit(p, e, k);
    let mut lo = match fit(floor) {
        Ok(f) => return Some((f.nodes(), f.level)),
        Err(r) => r.ceiling,
    };
    let mut best: Option<GreedyFit> = None;
    for _ in 0..MAX_PROBES {
        let hi = best.as_ref().map_or(top, |f| f.level);
        if lo * (1.0 + PRECISION) >= hi {
            break;
        }
        let e = (0.5 * (lo.ln() + hi.ln())).exp().clamp(lo, hi);
        match fit(e) {
            Ok(f) => best = Some(f),
            Err(r) => lo = lo.max(r.ceiling),
        }
    }
    match best {
        Some(f) => Some((f.nodes(), f.level)),
        None => fit(CEILING).ok().map(|f| (f.nodes(), f.level)),
    }
}

/// The smallest error the search tries (in `T`).
const FLOOR: f64 = 1e-7;
/// The largest: a chord from the first to the last breakpoint always fits there (`K >= 2`).
const CEILING: f64 = 0.999;
/// The search stops when the best fit's error is within this fraction of the bound below
/// which every fit is refused.
const PRECISION: f64 = 1e-2;
/// A cap on the probes (the bracket at least halves in log each time: 12 reach
/// [`PRECISION`] from `[FLOOR, CEILING]`).
const MAX_PROBES: usize = 24;

/// The stored nodes `u_0, tau_0, u_1, tau_1, ...` of profile `p` (`k` nodes).
#[must_use]
pub fn encode(p: &NormProfile, k: u32) -> Vec<f32> {
    let (u, tau) = (p.u(), p.tau());
    let k = k as usize;
    let chosen = if u.len() <= k {
        Some((0..u.len()).collect::<Vec<usize>>())
    } else {
        search(u, tau, k)
    };
    let idx = chosen.unwrap_or_default();
    let mut out = Vec::with_capacity(2 * k);
    for &i in &idx {
        out.extend([u[i] as f32, tau[i] as f32]);
    }
    let last = match idx.last() {
        Some(&i) => [u[i] as f32, tau[i] as f32],
        None => [0.0, 0.0],
    };
    while out.len() < 2 * k {
        out.extend(last);
    }
    out
}

/// `tau` at `u` from stored nodes `c` (the limit from the left with `left`).
#[must_use]
pub fn tau(c: &[f32], u: f64, left: bool) -> f64 {
    let node = |i: usize| (f64::from(c[2 * i]), f64::from(c[2 * i + 1]));
    let k = c.len() / 2;
    if k == 0 {
        return 0.0;
    }
    let before = |x: f64| if left { u <= x } else { u < x };
    if before(node(0).0) {
        return 0.0;
    }
    for i in 0..k - 1 {
        let ((u0, t0), (u1, t1)) = (node(i), node(i + 1));
        if before(u1) {
            return super::lerp(u0, u1, t0, t1, u).max(0.0);
        }
    }
    node(k - 1).1.max(0.0)
}
