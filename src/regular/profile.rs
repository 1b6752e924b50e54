//! Exact optical-depth profiles: `tau(t)` along a ray as a piecewise-linear function, for deep
//! shadow maps.
//!
//! The walk is regular tracking's (closed-form tiles, a DDA per voxel or dual cell), recording
//! breakpoints `(t_k, tau_k)` instead of only the sum:
//! - constant segments (tiles, constant halos, the background in the gaps) are linear in `t`:
//!   their ends are breakpoints, exactly;
//! - nearest lookups: each voxel is a constant extinction, so every voxel boundary is a
//!   breakpoint and the profile is exact;
//! - trilinear lookups: inside a dual cell `mu(t)` is a cubic and `tau(t)` a quartic. A piece
//!   `[a, b]` on which `mu` stays within a range of width `D` deviates from its chord by at
//!   most `D (b - a) / 4` (write `mu = m + r`, `0 <= r <= D`: `int_a^t r - s int_a^b r`, `s =
//!   (t - a)/(b - a)`, lies in `[-s(1-s) D (b-a), s(1-s) D (b-a)]`). The 8 corner values bound
//!   `mu` on the cell, so a cell piece of length `L` is cut into
//!   `m = ceil(D L / (4 tol))` equal pieces, each breakpoint's `tau` exact (two-point
//!   Gauss-Legendre on the cubic). With `tol = E exp(tau(a))` the chord's transmittance is
//!   within `E` of the exact one everywhere on the piece, since `|exp(-x) - exp(-y)| <=
//!   exp(-min(x, y)) |x - y|` and both are at least `tau(a)` there.
//!
//! So `|exp(-tau_lin(t)) - exp(-tau(t))| <= E` at every depth, with `E` the caller's
//! `max_error` (a cell needing more than [`MAX_PIECES`] pieces is cut into that many and
//! counted in [`Profile::coarse_cells`]).

use super::{cell_range, cubic_cell_integral, AccSource, Counts, GAUSS};
use crate::error::{Error, Result};
use crate::math::non_empty;
use crate::ray::Ray;
use crate::traverse::{lookup_ray, walk_nodes, Dda, Granularity, Segment};
use crate::tree::Accessor;
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

/// Most pieces one trilinear dual cell is cut into.
pub const MAX_PIECES: usize = 4096;

/// The optical depth along a ray as a function of depth `t`: breakpoints `(t_k, tau_k)`, `t`
/// increasing from the ray's start (`tau = 0` there), `tau` non-decreasing, linear between
/// consecutive breakpoints. An opaque voxel (`+inf`) ends the profile: `tau` is infinite from
/// [`Profile::opaque_at`] on.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Profile {
    t: Vec<f64>,
    tau: Vec<f64>,
    opaque_at: Option<f64>,
    coarse_cells: u64,
    lookups: u64,
}

impl Profile {
    /// Depths of the breakpoints (world units along the ray).
    #[must_use]
    pub fn t(&self) -> &[f64] {
        &self.t
    }

    /// Optical depth from the ray's start at each breakpoint.
    #[must_use]
    pub fn tau(&self) -> &[f64] {
        &self.tau
    }

    /// Where the ray meets an opaque voxel (`tau = inf` from there on), if it does.
    #[must_use]
    pub fn opaque_at(&self) -> Option<f64> {
        self.opaque_at
    }

    /// Trilinear cells that needed more than [`MAX_PIECES`] pieces for the error bound (the
    /// bound does not hold inside them).
    #[must_use]
    pub fn coarse_cells(&self) -> u64 {
        self.coarse_cells
    }

    /// Voxel values read.
    #[must_use]
    pub fn lookups(&self) -> u64 {
        self.lookups
    }

    /// The profile's optical depth at `t`: linear between breakpoints, 0 before the first,
    /// the last value after the last, infinite from [`Profile::opaque_at`] on.
    #[must_use]
    pub fn at(&self, t: f64) -> f64 {
        if self.opaque_at.is_some_and(|o| t >= o) {
            return f64::INFINITY;
        }
        let k = self.t.partition_point(|&x| x <= t);
        match k {
            0 => 0.0,
            k if k == self.t.len() => self.tau[k - 1],
            k => {
                let (t0, t1) = (self.t[k - 1], self.t[k]);
                let (a, b) = (self.tau[k - 1], self.tau[k]);
                if t1 > t0 {
                    a + (b - a) * (t - t0) / (t1 - t0)
                } else {
                    b
                }
            }
        }
    }

    fn push(&mut self, t: f64, tau: f64) {
        match self.t.last() {
            Some(&last) if t < last => {}
            Some(&last) if t == last => {
                if let Some(x) = self.tau.last_mut() {
                    *x = x.max(tau);
                }
            }
            _ => {
                self.t.push(t);
                self.tau.push(tau);
            }
        }
    }
}

/// The exact optical-depth profile of `ray` through `vol` (module docs): piecewise linear,
/// its transmittance within `max_error` of the exact `exp(-tau(t))` at every depth of the ray.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `deep-error`) for `max_error` outside `(0, 1)`;
/// [`Error::NotANumber`] for a walk through leaves a partial load did not read.
pub fn optical_depth_profile(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    max_error: f64,
) -> Result<Profile> {
    if !(max_error > 0.0 && max_error < 1.0) {
        return Err(Error::InvalidArgument {
            name: "deep-error".into(),
            reason: format!("{max_error}: an error bound between 0 and 1 (in T)"),
        });
    }
    walk_profile(vol, ray, interp, max_error, true)
}

/// [`optical_depth_profile`] with the bound on optical depth instead: `|tau_lin(t) - tau(t)|
/// <= max_tau_error` at every depth (what a sum of several volumes' profiles needs: the
/// errors add, weighted by each volume's extinction colour).
///
/// # Errors
/// As [`optical_depth_profile`], for `max_tau_error` not finite and positive.
pub fn optical_depth_profile_tau(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    max_tau_error: f64,
) -> Result<Profile> {
    if !(max_tau_error > 0.0 && max_tau_error.is_finite()) {
        return Err(Error::InvalidArgument {
            name: "deep-error".into(),
            reason: format!("{max_tau_error}: an optical-depth error bound above 0"),
        });
    }
    walk_profile(vol, ray, interp, max_tau_error, false)
}

/// The walk of both profiles: the tolerance of a piece starting at optical depth `tau` is
/// `e exp(tau)` (`relative`, a bound in T) or `e` (a bound in tau).
fn walk_profile(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    e: f64,
    relative: bool,
) -> Result<Profile> {
    let mut acc = Accessor::new(vol.tree());
    let mut n = Counts::default();
    let (q, d) = lookup_ray(vol, ray, interp);
    let mu_bg = vol.mu_background();
    let mut b = Builder {
        p: Profile::default(),
        tau: 0.0,
        q,
        d,
        du: [0, 1, 2].map(|a| d[a] * GAUSS),
        scale: vol.density_scale(),
        max_error: e,
        relative,
    };
    let mut last = ray.t_min();
    b.p.push(last, 0.0);
    let w = walk_nodes(vol, ray, interp, Granularity::Leaf, |s: Segment, _| {
        if s.t_min > last {
            b.tau += mu_bg * (s.t_min - last);
            b.p.push(s.t_min, b.tau);
        }
        last = last.max(s.t_max);
        if s.is_constant() {
            b.tau += s.mu_min * s.length();
            if b.tau.is_infinite() {
                b.p.opaque_at = Some(s.t_min);
                return ControlFlow::Break(());
            }
            b.p.push(s.t_max, b.tau);
            return ControlFlow::Continue(());
        }
        if !non_empty(s.t_min, s.t_max) {
            return ControlFlow::Continue(());
        }
        b.cells(&mut acc, &mut n, interp, (s.t_min, s.t_max));
        if b.p.opaque_at.is_some() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    let Builder { mut p, mut tau, .. } = b;
    if w.unloaded || tau.is_nan() {
        return Err(Error::nan_on_ray("optical depth profile", ray));
    }
    if p.opaque_at.is_none() && ray.t_max() > last && ray.t_max().is_finite() {
        tau += mu_bg * (ray.t_max() - last);
        if tau.is_infinite() {
            p.opaque_at = Some(last);
        } else {
            p.push(ray.t_max(), tau);
        }
    }
    p.lookups = n.reads;
    Ok(p)
}

/// A profile being walked ([`walk_profile`]): its breakpoints so far and the optical depth
/// `tau` reached; the ray `q + t d` in lookup space (`du = GAUSS d`, for the Gauss points), the
/// density scale, and the tolerance `max_error` (in T when `relative`, else in tau).
struct Builder {
    p: Profile,
    tau: f64,
    q: [f64; 3],
    d: [f64; 3],
    du: [f64; 3],
    scale: f64,
    max_error: f64,
    relative: bool,
}

impl Builder {
    /// The cells of a segment `[t0, t1]` of a leaf with varying values, by the DDA of `interp`:
    /// a breakpoint at each voxel's end (nearest) or each dual cell cut within the tolerance
    /// (trilinear), until the ray turns opaque.
    fn cells(
        &mut self,
        acc: &mut Accessor<'_>,
        n: &mut Counts,
        interp: Interp,
        (t0, t1): (f64, f64),
    ) {
        let (q, d) = (self.q, self.d);
        let (lo, hi) = cell_range(q, d, t0, t1);
        let dda = Dda::new(q, d, t0, lo, hi);
        let mut src = AccSource { acc, cell: [0; 3] };
        match interp {
            Interp::Nearest => {
                super::nearest_walk(&mut src, dda, q, d, t1, lo, hi, n, |v, ta, tb| {
                    self.voxel(v, ta, tb);
                })
            }
            Interp::Trilinear => {
                super::trilinear_walk(&mut src, dda, q, d, t1, lo, hi, n, |v, cell, ta, tb| {
                    self.cell(v, cell, ta, tb);
                });
            }
        }
    }

    /// A voxel of value `v` on `[ta, tb]`: `tau += scale v (tb - ta)`, exactly linear.
    fn voxel(&mut self, v: f64, ta: f64, tb: f64) {
        let p = &mut self.p;
        if p.opaque_at.is_some() {
            return;
        }
        self.tau += self.scale * v * (tb - ta);
        if self.tau.is_infinite() {
            p.opaque_at = Some(ta);
        } else {
            p.push(tb, self.tau);
        }
    }

    /// A dual cell with corner values `v` on `[ta, tb]`: cut into `m = ceil(D L / (4 tol))`
    /// equal pieces (at most [`MAX_PIECES`]), `D` the spread of its corners' extinction, each
    /// breakpoint's `tau` exact (module docs).
    fn cell(&mut self, v: &[f64; 8], cell: [i64; 3], ta: f64, tb: f64) {
        let p = &mut self.p;
        if p.opaque_at.is_some() {
            return;
        }
        if v.iter().any(|x| x.is_infinite()) {
            p.opaque_at = Some(ta);
            return;
        }
        let (lo_v, hi_v) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        let spread = self.scale * (hi_v - lo_v);
        let tol = if self.relative {
            self.max_error * self.tau.exp().min(1e300)
        } else {
            self.max_error
        };
        let want = (spread * (tb - ta) / (4.0 * tol)).ceil();
        let m = if want.is_finite() && want >= 1.0 {
            want.min(MAX_PIECES as f64) as usize
        } else {
            1
        };
        if want > MAX_PIECES as f64 {
            p.coarse_cells += 1;
        }
        let h = (tb - ta) / m as f64;
        let mut a = ta;
        for k in 1..=m {
            let b = if k == m { tb } else { ta + h * k as f64 };
            self.tau += self.scale * cubic_cell_integral(v, cell, self.q, self.d, self.du, a, b);
            if self.tau.is_infinite() {
                p.opaque_at = Some(a);
                return;
            }
            p.push(b, self.tau);
            a = b;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    fn volume() -> Volume {
        let mut b = TreeBuilder::new(0.0);
        let mut s = 7u64;
        for x in -4..20 {
            for y in -3..5 {
                for z in -3..5 {
                    s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                    let v = ((s >> 40) as f32 / (1u64 << 24) as f32) * 3.0;
                    b.set([x, y, z], if (s >> 20).is_multiple_of(5) { 0.0 } else { v });
                }
            }
        }
        b.tile([64, 0, 0], 3, 0.5);
        let tree = b.build();
        let m = [
            [0.5, 0.0, 0.0, 0.1],
            [0.0, 0.5, 0.0, -0.2],
            [0.0, 0.0, 0.5, 0.3],
        ];
        Volume::from_tree("t".into(), tree, m, 1.0).unwrap()
    }

    /// The profile ends at the exact optical depth, is monotone, and its transmittance stays
    /// within E of the exact prefix transmittance at many depths, for both interpolations.
    #[test]
    fn profile_matches_exact_prefixes() {
        let vol = volume();
        for interp in [Interp::Nearest, Interp::Trilinear] {
            for (o, dir) in [
                ([-5.0, 0.3, 0.2], [1.0f64, 0.05, 0.02]),
                ([40.0, 1.1, -0.4], [-1.0, 0.1, 0.07]),
                ([-3.0, -3.0, -3.0], [1.0, 0.8, 0.9]),
            ] {
                let len: f64 = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
                let dir = dir.map(|c| c / len);
                let ray = Ray::new(o, dir, 0.0, 50.0).unwrap();
                let e = 1e-3;
                let p = optical_depth_profile(&vol, &ray, interp, e).unwrap();
                let full = super::super::optical_depth(&vol, &ray, interp).unwrap().tau;
                let last = *p.tau().last().unwrap();
                assert!(
                    (last - full).abs() <= 1e-9 * full.max(1.0),
                    "{last} vs {full}"
                );
                assert!(p.tau().windows(2).all(|w| w[1] >= w[0]));
                assert!(p.t().windows(2).all(|w| w[1] > w[0]));
                for k in 0..=400 {
                    let t = 50.0 * f64::from(k) / 400.0;
                    let exact = super::super::optical_depth(
                        &vol,
                        &Ray::new(o, dir, 0.0, t).unwrap(),
                        interp,
                    )
                    .unwrap()
                    .tau;
                    let gap = ((-p.at(t)).exp() - (-exact).exp()).abs();
                    assert!(gap <= e, "{interp:?} t={t}: {gap}");
                    if interp == Interp::Nearest {
                        assert!((p.at(t) - exact).abs() <= 1e-9 * exact.max(1.0));
                    }
                }
            }
        }
    }

    #[test]
    fn bad_error_bound_is_refused() {
        let vol = volume();
        let ray = Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, 1.0).unwrap();
        for e in [0.0, 1.0, f64::NAN, -1.0] {
            assert!(optical_depth_profile(&vol, &ray, Interp::Trilinear, e).is_err());
        }
    }
}
