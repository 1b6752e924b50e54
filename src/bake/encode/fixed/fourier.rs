//! Fourier opacity maps (Jansen and Bavoil 2010), windowed so that they never lighten.
//!
//! The extinction density `sigma(u) = dtau/du` on `[0, 1]` has the Fourier series
//! `sigma = a_0 + sum_k (a_k cos(2 pi k u) + b_k sin(2 pi k u))` with `a_0 = int sigma` (the total
//! optical depth), `a_k = 2 int sigma cos(2 pi k u) du`, `b_k = 2 int sigma sin(2 pi k u) du`. A
//! profile is piecewise linear in `tau`, so `sigma` is piecewise constant (`s` on `[u0, u1]`) plus
//! point masses (`m` at an opaque depth), and the coefficients are closed form:
//! `s (sin w u1 - sin w u0) / w`, `s (cos w u0 - cos w u1) / w` (`w = 2 pi k`), `m cos w u`,
//! `m sin w u`, each times 2.
//!
//! `fourier:K` keeps `a_0` and `N = (K - 1) / 2` pairs. The reconstruction weights term `k` by
//! Fejer's window `f_k = 1 - k / (N + 1)`: the windowed series is the density convolved with
//! Fejer's kernel, which is non-negative, so it is non-negative wherever `sigma` is (no ringing
//! below zero: `tau` never decreases and `T` never grows with depth). Its integral from 0 is
//!
//! `tau(u) = a_0 u + sum_k f_k (a_k sin(w u) + b_k (1 - cos(w u))) / w`,
//!
//! so `tau(0) = 0` and `tau(1) = a_0`: the map's far value is the exact total. Rounding the
//! coefficients to f32 would break the non-negativity by up to `sum_k f_k (|da_k| + |db_k|)`;
//! the stored `a_0` is raised by that sum (rounded up), which restores it for the stored values.

use super::{f32_up, NormProfile};
use std::f64::consts::TAU;

/// `(sin, cos)` of `2 pi i u` for `i = 1..=n`: one `sin_cos`, the higher harmonics by the angle
/// addition formulas (within a few `n` ulps of the direct values, far below the f32 storage).
fn harmonics(u: f64, n: usize, out: &mut Vec<(f64, f64)>) {
    out.clear();
    let (s1, c1) = (TAU * u).sin_cos();
    let (mut s, mut c) = (s1, c1);
    for _ in 0..n {
        out.push((s, c));
        (s, c) = (s * c1 + c * s1, c * c1 - s * s1);
    }
}

/// The stored coefficients `a_0, a_1, b_1, ..., a_N, b_N` of profile `p` (`k = 2N + 1`).
///
/// The harmonics at a piece's ends ([`harmonics`]) are shared with the next piece where the
/// pieces touch, so a profile of `B` breakpoints costs about `B` `sin_cos` calls whatever `k`.
#[must_use]
pub fn encode(p: &NormProfile, k: u32) -> Vec<f32> {
    let n = (k / 2) as usize;
    let mut c = vec![0.0f64; 2 * n + 1];
    // `ha` gets the harmonics at a piece's start, `hb` at its end; `hb_at` is where `hb`'s are.
    let (mut ha, mut hb) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut hb_at = f64::NAN;
    for (u0, u1, dtau) in p.pieces() {
        c[0] += dtau;
        if hb_at.to_bits() == u0.to_bits() {
            std::mem::swap(&mut ha, &mut hb);
        } else {
            harmonics(u0, n, &mut ha);
        }
        if u1 > u0 {
            harmonics(u1, n, &mut hb);
            hb_at = u1;
            let s = dtau / (u1 - u0);
            for (i, (&(s0, c0), &(s1, c1))) in ha.iter().zip(&hb).enumerate() {
                let w = TAU * (i + 1) as f64;
                c[2 * i + 1] += 2.0 * (s * (s1 - s0) / w);
                c[2 * i + 2] += 2.0 * (s * (c0 - c1) / w);
            }
        } else {
            for (i, &(sn, cs)) in ha.iter().enumerate() {
                c[2 * i + 1] += 2.0 * (dtau * cs);
                c[2 * i + 2] += 2.0 * (dtau * sn);
            }
            std::mem::swap(&mut ha, &mut hb);
            hb_at = u0;
        }
    }
    let mut out: Vec<f32> = c.iter().map(|&v| v as f32).collect();
    // The rounding of the other coefficients, made up for by a_0 (module docs).
    let mut guard = 0.0;
    for i in 1..=n {
        let f = window(i, n);
        guard += f
            * ((f64::from(out[2 * i - 1]) - c[2 * i - 1]).abs()
                + (f64::from(out[2 * i]) - c[2 * i]).abs());
    }
    out[0] = f32_up(c[0] + guard);
    out
}

/// Fejer's weight of term `i` of `n`.
fn window(i: usize, n: usize) -> f64 {
    1.0 - i as f64 / (n + 1) as f64
}

/// The windowed optical depth at `u` (module docs), clamped to `[0, 1]` in `u` and at 0 below.
#[must_use]
pub fn tau(c: &[f32], u: f64) -> f64 {
    let u = u.clamp(0.0, 1.0);
    let n = c.len() / 2;
    let mut t = f64::from(c[0]) * u;
    for i in 1..=n {
        let w = TAU * i as f64;
        let (s, co) = (w * u).sin_cos();
        t += window(i, n) * (f64::from(c[2 * i - 1]) * s + f64::from(c[2 * i]) * (1.0 - co)) / w;
    }
    t.max(0.0)
}
