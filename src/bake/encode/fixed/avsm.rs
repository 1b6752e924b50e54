//! Adaptive volumetric shadow maps (Salvi et al. 2010): `K` nodes `(u_i, tau_i)` per texel.
//!
//! Salvi et al. insert a ray's samples into `K` nodes on the fly and, when full, remove the node
//! whose removal changes the area under `T` least: the order a GPU meets fragments in. Offline the
//! whole profile is known, so the nodes are placed by a minimax fit instead: the smallest error
//! `E` (bisected on a log scale, 14 steps: within 0.1 % of the smallest) for which the greedy
//! chord fit of [`crate::bake::fit_spans`] covers the profile within `E` in `T` at every depth
//! using at most `K` nodes (each sample's two ends, shared where samples touch). Between nodes
//! `tau` is linear, as inside an OpenEXR volumetric deep sample, which is exact for a
//! homogeneous slab; before the first node `tau = 0`, after the last it stays. Unused nodes
//! repeat the last one. The stored `u` and `tau` are rounded to f32, which keeps both sorted, so
//! the reconstruction never lightens with depth; two nodes at one depth are a jump (an opaque
//! depth).
//!
//! Each fit of the bisection stops as soon as it needs more than `K` nodes, and a step whose
//! outcome an earlier fit settles is not fitted again ([`bisect`]): the nodes are those of the
//! plain bisection, bit for bit.

use super::NormProfile;
use crate::bake::encode::deep_fit::{check_profile, greedy_fit, GreedyFit};

/// Nodes of a span list: each span's ends, a span starting where the last ended sharing it.
fn nodes(spans: &[(usize, usize)]) -> Vec<usize> {
    let mut out: Vec<usize> = Vec::with_capacity(2 * spans.len());
    for &(i, j) in spans {
        if out.last() != Some(&i) {
            out.push(i);
        }
        out.push(j);
    }
    out
}

/// The nodes of the smallest error the bisection of the module docs finds for profile `p`
/// with `k` nodes (`None` for a profile the fit refuses).
///
/// Each fit stops as soon as it needs more than `k` nodes. A fit that succeeds at `e` is the
/// fit at every bound in `[level, e]` ([`GreedyFit::level`]), so a later bisection step inside
/// that range is known to succeed without fitting: the same steps, the same nodes.
fn bisect(u: &[f64], tau: &[f64], k: usize) -> Option<Vec<usize>> {
    check_profile(u, &[tau]).ok()?;
    let fit = |e: f64| greedy_fit(u, &[tau], e, k);
    // Bisect the error on a log scale between 1e-7 and 0.999 (a chord from the first to
    // the last breakpoint always fits there: K >= 2).
    if let Some(f) = fit(1e-7) {
        return Some(nodes(&f.spans));
    }
    let (mut lo, mut hi) = (1e-7f64.ln(), 0.999f64.ln());
    // The last success: its fit and the bound it was made at.
    let mut best: Option<(GreedyFit, f64)> = None;
    for _ in 0..14 {
        let mid = 0.5 * (lo + hi);
        let e = mid.exp();
        if best
            .as_ref()
            .is_some_and(|(f, at)| f.level <= e && e <= *at)
        {
            hi = mid;
            continue;
        }
        match fit(e) {
            Some(f) => {
                best = Some((f, e));
                hi = mid;
            }
            None => lo = mid,
        }
    }
    match best {
        Some((f, _)) => Some(nodes(&f.spans)),
        None => fit(0.999).map(|f| nodes(&f.spans)),
    }
}

/// The stored nodes `u_0, tau_0, u_1, tau_1, ...` of profile `p` (`k` nodes).
#[must_use]
pub fn encode(p: &NormProfile, k: u32) -> Vec<f32> {
    let (u, tau) = (p.u(), p.tau());
    let k = k as usize;
    let chosen = if u.len() <= k {
        Some((0..u.len()).collect::<Vec<usize>>())
    } else {
        bisect(u, tau, k)
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
