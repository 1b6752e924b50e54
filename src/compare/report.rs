//! Writing a comparison: `report.csv`, `report.json`, `report.md` (one table per budget level,
//! best estimator per error level marked) and, when the caller drew one, `error_vs_time.svg`
//! (the CLI draws it with plotters; the library has no plotting dependency). The files are
//! staged and renamed together: all of them appear, or none.

use super::Row;
use crate::error::Result;
pub use crate::math::sig3;
use crate::output::{commit_all, stage};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// What the report states about how it was made.
#[derive(Debug, Clone, Serialize)]
pub struct Meta {
    /// Source file and grid.
    pub source: String,
    /// Rays in the set.
    pub rays: usize,
    /// Worker threads.
    pub threads: usize,
    /// Timed repetitions per point (median reported), after one warm-up.
    pub repeats: usize,
    /// Interpolation, density scale, seed.
    pub medium: String,
    /// Machine description (CPU model, cores).
    pub machine: String,
    /// Mean exact transmittance over the rays, and the range of optical depths.
    pub reference: String,
}

fn io(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Write the report files into `dir` (created if missing): CSV, JSON, markdown, and `svg` as
/// `error_vs_time.svg` when given.
///
/// # Errors
/// [`crate::error::Error::Output`] when a file cannot be written (then none is).
pub fn write_reports(dir: &Path, rows: &[Row], meta: &Meta, svg: Option<&str>) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| crate::error::Error::Io {
        path: dir.to_path_buf(),
        err: e,
    })?;
    let mut staged = Vec::new();
    staged.push(stage(&dir.join("report.csv"), true, |w| {
        writeln!(w, "estimator,budget,rmse,bias,variance,max_error,seconds,lookups,efficiency,capped,non_finite").map_err(io)?;
        for r in rows {
            writeln!(
                w,
                "{},{},{:e},{:e},{:e},{:e},{:e},{},{:e},{},{}",
                r.estimator,
                r.budget,
                r.rmse,
                r.bias,
                r.variance,
                r.max_error,
                r.seconds,
                r.lookups,
                r.efficiency,
                r.capped,
                r.non_finite
            )
            .map_err(io)?;
        }
        Ok(())
    })?);
    staged.push(stage(&dir.join("report.json"), true, |w| {
        let rows_json: Vec<serde_json::Value> = rows
            .iter()
            .map(|r| {
                let mut v = serde_json::to_value(r).unwrap_or_default();
                if !r.efficiency.is_finite() {
                    v["efficiency"] = serde_json::json!("inf");
                }
                v
            })
            .collect();
        serde_json::to_writer_pretty(
            &mut *w,
            &serde_json::json!({ "meta": meta, "notes": notes(rows), "rows": rows_json }),
        )
        .map_err(io)?;
        writeln!(w).map_err(io)
    })?);
    staged.push(stage(&dir.join("report.md"), true, |w| {
        w.write_all(markdown(rows, meta).as_bytes()).map_err(io)
    })?);
    if let Some(svg) = svg {
        staged.push(stage(&dir.join("error_vs_time.svg"), true, |w| {
            w.write_all(svg.as_bytes()).map_err(io)
        })?);
    }
    commit_all(staged)
}

/// What the rows say that a reader would otherwise have to find out: `collision` scoring the
/// same as `track-length` at every budget (its ramp kernel only scores collisions within
/// `--kernel` voxels before the end of a ray's last stretch of active voxels, and the compared
/// rays cross the whole volume).
#[must_use]
pub fn notes(rows: &[Row]) -> Vec<String> {
    let of = |name: &str| -> Vec<&Row> { rows.iter().filter(|r| r.estimator == name).collect() };
    let (collision, track) = (of("collision"), of("track-length"));
    let same = !collision.is_empty()
        && collision.iter().all(|c| {
            track.iter().any(|t| {
                t.budget == c.budget
                    && t.rmse.to_bits() == c.rmse.to_bits()
                    && t.bias.to_bits() == c.bias.to_bits()
                    && t.max_error.to_bits() == c.max_error.to_bits()
            })
        });
    let mut out = Vec::new();
    if same {
        out.push(
            "collision's errors equal track-length's at every budget (only their times \
             differ): both walk the same delta-tracking flights, and collision's ramp kernel \
             scores only a real collision within --kernel voxels before the end of the ray's \
             last stretch of active voxels. Every compared ray crosses the volume, so that \
             stretch is the medium's faint edge, where no real collision landed. The two \
             differ on segments that end inside the medium (a shadow ray from a point in the \
             cloud: `query --at`, `--from/--to`)."
                .to_string(),
        );
    }
    out
}

/// The markdown report: settings, then rows grouped by budget rank (cheapest first), the most
/// efficient stochastic estimator of each group in bold.
#[must_use]
pub fn markdown(rows: &[Row], meta: &Meta) -> String {
    let mut s = String::new();
    s.push_str("# Error against run time\n\n");
    s.push_str(&format!(
        "- source: {}\n- rays: {}; threads: {}; timing: median of {} runs after a warm-up\n- medium: {}\n- reference: {}\n- machine: {}\n\n",
        meta.source, meta.rays, meta.threads, meta.repeats, meta.medium, meta.reference, meta.machine
    ));
    s.push_str("Efficiency is 1 / (MSE x seconds); **bold** marks the most efficient estimator at each budget level.\n\n");
    for n in notes(rows) {
        s.push_str(&format!("Note: {n}\n\n"));
    }
    // Budget levels: position in each estimator's ladder.
    let mut by_level: BTreeMap<usize, Vec<&Row>> = BTreeMap::new();
    let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
    for r in rows {
        let k = seen.entry(r.estimator.as_str()).or_insert(0);
        by_level.entry(*k).or_default().push(r);
        *k += 1;
    }
    for (level, group) in by_level {
        s.push_str(&format!("## Budget level {}\n\n", level + 1));
        s.push_str("| estimator | budget | RMSE | bias | max error | seconds | lookups | efficiency |\n|---|---|---:|---:|---:|---:|---:|---:|\n");
        let best = group
            .iter()
            .filter(|r| r.efficiency.is_finite())
            .max_by(|a, b| a.efficiency.total_cmp(&b.efficiency))
            .map(|r| (r.estimator.clone(), r.budget.clone()));
        for r in group {
            let mark = best.as_ref() == Some(&(r.estimator.clone(), r.budget.clone()));
            let name = if mark {
                format!("**{}**", r.estimator)
            } else {
                r.estimator.clone()
            };
            s.push_str(&format!(
                "| {name} | {} | {:.3e} | {:.2e} | {:.2e} | {} | {} | {} |\n",
                r.budget,
                r.rmse,
                r.bias,
                r.max_error,
                sig3(r.seconds),
                r.lookups,
                if r.efficiency.is_finite() {
                    format!("{:.3e}", r.efficiency)
                } else {
                    "exact".into()
                }
            ));
        }
        s.push('\n');
    }
    s
}
