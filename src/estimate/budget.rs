//! The work budget: parameters that imply more work than any real job needs are refused up
//! front, with the largest accepted value in the message, instead of running for hours with no
//! end in sight (`--samples 4294967295`, a 0.001-voxel march at 16K, `--max-spp 2^32`).
//!
//! The costs are bounded before any ray is traced:
//! - samples per ray: at most [`MAX_SAMPLES_PER_RAY`] (`--samples`, `--spp`, `--max-spp`);
//! - samples per job: `rays x samples <= `[`MAX_SAMPLES_PER_JOB`] (a bake's rays are its pixels,
//!   its samples `max(spp, max-spp)` when adaptive);
//! - ray-marching lookups: `steps = reach / step + 3 (reach / 8 + 1)` per sample (each chord
//!   of an `8^3` block may add a piece, and a ray crosses at most `reach / 8 + 1` block
//!   planes per axis), `reach` being
//!   [`Volume::data_reach`] (the longest index-space length a ray can spend in non-background
//!   nodes, so a sparse grid spanning the index range is not charged for its empty space);
//!   `samples x steps <= `[`MAX_LOOKUPS_PER_RAY`] and `rays x samples x steps <=
//!   `[`MAX_LOOKUPS_PER_JOB`], a blurred marcher's samples counted once per stratified shutter
//!   time (`--time-samples`).
//!
//! Null-collision estimators' cost depends on the data (the majorant optical depth); each
//! sample is capped by `Options::max_collisions`, and long bakes show progress and stop
//! cleanly on SIGINT.

use super::Estimator;
use crate::error::{Error, Result};
use crate::math::{approx, short};
use crate::volume::Volume;

/// Most samples per ray: 2^24 = 16,777,216. The standard error of a mean of estimates in
/// `[0, 1]` is at most `0.5 / sqrt(n)`: 1.2e-4 at this count, finer than any shadow map needs.
pub const MAX_SAMPLES_PER_RAY: u32 = 1 << 24;
/// Most samples per job: 2^36 = 6.9e10 (a 4096^2 map at 4096 spp).
pub const MAX_SAMPLES_PER_JOB: u64 = 1 << 36;
/// Most ray-marching lookups per ray: 2^34 = 1.7e10 (minutes for a single ray).
pub const MAX_LOOKUPS_PER_RAY: f64 = (1u64 << 34) as f64;
/// Most ray-marching lookups per job: 2^42 = 4.4e12 (hours on a farm node).
pub const MAX_LOOKUPS_PER_JOB: f64 = (1u64 << 42) as f64;

fn refuse(name: &str, reason: String) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason,
    }
}

/// Check the samples of one ray: `samples <= MAX_SAMPLES_PER_RAY`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `name` (`samples`, `spp`, `max-spp`).
pub fn check_samples(name: &str, samples: u64) -> Result<()> {
    if samples > u64::from(MAX_SAMPLES_PER_RAY) {
        return Err(refuse(
            name,
            format!(
                "{samples} samples per ray is beyond the work budget: at most \
                 {MAX_SAMPLES_PER_RAY}"
            ),
        ));
    }
    Ok(())
}

/// Marching steps per sample for `est` on `vol` (`None` for estimators without a step).
#[must_use]
pub fn steps_per_sample(vol: &Volume, est: &Estimator) -> Option<f64> {
    est.param("step")
        .map(|step| vol.data_reach() / step + chord_pieces(vol))
}

/// The pieces a march may add to `reach / step` per sample: one per `8^3` block chord, at
/// most `reach / 8 + 1` block planes crossed per axis.
fn chord_pieces(vol: &Volume) -> f64 {
    3.0 * (vol.data_reach() / 8.0 + 1.0)
}

/// Check one ray's cost: `samples` samples of `est` on `vol`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `samples`, or `step` when the march is too fine, with
/// the largest (smallest step) accepted value.
pub fn check_ray(vol: &Volume, est: &Estimator, samples: u32) -> Result<()> {
    check_samples("samples", u64::from(samples))?;
    let samples = if est.spec().deterministic { 1 } else { samples };
    let marches = f64::from(samples) * marches_per_sample(vol, est);
    check_steps(vol, est, marches, MAX_LOOKUPS_PER_RAY, "per ray")
}

/// Marches per sample: a marcher on a moving volume marches each of its `K` stratified shutter
/// times (`--time-samples`), every other case once.
fn marches_per_sample(vol: &Volume, est: &Estimator) -> f64 {
    match vol.moving() {
        Some(m) if est.marches() => f64::from(m.spec().time_samples()),
        _ => 1.0,
    }
}

/// Check a job of `rays` rays of up to `samples` samples each (`name`: the option that sets
/// them, `samples`, `spp` or `max-spp`): each ray as [`check_ray`], then the job's totals.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `name` or `step`, with the largest accepted value.
pub fn check_job(vol: &Volume, est: &Estimator, rays: u64, samples: u64, name: &str) -> Result<()> {
    check_samples(name, samples)?;
    check_ray(vol, est, u32::try_from(samples).unwrap_or(u32::MAX))?;
    let samples = if est.spec().deterministic { 1 } else { samples };
    let total = rays.saturating_mul(samples);
    if total > MAX_SAMPLES_PER_JOB {
        return Err(refuse(
            name,
            format!(
                "{rays} rays x {samples} samples is {} samples, beyond the work budget of \
                 {MAX_SAMPLES_PER_JOB} per job: at most {} samples per ray here",
                approx(total as f64),
                (MAX_SAMPLES_PER_JOB / rays.max(1)).max(1)
            ),
        ));
    }
    let marches = total as f64 * marches_per_sample(vol, est);
    check_steps(vol, est, marches, MAX_LOOKUPS_PER_JOB, "per job")
}

fn check_steps(vol: &Volume, est: &Estimator, samples: f64, budget: f64, per: &str) -> Result<()> {
    let (Some(step), Some(steps)) = (est.param("step"), steps_per_sample(vol, est)) else {
        return Ok(());
    };
    let lookups = samples * steps;
    if lookups > budget {
        // `samples (reach / step + extra) <= budget`; past `budget / samples <= extra` no step
        // fits, and the message says so with an infinite step.
        let room = budget / samples - chord_pieces(vol);
        let smallest = if room > 0.0 {
            vol.data_reach() / room
        } else {
            f64::INFINITY
        };
        return Err(refuse(
            "step",
            format!(
                "a {} voxel step over up to {} voxels of data ({} marches: samples x shutter \
                 times) is {} lookups, \
                 beyond the work budget of {} {per}: a step of at least {} voxels is accepted",
                short(step),
                approx(vol.data_reach()),
                approx(samples),
                approx(lookups),
                approx(budget),
                approx(smallest * 1.001)
            ),
        ));
    }
    Ok(())
}
