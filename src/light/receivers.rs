//! Receivers toward one light with extent: the one path every product takes (maps, `query
//! --at` and `--positions`, Python's per-point calls, transmittance volumes), so each
//! receiver's answer is the one `query --at` gives at that point with the same seed and ray
//! id, bit for bit.
//!
//! Every receiver traces the same directions ([`SoftLight::rays`]: rotations keyed by the seed,
//! the replicate and the stage), its directions' estimator streams keyed by its ray id, so the
//! answers are the same whatever the thread count and however the receivers are split. With a
//! target error ([`SoftLight::target`]) each receiver runs Stein's two-stage rule
//! ([`super::adaptive`]): the pilot of every receiver of a group is one batch of rays, the
//! extra replicates another, each handed to [`crate::scene::estimate_many`] whole (exact queries in
//! batches on the SIMD kernel), then combined per receiver ([`SoftRays::combine`]).

use super::adaptive::PILOT_POINTS;
use super::extent::{Key, SoftRays, REPLICATES};
use super::occupancy::Occupancy;
use super::SoftLight;
use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use crate::ray::Ray;
use crate::scene::{Scene, SceneEstimate};
use rayon::prelude::*;

/// Most directions handed to the estimator together (a group of receivers).
pub const RAYS_PER_BATCH: usize = 1 << 16;

/// One receiver's answer toward a light with extent.
#[derive(Debug, Clone)]
pub struct SoftAnswer {
    /// The mean over the light and the replicates' error bar (`tau` is `None`).
    pub estimate: SceneEstimate,
    /// The ray toward the light's centre (what a query reports as its ray).
    pub centre: Ray,
    /// The directions traced (a pilot's and its final stage's together), or 0 when its whole
    /// cone provably misses every volume's and solid's box (`T = 1` without sampling).
    pub light_samples: usize,
    /// The count the target error asked for was more than `light-max-samples` allows: the
    /// error bar may be above the target.
    pub light_capped: bool,
}

/// A receiver: where it is and its ray id (its directions' estimator streams).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Receiver {
    /// World position.
    pub at: [f64; 3],
    /// Ray id.
    pub ray_id: u64,
}

/// One stage of a receiver: its ray toward the light's centre, its directions' estimates and
/// their combined answer (the directions themselves are dropped once traced).
struct Stage {
    centre: Ray,
    per: Vec<SceneEstimate>,
    answer: SceneEstimate,
    /// The directions' weights (empty: all equal) and where each replicate ends in `per`.
    weights: Vec<f64>,
    ends: Vec<usize>,
}

impl SoftLight {
    /// The work budget of `receivers` receivers toward this light on every fog volume of
    /// `scene`: one receiver's directions as a job of that many rays
    /// ([`crate::estimate::budget::check_job`]), and every receiver's directions together
    /// within [`crate::estimate::budget::MAX_SAMPLES_PER_JOB`] samples (a stochastic
    /// estimator's samples counted), so a huge `light-samples` over many receivers is refused
    /// up front, never a run of hours.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `samples` or `light-samples`.
    pub fn check_budget(
        &self,
        scene: &Scene,
        receivers: u64,
        est: &Estimator,
        opts: &Options,
    ) -> Result<()> {
        let n = u64::from(self.samples);
        for f in scene.fogs() {
            crate::estimate::budget::check_job(
                f.volume(),
                est,
                n,
                u64::from(opts.samples),
                "samples",
            )?;
        }
        let per = if est.spec().deterministic {
            1
        } else {
            u64::from(opts.samples)
        };
        let total = receivers.saturating_mul(n).saturating_mul(per);
        if total > crate::estimate::budget::MAX_SAMPLES_PER_JOB {
            return Err(Error::InvalidArgument {
                name: "light-samples".into(),
                reason: format!(
                    "{receivers} receivers x {n} directions x {per} samples is {total} samples, \
                     beyond the work budget of {} per job: give fewer directions (or samples)",
                    crate::estimate::budget::MAX_SAMPLES_PER_JOB
                ),
            });
        }
        Ok(())
    }

    /// Answer every receiver of `receivers` toward this light, receiver `k` with ray id
    /// `first_id + k` (wrapping) and the seed of `opts`: one result per receiver, in order.
    /// Runs on the current rayon pool.
    ///
    /// # Errors
    /// Per receiver: a point that is not finite, or the first error of its directions'
    /// estimates (options, budget, NaN on a ray).
    #[must_use]
    pub fn answer_many(
        &self,
        scene: &Scene,
        receivers: &[[f64; 3]],
        first_id: u64,
        est: &Estimator,
        opts: &Options,
    ) -> Vec<Result<SoftAnswer>> {
        let typical = match self.target {
            Some(_) => 4 * super::adaptive::LEAST_ADAPTIVE,
            None => self.samples,
        };
        let per_group = (RAYS_PER_BATCH / typical.max(1) as usize).max(1);
        let occupancy = Occupancy::of(scene);
        // Groups in parallel: one group's pilot is about one batch of the kernel, which a
        // single worker walks (`regular::batch`), so groups one after another kept one core.
        let groups: Vec<Vec<Result<SoftAnswer>>> = receivers
            .par_chunks(per_group)
            .enumerate()
            .map(|(g, group)| {
                let first = first_id.wrapping_add((g * per_group) as u64);
                let asked: Vec<Option<Receiver>> = group
                    .iter()
                    .enumerate()
                    .map(|(k, at)| {
                        Some(Receiver {
                            at: *at,
                            ray_id: first.wrapping_add(k as u64),
                        })
                    })
                    .collect();
                self.answer_each(scene, &occupancy, &asked, est, opts)
                    .into_iter()
                    .map(|a| a.unwrap_or_else(|| Err(missing())))
                    .collect()
            })
            .collect();
        groups.into_iter().flatten().collect()
    }

    /// Every receiver of `receivers` answered (`None`: not asked, `None` back), in order. A
    /// receiver whose light's whole cone ([`SoftLight::reach`]) provably meets no density
    /// (`occupancy`, [`Occupancy::optical_bound`] 0) is `T = 1` exactly, without sampling;
    /// under a target error, one whose cone only grazes density, every direction's optical
    /// depth at most `B` with `e^B - 1 <= target`, is `T = 1` with that error bar
    /// (docs/lights.md, "Receivers answered without sampling"). The others trace exactly
    /// [`SoftLight::samples`] directions each, or with a target error Stein's two stages
    /// (module docs), each stage's rays of every receiver in one
    /// [`crate::scene::estimate_many`] call. Runs on the current rayon pool.
    #[must_use]
    pub fn answer_each(
        &self,
        scene: &Scene,
        occupancy: &Occupancy,
        receivers: &[Option<Receiver>],
        est: &Estimator,
        opts: &Options,
    ) -> Vec<Option<Result<SoftAnswer>>> {
        let limit = self.target.map_or(0.0, f64::ln_1p);
        let bounds: Vec<Option<f64>> = receivers
            .par_iter()
            .map(|r| {
                let reach = self.reach(scene, (*r)?.at).ok()?;
                occupancy.optical_bound(&reach, limit)
            })
            .collect();
        let umbral = self.umbral(scene, receivers, &bounds, opts);
        let asked: Vec<Option<Receiver>> = receivers
            .iter()
            .zip(bounds.iter().zip(&umbral))
            .map(|(r, (b, u))| r.filter(|_| b.is_none() && u.is_none()))
            .collect();
        let sampled = self.sample_each(scene, &asked, est, opts);
        sampled
            .into_iter()
            .zip(receivers)
            .zip(bounds.into_iter().zip(umbral))
            .map(|((s, r), (b, u))| match (r, b, u) {
                (Some(r), Some(b), _) => Some(self.bounded(scene, *r, b, opts.seed)),
                (Some(_), None, Some((centre, tau))) => Some(Ok(in_umbra(scene, centre, tau))),
                _ => s,
            })
            .collect()
    }

    /// Under a target error `E`, the receivers (not already `bounded`) proven in umbra: every
    /// direction of the light's cone has an optical depth of at least `tau_c` per channel with
    /// `e^-tau_c <= 2 E` ([`super::umbra`]), with their rays toward the light's centre. Only a
    /// receiver whose own centre ray is that deep (one exact ray each, all in one
    /// [`crate::scene::estimate_many`] call) is marched: the cone's bound is never above it.
    fn umbral(
        &self,
        scene: &Scene,
        receivers: &[Option<Receiver>],
        bounds: &[Option<f64>],
        opts: &Options,
    ) -> Vec<Option<(Ray, [f64; 3])>> {
        let none = || vec![None; receivers.len()];
        let (Some(target), Some(umbra)) =
            (self.target, super::umbra::Umbra::of(scene, opts.interp))
        else {
            return none();
        };
        let need = -(2.0 * target).ln();
        if !(need > 0.0 && need.is_finite()) {
            return none();
        }
        let centres: Vec<Option<(Receiver, Ray)>> = receivers
            .par_iter()
            .zip(bounds)
            .map(|(r, b)| {
                let r = r.filter(|_| b.is_none())?;
                let key = Key {
                    seed: opts.seed,
                    ray_id: r.ray_id,
                    stage: 1,
                };
                let centre = self.replicates(scene, r.at, key, 1, 0..0).ok()?.centre;
                Some((r, centre))
            })
            .collect();
        let (rays, ids): (Vec<Ray>, Vec<u64>) = centres
            .iter()
            .flatten()
            .map(|(r, c)| (*c, r.ray_id))
            .unzip();
        let exact = crate::scene::estimate_many(scene, &rays, &ids, &Estimator::REGULAR, opts);
        let mut exact = exact.into_iter();
        let deep: Vec<Option<(Receiver, Ray)>> = centres
            .into_iter()
            .map(|c| {
                let c = c?;
                let tau = exact.next()?.ok()?.tau?;
                let least = tau[..scene.channels()]
                    .iter()
                    .copied()
                    .fold(f64::INFINITY, f64::min);
                (least >= need).then_some(c)
            })
            .collect();
        deep.into_par_iter()
            .map(|c| {
                let (r, centre) = c?;
                let reach = self.reach(scene, r.at).ok()?;
                let shortest = self.shortest(&reach)?;
                let tau = umbra.depth_at_least(&reach, shortest, need)?;
                Some((centre, tau))
            })
            .collect()
    }

    /// The answer at `r` when every direction of its light's cone has an optical depth of at
    /// most `bound`: `T = 1` with the error bar `e^B - 1`, which holds `|T(w) - 1|` for
    /// every direction `w` (`T(w) >= e^-B`) and so their mean; exactly 1 (error bar 0) where
    /// `B = 0`.
    fn bounded(&self, scene: &Scene, r: Receiver, bound: f64, seed: u64) -> Result<SoftAnswer> {
        let key = Key {
            seed,
            ray_id: r.ray_id,
            stage: 1,
        };
        let centre = self.replicates(scene, r.at, key, 1, 0..0)?.centre;
        let mut estimate = SceneEstimate::exact(scene.channels(), [0.0; 3], 0, 0);
        estimate.tau = None;
        estimate.value = [1.0; 3];
        estimate.std_err = [bound.exp_m1(); 3];
        Ok(SoftAnswer {
            estimate,
            centre,
            light_samples: 0,
            light_capped: false,
        })
    }

    /// [`SoftLight::answer_each`] of the receivers it samples.
    fn sample_each(
        &self,
        scene: &Scene,
        receivers: &[Option<Receiver>],
        est: &Estimator,
        opts: &Options,
    ) -> Vec<Option<Result<SoftAnswer>>> {
        let Some(target) = self.target else {
            let made = self.make(scene, receivers, (opts.seed, 0), &|_| Some(0..REPLICATES));
            return stage(scene, made, est, opts)
                .into_iter()
                .map(|s| s.map(|s| s.map(|s| Answered::pilot(s, false).answer())))
                .collect();
        };
        let r0 = REPLICATES;
        let pilot = self.make(scene, receivers, (opts.seed, 1), &|_| Some(0..r0));
        let pilots = stage(scene, pilot, est, opts);
        let cap = self.samples / PILOT_POINTS;
        let channels = scene.channels();
        let plan: Vec<Option<(u32, bool)>> = pilots
            .iter()
            .map(|p| match p {
                Some(Ok(p)) if !p.per.is_empty() => Some(super::adaptive::replicates_for(
                    p.traced(),
                    (&p.answer, r0),
                    channels,
                    target,
                    cap,
                )),
                _ => None,
            })
            .collect();
        // Only the receivers whose pilot fell short of the target trace more.
        let more = |k: usize| plan[k].and_then(|(n, _)| (n > r0).then_some(r0..n));
        let extra = self.make(scene, receivers, (opts.seed, 1), &more);
        let extras = stage(scene, extra, est, opts);
        let firsts: Vec<Option<Result<Answered>>> = pilots
            .into_iter()
            .zip(extras)
            .zip(&plan)
            .map(|((p, x), plan)| {
                let capped = plan.is_some_and(|(_, capped)| capped);
                let n = plan.map_or(r0, |(n, _)| n);
                Some(match (p?, x) {
                    (Err(e), _) | (Ok(_), Some(Err(e))) => Err(e),
                    (Ok(p), None) => Ok(Answered::pilot(p, capped)),
                    (Ok(p), Some(Ok(x))) => Ok(Answered::joined(p, x, n, capped)),
                })
            })
            .collect();
        // A pilot that agreed and extras that did not, with an error bar above the target:
        // Stein once more, everything so far the pilot (module docs of `adaptive`).
        let again: Vec<Option<(u32, u32, bool)>> = firsts
            .iter()
            .map(|a| match a {
                Some(Ok(a)) if !a.capped && a.recount(channels, target) => {
                    let (n, capped) = super::adaptive::replicates_for(
                        a.all.traced(),
                        (&a.all.answer, a.reps),
                        channels,
                        target,
                        cap,
                    );
                    (n > a.reps).then_some((a.reps, n, capped))
                }
                _ => None,
            })
            .collect();
        let more = |k: usize| again[k].map(|(from, n, _)| from..n);
        let extra = self.make(scene, receivers, (opts.seed, 1), &more);
        let extras = stage(scene, extra, est, opts);
        firsts
            .into_iter()
            .zip(extras)
            .zip(again)
            .map(|((a, x), again)| {
                Some(match (a?, x) {
                    (Err(e), _) | (Ok(_), Some(Err(e))) => Err(e),
                    (Ok(a), None) => Ok(a.answer()),
                    (Ok(a), Some(Ok(x))) => {
                        let (n, capped) = again.map_or((a.reps, false), |(_, n, c)| (n, c));
                        Ok(a.again(x, n, capped))
                    }
                })
            })
            .collect()
    }

    /// Each asked receiver's rays of one stage (`(seed, stage)`): the replicates `reps(k)` of
    /// [`PILOT_POINTS`] points, or with a fixed count all 16 of `samples / 16` points, for
    /// receiver `k` (`None`: none asked).
    fn make(
        &self,
        scene: &Scene,
        receivers: &[Option<Receiver>],
        (seed, stage): (u64, u64),
        reps: &(dyn Fn(usize) -> Option<std::ops::Range<u32>> + Sync),
    ) -> Vec<Option<Result<SoftRays>>> {
        let m = if stage == 0 {
            self.samples / REPLICATES
        } else {
            PILOT_POINTS
        };
        receivers
            .par_iter()
            .enumerate()
            .map(|(k, r)| {
                let r = (*r)?;
                let key = Key {
                    seed,
                    ray_id: r.ray_id,
                    stage,
                };
                Some(self.replicates(scene, r.at, key, m, reps(k)?))
            })
            .collect()
    }
}

/// One stage of every receiver: every ray of `made` through one
/// [`crate::scene::estimate_many`] call, then each receiver's mean and error bar, in order.
fn stage(
    scene: &Scene,
    made: Vec<Option<Result<SoftRays>>>,
    est: &Estimator,
    opts: &Options,
) -> Vec<Option<Result<Stage>>> {
    let (rays, ids): (Vec<Ray>, Vec<u64>) = made
        .iter()
        .flatten()
        .flatten()
        .flat_map(|s| s.rays.iter().copied().zip(s.ids.iter().copied()))
        .unzip();
    let mut per = crate::scene::estimate_many(scene, &rays, &ids, est, opts).into_iter();
    made.into_iter()
        .map(|m| {
            m.map(|r| {
                let s = r?;
                let mine: Vec<Result<SceneEstimate>> = per.by_ref().take(s.rays.len()).collect();
                if mine.len() != s.rays.len() {
                    return Err(missing());
                }
                let mine = mine.into_iter().collect::<Result<Vec<_>>>()?;
                let answer = s.combine(scene.channels(), &mine);
                Ok(Stage {
                    centre: s.centre,
                    per: mine,
                    answer,
                    weights: s.weights,
                    ends: s.ends,
                })
            })
        })
        .collect()
}

impl Stage {
    /// Its directions' estimates with their replicates' ends.
    fn traced(&self) -> super::adaptive::Traced<'_> {
        super::adaptive::Traced::new(&self.per, &self.ends)
    }
}

/// A receiver's stages so far: every direction together (`all`), the answer with Stein's
/// error bar, the replicates it took and whether the cap cut them.
struct Answered {
    /// How many of `all`'s directions are the pilot's (0: no pilot to re-count from), and
    /// the pilot's answer (whose spread scales the error bar).
    pilot: (usize, SceneEstimate),
    /// The pilot's and every extra replicate's directions, combined.
    all: Stage,
    /// The answer: `all`'s mean, Stein's error bar.
    answer: SceneEstimate,
    reps: u32,
    capped: bool,
}

impl Answered {
    /// A fixed count's stage, or a pilot that met the target on its own.
    fn pilot(first: Stage, capped: bool) -> Self {
        let reps = first.ends.len() as u32;
        Self {
            pilot: (0, first.answer),
            answer: first.answer,
            all: first,
            reps,
            capped,
        }
    }

    /// The pilot `first` and the `n - 16` extra replicates `x` it asked for (Stein's rule: the
    /// mean of every replicate, the pilot's error bar scaled to their number,
    /// [`super::adaptive::stein`]).
    fn joined(first: Stage, x: Stage, n: u32, capped: bool) -> Self {
        let r0 = first.ends.len() as u32;
        let pilot_answer = first.answer;
        let pilot_len = first.per.len();
        let all = join(first, x);
        let pilot = all.traced().head(pilot_len);
        let answer = super::adaptive::stein(pilot, (&pilot_answer, r0), all.answer, n);
        Self {
            pilot: (pilot_len, pilot_answer),
            all,
            answer,
            reps: n,
            capped,
        }
    }

    /// True when a channel whose pilot was not normal ended above `target`
    /// ([`super::adaptive::recount`]).
    fn recount(&self, channels: usize, target: f64) -> bool {
        let pilot = self.all.traced().head(self.pilot.0);
        !pilot.per().is_empty() && super::adaptive::recount(pilot, &self.answer, channels, target)
    }

    /// One more Stein stage: `x`, the `n - reps` replicates everything so far asked for. The
    /// channels whose first pilot was normal keep its error bar, scaled to `n`; the others
    /// take the spread of everything before `x`, scaled to `n`.
    fn again(self, x: Stage, n: u32, capped: bool) -> SoftAnswer {
        let before = self.all.per.len();
        let (previous, r1) = (self.all.answer, self.reps);
        let ((pilot_len, pilot), r0) = (self.pilot, REPLICATES);
        let all = join(self.all, x);
        let answer =
            super::adaptive::stein_again(all.traced().head(before), (&previous, r1), all.answer, n);
        // The first pilot's normal channels keep its bar (Stein over it overwrites them).
        let answer = super::adaptive::stein(all.traced().head(pilot_len), (&pilot, r0), answer, n);
        SoftAnswer {
            light_samples: all.per.len(),
            estimate: answer,
            centre: all.centre,
            light_capped: capped || self.capped,
        }
    }

    /// The answer as it stands.
    fn answer(self) -> SoftAnswer {
        SoftAnswer {
            light_samples: self.all.per.len(),
            estimate: self.answer,
            centre: self.all.centre,
            light_capped: self.capped,
        }
    }
}

/// Two stages of one receiver as one: `first`'s directions, then `x`'s (moved, not copied),
/// combined.
fn join(first: Stage, x: Stage) -> Stage {
    let (first_len, channels) = (first.per.len(), first.answer.channels);
    let mut ends = first.ends;
    ends.extend(x.ends.iter().map(|e| e + first_len));
    let mut weights = first.weights;
    weights.extend(x.weights);
    let mut per = first.per;
    per.extend(x.per);
    let answer = super::adaptive::combine(&weights, &ends, channels, &per);
    Stage {
        centre: first.centre,
        per,
        answer,
        weights,
        ends,
    }
}

/// The error of a receiver that got no answer (the batch returned fewer than it was given).
fn missing() -> Error {
    Error::InvalidArgument {
        name: "ids".into(),
        reason: "a receiver's directions got no answer".into(),
    }
}

/// A receiver in umbra: every direction's `T_c <= U_c = e^-tau_c`, so the mean is in
/// `[0, U_c]`: `T_c = U_c / 2` with the error bar `U_c / 2` (at most the target).
fn in_umbra(scene: &Scene, centre: Ray, tau: [f64; 3]) -> SoftAnswer {
    let mut estimate = SceneEstimate::exact(scene.channels(), [0.0; 3], 0, 0);
    estimate.tau = None;
    estimate.value = tau.map(|t| (-t).exp() / 2.0);
    estimate.std_err = estimate.value;
    SoftAnswer {
        estimate,
        centre,
        light_samples: 0,
        light_capped: false,
    }
}
