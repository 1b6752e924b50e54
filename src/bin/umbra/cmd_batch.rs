//! `umbra batch`: many inputs x many lights from a TOML job file, resumable, shardable.

use crate::common::CliProgress;
use anyhow::Result;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};
use umbra::batch::{load_job, parse_shard, parse_tasks, BatchError, Progress, Record, RunOptions};

/// Arguments of `umbra batch`.
#[derive(Debug, clap::Args)]
pub struct BatchArgs {
    /// The TOML job file.
    #[arg(required_unless_present = "schema")]
    job: Option<PathBuf>,
    /// Print the JSON Schema (draft 2020-12) of job files and exit: pipeline tools validate
    /// job files against it, editors complete them.
    #[arg(long, exclusive = true)]
    schema: bool,
    /// Print one self-contained `umbra batch JOB --task I` command per task and exit.
    #[arg(long)]
    plan: bool,
    /// Run only task I, or tasks I to J (0-based, as `--plan` numbers them).
    #[arg(long, conflicts_with = "shard", value_parser = parse_tasks, value_name = "I[-J]")]
    task: Option<(usize, usize)>,
    /// Run only shard I of N (1-based): the tasks whose index % N == I-1.
    #[arg(long, value_parser = parse_shard)]
    shard: Option<(usize, usize)>,
    /// Re-bake outputs that are up to date.
    #[arg(long)]
    force: bool,
    /// Take outputs that carry no key (baked by an older umbra, or by hand) as up to date
    /// instead of stale.
    #[arg(long)]
    keep_unkeyed: bool,
    /// Hash every file a task reads, even when its size and modification time match the ones
    /// its output's key records (finds a re-simulated file of the same size and time; reads
    /// every input in full).
    #[arg(long)]
    verify: bool,
    /// JSON-lines log (default: the job's `log`, else umbra_batch.jsonl beside the outputs).
    /// With --status: more logs to read (repeatable; the job's own is always read).
    #[arg(long)]
    log: Vec<PathBuf>,
    /// Report where the job stands and exit: tasks done (output on disk carrying the task's
    /// key now), failed (with the error a log records), stale (baked with other settings or
    /// inputs, with the reason) and not yet run. Exit 0 when all are done, 3 otherwise.
    #[arg(long, conflicts_with_all = ["plan", "task", "shard", "force"])]
    status: bool,
    /// With --status: one JSON object with arrays done, failed, stale and missing.
    #[arg(long, requires = "status")]
    json: bool,
    /// Tasks baked at once (0: as many as cores, at most the number of tasks); the cores are
    /// split among them.
    #[arg(long, short, default_value_t = 0)]
    jobs: usize,
    /// No progress bar and no summary line (failures and warnings still go to stderr; the
    /// log records every task).
    #[arg(long, short)]
    quiet: bool,
    /// Print a farm spec that runs the job and exit: `openjd` (an Open Job Description
    /// template; JSON, which is also YAML), `opencue` (an OpenCue job spec, XML) or `slurm`
    /// (an sbatch array script).
    #[arg(long, value_enum, conflicts_with_all = ["plan", "status", "task", "shard"])]
    emit: Option<Engine>,
    /// With --emit: write the spec to this file (atomically; --force to replace it).
    #[arg(short = 'o', long = "output", requires = "emit")]
    output: Option<PathBuf>,
    /// With --emit: farm tasks of up to N job tasks each (shards; OpenCue's own chunks of N
    /// consecutive tasks).
    #[arg(long, requires = "emit", value_name = "N")]
    chunk: Option<usize>,
    /// With --emit opencue: the show (default: $SHOW, else `testing`, as pyoutline).
    #[arg(long, requires = "emit")]
    show: Option<String>,
    /// With --emit opencue: the shot (default: $SHOT, else `default`, as pyoutline).
    #[arg(long, requires = "emit")]
    shot: Option<String>,
    #[command(flatten)]
    progress: crate::common::ProgressArgs,
}

/// Farm engines `--emit` writes specs for.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Engine {
    /// Open Job Description (AWS Deadline Cloud): `openjd check` / `openjd run` it.
    Openjd,
    /// OpenCue: the job spec pyoutline would write (`cueadmin`/pycue `launchSpec` it).
    Opencue,
    /// A Slurm job-array script: `sbatch` it.
    Slurm,
}

use umbra::batch::emit::shell_quote;

/// `--emit`: the spec on stdout, or written atomically to `-o`.
fn emit(job: &umbra::batch::Job, a: &BatchArgs, engine: Engine) -> Result<ExitCode> {
    let exe = std::env::current_exe()?;
    if let Some(o) = &a.output {
        umbra::internals::output::check_target(o, a.force)?;
    }
    if a.chunk == Some(0) {
        anyhow::bail!("invalid argument '--chunk': give N >= 1 job tasks per farm task");
    }
    if !matches!(engine, Engine::Opencue) && (a.show.is_some() || a.shot.is_some()) {
        let flag = if a.show.is_some() { "--show" } else { "--shot" };
        anyhow::bail!("invalid argument '{flag}': applies to --emit opencue");
    }
    let chunks = umbra::batch::emit::Chunks::of(job, a.chunk);
    let dir = match &a.output {
        Some(o) => o.parent(),
        None => job.path.parent(),
    }
    .filter(|d| !d.as_os_str().is_empty())
    .unwrap_or(std::path::Path::new("."))
    .to_path_buf();
    let text = match engine {
        Engine::Openjd => umbra::batch::emit::openjd(job, &exe, &dir, chunks)
            .map_err(crate::common::flag_error)?,
        Engine::Opencue => {
            let env = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
            let show = a.show.clone().or_else(|| env("SHOW"));
            let shot = a.shot.clone().or_else(|| env("SHOT"));
            // pyoutline's `outline.util.get_user()`: $USER, else `getpass.getuser()` ($LOGNAME,
            // $LNAME, $USERNAME, then the password database's name of the uid).
            let Some(user) = ["USER", "LOGNAME", "LNAME", "USERNAME"]
                .into_iter()
                .find_map(env)
                .or_else(|| uid().and_then(passwd_name))
            else {
                anyhow::bail!("--emit opencue: set USER to the user the job runs as");
            };
            let id = umbra::batch::emit::CueIdentity::new(
                show.as_deref().unwrap_or("testing"),
                shot.as_deref().unwrap_or("default"),
                &user,
                uid(),
            )
            .map_err(|e| match e {
                umbra::Error::InvalidArgument { name, reason } if name == "user" => {
                    anyhow::anyhow!("the environment's USER: {reason}")
                }
                e => crate::common::flag_error(e).into(),
            })?;
            umbra::batch::emit::opencue(job, &exe, a.chunk.unwrap_or(1), &id)
                .map_err(crate::common::flag_error)?
        }
        Engine::Slurm => umbra::batch::emit::slurm(job, &exe, chunks),
    };
    match &a.output {
        Some(o) => umbra::internals::output::write_atomic(o, a.force, |w| {
            w.write_all(text.as_bytes()).map_err(|e| e.to_string())
        })?,
        None => std::io::stdout().lock().write_all(text.as_bytes())?,
    }
    Ok(ExitCode::SUCCESS)
}

/// The user id this process runs as (OpenCue's RQD runs a job's frames as it).
fn uid() -> Option<u32> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata("/proc/self").ok().map(|m| m.uid())
    }
    #[cfg(not(unix))]
    {
        None
    }
}

/// The login name of user `uid` in `/etc/passwd` (what `getpass.getuser()`, pyoutline's
/// fallback, finds when `USER` is unset, as on many farm containers).
fn passwd_name(uid: u32) -> Option<String> {
    let text = std::fs::read_to_string("/etc/passwd").ok()?;
    text.lines().find_map(|l| {
        let mut f = l.split(':');
        let name = f.next()?;
        (f.nth(1)?.parse() == Ok(uid)).then(|| name.to_string())
    })
}

/// Run the job (or print its plan): the library's runner ([`umbra::batch::run`]) with a
/// progress bar, warnings and failures on stderr, and a summary line.
pub fn run(a: &BatchArgs) -> Result<ExitCode> {
    let Some(path) = &a.job else {
        let schema = serde_json::to_string_pretty(&umbra::batch::job_schema())?;
        writeln!(std::io::stdout().lock(), "{schema}")?;
        return Ok(ExitCode::SUCCESS);
    };
    let job = load_job(path)?;
    if a.plan {
        // Every task checked as the run would check it: an unrunnable job fails here.
        let skipped = job.check_tasks()?;
        let exe = std::env::current_exe()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|_| "umbra".into());
        let mut out = std::io::stdout().lock();
        for i in 0..job.task_count() {
            // A bake task that bakes nothing (a light without shadows) is a shell comment.
            let skip = skipped.iter().find(|(k, _)| *k == i);
            if let (Some((_, why)), Some(t)) = (skip, job.tasks.get(i)) {
                writeln!(
                    out,
                    "# skipped task {} ({}, light {}): {}",
                    t.index,
                    t.input.display(),
                    t.light,
                    umbra::internals::text::escape(why)
                )?;
                continue;
            }
            writeln!(
                out,
                "{} batch {} --task {i}",
                shell_quote(&exe),
                shell_quote(&job.path.display().to_string()),
            )?;
        }
        return Ok(ExitCode::SUCCESS);
    }
    if a.status {
        return status(&job, a);
    }
    if let Some(engine) = a.emit {
        return emit(&job, a, engine);
    }
    if a.log.len() > 1 {
        anyhow::bail!(
            "invalid argument '--log': a run writes one log (several are read by --status)"
        );
    }
    let opts = RunOptions {
        task: a.task,
        shard: a.shard,
        force: a.force,
        log: a.log.first().cloned(),
        jobs: a.jobs,
        check: check(a),
    };
    let bar = Bar {
        shown: CliProgress::new(a.progress.progress, a.quiet, |_| {
            "{spinner} batch [{bar:40}] {percent}% {msg} eta {eta}".to_string()
        }),
        tasks: AtomicUsize::new(0),
        done: AtomicUsize::new(0),
        failed: AtomicUsize::new(0),
    };
    let report = umbra::batch::run(&job, &opts, &bar).map_err(|e| match e {
        BatchError::Options(e) => crate::common::flag_error(e).into(),
        other => anyhow::Error::from(other),
    })?;
    bar.shown.finish();
    if a.quiet {
        // The log holds every task's outcome; failures were printed on stderr.
        return Ok(if report.failed > 0 {
            ExitCode::from(3)
        } else {
            ExitCode::SUCCESS
        });
    }
    let shadowless = if report.shadowless > 0 {
        format!(", {} skipped (no shadows)", report.shadowless)
    } else {
        String::new()
    };
    println!(
        "umbra batch: {} tasks: {} baked, {} skipped (up to date){shadowless}, {} failed in {:.2} s on {} workers x {} threads; log {}",
        report.selected,
        report.baked,
        report.skipped,
        report.failed,
        report.seconds,
        report.workers,
        report.threads_per_task,
        report.log.display()
    );
    if let Some(u) = &report.usd_out {
        println!(
            "umbra batch: {} maps on their stage lights in {}",
            u.maps,
            u.layer.display()
        );
    }
    for p in &report.points_out {
        println!(
            "umbra batch: {} frames of per-point transmittance in {}",
            p.frames,
            p.layer.display()
        );
    }
    Ok(if report.failed > 0 {
        ExitCode::from(3)
    } else {
        ExitCode::SUCCESS
    })
}

/// The runner's progress as an indicatif bar (or a farm engine's lines: `--progress`), with
/// each task's warnings and failures printed above it.
struct Bar {
    shown: CliProgress,
    tasks: AtomicUsize,
    done: AtomicUsize,
    failed: AtomicUsize,
}

impl umbra::progress::Progress for Bar {
    fn start(&self, work: &umbra::progress::Work) {
        self.shown.start(work);
        if let Some(b) = self.shown.bar() {
            b.set_message(format!(
                "0/{} tasks, 0 failed,",
                self.tasks.load(Ordering::Relaxed)
            ));
        }
    }

    fn advance(&self, units: u64) {
        self.shown.advance(units);
    }
}

impl Progress for Bar {
    fn tasks(&self, tasks: usize) {
        self.tasks.store(tasks, Ordering::Relaxed);
    }

    fn task(&self, r: &Record) {
        let print = || {
            for w in &r.warnings {
                eprintln!(
                    "umbra: warning: task {} ({}): {w}",
                    r.task,
                    r.input.display()
                );
            }
            if let Some(e) = &r.error {
                eprintln!(
                    "umbra: task {} ({}) failed: {}",
                    r.task,
                    r.input.display(),
                    umbra::internals::text::escape(e)
                );
            }
        };
        if r.error.is_some() {
            self.failed.fetch_add(1, Ordering::Relaxed);
        }
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        let Some(b) = self.shown.bar() else {
            print();
            return;
        };
        b.suspend(print);
        b.set_message(format!(
            "{}/{} tasks, {} failed,",
            done,
            self.tasks.load(Ordering::Relaxed),
            self.failed.load(Ordering::Relaxed)
        ));
    }
}

/// How `--keep-unkeyed` and `--verify` ask keys to be checked.
fn check(a: &BatchArgs) -> umbra::batch::KeyCheck {
    umbra::batch::KeyCheck {
        keep_unkeyed: a.keep_unkeyed,
        verify: a.verify,
    }
}

/// `--status`: the library's report ([`umbra::batch::status`]) as text or JSON.
fn status(job: &umbra::batch::Job, a: &BatchArgs) -> Result<ExitCode> {
    let s = umbra::batch::status(job, &a.log, check(a));
    let mut out = std::io::stdout().lock();
    if a.json {
        serde_json::to_writer_pretty(&mut out, &s)?;
        writeln!(out)?;
    } else {
        let skipped = if s.skipped.is_empty() {
            String::new()
        } else {
            format!(", {} skipped (no shadows)", s.skipped.len())
        };
        writeln!(
            out,
            "umbra batch: {} tasks: {} done, {} failed, {} stale, {} not yet run{skipped}",
            job.task_count(),
            s.done.len(),
            s.failed.len(),
            s.stale.len(),
            s.missing.len()
        )?;
        for t in &s.stale {
            writeln!(
                out,
                "stale   task {} ({}, light {}): {}",
                t.task,
                t.input.display(),
                t.light,
                umbra::internals::text::escape(t.reason.as_deref().unwrap_or(""))
            )?;
        }
        for t in &s.skipped {
            writeln!(
                out,
                "skipped task {} ({}, light {}): {}",
                t.task,
                t.input.display(),
                t.light,
                umbra::internals::text::escape(t.error.as_deref().unwrap_or(""))
            )?;
        }
        for t in &s.failed {
            writeln!(
                out,
                "failed  task {} ({}, light {}): {}",
                t.task,
                t.input.display(),
                t.light,
                umbra::internals::text::escape(t.error.as_deref().unwrap_or(""))
            )?;
        }
        for t in &s.missing {
            writeln!(
                out,
                "missing task {} ({}, light {}) -> {}",
                t.task,
                t.input.display(),
                t.light,
                t.output.display()
            )?;
        }
    }
    Ok(if s.complete() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(3)
    })
}
