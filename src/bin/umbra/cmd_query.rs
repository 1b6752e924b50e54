//! `umbra query`: what does the cloud attenuate along a segment, toward a light, or along
//! thousands of segments from a CSV file?

use crate::common::{flag_error, load_scene, load_scene_for, parse_vec3, thread_pool};
use anyhow::{anyhow, bail, Context, Result};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use umbra::bake::Warning;
use umbra::estimate::{Estimator, Options};
use umbra::scene::{Scene, SceneEstimate};
use umbra::{Interp, Light, Ray};

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
    /// Direction the light travels, DX,DY,DZ: trace from --at against it until the ray leaves
    /// the volume box.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    light_dir: Option<[f64; 3]>,
    /// Point light position X,Y,Z: trace the segment from --at to it.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    light_pos: Option<[f64; 3]>,
    /// CSV of segments, one per line: `ox,oy,oz,ex,ey,ez` (with that header in any column
    /// order, or without a header in that order), or `-` for stdin. Answers come in input order;
    /// a bad line is reported on its own output line and makes the exit code 3 once every other
    /// line is answered.
    #[arg(long)]
    rays: Option<PathBuf>,
    /// How FILE is read: grid or stage selection (the stage light --at is toward),
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

/// `--load`: how much of a grid a query decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LoadMode {
    /// Lazy for large grids, whole for small ones.
    Auto,
    /// Only the leaves the rays touch.
    Lazy,
    /// The whole grid.
    Eager,
}

/// One answered (or failed) query.
struct Answer {
    line: Option<usize>,
    result: Result<(Ray, SceneEstimate, f64), String>,
}

/// Run the query and print the answer(s): check the flags, load what the rays cross, answer.
pub fn run(a: &QueryArgs) -> Result<ExitCode> {
    if let Some(prim) = &a.positions {
        return run_points(a, prim);
    }
    let Asked {
        single,
        light,
        toward,
    } = asked(a)?;
    // Read the batch before the (possibly slow) load so a missing file fails fast.
    let batch = match &a.rays {
        Some(p) => Some(read_rays(p)?),
        None => None,
    };
    let interp = a.source.interp;
    let (est, opts) = a.est.resolve(&a.params, interp).map_err(flag_error)?;
    a.est.motion(&a.source).map_err(flag_error)?;
    let mut source = umbra::input::Source::new(&a.file, a.source.clone());
    source.options_mut().light = toward;
    let pool = thread_pool(a.threads)?;
    // The query's rays, made against the scene's boxes (a lazy load's shell): a single ray
    // that cannot be made keeps its error here and asks for nothing to be decoded.
    let mut ray_error = None;
    let make_rays = |scene: &Scene| -> Vec<Ray> {
        if let Some(rows) = &batch {
            return rows
                .iter()
                .filter_map(|(_, r)| r.as_ref().ok().copied())
                .collect();
        }
        let ray = match (single, a.at, light) {
            (Some((from, to)), _, _) => Ray::between(from, to),
            (None, Some(at), Some(l)) => l.ray_from_scene(scene, at),
            _ => return Vec::new(),
        };
        ray.map_err(|e| ray_error = Some(e)).into_iter().collect()
    };
    let (scene, rays) = pool.install(|| load(a, &source, &opts, make_rays))?;
    if let Some(e) = ray_error {
        return Err(e.into());
    }
    // The work budget, up front: per ray and for every ray of the batch together.
    let n_rays = batch.as_ref().map_or(1, Vec::len) as u64;
    for f in scene.fogs() {
        umbra::estimate::budget::check_job(
            f.volume(),
            &est,
            n_rays,
            u64::from(opts.samples),
            "samples",
        )
        .map_err(flag_error)?;
    }
    let answers: Vec<Answer> = if let Some(rows) = batch {
        pool.install(|| answer_rows(&scene, &rows, &rays, a.ray_id, (&est, &opts)))
    } else {
        let Some(ray) = rays.first() else {
            bail!("nothing to query");
        };
        let r = answer(&scene, ray, a.ray_id, &est, &opts)?;
        vec![Answer {
            line: None,
            result: Ok(r),
        }]
    };
    print_answers(&answers, est.name(), interp, a.json)
}

/// What a query asks, from its flags: a segment, or a light (and the stage light it is, whose
/// shadow link picks the volumes) for `--at`.
struct Asked {
    single: Option<([f64; 3], [f64; 3])>,
    light: Option<Light>,
    toward: Option<String>,
}

/// The flags checked against each other: exactly one of a segment, a point toward a light, or
/// a file of rays; `--frames`, `--usd-out` and `--force` only with `--positions`.
fn asked(a: &QueryArgs) -> Result<Asked> {
    for (flag, given) in [
        ("--frames", a.frames.is_some()),
        ("--usd-out", a.usd_out.is_some()),
        ("--force", a.force),
    ] {
        if given {
            bail!("invalid argument '{flag}': goes with --positions PRIM");
        }
    }
    let single = match (a.from, a.to, a.at) {
        (Some(from), Some(to), None) => Some((from, to)),
        (Some(_), None, _) | (None, Some(_), _) => {
            bail!("--from and --to go together (a segment from one point to the other)")
        }
        _ => None,
    };
    let source = umbra::input::Source::new(&a.file, a.source.clone());
    source.check().map_err(flag_error)?;
    // The stage light the query is toward (named, or the stage's only one): the scene holds
    // only the volumes its shadow link includes.
    let mut toward = a.source.light.clone();
    let light = match (a.light_dir, a.light_pos) {
        (Some(_), Some(_)) => bail!("give --light-dir or --light-pos, not both"),
        (Some(_), None) | (None, Some(_)) if a.source.light.is_some() => {
            bail!("give --light (a stage light) or --light-dir / --light-pos, not both")
        }
        (Some(dir), None) => Some(Light::Directional { dir }),
        (None, Some(pos)) => Some(Light::Point { pos }),
        (None, None) if a.at.is_some() && source.kind().is_stage() => {
            let (l, prim) = crate::common::light_of(&source)?;
            toward = Some(prim);
            Some(l)
        }
        (None, None) => None,
    };
    let modes =
        usize::from(single.is_some()) + usize::from(a.at.is_some()) + usize::from(a.rays.is_some());
    if modes != 1 || (a.from.is_some() && a.at.is_some()) {
        bail!(
            "give exactly one of --from/--to, --at with --light-dir or --light-pos, or --rays FILE"
        );
    }
    if a.at.is_some() != light.is_some() {
        bail!(
            "--at needs --light-dir DX,DY,DZ or --light-pos X,Y,Z (or a stage's light), and \
             those need --at"
        );
    }
    Ok(Asked {
        single,
        light,
        toward,
    })
}

/// The scene and the query's rays: the whole grid (`--load eager`, or a grid-wide majorant,
/// which is every leaf's bound), else only what the rays cross.
fn load(
    a: &QueryArgs,
    source: &umbra::input::Source,
    opts: &Options,
    mut make_rays: impl FnMut(&Scene) -> Vec<Ray>,
) -> Result<(Scene, Vec<Ray>)> {
    if a.load == LoadMode::Eager || opts.global_majorant {
        load_scene(source).map(|s| {
            let r = make_rays(&s);
            (s, r)
        })
    } else {
        let always = a.load == LoadMode::Lazy;
        load_scene_for(source, opts.granularity, always, make_rays)
    }
}

/// `--rays FILE`: row `n` has ray id `ray_id + n`; its rays go to the library together (exact
/// queries in batches on the SIMD kernel), a row's `seconds` is the batch's time per ray.
fn answer_rows(
    scene: &Scene,
    rows: &[(usize, std::result::Result<Ray, String>)],
    rays: &[Ray],
    ray_id: u64,
    (est, opts): (&Estimator, &Options),
) -> Vec<Answer> {
    let ids: Vec<u64> = rows
        .iter()
        .enumerate()
        .filter(|(_, (_, seg))| seg.is_ok())
        .map(|(n, _)| ray_id.wrapping_add(n as u64))
        .collect();
    let start = std::time::Instant::now();
    let results = umbra::scene::estimate_many(scene, rays, &ids, est, opts);
    let per_ray = start.elapsed().as_secs_f64() / rays.len().max(1) as f64;
    let mut results = rays.iter().copied().zip(results);
    rows.iter()
        .map(|(line, seg)| Answer {
            line: Some(*line),
            result: seg.clone().and_then(|_| match results.next() {
                Some((ray, Ok(e))) => Ok((ray, e, per_ray)),
                Some((_, Err(e))) => Err(format!("{:#}", anyhow::Error::from(e))),
                None => Err("no answer for this row".to_string()),
            }),
        })
        .collect()
}

/// `--positions PRIM`: every point of a stage's points prim, frame by frame.
fn run_points(a: &QueryArgs, prim: &str) -> Result<ExitCode> {
    let source = umbra::input::Source::new(&a.file, a.source.clone());
    if !source.kind().is_stage() {
        bail!("invalid argument '--positions': {}", source.not_a_stage());
    }
    let others = [
        ("--from", a.from.is_some()),
        ("--to", a.to.is_some()),
        ("--at", a.at.is_some()),
        ("--rays", a.rays.is_some()),
        ("--light-dir", a.light_dir.is_some()),
        ("--light-pos", a.light_pos.is_some()),
        ("--xform", a.source.xform.is_some()),
    ];
    if let Some((flag, _)) = others.iter().find(|(_, g)| *g) {
        bail!("invalid argument '{flag}': --positions answers every point toward a stage light");
    }
    source.check().map_err(flag_error)?;
    let frames = match (&a.frames, a.source.frame) {
        (Some(_), Some(_)) => bail!("give --frame F or --frames A-B, not both"),
        (Some(f), None) => f.0.clone(),
        (None, Some(f)) => vec![f],
        (None, None) => vec![umbra::usd::lights_at(&a.file, None)?.time],
    };
    let (est, opts) = a
        .est
        .resolve(&a.params, a.source.interp)
        .map_err(flag_error)?;
    a.est.motion(&a.source).map_err(flag_error)?;
    let spec = crate::query_points::Spec {
        file: &a.file,
        prim,
        light: a.source.light.as_deref(),
        frames: &frames,
        usd_out: a.usd_out.as_deref(),
        force: a.force,
        json: a.json,
    };
    let pool = thread_pool(a.threads)?;
    pool.install(|| crate::query_points::run(&spec, &source, &est, &opts))
}

fn answer(
    scene: &Scene,
    ray: &Ray,
    ray_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Result<(Ray, SceneEstimate, f64)> {
    // Through the batch entry point like `--rays` rows and Python's arrays, so one segment
    // gets the same number however it is asked.
    let start = std::time::Instant::now();
    let mut e = umbra::scene::estimate_many(scene, std::slice::from_ref(ray), &[ray_id], est, opts);
    let e = e.pop().context("no answer for the query")??;
    Ok((*ray, e, start.elapsed().as_secs_f64()))
}

/// Read a CSV of segments: `(line number, ray or why the line is bad)` per data line.
fn read_rays(path: &Path) -> Result<Vec<(usize, Result<Ray, String>)>> {
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
            (n, parse())
        })
        .collect())
}

fn print_answers(answers: &[Answer], est: &str, interp: Interp, json: bool) -> Result<ExitCode> {
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut failed: Vec<String> = Vec::new();
    let warnings = run_warnings(answers);
    // In JSON each line carries the run's warnings (as data, with the line stderr prints).
    let warnings_json: Vec<serde_json::Value> = warnings
        .iter()
        .map(|w| {
            let mut v = serde_json::to_value(w).unwrap_or_default();
            if let Some(o) = v.as_object_mut() {
                o.insert("message".into(), w.to_string().into());
            }
            v
        })
        .collect();
    for a in answers {
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
            Ok((ray, e, seconds)) => {
                let nc = e.channels;
                if json {
                    // Grey: numbers; RGB: [r, g, b] arrays.
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
                        "seconds": seconds, "warnings": warnings_json,
                    });
                    if let Some(h) = e.hit {
                        v["solid_hit"] = h.into();
                    }
                    if let Some(n) = a.line {
                        v["line"] = n.into();
                    }
                    writeln!(out, "{v}")?;
                } else {
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
                    writeln!(
                        out,
                        "{at}T = {}{err}{tau}{hit} ({est}, {interp:?}, {} samples, length {}, {} lookups)",
                        list(e.value, &|x| full(x)), e.samples, full(ray.t_max()), e.lookups
                    )?;
                }
            }
        }
    }
    out.flush()?;
    for w in &warnings {
        eprintln!("umbra: warning: {w}");
    }
    if let Some(first) = failed.first() {
        eprintln!(
            "umbra: error: {} of {} queries failed (first: {})",
            failed.len(),
            answers.len(),
            umbra::internals::text::escape(first)
        );
        return Ok(ExitCode::from(3));
    }
    Ok(ExitCode::SUCCESS)
}

/// What the answers want their user to know: capped samples, majorant violations, and every
/// query missing every active voxel (each answered, T = 1, no segment walked, no solid hit).
fn run_warnings(answers: &[Answer]) -> Vec<Warning> {
    let ok: Vec<&SceneEstimate> = answers
        .iter()
        .filter_map(|a| a.result.as_ref().ok().map(|(_, e, _)| e))
        .collect();
    let capped = ok.iter().map(|e| e.capped).sum::<u64>();
    let violations = ok.iter().map(|e| e.majorant_violations).sum::<u64>();
    let mut out = Vec::new();
    if capped > 0 {
        out.push(Warning::Capped { samples: capped });
    }
    if violations > 0 {
        out.push(Warning::MajorantViolations {
            lookups: violations,
        });
    }
    let missed = |e: &SceneEstimate| {
        e.segments == 0 && e.hit.is_none() && e.value[..e.channels].iter().all(|v| *v == 1.0)
    };
    if !ok.is_empty() && ok.iter().all(|e| missed(e)) {
        out.push(Warning::MissedEveryVoxel {
            queries: ok.len() as u64,
        });
    }
    out
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
