//! A 3D digital differential analyser (Amanatides & Woo) over cubic cells of edge `size`,
//! restricted to an inclusive range of cell indices. Cells come in ray order with the exact `t`
//! interval the ray spends in each; zero-length visits (at edges and corners) are skipped.
//! Every step moves one axis's cell index one step in the ray's direction, so the walk ends
//! after at most the number of cells in the range: no stall, no infinite loop.

use std::cmp::Ordering;
use std::ops::ControlFlow;

/// A lattice of cubic cells of edge `size`, restricted to the cell indices `[lo, hi]` (per axis,
/// inclusive): cell `c` covers `[c * size, (c + 1) * size)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cells {
    /// Cell edge.
    pub size: f64,
    /// Smallest cell index per axis.
    pub lo: [i64; 3],
    /// Largest cell index per axis.
    pub hi: [i64; 3],
}

/// `floor(x) as i64` (saturating; NaN gives 0) without a libm call: the default x86-64 target
/// has no `roundsd`, so `f64::floor` is a function call in the hottest loops.
#[inline]
#[must_use]
pub fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// True if `[t0, t1]` is a non-empty interval (false for NaN ends).
#[inline]
#[must_use]
pub fn non_empty(t0: f64, t1: f64) -> bool {
    t0.partial_cmp(&t1) == Some(Ordering::Less)
}

/// Visit the cells crossed by `q + t d` for `t` in `[t0, t1]`. The visitor gets the cell index
/// and its `t` interval and may stop the walk with `ControlFlow::Break`.
#[inline]
pub fn dda(
    q: [f64; 3],
    d: [f64; 3],
    (t0, t1): (f64, f64),
    cells: &Cells,
    mut visit: impl FnMut([i64; 3], f64, f64) -> ControlFlow<()>,
) -> ControlFlow<()> {
    if !non_empty(t0, t1) {
        return ControlFlow::Continue(());
    }
    let Cells { size, lo, hi } = *cells;
    let mut cell = [0i64; 3];
    let mut step = [0i64; 3];
    let mut t_next = [f64::INFINITY; 3];
    for a in 0..3 {
        let p = q[a] + d[a] * t0;
        cell[a] = floor_i64(p / size).clamp(lo[a], hi[a]);
        step[a] = if d[a] > 0.0 {
            1
        } else if d[a] < 0.0 {
            -1
        } else {
            0
        };
        t_next[a] = boundary_t(q[a], d[a], cell[a], size);
    }
    let mut t = t0;
    loop {
        let axis = if t_next[0] <= t_next[1] && t_next[0] <= t_next[2] {
            0
        } else if t_next[1] <= t_next[2] {
            1
        } else {
            2
        };
        let t_exit = t_next[axis].min(t1);
        if t_exit > t {
            visit(cell, t, t_exit)?;
            t = t_exit;
        }
        if t_exit >= t1 || step[axis] == 0 {
            return ControlFlow::Continue(());
        }
        cell[axis] += step[axis];
        if cell[axis] < lo[axis] || cell[axis] > hi[axis] {
            return ControlFlow::Continue(());
        }
        t_next[axis] = boundary_t(q[axis], d[axis], cell[axis], size);
    }
}

/// `t` at which the ray leaves cell `c` along one axis (infinity if it never does).
#[inline]
fn boundary_t(q: f64, d: f64, c: i64, size: f64) -> f64 {
    if d > 0.0 {
        ((c + 1) as f64 * size - q) / d
    } else if d < 0.0 {
        (c as f64 * size - q) / d
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells(q: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> Vec<([i64; 3], f64, f64)> {
        let mut v = Vec::new();
        let cells = Cells {
            size: 1.0,
            lo: [-100; 3],
            hi: [100; 3],
        };
        let _ = dda(q, d, (t0, t1), &cells, |c, a, b| {
            v.push((c, a, b));
            ControlFlow::Continue(())
        });
        v
    }

    #[test]
    fn axis_aligned_ray_from_a_boundary_visits_each_cell_once() {
        let v = cells([0.0, 0.5, 0.5], [1.0, 0.0, -0.0], 0.0, 3.0);
        assert_eq!(v.iter().map(|c| c.0[0]).collect::<Vec<_>>(), vec![0, 1, 2]);
        assert!(v.windows(2).all(|w| w[0].2 == w[1].1));
        assert_eq!((v[0].1, v[2].2), (0.0, 3.0));
    }

    #[test]
    fn negative_direction_starting_on_a_boundary() {
        let v = cells([3.0, 0.5, 0.5], [-1.0, 0.0, 0.0], 0.0, 2.0);
        assert_eq!(v.iter().map(|c| c.0[0]).collect::<Vec<_>>(), vec![2, 1]);
    }

    #[test]
    fn diagonal_through_corners_covers_the_range_contiguously() {
        let v = cells([0.0; 3], [1.0, 1.0, 1.0], 0.0, 4.0);
        let total: f64 = v.iter().map(|c| c.2 - c.1).sum();
        assert!((total - 4.0).abs() < 1e-12);
        assert!(v.windows(2).all(|w| w[0].2 == w[1].1));
        assert_eq!(v.len(), 4, "zero-length corner visits are skipped: {v:?}");
    }

    #[test]
    fn fast_floor_matches_floor() {
        for x in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.9999,
            -2.0001,
            1e300,
            -1e300,
            9.3e18,
            -9.3e18,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            4503599627370497.0,
            -4503599627370497.5,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn huge_coordinates_make_progress() {
        let q = [1.0e6 + 0.25, -1.0e6 + 0.5, 3.0e6];
        let (mut n, mut total) = (0, 0.0);
        let cells = Cells {
            size: 1.0,
            lo: [i64::MIN / 2; 3],
            hi: [i64::MAX / 2; 3],
        };
        let _ = dda(q, [0.6, 0.0, 0.8], (0.0, 50.0), &cells, |_, a, b| {
            assert!(b > a);
            n += 1;
            total += b - a;
            ControlFlow::Continue(())
        });
        // 30 x-crossings and 39 z-crossings, 10 of which coincide (zero-length visits skipped).
        assert_eq!(n, 60);
        assert!((total - 50.0f64).abs() < 1e-9);
    }
}
