//! Colour walks side by side (`umbra compare FILE --sigma-t R,G,B`): every stochastic or
//! marching estimator over its ladder, once with the shared walk (one majorant for all
//! channels, lookups replayed) and once with split walks (per-channel majorants), on the same
//! rays and seeds, scored per channel against exact regular tracking.
//!
//! A point's error is the mean over channels of the per-channel MSE, and its efficiency
//! `1 / (MSE x seconds)` as in the grey ladder. Per estimator, the walk that wins is the one
//! with the larger geometric mean of efficiency over the ladder's budgets (the ratio
//! `split / shared` per budget is in the table); [`ColourWalk::Auto`] takes the choice
//! written in the registry ([`crate::estimate::Spec::colour`]), and the report says whether
//! this run agrees with it.

use super::{score, timed, Settings};
use crate::error::Result;
use crate::estimate::{ColourWalk, Estimator};
use crate::ray::Ray;
use crate::scene::{estimate as scene_estimate, Scene};
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;

/// One (estimator, budget, walk) point of the colour comparison.
#[derive(Debug, Clone, Serialize)]
pub struct ColourRow {
    /// Estimator name.
    pub estimator: String,
    /// Budget label as in the grey ladder (`spp=N`, `step=S`, `points=P`).
    pub budget: String,
    /// The walk: `shared` or `split`.
    pub walk: ColourWalk,
    /// Root mean square error of `T_c` over the rays, per channel (R, G, B).
    pub rmse: [f64; 3],
    /// Mean signed error per channel.
    pub bias: [f64; 3],
    /// Mean over channels of the per-channel MSE.
    pub mse: f64,
    /// Median wall time for the whole ray set (all channels), seconds.
    pub seconds: f64,
    /// Density lookups for the whole ray set (one lookup serves every channel).
    pub lookups: u64,
    /// `1 / (mse x seconds)`; infinite for exact answers.
    pub efficiency: f64,
    /// Samples stopped by the collision cap.
    pub capped: u64,
    /// Non-finite estimates, all channels.
    pub non_finite: u64,
}

/// Per estimator: which walk this run measured as more efficient, and what `auto` picks.
#[derive(Debug, Clone, Serialize)]
pub struct ColourVerdict {
    /// Estimator name.
    pub estimator: String,
    /// Geometric mean over budgets of `efficiency(split) / efficiency(shared)`.
    pub split_over_shared: f64,
    /// The walk with the larger mean efficiency.
    pub winner: ColourWalk,
    /// What [`ColourWalk::Auto`] resolves to for this estimator.
    pub auto: ColourWalk,
}

/// Exact transmittance of each ray, per channel (what [`compare_colour`] scores against).
#[must_use]
pub fn reference(scene: &Scene, rays: &[Ray], s: &Settings) -> Vec<[f64; 3]> {
    rays.par_iter()
        .enumerate()
        .map(|(i, r)| {
            scene_estimate(scene, r, i as u64, &Estimator::REGULAR, &s.options)
                .map_or([f64::NAN; 3], |e| e.value)
        })
        .collect()
}

/// Run every estimator of `estimators` (exact ones are skipped: they have no walk) over its
/// ladder with both walks, scored against `exact` (`reference` of the same rays).
///
/// # Errors
/// Propagates estimator errors.
pub fn compare_colour(
    scene: &Scene,
    rays: &[Ray],
    exact: &[[f64; 3]],
    estimators: &[Estimator],
    s: &Settings,
    mut progress: impl FnMut(&str),
) -> Result<Vec<ColourRow>> {
    s.options.validate()?;
    let channels = scene.channels();
    let mut rows = Vec::new();
    for base in estimators.iter().filter(|e| **e != Estimator::REGULAR) {
        for (est, label, value) in super::ladder(base) {
            for walk in [ColourWalk::Shared, ColourWalk::Split] {
                progress(&format!("{} {label} {}", base.name(), walk.name()));
                let mut opts = s.options;
                opts.colour_walk = walk;
                opts.samples = if label.starts_with("spp=") {
                    value as u32
                } else {
                    1
                };
                let run = || -> Result<Vec<([f64; 3], u64, u64)>> {
                    rays.par_iter()
                        .enumerate()
                        .map(|(i, r)| {
                            scene_estimate(scene, r, i as u64, &est, &opts)
                                .map(|e| (e.value, e.lookups, e.capped))
                        })
                        .collect()
                };
                let (last, seconds) = timed(s.repeats, run)?;
                let (mut rmse, mut bias, mut mse, mut non_finite) = ([0.0; 3], [0.0; 3], 0.0, 0);
                for c in 0..channels {
                    let v: Vec<f64> = last.iter().map(|x| x.0[c]).collect();
                    let t: Vec<f64> = exact.iter().map(|x| x[c]).collect();
                    let (r, b, _, _, nf) = score(&v, &t);
                    rmse[c] = r;
                    bias[c] = b;
                    mse += r * r / channels as f64;
                    non_finite += nf;
                }
                rows.push(ColourRow {
                    estimator: base.name().to_string(),
                    budget: label.clone(),
                    walk,
                    rmse,
                    bias,
                    mse,
                    seconds,
                    lookups: last.iter().map(|x| x.1).sum(),
                    efficiency: if mse > 0.0 {
                        1.0 / (mse * seconds.max(1e-9))
                    } else {
                        f64::INFINITY
                    },
                    capped: last.iter().map(|x| x.2).sum(),
                    non_finite,
                });
            }
        }
    }
    Ok(rows)
}

/// Per estimator, the walk that won (geometric mean of the efficiency ratio over the budgets
/// where both are finite and positive) and what `auto` picks for one volume of colour `sigma`.
#[must_use]
pub fn verdicts(rows: &[ColourRow], sigma: [f64; 3]) -> Vec<ColourVerdict> {
    let high = sigma.iter().copied().fold(0.0f64, f64::max);
    let low = sigma.iter().copied().fold(f64::INFINITY, f64::min);
    let spread = if high > 0.0 { low / high } else { 1.0 };
    let mut names: Vec<&str> = rows.iter().map(|r| r.estimator.as_str()).collect();
    names.dedup();
    names
        .into_iter()
        .filter_map(|name| {
            let (mut sum, mut n) = (0.0, 0u32);
            for shared in rows
                .iter()
                .filter(|r| r.estimator == name && r.walk == ColourWalk::Shared)
            {
                let split = rows.iter().find(|r| {
                    r.estimator == name && r.budget == shared.budget && r.walk == ColourWalk::Split
                })?;
                let ratio = split.efficiency / shared.efficiency;
                if ratio.is_finite() && ratio > 0.0 {
                    sum += ratio.ln();
                    n += 1;
                }
            }
            let ratio = if n > 0 {
                (sum / f64::from(n)).exp()
            } else {
                1.0
            };
            let auto = Estimator::from_name(name)
                .map_or(ColourWalk::Shared, |e| ColourWalk::Auto.resolve(&e, spread));
            Some(ColourVerdict {
                estimator: name.to_string(),
                split_over_shared: ratio,
                winner: if ratio > 1.0 {
                    ColourWalk::Split
                } else {
                    ColourWalk::Shared
                },
                auto,
            })
        })
        .collect()
}

/// The colour report as Markdown: the verdicts ([`verdicts`] of `rows`), then every point.
#[must_use]
pub fn colour_markdown(
    rows: &[ColourRow],
    verdicts: &[ColourVerdict],
    meta: &super::Meta,
    sigma: [f64; 3],
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# umbra colour walks: shared against split\n");
    let _ = writeln!(
        md,
        "- source: {}\n- extinction colour sigma_t: {}, {}, {}\n- rays: {}, threads: {}, \
         repeats: {}\n- medium: {}\n- reference: {}\n- machine: {}\n",
        meta.source,
        sigma[0],
        sigma[1],
        sigma[2],
        meta.rays,
        meta.threads,
        meta.repeats,
        meta.medium,
        meta.reference,
        meta.machine
    );
    let _ = writeln!(
        md,
        "Efficiency is `1 / (MSE x seconds)`, MSE averaged over R, G, B. `split / shared` is \
         the geometric mean over the budgets of the ratio of efficiencies; `auto` is what \
         `--colour-walk auto` (the default) runs.\n"
    );
    let _ = writeln!(
        md,
        "| estimator | split / shared | winner here | auto | agrees |\n|---|---:|---|---|---|"
    );
    for v in verdicts {
        let _ = writeln!(
            md,
            "| {} | {:.2} | {} | {} | {} |",
            v.estimator,
            v.split_over_shared,
            v.winner.name(),
            v.auto.name(),
            if v.winner == v.auto { "yes" } else { "no" }
        );
    }
    let _ = writeln!(
        md,
        "\n| estimator | budget | walk | RMSE R | RMSE G | RMSE B | seconds | lookups | \
         efficiency |\n|---|---|---|---:|---:|---:|---:|---:|---:|"
    );
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.3e} | {:.3e} | {:.3e} | {:.4} | {} | {:.3e} |",
            r.estimator,
            r.budget,
            r.walk.name(),
            r.rmse[0],
            r.rmse[1],
            r.rmse[2],
            r.seconds,
            r.lookups,
            r.efficiency
        );
    }
    md
}
