//! Ray marching: estimate the optical depth of each sampled segment from point lookups and
//! return `exp(-tau_hat)`. The segment of length `L` is cut into `n = ceil(L / h)` equal pieces
//! of length `L / n <= h`, `h` being the step converted from voxels to world units.
//! - `riemann`: midpoint of each piece (deterministic; error O(h^2) for smooth media).
//! - `monte_carlo`: `n` independent uniform points (tau_hat unbiased, variance O(h)).
//! - `jittered`: one uniform point per piece (stratified; variance O(h^3) for smooth media).
//!
//! `exp(-tau_hat)` is biased upward for the random variants: `E[exp(-X)] >= exp(-E[X])`
//! (Jensen), so they overestimate transmittance.

use super::medium::RayMedium;
use crate::rng::Rng;
use crate::traverse::Segment;

fn pieces(s: &Segment, step_world: f64) -> (u64, f64) {
    let len = s.length();
    let n = (len / step_world).ceil().max(1.0);
    (n as u64, len / n)
}

fn step_world(m: &RayMedium<'_>, step_voxels: f64) -> f64 {
    let v = m.voxels_per_world_unit();
    (step_voxels / v).max(f64::MIN_POSITIVE)
}

/// Midpoint-rule ray marching.
pub(crate) fn riemann(segs: &[Segment], m: &mut RayMedium<'_>, step: f64) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in segs {
        let (n, dt) = pieces(s, h);
        for k in 0..n {
            tau += m.mu(s.t_min + (k as f64 + 0.5) * dt) * dt;
        }
    }
    (-tau).exp()
}

/// Monte Carlo optical depth from uniform random points.
pub(crate) fn monte_carlo(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    step: f64,
) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in segs {
        let (n, dt) = pieces(s, h);
        for _ in 0..n {
            tau += m.mu(s.t_min + rng.uniform() * s.length()) * dt;
        }
    }
    (-tau).exp()
}

/// Stratified (jittered) ray marching: one random point per piece.
pub(crate) fn jittered(segs: &[Segment], m: &mut RayMedium<'_>, rng: &mut Rng, step: f64) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in segs {
        let (n, dt) = pieces(s, h);
        for k in 0..n {
            tau += m.mu(s.t_min + (k as f64 + rng.uniform()) * dt) * dt;
        }
    }
    (-tau).exp()
}
