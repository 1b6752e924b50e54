//! `umbra batch`: many inputs x many lights from a TOML job file, resumable, shardable.

use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use umbra::batch::{in_shard, load_job, parse_shard, up_to_date, Job, Record, Task};

/// Arguments of `umbra batch`.
#[derive(Debug, clap::Args)]
pub struct BatchArgs {
    /// The TOML job file.
    job: PathBuf,
    /// Print one self-contained `umbra batch JOB --task I` command per task and exit.
    #[arg(long)]
    plan: bool,
    /// Run only task I (0-based, as `--plan` numbers them).
    #[arg(long, conflicts_with = "shard")]
    task: Option<usize>,
    /// Run only shard I of N (1-based): the tasks whose index % N == I-1.
    #[arg(long, value_parser = parse_shard)]
    shard: Option<(usize, usize)>,
    /// Re-bake outputs that are up to date.
    #[arg(long)]
    force: bool,
    /// JSON-lines log (default: the job's `log`, else umbra_batch.jsonl beside the outputs).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Tasks baked at once (0: as many as cores, at most the number of tasks); the cores are
    /// split among them.
    #[arg(long, short, default_value_t = 0)]
    jobs: usize,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+=:,@".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// Run the job (or print its plan).
pub fn run(a: &BatchArgs) -> Result<ExitCode> {
    let job = load_job(&a.job)?;
    if a.plan {
        let exe = std::env::current_exe()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|_| "umbra".into());
        let mut out = std::io::stdout().lock();
        for t in &job.tasks {
            writeln!(
                out,
                "{} batch {} --task {}",
                shell_quote(&exe),
                shell_quote(&job.path.display().to_string()),
                t.index
            )?;
        }
        return Ok(ExitCode::SUCCESS);
    }
    let selected: Vec<&Task> = match (a.task, a.shard) {
        (Some(i), _) => match job.tasks.get(i) {
            Some(t) => vec![t],
            None => bail!(
                "--task {i}: the job has {} tasks (0..{})",
                job.tasks.len(),
                job.tasks.len()
            ),
        },
        (None, Some(s)) => job.tasks.iter().filter(|t| in_shard(t.index, s)).collect(),
        (None, None) => job.tasks.iter().collect(),
    };
    let log_path = a.log.clone().unwrap_or_else(|| job.log.clone());
    // An explicit --log goes into an existing directory (a typo must not create /nonexistent);
    // the job's own log sits beside its outputs, whose directories the job creates.
    if let Some(d) = a
        .log
        .as_ref()
        .and_then(|l| l.parent())
        .filter(|d| !d.as_os_str().is_empty() && !d.is_dir())
    {
        bail!(
            "invalid argument '--log': no directory {} (create it first)",
            d.display()
        );
    }
    if let Some(d) = log_path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    for t in &selected {
        if let Some(d) = t.output.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
        }
    }
    let log = Mutex::new(
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .with_context(|| format!("opening the log {}", log_path.display()))?,
    );
    let (todo, skipped): (Vec<&Task>, Vec<&Task>) =
        selected.iter().partition(|t| a.force || !up_to_date(t));
    if !todo.is_empty() {
        // Missing frames and grids fail the job up front; then one camera per light over every
        // input (not just this shard's), so shards agree.
        job.check_inputs()?;
        let stem = log_path.file_stem().map_or_else(
            || "umbra_batch".into(),
            |s| s.to_string_lossy().into_owned(),
        );
        job.share_cameras_cached(&log_path.with_file_name(format!("{stem}.cameras.json")))?;
    }
    for t in &skipped {
        write_record(&log, &record(&job, t, "skipped", 0.0, 0.0, None))?;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let workers = if a.jobs == 0 { cores } else { a.jobs }
        .min(todo.len())
        .max(1);
    let per_task = (cores / workers).max(1);
    // With a fixed resolution the bar counts pixels (it moves during long bakes), else tasks.
    let pixels = job.pixels_hint();
    let total_units = pixels.map_or(todo.len() as u64, |p| p * todo.len() as u64);
    let bar = crate::common::progress_bar(
        a.quiet,
        "{spinner} batch [{bar:40}] {percent}% {msg} eta {eta}",
        total_units,
    );
    bar.set_message(format!("0/{} tasks, 0 failed,", todo.len()));
    let done = AtomicUsize::new(0);
    let start = std::time::Instant::now();
    let next = AtomicUsize::new(0);
    let failed = AtomicUsize::new(0);
    let errors: Mutex<Vec<String>> = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(t) = todo.get(k) else { break };
                let t0 = std::time::Instant::now();
                let tick = |n: u64| {
                    if pixels.is_some() {
                        bar.inc(n);
                    }
                };
                // Maps report rays per second, transmittance volumes voxels per second.
                let result = if job.volume.is_some() {
                    job.run_volume_task(t, per_task, &tick).map(|d| {
                        let rate = d.stats.voxels as f64 / d.stats.seconds.max(1e-9);
                        (rate, d.warnings)
                    })
                } else {
                    job.run_task(t, per_task, &tick).map(|d| {
                        let rate = d.map.stats.rays as f64 / d.map.stats.seconds.max(1e-9);
                        (rate, d.warnings)
                    })
                };
                let secs = t0.elapsed().as_secs_f64();
                let rec = match result {
                    Ok((rate, warnings)) => {
                        let mut r = record(&job, t, "ok", secs, rate, None);
                        r.warnings = warnings.iter().map(ToString::to_string).collect();
                        for w in &r.warnings {
                            bar.suspend(|| {
                                eprintln!(
                                    "umbra: warning: task {} ({}): {w}",
                                    t.index,
                                    t.input.display()
                                );
                            });
                        }
                        r
                    }
                    Err(e) => {
                        failed.fetch_add(1, Ordering::Relaxed);
                        bar.suspend(|| {
                            eprintln!(
                                "umbra: task {} ({}) failed: {}",
                                t.index,
                                t.input.display(),
                                umbra::text::escape(&e.to_string())
                            );
                        });
                        record(&job, t, "failed", secs, 0.0, Some(e.to_string()))
                    }
                };
                if let Err(e) = write_record(&log, &rec) {
                    if let Ok(mut v) = errors.lock() {
                        v.push(format!("{e:#}"));
                    }
                }
                if pixels.is_none() {
                    bar.inc(1);
                }
                bar.set_message(format!(
                    "{}/{} tasks, {} failed,",
                    done.fetch_add(1, Ordering::Relaxed) + 1,
                    todo.len(),
                    failed.load(Ordering::Relaxed)
                ));
            });
        }
    });
    bar.finish_and_clear();
    if let Some(e) = errors.into_inner().ok().and_then(|v| v.into_iter().next()) {
        bail!("writing the log: {e}");
    }
    let failed = failed.into_inner();
    println!(
        "umbra batch: {} tasks: {} baked, {} skipped (up to date), {failed} failed in {:.2} s on {workers} workers x {per_task} threads; log {}",
        selected.len(),
        todo.len() - failed,
        skipped.len(),
        start.elapsed().as_secs_f64(),
        log_path.display()
    );
    Ok(if failed > 0 {
        ExitCode::from(3)
    } else {
        ExitCode::SUCCESS
    })
}

fn record(
    job: &Job,
    t: &Task,
    status: &'static str,
    seconds: f64,
    rays_per_second: f64,
    error: Option<String>,
) -> Record {
    Record {
        task: t.index,
        input: t.input.clone(),
        grid: job.grid.clone(),
        light: t.light.clone(),
        output: t.output.clone(),
        status,
        seconds,
        rays_per_second,
        error,
        warnings: Vec::new(),
    }
}

fn write_record(log: &Mutex<std::fs::File>, rec: &Record) -> Result<()> {
    let line = serde_json::to_string(rec)? + "\n";
    let mut f = log
        .lock()
        .map_err(|_| anyhow::anyhow!("log lock poisoned"))?;
    f.write_all(line.as_bytes())?;
    Ok(())
}
