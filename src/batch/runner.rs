//! Running a job: select its tasks (all, one, or a shard), validate before anything is created,
//! skip what is up to date, bake the rest on worker threads, and log every task as a JSON line.
//! The command line (`umbra batch`) and the Python module (`umbra.run_job`) are thin over
//! [`run`]; progress reaches them through [`Progress`], the library's
//! [`crate::progress::Progress`] with the tasks' records: each task's bake is a
//! [`crate::progress::Share`] of the run's units, so the run moves as every bake does.
//!
//! **Order of work.** The task selection, the inputs (every file and grid) and the shared
//! cameras are checked first: a refused job creates no directory and no log. Then the log's and
//! the outputs' directories are made, skipped tasks are logged, and `workers` threads take the
//! remaining tasks in index order, each with `cores / workers` threads of its own. A failed task
//! is logged with its error and the others go on.

use super::{
    in_shard, valid_shard, BatchError, Freshness, Job, KeyCheck, PositionsTask, Record, Stale, Task,
};
use crate::progress::{Share, Work};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Which tasks to run and how (the options of `umbra batch`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RunOptions {
    /// Only tasks `first..=last` (0-based, as `--plan` numbers them; one task: `(i, i)`).
    pub task: Option<(usize, usize)>,
    /// Only shard `(I, N)`, 1-based: the tasks whose index `% N == I - 1`.
    pub shard: Option<(usize, usize)>,
    /// Re-bake outputs that are up to date.
    pub force: bool,
    /// The JSON-lines log (default: the job's `log`). Its directory must exist.
    pub log: Option<PathBuf>,
    /// Tasks baked at once (0: as many as cores, at most the number of tasks).
    pub jobs: usize,
    /// How outputs' keys are checked: take outputs without a key as up to date
    /// ([`KeyCheck::keep_unkeyed`]), hash every input ([`KeyCheck::verify`]).
    pub check: KeyCheck,
}

/// What a run reports as it goes: the library's [`crate::progress::Progress`] (the run's
/// [`Work`] is told once, before any task runs: every task's share, `TASK_UNITS` (1000) or the
/// pixels of its map when every map has a known size, and one unit per positions task), with
/// the number of tasks and each task's record. Called from worker threads.
pub trait Progress: crate::progress::Progress {
    /// The run is about to start `tasks` tasks (before [`crate::progress::Progress::start`]).
    fn tasks(&self, _tasks: usize) {}
    /// A task finished (`ok`, `failed`; `skipped` ones are reported before the run starts).
    fn task(&self, _record: &Record) {}
}

/// The units of a task's share of a run when its map's size is not known before it is framed.
pub const TASK_UNITS: u64 = 1000;

pub use crate::progress::Silent;

impl Progress for Silent {}

/// A farm engine's progress lines for a whole run.
impl<W: std::io::Write + Send> Progress for crate::progress::Lines<W> {}

/// What a run did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunReport {
    /// Tasks selected (all, one, or a shard's).
    pub selected: usize,
    /// Tasks baked successfully.
    pub baked: usize,
    /// Tasks skipped as up to date.
    pub skipped: usize,
    /// Tasks skipped because their stage light casts no shadows ([`Job::shadowless`]).
    pub shadowless: usize,
    /// Tasks that failed.
    pub failed: usize,
    /// Wall time of the run, seconds.
    pub seconds: f64,
    /// Worker threads, and threads per task.
    pub workers: usize,
    /// Threads each task bakes with.
    pub threads_per_task: usize,
    /// The log written.
    pub log: PathBuf,
    /// The job's USD layer (`bake.usd_out`), rewritten after the run.
    pub usd_out: Option<UsdOut>,
    /// Each `[[positions]]` entry's layer, rebuilt after the run from the per-frame files on
    /// disk.
    pub points_out: Vec<PointsOut>,
    /// Every selected task's record, in task order.
    pub records: Vec<Record>,
}

/// The layer a run wrote for `bake.usd_out`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct UsdOut {
    /// The `.usda` layer.
    pub layer: PathBuf,
    /// Maps it puts on their lights (every stage-light task's map on disk).
    pub maps: usize,
}

/// Run `job` as `opts` asks (module docs).
///
/// # Errors
/// [`BatchError::Options`] for a task index or shard out of range or a `log` whose directory
/// does not exist; input and framing errors of [`Job::check_inputs`] and [`Job::share_cameras_cached`]
/// (nothing created then); an I/O error creating directories or writing the log. A failed task
/// is not an error: it is counted in [`RunReport::failed`] and logged.
pub fn run(job: &Job, opts: &RunOptions, progress: &dyn Progress) -> Result<RunReport, BatchError> {
    if let Some((i, n)) = opts.shard.filter(|s| !valid_shard(*s)) {
        return Err(invalid(
            "shard",
            format!("{i}/{n}: give I/N with 1 <= I <= N"),
        ));
    }
    let (selected, points) = select(job, opts)?;
    let log_path = log_path(job, opts)?;
    // Tasks toward a light without shadows bake nothing, forced or not.
    let shadowless: Vec<(&Task, String)> = selected
        .iter()
        .filter_map(|t| job.shadowless(t).map(|why| (*t, why)))
        .collect();
    let bakes: Vec<&Task> = selected
        .iter()
        .copied()
        .filter(|t| !shadowless.iter().any(|(s, _)| s.index == t.index))
        .collect();
    if !bakes.is_empty() {
        // A task's key holds its camera: the inputs are checked and the shared cameras framed
        // before anything is decided (or created).
        frame(job, &log_path)?;
    }
    let fresh = |f: Freshness| match opts.force {
        true => Freshness {
            stale: Some(Stale::Forced),
            ..f
        },
        false => f,
    };
    let (todo, skipped): (Vec<_>, Vec<_>) = bakes
        .iter()
        .map(|t| (*t, fresh(job.freshness(t, opts.check))))
        .partition(|(_, f)| f.stale.is_some());
    let (points_todo, points_skipped): (Vec<_>, Vec<_>) = points
        .iter()
        .map(|t| (*t, fresh(job.positions_freshness(t, opts.check))))
        .partition(|(_, f)| f.stale.is_some());
    prepare(job, (&todo, &points_todo), &log_path)?;
    let log = Mutex::new(
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .map_err(|e| io(&log_path, e))?,
    );
    let records: Mutex<Vec<Record>> = Mutex::new(Vec::new());
    let log_error: Mutex<Option<std::io::Error>> = Mutex::new(None);
    let keep = |rec: Record| {
        let line = serde_json::to_string(&rec).unwrap_or_default() + "\n";
        if let Ok(mut f) = log.lock() {
            if let Err(e) = f.write_all(line.as_bytes()) {
                if let Ok(mut slot) = log_error.lock() {
                    slot.get_or_insert(e);
                }
            }
        }
        if let Ok(mut v) = records.lock() {
            v.push(rec);
        }
    };
    for (t, f) in &skipped {
        keep(Record {
            reason: Some(f.reason()),
            ..record(t, "skipped", 0.0, 0.0, None)
        });
    }
    for (t, why) in &shadowless {
        keep(Record {
            reason: Some(why.clone()),
            ..record(t, "skipped", 0.0, 0.0, None)
        });
    }
    for (t, f) in &points_skipped {
        keep(Record {
            reason: Some(f.reason()),
            ..points_record(t, "skipped", 0.0, 0.0, None)
        });
    }
    // Held frames bake once: a unit's first task bakes, the others copy its map.
    let units = super::hold::units(job, &todo);
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    let workers = if opts.jobs == 0 { cores } else { opts.jobs }
        .min(units.len())
        .max(1);
    let per_task = (cores / workers).max(1);
    // Each bake is a share of the run: its map's pixels when every map has a known size, else
    // TASK_UNITS; the bake's own units (pixels, a deep map's passes) are scaled into it.
    let worth = job.pixels_hint().unwrap_or(TASK_UNITS);
    progress.tasks(todo.len() + points_todo.len());
    progress.start(&Work {
        units: worth * todo.len() as u64 + points_todo.len() as u64,
        what: "batch",
        unit: None,
    });
    let start = std::time::Instant::now();
    let next = AtomicUsize::new(0);
    let failed = AtomicUsize::new(0);
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                let u = next.fetch_add(1, Ordering::Relaxed);
                let Some(unit) = units.get(u) else { break };
                // The unit's bake (its frame and report), when others hold its frame.
                let mut lead: Option<(i64, crate::bake::BakeReport)> = None;
                for &k in unit {
                    let (t, f) = &todo[k];
                    let share = Share::new(progress, worth);
                    let copied = lead
                        .as_ref()
                        .and_then(|(frame, r)| copy_held(job, (t, f), (*frame, r)));
                    let rec = match copied {
                        Some(rec) => rec,
                        None => {
                            let keep_report = lead.is_none() && unit.len() > 1;
                            let (rec, report) =
                                run_task(job, t, f.key.as_ref(), per_task, &share, keep_report);
                            if let (Some(r), Some(frame)) = (report, t.frame) {
                                lead = Some((frame, r));
                            }
                            rec
                        }
                    };
                    let rec = Record {
                        reason: Some(f.reason()),
                        ..rec
                    };
                    if rec.status == "failed" {
                        failed.fetch_add(1, Ordering::Relaxed);
                    }
                    share.finish();
                    progress.task(&rec);
                    keep(rec);
                }
            });
        }
    });
    failed.fetch_add(
        run_points(job, &points_todo, &keep, progress),
        Ordering::Relaxed,
    );
    if let Some(e) = log_error.into_inner().ok().flatten() {
        return Err(io(&log_path, e));
    }
    let failed = failed.into_inner();
    let mut records = records.into_inner().unwrap_or_default();
    records.sort_by_key(|r| r.task);
    let (usd_out, points_out) = outputs(job)?;
    Ok(RunReport {
        selected: selected.len() + points.len(),
        baked: todo.len() + points_todo.len() - failed,
        skipped: skipped.len() + points_skipped.len(),
        shadowless: shadowless.len(),
        failed,
        seconds: start.elapsed().as_secs_f64(),
        workers,
        threads_per_task: per_task,
        log: log_path,
        usd_out,
        points_out,
        records,
    })
}

/// The run's log: `opts.log` (in a directory that exists: a typo must not create
/// `/nonexistent`), else the job's own, beside its outputs.
fn log_path(job: &Job, opts: &RunOptions) -> Result<PathBuf, BatchError> {
    if let Some(d) = opts
        .log
        .as_ref()
        .and_then(|l| l.parent())
        .filter(|d| !d.as_os_str().is_empty() && !d.is_dir())
    {
        return Err(invalid(
            "log",
            format!("no directory {} (create it first)", d.display()),
        ));
    }
    Ok(opts.log.clone().unwrap_or_else(|| job.log.clone()))
}

/// A task to bake, and why (its [`Freshness`], with its key).
type ToBake<'a, T> = (&'a T, Freshness);

/// Check every input and frame the shared cameras (one camera per light over every input, not
/// just this shard's, so shards agree), cached beside the log: missing frames and grids fail
/// the job up front, before anything is created.
fn frame(job: &Job, log_path: &Path) -> Result<(), BatchError> {
    job.check_inputs()?;
    let stem = log_path.file_stem().map_or_else(
        || "umbra_batch".into(),
        |s| s.to_string_lossy().into_owned(),
    );
    job.share_cameras_cached(&log_path.with_file_name(format!("{stem}.cameras.json")))?;
    Ok(())
}

/// Before anything is created: the positions entries checked (when there are positions tasks
/// to run); then the log's and the outputs' directories made.
fn prepare(
    job: &Job,
    (todo, points_todo): (&[ToBake<'_, Task>], &[ToBake<'_, PositionsTask>]),
    log_path: &Path,
) -> Result<(), BatchError> {
    if !points_todo.is_empty() {
        job.check_positions()?;
    }
    let dirs = std::iter::once(log_path)
        .chain(todo.iter().map(|(t, _)| t.output.as_path()))
        .filter_map(|p| p.parent().filter(|d| !d.as_os_str().is_empty()));
    for d in dirs {
        std::fs::create_dir_all(d).map_err(|e| io(d, e))?;
    }
    Ok(())
}

/// An I/O error on `path` as a batch error.
fn io(path: &Path, e: std::io::Error) -> BatchError {
    BatchError::Task(crate::error::Error::Io {
        path: path.to_path_buf(),
        err: e,
    })
}

/// Bake task `t` on `per_task` threads, its progress a share of the run's: its record, `ok`
/// (with its rate: rays per second for a map, voxels per second for a transmittance volume,
/// and its warnings) or `failed` (with the error); with `keep_report`, a map's report too (the
/// bake that held frames copy, [`super::hold`]).
fn run_task(
    job: &Job,
    t: &Task,
    key: Option<&super::TaskKey>,
    per_task: usize,
    share: &Share<'_, dyn Progress + '_>,
    keep_report: bool,
) -> (Record, Option<crate::bake::BakeReport>) {
    let t0 = std::time::Instant::now();
    // Maps report rays per second, transmittance volumes voxels per second.
    let result = if job.volume {
        job.run_volume_task(t, per_task, key, share).map(|d| {
            let rate = d.stats.voxels as f64 / d.stats.seconds.max(1e-9);
            (
                rate,
                d.warnings.iter().map(ToString::to_string).collect(),
                None,
            )
        })
    } else {
        job.run_task(t, per_task, key, share).map(|d| {
            let rate = d.map.stats.rays as f64 / d.map.stats.seconds.max(1e-9);
            let warnings = d.warnings.iter().map(ToString::to_string).collect();
            (rate, warnings, keep_report.then_some(d))
        })
    };
    let secs = t0.elapsed().as_secs_f64();
    match result {
        Ok((rate, warnings, report)) => (
            Record {
                warnings,
                ..record(t, "ok", secs, rate, None)
            },
            report,
        ),
        Err(e) => (record(t, "failed", secs, 0.0, Some(e.to_string())), None),
    }
}

/// What a run writes after its tasks: the job's USD layer, and each `[[positions]]` entry's.
fn outputs(job: &Job) -> Result<(Option<UsdOut>, Vec<PointsOut>), BatchError> {
    let usd_out = match &job.usd_out {
        Some(layer) => Some(UsdOut {
            maps: super::layer::write(job, layer)?,
            layer: layer.clone(),
        }),
        None => None,
    };
    let points_out = job
        .write_positions_layers()?
        .into_iter()
        .map(|(layer, frames)| PointsOut { layer, frames })
        .collect();
    Ok((usd_out, points_out))
}

/// A `[[positions]]` layer a run wrote.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PointsOut {
    /// The `.usda` layer.
    pub layer: PathBuf,
    /// Frames it holds (every per-frame file on disk).
    pub frames: usize,
}

/// The tasks `opts` selects (every task, a range, or a shard), bakes and positions.
fn select<'a>(
    job: &'a Job,
    opts: &RunOptions,
) -> Result<(Vec<&'a Task>, Vec<&'a PositionsTask>), BatchError> {
    let n = job.task_count();
    let keep_index: Box<dyn Fn(usize) -> bool> = match (opts.task, opts.shard) {
        (Some((first, last)), _) => {
            if first > last || last >= n {
                let which = if first == last {
                    format!("{first}")
                } else {
                    format!("{first}-{last}")
                };
                return Err(invalid(
                    "task",
                    format!(
                        "{which}: the job has {n} tasks (0..{})",
                        n.saturating_sub(1)
                    ),
                ));
            }
            Box::new(move |i| (first..=last).contains(&i))
        }
        (None, Some(s)) => Box::new(move |i| in_shard(i, s)),
        (None, None) => Box::new(|_| true),
    };
    Ok((
        job.tasks.iter().filter(|t| keep_index(t.index)).collect(),
        job.positions
            .iter()
            .filter(|t| keep_index(t.index))
            .collect(),
    ))
}

/// Run positions tasks one after another, each on every core (the estimator's own pool);
/// how many failed.
fn run_points(
    job: &Job,
    todo: &[(&PositionsTask, Freshness)],
    keep: &dyn Fn(Record),
    progress: &dyn Progress,
) -> usize {
    let mut failed = 0;
    for (t, f) in todo {
        let t0 = std::time::Instant::now();
        let result = job.run_positions_task(t, f.key.as_ref());
        let secs = t0.elapsed().as_secs_f64();
        let rec = match result {
            Ok(n) => points_record(t, "ok", secs, n as f64 / secs.max(1e-9), None),
            Err(e) => {
                failed += 1;
                points_record(t, "failed", secs, 0.0, Some(e.to_string()))
            }
        };
        let rec = Record {
            reason: Some(f.reason()),
            ..rec
        };
        progress.task(&rec);
        keep(rec);
        progress.advance(1);
    }
    failed
}

fn invalid(option: &str, reason: String) -> BatchError {
    BatchError::Options(crate::error::Error::InvalidArgument {
        name: option.into(),
        reason,
    })
}

fn record(
    t: &Task,
    status: &'static str,
    seconds: f64,
    rays_per_second: f64,
    error: Option<String>,
) -> Record {
    Record {
        task: t.index,
        input: t.input.clone(),
        grid: t.grid.clone(),
        light: t.light.clone(),
        output: t.output.clone(),
        status,
        seconds,
        rays_per_second,
        error,
        reason: None,
        holds: None,
        warnings: Vec::new(),
    }
}

/// The log record of a positions task: `input` is the stage, `grid` the field read, `output`
/// the per-frame file, `rays_per_second` points per second.
fn points_record(
    t: &PositionsTask,
    status: &'static str,
    seconds: f64,
    rays_per_second: f64,
    error: Option<String>,
) -> Record {
    Record {
        task: t.index,
        input: t.stage.clone(),
        grid: t
            .options
            .source
            .field
            .clone()
            .unwrap_or_else(|| "density".into()),
        light: t.light_name(),
        output: t.output.clone(),
        status,
        seconds,
        rays_per_second,
        error,
        warnings: Vec::new(),
        reason: None,
        holds: None,
    }
}

/// The record of `t` written as a copy of `from` (the bake of frame `frame`, whose warnings
/// its map shares), `None` when it must bake.
fn copy_held(
    job: &Job,
    (t, f): (&Task, &Freshness),
    (frame, from): (i64, &crate::bake::BakeReport),
) -> Option<Record> {
    let t0 = std::time::Instant::now();
    let done = job.copy_task(t, f.key.as_ref(), from);
    let secs = t0.elapsed().as_secs_f64();
    match done {
        Ok(false) => None,
        Ok(true) => Some(Record {
            holds: Some(frame),
            warnings: from.warnings.iter().map(ToString::to_string).collect(),
            ..record(t, "ok", secs, 0.0, None)
        }),
        Err(e) => Some(record(t, "failed", secs, 0.0, Some(e.to_string()))),
    }
}
