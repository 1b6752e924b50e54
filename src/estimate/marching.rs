//! Ray marching: estimate the optical depth of the sampled segments from point lookups and
//! return `exp(-tau_hat)`. Touching segments are merged into spans; a span of length `L` is cut
//! into `n = ceil(L / h)` equal pieces of length `L / n <= h`, `h` being the step converted
//! from voxels to world units.
//! - `riemann`: midpoint of each piece (deterministic; error O(h^2) for smooth media).
//! - `monte_carlo`: `n` independent uniform points (tau_hat unbiased, variance O(h)).
//! - `jittered`: one uniform point per piece (stratified; variance O(h^3) for smooth media).
//!
//! `exp(-tau_hat)` is biased upward for the random variants: `E[exp(-X)] >= exp(-E[X])`
//! (Jensen), so they overestimate transmittance.

use super::medium::Extinction;
use crate::rng::Rng;
use crate::traverse::Segment;

/// The sampled segments merged where they touch (`t_max` of one equal to `t_min` of the next
/// within round-off): a march over a run of leaves is one span with one piece grid, not one
/// grid per leaf with a partial piece at every leaf boundary.
fn spans(segs: &[Segment]) -> impl Iterator<Item = Segment> + '_ {
    let mut i = 0;
    std::iter::from_fn(move || {
        let mut span = *segs.get(i)?;
        i += 1;
        while let Some(next) = segs.get(i) {
            if next.t_min > span.t_max + 1e-12 * span.t_max.abs().max(1.0) {
                break;
            }
            span.t_max = span.t_max.max(next.t_max);
            span.mu_min = span.mu_min.min(next.mu_min);
            span.mu_maj = span.mu_maj.max(next.mu_maj);
            i += 1;
        }
        Some(span)
    })
}

/// Relative slack when counting pieces: a segment of `8.000000000000002` steps (a leaf
/// segment of 8 voxels after round-off in `t`) is 8 pieces that line up with the voxels, not 9
/// that do not. Pieces may then exceed the step by this fraction.
const PIECE_SLACK: f64 = 1e-9;

/// `(n, L / n)`: the fewest equal pieces of segment `s` no longer than the step (within
/// [`PIECE_SLACK`]), `n = ceil(L / h - slack)`, at least 1.
fn pieces(s: &Segment, step_world: f64) -> (u64, f64) {
    let len = s.length();
    let x = len / step_world;
    let n = (x - x * PIECE_SLACK).ceil().max(1.0);
    (n as u64, len / n)
}

fn step_world(m: &impl Extinction, step_voxels: f64) -> f64 {
    let v = m.voxels_per_world_unit();
    (step_voxels / v).max(f64::MIN_POSITIVE)
}

/// Midpoint-rule ray marching.
pub(crate) fn riemann(segs: &[Segment], m: &mut impl Extinction, step: f64) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in spans(segs) {
        let (n, dt) = pieces(&s, h);
        for k in 0..n {
            tau += m.mu(s.t_min + (k as f64 + 0.5) * dt) * dt;
        }
    }
    (-tau).exp()
}

/// Monte Carlo optical depth from uniform random points.
pub(crate) fn monte_carlo(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    step: f64,
) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in spans(segs) {
        let (n, dt) = pieces(&s, h);
        for _ in 0..n {
            tau += m.mu(s.t_min + rng.uniform() * s.length()) * dt;
        }
    }
    (-tau).exp()
}

/// Stratified (jittered) ray marching: one random point per piece.
pub(crate) fn jittered(segs: &[Segment], m: &mut impl Extinction, rng: &mut Rng, step: f64) -> f64 {
    let h = step_world(m, step);
    let mut tau = 0.0;
    for s in spans(segs) {
        let (n, dt) = pieces(&s, h);
        for k in 0..n {
            tau += m.mu(s.t_min + (k as f64 + rng.uniform()) * dt) * dt;
        }
    }
    (-tau).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(len: f64) -> Segment {
        Segment {
            t_min: 1.0,
            t_max: 1.0 + len,
            mu_min: 0.0,
            mu_maj: 1.0,
            level: 1,
        }
    }

    #[test]
    fn pieces_tolerate_round_off_but_not_real_excess() {
        // 8 steps plus round-off: 8 pieces (used to be 9, off the voxel grid).
        assert_eq!(pieces(&seg(8.000_000_000_000_002), 1.0).0, 8);
        assert_eq!(pieces(&seg(8.0 * 0.1 * (1.0 + 1e-15)), 0.1).0, 8);
        // A real excess still takes another piece; short segments take one.
        assert_eq!(pieces(&seg(8.001), 1.0).0, 9);
        assert_eq!(pieces(&seg(8.0), 1.0).0, 8);
        assert_eq!(pieces(&seg(1e-3), 1.0).0, 1);
        let (n, dt) = pieces(&seg(7.5), 0.5);
        assert_eq!((n, dt), (15, 0.5));
    }

    #[test]
    fn touching_segments_merge_into_spans_and_gaps_split_them() {
        let at = |a: f64, b: f64| Segment {
            t_min: a,
            t_max: b,
            mu_min: a,
            mu_maj: b,
            level: 1,
        };
        let segs = [
            at(0.0, 1.0),
            at(1.0, 2.5),
            at(2.5 + 1e-15, 3.0),
            at(4.0, 5.0),
        ];
        let got: Vec<(f64, f64)> = spans(&segs).map(|s| (s.t_min, s.t_max)).collect();
        assert_eq!(got, vec![(0.0, 3.0), (4.0, 5.0)]);
        assert_eq!(spans(&[]).count(), 0);
    }
}
