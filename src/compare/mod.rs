//! Error against run time: every estimator over a ladder of budgets, scored against exact
//! regular tracking on the same rays.
//!
//! For each (estimator, budget) point the report holds, over the ray set: RMSE, bias (mean
//! signed error), variance of the error, max |error|, wall time (median of `repeats` timed runs
//! after one warm-up, all rays in parallel on `threads` threads), density lookups, and the
//! efficiency `1 / (MSE x seconds)`. Results are deterministic (per-ray random streams); only
//! the times vary between runs.

pub mod colour;
pub mod deep;
mod report;
pub mod stress;

pub use report::{markdown, write_reports, Meta};

use crate::error::Result;
use crate::estimate::registry::Budget;
use crate::estimate::{estimate, Estimator, Options};
use crate::ray::Ray;
use crate::regular::optical_depth;
use crate::rng::Rng;
use crate::volume::Volume;
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// `n` rays crossing the volume's value box: from a random point on a sphere around the box,
/// through a random point of the box's middle 60 %, to the far side of the sphere.
#[must_use]
pub fn random_rays(vol: &Volume, n: usize, seed: u64) -> Vec<Ray> {
    let Some([lo, hi]) = vol.value_box() else {
        return Vec::new();
    };
    let lo_w = vol.to_world(lo.map(|c| c as f64));
    let hi_w = vol.to_world(hi.map(|c| c as f64));
    let (mut bmin, mut bmax) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for a in 0..3 {
        bmin[a] = lo_w[a].min(hi_w[a]);
        bmax[a] = lo_w[a].max(hi_w[a]);
    }
    let radius = (0..3)
        .map(|a| (bmax[a] - bmin[a]).powi(2))
        .sum::<f64>()
        .sqrt()
        .max(1e-300);
    (0..n)
        .filter_map(|i| {
            let mut rng = Rng::new(seed, i as u64, u64::MAX);
            let mut d = [0.0; 3];
            while d.iter().map(|x| x * x).sum::<f64>() < 1e-2 {
                d = [0, 1, 2].map(|_| 2.0 * rng.uniform() - 1.0);
            }
            let len = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            let target =
                [0, 1, 2].map(|a| bmin[a] + (0.2 + 0.6 * rng.uniform()) * (bmax[a] - bmin[a]));
            let o = [0, 1, 2].map(|a| target[a] - d[a] / len * radius);
            Ray::new(o, d, 0.0, 2.0 * radius).ok()
        })
        .collect()
}

/// One point of the error-vs-time ladder.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// Estimator name.
    pub estimator: String,
    /// Budget label: `spp=N`, `step=S`, `points=P`, or `exact`.
    pub budget: String,
    /// Numeric budget (samples, step in voxels, or points) for plotting.
    pub budget_value: f64,
    /// Root mean square error of T over the rays.
    pub rmse: f64,
    /// Mean signed error.
    pub bias: f64,
    /// Variance of the error over the rays.
    pub variance: f64,
    /// Largest absolute error.
    pub max_error: f64,
    /// Median wall time for the whole ray set, seconds.
    pub seconds: f64,
    /// Density lookups for the whole ray set.
    pub lookups: u64,
    /// `1 / (MSE x seconds)`; infinite for exact answers.
    pub efficiency: f64,
    /// Samples stopped by the collision cap.
    pub capped: u64,
    /// Non-finite estimates (should be 0).
    pub non_finite: u64,
}

/// The ladder of budgets `umbra compare` runs `base` at, derived from its registry entry
/// ([`crate::estimate::registry::Budget`]): exact estimators once, parameter budgets over
/// [`crate::estimate::Param::ladder`] (other parameters as in `base`), sampled ones at
/// 1, 4, 16, 64 samples per ray. Each entry is the estimator, its budget label and the budget
/// value (samples for `spp=` labels).
#[must_use]
pub fn ladder(base: &Estimator) -> Vec<(Estimator, String, f64)> {
    let spec = base.spec();
    match spec.budget {
        Budget::Exact => vec![(*base, "exact".into(), 1.0)],
        Budget::Param => {
            let p = &spec.params[0];
            p.ladder
                .iter()
                .filter_map(|&v| base.set(p.name, v).ok())
                .map(|e| {
                    let v = e.param(p.name).unwrap_or(f64::NAN);
                    (e, format!("{}={v}", p.name), v)
                })
                .collect()
        }
        Budget::Samples => [1u32, 4, 16, 64]
            .iter()
            .map(|&n| (*base, format!("spp={n}"), f64::from(n)))
            .collect(),
    }
}

/// Settings of a comparison run.
#[derive(Debug, Clone, Serialize)]
pub struct Settings {
    /// Estimator options (interp, seed, granularity...); `samples` is set by the ladder.
    pub options: Options,
    /// Timed repetitions per point (after one warm-up).
    pub repeats: usize,
    /// Worker threads.
    pub threads: usize,
    /// Whether the ratio-tracking baseline with a global majorant is added.
    pub global_baseline: bool,
}

/// Exact transmittance of each ray.
#[must_use]
pub fn reference(vol: &Volume, rays: &[Ray], opts: &Options) -> Vec<f64> {
    rays.par_iter()
        .map(|r| optical_depth(vol, r, opts.interp).map_or(f64::NAN, |od| od.transmittance()))
        .collect()
}

/// Shortest time one timed repetition of a ladder point lasts: shorter runs are repeated
/// (the whole ray set again) until they reach it, and the time per pass is reported.
pub const MIN_TIMED: std::time::Duration = std::time::Duration::from_millis(50);

/// Run one ladder point over all rays: one warm-up, then `repeats` timed repetitions, each
/// running the ray set `k` times where `k` makes it last at least [`MIN_TIMED`]. Returns the
/// values, the median seconds per pass over the ray set, the lookups and the capped samples.
///
/// # Errors
/// Propagates estimator errors (none are expected for valid rays).
pub fn run_point(
    vol: &Volume,
    rays: &[Ray],
    est: &Estimator,
    opts: &Options,
    repeats: usize,
) -> Result<(Vec<f64>, f64, u64, u64)> {
    let run = || -> Result<Vec<(f64, u64, u64)>> {
        rays.par_iter()
            .enumerate()
            .map(|(i, r)| {
                estimate(vol, r, i as u64, est, opts).map(|e| (e.value, e.lookups, e.capped))
            })
            .collect()
    };
    let (last, seconds) = timed(repeats, run)?;
    let values: Vec<f64> = last.iter().map(|x| x.0).collect();
    let lookups = last.iter().map(|x| x.1).sum();
    let capped = last.iter().map(|x| x.2).sum();
    Ok((values, seconds, lookups, capped))
}

/// Time `run` (one pass over a ray set): one warm-up, then `repeats` timed repetitions, each
/// running it `k` times where `k` makes it last at least [`MIN_TIMED`]. Returns the last
/// pass's results and the median seconds per pass.
fn timed<T>(repeats: usize, run: impl Fn() -> Result<Vec<T>>) -> Result<(Vec<T>, f64)> {
    let t0 = Instant::now();
    let mut last = run()?; // warm-up, and the pass count that reaches MIN_TIMED
    let once = t0.elapsed().as_secs_f64().max(1e-9);
    let passes = (MIN_TIMED.as_secs_f64() / once).ceil().clamp(1.0, 1e6) as usize;
    let mut times = Vec::new();
    for _ in 0..repeats.max(1) {
        let t0 = Instant::now();
        for _ in 0..passes {
            last = run()?;
        }
        times.push(t0.elapsed().as_secs_f64() / passes as f64);
    }
    times.sort_by(f64::total_cmp);
    Ok((last, times[times.len() / 2]))
}

/// Error statistics of estimates against the exact values.
#[must_use]
pub fn score(values: &[f64], exact: &[f64]) -> (f64, f64, f64, f64, u64) {
    let n = values.len().max(1) as f64;
    let mut non_finite = 0;
    let errs: Vec<f64> = values
        .iter()
        .zip(exact)
        .map(|(v, t)| {
            if !v.is_finite() {
                non_finite += 1;
            }
            v - t
        })
        .collect();
    let bias = errs.iter().sum::<f64>() / n;
    let mse = errs.iter().map(|e| e * e).sum::<f64>() / n;
    let variance = errs.iter().map(|e| (e - bias).powi(2)).sum::<f64>() / n;
    let max = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    (mse.sqrt(), bias, variance, max, non_finite)
}

/// Run every estimator of `names` over its ladder.
///
/// # Errors
/// Propagates estimator errors.
pub fn compare(
    vol: &Volume,
    rays: &[Ray],
    estimators: &[Estimator],
    s: &Settings,
    mut progress: impl FnMut(&str),
) -> Result<Vec<Row>> {
    s.options.validate()?;
    let exact = reference(vol, rays, &s.options);
    let mut rows = Vec::new();
    let mut points: Vec<(String, Estimator, String, f64, bool)> = Vec::new();
    for base in estimators {
        for (e, label, v) in ladder(base) {
            points.push((base.name().to_string(), e, label, v, false));
        }
    }
    if s.global_baseline {
        for (e, label, v) in ladder(&Estimator::from_name("ratio")?) {
            points.push(("ratio-global-majorant".into(), e, label, v, true));
        }
    }
    for (name, est, label, value, global) in points {
        progress(&format!("{name} {label}"));
        let mut opts = s.options;
        opts.global_majorant = global;
        if label.starts_with("spp=") {
            opts.samples = value as u32;
        } else {
            opts.samples = 1;
        }
        let (values, seconds, lookups, capped) = run_point(vol, rays, &est, &opts, s.repeats)?;
        let (rmse, bias, variance, max_error, non_finite) = score(&values, &exact);
        let mse = rmse * rmse;
        rows.push(Row {
            estimator: name,
            budget: label,
            budget_value: value,
            rmse,
            bias,
            variance,
            max_error,
            seconds,
            lookups,
            efficiency: if mse > 0.0 {
                1.0 / (mse * seconds.max(1e-9))
            } else {
                f64::INFINITY
            },
            capped,
            non_finite,
        });
    }
    Ok(rows)
}
