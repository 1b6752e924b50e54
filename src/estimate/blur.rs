//! Motion-blurred estimates: the shutter mean of the transmittance through the advected
//! density `rho_t(x) = rho(x - S v(x) t / F)` (`crate::motion`).
//!
//! The ray is cut by the blurred bounds ([`BlurBounds`], walked by `bound_segments`: one segment
//! per run of `8^3` blocks, minorant and majorant valid at every shutter time, or one segment
//! under the whole grid's bounds with `--global-majorant`); the background outside them is
//! closed form. The minorant is what the controls of `residual-ratio` and `decomposition` take
//! in closed form, as on a still grid. Then:
//! - marchers (`riemann`, `mc`, `jittered`): each sample is the mean over `K` stratified
//!   shutter times `t_k = o + (k + u_k) / K (c - o)`, `u_k` uniform from the stream of sample
//!   index `i K + k`, each time marched as the still estimator marches it. For the
//!   deterministic `riemann` the `K` times are the samples the error bar is made of.
//! - every other estimator (null collisions, power series): sample `i` draws its own time
//!   uniformly from its stream, then walks the segments of that time's interval of the shutter
//!   ([`crate::motion::IntervalBounds`]: bounds that hold over the interval only, much tighter
//!   than the whole shutter's; the ray is cut under an interval's bounds when a sample first
//!   lands in it): the mean over samples is unbiased for the shutter mean whenever the
//!   estimator is unbiased for one time.
//!
//! Segments with an infinite majorant (opaque voxels nearby) are integrated at each sample's
//! time by a fine midpoint march ([`BlurredMedium::exact`], quarter-voxel steps): there is no
//! closed form through a warped density. `regular` is refused: it is exact only for a still
//! grid.

use super::{marching, Algo, Cap, Estimate, Estimator, Extinction, Options};
use crate::error::{Error, Result};
use crate::estimate::error_bar::{Bounds, SampleRange, Spread};
use crate::math::{floor_i64, scaled};
use crate::motion::{BlurBounds, Motion, VelocityLookup};
use crate::ray::Ray;
use crate::rng::Rng;
use crate::traverse::{dda, Cells, Segment};
use crate::tree::Accessor;
use crate::volume::{Interp, Volume};
use glam::{DAffine3, DVec3};
use std::ops::ControlFlow;

/// Step of the fine march that stands in for an exact integral, in voxels.
const FINE_STEP: f64 = 0.25;

/// The error bar of a blurred marcher that traced one shutter time in all: unknown (`NaN`,
/// `null` in JSON), never the 0 of a single value.
pub const UNKNOWN_STD_ERR: f64 = f64::NAN;

/// Whether an estimate of `est` may carry [`UNKNOWN_STD_ERR`]: a marcher on a volume that
/// moves (`moving`). Everywhere else a NaN error bar is a fault, as a NaN value always is.
#[must_use]
pub fn may_be_unknown(est: &Estimator, moving: bool) -> bool {
    moving && est.marches()
}

/// The line a volume with motion refuses `regular` with.
pub const REGULAR_REFUSED: &str = "regular tracking is exact only for a still grid; with a \
    velocity use riemann, mc or jittered (marching over stratified shutter times) or a \
    null-collision estimator (ratio, residual-ratio, track-length, next-flight, decomposition: \
    a time per sample)";

/// The extinction along one ray at one shutter time: the density read at `x - k v(x)`.
#[derive(Debug, Clone)]
pub struct BlurredMedium<'v> {
    density: Accessor<'v>,
    velocity: VelocityLookup<'v>,
    index_from_world: DAffine3,
    origin: DVec3,
    dir: DVec3,
    shift: f64,
    interp: Interp,
    scale: f64,
    voxels_per_world: f64,
    /// World displacement per unit of velocity at the current time, `S t / F`.
    k: f64,
    lookups: u64,
    /// The ray in lookup space (`q + d t`): marchers cut their spans at its `8^3` blocks.
    lattice: ([f64; 3], [f64; 3]),
}

impl<'v> BlurredMedium<'v> {
    /// The medium of `vol` (moving as `m` says) along `ray`, at the shutter time 0.
    #[must_use]
    pub fn new(vol: &'v Volume, m: &'v Motion, ray: &Ray, interp: Interp) -> Self {
        let lattice = crate::traverse::lookup_ray(vol, ray, interp);
        Self {
            density: Accessor::new(vol.tree()),
            velocity: m.field().lookup(),
            index_from_world: vol.index_from_world(),
            origin: ray.origin(),
            dir: ray.direction(),
            shift: interp.shift(),
            interp,
            scale: vol.density_scale(),
            voxels_per_world: vol.to_index_dir(ray.direction()).length(),
            k: 0.0,
            lookups: 0,
            lattice,
        }
    }

    /// Read the density at shutter time `t` (frames) from now on.
    pub fn set_time(&mut self, m: &Motion, t: f64) {
        self.k = m.spec().displacement_per_velocity(t);
    }

    /// Density evaluations so far (a velocity read and a density read each).
    #[must_use]
    pub fn lookups(&self) -> u64 {
        self.lookups
    }
}

impl BlurredMedium<'_> {
    /// The world point at distance `t` and the velocity there.
    #[inline]
    fn point_and_velocity(&mut self, t: f64) -> (DVec3, DVec3) {
        let p = self.origin + self.dir * t;
        (p, self.velocity.at(p))
    }

    /// The extinction at `p` moved by `-k v` (one density lookup).
    #[inline]
    fn mu_moved(&mut self, p: DVec3, v: DVec3, k: f64) -> f64 {
        self.lookups += 1;
        let y = p - k * v;
        let u = self.index_from_world.transform_point3(y).to_array();
        let q = u.map(|c| c + self.shift);
        let v = match self.interp {
            Interp::Nearest => self.density.value_at(q.map(floor_i64)),
            Interp::Trilinear => self.density.trilinear(q),
        };
        scaled(self.scale, f64::from(v))
    }
}

impl Extinction for BlurredMedium<'_> {
    #[inline]
    fn mu(&mut self, t: f64) -> f64 {
        let (p, v) = self.point_and_velocity(t);
        self.mu_moved(p, v, self.k)
    }

    /// A midpoint march of `FINE_STEP` voxels (no closed form through a warped density).
    fn exact(&mut self, t0: f64, t1: f64) -> f64 {
        let len = t1 - t0;
        if len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return 0.0;
        }
        let n = ((len * self.voxels_per_world / FINE_STEP).ceil()).clamp(1.0, 1e7) as u64;
        let h = len / n as f64;
        (0..n).map(|i| self.mu(t0 + (i as f64 + 0.5) * h) * h).sum()
    }

    fn voxels_per_world_unit(&self) -> f64 {
        self.voxels_per_world
    }

    /// The lookup lattice of the still grid: a blurred march lays its pieces on the chords
    /// of the `8^3` blocks the midpoints lie in, so a blurred map swept block by block
    /// (`bake::trace::sweep::blur`) takes the same points.
    fn lattice(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.lattice)
    }
}

/// `riemann` at every shutter time at once: its midpoints do not depend on the time, so the
/// velocity at each is read once and the density once per time,
/// `tau_k += mu(p - k_k v(p)) dt` with `k_k = S t_k / F` (`ks`); the same sums, in the same
/// order, as marching each time on its own.
fn riemann_times(
    segs: &[Segment],
    m: &mut BlurredMedium<'_>,
    step: f64,
    ks: &[f64],
    taus: &mut [f64],
) {
    let h = marching::step_world(m.voxels_per_world_unit(), step);
    taus.fill(0.0);
    marching::for_chords(segs, m.lattice(), h, |a, n, dt, _| {
        for i in 0..n {
            let (p, v) = m.point_and_velocity(a + (i as f64 + 0.5) * dt);
            for (tau, &k) in taus.iter_mut().zip(ks) {
                *tau += m.mu_moved(p, v, k) * dt;
            }
        }
    });
}

/// The segments of the index-space line `q + d t` over `[t0, t1]` inside `bounds`' dense box,
/// in order, each with the minorant and majorant `scale * (min, max)` of its blocks as
/// `range` gives them (runs of equal bounds merged), or with `global`, one segment under the
/// whole grid's bounds (`--global-majorant`); returns the length of `[t0, t1]` outside the
/// box (background).
fn bound_segments(
    (bounds, range): (&BlurBounds, impl Fn([i64; 3]) -> (f32, f32)),
    (q, d): ([f64; 3], [f64; 3]),
    (t0, t1): (f64, f64),
    (scale, global): (f64, bool),
    out: &mut Vec<Segment>,
) -> f64 {
    let total = (t1 - t0).max(0.0);
    let Some((a, b)) = bounds.clip(q, d, (t0, t1)) else {
        return total;
    };
    let (lo, dims) = bounds.dense_box();
    if global {
        let (lo, hi) = bounds.global_range();
        out.push(Segment {
            t_min: a,
            t_max: b,
            mu_min: scaled(scale, f64::from(lo)),
            mu_maj: scaled(scale, f64::from(hi)),
            level: 4,
        });
        return total - (b - a);
    }
    let cells = Cells {
        size: 8.0,
        lo,
        hi: [0, 1, 2].map(|k| lo[k] + dims[k] as i64 - 1),
    };
    let start = out.len();
    let _ = dda(q, d, (a, b), &cells, |c, ta, tb| {
        let (lo, hi) = range(c);
        let (mu_min, mu) = (scaled(scale, f64::from(lo)), scaled(scale, f64::from(hi)));
        let run = out.len() > start;
        match out.last_mut() {
            Some(s) if run && s.mu_maj == mu && s.mu_min == mu_min && s.t_max == ta => {
                s.t_max = tb;
            }
            _ => out.push(Segment {
                t_min: ta,
                t_max: tb,
                mu_min,
                mu_maj: mu,
                level: 0,
            }),
        }
        ControlFlow::Continue(())
    });
    total - (b - a)
}

/// The blurred transmittance estimate of `est` along `ray` (module docs).
///
/// # Errors
/// [`Error::InvalidArgument`] (name `estimator`) for `regular`.
pub(crate) fn estimate(
    vol: &Volume,
    m: &Motion,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Result<Estimate> {
    if est.algo().0 == Algo::Regular {
        return Err(Error::InvalidArgument {
            name: "estimator".into(),
            reason: REGULAR_REFUSED.into(),
        });
    }
    let run = |s: &mut Scratch| estimate_in(vol, m, ray, (ray_id, est, opts), s);
    Ok(SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut s) => run(&mut s),
        // Re-entered on this thread (not done today): fresh buffers rather than a panic.
        Err(_) => run(&mut Scratch::default()),
    }))
}

/// Buffers [`estimate`] fills and empties for each ray, kept per thread so that a warm thread
/// allocates nothing per ray.
#[derive(Debug, Default)]
struct Scratch {
    part: RayPart,
    /// The ray's parts under each interval's bounds ([`crate::motion::IntervalBounds`]), cut
    /// when a sample first draws a time in that interval.
    layers: Layers,
    /// `riemann`'s stratum times, their displacements per velocity, and their optical depths
    /// (then their transmittances).
    times: Vec<f64>,
    ks: Vec<f64>,
    taus: Vec<f64>,
}

thread_local! {
    /// Per-thread buffers of [`estimate`].
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// [`estimate`] (`regular` already refused) in the buffers `s`.
fn estimate_in(
    vol: &Volume,
    m: &Motion,
    ray: &Ray,
    (ray_id, est, opts): (u64, &Estimator, &Options),
    s: &mut Scratch,
) -> Estimate {
    s.part.fill(vol, m, ray, (opts.global_majorant, None));
    let part = &s.part;
    if part.segs.is_empty() && part.opaque.is_empty() {
        return Estimate {
            value: (-part.tau_known).exp(),
            std_err: 0.0,
            lookups: 0,
            segments: 0,
            samples: 1,
            capped: 0,
            majorant_violations: 0,
            tau: Some(part.tau_known),
            spread: Spread::default(),
        };
    }
    let mut medium = BlurredMedium::new(vol, m, ray, opts.interp);
    let mut bounds = Bounds::of_segments(part.tau_known, &part.segs);
    if !part.opaque.is_empty() {
        // An opaque voxel may lie on the ray at some shutter time: nothing bounds T below.
        bounds.lo = 0.0;
    }
    let (samples, w) = if let (Algo::Riemann, step) = est.algo() {
        let mut w = Walks::new(marcher_spread(bounds));
        let bufs = (&mut s.times, &mut s.ks, &mut s.taus);
        riemann_strata(
            part,
            &mut medium,
            m,
            step,
            (opts.seed, ray_id),
            bufs,
            &mut w.spread,
        );
        (1, w)
    } else {
        let samples = if est.is_deterministic() {
            1
        } else {
            opts.samples.max(1)
        };
        let spread = if est.marches() {
            marcher_spread(bounds)
        } else {
            Spread::of(est, bounds)
        };
        let mut w = Walks::new(spread);
        s.layers
            .reset((vol, m), !est.marches() && !opts.global_majorant);
        let parts = (part, &mut s.layers);
        sampled(
            parts,
            (vol, m, ray),
            &mut medium,
            est,
            opts,
            (ray_id, samples),
            &mut w,
        );
        (samples, w)
    };
    // One shutter time in all (`--time-samples 1`, one sample): nothing says how T varies
    // over the shutter, so the error bar is unknown rather than the 0 of a single value.
    let std_err = if est.marches() {
        marcher_std_err(&w.spread)
    } else {
        w.spread.std_err()
    };
    Estimate {
        value: w.spread.mean,
        std_err,
        lookups: medium.lookups(),
        segments: (part.segs.len() + part.opaque.len()) as u64,
        samples,
        capped: w.capped,
        majorant_violations: w.violations,
        tau: None,
        spread: w.spread,
    }
}

/// A ray cut by the blurred bounds: the sampled segments, those with an infinite majorant, and
/// the background's optical depth outside them.
#[derive(Debug, Default)]
struct RayPart {
    segs: Vec<Segment>,
    opaque: Vec<Segment>,
    tau_known: f64,
}

impl RayPart {
    /// This ray's parts, in the buffers already held: under the whole shutter's bounds, or
    /// under those of interval `layer` ([`crate::motion::IntervalBounds`]).
    fn fill(
        &mut self,
        vol: &Volume,
        m: &Motion,
        ray: &Ray,
        (global, layer): (bool, Option<usize>),
    ) {
        let q = vol.to_index(ray.origin()).to_array();
        let d = vol.to_index_dir(ray.direction()).to_array();
        self.segs.clear();
        self.opaque.clear();
        let range = (ray.t_min(), ray.t_max());
        let scale = (vol.density_scale(), global);
        let whole = m.bounds();
        let intervals = layer.map(|j| (j, m.intervals(vol.tree(), vol.index_from_world())));
        let bounds = |c| {
            match intervals {
                Some((j, iv)) => iv.block_range(j, c),
                None => None,
            }
            .unwrap_or_else(|| whole.block_range(c))
        };
        let gap = bound_segments((whole, bounds), (q, d), range, scale, &mut self.segs);
        let mu_bg = vol.mu_background();
        self.tau_known = if mu_bg != 0.0 && gap > 0.0 {
            mu_bg * gap
        } else {
            0.0
        };
        let opaque = |s: &Segment| s.mu_maj > 0.0 && !s.mu_maj.is_finite();
        self.opaque
            .extend(self.segs.iter().filter(|s| opaque(s)).copied());
        self.segs.retain(|s| s.mu_maj > 0.0 && s.mu_maj.is_finite());
    }

    /// `T` of the ray at the medium's current time given the sampled part's `t`: the closed
    /// form outside, the opaque segments by the fine march.
    fn transmittance(&self, medium: &mut BlurredMedium<'_>, t: f64) -> f64 {
        let tau_opaque: f64 = self
            .opaque
            .iter()
            .map(|s| medium.exact(s.t_min, s.t_max))
            .sum();
        (-self.tau_known).exp() * (-tau_opaque).exp() * t
    }
}

/// A ray's parts under each interval's bounds, each cut on first use.
#[derive(Debug, Default)]
struct Layers {
    parts: Vec<RayPart>,
    /// Whether `parts[j]` holds this ray's part.
    cut: Vec<bool>,
    /// Whether the intervals are used on this ray (more than one kept, and wanted).
    used: bool,
}

impl Layers {
    /// Forget the last ray's parts; use the intervals of `m` when `wanted` and kept.
    fn reset(&mut self, (vol, m): (&Volume, &Motion), wanted: bool) {
        let count = if wanted {
            m.intervals(vol.tree(), vol.index_from_world()).count()
        } else {
            1
        };
        self.used = wanted && count > 1;
        if !self.used {
            return;
        }
        if self.parts.len() < count {
            self.parts.resize_with(count, RayPart::default);
        }
        self.cut.clear();
        self.cut.resize(count, false);
    }

    /// The part of the interval holding shutter fraction `f` of the ray (cut now if not yet),
    /// or `whole` when the intervals are not used.
    fn part<'a>(
        &'a mut self,
        whole: &'a RayPart,
        (vol, m, ray): (&Volume, &Motion, &Ray),
        f: f64,
    ) -> &'a RayPart {
        if !self.used {
            return whole;
        }
        let j = m
            .intervals(vol.tree(), vol.index_from_world())
            .interval_of(f);
        if !self.cut[j] {
            self.parts[j].fill(vol, m, ray, (false, Some(j)));
            self.cut[j] = true;
        }
        &self.parts[j]
    }
}

/// What the walks of one ray gave: their spread, capped samples and majorant violations.
struct Walks {
    spread: Spread,
    capped: u64,
    violations: u64,
}

impl Walks {
    fn new(spread: Spread) -> Self {
        Self {
            spread,
            capped: 0,
            violations: 0,
        }
    }
}

/// `riemann` over the `K` stratified times of stream `(seed, ray_id)`: every stratum's time
/// from its stream, then one march for all of them ([`riemann_times`]); each stratum's `T`
/// is a value of `spread` (see [`time_range`]).
fn riemann_strata(
    part: &RayPart,
    medium: &mut BlurredMedium<'_>,
    m: &Motion,
    step: f64,
    (seed, ray_id): (u64, u64),
    (times, ks, taus): (&mut Vec<f64>, &mut Vec<f64>, &mut Vec<f64>),
    spread: &mut Spread,
) {
    strata_times(m.spec(), (seed, ray_id), times, ks);
    taus.resize(ks.len(), 0.0);
    riemann_times(&part.segs, medium, step, ks, taus);
    for (&t, tau) in times.iter().zip(taus.iter_mut()) {
        medium.set_time(m, t);
        *tau = part.transmittance(medium, (-*tau).exp());
        spread.push(*tau);
    }
}

/// `riemann`'s `K` stratified shutter times of stream `(seed, ray_id)`,
/// `t_k = o + (k + u_k) / K (c - o)` with `u_k` the first uniform of sample `k`'s stream, into
/// `times`, and their displacements per velocity `S t_k / F` into `ks`.
pub(crate) fn strata_times(
    spec: &crate::motion::MotionSpec,
    (seed, ray_id): (u64, u64),
    times: &mut Vec<f64>,
    ks: &mut Vec<f64>,
) {
    let strata = spec.time_samples();
    times.clear();
    times.extend((0..strata).map(|k| {
        let u = Rng::new(seed, ray_id, u64::from(k)).uniform();
        spec.time_at((f64::from(k) + u) / f64::from(strata))
    }));
    ks.clear();
    ks.extend(times.iter().map(|&t| spec.displacement_per_velocity(t)));
}

/// The spread a blurred marcher's values go into on a ray whose `T` lies in `bounds` at every
/// shutter time (see [`time_range`]).
pub(crate) fn marcher_spread(bounds: Bounds) -> Spread {
    Spread::new(Some(time_range(bounds)), bounds)
}

/// A blurred marcher's error bar from its values' `spread`: [`UNKNOWN_STD_ERR`] for one
/// shutter time in all (nothing says how `T` varies over the shutter), else the spread's.
pub(crate) fn marcher_std_err(spread: &Spread) -> f64 {
    if spread.n < 2 {
        UNKNOWN_STD_ERR
    } else {
        spread.std_err()
    }
}

/// `samples` samples of `est` along the ray of `ray_id`: a marcher's sample is the mean of
/// `K` walks at stratified times, any other estimator's one walk at a uniform time; each time
/// is drawn first from the walk's own stream.
fn sampled(
    (whole, layers): (&RayPart, &mut Layers),
    (vol, m, ray): (&Volume, &Motion, &Ray),
    medium: &mut BlurredMedium<'_>,
    est: &Estimator,
    opts: &Options,
    (ray_id, samples): (u64, u32),
    w: &mut Walks,
) {
    // A marcher's values are its strata (each one of the error bar's, see [`time_range`]);
    // any other estimator's value is its one walk.
    let marches = est.marches();
    let strata = if marches { m.spec().time_samples() } else { 1 };
    for i in 0..samples {
        let mut x = 0.0;
        for k in 0..strata {
            let index = u64::from(i) * u64::from(strata) + u64::from(k);
            let mut rng = Rng::new(opts.seed, ray_id, index);
            let u = rng.uniform();
            let f = (f64::from(k) + u) / f64::from(strata);
            medium.set_time(m, m.spec().time_at(f));
            // One time per sample: the bounds of its interval (a marcher's part is the whole
            // shutter's, `layers` unused).
            let part = layers.part(whole, (vol, m, ray), f);
            let mut cap = Cap::new(opts.max_collisions);
            let t = if part.segs.is_empty() {
                1.0
            } else {
                super::sample_once(est, &part.segs, medium, &mut rng, &mut cap)
            };
            w.capped += u64::from(cap.hit);
            w.violations += cap.violations;
            let tk = part.transmittance(medium, t);
            if marches {
                w.spread.push(tk);
            } else {
                x += tk;
            }
        }
        if !marches {
            w.spread.push(x);
        }
    }
}

/// What the error bar of a blurred marcher knows: `T(t)` lies in the walk's `[L, U]` at every
/// shutter time (the blurred majorants hold over the whole shutter), so each stratum's value
/// lies there too, and a feature of the shutter that the `n = K x samples` times all missed
/// (density crossing the ray for less than a stratum) is an outcome of probability at most
/// `3 / n` somewhere in `[L, U]` ([`super::error_bar`]'s rule of three, `rare`). The spread
/// part is the plain sample variance of the `n` values, `s^2 / n`: for one jittered time per
/// stratum it is at least the variance of the stratified mean (`E[s^2] = mean within-stratum
/// variance + the spread of the stratum means`), so it never claims the stratification's gain.
fn time_range(bounds: Bounds) -> SampleRange {
    SampleRange {
        a: bounds.lo,
        b: bounds.hi,
        rare: true,
    }
}
