//! `error_vs_time.svg` of `umbra compare`, drawn with plotters (a CLI dependency only).

use anyhow::Result;
use plotters::coord::Shift;
use plotters::prelude::*;
use umbra::compare::deep::DeepRow;
use umbra::compare::Row;

/// The log-log plot of RMSE against wall time, one line per estimator, each point labelled
/// with its budget, exact regular tracking as a vertical line at its time (its error is 0, off
/// a log axis), the legend beside the plot; as SVG text.
pub fn svg(rows: &[Row]) -> Result<String> {
    let mut out = String::new();
    {
        let pts: Vec<&Row> = rows
            .iter()
            .filter(|r| r.rmse > 0.0 && r.seconds > 0.0)
            .collect();
        let exact: Vec<&Row> = rows
            .iter()
            .filter(|r| r.rmse == 0.0 && r.seconds > 0.0 && r.budget == "exact")
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
        for r in &pts {
            x0 = x0.min(r.seconds);
            x1 = x1.max(r.seconds);
            y0 = y0.min(r.rmse);
            y1 = y1.max(r.rmse);
        }
        for r in &exact {
            x0 = x0.min(r.seconds);
            x1 = x1.max(r.seconds);
        }
        if pts.is_empty() {
            (x0, x1, y0, y1) = (1e-3, 1.0, 1e-4, 1.0);
        }
        let root = SVGBackend::with_string(&mut out, (1200, 700)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing the plot: {e}");
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let (plot, legend) = root.split_horizontally(930);
        let mut chart = ChartBuilder::on(&plot)
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
        names.sort_unstable();
        names.dedup();
        let mut keys = Vec::new();
        let mut labels = Labels::default();
        // The points first, so no label covers one.
        for r in &pts {
            let (x, y) = chart.backend_coord(&(r.seconds, r.rmse));
            labels.taken.push([x - 4, y - 4, x + 4, y + 4]);
        }
        for r in &exact {
            let color = BLACK.mix(0.7);
            let line = vec![(r.seconds, y0 / 1.5), (r.seconds, y1 * 1.5)];
            chart
                .draw_series(DashedLineSeries::new(line, 8, 5, color.stroke_width(2)))
                .map_err(|e| err(&e))?;
            keys.push((format!("{} (exact, RMSE 0)", r.estimator), color, true));
        }
        for (i, name) in names.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let mut line: Vec<&&Row> = pts.iter().filter(|r| r.estimator == *name).collect();
            line.sort_by(|a, b| a.budget_value.total_cmp(&b.budget_value));
            let xy: Vec<(f64, f64)> = line.iter().map(|r| (r.seconds, r.rmse)).collect();
            chart
                .draw_series(LineSeries::new(xy.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(xy.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
            for r in &line {
                let label = r.budget.split('=').nth(1).unwrap_or(&r.budget).to_string();
                let at = chart.backend_coord(&(r.seconds, r.rmse));
                if let Some(p) = labels.place(at, &label) {
                    root.draw(&Text::new(
                        label,
                        p,
                        ("sans-serif", 12).into_font().color(&color),
                    ))
                    .map_err(|e| err(&e))?;
                }
            }
            keys.push(((*name).to_string(), color, false));
        }
        // The legend, beside the plot.
        let style = ("sans-serif", 15).into_font();
        for (i, (name, color, dashed)) in keys.iter().enumerate() {
            let y = 70 + 24 * i as i32;
            let seg = vec![(8, y), (36, y)];
            if *dashed {
                legend
                    .draw(&PathElement::new(
                        vec![(8, y), (18, y)],
                        color.stroke_width(2),
                    ))
                    .map_err(|e| err(&e))?;
                legend
                    .draw(&PathElement::new(
                        vec![(26, y), (36, y)],
                        color.stroke_width(2),
                    ))
                    .map_err(|e| err(&e))?;
            } else {
                legend
                    .draw(&PathElement::new(seg, color.stroke_width(2)))
                    .map_err(|e| err(&e))?;
            }
            legend
                .draw(&Text::new(name.clone(), (44, y - 8), style.clone()))
                .map_err(|e| err(&e))?;
        }
        let y = 70 + 24 * keys.len() as i32 + 16;
        legend
            .draw(&Text::new(
                "labels: the budget (spp, step, points)",
                (8, y),
                ("sans-serif", 13).into_font(),
            ))
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

/// The budget labels placed so far, as pixel boxes `[x0, y0, x1, y1]`: a label goes to the first
/// spot around its point that overlaps none (above right, below right, above left, below left,
/// then further out), or is left out when every spot is taken (estimators whose points
/// coincide, such as `collision` and `track-length` on crossing rays, share the first's).
#[derive(Default)]
struct Labels {
    taken: Vec<[i32; 4]>,
}

impl Labels {
    /// Approximate size of a 12 px sans-serif label.
    fn size(text: &str) -> (i32, i32) {
        (7 * text.chars().count() as i32, 12)
    }

    fn place(&mut self, (x, y): (i32, i32), text: &str) -> Option<(i32, i32)> {
        let (w, h) = Self::size(text);
        let spots = [
            (x + 5, y - h - 4),
            (x + 5, y + 4),
            (x - w - 5, y - h - 4),
            (x - w - 5, y + 4),
            (x + 5, y - 2 * h - 6),
            (x + 5, y + h + 6),
            (x - w - 5, y - 2 * h - 6),
            (x - w - 5, y + h + 6),
        ];
        let free = |b: [i32; 4]| {
            self.taken
                .iter()
                .all(|t| b[2] <= t[0] || t[2] <= b[0] || b[3] <= t[1] || t[3] <= b[1])
        };
        let spot = spots
            .into_iter()
            .find(|&(sx, sy)| free([sx, sy, sx + w, sy + h]))?;
        self.taken.push([spot.0, spot.1, spot.0 + w, spot.1 + h]);
        Some(spot)
    }
}

/// `deep_error_vs_bytes.svg` of `umbra compare --deep`: error in T against bytes per texel
/// (log-log), one line per family through its RMS errors (filled dots) and its max errors
/// (crosses, dashed), each point labelled with its budget; the legend beside the plot.
pub fn deep_svg(rows: &[DeepRow]) -> Result<String> {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (1040, 640)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| drawing(&e))?;
        let (plot, legend) = root.split_horizontally(800);
        let pts: Vec<&DeepRow> = rows
            .iter()
            .filter(|r| r.bytes_per_texel > 0.0 && r.rms_error > 0.0 && r.max_error > 0.0)
            .collect();
        let (x0, x1, y0, y1) = deep_range(&pts);
        let mut chart = ChartBuilder::on(&plot)
            .caption(
                "Error in T against bytes per texel (log-log)",
                ("sans-serif", 22),
            )
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (x0 / 1.4..x1 * 1.4).log_scale(),
                (y0 / 1.6..y1 * 1.6).log_scale(),
            )
            .map_err(|e| drawing(&e))?;
        chart
            .configure_mesh()
            .x_desc("bytes per texel (the encoding's own, before compression)")
            .y_desc("error in T")
            .draw()
            .map_err(|e| drawing(&e))?;
        let mut families: Vec<&str> = pts.iter().map(|r| r.family.as_str()).collect();
        families.dedup();
        let mut keys = Vec::new();
        for (i, fam) in families.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let mine: Vec<&DeepRow> = pts.iter().copied().filter(|r| r.family == *fam).collect();
            deep_family(&mut chart, color, &mine)?;
            keys.push((fam.to_string(), color));
        }
        deep_legend(&legend, &keys)?;
        root.present().map_err(|e| drawing(&e))?;
    }
    Ok(out)
}

/// A drawing error of a plot.
fn drawing(e: &dyn std::fmt::Display) -> anyhow::Error {
    anyhow::anyhow!("drawing the plot: {e}")
}

/// The range `(x0, x1, y0, y1)` of the deep plot's points: bytes per texel, and errors (RMS
/// and max); a default frame when there are none.
fn deep_range(pts: &[&DeepRow]) -> (f64, f64, f64, f64) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for r in pts {
        x0 = x0.min(r.bytes_per_texel);
        x1 = x1.max(r.bytes_per_texel);
        y0 = y0.min(r.rms_error.min(r.max_error));
        y1 = y1.max(r.rms_error.max(r.max_error));
    }
    if pts.is_empty() {
        (x0, x1, y0, y1) = (1.0, 100.0, 1e-4, 1.0);
    }
    (x0, x1, y0, y1)
}

/// A log-log chart drawn as SVG text.
type LogChart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<LogCoord<f64>, LogCoord<f64>>>;

/// One family of the deep plot in `color`: its RMS errors (a line through filled dots), its max
/// errors (a dashed line through crosses), each point labelled with its budget.
fn deep_family(chart: &mut LogChart<'_, '_>, color: RGBAColor, mine: &[&DeepRow]) -> Result<()> {
    let rms: Vec<(f64, f64)> = mine
        .iter()
        .map(|r| (r.bytes_per_texel, r.rms_error))
        .collect();
    let max: Vec<(f64, f64)> = mine
        .iter()
        .map(|r| (r.bytes_per_texel, r.max_error))
        .collect();
    chart
        .draw_series(LineSeries::new(rms.clone(), color.stroke_width(2)))
        .map_err(|e| drawing(&e))?;
    chart
        .draw_series(rms.iter().map(|&p| Circle::new(p, 4, color.filled())))
        .map_err(|e| drawing(&e))?;
    chart
        .draw_series(DashedLineSeries::new(
            max.clone(),
            6,
            4,
            color.stroke_width(1),
        ))
        .map_err(|e| drawing(&e))?;
    chart
        .draw_series(max.iter().map(|&p| Cross::new(p, 4, color.stroke_width(2))))
        .map_err(|e| drawing(&e))?;
    for r in mine {
        let label = r
            .encoding
            .split(':')
            .nth(1)
            .unwrap_or(&r.encoding)
            .replace("--deep-error ", "E=");
        chart
            .draw_series(std::iter::once(Text::new(
                label,
                (r.bytes_per_texel * 1.05, r.rms_error * 1.15),
                ("sans-serif", 13).into_font().color(&color),
            )))
            .map_err(|e| drawing(&e))?;
    }
    Ok(())
}

/// The deep plot's legend: a line per family (`keys`: name and colour), then what the marks
/// mean.
fn deep_legend(
    legend: &DrawingArea<SVGBackend<'_>, Shift>,
    keys: &[(String, RGBAColor)],
) -> Result<()> {
    let style = ("sans-serif", 16).into_font();
    for (i, (name, color)) in keys.iter().enumerate() {
        let y = 80 + 28 * i as i32;
        legend
            .draw(&PathElement::new(
                vec![(10, y), (40, y)],
                color.stroke_width(2),
            ))
            .map_err(|e| drawing(&e))?;
        legend
            .draw(&Text::new(name.clone(), (48, y - 8), style.clone()))
            .map_err(|e| drawing(&e))?;
    }
    let y = 80 + 28 * keys.len() as i32 + 20;
    for (k, text) in [
        "dot, solid: RMS error",
        "cross, dashed: max error",
        "label: budget",
    ]
    .iter()
    .enumerate()
    {
        legend
            .draw(&Text::new(
                *text,
                (10, y + 22 * k as i32),
                ("sans-serif", 14).into_font(),
            ))
            .map_err(|e| drawing(&e))?;
    }
    Ok(())
}

/// `compare --sigma-t`'s plot: per estimator, `efficiency(split) / efficiency(shared)` at each
/// budget (dots) and their geometric mean (a bar), on a log scale around 1; the colour says
/// which walk `auto` takes. The legend is beside the plot.
pub fn colour_svg(
    rows: &[umbra::compare::colour::ColourRow],
    verdicts: &[umbra::compare::colour::ColourVerdict],
) -> Result<String> {
    use umbra::estimate::ColourWalk;
    let mut out = String::new();
    {
        let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing the plot: {e}");
        let root = SVGBackend::with_string(&mut out, (1040, 640)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let (plot, legend) = root.split_horizontally(840);
        // Per estimator, the ratio at each budget.
        let ratios: Vec<Vec<f64>> = verdicts
            .iter()
            .map(|v| {
                let mine = |walk| {
                    rows.iter()
                        .filter(move |r| r.estimator == v.estimator && r.walk == walk)
                };
                mine(ColourWalk::Shared)
                    .zip(mine(ColourWalk::Split))
                    .map(|(a, b)| b.efficiency / a.efficiency)
                    .filter(|x| x.is_finite() && *x > 0.0)
                    .collect()
            })
            .collect();
        let all = ratios
            .iter()
            .flatten()
            .chain(verdicts.iter().map(|v| &v.split_over_shared));
        let (lo, hi) = all.fold((1.0f64, 1.0f64), |(lo, hi), &x| (lo.min(x), hi.max(x)));
        let n = verdicts.len().max(1);
        let names: Vec<String> = verdicts.iter().map(|v| v.estimator.clone()).collect();
        // One row per estimator, the first on top.
        let row = |i: usize| (n - 1 - i) as f64;
        let mut chart = ChartBuilder::on(&plot)
            .caption(
                "Split walks against the shared walk, per estimator",
                ("sans-serif", 22),
            )
            .margin(20)
            .x_label_area_size(45)
            .y_label_area_size(170)
            .build_cartesian_2d((lo / 1.5..hi * 1.5).log_scale(), -0.5..n as f64 - 0.5)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .y_labels(n)
            .y_label_formatter(&|y| {
                let k = y.round();
                if (y - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < n {
                    names[n - 1 - k as usize].clone()
                } else {
                    String::new()
                }
            })
            .y_label_style(("sans-serif", 14))
            .disable_y_mesh()
            .x_desc("efficiency split / shared (right of 1: split wins)")
            .draw()
            .map_err(|e| err(&e))?;
        chart
            .draw_series(DashedLineSeries::new(
                vec![(1.0, -0.5), (1.0, n as f64 - 0.5)],
                6,
                4,
                BLACK.stroke_width(1),
            ))
            .map_err(|e| err(&e))?;
        let colour = |w: ColourWalk| match w {
            ColourWalk::Split => RGBColor(200, 60, 30),
            _ => RGBColor(30, 90, 200),
        };
        for (i, (v, r)) in verdicts.iter().zip(&ratios).enumerate() {
            let y = row(i);
            let c = colour(v.auto);
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(1.0, y - 0.3), (v.split_over_shared, y + 0.3)],
                    c.mix(0.35).filled(),
                )))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(r.iter().map(|&x| Circle::new((x, y), 4, c.filled())))
                .map_err(|e| err(&e))?;
        }
        let style = ("sans-serif", 15).into_font();
        for (k, (text, c)) in [
            ("auto takes split here", Some(colour(ColourWalk::Split))),
            ("auto takes shared here", Some(colour(ColourWalk::Shared))),
            ("bar: geometric mean", None),
            ("dots: each budget", None),
        ]
        .iter()
        .enumerate()
        {
            let y = 80 + 26 * k as i32;
            if let Some(c) = c {
                legend
                    .draw(&Rectangle::new(
                        [(10, y - 6), (34, y + 6)],
                        c.mix(0.6).filled(),
                    ))
                    .map_err(|e| err(&e))?;
            }
            legend
                .draw(&Text::new(*text, (42, y - 8), style.clone()))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::Labels;

    /// Two estimators' points at the same spot (collision and track-length on crossing rays):
    /// the second label goes beside the first, not over it; a spot ringed by labels drops one.
    #[test]
    fn labels_of_coinciding_points_do_not_overprint() {
        let mut l = Labels::default();
        let a = l.place((300, 200), "64").unwrap();
        let b = l.place((300, 200), "64").unwrap();
        assert_ne!(a, b);
        let (w, h) = Labels::size("64");
        let apart = a.0 + w <= b.0 || b.0 + w <= a.0 || a.1 + h <= b.1 || b.1 + h <= a.1;
        assert!(apart, "{a:?} {b:?}");
        let placed = (0..20).filter_map(|_| l.place((300, 200), "64")).count();
        assert_eq!(placed, 6, "eight spots around a point");
        assert!(l.place((300, 200), "64").is_none());
    }
}
