//! `error_vs_time.svg` of `umbra compare`, drawn with plotters (a CLI dependency only).

use anyhow::Result;
use plotters::prelude::*;
use umbra::compare::Row;

/// The log-log plot of RMSE against wall time, one line per estimator, as SVG text.
pub fn svg(rows: &[Row]) -> Result<String> {
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
        let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing the plot: {e}");
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
