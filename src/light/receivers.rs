//! Many receivers toward one light with extent: the one path every product that answers
//! points in bulk takes (`query --positions`, Python's per-point calls, transmittance
//! volumes), so each receiver's answer is the one `query --at` gives at that point with the
//! same seed and ray id, bit for bit.
//!
//! Receiver `k` is answered with ray id `first_id + k` ([`SoftLight::rays`]: its directions'
//! rotations and ray ids are keyed by the seed and that id alone), so the answers are the same
//! whatever the thread count and however the receivers are split. The receivers go in groups
//! of at most [`RAYS_PER_BATCH`] directions: each group's rays are made on the current rayon
//! pool and handed to [`crate::scene::estimate_many`] together (exact queries in batches on
//! the SIMD kernel), then combined per receiver ([`super::extent::SoftRays::combine`]).

use super::extent::SoftRays;
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
    /// The directions traced: the light's samples, or 0 when its whole cone provably misses
    /// every volume's and solid's box (`T = 1` without sampling).
    pub light_samples: usize,
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
        let per_group = (RAYS_PER_BATCH / self.samples.max(1) as usize).max(1);
        let mut out = Vec::with_capacity(receivers.len());
        for (g, group) in receivers.chunks(per_group).enumerate() {
            let first = first_id.wrapping_add((g * per_group) as u64);
            let made: Vec<Result<SoftRays>> = group
                .par_iter()
                .enumerate()
                .map(|(k, at)| self.rays(scene, *at, opts.seed, first.wrapping_add(k as u64)))
                .collect();
            let refs: Vec<Option<&SoftRays>> = made.iter().map(|m| m.as_ref().ok()).collect();
            let answers = answer_each(scene, &refs, est, opts);
            for (m, a) in made.into_iter().zip(answers) {
                out.push(m.and_then(|_| a.unwrap_or_else(|| Err(missing()))));
            }
        }
        out
    }
}

impl SoftRays {
    /// This receiver's answer: every direction through [`crate::scene::estimate_many`], then
    /// their mean and error bar (what [`SoftLight::answer_many`] gives each of its receivers).
    ///
    /// # Errors
    /// The first error of its directions' estimates.
    pub fn answer(&self, scene: &Scene, est: &Estimator, opts: &Options) -> Result<SoftAnswer> {
        let per = crate::scene::estimate_many(scene, &self.rays, &self.ids, est, opts);
        combined(scene, self, per)
    }
}

/// The receivers `made` (`None`: a receiver not sampled) answered together: every
/// receiver's directions through one [`crate::scene::estimate_many`] call (exact queries in
/// batches on the SIMD kernel), then each receiver's mean and error bar, in order (`None` for
/// `None`). What [`SoftLight::answer_many`] and a soft map's blocks of receivers both run.
#[must_use]
pub fn answer_each(
    scene: &Scene,
    made: &[Option<&SoftRays>],
    est: &Estimator,
    opts: &Options,
) -> Vec<Option<Result<SoftAnswer>>> {
    let (rays, ids): (Vec<Ray>, Vec<u64>) = made
        .iter()
        .flatten()
        .flat_map(|s| s.rays.iter().copied().zip(s.ids.iter().copied()))
        .unzip();
    let mut per = crate::scene::estimate_many(scene, &rays, &ids, est, opts).into_iter();
    made.iter()
        .map(|m| {
            m.map(|s| {
                let mine: Vec<Result<SceneEstimate>> = per.by_ref().take(s.rays.len()).collect();
                combined(scene, s, mine)
            })
        })
        .collect()
}

/// The error of a receiver that got no answer (the batch returned fewer than it was given).
fn missing() -> Error {
    Error::InvalidArgument {
        name: "ids".into(),
        reason: "a receiver's directions got no answer".into(),
    }
}

/// One receiver's answer from its directions' estimates: the first error, or their mean.
fn combined(scene: &Scene, s: &SoftRays, per: Vec<Result<SceneEstimate>>) -> Result<SoftAnswer> {
    if per.len() != s.rays.len() {
        return Err(Error::InvalidArgument {
            name: "ids".into(),
            reason: format!("{} answers for {} directions", per.len(), s.rays.len()),
        });
    }
    let per = per.into_iter().collect::<Result<Vec<_>>>()?;
    Ok(SoftAnswer {
        estimate: s.combine(scene.channels(), &per),
        centre: s.centre,
        light_samples: per.len(),
    })
}
