//! Small numeric helpers shared by the tree, the traversal and the estimators.

use std::cmp::Ordering;

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

/// Extinction from a value: `mu = scale * v`, with `0 * v = 0` even for an infinite `v` (a zero
/// density scale makes the medium empty, opaque voxels included).
#[inline]
#[must_use]
pub fn scaled(scale: f64, v: f64) -> f64 {
    if scale == 0.0 {
        0.0
    } else {
        scale * v
    }
}

/// A number for a message: plain when moderate, `1e308` rather than 309 digits otherwise.
#[must_use]
pub fn short(v: f64) -> String {
    if v.is_finite() && v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn zero_scale_clears_opaque_values() {
        assert_eq!(scaled(0.0, f64::INFINITY), 0.0);
        assert_eq!(scaled(2.0, 3.0), 6.0);
    }
}
