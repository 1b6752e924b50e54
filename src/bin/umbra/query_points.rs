//! `umbra query STAGE --positions PRIM`: the transmittance toward a stage light at every point
//! of a `Points` prim or `PointInstancer`, frame by frame, printed (a summary per frame, or
//! `--json`) and, with `--usd-out`, written back into the shot as a time-sampled primvar.

use anyhow::Result;
use std::io::Write;
use std::process::ExitCode;
use umbra::internals::points::PointFrame;
use umbra::request::PointsOutcome;

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

/// A frame's summary line, as it is answered (text output).
pub fn print_frame(f: &PointFrame) {
    let t = &f.transmittance;
    let (lo, hi) = t
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let mean = t.iter().sum::<f64>() / t.len().max(1) as f64;
    let mut line = if t.is_empty() {
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
    // Toward a light with extent: the largest error bar and the points sampled.
    if let Some(n) = f.sampled {
        let worst = f.std_err.iter().fold(0.0f64, |a, &e| a.max(e));
        line.push_str(&format!(
            ", std_err max {worst:.2e}, {n} of {} points sampled",
            t.len()
        ));
    }
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

/// Report the answers: the warnings, the JSON document (`--json`), the layer written.
pub fn report(p: &PointsOutcome, json: bool) -> Result<ExitCode> {
    let answers = &p.answers;
    for w in &answers.warnings {
        eprintln!("umbra: warning: {w}");
    }
    if json {
        let frames: Vec<serde_json::Value> = answers
            .frames
            .iter()
            .map(|f| {
                let mut v = serde_json::json!({
                    "frame": f.frame,
                    "T": f.transmittance,
                    "std_err": f.std_err,
                    "positions": f.positions,
                });
                if let Some(n) = f.sampled {
                    v["sampled"] = n.into();
                }
                v
            })
            .collect();
        let mut doc = serde_json::json!({
            "prim": answers.prim,
            "type": answers.type_name,
            "light": answers.light,
            "estimator": p.estimator,
            "frames": frames,
        });
        if let Some(n) = answers.light_samples {
            doc["light_samples"] = n.into();
        }
        writeln!(std::io::stdout().lock(), "{doc}")?;
    }
    if let (Some(layer), false) = (&p.usd_out, json) {
        println!(
            "wrote {}: primvars:umbra:transmittance:{} on {}, {} frames",
            layer.display(),
            answers.light_name,
            answers.prim,
            answers.frames.len()
        );
    }
    Ok(ExitCode::SUCCESS)
}
