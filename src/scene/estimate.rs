//! Transmittance through a scene: several fog volumes (each with its own tree, transform,
//! HDDA and halos), per-channel extinction, and opaque solids.
//!
//! **Exact.** Optical depth is additive across volumes as along a ray:
//! `tau_c = sum_k sigma_{k,c} tau_k`, each `tau_k` by regular tracking in volume `k`'s own index
//! space; one pass per volume, then one exponential per channel.
//!
//! **Stochastic.** Each volume's ray is prepared as for a single grid (closed-form parts into
//! `tau_known_k`, the rest as majorant segments). The segments of all volumes are merged into
//! elementary intervals, each with the set `K` of volumes sampled there and per-channel bounds
//! `mu_min,c = sum_{k in K} sigma_{k,c} mu_min,k`, `mu_maj,c = sum_{k in K} sigma_{k,c} mu_maj,k`.
//! The estimators run on these intervals with the *shared* majorant `max_c mu_maj,c` (a valid
//! majorant of every channel) and the lookup `mu_c(t) = sum_{k in K(t)} sigma_{k,c} mu_k(t)`.
//! The closed-form parts add `sum_k sigma_{k,c} tau_known_k`. Since `tau = known + sampled`
//! exactly, every unbiased estimator stays unbiased on the union.
//!
//! **Colour: the shared walk** ([`ColourWalk::Shared`], spectral tracking). The three channels use the same random
//! numbers (sample `i` of ray `r` draws `Rng::new(seed, r, i)` for every channel) and the same
//! majorant, so their tentative collisions fall at the same distances: the first channel's
//! lookups are recorded (all three channels' extinction at once, one tree lookup per volume)
//! and the others replay them. Where a channel's walk leaves the shared path (a delta-tracking
//! walk that stops at a different real collision, a channel-specific control), it looks the
//! medium up itself; each channel is the single-channel estimator with a valid majorant, so
//! each is unbiased (Kutz et al. 2017, "Spectral and decomposition tracking"; Miller et al.
//! 2019, "A null-scattering path integral formulation": a majorant shared by all wavelengths).
//!
//! **Colour: split walks** ([`ColourWalk::Split`], per-channel majorants). Channel `c` is
//! sampled on its own per-node bounds `mu_min,c`, `mu_maj,c` (above), each channel a walk of
//! its own from the same stream `Rng::new(seed, r, i)`; intervals where `mu_maj,c = 0` hold
//! no extinction of channel `c` and are left out of its walk. Where one channel's extinction
//! is 10x another's, the weak channel's walk costs a tenth of the strong one's instead of the
//! same; the shared walk's replay is lost. Which wins depends on the estimator (a ratio
//! tracker's variance falls as its majorant grows, a delta tracker's does not): `Auto` takes
//! the estimator's measured choice ([`ColourWalk::resolve`]).
//!
//! **Solids.** The first point of the ray inside any solid (`phi < 0`) cuts the ray: `T = 0`
//! for every channel if it is within `[t_min, t_max]`.
//!
//! Allocation: the scene path allocates its merged intervals per ray (the single-volume path
//! allocates nothing per ray).

use super::Scene;
use crate::error::Result;
use crate::estimate::{
    budget, estimate as estimate_one, prepare, sample_once, Bounds, Cap, ColourWalk, Estimate,
    Estimator, Extinction, Options, RayMedium, Spread,
};
use crate::math::scaled;
use crate::ray::Ray;
use crate::rng::Rng;
use crate::traverse::Segment;

/// A scene's transmittance estimate, per channel (`channels` is 1 or 3; unused entries are
/// copies of channel 0).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SceneEstimate {
    /// 1 (grey) or 3 (R, G, B).
    pub channels: usize,
    /// Mean of the per-sample estimates of `T_c`.
    pub value: [f64; 3],
    /// Error bar of each mean ([`crate::estimate::error_bar`]; 0 for deterministic
    /// estimators).
    pub std_err: [f64; 3],
    /// Exact optical depth per channel (regular tracking; `inf` behind a solid).
    pub tau: Option<[f64; 3]>,
    /// Density lookups, all volumes and channels.
    pub lookups: u64,
    /// HDDA segments walked, all volumes.
    pub segments: u64,
    /// Samples averaged per channel.
    pub samples: u32,
    /// Samples stopped by the collision cap, all channels.
    pub capped: u64,
    /// Lookups outside their interval's bounds (a wrong majorant; see
    /// [`Estimate::majorant_violations`]).
    pub majorant_violations: u64,
    /// Where the ray first enters a solid, if it does within its range.
    pub hit: Option<f64>,
    /// Per channel, the samples' statistics and the walk's bounds `std_err` is made from.
    #[serde(skip)]
    pub spread: [Spread; 3],
}

impl SceneEstimate {
    /// Channel `c` as a single-grid [`Estimate`] (costs are the whole ray's).
    #[must_use]
    pub fn channel(&self, c: usize) -> Estimate {
        let c = c.min(2);
        Estimate {
            value: self.value[c],
            std_err: self.std_err[c],
            lookups: self.lookups,
            segments: self.segments,
            samples: self.samples,
            capped: self.capped,
            majorant_violations: self.majorant_violations,
            tau: self.tau.map(|t| t[c]),
            spread: self.spread[c],
        }
    }

    /// The exact answer from optical depths per channel: `T_c = exp(-tau_c)`.
    pub(crate) fn exact(channels: usize, tau: [f64; 3], lookups: u64, segments: u64) -> Self {
        Self {
            channels,
            value: tau.map(|t| (-t).exp()),
            std_err: [0.0; 3],
            tau: Some(tau),
            lookups,
            segments,
            samples: 1,
            capped: 0,
            majorant_violations: 0,
            hit: None,
            spread: [Spread::default(); 3],
        }
    }

    /// A ray that enters a solid at `t`: `T = 0` in every channel, `tau = inf` when the
    /// estimator is deterministic (none otherwise).
    pub(crate) fn behind_solid(channels: usize, t: f64, deterministic: bool) -> Self {
        Self {
            channels,
            value: [0.0; 3],
            std_err: [0.0; 3],
            tau: deterministic.then_some([f64::INFINITY; 3]),
            lookups: 0,
            segments: 0,
            samples: 1,
            capped: 0,
            majorant_violations: 0,
            hit: Some(t),
            spread: [Spread::default(); 3],
        }
    }

    pub(crate) fn grey(e: &Estimate) -> Self {
        Self {
            channels: 1,
            value: [e.value; 3],
            std_err: [e.std_err; 3],
            tau: e.tau.map(|t| [t; 3]),
            lookups: e.lookups,
            segments: e.segments,
            samples: e.samples,
            capped: e.capped,
            majorant_violations: e.majorant_violations,
            spread: [e.spread; 3],
            hit: None,
        }
    }
}

/// Estimate the transmittance of `scene` along `ray` (see the module docs). A scene of one
/// grey volume without solids gives exactly [`crate::estimate::estimate`]'s answer.
///
/// # Errors
/// As [`crate::estimate::estimate`]: invalid options, a budget exceeded on any volume, NaN.
pub fn estimate(
    scene: &Scene,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Result<SceneEstimate> {
    opts.validate()?;
    for f in &scene.fogs {
        budget::check_ray(&f.volume, est, opts.samples)?;
    }
    let (ray, moved) = Scene::localise(ray, scene.world_box());
    let ray = &ray;
    let channels = scene.channels();
    let hit = scene
        .solids
        .iter()
        .filter_map(|s| s.first_hit(ray))
        .min_by(f64::total_cmp);
    if let Some(t) = hit {
        return Ok(SceneEstimate::behind_solid(
            channels,
            t + moved,
            est.is_deterministic(),
        ));
    }
    if let Some(vol) = scene.single() {
        return Ok(SceneEstimate::grey(&estimate_one(
            vol, ray, ray_id, est, opts,
        )?));
    }
    let e = if *est == Estimator::REGULAR {
        exact(scene, ray, opts)?
    } else {
        sampled(scene, ray, ray_id, est, opts)
    };
    let moving = scene.fogs().iter().any(|f| f.volume().moving().is_some());
    let unknown_ok = crate::estimate::blur::may_be_unknown(est, moving);
    let nan =
        e.value.iter().any(|v| v.is_nan()) || (!unknown_ok && e.std_err.iter().any(|v| v.is_nan()));
    if nan {
        return Err(crate::error::Error::nan_on_ray(
            format!("{} transmittance estimate", est.name()),
            ray,
        ));
    }
    Ok(e)
}

/// Regular tracking in every volume, summed per channel.
fn exact(scene: &Scene, ray: &Ray, opts: &Options) -> Result<SceneEstimate> {
    let mut tau = [0.0f64; 3];
    let (mut lookups, mut segments) = (0, 0);
    for f in &scene.fogs {
        let od = crate::regular::optical_depth(&f.volume, ray, opts.interp)?;
        for (c, t) in tau.iter_mut().enumerate() {
            *t += scaled(f.sigma[c], od.tau);
        }
        lookups += od.lookups;
        segments += od.segments;
    }
    Ok(SceneEstimate::exact(
        scene.channels(),
        tau,
        lookups,
        segments,
    ))
}

/// An elementary interval of the merged segments: `[t0, t1]`, the volumes sampled there, and
/// the per-channel bounds `mu_min,c = sum_k sigma_k,c mu_min,k`, `mu_maj,c = sum_k sigma_k,c
/// mu_maj,k` over them (the per-node, per-channel majorants of a coloured medium).
#[derive(Debug, Clone, Copy)]
struct Piece {
    t0: f64,
    t1: f64,
    mask: u64,
    lo: [f64; 3],
    hi: [f64; 3],
    level: u8,
}

/// Merge each volume's sampled segments into elementary intervals (every boundary of every
/// volume's segments is a boundary), keeping those where at least one volume is sampled.
/// Each volume's segments are in ray order and do not overlap.
fn merge(per: &[Vec<Segment>], sigma: &[[f64; 3]], channels: usize) -> Vec<Piece> {
    let mut cuts: Vec<f64> = per
        .iter()
        .flatten()
        .flat_map(|s| [s.t_min, s.t_max])
        .collect();
    cuts.sort_by(f64::total_cmp);
    cuts.dedup();
    let mut next = vec![0usize; per.len()];
    let mut pieces = Vec::new();
    for w in cuts.windows(2) {
        let (a, b) = (w[0], w[1]);
        let mut p = Piece {
            t0: a,
            t1: b,
            mask: 0,
            lo: [0.0; 3],
            hi: [0.0; 3],
            level: 0,
        };
        for (k, list) in per.iter().enumerate() {
            while next[k] < list.len() && list[next[k]].t_max <= a {
                next[k] += 1;
            }
            let Some(s) = list.get(next[k]).filter(|s| s.t_min <= a && s.t_max >= b) else {
                continue;
            };
            p.mask |= 1 << k;
            p.level = p.level.max(s.level);
            for (c, &sig) in sigma[k].iter().enumerate().take(channels) {
                p.lo[c] += scaled(sig, s.mu_min);
                p.hi[c] += scaled(sig, s.mu_maj);
            }
        }
        if p.mask != 0 {
            pieces.push(p);
        }
    }
    pieces
}

/// How far apart the channels' majorants are along the ray: `sum_pieces len min_c mu_maj,c /
/// sum_pieces len max_c mu_maj,c` in `[0, 1]` (1 for grey or nothing sampled). For one fog
/// volume it is `min_c sigma_c / max_c sigma_c`.
fn spread(pieces: &[Piece], channels: usize) -> f64 {
    let (mut low, mut high) = (0.0, 0.0);
    for p in pieces {
        let hi = &p.hi[..channels];
        let len = p.t1 - p.t0;
        low += len * hi.iter().copied().fold(f64::INFINITY, f64::min);
        high += len * hi.iter().copied().fold(0.0f64, f64::max);
    }
    if high > 0.0 && high.is_finite() {
        (low / high).clamp(0.0, 1.0)
    } else {
        1.0
    }
}

/// Per channel `c < channels`, the segments its walk samples: every piece with `mu_min,c` and
/// the shared majorant `max_c mu_maj,c`, or with `split` the channel's own `mu_maj,c` (a piece
/// where that is 0 holds none of channel `c`'s extinction and is left out).
fn channel_segments(pieces: &[Piece], channels: usize, split: bool) -> [Vec<Segment>; 3] {
    let mut segs: [Vec<Segment>; 3] = Default::default();
    for p in pieces {
        let shared = p.hi[..channels].iter().copied().fold(0.0f64, f64::max);
        for (c, list) in segs.iter_mut().enumerate().take(channels) {
            let mu_maj = if split { p.hi[c] } else { shared };
            if split && mu_maj == 0.0 {
                continue;
            }
            list.push(Segment {
                t_min: p.t0,
                t_max: p.t1,
                mu_min: p.lo[c],
                mu_maj,
                level: p.level,
            });
        }
    }
    segs
}

/// The medium of a scene along one ray: the sum of the sampled volumes' extinction, per
/// channel, with the first channel's lookups recorded for the others (see the module docs).
struct SceneMedium<'v> {
    media: Vec<RayMedium<'v>>,
    sigma: Vec<[f64; 3]>,
    pieces: Vec<Piece>,
    cursor: usize,
    channel: usize,
    record: bool,
    log: Vec<(f64, [f64; 3])>,
    replay: usize,
    voxels: f64,
}

impl SceneMedium<'_> {
    /// The piece holding `t` (the cursor follows the walk; a jump back searches).
    fn locate(&mut self, t: f64) -> Option<Piece> {
        let n = self.pieces.len();
        if n == 0 {
            return None;
        }
        let mut i = self.cursor.min(n - 1);
        if t < self.pieces[i].t0 || t > self.pieces[i].t1 {
            i = self.pieces.partition_point(|p| p.t1 < t).min(n - 1);
        }
        self.cursor = i;
        let p = self.pieces[i];
        (p.t0 <= t && t <= p.t1).then_some(p)
    }

    /// Extinction of every channel at `t`: one lookup per sampled volume there.
    fn lookup(&mut self, t: f64) -> [f64; 3] {
        let Some(p) = self.locate(t) else {
            return [0.0; 3];
        };
        let mut mu = [0.0; 3];
        let mut m = p.mask;
        while m != 0 {
            let k = m.trailing_zeros() as usize;
            m &= m - 1;
            let v = self.media[k].mu(t);
            for (c, x) in mu.iter_mut().enumerate() {
                *x += scaled(self.sigma[k][c], v);
            }
        }
        mu
    }

    /// Start channel `c`'s walk: channel 0 records, the others replay.
    fn begin(&mut self, c: usize, record: bool) {
        self.channel = c;
        self.record = record;
        self.replay = 0;
        if record {
            self.log.clear();
        }
    }

    fn lookups(&self) -> u64 {
        self.media.iter().map(RayMedium::lookups).sum()
    }
}

impl Extinction for SceneMedium<'_> {
    fn mu(&mut self, t: f64) -> f64 {
        if !self.record {
            if let Some(&(lt, v)) = self.log.get(self.replay) {
                if lt.to_bits() == t.to_bits() {
                    self.replay += 1;
                    return v[self.channel];
                }
                self.replay = usize::MAX; // left the shared path: look up from here on
            }
        }
        let v = self.lookup(t);
        if self.record {
            self.log.push((t, v));
        }
        v[self.channel]
    }

    fn exact(&mut self, t0: f64, t1: f64) -> f64 {
        let c = self.channel;
        let mut tau = 0.0;
        for i in 0..self.pieces.len() {
            let p = self.pieces[i];
            let (a, b) = (p.t0.max(t0), p.t1.min(t1));
            if a >= b {
                continue;
            }
            let mut m = p.mask;
            while m != 0 {
                let k = m.trailing_zeros() as usize;
                m &= m - 1;
                tau += scaled(self.sigma[k][c], self.media[k].exact(a, b));
            }
        }
        tau
    }

    fn voxels_per_world_unit(&self) -> f64 {
        self.voxels
    }
}

/// Every stochastic estimator on the merged intervals (see the module docs).
fn sampled(
    scene: &Scene,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> SceneEstimate {
    let channels = scene.channels();
    let mut media = Vec::with_capacity(scene.fogs.len());
    let mut per = Vec::with_capacity(scene.fogs.len());
    let mut known = [0.0f64; 3];
    let mut segments = 0;
    let mut voxels = 0.0f64;
    for f in &scene.fogs {
        let mut m = RayMedium::new(&f.volume, ray, opts.interp);
        let p = prepare(&f.volume, ray, opts, &mut m);
        for (c, k) in known.iter_mut().enumerate() {
            *k += scaled(f.sigma[c], p.tau_known);
        }
        segments += p.walked;
        voxels = voxels.max(m.voxels_per_world_unit());
        per.push(p.segs);
        media.push(m);
    }
    let sigma: Vec<[f64; 3]> = scene.fogs.iter().map(|f| f.sigma).collect();
    let pieces = merge(&per, &sigma, channels);
    let split = channels > 1
        && opts.colour_walk.resolve(est, spread(&pieces, channels)) == ColourWalk::Split;
    let segs = channel_segments(&pieces, channels, split);
    let mut medium = SceneMedium {
        media,
        sigma,
        pieces,
        cursor: 0,
        channel: 0,
        record: false,
        log: Vec::new(),
        replay: 0,
        voxels,
    };
    let samples = if est.is_deterministic() || segs.iter().all(Vec::is_empty) {
        1
    } else {
        opts.samples.max(1)
    };
    let mut stats: [Spread; 3] =
        std::array::from_fn(|c| Spread::of(est, Bounds::of_segments(known[c], &segs[c])));
    let (mut capped, mut violations) = (0u64, 0u64);
    for i in 0..samples {
        for (c, sp) in stats.iter_mut().enumerate().take(channels) {
            let mut rng = Rng::new(opts.seed, ray_id, u64::from(i));
            let mut cap = Cap::new(opts.max_collisions);
            medium.begin(c, c == 0 && channels > 1 && !split);
            let x = (-known[c]).exp() * sample_once(est, &segs[c], &mut medium, &mut rng, &mut cap);
            capped += u64::from(cap.hit);
            violations += cap.violations;
            sp.push(x);
        }
    }
    let mean = stats.map(|s| s.mean);
    let std_err = std::array::from_fn(|c| {
        if c < channels {
            stats[c].std_err()
        } else {
            0.0
        }
    });
    let fill = |v: [f64; 3]| if channels == 1 { [v[0]; 3] } else { v };
    let stats = if channels == 1 { [stats[0]; 3] } else { stats };
    SceneEstimate {
        channels,
        value: fill(mean),
        std_err: fill(std_err),
        tau: None,
        lookups: medium.lookups(),
        segments,
        samples,
        capped,
        majorant_violations: violations,
        hit: None,
        spread: stats,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn piece(t0: f64, t1: f64, hi: [f64; 3]) -> Piece {
        Piece {
            t0,
            t1,
            mask: 1,
            lo: [0.0; 3],
            hi,
            level: 0,
        }
    }

    #[test]
    fn spread_weighs_each_piece_by_its_length() {
        assert_eq!(spread(&[], 3), 1.0);
        assert_eq!(spread(&[piece(0.0, 1.0, [2.0, 1.0, 0.5])], 3), 0.25);
        // 1 x min 1 + 3 x min 0 over 1 x max 2 + 3 x max 4: 1 / 14.
        let p = [
            piece(0.0, 1.0, [2.0, 1.0, 1.0]),
            piece(1.0, 4.0, [4.0, 0.0, 1.0]),
        ];
        assert!((spread(&p, 3) - 1.0 / 14.0).abs() < 1e-15);
        // Grey: one channel, spread 1.
        assert_eq!(spread(&p, 1), 1.0);
    }

    #[test]
    fn split_segments_carry_each_channels_majorant_and_skip_empty_ones() {
        let p = [piece(0.0, 1.0, [2.0, 0.0, 0.5])];
        let shared = channel_segments(&p, 3, false);
        assert!(shared.iter().all(|s| s.len() == 1 && s[0].mu_maj == 2.0));
        let split = channel_segments(&p, 3, true);
        assert_eq!(split[0][0].mu_maj, 2.0);
        assert!(
            split[1].is_empty(),
            "no extinction in green: nothing to walk"
        );
        assert_eq!(split[2][0].mu_maj, 0.5);
    }

    #[test]
    fn auto_takes_the_registry_choice_at_the_rays_spread() {
        let e = |n| Estimator::from_name(n).unwrap();
        assert_eq!(
            ColourWalk::Auto.resolve(&e("ratio"), 0.1),
            ColourWalk::Shared
        );
        assert_eq!(
            ColourWalk::Auto.resolve(&e("next-flight"), 0.9),
            ColourWalk::Split
        );
        assert_eq!(
            ColourWalk::Auto.resolve(&e("track-length"), 0.1),
            ColourWalk::Split
        );
        assert_eq!(
            ColourWalk::Auto.resolve(&e("track-length"), 0.9),
            ColourWalk::Shared
        );
        assert_eq!(
            ColourWalk::Shared.resolve(&e("next-flight"), 0.1),
            ColourWalk::Shared
        );
        for w in [ColourWalk::Auto, ColourWalk::Shared, ColourWalk::Split] {
            assert_eq!(ColourWalk::from_name(w.name()).unwrap(), w);
        }
        let err = ColourWalk::from_name("both").unwrap_err().to_string();
        assert!(err.contains("colour-walk"), "{err}");
    }
}
