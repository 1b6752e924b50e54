//! `umbra query`: what does the cloud attenuate along a segment, toward a light, or along
//! thousands of segments from a CSV file?

use crate::common::{flag_error, parse_vec3};
use anyhow::{anyhow, bail, Context, Result};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use umbra::request::{LoadMode, QueryOutcome, QueryRequest, RayAnswers, RayRow};
use umbra::{Interp, Ray};

/// Arguments of `umbra query`.
#[derive(Debug, clap::Args)]
#[command(mut_arg("estimator", |a| a.long_help(crate::common::estimator_help())))]
pub struct QueryArgs {
    /// The .vdb or NanoVDB .nvdb file, a .toml scene file (several volumes, colour, solids) or a
    /// USD stage
    /// (.usd, .usda, .usdc, .usdz: its volumes and lights at --frame).
    file: PathBuf,
    /// Segment start, world space: X,Y,Z (with --to).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    from: Option<[f64; 3]>,
    /// Segment end, world space: X,Y,Z (with --from).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    to: Option<[f64; 3]>,
    /// Shading point, world space: X,Y,Z (with --light-dir or --light-pos).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    at: Option<[f64; 3]>,
    #[command(flatten)]
    light: umbra::request::LightOptions,
    /// CSV of segments, one per line: `ox,oy,oz,ex,ey,ez` (with that header in any column
    /// order, or without a header in that order), or `-` for stdin. Answers come in input order;
    /// a bad line is reported on its own output line and makes the exit code 3 once every other
    /// line is answered.
    #[arg(long)]
    rays: Option<PathBuf>,
    /// How FILE is read: grid or stage selection (--light: the stage light --at is toward),
    /// interpolation, scale, colour, level sets, placement (positions stay in world space),
    /// motion.
    #[command(flatten)]
    source: umbra::input::SourceOptions,
    /// One JSON object per query on stdout.
    #[arg(long)]
    json: bool,
    /// Ray id of the query (selects its random streams; `--rays` numbers its rows from it).
    /// Pixel (i, j) of a bake is ray id j*W+i.
    #[arg(long, default_value_t = 0)]
    ray_id: u64,
    /// Worker threads for --rays and for decoding (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// How much of a `.vdb` grid to decode: `lazy` reads its topology and decodes only the
    /// leaves the query's rays touch, `eager` the whole grid, `auto` (the default) is lazy for
    /// grids with 16 MiB of leaf data or more. The answers are the same, bit for bit.
    #[arg(long, value_enum, default_value_t = LoadMode::Auto)]
    load: LoadMode,
    #[command(flatten)]
    est: umbra::request::EstimatorOptions,
    #[command(flatten)]
    params: umbra::request::EstimatorParams,
    /// USD stage inputs: answer every point of this Points prim (`points`) or PointInstancer
    /// (`positions`), placed in the world at each frame, toward the stage light.
    #[arg(long, value_name = "PRIM")]
    positions: Option<String>,
    /// With --positions: the frames A-B (A, A+1, ... up to B), instead of --frame.
    #[arg(long, value_name = "A-B", value_parser = crate::query_points::parse_frames, allow_hyphen_values = true)]
    frames: Option<crate::query_points::Frames>,
    /// With --positions: also write a .usda layer that time-samples
    /// `primvars:umbra:transmittance:<light>` on the prim (sublayer it over the shot).
    #[arg(long, value_name = "LAYER.usda")]
    usd_out: Option<PathBuf>,
    /// With --usd-out: replace an existing layer.
    #[arg(long)]
    force: bool,
}

/// Run the query through the library's one entry point ([`QueryRequest::run`]) and print the
/// answer(s). The flags are checked before a file of rays is read, and that file before the
/// (possibly slow) load, so a missing file fails fast.
pub fn run(a: &QueryArgs) -> Result<ExitCode> {
    let mut request = request(a);
    request.check().map_err(flag_error)?;
    if let Some(p) = &a.rays {
        request.rays = Some(read_rays(p)?);
    }
    let json = a.json;
    let mut on_frame = |f: &umbra::internals::points::PointFrame| {
        if !json {
            crate::query_points::print_frame(f);
        }
    };
    let outcome = request.run(&mut on_frame).map_err(|e| {
        warn_input(&a.file, &e.load_warnings);
        let e = e.worded(flag_error);
        match e.context {
            Some(c) => anyhow::Error::from(e.error).context(c),
            None => anyhow::Error::from(e.error),
        }
    })?;
    match outcome {
        QueryOutcome::Rays(r) => {
            warn_input(&a.file, &r.load_warnings);
            print_answers(&r, json)
        }
        QueryOutcome::Points(p) => crate::query_points::report(&p, json),
    }
}

/// The library's request for the flags: a file of rays is read later ([`read_rays`]).
fn request(a: &QueryArgs) -> QueryRequest {
    QueryRequest {
        source: umbra::input::Source::new(&a.file, a.source.clone()),
        from: a.from,
        to: a.to,
        at: a.at,
        light: a.light.clone(),
        rays: a.rays.as_ref().map(|_| Vec::new()),
        positions: a.positions.clone(),
        frames: a.frames.as_ref().map(|f| f.0.clone()),
        usd_out: a.usd_out.clone(),
        force: a.force,
        estimator: a.est.clone(),
        params: a.params.clone(),
        ray_id: a.ray_id,
        threads: a.threads,
        load: a.load,
    }
}

/// What reading the input changed, one line each.
fn warn_input(file: &Path, warnings: &[umbra::bake::Warning]) {
    for w in warnings {
        eprintln!("umbra: warning: {}: {w}", file.display());
    }
}

/// Read a CSV of segments: `(line number, ray or why the line is bad)` per data line.
fn read_rays(path: &Path) -> Result<Vec<RayRow>> {
    let text = if path.as_os_str() == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("reading rays from stdin")?;
        s
    } else {
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?
    };
    let name = if path.as_os_str() == "-" {
        "stdin".to_string()
    } else {
        path.display().to_string()
    };
    // A UTF-8 byte-order mark (spreadsheets write one) is not part of the header.
    let lines = text
        .trim_start_matches('\u{feff}')
        .lines()
        .enumerate()
        .map(|(n, l)| (n + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let want = ["ox", "oy", "oz", "ex", "ey", "ez"];
    let mut lines = lines.peekable();
    let Some(&(hline, first)) = lines.peek() else {
        bail!("{name}: no segments (expected lines ox,oy,oz,ex,ey,ez)");
    };
    let first_cols: Vec<&str> = first.split(',').map(str::trim).collect();
    // A first line of six numbers is data: the columns are then ox,oy,oz,ex,ey,ez in order.
    let headerless = first_cols.len() == 6 && first_cols.iter().all(|c| c.parse::<f64>().is_ok());
    let idx: Vec<usize> = if headerless {
        (0..6).collect()
    } else {
        let header = first;
        lines.next();
        want.iter()
            .map(|w| first_cols.iter().position(|c| c == w))
            .collect::<Option<_>>()
            .filter(|_| first_cols.len() == want.len())
            .ok_or_else(|| {
                anyhow!(
                    "{name}:{hline}: '{}' is neither the header ox,oy,oz,ex,ey,ez nor six numbers",
                    clip(header)
                )
            })?
    };
    Ok(lines
        .map(|(n, l)| {
            let parse = || -> Result<Ray, String> {
                let f: Vec<&str> = l.split(',').map(str::trim).collect();
                if f.len() != 6 {
                    return Err(format!("expected 6 fields, got {}", f.len()));
                }
                let v: Vec<f64> = idx
                    .iter()
                    .zip(want)
                    .map(|(&i, w)| match f[i].parse::<f64>() {
                        Ok(x) if x.is_finite() => Ok(x),
                        _ => Err(format!("{w} = '{}' is not a finite number", clip(f[i]))),
                    })
                    .collect::<Result<_, _>>()?;
                Ray::between([v[0], v[1], v[2]], [v[3], v[4], v[5]]).map_err(|e| e.to_string())
            };
            RayRow {
                line: n,
                ray: parse(),
            }
        })
        .collect())
}

/// Print the answers in input order (text, or one JSON object each), then the warnings; exit
/// 3 when a row failed. A single query that failed is the command's error.
fn print_answers(r: &RayAnswers, json: bool) -> Result<ExitCode> {
    if let [umbra::request::Answer {
        line: None,
        result: Err(e),
    }] = r.answers.as_slice()
    {
        bail!("{e}");
    }
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut failed: Vec<String> = Vec::new();
    // In JSON each line carries the run's warnings (as data, with the line stderr prints).
    let warnings_json: Vec<serde_json::Value> = r
        .warnings
        .iter()
        .map(|w| {
            let mut v = serde_json::to_value(w).unwrap_or_default();
            if let Some(o) = v.as_object_mut() {
                o.insert("message".into(), w.to_string().into());
            }
            v
        })
        .collect();
    for a in &r.answers {
        let at = a.line.map_or(String::new(), |n| format!("line {n}: "));
        match &a.result {
            Err(e) => {
                if json {
                    let v = serde_json::json!({ "line": a.line, "error": e });
                    writeln!(out, "{v}")?;
                } else {
                    writeln!(out, "{at}error: {e}")?;
                }
                failed.push(format!("{at}{e}"));
            }
            Ok(ok) if json => {
                let v = answer_json(ok, a.line, (&r.estimator, r.interp), &warnings_json);
                writeln!(out, "{v}")?;
            }
            Ok(ok) => writeln!(out, "{at}{}", answer_text(ok, &r.estimator, r.interp))?,
        }
    }
    out.flush()?;
    for w in &r.warnings {
        eprintln!("umbra: warning: {w}");
    }
    if let Some(first) = failed.first() {
        eprintln!(
            "umbra: error: {} of {} queries failed (first: {})",
            failed.len(),
            r.answers.len(),
            umbra::internals::text::escape(first)
        );
        return Ok(ExitCode::from(3));
    }
    Ok(ExitCode::SUCCESS)
}

/// One answer as JSON: grey values as numbers, RGB as `[r, g, b]` arrays.
fn answer_json(
    a: &umbra::request::Answered,
    line: Option<usize>,
    (est, interp): (&str, Interp),
    warnings: &[serde_json::Value],
) -> serde_json::Value {
    let (ray, e) = (&a.ray, &a.estimate);
    let nc = e.channels;
    let per = |v: [f64; 3], f: &dyn Fn(f64) -> serde_json::Value| {
        if nc == 3 {
            serde_json::Value::Array(v.iter().map(|x| f(*x)).collect())
        } else {
            f(v[0])
        }
    };
    let num = |x: f64| serde_json::json!(x);
    let tau = match e.tau {
        Some(t) => per(t, &|x| tau_json(Some(x))),
        None => serde_json::Value::Null,
    };
    let mut v = serde_json::json!({
        "T": per(e.value, &num), "std_err": per(e.std_err, &num), "tau": tau,
        "lookups": e.lookups,
        "estimator": est, "samples": e.samples, "interp": interp,
        "length": ray.t_max(), "segments": e.segments, "capped": e.capped,
        "seconds": a.seconds, "warnings": warnings,
    });
    if let Some(h) = e.hit {
        v["solid_hit"] = h.into();
    }
    if let Some(n) = line {
        v["line"] = n.into();
    }
    if let Some(n) = a.light_samples {
        v["light_samples"] = n.into();
        v["light_capped"] = a.light_capped.into();
    }
    v
}

/// One answer as a line of text (after its `line N: `).
fn answer_text(a: &umbra::request::Answered, est: &str, interp: Interp) -> String {
    let (ray, e) = (&a.ray, &a.estimate);
    let nc = e.channels;
    let list = |v: [f64; 3], f: &dyn Fn(f64) -> String| {
        v[..nc].iter().map(|x| f(*x)).collect::<Vec<_>>().join(", ")
    };
    let tau = e.tau.map_or(String::new(), |t| {
        format!(", tau = {}", list(t, &|x| full(x)))
    });
    let err = if e.std_err[..nc].iter().any(|s| s.is_nan()) {
        " +- unknown".to_string()
    } else if e.std_err.iter().any(|s| *s > 0.0) {
        format!(" +- {}", list(e.std_err, &|x| format!("{x:.2e}")))
    } else {
        String::new()
    };
    let hit = e
        .hit
        .map_or(String::new(), |h| format!(", solid hit at {}", full(h)));
    let light = a.light_samples.map_or(String::new(), |n| {
        let capped = if a.light_capped {
            " (capped: light-max-samples)"
        } else {
            ""
        };
        format!(", {n} light directions{capped}")
    });
    format!(
        "T = {}{err}{tau}{hit} ({est}, {interp:?}, {} samples, length {}, {} lookups{light})",
        list(e.value, &|x| full(x)),
        e.samples,
        full(ray.t_max()),
        e.lookups
    )
}

/// A value printed so that it can be read back: nine decimals in `[1e-4, 1e6)` (and for 0),
/// otherwise scientific notation with every significant digit (`6.3e-18`, not `0.000000000`).
fn full(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 || (1e-4..1e6).contains(&a) {
        format!("{v:.9}")
    } else {
        format!("{v:e}")
    }
}

/// `tau` in JSON: a number, `"inf"` through opaque voxels, `null` when the estimator does not
/// compute it (only regular tracking is exact).
fn tau_json(tau: Option<f64>) -> serde_json::Value {
    match tau {
        Some(t) if t.is_finite() => serde_json::json!(t),
        Some(t) if t > 0.0 => serde_json::json!("inf"),
        Some(_) => serde_json::json!("nan"),
        None => serde_json::Value::Null,
    }
}

/// A field from a file, cut to 40 characters for a message.
fn clip(s: &str) -> String {
    if s.chars().count() <= 40 {
        return s.to_string();
    }
    let head: String = s.chars().take(40).collect();
    format!("{head}... ({} bytes)", s.len())
}
