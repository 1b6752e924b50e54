//! Rays in world space and their image in a grid's index space.

use crate::error::{Error, Result};
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
        if !(origin.is_finite() && direction.is_finite()) {
            return Err(bad(format!(
                "non-finite origin {origin} or direction {direction}"
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
            return Err(bad(format!("direction {direction} has no length")));
        }
        if t_min.is_nan() || t_max.is_nan() || t_min > t_max || t_min < 0.0 || t_min.is_infinite() {
            return Err(bad(format!("invalid range [{t_min}, {t_max}]")));
        }
        Ok(Self {
            origin,
            direction: direction / len,
            t_min,
            t_max,
        })
    }

    /// The segment from `a` to `b`.
    ///
    /// # Errors
    /// As [`Ray::new`]; `a == b` gives a valid zero-length segment along +x.
    pub fn between(a: impl Into<DVec3>, b: impl Into<DVec3>) -> Result<Self> {
        let (a, b) = (a.into(), b.into());
        let d = b - a;
        let len = d.length();
        if len == 0.0 {
            return Self::new(a, DVec3::X, 0.0, 0.0);
        }
        Self::new(a, d, 0.0, len)
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
        Self::new(self.origin, self.direction, t_min, t_max)
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
                ray.origin(),
                ray.direction()
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
