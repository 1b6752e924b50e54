//! Moment shadow maps for transmittance (Peters and Klein 2015; Peters et al. 2017;
//! Muenstermann et al. 2018): the total optical depth and the first 4 or 6 power moments of the
//! extinction along the ray.
//!
//! **Stored.** On `x = 2u - 1` in `[-1, 1]`, `b_0 = int sigma dx` (the total optical depth) and
//! `m_j = int x^j sigma dx / b_0`, `j = 1..2n` (`n = 2` for `moments:4`, 3 for `moments:6`): the
//! moments of the distribution of extinction over depth. Closed form per profile piece: a linear
//! piece of `dtau` on `[x0, x1]` adds `dtau (x1^(j+1) - x0^(j+1)) / ((j + 1)(x1 - x0))`
//! (summed as `sum_i x1^i x0^(j-i) / (j + 1)`, without cancellation), a jump `dtau x^j`.
//!
//! **Reconstruction** at depth `x`: the fraction `F(x)` of the extinction in front of `x`,
//! bounded by the moments (the Chebyshev-Markov-Stieltjes inequalities), then `T = exp(-b_0 F)`.
//! The moments are first biased toward those of the uniform distribution on `[-1, 1]`
//! (`m* = 1/(j + 1)` for even `j`, 0 for odd): `m' = (1 - beta) m + beta m*`, with `beta`
//! [`BIAS_4`] / [`BIAS_6`], which puts them strictly inside the moment space whatever the f32
//! rounding did (a profile with all its extinction at a few depths lies on its boundary). With the
//! Hankel matrix `B = (m'_(i+j))`, `i, j = 0..n`, the polynomial `c = B^-1 (1, x, ..., x^n)` has
//! `n` real roots `y_i`; `x` and the `y_i` carry the distribution consistent with the moments
//! that puts the most (or least) mass at `x`. Its weights come from the moments through the
//! polynomial `q` of degree `n` interpolating `f(x) = 1/4` (the overestimation of Muenstermann
//! et al.: a quarter of the mass that may lie at `x` counts as in front of it) and
//! `f(y_i) = [y_i < x]`: `F = sum_j q_j m'_j`, clamped to `[0, 1]`. `F` is a distribution
//! function's bound, so it grows with `x` and `T` never grows with depth. A root beyond
//! [`FAR_ROOT`] (where the polynomial's leading coefficient nears 0) carries a weight of order
//! `|y|^(-2n)`; it is dropped and `q` interpolates the other atoms, the bound's limit as the
//! root goes to infinity (keeping it made the result depend on the last bits of the root).

use super::NormProfile;

/// Bias toward the uniform distribution for `moments:4` (f32 storage).
pub const BIAS_4: f64 = 5e-7;
/// Bias toward the uniform distribution for `moments:6` (f32 storage).
pub const BIAS_6: f64 = 5e-6;
/// Roots of the kernel polynomial beyond this are dropped (see [`fraction_before`]).
pub const FAR_ROOT: f64 = 1e3;
/// Share of the mass that may sit at the depth looked up that counts as in front of it.
pub const OVERESTIMATION: f64 = 0.25;

/// `x^e` for `e = 0..=6` as `f64::powi` computes it (square and multiply, the exponent's
/// bits from the lowest), so the table gives the same bits as the calls it replaces.
pub(crate) fn powers(x: f64) -> [f64; 7] {
    let mut out = [1.0f64; 7];
    for (e, o) in out.iter_mut().enumerate().skip(1) {
        let (mut r, mut a, mut b) = (1.0f64, x, e);
        loop {
            if b & 1 == 1 {
                r *= a;
            }
            b /= 2;
            if b == 0 {
                break;
            }
            a *= a;
        }
        *o = r;
    }
    out
}

/// The stored `b_0, m_1, ..., m_k` of profile `p`.
///
/// Each piece's powers of its ends come from a table ([`powers`]), shared with the next piece
/// where the pieces touch: `O(k^2)` multiplications per piece and no `powi` call.
#[must_use]
pub fn encode(p: &NormProfile, k: u32) -> Vec<f32> {
    let k = (k as usize).min(6);
    let mut m = vec![0.0f64; k + 1];
    let mut cache: Option<(f64, [f64; 7])> = None;
    let mut table = |x: f64| match cache {
        Some((c, t)) if c.to_bits() == x.to_bits() => t,
        _ => {
            let t = powers(x);
            cache = Some((x, t));
            t
        }
    };
    for (u0, u1, dtau) in p.pieces() {
        let (x0, x1) = (2.0 * u0 - 1.0, 2.0 * u1 - 1.0);
        let p0 = table(x0);
        if x1 > x0 {
            let p1 = table(x1);
            for (j, mj) in m.iter_mut().enumerate() {
                // sum_i x1^i x0^(j - i) / (j + 1)
                let mut s = 0.0;
                for i in 0..=j {
                    s += p1[i] * p0[j - i];
                }
                *mj += dtau * (s / (j + 1) as f64);
            }
        } else {
            for (j, mj) in m.iter_mut().enumerate() {
                *mj += dtau * p0[j];
            }
        }
    }
    let b0 = m[0];
    let mut out = vec![b0 as f32];
    out.extend(
        m[1..]
            .iter()
            .map(|&v| if b0 > 0.0 { (v / b0) as f32 } else { 0.0 }),
    );
    out
}

/// The optical depth `b_0 F(x)` at `u` (module docs) from stored values `c` (`k + 1`).
#[must_use]
pub fn tau(c: &[f32], u: f64, k: u32) -> f64 {
    let b0 = f64::from(c[0]);
    if b0.is_nan() || b0 <= 0.0 {
        return 0.0;
    }
    let x = (2.0 * u - 1.0).clamp(-1.0, 1.0);
    let beta = if k == 4 { BIAS_4 } else { BIAS_6 };
    let n = k as usize / 2;
    let mut m = [0.0f64; 7];
    m[0] = 1.0;
    for j in 1..=2 * n {
        let star = if j % 2 == 0 {
            1.0 / (j + 1) as f64
        } else {
            0.0
        };
        m[j] = (1.0 - beta) * f64::from(c[j]) + beta * star;
    }
    let f = fraction_before(&m[..=2 * n], x);
    b0 * f
}

/// `F(x)`: the moment bound on the share of the distribution with moments `m` (`m[0] = 1`)
/// in front of `x` (module docs).
fn fraction_before(m: &[f64], x: f64) -> f64 {
    let n = (m.len() - 1) / 2;
    // Solve B c = (1, x, .., x^n) by B = L D L^T.
    let mut rhs = [0.0f64; 4];
    let mut xp = 1.0;
    for r in rhs.iter_mut().take(n + 1) {
        *r = xp;
        xp *= x;
    }
    let Some(c) = solve_hankel(m, n, rhs) else {
        return fallback(m, x);
    };
    let mut atoms = [0.0f64; 4];
    atoms[0] = x;
    let roots = match n {
        2 => quadratic(c[2], c[1], c[0]),
        _ => cubic(c[3], c[2], c[1], c[0]),
    };
    let Some(roots) = roots else {
        return fallback(m, x);
    };
    // A root far outside [-1, 1] carries a weight of order |y|^(-2n) and makes the
    // interpolation ill-conditioned (the leading coefficient near 0): drop it, the limit of the
    // bound as it goes to infinity.
    let mut d = 0;
    for &r in roots.iter().filter(|r| r.abs() <= FAR_ROOT) {
        d += 1;
        atoms[d] = r;
    }
    let mut vals = [0.0f64; 4];
    vals[0] = OVERESTIMATION;
    for i in 1..=d {
        vals[i] = if atoms[i] < x { 1.0 } else { 0.0 };
    }
    // Newton's divided differences, then the monomial coefficients.
    let z = &atoms[..=d];
    let mut dd = vals;
    for lvl in 1..=d {
        for i in (lvl..=d).rev() {
            let den = z[i] - z[i - lvl];
            if den == 0.0 {
                return fallback(m, x);
            }
            dd[i] = (dd[i] - dd[i - 1]) / den;
        }
    }
    let mut poly = [0.0f64; 4];
    poly[0] = dd[d];
    for i in (0..d).rev() {
        // poly = poly (y - z_i) + dd_i
        for j in (1..=d - i).rev() {
            poly[j] = poly[j - 1] - z[i] * poly[j];
        }
        poly[0] = dd[i] - z[i] * poly[0];
    }
    let f: f64 = (0..=d).map(|j| poly[j] * m[j]).sum();
    if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        fallback(m, x)
    }
}

/// Where the bound cannot be formed (a singular system: never for biased moments in practice):
/// all the extinction at the mean depth.
fn fallback(m: &[f64], x: f64) -> f64 {
    if x < m[1] {
        0.0
    } else {
        1.0
    }
}

/// `B c = rhs` for the Hankel matrix `B_ij = m_(i+j)`, `i, j = 0..=n`, by `L D L^T`; `None`
/// when a pivot is not positive.
fn solve_hankel(m: &[f64], n: usize, rhs: [f64; 4]) -> Option<[f64; 4]> {
    let s = n + 1;
    let mut l = [[0.0f64; 4]; 4];
    let mut dg = [0.0f64; 4];
    for i in 0..s {
        for j in 0..=i {
            let mut v = m[i + j];
            for k in 0..j {
                v -= l[i][k] * l[j][k] * dg[k];
            }
            if i == j {
                if v.is_nan() || v <= 0.0 {
                    return None;
                }
                dg[i] = v;
                l[i][i] = 1.0;
            } else {
                l[i][j] = v / dg[j];
            }
        }
    }
    let mut y = rhs;
    for i in 0..s {
        for k in 0..i {
            y[i] -= l[i][k] * y[k];
        }
    }
    for (yi, di) in y.iter_mut().zip(dg).take(s) {
        *yi /= di;
    }
    for i in (0..s).rev() {
        for k in i + 1..s {
            y[i] -= l[k][i] * y[k];
        }
    }
    Some(y)
}

/// Up to three real roots, without an allocation (the reconstruction runs thousands of times
/// per texel while its error is bounded).
#[derive(Debug, Clone, Copy, Default)]
struct Roots {
    r: [f64; 3],
    n: usize,
}

impl Roots {
    fn of(r: &[f64]) -> Self {
        let mut out = Self::default();
        for &x in r {
            out.push(x);
        }
        out
    }

    fn push(&mut self, x: f64) {
        self.r[self.n] = x;
        self.n += 1;
    }

    fn iter(&self) -> impl Iterator<Item = &f64> {
        self.r[..self.n].iter()
    }
}

/// The real roots of `a y^2 + b y + c` (two; a double root twice).
fn quadratic(a: f64, b: f64, c: f64) -> Option<Roots> {
    if a == 0.0 {
        return (b != 0.0).then(|| Roots::of(&[-c / b]));
    }
    let disc = (b * b - 4.0 * a * c).max(0.0);
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return Some(Roots::of(&[0.0, 0.0]));
    }
    Some(Roots::of(&[q / a, c / q]))
}

/// The real roots of `a y^3 + b y^2 + c y + d`, which has three (the kernel polynomial of a
/// positive definite Hankel matrix): the largest in magnitude by the trigonometric solution,
/// polished by two Newton steps, then the other two from the quadratic left by dividing it out
/// from the constant term (stable when that root is large: a root far outside `[-1, 1]`, where
/// the trigonometric solution loses the small ones to cancellation).
fn cubic(a: f64, b: f64, c: f64, d: f64) -> Option<Roots> {
    let scale = a.abs().max(b.abs()).max(c.abs()).max(d.abs());
    if a.abs() <= 1e-14 * scale {
        return quadratic(b, c, d);
    }
    let (b1, c1, d1) = (b / a, c / a, d / a);
    let p = c1 - b1 * b1 / 3.0;
    let q = 2.0 * b1 * b1 * b1 / 27.0 - b1 * c1 / 3.0 + d1;
    let shift = -b1 / 3.0;
    let mut r = if p >= 0.0 {
        // One real root numerically: the cube root of -q.
        (-q).cbrt() + shift
    } else {
        let m = 2.0 * (-p / 3.0).sqrt();
        let phi = (3.0 * q / (p * m)).clamp(-1.0, 1.0).acos() / 3.0;
        (0..3)
            .map(|k| m * (phi - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos() + shift)
            .fold(0.0f64, |acc, y| if y.abs() > acc.abs() { y } else { acc })
    };
    for _ in 0..2 {
        let f = ((a * r + b) * r + c) * r + d;
        let df = (3.0 * a * r + 2.0 * b) * r + c;
        if df != 0.0 {
            r -= f / df;
        }
    }
    if r == 0.0 {
        return quadratic(a, b, c).map(|mut v| {
            v.push(0.0);
            v
        });
    }
    // a y^3 + b y^2 + c y + d = (y - r)(qa y^2 + qb y + qc), from the constant term up.
    let qc = -d / r;
    let qb = (qc - c) / r;
    let qa = (qb - b) / r;
    let mut out = quadratic(qa, qb, qc)?;
    out.push(r);
    Some(out)
}
