//! `umbra._umbra`: the native half of umbra's Python module, a thin layer over the umbra
//! library. The pure-Python package `umbra` (`python/umbra/__init__.py`) checks and converts
//! arguments (NumPy arrays to C-contiguous `float64`), and this module does the work with the
//! GIL released, on rayon's threads.
//!
//! Errors become `umbra.Error` (`umbra.FileError`, also an `OSError`, for what a file or the
//! file system did; `umbra.InvalidArgument`, also a `ValueError`, for what the caller asked),
//! with the messages the CLI prints after `umbra: error: `.

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use umbra::bake::{BakeJob, Camera, Channel, MapSummary};
use umbra::estimate::{Estimator, Options};
use umbra::request::{BakeOptions, BakeOutcome, BakePlan, BakeRequest, EstimatorOptions};
use umbra::scene::{Scene, SceneOptions};
use umbra::{Interp, Light, Ray};

// ---------------------------------------------------------------------------------------------
// Errors

/// Which Python exception a library error becomes.
#[derive(Clone, Copy)]
enum Class {
    /// `umbra.FileError` (an `OSError`): the file or the file system.
    File,
    /// `umbra.InvalidArgument` (a `ValueError`): the caller's arguments.
    Argument,
    /// `umbra.Error`: anything else (a NaN answer).
    Other,
}

fn class_of(e: &umbra::Error) -> Class {
    use umbra::Error as E;
    match e {
        E::Io { .. }
        | E::NotVdb { .. }
        | E::Invalid { .. }
        | E::Unsupported { .. }
        | E::Output { .. }
        | E::Exists { .. }
        | E::Scene { .. } => Class::File,
        E::InvalidArgument { .. } | E::GridNotFound { .. } => Class::Argument,
        _ => Class::Other,
    }
}

static ERRORS: PyOnceLock<Py<PyModule>> = PyOnceLock::new();

/// A Python exception of `class` with `message` (the classes live in `umbra._errors`, so that
/// `FileError` can be both an `umbra.Error` and an `OSError`).
fn raise(class: Class, message: String) -> PyErr {
    Python::attach(|py| {
        let module =
            ERRORS.get_or_try_init(py, || py.import("umbra._errors").map(pyo3::Bound::unbind));
        let name = match class {
            Class::File => "FileError",
            Class::Argument => "InvalidArgument",
            Class::Other => "Error",
        };
        match module.and_then(|m| m.bind(py).getattr(name)) {
            Ok(ty) => match ty.cast_into::<PyType>() {
                Ok(ty) => PyErr::from_type(ty, message),
                Err(_) => pyo3::exceptions::PyRuntimeError::new_err(message),
            },
            Err(e) => e,
        }
    })
}

/// A library error as a Python exception, worded for Python: an option named as its keyword
/// (the library's `deep-error` is `deep_error`), an existing output with how to replace it.
fn py_err(e: umbra::Error) -> PyErr {
    let e = py_worded(e);
    raise(class_of(&e), e.to_string())
}

/// A library error worded for Python: an option named as its keyword (the library's
/// `deep-error` is `deep_error`), an existing output with how to replace it.
fn py_worded(e: umbra::Error) -> umbra::Error {
    match e {
        umbra::Error::InvalidArgument { name, reason } => umbra::Error::InvalidArgument {
            name: name.trim_start_matches("--").replace('-', "_"),
            reason,
        },
        umbra::Error::Exists { path } => umbra::Error::Output {
            path,
            reason: "already exists (pass force=True to replace it)".into(),
        },
        other => other,
    }
}

/// A library error as the command line words it (an option as its flag, `--step`): the
/// messages a query batch records per row, which the CLI's `query --rays` prints the same.
fn cli_worded(e: umbra::Error) -> umbra::Error {
    match e {
        umbra::Error::InvalidArgument { name, reason } => umbra::Error::InvalidArgument {
            name: format!("--{}", name.trim_start_matches("--").replace('_', "-")),
            reason,
        },
        other => other,
    }
}

/// A load error as `umbra query`/`bake` print it: `loading grid 'NAME': ...` (`loading the
/// scene: ...`), argument errors as they are.
fn load_err(e: umbra::Error, file: &Path, grid: &str) -> PyErr {
    let class = class_of(&e);
    match e {
        umbra::Error::InvalidArgument { .. } => py_err(e),
        other if umbra::input::InputKind::of(file).is_scene_file() => {
            raise(class, format!("loading the scene: {other}"))
        }
        other => raise(class, format!("loading grid '{grid}': {other}")),
    }
}

fn arg(name: &str, reason: impl Into<String>) -> PyErr {
    raise(
        Class::Argument,
        format!("invalid argument '{name}': {}", reason.into()),
    )
}

// ---------------------------------------------------------------------------------------------
// Module functions

/// The `umbra info --json` report on `path` (every grid, or only `grid`), as JSON text.
#[pyfunction]
#[pyo3(signature = (path, grid=None))]
fn info_json(py: Python<'_>, path: PathBuf, grid: Option<String>) -> PyResult<String> {
    let info = py
        .detach(|| umbra::info::FileInfo::read(&path, grid.as_deref()))
        .map_err(py_err)?;
    serde_json::to_string(&info).map_err(|e| raise(Class::Other, e.to_string()))
}

/// Run a batch job (`umbra batch JOB [--task I | --shard I/N] [--force] [--log F] [--jobs N]`)
/// with the library's runner, the GIL released; `progress(done, total)` is called with units of
/// work (pixels, or tasks) as they finish, from the runner's threads. The run's report as JSON
/// text.
#[pyfunction]
#[pyo3(signature = (path, task, shard, force, log, jobs, progress))]
#[allow(clippy::too_many_arguments)]
fn run_job(
    py: Python<'_>,
    path: PathBuf,
    task: Option<usize>,
    shard: Option<(usize, usize)>,
    force: bool,
    log: Option<PathBuf>,
    jobs: usize,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let batch_err = |e: umbra::batch::BatchError| match e {
        umbra::batch::BatchError::Task(e) | umbra::batch::BatchError::Options(e) => py_err(e),
        other => raise(Class::File, other.to_string()),
    };
    let job = py
        .detach(|| umbra::batch::load_job(&path))
        .map_err(batch_err)?;
    let opts = umbra::batch::RunOptions {
        task: task.map(|i| (i, i)),
        shard,
        force,
        log,
        jobs,
    };
    let callback = PyProgress::new(progress);
    let report = py
        .detach(|| umbra::batch::run(&job, &opts, &callback))
        .map_err(batch_err)?;
    serde_json::to_string(&report).map_err(|e| raise(Class::Other, e.to_string()))
}

/// Where a job stands (`umbra batch JOB --status --json`), reading the job's log and `logs`.
#[pyfunction]
fn job_status(py: Python<'_>, path: PathBuf, logs: Vec<PathBuf>) -> PyResult<String> {
    let job = py
        .detach(|| umbra::batch::load_job(&path))
        .map_err(|e| raise(Class::File, e.to_string()))?;
    let s = py.detach(|| umbra::batch::status(&job, &logs));
    serde_json::to_string(&s).map_err(|e| raise(Class::Other, e.to_string()))
}

/// A farm spec for a job (`umbra batch JOB --emit ENGINE`): `engine` `openjd`, `opencue` or
/// `slurm`, running the umbra CLI at `exe`, its path defaults relative to `directory`
/// (openjd); `cue`: OpenCue's (show, shot, user, uid).
#[pyfunction]
#[pyo3(signature = (path, engine, exe, directory, chunk, cue))]
#[allow(clippy::too_many_arguments)]
fn emit_job(
    py: Python<'_>,
    path: PathBuf,
    engine: &str,
    exe: PathBuf,
    directory: PathBuf,
    chunk: Option<usize>,
    cue: (String, String, String, Option<u32>),
) -> PyResult<String> {
    let job = py
        .detach(|| umbra::batch::load_job(&path))
        .map_err(|e| raise(Class::File, e.to_string()))?;
    let chunks = umbra::batch::emit::Chunks::of(&job, chunk);
    match engine {
        "openjd" => umbra::batch::emit::openjd(&job, &exe, &directory, chunks).map_err(py_err),
        "opencue" => {
            let (show, shot, user, uid) = cue;
            let id =
                umbra::batch::emit::CueIdentity::new(&show, &shot, &user, uid).map_err(py_err)?;
            umbra::batch::emit::opencue(&job, &exe, chunk.unwrap_or(1), &id).map_err(py_err)
        }
        "slurm" => Ok(umbra::batch::emit::slurm(&job, &exe, chunks)),
        other => Err(raise(
            Class::Argument,
            format!(
                "invalid argument 'engine': {other:?}: give \"openjd\", \"opencue\" or \"slurm\""
            ),
        )),
    }
}

/// The library's progress (a bake's, or a batch run's) as calls of a Python callable
/// `progress(done, total)`.
///
/// Worker threads finish work in any order; the count is kept under a lock that is held
/// while the callable runs, so the calls see `done` rise monotonically (lock order: this lock,
/// then the GIL, on every thread).
struct PyProgress {
    callback: Option<Py<PyAny>>,
    total: std::sync::atomic::AtomicU64,
    done: std::sync::Mutex<u64>,
}

impl umbra::progress::Progress for PyProgress {
    fn start(&self, work: &umbra::progress::Work) {
        self.total
            .store(work.units, std::sync::atomic::Ordering::Relaxed);
        let done = self.done.lock().unwrap_or_else(|p| p.into_inner());
        self.call(*done);
    }
    fn advance(&self, units: u64) {
        let mut done = self.done.lock().unwrap_or_else(|p| p.into_inner());
        *done += units;
        self.call(*done);
    }
}

impl umbra::batch::Progress for PyProgress {}

impl PyProgress {
    /// Calls of `callback(done, total)`, if there is one.
    fn new(callback: Option<Py<PyAny>>) -> Self {
        Self {
            callback,
            total: std::sync::atomic::AtomicU64::new(0),
            done: std::sync::Mutex::new(0),
        }
    }

    fn call(&self, done: u64) {
        if let Some(cb) = &self.callback {
            let total = self.total.load(std::sync::atomic::Ordering::Relaxed);
            // A callback that raises is reported as Python reports unraisable errors; the
            // run goes on (its outputs and log are the job's, not the callback's).
            Python::attach(|py| {
                if let Err(e) = cb.call1(py, (done, total)) {
                    e.write_unraisable(py, None);
                }
            });
        }
    }
}

/// The estimator registry (`umbra estimators --json`), as JSON text.
#[pyfunction]
fn estimators_json() -> PyResult<String> {
    serde_json::to_string(umbra::estimate::REGISTRY).map_err(|e| raise(Class::Other, e.to_string()))
}

/// The estimator options with their defaults (`request::EstimatorOptions::default()`), as a
/// JSON object in field order: the one list the Python module's estimator keywords are
/// taken from (and `python/tests/test_keywords.py` holds them to).
#[pyfunction]
fn estimator_options_json() -> PyResult<String> {
    serde_json::to_string(&EstimatorOptions::default())
        .map_err(|e| raise(Class::Other, e.to_string()))
}

/// Write an image and its summary (a map's `camera` dict, as JSON text) as the OpenEXR file
/// `umbra bake` writes. `t`/`err` hold `C` channels of `W x H` pixels, channel-major.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (path, summary, t, err, channels, overwrite, tile, mipmap))]
fn write_exr(
    py: Python<'_>,
    path: PathBuf,
    summary: &str,
    t: PyReadonlyArray1<'_, f32>,
    err: Option<PyReadonlyArray1<'_, f32>>,
    channels: usize,
    overwrite: bool,
    tile: Option<u32>,
    mipmap: bool,
) -> PyResult<()> {
    let summary: MapSummary = serde_json::from_str(summary)
        .map_err(|e| arg("camera", format!("not the camera dict of a baked map: {e}")))?;
    // Channel-major planes, one `Vec` each.
    let split = |v: &[f32]| -> std::vec::IntoIter<Vec<f32>> {
        let n = (v.len() / channels.max(1)).max(1);
        v.chunks(n)
            .map(<[f32]>::to_vec)
            .collect::<Vec<_>>()
            .into_iter()
    };
    let mut t = split(t.as_slice()?);
    let mut e = match &err {
        Some(e) => Some(split(e.as_slice()?)),
        None => None,
    };
    let red = t.next().unwrap_or_default();
    let red_err = e.as_mut().and_then(Iterator::next);
    let color = (channels == 3).then(|| {
        let mut ch = || Channel {
            t: t.next().unwrap_or_default(),
            std_err: e.as_mut().and_then(Iterator::next),
            slices: Vec::new(),
        };
        let g = ch();
        let b = ch();
        Box::new([g, b])
    });
    // The summary's own names (`camera`, `image`), not flags.
    let (map, prov) = summary
        .to_map(red, red_err, color)
        .map_err(|e| raise(class_of(&e), e.to_string()))?;
    let layout = umbra::bake::ExrLayout { tile, mipmap };
    py.detach(|| umbra::bake::write_exr_as(&path, &map, &prov, &layout, overwrite))
        .map_err(py_err)
}

// ---------------------------------------------------------------------------------------------
// Volumes

/// A loaded volume (a grid of a `.vdb` file, or a scene) with what it was loaded with.
#[pyclass(frozen, module = "umbra._umbra", name = "Volume")]
struct NativeVolume {
    scene: Scene,
    path: PathBuf,
    grid: String,
    density_scale: f64,
    xform: Option<umbra::internals::xform::Xform>,
    interp: Interp,
    warnings: Vec<String>,
    /// Each fog volume's tree statistics, computed on first use (a pass over every leaf).
    stats: std::sync::OnceLock<Vec<umbra::internals::tree::TreeStats>>,
}

fn parse_interp(s: &str) -> PyResult<Interp> {
    match s {
        "trilinear" => Ok(Interp::Trilinear),
        "nearest" => Ok(Interp::Nearest),
        other => Err(arg(
            "interp",
            format!("'{other}': expected 'trilinear' or 'nearest'"),
        )),
    }
}

/// Run `f` on `threads` workers (0: rayon's global pool, every core).
fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> umbra::Result<T> {
    if threads == 0 {
        return Ok(f());
    }
    umbra::bake::check_threads(threads)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| umbra::Error::InvalidArgument {
            name: "threads".into(),
            reason: format!("cannot start worker threads: {e}"),
        })?;
    Ok(pool.install(f))
}

/// Calls with fewer rows run without watching for Ctrl-C (they are short).
const INTERRUPTIBLE_ROWS: usize = 4096;

/// Run `work` while the calling thread (the GIL released) watches Python's signal handlers:
/// on Ctrl-C (a `KeyboardInterrupt` from `check_signals`) `cancel` is set, the work winds down
/// (every row not yet started is skipped) and the interrupt is returned. The work runs on a
/// scoped thread, the caller waking every 50 ms; a panic in the work is resumed here.
fn interruptible<T: Send>(work: impl FnOnce() -> T + Send, cancel: &AtomicBool) -> PyResult<T> {
    std::thread::scope(|s| {
        let (tx, rx) = std::sync::mpsc::channel();
        let handle = s.spawn(move || {
            let r = work();
            let _ = tx.send(());
            r
        });
        let mut interrupt = None;
        loop {
            match rx.recv_timeout(std::time::Duration::from_millis(50)) {
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) if interrupt.is_none() => {
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        cancel.store(true, Ordering::Relaxed);
                        interrupt = Some(e);
                    }
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                _ => break,
            }
        }
        let result = match handle.join() {
            Ok(r) => r,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        match interrupt {
            Some(e) => Err(e),
            None => Ok(result),
        }
    })
}

/// `(N, 3)` rows as points.
fn points(a: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<[f64; 3]>> {
    let s = a.as_slice()?;
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// What a batch of rays gave, row by row: `C` values per row (1 grey, 3 RGB).
struct Traced {
    channels: usize,
    t: Vec<f64>,
    err: Vec<f64>,
    tau: Vec<f64>,
    capped: u64,
    violations: u64,
}

/// Rows handed to the library in one call by `trace_rays` for exact answers (their rays held
/// meanwhile: about 100 bytes a row): enough for full batches on the kernel.
const ROWS_PER_CALL: usize = 65_536;
/// Rows a call for a stochastic or nearest estimate (ray by ray in the library): few, so Ctrl-C
/// is seen between calls within a fraction of a second even at many samples.
const ROWS_PER_CALL_BY_RAY: usize = 1_024;

/// Counters and the first failure (lowest row) of a batch.
#[derive(Default)]
struct Tally {
    capped: u64,
    violations: u64,
    failed: u64,
    first: Option<(usize, String)>,
}

impl Tally {
    fn merge(mut self, o: Self) -> Self {
        self.capped += o.capped;
        self.violations += o.violations;
        self.failed += o.failed;
        self.first = match (self.first, o.first) {
            (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
            (a, b) => a.or(b),
        };
        self
    }
}

impl NativeVolume {
    fn load(
        py: Python<'_>,
        path: PathBuf,
        grid: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
        stage: umbra::usd::Selection,
    ) -> PyResult<Self> {
        let interp = parse_interp(interp)?;
        let xform = xform
            .map(|v| umbra::internals::xform::Xform::from_row_major(&v))
            .transpose()
            .map_err(py_err)?;
        let opts = SceneOptions {
            grid: grid.clone(),
            density_scale,
            sigma_t: None,
            xform,
            levelset_solid: false,
            stage,
        };
        let scene = py
            .detach(|| umbra::scene::load(&path, &opts))
            .map_err(|e| load_err(e, &path, &grid))?;
        let warnings = umbra::bake::volume_warnings(&scene.sanitized())
            .iter()
            .map(|w| format!("{}: {w}", path.display()))
            .collect();
        Ok(Self {
            scene,
            path,
            grid,
            density_scale,
            xform,
            interp,
            warnings,
            stats: std::sync::OnceLock::new(),
        })
    }

    /// The tree statistics of each fog volume, in scene order.
    fn stats(&self) -> &[umbra::internals::tree::TreeStats] {
        self.stats.get_or_init(|| {
            self.scene
                .fogs()
                .iter()
                .map(|f| f.volume().tree().stats())
                .collect()
        })
    }

    /// The one volume of a single-grid load, or an argument error for a scene of several.
    fn single(&self, what: &str) -> PyResult<&umbra::Volume> {
        self.scene.single().ok_or_else(|| {
            arg(
                what,
                format!(
                    "a scene of {} volumes has no single {what}",
                    self.scene.fogs().len() + self.scene.solids().len()
                ),
            )
        })
    }

    /// Trace `n` rays, row `row` along `ray_of(row)` with ray id `ray_id + row`; a ray that
    /// could not be made is its row's failure. Rows go in chunks of [`ROWS_PER_CALL`] (exact)
    /// or [`ROWS_PER_CALL_BY_RAY`]: each chunk's rays are made on the worker threads and handed
    /// to the library together (`scene::estimate_many`: exact queries in batches on the SIMD
    /// kernel), then dropped; Ctrl-C is seen between chunks.
    fn trace_rays(
        &self,
        n: usize,
        ray_of: &(dyn Fn(usize) -> Result<Ray, String> + Sync),
        est: &Estimator,
        opts: &Options,
        ray_id: u64,
        cancel: &AtomicBool,
    ) -> Result<Traced, String> {
        let c = self.scene.channels();
        let (mut t, mut err, mut tau) = (vec![0.0; n * c], vec![0.0; n * c], vec![0.0; n * c]);
        let mut tally = Tally::default();
        let per_call = if *est == Estimator::REGULAR && opts.interp == Interp::Trilinear {
            ROWS_PER_CALL
        } else {
            ROWS_PER_CALL_BY_RAY
        };
        for start in (0..n).step_by(per_call) {
            if cancel.load(Ordering::Relaxed) {
                break;
            }
            let end = (start + per_call).min(n);
            let made: Vec<Result<Ray, String>> = (start..end).into_par_iter().map(ray_of).collect();
            let (rays, ids): (Vec<Ray>, Vec<u64>) = made
                .iter()
                .enumerate()
                .filter_map(|(k, r)| {
                    let id = ray_id.wrapping_add((start + k) as u64);
                    r.as_ref().ok().map(|r| (*r, id))
                })
                .unzip();
            let mut answers =
                umbra::scene::estimate_many(&self.scene, &rays, &ids, est, opts).into_iter();
            for (k, made) in made.into_iter().enumerate() {
                let row = start + k;
                let at = row * c..(row + 1) * c;
                let r = made.and_then(|_| match answers.next() {
                    Some(a) => a.map_err(|e| e.to_string()),
                    None => Err("no answer for this row".to_string()),
                });
                let one = match r {
                    Ok(v) => {
                        t[at.clone()].copy_from_slice(&v.value[..c]);
                        err[at.clone()].copy_from_slice(&v.std_err[..c]);
                        match v.tau {
                            Some(x) => tau[at].copy_from_slice(&x[..c]),
                            None => tau[at].fill(f64::NAN),
                        }
                        Tally {
                            capped: v.capped,
                            violations: v.majorant_violations,
                            ..Tally::default()
                        }
                    }
                    Err(msg) => {
                        t[at.clone()].fill(f64::NAN);
                        err[at.clone()].fill(f64::NAN);
                        tau[at].fill(f64::NAN);
                        Tally {
                            failed: 1,
                            first: Some((row, msg)),
                            ..Tally::default()
                        }
                    }
                };
                tally = tally.merge(one);
            }
        }
        if let Some((row, msg)) = tally.first {
            return Err(format!(
                "{} of {n} rays failed (first: row {row}: {msg})",
                tally.failed
            ));
        }
        Ok(Traced {
            channels: c,
            t,
            err,
            tau,
            capped: tally.capped,
            violations: tally.violations,
        })
    }

    /// Estimate along `rows` rays (`ray_of(row)`) after the CLI's up-front checks (the
    /// estimator, its options and the job's work budget). `options`: the estimator options
    /// as JSON ([`EstimatorOptions::from_json`]).
    fn run<'py>(
        &self,
        py: Python<'py>,
        rows: usize,
        ray_of: impl Fn(usize) -> Result<Ray, String> + Send + Sync,
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let (est, opts) = EstimatorOptions::from_json(options)
            .and_then(|o| o.resolve(self.interp))
            .map_err(py_err)?;
        let cancel = AtomicBool::new(false);
        let work = || {
            on_threads(threads, || {
                for f in self.scene.fogs() {
                    umbra::estimate::budget::check_job(
                        f.volume(),
                        &est,
                        rows as u64,
                        u64::from(opts.samples),
                        "samples",
                    )?;
                }
                Ok(self.trace_rays(rows, &ray_of, &est, &opts, ray_id, &cancel))
            })
        };
        // Short calls run inline: watching for Ctrl-C costs a thread.
        let traced = if rows >= INTERRUPTIBLE_ROWS {
            py.detach(|| interruptible(work, &cancel))?
        } else {
            py.detach(work)
        };
        let traced = traced.and_then(|r| r).map_err(py_err)?;
        let traced = traced.map_err(|m| raise(Class::Other, m))?;
        let c = traced.channels;
        let n = traced.t.len() / c;
        let shape = |v: Vec<f64>| -> PyResult<Bound<'py, PyArray2<f64>>> {
            PyArray1::from_vec(py, v).reshape([n, c])
        };
        let mut warnings = Vec::new();
        if traced.capped > 0 {
            warnings.push(
                umbra::bake::Warning::Capped {
                    samples: traced.capped,
                }
                .to_string(),
            );
        }
        if traced.violations > 0 {
            warnings.push(
                umbra::bake::Warning::MajorantViolations {
                    lookups: traced.violations,
                }
                .to_string(),
            );
        }
        Ok((
            shape(traced.t)?,
            shape(traced.err)?,
            shape(traced.tau)?,
            warnings,
        ))
    }
}

/// `(T, std_err, tau, warnings)`, arrays of shape `(N, C)`.
type TraceOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Vec<String>,
);

/// A baked image: `(T, std_err or None, summary JSON, warnings)`, arrays of shape `(C, H, W)`
/// flattened channel-major.
type BakeOut<'py> = (
    Bound<'py, PyArray1<f32>>,
    Option<Bound<'py, PyArray1<f32>>>,
    String,
    Vec<String>,
);

/// A transmittance volume in memory: `(ijk, T, stats JSON, warnings)`, `ijk` of shape `(N, 3)`.
type VolumeOut<'py> = (
    Bound<'py, PyArray2<i32>>,
    Bound<'py, PyArray1<f32>>,
    String,
    Vec<String>,
);

/// A transmittance volume's stats as a JSON object: [`umbra::bake::VolumeStats`]'s fields
/// and `ns_per_voxel`.
fn stats_json(st: &umbra::bake::VolumeStats) -> PyResult<String> {
    let mut v = serde_json::to_value(st).map_err(|e| raise(Class::Other, e.to_string()))?;
    if let Some(o) = v.as_object_mut() {
        o.insert("ns_per_voxel".into(), serde_json::json!(st.ns_per_voxel()));
    }
    Ok(v.to_string())
}

impl NativeVolume {
    /// This volume's transmittance volume as the options (the Python keywords, JSON text) ask
    /// for it, written to `output` (or a name only, in memory): the request's plan, checked
    /// as the CLI checks it, and the loaded grid.
    fn volume_plan(
        &self,
        options: &str,
        output: PathBuf,
    ) -> PyResult<(&umbra::Volume, umbra::bake::VolumeJob)> {
        let request = self.request(options, output)?;
        let plan = request.plan().map_err(py_err)?;
        let BakePlan::Volume(job) = plan else {
            return Err(arg(
                "path",
                "a transmittance volume is written to a .vdb file",
            ));
        };
        let vol = self.single("transmittance volume")?;
        Ok((vol, *job))
    }

    /// A transmittance volume's warnings as the CLI prints them: `FILE: warning`.
    fn volume_warnings(&self, w: &[umbra::bake::Warning]) -> Vec<String> {
        w.iter()
            .map(|w| format!("{}: {w}", self.path.display()))
            .collect()
    }
}

#[pymethods]
impl NativeVolume {
    /// Load grid `grid` of the `.vdb` file `path` (whole).
    #[staticmethod]
    #[pyo3(signature = (path, grid, density_scale, interp, xform))]
    fn open(
        py: Python<'_>,
        path: PathBuf,
        grid: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        if umbra::input::InputKind::of(&path).is_scene_file() {
            return Err(arg(
                "path",
                format!(
                    "{} is a scene file: load it with umbra.Volume.from_scene",
                    path.display()
                ),
            ));
        }
        Self::load(
            py,
            path,
            grid,
            density_scale,
            interp,
            xform,
            Default::default(),
        )
    }

    /// Load the `.toml` scene file `path`.
    #[staticmethod]
    #[pyo3(signature = (path, density_scale, interp, xform))]
    fn open_scene(
        py: Python<'_>,
        path: PathBuf,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        if !umbra::input::InputKind::of(&path).is_scene_file() {
            return Err(arg(
                "path",
                format!(
                    "{} is not a scene file (.toml): load a grid with umbra.Volume",
                    path.display()
                ),
            ));
        }
        Self::load(
            py,
            path,
            "density".into(),
            density_scale,
            interp,
            xform,
            Default::default(),
        )
    }

    /// Load the volumes of the USD stage `path` at time code `time` (default: its start);
    /// toward `light`, only those its shadow link includes.
    #[staticmethod]
    #[pyo3(signature = (path, time, volumes, field, density_scale, interp, xform, light=None))]
    #[allow(clippy::too_many_arguments)]
    fn open_stage(
        py: Python<'_>,
        path: PathBuf,
        time: Option<f64>,
        volumes: Vec<String>,
        field: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
        light: Option<String>,
    ) -> PyResult<Self> {
        if !umbra::input::InputKind::of(&path).is_stage() {
            return Err(arg(
                "path",
                format!(
                    "{} is not a USD stage (.usd, .usda, .usdc, .usdz)",
                    path.display()
                ),
            ));
        }
        let sel = umbra::usd::Selection {
            time,
            volumes,
            field,
            light,
        };
        Self::load(
            py,
            path,
            "density".into(),
            density_scale,
            interp,
            xform,
            sel,
        )
    }

    /// What the bad-voxel policy changed, as warning lines.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    #[getter]
    fn grid(&self) -> String {
        self.scene.grid_names()
    }

    #[getter]
    fn density_scale(&self) -> f64 {
        self.density_scale
    }

    #[getter]
    fn interp(&self) -> &'static str {
        match self.interp {
            Interp::Nearest => "nearest",
            Interp::Trilinear => "trilinear",
        }
    }

    #[getter]
    fn channels(&self) -> usize {
        self.scene.channels()
    }

    /// World-from-index, 4x4 row-major (the translation in the last column).
    fn world_from_index(&self) -> PyResult<[[f64; 4]; 4]> {
        let r = self.single("world_from_index")?.world_from_index_rows();
        Ok([r[0], r[1], r[2], [0.0, 0.0, 0.0, 1.0]])
    }

    /// Inclusive index box of the active voxels (tiles count as the voxels they cover).
    fn index_bbox(&self) -> PyResult<Option<[[i32; 3]; 2]>> {
        self.single("index_bbox")?;
        Ok(self.stats().first().and_then(|s| s.index_bbox))
    }

    /// Active voxels (over every volume of a scene).
    fn active_voxels(&self) -> u64 {
        self.stats().iter().map(|s| s.active_voxels).sum()
    }

    /// World box of the active voxel centres (the index box's corners in world space; a
    /// scene: over its volumes).
    fn world_bbox(&self) -> Option<[[f64; 3]; 2]> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (f, s) in self.scene.fogs().iter().zip(self.stats()) {
            let Some(b) = s.index_bbox else {
                continue;
            };
            let b = b.map(|c| c.map(f64::from));
            for p in umbra::internals::math::box_corners(b) {
                let w = f.volume().to_world(p).to_array();
                for a in 0..3 {
                    lo[a] = lo[a].min(w[a]);
                    hi[a] = hi[a].max(w[a]);
                }
            }
        }
        (lo[0] <= hi[0]).then_some([lo, hi])
    }

    /// Transmittance along the segments `origins[n] -> ends[n]` (ray id `ray_id + n`).
    fn trace<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f64>,
        ends: PyReadonlyArray2<'py, f64>,
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let (o, e) = (points(&origins)?, points(&ends)?);
        if o.len() != e.len() {
            return Err(arg(
                "ends",
                format!("{} origins but {} ends", o.len(), e.len()),
            ));
        }
        drop((origins, ends));
        let n = o.len();
        let ray_of = |row: usize| Ray::between(o[row], e[row]).map_err(|e| e.to_string());
        self.run(py, n, ray_of, options, ray_id, threads)
    }

    /// Transmittance from each point toward a light (`query --at`), ray id `ray_id + n`.
    #[allow(clippy::too_many_arguments)]
    fn trace_to_light<'py>(
        &self,
        py: Python<'py>,
        points_: PyReadonlyArray2<'py, f64>,
        light_dir: Option<[f64; 3]>,
        light_pos: Option<[f64; 3]>,
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let light = match (light_dir, light_pos) {
            (Some(dir), None) => Light::Directional { dir },
            (None, Some(pos)) => Light::Point { pos },
            _ => {
                return Err(arg(
                    "light_dir",
                    "give light_dir=(dx, dy, dz) or light_pos=(x, y, z), one of them",
                ))
            }
        };
        // A direction that is no direction fails the call, not each row.
        if let Light::Directional { .. } = light {
            light
                .ray_from_scene(&self.scene, [0.0; 3])
                .map_err(py_err)?;
        }
        let p = points(&points_)?;
        drop(points_);
        let n = p.len();
        let scene = &self.scene;
        let ray_of = |row: usize| {
            light
                .ray_from_scene(scene, p[row])
                .map_err(|e| cli_worded(e).to_string())
        };
        self.run(py, n, ray_of, options, ray_id, threads)
    }

    /// T toward a light at every active voxel (`umbra bake ... -o OUT.vdb`, in memory):
    /// the voxels' index coordinates and values in output order (leaves by origin, voxels by
    /// offset).
    fn transmittance_volume<'py>(
        &self,
        py: Python<'py>,
        options: &str,
    ) -> PyResult<VolumeOut<'py>> {
        let (vol, job) = self.volume_plan(options, PathBuf::from("memory.vdb"))?;
        let (light, est, opts, threads) = (job.light, job.estimator, job.options, job.threads);
        let (ijk, t, stats) = py
            .detach(|| -> umbra::Result<_> {
                let (leaves, stats) =
                    umbra::bake::transmittance_leaves(vol, &light, &est, &opts, threads, &|_| {})?;
                let voxels = usize::try_from(stats.voxels).unwrap_or(0);
                let (mut ijk, mut t) = (Vec::with_capacity(voxels * 3), Vec::with_capacity(voxels));
                for l in &leaves {
                    for (n, &v) in l.values.iter().enumerate() {
                        if umbra::internals::tree::bit(&l.active, n) {
                            ijk.extend_from_slice(&[
                                l.origin[0] + (n >> 6) as i32,
                                l.origin[1] + ((n >> 3) & 7) as i32,
                                l.origin[2] + (n & 7) as i32,
                            ]);
                            t.push(v);
                        }
                    }
                }
                Ok((ijk, t, stats))
            })
            .map_err(py_err)?;
        let n = t.len();
        let warnings = self.volume_warnings(&umbra::bake::volume_warnings(&vol.sanitized()));
        Ok((
            PyArray1::from_vec(py, ijk).reshape([n, 3])?,
            PyArray1::from_vec(py, t),
            stats_json(&stats)?,
            warnings,
        ))
    }

    /// Write the transmittance volume `umbra bake FILE ... -o PATH` writes for this volume
    /// (its file, grid, density scale and `xform` recorded): `(stats JSON, warnings)`.
    fn write_transmittance_volume(
        &self,
        py: Python<'_>,
        path: PathBuf,
        options: &str,
    ) -> PyResult<(String, Vec<String>)> {
        let (vol, job) = self.volume_plan(options, path)?;
        let report = py.detach(|| job.run_on(vol, &|_| {})).map_err(py_err)?;
        Ok((
            stats_json(&report.stats)?,
            self.volume_warnings(&report.warnings),
        ))
    }

    /// Bake a transmittance map (`umbra bake`, in memory) as the options (the Python
    /// keywords, JSON text) ask.
    fn bake<'py>(&self, py: Python<'py>, options: &str) -> PyResult<BakeOut<'py>> {
        let request = self.request(options, PathBuf::new())?;
        let threads = request.options.threads;
        let report = py
            .detach(|| -> umbra::Result<_> {
                let (job, camera) = self.map_plan(&request)?;
                on_threads(threads, || job.bake_in_memory(&self.scene, camera, &|_| {}))?
            })
            .map_err(py_err)?;
        let map = &report.map;
        let json = summary_json(&report)?;
        let c = map.channels();
        let mut t = Vec::with_capacity(map.t.len() * c);
        let mut e = map
            .std_err
            .as_ref()
            .map(|_| Vec::with_capacity(map.t.len() * c));
        for ch in 0..c {
            let (tc, ec, _) = map.channel(ch);
            t.extend_from_slice(tc);
            if let (Some(e), Some(ec)) = (e.as_mut(), ec) {
                e.extend_from_slice(ec);
            }
        }
        let warnings = report.warnings.iter().map(ToString::to_string).collect();
        Ok((
            PyArray1::from_vec(py, t),
            e.map(|e| PyArray1::from_vec(py, e)),
            json,
            warnings,
        ))
    }

    /// Write the deep map `umbra bake FILE ... --deep [--deep-error E] -o PATH` writes for
    /// this volume (its file, grid, density scale and `xform` recorded), byte for byte:
    /// `(summary JSON, deep stats JSON, warnings)`.
    fn write_deep_map(
        &self,
        py: Python<'_>,
        path: PathBuf,
        options: &str,
    ) -> PyResult<(String, String, Vec<String>)> {
        let mut request = self.request(options, path)?;
        request.options.deep = request.options.deep_format.is_none();
        let threads = request.options.threads;
        // The CLI's order: the request is planned (a camera file read), the outputs checked,
        // then the camera framed.
        let report = py
            .detach(|| -> umbra::Result<_> {
                if let BakePlan::Map(job) = request.plan()? {
                    job.check_outputs()?;
                }
                let (job, camera) = self.map_plan(&request)?;
                on_threads(threads, || job.run_loaded(&self.scene, camera, &|_| {}))?
            })
            .map_err(py_err)?;
        let deep = match (report.deep.as_ref(), report.fixed.as_ref()) {
            (Some(d), _) => deep_json(d),
            (None, Some(f)) => {
                serde_json::to_value(f).map_err(|e| raise(Class::Other, e.to_string()))?
            }
            _ => return Err(raise(Class::Other, "the bake made no deep map".into())),
        };
        let warnings = report.warnings.iter().map(ToString::to_string).collect();
        Ok((summary_json(&report)?, deep.to_string(), warnings))
    }
}

impl NativeVolume {
    /// This volume's request: the Python keywords' options (JSON text), with what the volume
    /// was loaded with (file, grid, density scale, interpolation, `xform`) recorded.
    fn request(&self, options: &str, output: PathBuf) -> PyResult<BakeRequest> {
        let mut o = BakeOptions::from_json(options).map_err(py_err)?;
        o.grid.clone_from(&self.grid);
        o.density_scale = self.density_scale;
        o.interp = self.interp;
        o.xform = self
            .xform
            .map(|x| x.rows().iter().flatten().copied().collect());
        Ok(BakeRequest {
            input: self.path.clone(),
            output,
            options: o,
        })
    }

    /// The map of a request on this volume: its fixed camera, or the one its view frames.
    fn map_plan(&self, request: &BakeRequest) -> umbra::Result<(BakeJob, Camera)> {
        let BakePlan::Map(job) = request.plan()? else {
            return Err(umbra::Error::InvalidArgument {
                name: "output".into(),
                reason: "a map is written to an EXR file".into(),
            });
        };
        let camera = match job.camera {
            Some(c) => c,
            None => Camera::frame(&job.view, &self.scene.box_corners()?)?,
        };
        Ok((*job, camera))
    }
}

/// `umbra bake --json`'s `deep` object.
fn deep_json(d: &umbra::bake::DeepStats) -> serde_json::Value {
    serde_json::json!({
        "max_error": d.max_error, "samples": d.samples,
        "mean_samples_per_pixel": d.mean_samples(), "max_samples_per_pixel": d.max_samples,
        "empty_pixels": d.empty_pixels, "profile_breakpoints": d.breakpoints,
        "coarse_cells": d.coarse_cells, "rms_error": d.rms_error, "seconds": d.seconds,
    })
}

/// The lights of the USD stage `path` at `time` as JSON: `{"time", "up", "lights": [{"prim",
/// "name", "type", "kind", "dir" | "pos", "shadow_enable", "linked"}]}` (`kind` null for a
/// type umbra does not trace; `linked`: the volumes its shadow link includes).
#[pyfunction]
#[pyo3(signature = (path, time))]
fn usd_lights_json(py: Python<'_>, path: PathBuf, time: Option<f64>) -> PyResult<String> {
    let shot = py
        .detach(|| umbra::usd::lights_at(&path, time))
        .map_err(py_err)?;
    let lights: Vec<serde_json::Value> = shot
        .lights
        .iter()
        .map(|l| {
            let mut o = serde_json::json!({
                "prim": l.prim, "name": l.name(), "type": l.type_name, "kind": null,
                "shadow_enable": l.shadow.enabled, "linked": l.shadow.linked,
            });
            match l.emitter {
                Some(umbra::usd::Emitter::Directional { dir }) => {
                    o["kind"] = "directional".into();
                    o["dir"] = serde_json::json!(dir);
                }
                Some(umbra::usd::Emitter::Point { pos }) => {
                    o["kind"] = "point".into();
                    o["pos"] = serde_json::json!(pos);
                }
                None => {}
            }
            o
        })
        .collect();
    Ok(serde_json::json!({"time": shot.time, "up": shot.up, "lights": lights}).to_string())
}

/// Every point of the points prim `prim` of the stage `stage` toward `light` at each of
/// `frames` (the stage's start time code when empty), with the estimator and scene options of
/// `options` (bake options JSON): `({"prim", "type", "light", "frames": [{"frame", "T",
/// "std_err"}]}` as JSON, warnings)`, as `umbra query --positions` answers.
#[pyfunction]
#[pyo3(signature = (stage, prim, light, frames, options))]
fn usd_points_json(
    py: Python<'_>,
    stage: PathBuf,
    prim: String,
    light: Option<String>,
    frames: Vec<f64>,
    options: &str,
) -> PyResult<(String, Vec<String>)> {
    let o = BakeOptions::from_json(options).map_err(py_err)?;
    let (est, opts) = o.estimator().map_err(py_err)?;
    let scene = o.scene_options().map_err(py_err)?;
    let answers = py
        .detach(|| {
            let frames = if frames.is_empty() {
                vec![umbra::usd::lights_at(&stage, None)?.time]
            } else {
                frames
            };
            let q = umbra::internals::points::PointQuery {
                stage: &stage,
                prim: &prim,
                light: light.as_deref(),
                frames: &frames,
            };
            on_threads(o.threads, || {
                umbra::internals::points::point_transmittance(&q, &scene, &est, &opts, &mut |_| {})
            })?
        })
        .map_err(py_err)?;
    let frames: Vec<serde_json::Value> = answers
        .frames
        .iter()
        .map(|f| serde_json::json!({"frame": f.frame, "T": f.transmittance, "std_err": f.std_err}))
        .collect();
    let doc = serde_json::json!({
        "prim": answers.prim, "type": answers.type_name, "light": answers.light, "frames": frames,
    });
    Ok((doc.to_string(), answers.warnings))
}

/// `umbra.bake(input, output, **options)`: the one bake request, from a file to its output,
/// as `umbra bake INPUT -o OUTPUT --flags` runs it. Returns the summary as JSON text (a map's
/// camera dict with `deep` for a deep map; a transmittance volume's stats) and the warnings.
/// `progress(done, total)` is called from the bake's threads as work finishes (pixels, a
/// deep map's passes by cost, or voxels).
#[pyfunction]
#[pyo3(signature = (input, output, options, progress=None))]
fn bake_file(
    py: Python<'_>,
    input: PathBuf,
    output: PathBuf,
    options: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<(String, Vec<String>)> {
    let request = BakeRequest {
        input,
        output,
        options: BakeOptions::from_json(options).map_err(py_err)?,
    };
    let progress = PyProgress::new(progress);
    let outcome = py.detach(|| request.run(&progress)).map_err(|e| {
        let e = e.worded(py_worded);
        raise(class_of(&e.error), e.to_string())
    })?;
    match outcome {
        BakeOutcome::Map { report, .. } => {
            let mut summary =
                serde_json::to_value(MapSummary::new(&report.map, &report.provenance))
                    .map_err(|e| raise(Class::Other, e.to_string()))?;
            if let (Some(o), Some(d)) = (summary.as_object_mut(), report.deep.as_ref()) {
                o.insert("deep".into(), deep_json(d));
            }
            if let (Some(o), Some(f)) = (summary.as_object_mut(), report.fixed.as_ref()) {
                let v = serde_json::to_value(f).map_err(|e| raise(Class::Other, e.to_string()))?;
                o.insert("deep_format".into(), v);
            }
            let warnings = report.warnings.iter().map(ToString::to_string).collect();
            Ok((summary.to_string(), warnings))
        }
        BakeOutcome::Volume { report, .. } => {
            let warnings = report.warnings.iter().map(ToString::to_string).collect();
            Ok((stats_json(&report.stats)?, warnings))
        }
    }
}

/// A finished map's summary (the camera dict), as JSON text.
fn summary_json(report: &umbra::bake::BakeReport) -> PyResult<String> {
    let summary = MapSummary::new(&report.map, &report.provenance);
    serde_json::to_string(&summary).map_err(|e| raise(Class::Other, e.to_string()))
}

/// umbra's native module: see the `umbra` package.
#[pymodule]
fn _umbra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(info_json, m)?)?;
    m.add_function(wrap_pyfunction!(estimators_json, m)?)?;
    m.add_function(wrap_pyfunction!(estimator_options_json, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(run_job, m)?)?;
    m.add_function(wrap_pyfunction!(job_status, m)?)?;
    m.add_function(wrap_pyfunction!(emit_job, m)?)?;
    m.add_function(wrap_pyfunction!(bake_file, m)?)?;
    m.add_function(wrap_pyfunction!(usd_lights_json, m)?)?;
    m.add_function(wrap_pyfunction!(usd_points_json, m)?)?;
    m.add_class::<NativeVolume>()?;
    Ok(())
}
