//! Many rays through a scene at once: what `umbra query --rays` and the Python module's array
//! queries ask.
//!
//! Exact trilinear queries go in batches ([`crate::regular::optical_depths`]: every volume's
//! leaf chords grouped by leaf on the SIMD kernel; about 1.9x the throughput of one walk per
//! ray, docs/performance.md); solids cut a ray first as in [`super::estimate`]. Everything else
//! (stochastic estimators, nearest lookups) is [`super::estimate`] ray by ray, in parallel.
//! Either way each ray's answer depends on the ray, its id and the options alone, never on the
//! other rays of the batch or the thread count. A batched exact answer is the f64 walk's to the
//! kernel's f32 positions (within `1e-6 tau + 1e-7 M`, `M` the majorant optical depth), as the
//! exact maps are.

use super::estimate::{estimate, SceneEstimate};
use super::Scene;
use crate::error::Result;
use crate::estimate::{budget, Estimator, Options};
use crate::math::scaled;
use crate::ray::Ray;
use crate::volume::Interp;
use rayon::prelude::*;

/// Estimate the transmittance of `scene` along every ray of `rays`, ray `i` with ray id
/// `ids[i]` (its random streams): one result per ray, in order, as [`estimate`] would give it
/// (exact trilinear answers to the kernel's f32 positions, see the module docs). Runs on the
/// current rayon pool.
///
/// # Errors
/// Per ray, as [`estimate`]: invalid options or a budget exceeded (every ray gets the error),
/// NaN on that ray; `ids` shorter than `rays` is an argument error for the rays without one.
pub fn estimate_many(
    scene: &Scene,
    rays: &[Ray],
    ids: &[u64],
    est: &Estimator,
    opts: &Options,
) -> Vec<Result<SceneEstimate>> {
    let by_ray = || {
        rays.par_iter()
            .enumerate()
            .map(|(i, r)| match ids.get(i) {
                Some(&id) => estimate(scene, r, id, est, opts),
                None => Err(crate::error::Error::InvalidArgument {
                    name: "ids".into(),
                    reason: format!("{} ray ids for {} rays", ids.len(), rays.len()),
                }),
            })
            .collect()
    };
    // A volume with motion goes ray by ray: the batch kernel reads the still grid, and the
    // ray path refuses `regular` on it.
    let motion = scene.fogs.iter().any(|f| f.volume.motion().is_some());
    if *est != Estimator::REGULAR
        || opts.interp != Interp::Trilinear
        || ids.len() < rays.len()
        || motion
    {
        return by_ray();
    }
    let checked = opts.validate().and_then(|()| {
        scene
            .fogs
            .iter()
            .try_for_each(|f| budget::check_ray(&f.volume, est, opts.samples))
    });
    if checked.is_err() {
        return by_ray();
    }
    let channels = scene.channels();
    // Far rays moved next to the scene's box first, as `estimate` moves them.
    let world = scene.world_box();
    let moved: Vec<(Ray, f64)> = rays.iter().map(|r| Scene::localise(r, world)).collect();
    let hits: Vec<Option<f64>> = moved
        .par_iter()
        .map(|(ray, shift)| {
            scene
                .solids
                .iter()
                .filter_map(|s| s.first_hit(ray))
                .min_by(f64::total_cmp)
                .map(|t| t + shift)
        })
        .collect();
    let open: Vec<Ray> = moved
        .iter()
        .zip(&hits)
        .filter(|(_, h)| h.is_none())
        .map(|((r, _), _)| *r)
        .collect();
    // Per open ray: its optical depth per channel, lookups and segments, summed over the
    // volumes (the first volume's error kept).
    let single = scene.single().is_some();
    let mut sums: Vec<Result<([f64; 3], u64, u64)>> =
        (0..open.len()).map(|_| Ok(([0.0; 3], 0, 0))).collect();
    for f in &scene.fogs {
        let depths = crate::regular::optical_depths(&f.volume, &open, Interp::Trilinear);
        for (sum, od) in sums.iter_mut().zip(depths) {
            let Ok((tau, lookups, segments)) = sum else {
                continue;
            };
            match od {
                Ok(od) => {
                    for (c, t) in tau.iter_mut().enumerate() {
                        // One grey volume: its optical depth as it is, as the single-volume
                        // path gives it; otherwise `sum_k sigma_k,c tau_k`.
                        *t += if single {
                            od.tau
                        } else {
                            scaled(f.sigma[c], od.tau)
                        };
                    }
                    *lookups += od.lookups;
                    *segments += od.segments;
                }
                Err(e) => *sum = Err(e),
            }
        }
    }
    let mut open_sums = sums.into_iter();
    hits.iter()
        .map(|hit| {
            if let Some(t) = hit {
                return Ok(SceneEstimate::behind_solid(channels, *t, true));
            }
            // One sum per open ray, taken in order.
            let Some(sum) = open_sums.next() else {
                return Err(crate::error::Error::nan_on_ray("optical depth", &rays[0]));
            };
            let (tau, lookups, segments) = sum?;
            Ok(SceneEstimate::exact(channels, tau, lookups, segments))
        })
        .collect()
}
