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
            let (mut rays, mut ids) = (Vec::new(), Vec::new());
            for s in made.iter().flatten() {
                rays.extend_from_slice(&s.rays);
                ids.extend_from_slice(&s.ids);
            }
            let mut per = crate::scene::estimate_many(scene, &rays, &ids, est, opts).into_iter();
            for m in made {
                out.push(m.and_then(|s| {
                    let mine: Vec<Result<SceneEstimate>> =
                        per.by_ref().take(s.rays.len()).collect();
                    combined(scene, &s, mine)
                }));
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
