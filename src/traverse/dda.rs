//! The one 3D digital differential analyser (Amanatides & Woo) of umbra. [`Dda`] walks unit
//! cells (`cell c` covers `[c, c + 1)` on each axis) within an inclusive index range; [`dda`]
//! walks cubic cells of any power-of-two edge by scaling the line into unit cells (exact:
//! dividing by a power of two commutes with rounding), calling a visitor per cell. Regular
//! tracking drives a [`Dda`] directly in its per-voxel loops; the hierarchical DDA uses [`dda`]
//! at every node level.
//!
//! Cells come in ray order with the exact `t` interval the ray spends in each; zero-length
//! visits (at edges and corners) are skipped. Ties between axes go to the lower axis. Every
//! step moves one axis's cell index one step in the ray's direction or holds that axis for the
//! rest of the walk (a step out of the range, see [`Dda::advance`]), so the walk ends after at
//! most the number of cells in the range plus three: no stall, no infinite loop, and the
//! visits always cover all of `[t0, t1]`.

use crate::math::{floor_i64, non_empty};
use std::ops::ControlFlow;

/// A lattice of cubic cells of edge `size` (a power of two), restricted to the cell indices
/// `[lo, hi]` (per axis, inclusive): cell `c` covers `[c * size, (c + 1) * size)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cells {
    /// Cell edge.
    pub size: f64,
    /// Smallest cell index per axis.
    pub lo: [i64; 3],
    /// Largest cell index per axis.
    pub hi: [i64; 3],
}

/// The state of a walk over unit cells: current cell, step direction and the `t` of the next
/// boundary on each axis.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Dda {
    /// Where the walk starts.
    pub(crate) t0: f64,
    /// Current cell.
    pub(crate) cell: [i64; 3],
    /// Step per axis: -1, 0 or 1.
    pub(crate) step: [i64; 3],
    /// `t` where the line leaves the current cell on each axis.
    pub(crate) t_next: [f64; 3],
}

impl Dda {
    /// Start the walk of `q + t d` at `t0`, in the cell holding `q + t0 d` clamped to
    /// `[lo, hi]`. Always inlined: as a call (LLVM's choice once the HDDA's recursion grew) it
    /// cost the bare HDDA walk 17 % (perf: 11 % of the time in this function).
    #[inline(always)]
    pub(crate) fn new(q: [f64; 3], d: [f64; 3], t0: f64, lo: [i64; 3], hi: [i64; 3]) -> Self {
        let mut s = Self {
            t0,
            cell: [0; 3],
            step: [0; 3],
            t_next: [f64::INFINITY; 3],
        };
        for a in 0..3 {
            s.cell[a] = floor_i64(q[a] + d[a] * t0).clamp(lo[a], hi[a]);
            s.step[a] = if d[a] > 0.0 {
                1
            } else if d[a] < 0.0 {
                -1
            } else {
                0
            };
            s.t_next[a] = boundary_t(q[a], d[a], s.cell[a]);
        }
        s
    }

    /// The axis whose boundary comes first (ties go to the lower axis).
    #[inline(always)]
    pub(crate) fn axis(&self) -> usize {
        let t = &self.t_next;
        let a = usize::from(t[1] < t[0]);
        let ta = if a == 1 { t[1] } else { t[0] };
        if t[2] < ta {
            2
        } else {
            a
        }
    }

    /// Step along `axis`; false when the cell does not change. A step that would leave
    /// `[lo, hi]` *holds* the axis instead (`t_next[axis] = inf`): every caller's range holds
    /// its whole `[t0, t1]`, so a boundary inside `[t0, t1]` that leads out of it is rounding
    /// (a line a hair off a lattice plane, whose cell by position and by boundary `t`
    /// disagree), and the rest of the walk stays in this cell along `axis`. Stopping there
    /// instead dropped the rest of the segment: up to a whole tile of density.
    #[inline(always)]
    pub(crate) fn advance(
        &mut self,
        axis: usize,
        q: [f64; 3],
        d: [f64; 3],
        lo: [i64; 3],
        hi: [i64; 3],
    ) -> bool {
        if self.step[axis] == 0 {
            return false;
        }
        let c = self.cell[axis] + self.step[axis];
        if c < lo[axis] || c > hi[axis] {
            self.t_next[axis] = f64::INFINITY;
            return false;
        }
        self.cell[axis] = c;
        self.t_next[axis] = boundary_t(q[axis], d[axis], c);
        true
    }
}

/// `t` at which the line leaves unit cell `c` along one axis (infinity if it never does).
#[inline]
fn boundary_t(q: f64, d: f64, c: i64) -> f64 {
    if d > 0.0 {
        ((c + 1) as f64 - q) / d
    } else if d < 0.0 {
        (c as f64 - q) / d
    } else {
        f64::INFINITY
    }
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
    // In units of `size` the cells are unit cells and `t` is unchanged. `1 / size` is exact for
    // a power of two, so `v * (1 / size)` equals `v / size` bit for bit at one division a walk.
    let (q, d) = if size == 1.0 {
        (q, d)
    } else {
        let inv = 1.0 / size;
        (q.map(|v| v * inv), d.map(|v| v * inv))
    };
    let mut w = Dda::new(q, d, t0, lo, hi);
    let mut t = t0;
    loop {
        let axis = w.axis();
        let t_exit = w.t_next[axis].min(t1);
        if t_exit > t {
            visit(w.cell, t, t_exit)?;
            t = t_exit;
        }
        if t_exit >= t1 {
            return ControlFlow::Continue(());
        }
        w.advance(axis, q, d, lo, hi);
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

#[cfg(test)]
mod scaled_cells {
    use super::*;

    /// Cells of edge 8 visited by `dda` are those of the unit walk of the line scaled by 1/8,
    /// with the same `t` intervals.
    #[test]
    fn coarse_cells_are_scaled_unit_cells() {
        let q = [3.25, -17.5, 40.125];
        let d = [0.6, 0.48, -0.64];
        let coarse = Cells {
            size: 8.0,
            lo: [-100; 3],
            hi: [100; 3],
        };
        let unit = Cells {
            size: 1.0,
            ..coarse
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let _ = dda(q, d, (0.0, 90.0), &coarse, |c, t0, t1| {
            a.push((c, t0, t1));
            ControlFlow::Continue(())
        });
        let _ = dda(
            q.map(|v| v / 8.0),
            d.map(|v| v / 8.0),
            (0.0, 90.0),
            &unit,
            |c, t0, t1| {
                b.push((c, t0, t1));
                ControlFlow::Continue(())
            },
        );
        assert_eq!(a, b);
        assert!(a.len() > 10);
    }
}
