//! `umbra query STAGE --positions PRIM`: the transmittance toward a stage light at every point
//! of a `Points` prim or `PointInstancer`, frame by frame, printed (a summary per frame, or
//! `--json`) and, with `--usd-out`, written back into the shot as a time-sampled primvar.

use anyhow::{bail, Result};
use std::io::Write;
use std::path::Path;
use std::process::ExitCode;
use umbra::estimate::{Estimator, Options};

/// What `--positions` answers and where it goes.
pub struct Spec<'a> {
    pub file: &'a Path,
    pub prim: &'a str,
    pub light: Option<&'a str>,
    pub frames: &'a [f64],
    pub usd_out: Option<&'a Path>,
    pub force: bool,
    pub json: bool,
}

/// The frames of `--frames A-B`.
#[derive(Debug, Clone, PartialEq)]
pub struct Frames(pub Vec<f64>);

/// `--frames A-B`: A, A+1, ... while at most B (A and B finite, A <= B, at most 100,000 frames).
pub fn parse_frames(s: &str) -> std::result::Result<Frames, String> {
    let bad = || format!("'{s}' is not a frame range A-B (e.g. 1001-1100)");
    // The separator is a '-' after the first character (A may be negative).
    let cut = s
        .char_indices()
        .skip(1)
        .find(|&(i, c)| c == '-' && !s[..i].ends_with(['e', 'E']))
        .map(|(i, _)| i)
        .ok_or_else(bad)?;
    let a: f64 = s[..cut].trim().parse().map_err(|_| bad())?;
    let b: f64 = s[cut + 1..].trim().parse().map_err(|_| bad())?;
    if !a.is_finite() || !b.is_finite() || b < a {
        return Err(format!("'{s}': give finite frames A-B with A <= B"));
    }
    let n = (b - a).floor() as u64 + 1;
    if n > 100_000 {
        return Err(format!("'{s}' is {n} frames; at most 100,000"));
    }
    Ok(Frames((0..n).map(|i| a + i as f64).collect()))
}

/// Answer, print and write the layer.
pub fn run(
    s: &Spec<'_>,
    source: &umbra::input::Source,
    est: &Estimator,
    opts: &Options,
) -> Result<ExitCode> {
    if let Some(layer) = s.usd_out {
        if !umbra::input::is_usda_layer(layer) {
            bail!(
                "invalid argument '--usd-out': {} is not a .usda layer",
                layer.display()
            );
        }
        umbra::internals::output::check_target(layer, s.force)?;
    }
    let q = umbra::internals::points::PointQuery {
        stage: s.file,
        prim: s.prim,
        light: s.light,
        frames: s.frames,
    };
    let mut out = std::io::stdout().lock();
    let json = s.json;
    let mut print_frame = |f: &umbra::internals::points::PointFrame| {
        if json {
            return;
        }
        let t = &f.transmittance;
        let (lo, hi) = t
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
                (l.min(v), h.max(v))
            });
        let mean = t.iter().sum::<f64>() / t.len().max(1) as f64;
        let line = if t.is_empty() {
            format!("frame {}: no points", crate::common::num(f.frame))
        } else {
            format!(
                "frame {}: {} points, T min {:.6} mean {:.6} max {:.6}",
                crate::common::num(f.frame),
                t.len(),
                lo,
                mean,
                hi
            )
        };
        let _ = writeln!(out, "{line}");
        let _ = out.flush();
    };
    let answers =
        umbra::internals::points::point_transmittance(&q, source, est, opts, &mut print_frame)
            .map_err(crate::common::flag_error)?;
    for w in &answers.warnings {
        eprintln!("umbra: warning: {w}");
    }
    if json {
        let frames: Vec<serde_json::Value> = answers
            .frames
            .iter()
            .map(|f| {
                serde_json::json!({
                    "frame": f.frame,
                    "T": f.transmittance,
                    "std_err": f.std_err,
                    "positions": f.positions,
                })
            })
            .collect();
        let doc = serde_json::json!({
            "prim": answers.prim,
            "type": answers.type_name,
            "light": answers.light,
            "estimator": est.name(),
            "frames": frames,
        });
        writeln!(std::io::stdout().lock(), "{doc}")?;
    }
    if let Some(layer) = s.usd_out {
        let text = umbra::internals::points::layer_text(&answers)?;
        umbra::internals::output::write_atomic(layer, s.force, |w| {
            w.write_all(text.as_bytes()).map_err(|e| e.to_string())
        })?;
        if !json {
            println!(
                "wrote {}: primvars:umbra:transmittance:{} on {}, {} frames",
                layer.display(),
                answers.light_name,
                answers.prim,
                answers.frames.len()
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
