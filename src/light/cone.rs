//! The cone of directions from a receiver toward a light with extent, its directions, and the
//! box-level test that it misses everything.

use crate::scene::Scene;
use glam::DVec3;

/// The cone of directions from a receiver toward the light.
#[derive(Debug, Clone, Copy)]
pub(super) enum Cone {
    /// Directions within `acos(1 - one_minus_cos)` of `axis` (`axis + axis_lo` in
    /// double-double: a sphere light 1e16 away subtends 1e-17 radians, below a unit vector's
    /// rounding, and its directions keep it only so).
    Cap {
        axis: DVec3,
        axis_lo: DVec3,
        one_minus_cos: f64,
    },
    /// Every direction (a receiver inside a sphere light).
    All,
}

impl Cone {
    /// The cone from a receiver that sees a sphere of radius `radius` at the offset `v`
    /// (`v + v_lo` exactly): every direction when the receiver is inside it.
    pub(super) fn toward(v: DVec3, v_lo: DVec3, radius: f64) -> Self {
        let d = safe_length(v);
        if d.is_nan() || d <= radius {
            return Self::All;
        }
        let s = radius / d;
        let axis = v / d;
        Self::Cap {
            axis,
            axis_lo: crate::ray::unit_lo(v, v_lo, axis),
            one_minus_cos: s * s / (1.0 + (1.0 - s * s).max(0.0).sqrt()),
        }
    }

    /// `1 - cos(theta_max)`.
    pub(super) fn one_minus_cos(self) -> f64 {
        match self {
            Self::Cap { one_minus_cos, .. } => one_minus_cos,
            Self::All => 2.0,
        }
    }

    /// The direction of the lattice point `(u, v)` in `[0, 1)^2`, uniform in solid angle:
    /// `b1 sin(theta) cos(phi) + b2 sin(theta) sin(phi) + axis cos(theta)`, with what
    /// rounding left out of it (`(hi, lo)`, double-double): the axis's own low half and the
    /// parts of `cos(theta)` and of the sum a tiny cone loses, so that a direction `1e-17`
    /// off the axis is still off it.
    pub(super) fn direction_dd(self, u: f64, v: f64) -> (DVec3, DVec3) {
        let omc = self.one_minus_cos();
        let x = u * omc;
        let (cos, cos_lo) = crate::math::two_sum(1.0, -x);
        let sin = (x * (2.0 - x)).max(0.0).sqrt();
        let (s, c) = (std::f64::consts::TAU * v).sin_cos();
        let (axis, axis_lo) = match self {
            Self::Cap { axis, axis_lo, .. } => (axis, axis_lo),
            Self::All => (DVec3::Z, DVec3::ZERO),
        };
        let (b1, b2) = basis(axis);
        let off = b1 * (sin * c) + b2 * (sin * s);
        let hi = off + axis * cos;
        let lo = DVec3::from_array(std::array::from_fn(|k| {
            let (p, pe) = crate::math::two_prod(axis[k], cos);
            let (h, he) = crate::math::two_sum(off[k], p);
            (h - hi[k]) + he + pe + axis[k] * cos_lo + axis_lo[k] * cos
        }));
        (hi, lo)
    }
}

/// An orthonormal basis around the unit vector `n` (Duff et al. 2017, branchless).
pub(super) fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0_f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// `|v|` without overflow or underflow in its squares (a light at 1e300).
pub(super) fn safe_length(v: DVec3) -> f64 {
    let m = v.abs().max_element();
    if m > 0.0 && m.is_finite() {
        m * (v / m).length()
    } else {
        m
    }
}

/// Whether every ray of the cone from `p` provably misses every volume's box and every
/// solid's box (each box's bounding sphere lies outside the cone): `T = 1` exactly. A sun's
/// rays, a sphere light's segments and an area light's all lie in their cone.
pub(super) fn misses_everything(scene: &Scene, p: DVec3, cone: Cone) -> bool {
    let Cone::Cap {
        axis,
        one_minus_cos,
        ..
    } = cone
    else {
        return false;
    };
    // Angles from sines (`2 asin(sqrt(omc / 2))`, `atan2(|to x axis|, to . axis)`): an acos
    // of a cosine near 1 is off by 1e-8 radians, far more than a sphere light 1e16 away
    // subtends.
    let half = 2.0 * (one_minus_cos / 2.0).clamp(0.0, 1.0).sqrt().asin();
    let boxes = scene
        .fogs()
        .iter()
        .map(|f| f.volume().box_corners().ok())
        .chain(scene.solids().iter().map(|s| s.box_corners().ok()));
    boxes.flatten().all(|c| {
        let lo = c.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
        let hi = c.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
        let (centre, rho) = ((lo + hi) / 2.0, (hi - lo).length() / 2.0);
        let to = centre - p;
        let dist = to.length();
        if !dist.is_finite() || dist <= rho {
            return false;
        }
        let apart = to.cross(axis).length().atan2(to.dot(axis));
        apart > half + (rho / dist).asin() + 1e-9
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_stay_in_the_cone_and_are_unit() {
        let axis = DVec3::new(0.3, -0.8, 0.2).normalize();
        let omc = 1.0 - 4f64.to_radians().cos();
        let cone = Cone::Cap {
            axis,
            axis_lo: DVec3::ZERO,
            one_minus_cos: omc,
        };
        for (u, v) in [(0.0, 0.0), (0.999, 0.5), (0.5, 0.25), (1.0, 0.9)] {
            let d = cone.direction_dd(u, v).0;
            assert!((d.length() - 1.0).abs() < 1e-12);
            assert!(d.dot(axis) >= 1.0 - omc - 1e-12);
        }
        // u = 1 is the rim, u = 0 the axis.
        assert!((cone.direction_dd(1.0, 0.3).0.dot(axis) - (1.0 - omc)).abs() < 1e-12);
        assert!((cone.direction_dd(0.0, 0.3).0.dot(axis) - 1.0).abs() < 1e-12);
    }
}
