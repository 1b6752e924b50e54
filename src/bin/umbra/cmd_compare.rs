//! `umbra compare`: error against run time for every estimator, and the stress suite.

use anyhow::{Context, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::compare::{self, stress, Meta, Settings};
use umbra::estimate::{Estimator, Options};
use umbra::Volume;

/// Arguments of `umbra compare`.
#[derive(Debug, clap::Args)]
pub struct CompareArgs {
    /// The .vdb or .nvdb file, or a USD stage with one volume (or --volume naming one) at --frame
    /// (optional with --stress alone).
    file: Option<PathBuf>,
    /// Output directory for report.{csv,json,md} and error_vs_time.svg (and stress.*); created
    /// if missing (its parent must exist).
    #[arg(short = 'o', long = "output", visible_alias = "out")]
    out: PathBuf,
    /// Number of random rays crossing the volume.
    #[arg(long, default_value_t = 256)]
    rays: usize,
    /// Estimators: `all` (every registered one) or a comma-separated list of names; exactly
    /// these are run.
    #[arg(long, default_value = "all")]
    estimators: String,
    /// Also run ratio tracking with one grid-wide majorant (the naive baseline), reported as
    /// `ratio-global-majorant`.
    #[arg(long)]
    global_baseline: bool,
    /// Seed of the rays and of the estimators' random streams.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Timed repetitions per point (median reported), after one warm-up; each repetition runs
    /// the ray set as many times as it takes to last at least 50 ms.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Parameters for the estimators that take them (the budget parameter of a ladder is
    /// varied over its ladder).
    #[command(flatten)]
    params: umbra::request::EstimatorParams,
    /// Also run the stress catalogue and write stress.{md,json}.
    #[arg(long)]
    stress: bool,
    /// Compare deep encodings instead of estimators: one exact map of FILE baked as deep
    /// samples (three error bounds) and in every fixed-size format and size, each against the
    /// exact profile of every texel: deep.{md,json}, deep_error_vs_bytes.svg and the maps in
    /// DIR/maps/.
    #[arg(long)]
    deep: bool,
    /// With --deep: the maps' light (default: light-dir 0,-1,0, a sun overhead).
    #[command(flatten)]
    light: umbra::request::LightOptions,
    /// With --deep: the maps' resolution, N pixels on the long side.
    #[arg(long, default_value_t = 128)]
    res: u32,
    /// Samples per ray in the stress suite.
    #[arg(long, default_value_t = 16)]
    stress_samples: u32,
    /// No progress messages.
    #[arg(long, short)]
    quiet: bool,
    /// How FILE is read: its grid (or a USD stage's one volume, at a time code), scale,
    /// placement, interpolation; with sigma-t, compare the colour walks instead: FILE's grid
    /// as a coloured medium, every non-exact estimator over its ladder with the shared walk
    /// and with split walks (per-channel majorants): colour.{md,json}, colour_walks.svg.
    #[command(flatten)]
    source: umbra::input::SourceOptions,
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    format!(
        "{cpu}, {cores} cores available, {} {}",
        std::env::consts::OS,
        std::env::consts::ARCH
    )
}

/// The estimators `--estimators` names (registry order for `all`), with the given parameters
/// applied to those that take them.
fn selected(a: &CompareArgs) -> Result<Vec<Estimator>> {
    let names: Vec<&str> = if a.estimators == "all" {
        umbra::estimate::names().collect()
    } else {
        a.estimators.split(',').map(str::trim).collect()
    };
    let given = a.params.given();
    let mut used = vec![false; given.len()];
    let mut out = Vec::new();
    for n in names {
        let mut e = Estimator::from_name(n).map_err(crate::common::flag_error)?;
        for (k, &(p, v)) in given.iter().enumerate() {
            if e.spec().param(p).is_some() {
                e = e.set(p, v).map_err(crate::common::flag_error)?;
                used[k] = true;
            }
        }
        out.push(e);
    }
    if let Some(k) = used.iter().position(|u| !u) {
        anyhow::bail!(
            "--{}: none of the selected estimators takes it (see umbra estimators)",
            given[k].0
        );
    }
    Ok(out)
}

/// Run the comparison (and the stress suite) and write the reports.
pub fn run(a: &CompareArgs) -> Result<ExitCode> {
    umbra::bake::check_threads(a.threads).map_err(crate::common::flag_error)?;
    // Every comparison traces the light as a point (issue 60: lights with extent).
    a.light
        .refuse_extent("compare")
        .map_err(crate::common::flag_error)?;
    let threads = if a.threads == 0 {
        std::thread::available_parallelism().map_or(1, std::num::NonZero::get)
    } else {
        a.threads
    };
    check_output(a)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .context("starting worker threads")?;
    let estimators = selected(a)?;
    let say = |m: &str| {
        if !a.quiet {
            eprintln!("umbra compare: {m}");
        }
    };
    if a.source.sigma_t.is_some() && (a.deep || a.global_baseline) {
        anyhow::bail!(
            "invalid argument '--sigma-t': compares the colour walks; run {} without it",
            if a.deep {
                "--deep"
            } else {
                "--global-baseline"
            }
        );
    }
    if a.deep {
        let Some(file) = &a.file else {
            anyhow::bail!("compare --deep needs a .vdb file");
        };
        run_deep(a, file, threads, &say)?;
        return Ok(ExitCode::SUCCESS);
    }
    if let Some(file) = &a.file {
        if let Some(code) = run_estimators(a, file, &estimators, threads, &pool, &say)? {
            return Ok(code);
        }
    } else if !a.stress {
        anyhow::bail!("give a .vdb file to compare estimators on, or --stress");
    }
    if a.stress {
        return run_stress(a, &pool, &say);
    }
    Ok(ExitCode::SUCCESS)
}

/// The output directory: its parent must exist and be writable before any work.
fn check_output(a: &CompareArgs) -> Result<()> {
    if !a.out.is_dir() {
        let parent = a
            .out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(std::path::Path::new("."));
        umbra::internals::output::check_writable(&parent.join(".umbra-compare"), true)
            .with_context(|| {
                format!(
                    "invalid argument '--output': cannot create {}",
                    a.out.display()
                )
            })?;
    } else {
        umbra::internals::output::check_writable(&a.out.join("report.csv"), true)?;
    }
    Ok(())
}

/// The estimators compared on `file`'s grid over random rays (or, with `--sigma-t`, the
/// colour walks, whose exit code is returned): report.{csv,json,md} and error_vs_time.svg.
fn run_estimators(
    a: &CompareArgs,
    file: &std::path::Path,
    estimators: &[Estimator],
    threads: usize,
    pool: &rayon::ThreadPool,
    say: &(dyn Fn(&str) + Sync),
) -> Result<Option<ExitCode>> {
    let source = read_source(a, file)?;
    if source.kind().is_scene_file() {
        anyhow::bail!(
            "{}: compare takes one grid of a .vdb file; scenes (.toml) are traced by query \
             and bake",
            file.display()
        );
    }
    let interp = a.source.interp;
    let (vol, source) = load(&source)?;
    let rays = compare::random_rays(&vol, a.rays, a.seed);
    if rays.is_empty() {
        anyhow::bail!("{source} is empty, nothing to compare");
    }
    let options = Options {
        interp,
        seed: a.seed,
        ..Options::default()
    };
    let settings = Settings {
        options,
        repeats: a.repeats,
        threads,
        global_baseline: a.global_baseline,
    };
    if let Some(sigma) = a.source.sigma_t {
        return run_colour(
            a, vol, &rays, estimators, &settings, sigma, source, pool, say,
        )
        .map(Some);
    }
    let rows = pool.install(|| compare::compare(&vol, &rays, estimators, &settings, |m| say(m)))?;
    let exact = pool.install(|| compare::reference(&vol, &rays, &options));
    let mean_t = exact.iter().sum::<f64>() / exact.len() as f64;
    let taus: Vec<f64> = exact.iter().map(|t| -t.ln() + 0.0).collect();
    let meta = Meta {
        source,
        rays: rays.len(),
        threads,
        repeats: a.repeats,
        medium: format!(
            "{interp:?} lookups, density scale {}, seed {}",
            a.source.density_scale, a.seed
        ),
        machine: machine(),
        reference: format!(
            "mean exact T {mean_t:.4}; tau from {:.3} to {:.3}",
            taus.iter().copied().fold(f64::INFINITY, f64::min),
            taus.iter().copied().fold(0.0, f64::max)
        ),
    };
    let svg = crate::plot::svg(&rows)?;
    compare::write_reports(&a.out, &rows, &meta, Some(&svg))?;
    say(&format!(
        "wrote {}/report.{{csv,json,md}} and error_vs_time.svg",
        a.out.display()
    ));
    Ok(None)
}

/// The stress catalogue run: stress.{md,json}; exit code 3 when a row violates the soundness
/// properties.
fn run_stress(a: &CompareArgs, pool: &rayon::ThreadPool, say: &dyn Fn(&str)) -> Result<ExitCode> {
    say("stress catalogue");
    let cases = stress::catalogue(16)?;
    let rows = pool.install(|| stress::run(&cases, a.stress_samples, 5_000_000));
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let md = stress::markdown(&cases, &rows, a.stress_samples);
    umbra::internals::output::write_atomic(&a.out.join("stress.md"), true, |w| {
        std::io::Write::write_all(w, md.as_bytes()).map_err(|e| e.to_string())
    })?;
    let json = serde_json::to_string_pretty(&rows)?;
    umbra::internals::output::write_atomic(&a.out.join("stress.json"), true, |w| {
        std::io::Write::write_all(w, json.as_bytes()).map_err(|e| e.to_string())
    })?;
    let bad = rows
        .iter()
        .filter(|r| {
            r.non_finite > 0 || (!r.signed && r.out_of_range > 0) || r.underflow_violations > 0
        })
        .count();
    say(&format!(
        "wrote {}/stress.{{md,json}}: {} rows, {bad} with violations",
        a.out.display(),
        rows.len()
    ));
    if bad > 0 {
        eprintln!(
            "umbra: error: {bad} of {} stress rows violate the soundness properties (see {}/stress.md)",
            rows.len(),
            a.out.display()
        );
        return Ok(ExitCode::from(3));
    }
    Ok(ExitCode::SUCCESS)
}

/// `compare --sigma-t`: the colour walks side by side (see `umbra::compare::colour`).
#[allow(clippy::too_many_arguments)]
fn run_colour(
    a: &CompareArgs,
    vol: Volume,
    rays: &[umbra::Ray],
    estimators: &[Estimator],
    settings: &Settings,
    sigma: [f64; 3],
    source: String,
    pool: &rayon::ThreadPool,
    say: &(dyn Fn(&str) + Sync),
) -> Result<ExitCode> {
    if a.stress {
        anyhow::bail!("invalid argument '--stress': run it without --sigma-t");
    }
    let fog = umbra::scene::Fog::new(vol, sigma).map_err(crate::common::flag_error)?;
    let scene = umbra::scene::Scene::new(vec![fog], Vec::new(), true)?;
    let exact = pool.install(|| compare::colour::reference(&scene, rays, settings));
    let rows = pool.install(|| {
        compare::colour::compare_colour(&scene, rays, &exact, estimators, settings, |m| say(m))
    })?;
    let mean = |c: usize| exact.iter().map(|t| t[c]).sum::<f64>() / exact.len().max(1) as f64;
    let meta = Meta {
        source,
        rays: rays.len(),
        threads: settings.threads,
        repeats: a.repeats,
        medium: format!(
            "{:?} lookups, density scale {}, seed {}",
            settings.options.interp, a.source.density_scale, a.seed
        ),
        machine: machine(),
        reference: format!(
            "mean exact T: R {:.4}, G {:.4}, B {:.4}",
            mean(0),
            mean(1),
            mean(2)
        ),
    };
    let verdicts = compare::colour::verdicts(&rows, sigma);
    let md = compare::colour::colour_markdown(&rows, &verdicts, &meta, sigma);
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "meta": meta, "sigma_t": sigma, "verdicts": verdicts, "rows": rows,
    }))?;
    let svg = crate::plot::colour_svg(&rows, &verdicts)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    write_together(
        &a.out,
        &[
            ("colour.md", &md),
            ("colour.json", &json),
            ("colour_walks.svg", &svg),
        ],
        say,
    )?;
    Ok(ExitCode::SUCCESS)
}

/// `compare --deep`: every deep encoding of one exact map (see `umbra::compare::deep`).
fn run_deep(
    a: &CompareArgs,
    file: &std::path::Path,
    threads: usize,
    say: &dyn Fn(&str),
) -> Result<()> {
    if !read_source(a, file)?.kind().is_grid_file() {
        anyhow::bail!(
            "{}: compare --deep takes one grid of a .vdb file",
            file.display()
        );
    }
    let maps = a.out.join("maps");
    std::fs::create_dir_all(&maps).with_context(|| format!("creating {}", maps.display()))?;
    let mut rows = Vec::new();
    for product in compare::deep::deep_products() {
        let (name, deep, deep_error, deep_format) = match product {
            umbra::bake::Product::Deep { max_error } => (
                format!("lokovic_veach_{max_error}"),
                true,
                Some(max_error),
                None,
            ),
            umbra::bake::Product::Fixed { format } => (
                format.to_string().replace(':', "_"),
                false,
                None,
                Some(format.to_string()),
            ),
            umbra::bake::Product::Map => continue,
        };
        let options = umbra::request::BakeOptions {
            source: a.source.clone(),
            light: deep_light(&a.light),
            res: Some(umbra::bake::Resolution::LongSide(a.res)),
            deep,
            deep_error,
            deep_format,
            threads,
            force: true,
            ..umbra::request::BakeOptions::default()
        };
        let request = umbra::request::BakeRequest {
            input: file.to_path_buf(),
            output: maps.join(format!("{name}.exr")),
            options,
        };
        let umbra::request::BakePlan::Map(job) =
            request.plan().map_err(crate::common::flag_error)?
        else {
            anyhow::bail!("compare --deep bakes maps");
        };
        say(&format!("deep encoding {name}"));
        rows.push(compare::deep::deep_row(&job)?);
    }
    let source = format!("{} grid '{}'", file.display(), a.source.grid);
    let md = compare::deep::deep_markdown(&rows, &source);
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "source": source, "machine": machine(), "threads": threads, "res": a.res,
        "light_dir": deep_light(&a.light).light_dir, "rows": rows,
    }))?;
    let svg = crate::plot::deep_svg(&rows)?;
    write_together(
        &a.out,
        &[
            ("deep.md", &md),
            ("deep.json", &json),
            ("deep_error_vs_bytes.svg", &svg),
        ],
        say,
    )
}

/// The light of `compare --deep`'s maps: the one given, else a sun overhead.
fn deep_light(l: &umbra::request::LightOptions) -> umbra::request::LightOptions {
    match (l.light_dir, l.light_pos) {
        (None, None) => umbra::request::LightOptions {
            light_dir: Some([0.0, -1.0, 0.0]),
            light_pos: None,
            ..l.clone()
        },
        _ => l.clone(),
    }
}

/// Write the text reports `files` (name, text) into `dir`, all of them or none (staged, then
/// committed together), and say so.
fn write_together(
    dir: &std::path::Path,
    files: &[(&str, &String)],
    say: &dyn Fn(&str),
) -> Result<()> {
    let mut staged = Vec::new();
    for (name, text) in files {
        staged.push(umbra::internals::output::stage(
            &dir.join(name),
            true,
            |w| std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string()),
        )?);
    }
    umbra::internals::output::commit_all(staged)?;
    let names: Vec<&str> = files.iter().map(|f| f.0).collect();
    say(&format!("wrote {} in {}", names.join(", "), dir.display()));
    Ok(())
}

/// What `compare` reads: FILE with the read options, checked (stage options only for a
/// stage; no level sets or motion: compare traces one still fog grid).
fn read_source(a: &CompareArgs, file: &std::path::Path) -> Result<umbra::input::Source> {
    let source = umbra::input::Source::new(file, a.source.clone());
    source.check().map_err(crate::common::flag_error)?;
    let o = source.options();
    let still = [("--levelset", o.levelset.is_some())]
        .into_iter()
        .chain(o.motion_keys().map(|(k, g)| (k, g)));
    for (k, given) in still {
        if given {
            anyhow::bail!(
                "invalid argument '--{}': compare traces one still fog grid",
                k.trim_start_matches('-')
            );
        }
    }
    Ok(source)
}

/// The volume `compare` traces, and how the report names it: a grid of a `.vdb`, or the one
/// volume of a USD stage (its grid, placement and grey scale; `--density-scale` on top).
fn load(source: &umbra::input::Source) -> Result<(Volume, String)> {
    let (file, o) = (source.path(), source.options());
    if !source.kind().is_stage() {
        let mut vol = Volume::load(file, &o.grid, o.density_scale)
            .with_context(|| format!("loading grid '{}'", o.grid))?;
        if let Some(x) = &source.xform().map_err(crate::common::flag_error)? {
            vol = vol.with_xform(x).map_err(crate::common::flag_error)?;
        }
        return Ok((vol, format!("{} grid '{}'", file.display(), o.grid)));
    }
    if o.light.is_some() {
        anyhow::bail!("invalid argument '--light': compare traces random rays, not toward a light");
    }
    if o.xform.is_some() || o.grid != "density" {
        anyhow::bail!(
            "invalid argument '{}': the stage places its volumes and names their grids \
             (--volume, --field)",
            if o.xform.is_some() {
                "--xform"
            } else {
                "--grid"
            }
        );
    }
    let shot = umbra::usd::read(file, &umbra::usd::Selection::of(source.options()))
        .map_err(crate::common::flag_error)?;
    let v = shot.single_volume().map_err(crate::common::flag_error)?;
    let scale = v.grey_scale().map_err(crate::common::flag_error)? * o.density_scale;
    let path = v.asset.open()?;
    let vol = Volume::load(path.path(), &v.grid, scale)
        .with_context(|| format!("loading grid '{}' of {}", v.grid, v.asset.display()))?
        .with_xform(&v.xform)?;
    let source = format!(
        "{} at time {}: {} ({} grid '{}')",
        file.display(),
        shot.time,
        v.prim,
        v.asset.display(),
        v.grid
    );
    Ok((vol, source))
}
