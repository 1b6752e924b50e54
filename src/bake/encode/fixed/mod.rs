//! Deep shadow maps at a fixed size per texel: the transmittance function along a texel's ray
//! in a fixed number of f32 channels, for renderers and engines that cannot read variable-length
//! OpenEXR deep samples (`bake --deep-format`).
//!
//! **Depth.** Every format works on the normalised depth `u = (z - near) / (far - near)` in
//! `[0, 1]`, `z` the world distance along the texel's ray and `[near, far]` the map's depth range
//! (the camera's `t_near` and `t_max`: no ray meets the volume box before `near`, none is traced
//! past `far`), stored in the header as `umbra:deep_near` and `umbra:deep_far`. Before `u = 0`
//! `T = 1`; past `u = 1`, `T` is the value at `u = 1`.
//!
//! **The formats** (each module has the math):
//!
//! | format | channels | what a texel holds | reconstruction |
//! |---|---|---|---|
//! | `fourier:K` ([`fourier`]) | `K` (odd) | Fourier coefficients of the extinction density in `u` | `T = exp(-tau)`, `tau` the integral of the Fejer-windowed series (Jansen and Bavoil 2010) |
//! | `moments:4`, `moments:6` ([`moments`]) | 5, 7 | total optical depth and 4 or 6 power moments of the extinction in `x = 2u - 1` | `T = exp(-b0 F(x))`, `F` the Hamburger bound of Peters and Klein (biased moments, overestimation 1/4) |
//! | `avsm:K` ([`avsm`]) | `2K` | `K` nodes `(u_i, tau_i)` (Salvi et al. 2010) placed by a minimax fit | `tau` linear between nodes |
//!
//! Each reconstruction gives `T` in `[0, 1]`, non-increasing with depth, for any stored values
//! (the Fejer window keeps the density non-negative, the moment bound is a distribution
//! function, the nodes are sorted), so no shadow lightens behind an occluder.
//!
//! **Error.** [`texel_error`] bounds `sup_u |T_rec(u) - T_prof(u)|` over every depth, not only
//! sampled ones, for the values as stored (f32): both functions are non-increasing, so on an
//! open interval `(a, b)` their difference is at most `max(T_rec(a+) - T_prof(b-), T_prof(a+) -
//! T_rec(b-))`, and intervals whose bound exceeds a threshold are halved until it holds. The map's
//! header reports the largest bound (`umbra:deep_max_error`) plus the profile's own bound against
//! the exact `T`.

pub mod avsm;
pub mod fourier;
pub mod moments;

use crate::error::{Error, Result};

/// Optical depth at which a profile is cut: `exp(-30) = 9.4e-14`, far below any error a
/// format reaches, and finite (an opaque depth is a jump to it).
pub const TAU_CAP: f64 = 30.0;

/// A fixed-size deep format and its size parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeepFormat {
    /// `fourier:K`: `K` Fourier coefficients (odd, 3..=63).
    Fourier(u32),
    /// `moments:4` or `moments:6`: that many power moments and the total optical depth.
    Moments(u32),
    /// `avsm:K`: `K` nodes (2..=32), two channels each.
    Avsm(u32),
}

fn bad_format(s: &str, why: &str) -> Error {
    Error::InvalidArgument {
        name: "deep-format".into(),
        reason: format!("{}: {why}", crate::text::escape(s)),
    }
}

impl std::str::FromStr for DeepFormat {
    type Err = Error;

    /// `fourier:K` (K odd, 3..=63), `moments:4`, `moments:6`, `avsm:K` (2..=32).
    fn from_str(s: &str) -> Result<Self> {
        let expect =
            "expected fourier:K (K odd, 3 to 63), moments:4, moments:6 or avsm:K (K 2 to 32)";
        let (name, k) = s.split_once(':').ok_or_else(|| bad_format(s, expect))?;
        let k: u32 = k.trim().parse().map_err(|_| bad_format(s, expect))?;
        let f = match name.trim().to_ascii_lowercase().as_str() {
            "fourier" if k % 2 == 1 && (3..=63).contains(&k) => Self::Fourier(k),
            "moments" if k == 4 || k == 6 => Self::Moments(k),
            "avsm" if (2..=32).contains(&k) => Self::Avsm(k),
            _ => return Err(bad_format(s, expect)),
        };
        Ok(f)
    }
}

impl std::fmt::Display for DeepFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Fourier(k) => write!(f, "fourier:{k}"),
            Self::Moments(k) => write!(f, "moments:{k}"),
            Self::Avsm(k) => write!(f, "avsm:{k}"),
        }
    }
}

impl DeepFormat {
    /// f32 channels per texel (per colour channel).
    #[must_use]
    pub fn channels(&self) -> usize {
        match *self {
            Self::Fourier(k) => k as usize,
            Self::Moments(k) => k as usize + 1,
            Self::Avsm(k) => 2 * k as usize,
        }
    }

    /// The channels' names in the order [`DeepFormat::encode`] returns values: `a0, a1, b1,
    /// ...` (Fourier), `b0, m1, ..., mK` (moments), `z0, tau0, z1, tau1, ...` (nodes).
    #[must_use]
    pub fn channel_names(&self) -> Vec<String> {
        match *self {
            Self::Fourier(k) => std::iter::once("a0".to_string())
                .chain((1..=k / 2).flat_map(|i| [format!("a{i}"), format!("b{i}")]))
                .collect(),
            Self::Moments(k) => std::iter::once("b0".to_string())
                .chain((1..=k).map(|i| format!("m{i}")))
                .collect(),
            Self::Avsm(k) => (0..k)
                .flat_map(|i| [format!("z{i}"), format!("tau{i}")])
                .collect(),
        }
    }

    /// The texel's stored values (f32, as written) for the normalised profile `p`.
    #[must_use]
    pub fn encode(&self, p: &NormProfile) -> Vec<f32> {
        match *self {
            Self::Fourier(k) => fourier::encode(p, k),
            Self::Moments(k) => moments::encode(p, k),
            Self::Avsm(k) => avsm::encode(p, k),
        }
    }

    /// The optical depth the stored values `c` give at normalised depth `u` (the limit from
    /// the left with `left`, where a format jumps; others are continuous).
    ///
    /// # Panics
    /// Never for `c` of [`DeepFormat::channels`] values; fewer panics (a caller's bug).
    #[must_use]
    pub fn tau(&self, c: &[f32], u: f64, left: bool) -> f64 {
        match *self {
            Self::Fourier(_) => fourier::tau(c, u),
            Self::Moments(k) => moments::tau(c, u, k),
            Self::Avsm(_) => avsm::tau(c, u, left),
        }
    }

    /// `T` at normalised depth `u`: `exp(-tau)`.
    #[must_use]
    pub fn transmittance(&self, c: &[f32], u: f64) -> f64 {
        (-self.tau(c, u, false)).exp()
    }

    /// Whether the reconstruction can jump (then both one-sided limits are evaluated).
    fn jumps(&self) -> bool {
        matches!(self, Self::Avsm(_))
    }
}

/// A texel's optical-depth profile on normalised depth: breakpoints `(u_k, tau_k)`, `u` and
/// `tau` non-decreasing, `tau` linear between breakpoints and constant outside them; two
/// breakpoints at one `u` are a jump (an opaque depth, to [`TAU_CAP`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NormProfile {
    u: Vec<f64>,
    tau: Vec<f64>,
}

impl NormProfile {
    /// The profile `tau(t_k) = tau[k]` on `[near, far]`, opaque from `opaque_at` on: `u`
    /// clamped to `[0, 1]`, `tau` made non-decreasing and cut at [`TAU_CAP`], an opaque depth
    /// placed at the nearest f32 of `u` (so the nodes of a format can sit exactly on it).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `deep`) for profiles of different lengths or a depth
    /// range that is empty or not finite.
    pub fn new(
        t: &[f64],
        tau: &[f64],
        opaque_at: Option<f64>,
        (near, far): (f64, f64),
    ) -> Result<Self> {
        let bad = |reason: &str| Error::InvalidArgument {
            name: "deep".into(),
            reason: reason.into(),
        };
        if t.len() != tau.len() {
            return Err(bad(
                "the profile's depths and optical depths differ in number",
            ));
        }
        if !(near.is_finite() && far.is_finite() && far > near) {
            return Err(bad("the map's depth range is empty"));
        }
        let norm = |z: f64| ((z - near) / (far - near)).clamp(0.0, 1.0);
        let (mut us, mut taus) = (
            Vec::with_capacity(t.len() + 2),
            Vec::with_capacity(t.len() + 2),
        );
        let mut run = 0.0f64;
        for (&z, &v) in t.iter().zip(tau) {
            if opaque_at.is_some_and(|o| z >= o) {
                break;
            }
            let v = if v.is_nan() {
                run
            } else {
                v.clamp(run, TAU_CAP)
            };
            run = v;
            us.push(norm(z).max(us.last().copied().unwrap_or(0.0)));
            taus.push(v);
        }
        if let Some(o) = opaque_at {
            let uo = f64::from(norm(o) as f32);
            for u in &mut us {
                *u = u.min(uo);
            }
            us.extend([uo, uo]);
            taus.extend([run, TAU_CAP]);
        }
        Ok(Self { u: us, tau: taus })
    }

    /// Breakpoint depths.
    #[must_use]
    pub fn u(&self) -> &[f64] {
        &self.u
    }

    /// Breakpoint optical depths.
    #[must_use]
    pub fn tau(&self) -> &[f64] {
        &self.tau
    }

    /// The total optical depth (0 for an empty profile).
    #[must_use]
    pub fn total(&self) -> f64 {
        self.tau.last().copied().unwrap_or(0.0)
    }

    /// The pieces of extinction: `(u0, u1, dtau)` per interval where `tau` grows (`u0 == u1`
    /// for a jump).
    pub fn pieces(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        self.u
            .windows(2)
            .zip(self.tau.windows(2))
            .filter(|(_, t)| t[1] > t[0])
            .map(|(u, t)| (u[0], u[1], t[1] - t[0]))
    }

    /// `tau` at `u` (the limit from the left with `left`).
    #[must_use]
    pub fn at(&self, u: f64, left: bool) -> f64 {
        let n = self.u.len();
        if n == 0 {
            return 0.0;
        }
        if left {
            let k = self.u.partition_point(|&x| x < u);
            if k == n {
                return self.tau[n - 1];
            }
            if k == 0 || self.u[k] == u {
                return self.tau[k];
            }
            lerp(self.u[k - 1], self.u[k], self.tau[k - 1], self.tau[k], u)
        } else {
            crate::bake::encode::deep_fit::linear_at(&self.u, &self.tau, u)
        }
    }

    /// Depths where the profile jumps.
    fn jumps(&self) -> impl Iterator<Item = f64> + '_ {
        self.pieces().filter(|p| p.0 == p.1).map(|p| p.0)
    }
}

/// `tau` at `u` on the line through `(u0, t0)` and `(u1, t1)`, `u0 <= u <= u1`.
fn lerp(u0: f64, u1: f64, t0: f64, t1: f64, u: f64) -> f64 {
    if u1 <= u0 {
        return t1;
    }
    let w = ((u - u0) / (u1 - u0)).clamp(0.0, 1.0);
    t0 + (t1 - t0) * w
}

/// Uniform depths at which [`texel_error`] starts (and the RMS error is taken).
pub const ERROR_GRID: usize = 64;

/// What [`texel_error`] found for one texel.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TexelError {
    /// The bound on `sup_u |T_rec(u) - T_prof(u)|` (see the module docs).
    pub bound: f64,
    /// The largest error at an evaluated depth (a lower bound of the supremum).
    pub seen: f64,
    /// The sum of squared errors at the `ERROR_GRID` (64) + 1 uniform depths.
    pub sum_sq: f64,
}

/// Bound `|T_rec - T_prof|` over every depth for the stored values `c` of `format` against
/// the profile `p`: the uniform grid of `ERROR_GRID` (64) intervals and the profile's jumps, then
/// every interval whose bound exceeds `threshold` halved until it does not (or is narrower
/// than `1e-9`).
#[must_use]
pub fn texel_error(format: DeepFormat, c: &[f32], p: &NormProfile, threshold: f64) -> TexelError {
    let both = format.jumps() || p.jumps().next().is_some();
    // (left, right) values of T_rec and T_prof at u.
    let eval = |u: f64| {
        let rec_r = (-format.tau(c, u, false)).exp();
        let prof_r = (-p.at(u, false)).exp();
        if both {
            (
                ((-format.tau(c, u, true)).exp(), rec_r),
                ((-p.at(u, true)).exp(), prof_r),
            )
        } else {
            ((rec_r, rec_r), (prof_r, prof_r))
        }
    };
    let mut pts: Vec<f64> = (0..=ERROR_GRID)
        .map(|i| i as f64 / ERROR_GRID as f64)
        .chain(p.jumps())
        .collect();
    pts.sort_by(f64::total_cmp);
    pts.dedup();
    let mut out = TexelError::default();
    let vals: Vec<_> = pts.iter().map(|&u| eval(u)).collect();
    // The squared errors at the uniform depths (the points on the grid; a jump on a grid point
    // is that point).
    for (&u, ((_, r), (_, q))) in pts.iter().zip(&vals) {
        if (u * ERROR_GRID as f64).fract() == 0.0 {
            out.sum_sq += (r - q) * (r - q);
        }
    }
    for ((rl, rr), (ql, qr)) in &vals {
        out.seen = out.seen.max((rl - ql).abs()).max((rr - qr).abs());
    }
    out.bound = out.seen;
    let gap =
        |(_, rec_a): (f64, f64),
         (_, prof_a): (f64, f64),
         (rec_b, _): (f64, f64),
         (prof_b, _): (f64, f64)| { (rec_a - prof_b).max(prof_a - rec_b).max(0.0) };
    let mut stack: Vec<(f64, f64, _, _)> = pts
        .windows(2)
        .zip(vals.windows(2))
        .map(|(u, v)| (u[0], u[1], v[0], v[1]))
        .collect();
    while let Some((a, b, va, vb)) = stack.pop() {
        let g = gap(va.0, va.1, vb.0, vb.1);
        if g <= threshold.max(out.seen) || b - a < 1e-9 {
            out.bound = out.bound.max(g.min(1.0));
            continue;
        }
        let m = 0.5 * (a + b);
        let vm = eval(m);
        let ((rl, rr), (ql, qr)) = vm;
        out.seen = out.seen.max((rl - ql).abs()).max((rr - qr).abs());
        out.bound = out.bound.max(out.seen);
        stack.push((a, m, va, vm));
        stack.push((m, b, vm, vb));
    }
    out
}

/// `x` rounded up to an f32 (the smallest f32 at or above it).
pub(crate) fn f32_up(x: f64) -> f32 {
    let y = x as f32;
    if f64::from(y) < x {
        y.next_up()
    } else {
        y
    }
}

#[cfg(test)]
mod tests;
