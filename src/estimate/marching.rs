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

/// `2^63`: below it a non-negative `f64` truncates to the same integer as `i64` and as `u64`.
const I64_RANGE: f64 = 9_223_372_036_854_775_808.0;

/// `(n, L / n)`: the fewest equal pieces of a chord of length `len` no longer than the step
/// (within [`PIECE_SLACK`]), `n = ceil(L / h - slack)`, at least 1.
pub(crate) fn pieces(len: f64, step_world: f64) -> (u64, f64) {
    let x = len / step_world;
    let y = x - x * PIECE_SLACK;
    // `ceil(y)` without a libm call (baseline x86-64 has no rounding instruction): the
    // truncation, plus one when it fell short (NaN truncates to 0). Below `2^63` through
    // `i64`, the same numbers in one conversion instruction each way (baseline x86-64 has
    // none for `u64`, whose emulation put a long dependency chain on every chord).
    if y < I64_RANGE {
        let t = y as i64;
        let n = if (t as f64) < y { t + 1 } else { t }.max(1);
        return (n as u64, len / n as f64);
    }
    let t = y as u64;
    let n = if (t as f64) < y {
        t.saturating_add(1)
    } else {
        t
    }
    .max(1);
    (n, len / n as f64)
}

/// `2^52`: from `2^52` to `2^53` the `f64`s are the integers, so `(y + 2^52) - 2^52` is `y`
/// rounded to an integer for `0 <= y < 2^52`.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// [`pieces`] of `N` chords at once: lane `l`'s chord of length `len[l]` at step `h[l]`, its
/// count into `n[l]` and its piece length into `dt[l]`: the same numbers as [`pieces`]
/// (`ceil(y)` by rounding through [`TWO_52`], with no integer conversion), in a loop of
/// independent lanes that compiles to vector divisions. False (the outputs then unspecified)
/// when a lane's count is not below `2^52` or is NaN: the caller then asks [`pieces`].
#[inline(always)]
fn pieces_of<const N: usize>(
    len: &[f64; N],
    h: &[f64; N],
    n: &mut [f64; N],
    dt: &mut [f64; N],
) -> bool {
    let mut ok = true;
    for l in 0..N {
        let x = len[l] / h[l];
        let y = x - x * PIECE_SLACK;
        ok &= y < TWO_52;
        // For 1 < y < 2^52: the nearest integer, then `floor`, then `ceil`; at most 1: one.
        let r = (y + TWO_52) - TWO_52;
        let floor = if r > y { r - 1.0 } else { r };
        let ceil = if floor < y { floor + 1.0 } else { floor };
        n[l] = if y > 1.0 { ceil } else { 1.0 };
        dt[l] = len[l] / n[l];
    }
    ok
}

/// [`pieces_of`] built for an instruction set: `$name` with `$feature` enabled.
macro_rules! pieces_for {
    ($name:ident, $feature:literal, $doc:literal) => {
        #[doc = $doc]
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feature)]
        #[allow(unsafe_code)]
        unsafe fn $name<const N: usize>(
            len: &[f64; N],
            h: &[f64; N],
            n: &mut [f64; N],
            dt: &mut [f64; N],
        ) -> bool {
            pieces_of(len, h, n, dt)
        }
    };
}
pieces_for!(
    pieces_avx512,
    "avx512f",
    "[`pieces_of`] built for AVX-512F (8 lanes a division)."
);
pieces_for!(
    pieces_avx2,
    "avx2",
    "[`pieces_of`] built for AVX2 (4 lanes a division)."
);

/// [`pieces`] of the chords `0..used` of a batch (lane `l`: length `len[l]`, step `h[l]`):
/// the count into `n[l]` and the piece length as `f32` into `dt[l]`, the same numbers lane by
/// lane as [`pieces`] gives (IEEE divisions and conversions are exact whatever the register
/// width). The divisions go `simd`'s width at a time; a count of `2^52` or more, or NaN, goes
/// through [`pieces`]. Lanes from `used` on are left as they are.
pub(crate) fn pieces_lanes<const N: usize>(
    simd: crate::regular::kernel::Simd,
    (len, h): (&[f64; N], &[f64; N]),
    used: usize,
    n: &mut [u32; N],
    dt: &mut [f32; N],
) {
    use crate::regular::kernel::Simd;
    let (mut nf, mut df) = ([0.0f64; N], [0.0f64; N]);
    let ok = match simd {
        // SAFETY: `Simd::Avx512` and `Simd::Avx2` are chosen only on CPUs that report them
        // (`Simd::detected`).
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        Simd::Avx512 => unsafe { pieces_avx512(len, h, &mut nf, &mut df) },
        #[cfg(target_arch = "x86_64")]
        #[allow(unsafe_code)]
        Simd::Avx2 => unsafe { pieces_avx2(len, h, &mut nf, &mut df) },
        _ => pieces_of(len, h, &mut nf, &mut df),
    };
    for l in 0..used.min(N) {
        if ok {
            // `nf` is a whole number in [1, 2^52): `as u64` is exact, then the kernel's `u32`.
            (n[l], dt[l]) = (nf[l] as u64 as u32, df[l] as f32);
        } else {
            let (count, d) = pieces(len[l], h[l]);
            (n[l], dt[l]) = (count as u32, d as f32);
        }
    }
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
    fn pieces_of_a_batch_are_the_pieces_of_each_chord() {
        use crate::regular::kernel::Simd;
        let levels = [Simd::Portable, Simd::Avx2, Simd::Avx512];
        let mut rng = Rng::new(7, 0, 0);
        let edges = [
            0.0,
            -1.0,
            1e-300,
            1.0,
            1.0 + 1e-9,
            8.000_000_000_000_002,
            8.001,
            7.5,
            16.0 - 1e-12,
            1e17,
            f64::INFINITY,
            f64::NAN,
        ];
        for round in 0..400 {
            let mut len = [0.0f64; 16];
            let mut h = [1.0f64; 16];
            for l in 0..16 {
                let u = rng.uniform();
                len[l] = match (round + l) % 5 {
                    // Whole steps, as chords across whole voxels come.
                    0 => (u * 14.0).round() * 0.25,
                    1 => u * 14.0,
                    _ if round < 40 => edges[(round + l) % edges.len()],
                    _ => u * 1e3,
                };
                h[l] = [0.25, 0.5, 1.0, 1.5, 0.1, 1e-9][(round + 3 * l) % 6];
            }
            let used = 1 + round % 16;
            for &simd in levels.iter().filter(|&&s| s <= Simd::detected()) {
                let (mut n, mut dt) = ([u32::MAX; 16], [f32::NAN; 16]);
                pieces_lanes(simd, (&len, &h), used, &mut n, &mut dt);
                for l in 0..16 {
                    if l < used {
                        let (count, d) = pieces(len[l], h[l]);
                        assert_eq!(n[l], count as u32, "{simd:?} lane {l} len {}", len[l]);
                        assert_eq!(dt[l].to_bits(), (d as f32).to_bits(), "{simd:?} {}", len[l]);
                    } else {
                        assert_eq!(n[l], u32::MAX, "lanes past `used` are left alone");
                    }
                }
            }
        }
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
