//! Transmittance estimators, all behind one interface: [`Estimator`] names an algorithm and its
//! parameters, [`estimate`] runs it along a ray and returns an [`Estimate`].
//!
//! Glossary (lecture / pbrt): `mu` = extinction `mu_t` (pbrt `sigma_t`), `mu_maj` = majorant
//! (`sigma_maj`), `mu_min` = minorant, `mu_c` = control extinction, `tau` = optical depth,
//! `T = exp(-tau)` = transmittance.
//!
//! Every estimator sees the ray as the hierarchical DDA's segments (see `crate::traverse`):
//! parts of the ray outside any segment have the background extinction and contribute
//! `exp(-mu_bg * gap)` in closed form; constant segments (`mu_min == mu_maj`) contribute
//! `exp(-mu * length)` in closed form; only the other segments are sampled. Segments with an
//! infinite majorant (opaque voxels) are integrated exactly by regular tracking.
//!
//! Randomness: sample `i` of ray `r` under seed `s` uses the stream `Rng::new(s, r, i)`, so the
//! same seed gives bit-identical results whatever the thread count.
//!
//! Estimates outside `[0, 1]`: residual ratio tracking with a midpoint control (weights up to
//! 2) and next-flight ratio tracking (a sum of positive terms) can exceed 1, and the unbiased
//! ray-marching power series can also go below 0; all are reported raw (that is what keeps them
//! unbiased; averages converge to `T`). The jackknife estimator is clamped to `[0, 1]` (it is
//! biased anyway). [`Estimator::may_leave_unit_interval`] says which.
//!
//! High-contrast nodes: a segment whose expected null collisions `(mu_maj - mu_min) * length`
//! exceed [`REFINE_NULL_COLLISIONS`] is split into per-cell segments with exact cell bounds
//! before sampling, so a single 1e6 spike in a near-empty leaf costs a few lookups, not 1e6.

pub mod blur;
pub mod budget;
pub mod error_bar;
pub(crate) mod marching;
mod medium;
mod null_collision;
mod power_series;
pub mod registry;

pub use error_bar::{Bounds, Spread};
pub use medium::{Extinction, RayMedium};
pub use null_collision::BOUND_TOLERANCE;
pub(crate) use registry::Algo;
pub use registry::{names, Estimator, Kind, Param, Spec, REGISTRY};

use crate::error::Result;
use crate::ray::Ray;
use crate::rng::Rng;
use crate::traverse::{walk, Granularity, Segment};
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

/// How the control extinction of residual ratio tracking is chosen per segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Control {
    /// `mu_c = mu_min`: residual in `[0, mu_maj - mu_min]`, weights in `[0, 1]`.
    Minorant,
    /// `mu_c = (mu_min + mu_maj) / 2`: residual majorant halved, weights
    /// `1 - (mu - mu_c) / r` in `[0, 2]` (the estimate can exceed 1; unbiased).
    Midpoint,
}

/// How the channels of a coloured medium (`mu_c = sigma_c x rho`: `--sigma-t`, RGB scenes) are
/// tracked by a stochastic estimator. Grey media have one channel and ignore it.
///
/// - `Shared` (spectral tracking with one walk): every channel is sampled under the shared
///   majorant `max_c mu_maj,c` with the same random numbers, so tentative collisions fall at
///   the same distances and one lookup serves all channels (Kutz et al. 2017; Miller et al.
///   2019). Costs `max_c mu_maj,c x L` lookups per sample; a channel far below the largest
///   is sampled at the largest channel's rate.
/// - `Split` (per-channel majorants): channel `c` walks on its own per-node majorants
///   `mu_maj,c = sigma_c x rho_max(node)` (and minorants), a walk of its own. Costs
///   `sum_c mu_maj,c x L` lookups per sample, each channel at its own rate.
/// - `Auto`: what the estimator's registry entry names ([`Spec::colour`], a [`ColourChoice`]
///   chosen by measurement: `umbra compare --sigma-t`, docs/colour.md), per ray.
///
/// Each channel is the single-channel estimator with a valid majorant in both walks, so every
/// unbiased estimator stays unbiased per channel.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum ColourWalk {
    /// The estimator's measured choice.
    #[default]
    Auto,
    /// One walk under the largest channel's majorant, lookups shared.
    Shared,
    /// One walk per channel under its own majorant.
    Split,
}

impl ColourWalk {
    /// The walk called `name`: `auto`, `shared` or `split`.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] named `colour-walk` for any other name.
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "auto" => Ok(Self::Auto),
            "shared" => Ok(Self::Shared),
            "split" => Ok(Self::Split),
            other => Err(crate::error::Error::InvalidArgument {
                name: "colour-walk".into(),
                reason: format!("'{other}': expected auto, shared or split"),
            }),
        }
    }

    /// The name [`ColourWalk::from_name`] reads.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Shared => "shared",
            Self::Split => "split",
        }
    }

    /// The walk `est` runs on a ray whose channels' majorants are `spread` apart (`sum len
    /// min_c mu_maj,c / sum len max_c mu_maj,c`, in `[0, 1]`; `min sigma / max sigma` for one
    /// volume): `Auto` becomes the estimator's registry choice.
    #[must_use]
    pub fn resolve(self, est: &Estimator, spread: f64) -> Self {
        match self {
            Self::Auto => match est.spec().colour {
                ColourChoice::Shared => Self::Shared,
                ColourChoice::Split => Self::Split,
                ColourChoice::SplitBelow(s) if spread < s => Self::Split,
                ColourChoice::SplitBelow(_) => Self::Shared,
            },
            w => w,
        }
    }
}

/// What [`ColourWalk::Auto`] runs for one estimator (its registry entry, by measurement).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ColourChoice {
    /// Always the shared walk: the estimator's lookups fall at the same points in every channel
    /// (marching), or its variance falls as its majorant grows (ratio tracking, whose weak
    /// channels gain from the strong channel's majorant at no extra lookup).
    Shared,
    /// Always split walks: the shared majorant hurts the weak channels (a midpoint control
    /// set from it, next-flight's terms) more than the lost replay costs.
    Split,
    /// Split when the channels' majorants are further apart than this ratio (a delta tracker:
    /// its variance does not depend on the majorant, its cost does; near grey, the replay of
    /// the shared walk is cheaper).
    SplitBelow(f64),
}

/// Settings shared by every estimator.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Options {
    /// Lookup interpolation.
    pub interp: Interp,
    /// Independent samples averaged per ray (ignored by deterministic estimators).
    pub samples: u32,
    /// Seed of the random streams.
    pub seed: u64,
    /// Segment granularity of the HDDA (majorant tightness vs traversal cost).
    pub granularity: Granularity,
    /// Use one majorant for the whole grid instead of per-tile ones (the naive baseline).
    pub global_majorant: bool,
    /// Cap on tentative collisions per sample; a sample that hits it stops and is counted in
    /// [`Estimate::capped`] (its value is then biased).
    pub max_collisions: u64,
    /// How a coloured medium's channels are tracked (ignored by grey media).
    pub colour_walk: ColourWalk,
}

impl Options {
    /// Check the options: at least one sample, a collision cap of at least one.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming the field (`samples`, `max-collisions`).
    pub fn validate(&self) -> Result<()> {
        if self.samples == 0 {
            return Err(crate::error::Error::InvalidArgument {
                name: "samples".into(),
                reason: "must be at least 1".into(),
            });
        }
        budget::check_samples("samples", u64::from(self.samples))?;
        if self.max_collisions == 0 {
            return Err(crate::error::Error::InvalidArgument {
                name: "max-collisions".into(),
                reason: "must be at least 1".into(),
            });
        }
        Ok(())
    }
}

impl Default for Options {
    fn default() -> Self {
        Self {
            interp: Interp::Trilinear,
            samples: 1,
            seed: 0,
            granularity: Granularity::Leaf,
            global_majorant: false,
            max_collisions: 10_000_000,
            colour_walk: ColourWalk::Auto,
        }
    }
}

/// A transmittance estimate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Estimate {
    /// Mean of the per-sample estimates of `T`.
    pub value: f64,
    /// Error bar of the mean: the sample standard error with a floor from what the walk
    /// bounds ([`error_bar`]; 0 for deterministic estimators).
    pub std_err: f64,
    /// Density evaluations (the deterministic cost measure).
    pub lookups: u64,
    /// HDDA segments of the ray.
    pub segments: u64,
    /// Samples averaged.
    pub samples: u32,
    /// Samples stopped by the collision cap.
    pub capped: u64,
    /// Lookups that fell outside their segment's `[mu_min, mu_maj]` by more than round-off
    /// (see [`BOUND_TOLERANCE`]): a wrong bound, which biases null-collision estimators. Always
    /// 0 unless the tree's bounds are broken; callers should warn when it is not.
    pub majorant_violations: u64,
    /// Exact optical depth, when the estimator computed it (regular tracking).
    pub tau: Option<f64>,
    /// The samples' statistics and the walk's bounds `std_err` is made from (what adaptive
    /// batches merge).
    #[serde(skip)]
    pub spread: Spread,
}

/// The ray as the estimators see it: the segments that need sampling, and the closed-form
/// optical depth of everything else.
#[derive(Debug, Clone, Default)]
pub struct Prepared {
    /// Segments with a varying extinction and a finite majorant, in ray order.
    pub segs: Vec<Segment>,
    /// Optical depth known in closed form: background gaps, constant segments, and segments
    /// with an infinite majorant integrated exactly.
    pub tau_known: f64,
    /// HDDA segments walked.
    pub walked: u64,
    /// Lookups spent on the closed-form part.
    pub lookups: u64,
}

/// Expected null collisions above which a node segment is refined to per-cell bounds.
pub const REFINE_NULL_COLLISIONS: f64 = 8.0;

/// Walk the ray once and split it into closed-form and sampled parts.
#[must_use]
pub fn prepare(vol: &Volume, ray: &Ray, opts: &Options, medium: &mut RayMedium<'_>) -> Prepared {
    let mut p = Prepared::default();
    prepare_into(
        vol,
        ray,
        opts,
        true,
        medium,
        &mut Scratch::default(),
        &mut p,
    );
    p
}

/// Buffers [`prepare`] fills and empties for each ray; kept per thread by [`estimate`] so that
/// a warm thread allocates nothing per ray.
#[derive(Debug, Default)]
struct Scratch {
    all: Vec<Segment>,
    cells: Vec<Segment>,
}

thread_local! {
    /// Per-thread buffers of [`estimate`]: the walk's segments and the prepared ray.
    static BUFFERS: std::cell::RefCell<(Scratch, Prepared)> =
        std::cell::RefCell::new((Scratch::default(), Prepared::default()));
}

/// [`prepare`] into `p` (cleared first), with `scratch` for the intermediate segments;
/// `refine`: split high-contrast segments into cells (what null collisions need; ray marching
/// does not, and marches whole blocks so that its points are the object-order sweep's).
fn prepare_into(
    vol: &Volume,
    ray: &Ray,
    opts: &Options,
    refine: bool,
    medium: &mut RayMedium<'_>,
    scratch: &mut Scratch,
    p: &mut Prepared,
) {
    let Scratch { all, cells } = scratch;
    all.clear();
    let w = walk(vol, ray, opts.interp, opts.granularity, |s| {
        all.push(s);
        ControlFlow::Continue(())
    });
    let mu_bg = vol.mu_background();
    let bg_tau = |len: f64| {
        if mu_bg != 0.0 && len > 0.0 {
            mu_bg * len
        } else {
            0.0
        }
    };
    let sampled = |s: &Segment| !s.is_constant() && s.mu_maj.is_finite();
    let global = opts.global_majorant && vol.bounds().max.is_finite();
    let (first, last) = match (all.iter().position(sampled), all.iter().rposition(sampled)) {
        (Some(a), Some(b)) if global => (all[a].t_min, all[b].t_max),
        _ => (f64::INFINITY, f64::NEG_INFINITY),
    };
    p.segs.clear();
    // A partial load that missed this ray's leaves (a bug): refused as NaN, never a number.
    // The grid-wide majorant needs every leaf: a partial tree refuses it the same way.
    let partial_global = opts.global_majorant && !vol.tree().is_complete();
    p.tau_known = if w.unloaded || partial_global {
        f64::NAN
    } else {
        0.0
    };
    p.walked = w.segments;
    p.lookups = 0;
    let mut covered_outside = 0.0;
    for s in all.iter() {
        if global && s.t_min >= first && s.t_max <= last {
            continue; // inside the single global segment: sampled
        }
        covered_outside += s.length();
        // High-contrast nodes (a 1e6 spike in a near-empty leaf) would cost millions of null
        // collisions: refine them to per-cell bounds, unless the global baseline is asked for.
        cells.clear();
        if refine
            && !global
            && sampled(s)
            && (s.mu_maj - s.mu_min) * s.length() > REFINE_NULL_COLLISIONS
        {
            medium.refine(s, cells);
        } else {
            cells.push(*s);
        }
        for c in cells.iter() {
            if c.is_constant() {
                p.tau_known += c.mu_min * c.length();
            } else if c.mu_maj.is_finite() {
                p.segs.push(*c);
            } else {
                p.tau_known += medium.exact(c.t_min, c.t_max);
            }
        }
    }
    if global && first < last {
        // The naive baseline: one segment over the whole sampled range with the grid-wide
        // bounds; constant parts and background gaps inside it are sampled too.
        let b = vol.bounds();
        p.segs.clear();
        p.segs.push(Segment {
            t_min: first,
            t_max: last,
            mu_min: vol.density_scale() * f64::from(b.min.max(0.0)),
            mu_maj: vol.density_scale() * f64::from(b.max),
            level: 4,
        });
        p.tau_known += bg_tau(w.length - (last - first) - covered_outside);
    } else {
        p.tau_known += bg_tau(w.length - w.covered);
    }
    p.lookups = medium.lookups();
}

/// Estimate the transmittance along `ray` (ray index `ray_id` selects the random streams).
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] for invalid [`Options`] (see [`Options::validate`]);
/// rays and estimators are valid by construction.
pub fn estimate(
    vol: &Volume,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Result<Estimate> {
    let e = estimate_unchecked(vol, ray, ray_id, est, opts)?;
    let unknown_ok = blur::may_be_unknown(est, vol.moving().is_some());
    if e.value.is_nan() || (e.std_err.is_nan() && !unknown_ok) {
        return Err(crate::error::Error::nan_on_ray(
            format!("{} transmittance estimate", est.name()),
            ray,
        ));
    }
    Ok(e)
}

/// [`estimate`] before its NaN check.
fn estimate_unchecked(
    vol: &Volume,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Result<Estimate> {
    opts.validate()?;
    budget::check_ray(vol, est, opts.samples)?;
    if vol.motion().is_some() && est.algo().0 == Algo::Regular {
        return Err(crate::error::Error::InvalidArgument {
            name: "estimator".into(),
            reason: blur::REGULAR_REFUSED.into(),
        });
    }
    if let Some(m) = vol.moving() {
        return blur::estimate(vol, m, ray, ray_id, est, opts);
    }
    let mut medium = RayMedium::new(vol, ray, opts.interp);
    if est.algo().0 == Algo::Regular {
        let od = crate::regular::optical_depth(vol, ray, opts.interp)?;
        return Ok(Estimate {
            value: od.transmittance(),
            std_err: 0.0,
            lookups: od.lookups,
            segments: od.segments,
            samples: 1,
            capped: 0,
            majorant_violations: 0,
            tau: Some(od.tau),
            spread: Spread::default(),
        });
    }
    BUFFERS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut bufs) => {
            let (scratch, prep) = &mut *bufs;
            prepare_into(vol, ray, opts, !est.marches(), &mut medium, scratch, prep);
            Ok(sample_prepared(est, prep, medium, ray_id, opts))
        }
        // Re-entered on this thread (not done today): fresh buffers rather than a panic.
        Err(_) => {
            let mut prep = Prepared::default();
            let refine = !est.marches();
            let scratch = &mut Scratch::default();
            prepare_into(vol, ray, opts, refine, &mut medium, scratch, &mut prep);
            Ok(sample_prepared(est, &prep, medium, ray_id, opts))
        }
    })
}

/// The samples of a prepared ray: their mean, standard error and cost.
fn sample_prepared(
    est: &Estimator,
    prep: &Prepared,
    mut medium: RayMedium<'_>,
    ray_id: u64,
    opts: &Options,
) -> Estimate {
    let known = (-prep.tau_known).exp();
    let samples = if est.is_deterministic() || prep.segs.is_empty() {
        1
    } else {
        opts.samples.max(1)
    };
    // Welford running mean and variance of the per-sample estimates, and the walk's bounds.
    let mut spread = Spread::of(est, Bounds::of_segments(prep.tau_known, &prep.segs));
    let (mut capped, mut violations) = (0u64, 0u64);
    for i in 0..samples {
        let mut rng = Rng::new(opts.seed, ray_id, u64::from(i));
        let mut cap = Cap::new(opts.max_collisions);
        let x = known * sample_once(est, &prep.segs, &mut medium, &mut rng, &mut cap);
        capped += u64::from(cap.hit);
        violations += cap.violations;
        spread.push(x);
    }
    let (mean, std_err) = (spread.mean, spread.std_err());
    Estimate {
        value: mean,
        std_err,
        lookups: medium.lookups(),
        segments: prep.walked,
        samples,
        capped,
        majorant_violations: violations,
        tau: None,
        spread,
    }
}

/// Sample `sample` of the marcher `est` along `ray` (ray id `ray_id`): its optical depth (the
/// closed-form part plus `-ln` of the marched part) and the lookups spent. What a map swept in
/// object order asks of the ray path for a block it does not march itself (a shell block
/// inside a tile above lower nodes), so that block's points are the ray path's.
pub(crate) fn march_sample(
    vol: &Volume,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
    sample: u32,
) -> (f64, u64) {
    let mut rng = Rng::new(opts.seed, ray_id, u64::from(sample));
    let (known, t, lookups, _) = part_sample(vol, ray, est, opts, &mut rng, false);
    (known - t.ln(), lookups)
}

/// One sample of the null-collision estimator `est` along `ray` (usually one block's chord)
/// with the stream `rng`: `(tau_known, T, lookups, capped)`, the closed-form optical depth
/// and the sampled part's transmittance estimate `T` (the sample is `exp(-tau_known) T`),
/// whether it hit the collision budget. High-contrast segments are refined to per-cell
/// bounds as [`estimate`] refines them. What a null-collision map swept in object order asks
/// of the ray path for a block it does not fly through itself.
pub(crate) fn flight_sample(
    vol: &Volume,
    ray: &Ray,
    est: &Estimator,
    opts: &Options,
    rng: &mut Rng,
) -> (f64, f64, u64, bool) {
    part_sample(vol, ray, est, opts, rng, true)
}

/// The optical depths [`flight_sample`] sees along `ray` before sampling: `(tau_known, tau_min,
/// tau_maj)`, the closed-form part and the minorant and majorant depths of the sampled
/// segments (refined as [`estimate`] refines them). What a null-collision map swept in object
/// order asks for the error bar of a pixel whose chord it hands to the ray path.
pub(crate) fn flight_bounds(vol: &Volume, ray: &Ray, opts: &Options) -> (f64, f64, f64) {
    let mut medium = RayMedium::new(vol, ray, opts.interp);
    let mut run = |scratch: &mut Scratch, prep: &mut Prepared| {
        prepare_into(vol, ray, opts, true, &mut medium, scratch, prep);
        let (lo, hi) = error_bar::depths(&prep.segs);
        (prep.tau_known, lo, hi)
    };
    BUFFERS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut bufs) => {
            let (scratch, prep) = &mut *bufs;
            run(scratch, prep)
        }
        Err(_) => run(&mut Scratch::default(), &mut Prepared::default()),
    })
}

/// [`prepare_into`] (`refine` as it says) and one [`sample_once`] with `rng`, in the
/// per-thread buffers of [`estimate`] (fresh ones if this thread is already inside them).
fn part_sample(
    vol: &Volume,
    ray: &Ray,
    est: &Estimator,
    opts: &Options,
    rng: &mut Rng,
    refine: bool,
) -> (f64, f64, u64, bool) {
    let mut medium = RayMedium::new(vol, ray, opts.interp);
    let mut run = |scratch: &mut Scratch, prep: &mut Prepared| {
        prepare_into(vol, ray, opts, refine, &mut medium, scratch, prep);
        let mut cap = Cap::new(opts.max_collisions);
        let t = sample_once(est, &prep.segs, &mut medium, rng, &mut cap);
        (prep.tau_known, t, cap.hit)
    };
    let (known, t, capped) = BUFFERS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut bufs) => {
            let (scratch, prep) = &mut *bufs;
            run(scratch, prep)
        }
        Err(_) => run(&mut Scratch::default(), &mut Prepared::default()),
    });
    (known, t, medium.lookups(), capped)
}

/// Collision budget of one sample, and the bound violations it met.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cap {
    left: u64,
    /// Set when the budget ran out.
    pub hit: bool,
    /// Lookups outside their segment's bounds (see [`null_collision`]).
    pub violations: u64,
}

impl Cap {
    pub(crate) fn new(n: u64) -> Self {
        Self {
            left: n,
            hit: false,
            violations: 0,
        }
    }
    /// Spend one collision; false when the budget is exhausted (the caller finishes the
    /// sample and sets `hit`).
    #[inline]
    pub(crate) fn take(&mut self) -> bool {
        if self.left == 0 {
            return false;
        }
        self.left -= 1;
        true
    }
}

/// One sample of the transmittance of the sampled segments (closed-form parts excluded).
pub(crate) fn sample_once(
    est: &Estimator,
    segs: &[Segment],
    m: &mut impl Extinction,
    rng: &mut Rng,
    cap: &mut Cap,
) -> f64 {
    let (algo, p) = est.algo();
    match algo {
        Algo::Regular => (-segs.iter().map(|s| m.exact(s.t_min, s.t_max)).sum::<f64>()).exp(),
        Algo::Riemann => marching::riemann(segs, m, p),
        Algo::Mc => marching::monte_carlo(segs, m, rng, p),
        Algo::Jittered => marching::jittered(segs, m, rng, p),
        Algo::TrackLength => null_collision::track_length(segs, m, rng, cap),
        Algo::Collision => {
            let h = p / m.voxels_per_world_unit();
            null_collision::collision(segs, m, rng, cap, h)
        }
        Algo::Ratio => null_collision::ratio(segs, m, rng, cap),
        Algo::ResidualRatio(control) => null_collision::residual_ratio(segs, m, rng, cap, control),
        Algo::NextFlight => null_collision::next_flight(segs, m, rng, cap),
        Algo::Decomposition => null_collision::decomposition(segs, m, rng, cap),
        Algo::UnbiasedRaymarch => power_series::unbiased_raymarch(segs, m, rng),
        Algo::Jackknife => power_series::jackknife(segs, m, rng, p as u32),
    }
}
