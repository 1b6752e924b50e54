//! Exact regular tracking: the optical depth `tau = integral of mu_t(p(t)) dt` along a ray, in
//! closed form, and `T = exp(-tau)`. This is umbra's reference answer.
//!
//! - Constant segments (tiles, constant halos) contribute `mu * length`, no lookups.
//! - Nearest (piecewise-constant voxels): inside a segment, a unit DDA in lookup space sums
//!   `mu(voxel) * dt` over the voxels crossed.
//! - Trilinear: inside one dual cell the trilinear field along the ray is a cubic polynomial in
//!   `t` (a product of three linear factors), which two-point Gauss-Legendre quadrature
//!   integrates exactly: `int_a^b f = h (f(m - h/sqrt3) + f(m + h/sqrt3))`, `m = (a+b)/2`,
//!   `h = (b-a)/2`.
//! - The parts of the ray outside every segment have the background density: `mu_bg * gap`.

use crate::error::Result;
use crate::ray::Ray;
use crate::traverse::{dda, lookup_ray, walk, Cells, Granularity, Segment};
use crate::tree::Accessor;
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

/// Exact optical depth along a ray and what it cost.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OpticalDepth {
    /// Optical depth (may be `inf` through opaque voxels or an infinite ray in a non-zero
    /// background).
    pub tau: f64,
    /// Density lookups (voxel reads).
    pub lookups: u64,
    /// HDDA segments visited.
    pub segments: u64,
    /// Voxels (nearest) or dual cells (trilinear) integrated.
    pub cells: u64,
}

impl OpticalDepth {
    /// Transmittance `exp(-tau)`.
    #[must_use]
    pub fn transmittance(&self) -> f64 {
        (-self.tau).exp()
    }
}

const GAUSS: f64 = 0.577_350_269_189_625_8; // 1 / sqrt(3)

/// Exact optical depth of `ray` through `vol`.
///
/// # Errors
/// None at present; the `Result` leaves room for per-query validation.
pub fn optical_depth(vol: &Volume, ray: &Ray, interp: Interp) -> Result<OpticalDepth> {
    let mut acc = Accessor::new(&vol.tree);
    let (q, d) = lookup_ray(vol, ray, interp);
    let scale = vol.density_scale;
    let mut tau = 0.0f64;
    let mut cells = 0u64;
    let w = walk(vol, ray, interp, Granularity::Leaf, |s: Segment| {
        if s.is_constant() {
            tau += s.mu_min * s.length();
        } else {
            tau += scale * integrate_cells(&mut acc, q, d, s.t_min, s.t_max, interp, &mut cells);
        }
        ControlFlow::Continue(())
    });
    let gap = w.length - w.covered;
    let mu_bg = vol.mu_background();
    if mu_bg != 0.0 && gap > 0.0 {
        tau += mu_bg * gap;
    }
    Ok(OpticalDepth {
        tau,
        lookups: acc.lookups(),
        segments: w.segments,
        cells,
    })
}

/// Integral of the (unscaled) density over `[t0, t1]`, cell by cell.
pub(crate) fn integrate_cells(
    acc: &mut Accessor<'_>,
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    interp: Interp,
    cells: &mut u64,
) -> f64 {
    let p0 = [0, 1, 2].map(|a| q[a] + d[a] * t0);
    let p1 = [0, 1, 2].map(|a| q[a] + d[a] * t1);
    let lo = [0, 1, 2].map(|a| p0[a].min(p1[a]).floor() as i64);
    let hi = [0, 1, 2].map(|a| p0[a].max(p1[a]).floor() as i64);
    let mut sum = 0.0f64;
    let grid = Cells { size: 1.0, lo, hi };
    let _ = dda(q, d, (t0, t1), &grid, |c, ta, tb| {
        *cells += 1;
        let ijk = c.map(|v| v as i32);
        sum += match interp {
            Interp::Nearest => f64::from(acc.value(ijk)) * (tb - ta),
            Interp::Trilinear => cubic_cell_integral(acc, ijk, q, d, ta, tb),
        };
        ControlFlow::Continue(())
    });
    sum
}

/// Exact integral of the trilinear field of dual cell `ijk` along `q + t d`, `t` in `[ta, tb]`.
fn cubic_cell_integral(
    acc: &mut Accessor<'_>,
    ijk: [i32; 3],
    q: [f64; 3],
    d: [f64; 3],
    ta: f64,
    tb: f64,
) -> f64 {
    let mut v = [0f64; 8];
    for (n, val) in v.iter_mut().enumerate() {
        let o = [(n >> 2) as i32 & 1, (n >> 1) as i32 & 1, n as i32 & 1];
        *val = f64::from(acc.value([ijk[0] + o[0], ijk[1] + o[1], ijk[2] + o[2]]));
    }
    if v.iter().all(|&x| x == v[0]) {
        return v[0] * (tb - ta);
    }
    let m = 0.5 * (ta + tb);
    let h = 0.5 * (tb - ta);
    let f = |t: f64| {
        let u = [0, 1, 2].map(|a| q[a] + d[a] * t - f64::from(ijk[a]));
        let lerp = |a: f64, b: f64, w: f64| a + (b - a) * w;
        let x0 = lerp(lerp(v[0], v[1], u[2]), lerp(v[2], v[3], u[2]), u[1]);
        let x1 = lerp(lerp(v[4], v[5], u[2]), lerp(v[6], v[7], u[2]), u[1]);
        lerp(x0, x1, u[0])
    };
    h * (f(m - h * GAUSS) + f(m + h * GAUSS))
}
