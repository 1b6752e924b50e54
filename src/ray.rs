//! Rays in world space and their image in a grid's index space.

use crate::error::{Error, Result};
use crate::math::{two_prod, two_sum};
use glam::DVec3;

/// A world-space ray segment `p(t) = origin + t * direction`, `t` in `[t_min, t_max]`.
/// The direction is normalised on construction, so `t` is world distance along the ray.
///
/// Invariants (checked by every constructor, so the fields are private): finite origin, unit
/// finite direction, `0 <= t_min <= t_max` with `t_min` finite (`t_max` may be infinite).
///
/// ```compile_fail
/// // A struct literal would bypass the checks: it does not compile.
/// let r = umbra::Ray { origin: [0.0; 3], direction: [0.0; 3], t_min: 2.0, t_max: 1.0 };
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    origin: DVec3,
    direction: DVec3,
    t_min: f64,
    t_max: f64,
    lo: Lo,
}

/// What rounding left out of a ray (the low halves of double-doubles): `direction + lo.direction`
/// is the unit vector of the exact vector the ray was made along, to about `2^-104`, for a
/// segment between two points ([`Ray::between`]) and a ray along an exact vector
/// ([`Ray::along_exactly`]: a sun's `-dir`, a sphere light's cone); [`Ray::new`] takes its
/// rounded unit as exact (no cost per camera ray). `t_max + lo.t_max` is the exact length of
/// a segment. Nothing but a far ray's move ([`Ray::moved_to`]) reads them, so a ray's walk is
/// what it always was.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Lo {
    direction: DVec3,
    t_max: f64,
}

/// `|v + v_lo|` as a double-double `(n, n_lo)`, `v` scaled by a power of two first so that its
/// square neither overflows nor underflows; `None` for a zero or non-finite `v`.
fn norm_dd(v: DVec3, v_lo: DVec3) -> Option<(f64, f64)> {
    let m = v.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    let k = m.log2().floor() as i32;
    let (up, down) = (2f64.powi(k), 2f64.powi(-k));
    let (v, v_lo) = (v * down, v_lo * down);
    let (mut s, mut e) = (0.0, 0.0);
    for a in 0..3 {
        let (p, pe) = two_prod(v[a], v[a]);
        let (s2, se) = two_sum(s, p);
        s = s2;
        e += se + pe + 2.0 * v[a] * v_lo[a];
    }
    let (s, e) = two_sum(s, e);
    let n = s.sqrt();
    let n_lo = ((-n).mul_add(n, s) + e) / (2.0 * n);
    Some((n * up, n_lo * up))
}

/// `u - hi` for `u` the unit vector of `v + v_lo` (double-double) and `hi` its rounding:
/// the low half of a ray's direction. Zero when `v` has no length.
pub(crate) fn unit_lo(v: DVec3, v_lo: DVec3, hi: DVec3) -> DVec3 {
    let Some((n, n_lo)) = norm_dd(v, v_lo) else {
        return DVec3::ZERO;
    };
    let m = v.abs().max_element();
    let k = m.log2().floor() as i32;
    let down = 2f64.powi(-k);
    let (v, v_lo, n, n_lo) = (v * down, v_lo * down, n * down, n_lo * down);
    DVec3::from_array(std::array::from_fn(|a| {
        ((-hi[a]).mul_add(n, v[a]) + v_lo[a] - hi[a] * n_lo) / n
    }))
}

impl Ray {
    /// A ray from `origin` along `direction` over `[t_min, t_max]`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for non-finite origin/direction, a zero direction, a NaN or
    /// reversed range, or a negative `t_min`.
    pub fn new(
        origin: impl Into<DVec3>,
        direction: impl Into<DVec3>,
        t_min: f64,
        t_max: f64,
    ) -> Result<Self> {
        let (origin, direction) = (origin.into(), direction.into());
        let bad = |reason: String| Error::InvalidArgument {
            name: "ray".into(),
            reason,
        };
        if !origin.is_finite() {
            return Err(bad(format!(
                "origin {} is not finite",
                crate::math::short3(origin.to_array())
            )));
        }
        if !direction.is_finite() {
            return Err(bad(format!(
                "direction {} is not finite",
                crate::math::short3(direction.to_array())
            )));
        }
        // A huge (1e308) or tiny finite direction whose length over- or underflows is scaled by
        // its largest component first; ordinary ones are normalised as they are (bit for bit).
        let mut len = direction.length();
        let direction = if len.is_finite() && len > 1e-150 {
            direction
        } else {
            let d = direction / direction.abs().max_element().max(f64::MIN_POSITIVE);
            len = d.length();
            d
        };
        if len == 0.0 || !len.is_finite() {
            return Err(bad(format!(
                "direction {} has no length",
                crate::math::short3(direction.to_array())
            )));
        }
        if t_min.is_nan() || t_max.is_nan() || t_min > t_max || t_min < 0.0 || t_min.is_infinite() {
            return Err(bad(format!(
                "invalid range [{}, {}]",
                crate::math::short(t_min),
                crate::math::short(t_max)
            )));
        }
        Ok(Self {
            origin,
            direction: direction / len,
            t_min,
            t_max,
            lo: Lo::default(),
        })
    }

    /// The segment from `a` to `b`.
    ///
    /// # Errors
    /// As [`Ray::new`]; `a == b` gives a valid zero-length segment along +x.
    pub fn between(a: impl Into<DVec3>, b: impl Into<DVec3>) -> Result<Self> {
        let (a, b) = (a.into(), b.into());
        let d = b - a;
        // What `b - a` rounded away, per component: the segment's exact vector is `d + d_lo`.
        let d_lo = DVec3::from_array(std::array::from_fn(|k| two_sum(b[k], -a[k]).1));
        let mut len = d.length();
        if len.is_infinite() && d.is_finite() {
            // A finite segment whose squared length overflows (1e300 long): its length scaled.
            let m = d.abs().max_element();
            len = m * (d / m).length();
        }
        if len == 0.0 {
            return Self::new(a, DVec3::X, 0.0, 0.0);
        }
        let mut r = Self::new(a, d, 0.0, len)?;
        r.lo.direction = unit_lo(d, d_lo, r.direction);
        if let Some((n, n_lo)) = norm_dd(d, d_lo) {
            r.lo.t_max = (n - len) + n_lo;
        }
        Ok(r)
    }

    /// The same ray, its low direction taken from the exact vector `v + v_lo` it runs along
    /// (a directional light's `-dir` as given, before any normalisation rounded it; a sphere
    /// light's cone direction in double-double).
    #[must_use]
    pub(crate) fn along_exactly(mut self, v: DVec3, v_lo: DVec3) -> Self {
        self.lo.direction = unit_lo(v, v_lo, self.direction);
        self
    }

    /// The same line and end, from the point at `t` on: origin `origin + t direction` computed
    /// in double-double (`o + t (d + d_lo)`, so a ray made 1e17 from its volume loses nothing
    /// of its line), `t_min - t` (at least 0) and `t_max - t` (with the exact length's low
    /// half). What a walk from a far origin takes instead ([`crate::scene::Scene::localise`]);
    /// `None` when the moved origin is not finite.
    #[must_use]
    pub(crate) fn moved_to(&self, t: f64) -> Option<Self> {
        let origin = DVec3::from_array(std::array::from_fn(|k| {
            let (p, pe) = two_prod(t, self.direction[k]);
            let (s, se) = two_sum(self.origin[k], p);
            s + (se + pe + t * self.lo.direction[k])
        }));
        let t_min = (self.t_min - t).max(0.0);
        let t_max = if self.t_max.is_infinite() {
            f64::INFINITY
        } else {
            let (s, e) = two_sum(self.t_max, -t);
            (s + (e + self.lo.t_max)).max(t_min)
        };
        (origin.is_finite() && t.is_finite()).then_some(Self {
            origin,
            direction: self.direction,
            t_min,
            t_max,
            lo: Lo {
                direction: self.lo.direction,
                t_max: 0.0,
            },
        })
    }

    /// World-space origin.
    #[must_use]
    pub fn origin(&self) -> DVec3 {
        self.origin
    }

    /// Unit world-space direction.
    #[must_use]
    pub fn direction(&self) -> DVec3 {
        self.direction
    }

    /// Start of the segment (world units from the origin).
    #[must_use]
    pub fn t_min(&self) -> f64 {
        self.t_min
    }

    /// End of the segment; may be `f64::INFINITY` ("until the ray leaves the volume").
    #[must_use]
    pub fn t_max(&self) -> f64 {
        self.t_max
    }

    /// Length `t_max - t_min` (may be infinite).
    #[must_use]
    pub fn length(&self) -> f64 {
        self.t_max - self.t_min
    }

    /// The same line over `[t_min, t_max]`.
    ///
    /// # Errors
    /// As [`Ray::new`] for the range.
    pub fn with_range(&self, t_min: f64, t_max: f64) -> Result<Self> {
        let mut r = Self::new(self.origin, self.direction, t_min, t_max)?;
        r.lo.direction = self.lo.direction;
        Ok(r)
    }

    /// World point at `t`: `origin + t direction`.
    #[must_use]
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + t * self.direction
    }
}

/// Slab test of the line `q + t d` against the box `[lo, hi]`: the `t` interval inside, or
/// `None`. Zero (and negative-zero) direction components are handled without dividing.
#[must_use]
pub fn clip_box(
    q: impl Into<DVec3>,
    d: impl Into<DVec3>,
    lo: impl Into<DVec3>,
    hi: impl Into<DVec3>,
) -> Option<(f64, f64)> {
    let (q, d, lo, hi) = (q.into(), d.into(), lo.into(), hi.into());
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for a in 0..3 {
        if d[a] == 0.0 {
            if q[a] < lo[a] || q[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (u, v) = ((lo[a] - q[a]) / d[a], (hi[a] - q[a]) / d[a]);
        t0 = t0.max(u.min(v));
        t1 = t1.min(u.max(v));
    }
    (t0 <= t1).then_some((t0, t1))
}

impl Error {
    /// [`Error::NotANumber`] for `what` (`optical depth`, `... transmittance estimate`) on
    /// `ray`, naming its origin and direction.
    pub(crate) fn nan_on_ray(what: impl Into<String>, ray: &crate::ray::Ray) -> Self {
        Self::NotANumber {
            what: what.into(),
            context: format!(
                " on the ray from {} along {}",
                crate::math::short3(ray.origin().to_array()),
                crate::math::short3(ray.direction().to_array())
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip_handles_axis_parallel_and_negative_zero() {
        let r = clip_box([0.5, 0.5, -5.0], [0.0, -0.0, 1.0], [0.0; 3], [1.0; 3]);
        assert_eq!(r, Some((5.0, 6.0)));
        assert_eq!(
            clip_box([2.0, 0.5, -5.0], [0.0, -0.0, 1.0], [0.0; 3], [1.0; 3]),
            None
        );
    }

    #[test]
    fn a_far_ray_moves_without_losing_its_line() {
        // The line y = 3x through the world origin, from 1e16 away on either side: moved
        // next to the origin, its point still lies on it (a unit direction alone would put
        // it a few units off).
        let (a, b) = ([1e16, 3e16, 0.0], [-1e16, -3e16, 0.0]);
        let r = Ray::between(a, b).unwrap();
        let t = 1e16 * 10f64.sqrt();
        let m = r.moved_to(t).unwrap();
        let o = m.origin();
        assert!(o.x.abs() < 10.0 && (o.y - 3.0 * o.x).abs() < 1e-9, "{o}");
        // The end: b itself, from the new origin.
        assert!((m.at(m.t_max()) - DVec3::from_array(b)).length() < 8.0);
        // A segment 1e300 long has its finite length.
        let r = Ray::between([0.0; 3], [1e300, 1e300, 0.0]).unwrap();
        assert!(r.t_max().is_finite() && (r.t_max() / 1e300 - 2f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn rays_reject_bad_input() {
        assert!(Ray::new([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, 1.0).is_err());
        assert!(Ray::new([0.0; 3], [0.0; 3], 0.0, 1.0).is_err());
        assert!(Ray::new([0.0; 3], [1.0, 0.0, 0.0], 2.0, 1.0).is_err());
        let r = Ray::between([0.0; 3], [0.0, 3.0, 4.0]).ok();
        assert_eq!(
            r.map(|r| (r.t_max(), r.direction().to_array())),
            Some((5.0, [0.0, 0.6, 0.8]))
        );
    }
}
