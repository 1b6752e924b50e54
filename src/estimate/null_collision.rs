//! Free-flight (null-collision) estimators over per-segment majorants. Tentative collisions
//! are a Poisson process of rate `mu_maj` (or a residual rate) within each segment; the
//! expected number of lookups is the integral of that rate along the ray.
//!
//! - `track_length` (delta tracking): a tentative collision is real with probability
//!   `mu / mu_maj`; the estimate is 1 if no real collision happens before the end. Variance
//!   `T (1 - T)`.
//! - `collision`: delta tracking's first real collision `s`, scored with a linear ramp over the
//!   last `h` world units before the end `b` (0 before `b - h`, 1 at `b`): a kernel estimate of
//!   the free-flight CDF. Biased: its mean is the average of `T` over `[b - h, b]`, so it
//!   overestimates `T` by O(h).
//! - `ratio`: never stops; weight `prod (1 - mu / mu_maj)`. `E = exp(-int mu)`;
//!   `Var = T^2 (exp(int mu^2 / mu_maj) - 1)`.
//! - `residual_ratio`: `mu = mu_c + mu_r`; `exp(-int mu_c)` in closed form times ratio tracking
//!   of `mu_r` with rate `r`: minorant control (`r = mu_maj - mu_min`, weights in [0,1]) or
//!   midpoint control (`r = (mu_maj - mu_min) / 2`, weights in [0, 2]: the estimate can exceed 1;
//!   reported raw, unbiased).
//! - `next_flight`: ratio tracking plus, at every tentative collision, the running weight times
//!   the majorant transmittance to the end: `exp(-tau_maj) + sum_k W_k exp(-tau_maj(t_k, b))`.
//!   Never negative, but a sum of positive terms: one sample can exceed 1 (reported raw).
//! - `decomposition`: the minorant is a homogeneous control medium whose transmittance
//!   `exp(-int mu_min)` is exact; delta tracking only through the residual `mu - mu_min` with
//!   rate `mu_maj - mu_min`. Lookups drop from `int mu_maj` to `int (mu_maj - mu_min)`.

use super::medium::RayMedium;
use super::{Cap, Control};
use crate::rng::Rng;
use crate::traverse::Segment;

/// Delta tracking with the track-length estimator.
pub(crate) fn track_length(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    for s in segs {
        if first_real_collision(s, 0.0, m, rng, cap).is_some() {
            return 0.0;
        }
        if cap.hit {
            return 1.0;
        }
    }
    1.0
}

/// First real collision in `s` for the residual above `floor` (delta tracking), or None.
fn first_real_collision(
    s: &Segment,
    floor: f64,
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
) -> Option<f64> {
    let rate = s.mu_maj - floor;
    if rate <= 0.0 {
        return None;
    }
    let mut t = s.t_min;
    loop {
        t += rng.exponential(rate);
        if t >= s.t_max || !cap.take() {
            return None;
        }
        if rng.uniform() * rate < m.mu(t) - floor {
            return Some(t);
        }
    }
}

/// Delta tracking scored with a ramp kernel of width `h` before the end.
pub(crate) fn collision(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
    h: f64,
) -> f64 {
    let Some(end) = segs.last().map(|s| s.t_max) else {
        return 1.0;
    };
    for s in segs {
        if let Some(t) = first_real_collision(s, 0.0, m, rng, cap) {
            return if h > 0.0 {
                ((t - (end - h)) / h).clamp(0.0, 1.0)
            } else {
                0.0
            };
        }
    }
    1.0
}

/// Ratio tracking.
pub(crate) fn ratio(segs: &[Segment], m: &mut RayMedium<'_>, rng: &mut Rng, cap: &mut Cap) -> f64 {
    let mut w = 1.0;
    for s in segs {
        w *= ratio_segment(s, 0.0, s.mu_maj, m, rng, cap);
        if w == 0.0 || cap.hit {
            break;
        }
    }
    w
}

/// Ratio tracking of `mu - mu_c` through one segment with tentative-collision rate `rate`.
fn ratio_segment(
    s: &Segment,
    mu_c: f64,
    rate: f64,
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    if rate <= 0.0 {
        return 1.0;
    }
    let mut w = 1.0;
    let mut t = s.t_min;
    loop {
        t += rng.exponential(rate);
        if t >= s.t_max || !cap.take() {
            return w;
        }
        let x = 1.0 - (m.mu(t) - mu_c) / rate;
        // Mathematically within the weight range; clamp only float round-off at the bounds.
        w *= if mu_c <= s.mu_min {
            x.clamp(0.0, 1.0)
        } else {
            x.clamp(0.0, 2.0)
        };
        if w == 0.0 {
            return 0.0;
        }
    }
}

/// Residual ratio tracking.
pub(crate) fn residual_ratio(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
    control: Control,
) -> f64 {
    let mut w = 1.0;
    for s in segs {
        let (mu_c, rate) = match control {
            Control::Minorant => (s.mu_min, s.mu_maj - s.mu_min),
            Control::Midpoint => (0.5 * (s.mu_min + s.mu_maj), 0.5 * (s.mu_maj - s.mu_min)),
        };
        // Control first: a weight that underflows to 0 stops before the residual weights
        // (which reach 2 per collision with the midpoint control) can overflow to inf * 0.
        w *= (-mu_c * s.length()).exp();
        if w == 0.0 {
            return 0.0;
        }
        w *= ratio_segment(s, mu_c, rate, m, rng, cap);
        if w == 0.0 || !w.is_finite() || cap.hit {
            break;
        }
    }
    w
}

/// Next-flight ratio tracking.
pub(crate) fn next_flight(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    let tau_maj: f64 = segs.iter().map(|s| s.mu_maj * s.length()).sum();
    let mut est = (-tau_maj).exp();
    let mut w = 1.0;
    // Majorant optical depth of the segments after the current one, kept by subtraction (no
    // per-sample table; clamped at 0 against rounding).
    let mut tail = tau_maj;
    'outer: for s in segs {
        tail = (tail - s.mu_maj * s.length()).max(0.0);
        if s.mu_maj <= 0.0 {
            continue;
        }
        let mut t = s.t_min;
        loop {
            t += rng.exponential(s.mu_maj);
            if t >= s.t_max {
                break;
            }
            if !cap.take() {
                break 'outer;
            }
            w *= (1.0 - m.mu(t) / s.mu_maj).clamp(0.0, 1.0);
            if w == 0.0 {
                break 'outer;
            }
            est += w * (-(s.mu_maj * (s.t_max - t) + tail)).exp();
        }
    }
    est
}

/// Decomposition tracking with the minorant as the control medium.
pub(crate) fn decomposition(
    segs: &[Segment],
    m: &mut RayMedium<'_>,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    let mut w = 1.0;
    for s in segs {
        w *= (-s.mu_min * s.length()).exp();
        if first_real_collision(s, s.mu_min, m, rng, cap).is_some() {
            return 0.0;
        }
        if cap.hit {
            break;
        }
    }
    w
}
