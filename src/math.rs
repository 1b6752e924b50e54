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

/// A size in bytes for a message, in the binary unit that keeps it readable: `1 byte`,
/// `512 bytes`, `3.5 KiB`, `26.4 MiB`, `1.0 GiB`, up to EiB (one decimal past bytes), so a
/// budget of a few bytes never reads `0.0 MiB`.
#[must_use]
pub fn size(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    match bytes {
        1 => "1 byte".into(),
        b if b < 1024 => format!("{b} bytes"),
        b => {
            let mut v = b as f64 / 1024.0;
            let mut unit = 0;
            while v >= 1024.0 && unit + 1 < UNITS.len() {
                v /= 1024.0;
                unit += 1;
            }
            format!("{v:.1} {}", UNITS[unit])
        }
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

/// A point or vector for a message: `(x, y, z)`, each component as [`short`] writes it
/// (`(NaN, 0, 0)`, `(1e300, 0.5, 0)`).
#[must_use]
pub fn short3(v: [f64; 3]) -> String {
    format!("({}, {}, {})", short(v[0]), short(v[1]), short(v[2]))
}

/// `v` with `digits` significant digits: fixed-point for magnitudes `10^lo ..= 10^hi`
/// (`floor(log10 |v|)` in `lo..=hi`), scientific otherwise; with `trim`, trailing zeros (and a
/// trailing point) of the fixed or mantissa part dropped. Zero and non-finite values as `{v}`.
fn significant(v: f64, digits: i32, (lo, hi): (i32, i32), trim: bool) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let trimmed = |s: String| -> String {
        if trim && s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    let mag = v.abs().log10().floor() as i32;
    if (lo..=hi).contains(&mag) {
        let decimals = usize::try_from((digits - 1 - mag).max(0)).unwrap_or(0);
        trimmed(format!("{v:.decimals$}"))
    } else {
        let decimals = usize::try_from(digits - 1).unwrap_or(0);
        let s = format!("{v:.decimals$e}");
        match s.split_once('e') {
            Some((m, e)) => format!("{}e{e}", trimmed(m.to_string())),
            None => s,
        }
    }
}

/// A computed number for a message: four significant digits, scientific outside
/// `[1e-3, 1e6)` (`143.8`, `2.413e12`), trailing zeros dropped.
#[must_use]
pub fn approx(v: f64) -> String {
    significant(v, 4, (-3, 5), true)
}

/// Three significant digits for report tables, scientific outside `[1e-5, 1e6)`: `0.000123`,
/// `1.23`, `1.23e6`.
#[must_use]
pub fn sig3(v: f64) -> String {
    significant(v, 3, (-5, 5), false)
}

/// The 8 corners of the box `[lo, hi]`, corner `n` taking `hi` on axis `a` when bit `2 - a`
/// The axis-aligned box `[a, b]` holding the image of the box `[lo, hi]` under the affine
/// `map`: the smallest and largest of its 8 corners' images per axis (an affine map takes a box
/// to a parallelepiped whose extremes are at corners).
#[must_use]
pub fn mapped_box(
    map: &glam::DAffine3,
    lo: glam::DVec3,
    hi: glam::DVec3,
) -> (glam::DVec3, glam::DVec3) {
    let inf = glam::DVec3::splat(f64::INFINITY);
    box_corners([lo.to_array(), hi.to_array()])
        .iter()
        .map(|&c| map.transform_point3(c))
        .fold((inf, -inf), |(a, b), w| (a.min(w), b.max(w)))
}

/// of `n` is set (the order of [`crate::Volume::box_corners`]).
#[must_use]
pub fn box_corners([lo, hi]: [[f64; 3]; 2]) -> [glam::DVec3; 8] {
    std::array::from_fn(|n| {
        glam::DVec3::from_array(
            [0, 1, 2].map(|a| if n >> (2 - a) & 1 == 1 { hi[a] } else { lo[a] }),
        )
    })
}

/// A byte count: digits with an optional fraction and a suffix K, M, G or T (powers of 1024,
/// `B`/`iB` allowed: `512M`, `1.5GiB`), or plain bytes.
///
/// # Errors
/// A message saying what is wrong with `s`.
pub fn parse_bytes(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let lower = t.to_ascii_lowercase();
    let body = lower
        .strip_suffix("ib")
        .or_else(|| lower.strip_suffix('b'))
        .unwrap_or(&lower);
    let (num, unit) = match body.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => (&body[..i], c),
        _ => (body, ' '),
    };
    let scale = match unit {
        ' ' => 1u64,
        'k' => 1 << 10,
        'm' => 1 << 20,
        'g' => 1 << 30,
        't' => 1 << 40,
        _ => return Err(format!("{t:?}: the unit must be K, M, G or T")),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("{t:?} is not a size such as 512M or 2G"))?;
    let bytes = v * scale as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("{t:?} is not a size between 1 byte and 8 EiB"));
    }
    Ok(bytes as u64)
}

/// `v / |v|`, or `None` for a zero or non-finite vector. Scaled by its largest component first,
/// so a vector like `(1e308, 0, 0)` (whose length overflows) still has a direction.
pub(crate) fn normalise(v: glam::DVec3) -> Option<glam::DVec3> {
    v.try_normalize().or_else(|| {
        let m = v.abs().max_element();
        (m > 0.0 && m.is_finite())
            .then(|| (v / m).try_normalize())
            .flatten()
    })
}

/// `a + b` as `(s, e)` with `s = fl(a + b)` and `s + e = a + b` exactly (Knuth's two-sum):
/// the double-double sums that keep a far ray's line exact ([`crate::ray::Ray`]).
#[must_use]
pub(crate) fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// `a * b` as `(p, e)` with `p = fl(a b)` and `p + e = a b` exactly (one fused multiply-add).
#[must_use]
pub(crate) fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

#[cfg(test)]
mod tests {

    #[test]
    fn sizes_read_in_the_unit_that_keeps_them_readable() {
        assert_eq!(size(1), "1 byte");
        assert_eq!(size(0), "0 bytes");
        assert_eq!(size(1023), "1023 bytes");
        assert_eq!(size(1536), "1.5 KiB");
        assert_eq!(size(26 << 20), "26.0 MiB");
        assert_eq!(size(u64::MAX), "16.0 EiB");
    }
    use super::*;

    #[test]
    fn three_significant_digits() {
        assert_eq!(sig3(0.000_123_4), "0.000123");
        assert_eq!(sig3(0.045_67), "0.0457");
        assert_eq!(sig3(1.234), "1.23");
        assert_eq!(sig3(123.4), "123");
        assert_eq!(sig3(1_234_567.0), "1.23e6");
    }

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
