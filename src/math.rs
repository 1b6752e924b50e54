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

/// A computed number for a message: four significant digits, scientific outside
/// `[1e-3, 1e6)` (`143.8`, `2.413e12`), trailing zeros dropped.
#[must_use]
pub fn approx(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    let trim = |s: String| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    if (1e-3..1e6).contains(&v.abs()) {
        let decimals = (3 - v.abs().log10().floor() as i32).max(0) as usize;
        trim(format!("{v:.decimals$}"))
    } else {
        let s = format!("{v:.3e}");
        match s.split_once('e') {
            Some((m, e)) => format!("{}e{e}", trim(m.to_string())),
            None => s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approx_keeps_four_significant_digits() {
        assert_eq!(approx(143.819_331_106_774_37), "143.8");
        assert_eq!(approx(2.412_904_760_169_872_6e12), "2.413e12");
        assert_eq!(approx(0.140_589), "0.1406");
        assert_eq!(approx(16.0), "16");
        assert_eq!(approx(1.5e-5), "1.5e-5");
        assert_eq!(approx(0.0), "0");
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
    fn zero_scale_clears_opaque_values() {
        assert_eq!(scaled(0.0, f64::INFINITY), 0.0);
        assert_eq!(scaled(2.0, 3.0), 6.0);
    }
}
