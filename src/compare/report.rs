//! Writing a comparison: `report.csv`, `report.json`, `report.md` (one table per budget level,
//! best estimator per error level marked) and `error_vs_time.svg` (log-log RMSE against seconds,
//! one line per estimator). Every file is written atomically.

use super::Row;
use crate::error::Result;
use crate::output::write_atomic;
use plotters::prelude::*;
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

/// Write the four report files into `dir` (created if missing).
///
/// # Errors
/// [`crate::Error::Output`] when a file cannot be written.
pub fn write_reports(dir: &Path, rows: &[Row], meta: &Meta) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| crate::Error::Io {
        path: dir.to_path_buf(),
        err: e,
    })?;
    write_atomic(&dir.join("report.csv"), true, |w| {
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
    })?;
    write_atomic(&dir.join("report.json"), true, |w| {
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
            &serde_json::json!({ "meta": meta, "rows": rows_json }),
        )
        .map_err(io)?;
        writeln!(w).map_err(io)
    })?;
    write_atomic(&dir.join("report.md"), true, |w| {
        w.write_all(markdown(rows, meta).as_bytes()).map_err(io)
    })?;
    let svg = svg(rows)?;
    write_atomic(&dir.join("error_vs_time.svg"), true, |w| {
        w.write_all(svg.as_bytes()).map_err(io)
    })
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
                "| {name} | {} | {:.3e} | {:.2e} | {:.2e} | {:.4} | {} | {} |\n",
                r.budget,
                r.rmse,
                r.bias,
                r.max_error,
                r.seconds,
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

fn svg(rows: &[Row]) -> Result<String> {
    let mut out = String::new();
    {
        let pts: Vec<&Row> = rows
            .iter()
            .filter(|r| r.rmse > 0.0 && r.seconds > 0.0)
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
        for r in &pts {
            x0 = x0.min(r.seconds);
            x1 = x1.max(r.seconds);
            y0 = y0.min(r.rmse);
            y1 = y1.max(r.rmse);
        }
        if pts.is_empty() {
            (x0, x1, y0, y1) = (1e-3, 1.0, 1e-4, 1.0);
        }
        let root = SVGBackend::with_string(&mut out, (960, 640)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| crate::Error::InvalidArgument {
            name: "plot".into(),
            reason: e.to_string(),
        };
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption("RMSE of T against wall time (log-log)", ("sans-serif", 22))
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (x0 / 1.5..x1 * 1.5).log_scale(),
                (y0 / 1.5..y1 * 1.5).log_scale(),
            )
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("seconds (whole ray set)")
            .y_desc("RMSE")
            .draw()
            .map_err(|e| err(&e))?;
        let mut names: Vec<&str> = pts.iter().map(|r| r.estimator.as_str()).collect();
        names.dedup();
        names.sort_unstable();
        names.dedup();
        for (i, name) in names.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let mut line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|r| r.estimator == *name)
                .map(|r| (r.seconds, r.rmse))
                .collect();
            line.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label(*name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            chart
                .draw_series(line.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}
