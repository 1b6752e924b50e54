//! Ray marching: estimate the optical depth of the sampled segments from point lookups and
//! return `exp(-tau_hat)`. Touching segments are merged into spans, and spans cut into the
//! medium's chords ([`Extinction::chords`]: for one grid, the chords of the `8^3` blocks of
//! lookup space, so that a map marched block by block in object order takes the very same
//! points); a chord of length `L` is cut into `n = ceil(L / h)` equal pieces of length
//! `L / n <= h`, `h` being the step converted from voxels to world units.
//! - `riemann`: midpoint of each piece (deterministic; error O(h^2) for smooth media).
//! - `monte_carlo`: `n` independent uniform points per chord (tau_hat unbiased, variance O(h)).
//! - `jittered`: one uniform point per piece (stratified; variance O(h^3) for smooth media).
//!
//! The random points of a chord come from the sample's stream forked by the chord's block
//! ([`Rng::fork`]), so they do not depend on the chords before it.
//!
//! `exp(-tau_hat)` is biased upward for the random variants: `E[exp(-X)] >= exp(-E[X])`
//! (Jensen), so they overestimate transmittance.

use super::medium::{block_chords, Extinction, BLOCK_SIDE};
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

/// `(n, L / n)`: the fewest equal pieces of a chord of length `len` no longer than the step
/// (within [`PIECE_SLACK`]), `n = ceil(L / h - slack)`, at least 1.
pub(crate) fn pieces(len: f64, step_world: f64) -> (u64, f64) {
    let x = len / step_world;
    let y = x - x * PIECE_SLACK;
    // `ceil(y)` without a libm call (baseline x86-64 has no rounding instruction): the
    // truncation, plus one when it fell short (NaN truncates to 0).
    let t = y as u64;
    let n = if (t as f64) < y {
        t.saturating_add(1)
    } else {
        t
    }
    .max(1);
    (n, len / n as f64)
}

/// The marching step in world units: `step_voxels` voxels along a ray crossing
/// `voxels_per_world_unit` voxels per world unit.
pub(crate) fn step_world(voxels_per_world_unit: f64, step_voxels: f64) -> f64 {
    (step_voxels / voxels_per_world_unit).max(f64::MIN_POSITIVE)
}

/// Every chord of the sampled segments, in ray order (spans cut at the block lattice of
/// `lattice`, [`block_chords`], or whole): `f(a, n, dt, block)` with its start, its `n` pieces
/// of length `dt` and the `8^3` block it lies in (`None` without a lattice).
pub(crate) fn for_chords(
    segs: &[Segment],
    lattice: Option<([f64; 3], [f64; 3])>,
    h: f64,
    mut f: impl FnMut(f64, u64, f64, Option<[i64; 3]>),
) {
    for s in spans(segs) {
        match lattice {
            Some((q, d)) => block_chords(q, d, s.t_min, s.t_max, &mut |a, b| {
                let (n, dt) = pieces(b - a, h);
                f(a, n, dt, Some(block_of(q, d, 0.5 * (a + b))));
            }),
            None => {
                let (n, dt) = pieces(s.length(), h);
                f(s.t_min, n, dt, None);
            }
        }
    }
}

/// The `8^3` block (lookup-space origin over 8) holding the point at `t` of `q + d t`.
pub(crate) fn block_of(q: [f64; 3], d: [f64; 3], t: f64) -> [i64; 3] {
    [0, 1, 2].map(|k| crate::math::floor_i64((q[k] + d[k] * t) / BLOCK_SIDE))
}

/// The random stream of one chord: the sample's stream forked by the chord's block (so a map
/// swept block by block draws the same points), or the sample's stream itself, drawn along
/// the ray, without a lattice (a scene).
fn chord_rng<'r>(
    base: &Rng,
    block: Option<[i64; 3]>,
    own: &'r mut Option<Rng>,
    shared: &'r mut Rng,
) -> &'r mut Rng {
    match block {
        Some(b) => own.insert(base.fork(b)),
        None => shared,
    }
}

/// Midpoint-rule ray marching.
pub(crate) fn riemann(segs: &[Segment], m: &mut impl Extinction, step: f64) -> f64 {
    let h = step_world(m.voxels_per_world_unit(), step);
    let mut tau = 0.0;
    for_chords(segs, m.lattice(), h, |a, n, dt, _| {
        for k in 0..n {
            tau += m.mu(a + (k as f64 + 0.5) * dt) * dt;
        }
    });
    (-tau).exp()
}

/// Monte Carlo optical depth from uniform random points.
pub(crate) fn monte_carlo(
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    step: f64,
) -> f64 {
    let h = step_world(m.voxels_per_world_unit(), step);
    let mut tau = 0.0;
    let base = rng.clone();
    let mut own = None;
    for_chords(segs, m.lattice(), h, |a, n, dt, block| {
        let r = chord_rng(&base, block, &mut own, rng);
        let len = n as f64 * dt;
        for _ in 0..n {
            tau += m.mu(a + r.uniform() * len) * dt;
        }
    });
    (-tau).exp()
}

/// Stratified (jittered) ray marching: one random point per piece.
pub(crate) fn jittered(segs: &[Segment], m: &mut impl Extinction, rng: &mut Rng, step: f64) -> f64 {
    let h = step_world(m.voxels_per_world_unit(), step);
    let mut tau = 0.0;
    let base = rng.clone();
    let mut own = None;
    for_chords(segs, m.lattice(), h, |a, n, dt, block| {
        let r = chord_rng(&base, block, &mut own, rng);
        for k in 0..n {
            tau += m.mu(a + (k as f64 + r.uniform()) * dt) * dt;
        }
    });
    (-tau).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_tolerate_round_off_but_not_real_excess() {
        // 8 steps plus round-off: 8 pieces (used to be 9, off the voxel grid).
        assert_eq!(pieces(8.000_000_000_000_002, 1.0).0, 8);
        assert_eq!(pieces(8.0 * 0.1 * (1.0 + 1e-15), 0.1).0, 8);
        // A real excess still takes another piece; short segments take one.
        assert_eq!(pieces(8.001, 1.0).0, 9);
        assert_eq!(pieces(8.0, 1.0).0, 8);
        assert_eq!(pieces(1e-3, 1.0).0, 1);
        assert_eq!(pieces(0.0, 1.0).0, 1);
        assert_eq!(pieces(f64::NAN, 1.0).0, 1);
        // The integer ceiling agrees with `f64::ceil` on and around integers.
        for k in 1..2000u64 {
            for x in [k as f64, k as f64 + 1e-6, k as f64 - 1e-6, k as f64 + 0.5] {
                let want = (x - x * PIECE_SLACK).ceil().max(1.0) as u64;
                assert_eq!(pieces(x, 1.0).0, want, "{x}");
            }
        }
        let (n, dt) = pieces(7.5, 0.5);
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

    /// Chords of the 8^3 lookup blocks: cut at every plane `x_k = 8 m` the line crosses, in
    /// order, adding up to the span; axis-parallel and backward lines included.
    #[test]
    fn block_chords_cut_at_the_block_lattice() {
        let collect = |q: [f64; 3], d: [f64; 3], t0: f64, t1: f64| {
            let mut v = Vec::new();
            block_chords(q, d, t0, t1, &mut |a, b| v.push((a, b)));
            v
        };
        // Along +x from x = 3 for 20 units: planes at 8 and 16.
        assert_eq!(
            collect([3.0, 1.0, 1.0], [1.0, 0.0, 0.0], 0.0, 20.0),
            vec![(0.0, 5.0), (5.0, 13.0), (13.0, 20.0)]
        );
        // Backward along z, starting on a plane: the first cut is the plane below.
        assert_eq!(
            collect([1.0, 1.0, 16.0], [0.0, 0.0, -2.0], 0.0, 5.0),
            vec![(0.0, 4.0), (4.0, 5.0)]
        );
        // A diagonal line: each chord lies in one block, and they tile the span.
        let (q, d) = ([-3.3, 7.9, 0.1], [0.8, -0.45, 0.39]);
        let v = collect(q, d, 0.5, 60.0);
        assert_eq!(v.first().map(|c| c.0), Some(0.5));
        assert_eq!(v.last().map(|c| c.1), Some(60.0));
        for w in v.windows(2) {
            assert_eq!(w[0].1, w[1].0);
        }
        for &(a, b) in &v {
            let mid = (a + b) / 2.0;
            let block = |t: f64| [0, 1, 2].map(|k| ((q[k] + d[k] * t) / 8.0).floor());
            let eps = 1e-9 * (b - a);
            assert_eq!(block(a + eps), block(mid));
            assert_eq!(block(b - eps), block(mid));
        }
        assert!(collect(q, d, 1.0, 1.0).is_empty());
    }
}
