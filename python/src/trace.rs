//! Tracing rows of rays for `Volume`'s methods: threads, Ctrl-C, the work budget and the
//! tallies of what the estimators reported.

use crate::errors::*;
use crate::native::*;
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use umbra::estimate::{Estimator, Options};
use umbra::request::{QueryTally, TraceOptions};
use umbra::{Interp, Light, Ray};

pub(crate) fn parse_interp(s: &str) -> PyResult<Interp> {
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
pub(crate) fn on_threads<T: Send>(
    threads: usize,
    f: impl FnOnce() -> T + Send,
) -> umbra::Result<T> {
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
pub(crate) const INTERRUPTIBLE_ROWS: usize = 4096;

/// Run `work` while the calling thread (the GIL released) watches Python's signal handlers:
/// on Ctrl-C (a `KeyboardInterrupt` from `check_signals`) `cancel` is set, the work winds down
/// (every row not yet started is skipped) and the interrupt is returned. The work runs on a
/// scoped thread, the caller waking every 50 ms; a panic in the work is resumed here.
pub(crate) fn interruptible<T: Send>(
    work: impl FnOnce() -> T + Send,
    cancel: &AtomicBool,
) -> PyResult<T> {
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
pub(crate) fn points(a: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<[f64; 3]>> {
    let s = a.as_slice()?;
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// What a batch of rays gave, row by row: `C` values per row (1 grey, 3 RGB).
pub(crate) struct Traced {
    channels: usize,
    t: Vec<f64>,
    err: Vec<f64>,
    tau: Vec<f64>,
    /// What the answers tell their user (the library's tally, as `umbra query` counts).
    tally: QueryTally,
}

/// Rows handed to the library in one call by `trace_rays` for exact answers (their rays held
/// meanwhile: about 100 bytes a row): enough for full batches on the kernel.
pub(crate) const ROWS_PER_CALL: usize = 65_536;
/// Rows a call for a stochastic or nearest estimate (ray by ray in the library): few, so Ctrl-C
/// is seen between calls within a fraction of a second even at many samples.
pub(crate) const ROWS_PER_CALL_BY_RAY: usize = 1_024;

/// The library's tally of the answers and the first failure (lowest row) of a batch.
#[derive(Default)]
pub(crate) struct Tally {
    answers: QueryTally,
    failed: u64,
    first: Option<(usize, String)>,
}

impl Tally {
    pub(crate) fn merge(mut self, o: Self) -> Self {
        self.answers = self.answers.merge(o.answers);
        self.failed += o.failed;
        self.first = match (self.first, o.first) {
            (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
            (a, b) => a.or(b),
        };
        self
    }
}

impl NativeVolume {
    /// What `path` is read as: grid `grid`, `density_scale`, `interp` (its Python name),
    /// `xform` (16 numbers, row-major).
    pub(crate) fn source(
        path: PathBuf,
        grid: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
    ) -> PyResult<umbra::input::Source> {
        let options = umbra::input::SourceOptions {
            grid,
            density_scale,
            interp: parse_interp(interp)?,
            xform,
            ..umbra::input::SourceOptions::default()
        };
        Ok(umbra::input::Source::new(path, options))
    }

    /// Load `source` ([`umbra::input::Source::load`]), keeping what it was loaded with.
    pub(crate) fn load(py: Python<'_>, source: umbra::input::Source) -> PyResult<Self> {
        let scene = py
            .detach(|| source.load())
            .map_err(|e| load_err(e, &source))?;
        let warnings = umbra::bake::volume_warnings(&scene.sanitized())
            .iter()
            .map(|w| format!("{}: {w}", source.path().display()))
            .collect();
        Ok(Self {
            scene,
            source,
            warnings,
            stats: std::sync::OnceLock::new(),
            moving: std::sync::Mutex::new(None),
        })
    }

    pub(crate) fn stats(&self) -> &[umbra::internals::tree::TreeStats] {
        self.stats.get_or_init(|| {
            self.scene
                .fogs()
                .iter()
                .map(|f| f.volume().tree().stats())
                .collect()
        })
    }

    /// The one volume of a single-grid load, or an argument error for a scene of several.
    pub(crate) fn single(&self, what: &str) -> PyResult<&umbra::Volume> {
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
    /// to the library together (`umbra::request::answer_rows`, as `umbra query --rays` answers
    /// its rows: exact queries in batches on the SIMD kernel), then dropped; Ctrl-C is seen
    /// between chunks.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn trace_rays(
        &self,
        scene: &umbra::scene::Scene,
        n: usize,
        ray_of: &(dyn Fn(usize) -> Result<Ray, String> + Sync),
        est: &Estimator,
        opts: &Options,
        ray_id: u64,
        cancel: &AtomicBool,
    ) -> Result<Traced, String> {
        let c = scene.channels();
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
            let first_id = ray_id.wrapping_add(start as u64);
            let answers = umbra::request::answer_rows(scene, &made, first_id, est, opts);
            for (k, r) in answers.into_iter().enumerate() {
                let row = start + k;
                let at = row * c..(row + 1) * c;
                let one = match r {
                    Ok(v) => {
                        t[at.clone()].copy_from_slice(&v.value[..c]);
                        err[at.clone()].copy_from_slice(&v.std_err[..c]);
                        match v.tau {
                            Some(x) => tau[at].copy_from_slice(&x[..c]),
                            None => tau[at].fill(f64::NAN),
                        }
                        let mut answers = QueryTally::default();
                        answers.add(&v);
                        Tally {
                            answers,
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
            tally: tally.answers,
        })
    }

    /// Estimate along `rows` rays (`ray_of(row)`) after the CLI's up-front checks (the
    /// estimator, its options and the job's work budget, `umbra::request::check_budget`). `options`: the estimator options
    /// as JSON ([`EstimatorOptions::from_json`]).
    pub(crate) fn run<'py>(
        &self,
        py: Python<'py>,
        rows: usize,
        ray_of: impl Fn(usize) -> Result<Ray, String> + Send + Sync,
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let o = TraceOptions::from_json(options).map_err(py_err)?;
        // `regular` with a velocity is refused here, by the keyword.
        o.estimator.motion(&o.source).map_err(py_err)?;
        let (est, opts) = o
            .estimator
            .resolve(&o.params, self.source.options().interp)
            .map_err(py_err)?;
        let scene = self.scene_for(py, o.source)?;
        let scene = &*scene;
        let cancel = AtomicBool::new(false);
        let work = || {
            on_threads(threads, || {
                umbra::request::check_budget(scene, &est, &opts, rows as u64)?;
                Ok(self.trace_rays(scene, rows, &ray_of, &est, &opts, ray_id, &cancel))
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
        out(py, traced)
    }

    /// Each point toward a light with extent (`query --at` with `--light-angle` or
    /// `--light-radius`): point `n` with ray id `ray_id + n`, through the library's one path
    /// for many receivers ([`umbra::internals::light::SoftLight::answer_many`]), so a row equals the
    /// CLI's answer at that point, bit for bit. `tau` is NaN (the mean of T has no single
    /// optical depth). The work budget is checked up front (`SoftLight::check_budget`).
    pub(crate) fn run_soft<'py>(
        &self,
        py: Python<'py>,
        soft: &umbra::internals::light::SoftLight,
        p: &[[f64; 3]],
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let o = TraceOptions::from_json(options).map_err(py_err)?;
        o.estimator.motion(&o.source).map_err(py_err)?;
        let (est, opts) = o
            .estimator
            .resolve(&o.params, self.source.options().interp)
            .map_err(py_err)?;
        let scene = self.scene_for(py, o.source)?;
        let scene = &*scene;
        // A direction that is no direction fails the call, not each row.
        if let Light::Directional { .. } = soft.light {
            soft.light.ray_from_scene(scene, [0.0; 3]).map_err(py_err)?;
        }
        let cancel = AtomicBool::new(false);
        let work = || {
            on_threads(threads, || {
                soft.check_budget(scene, p.len() as u64, &est, &opts)?;
                Ok(soft_rows(scene, soft, p, ray_id, (&est, &opts), &cancel))
            })
        };
        let rays = p.len().saturating_mul(soft.samples as usize);
        let traced = if rays >= INTERRUPTIBLE_ROWS {
            py.detach(|| interruptible(work, &cancel))?
        } else {
            py.detach(work)
        };
        let traced = traced.and_then(|r| r).map_err(py_err)?;
        let traced = traced.map_err(|m| raise(Class::Other, m))?;
        out(py, traced)
    }
}

/// Points toward a light with extent, in groups of [`umbra::internals::light::RAYS_PER_BATCH`]
/// directions (Ctrl-C seen between groups): point `n` with ray id `ray_id + n`.
fn soft_rows(
    scene: &umbra::scene::Scene,
    soft: &umbra::internals::light::SoftLight,
    p: &[[f64; 3]],
    ray_id: u64,
    (est, opts): (&Estimator, &Options),
    cancel: &AtomicBool,
) -> Result<Traced, String> {
    let (c, n) = (scene.channels(), p.len());
    let (mut t, mut err) = (vec![f64::NAN; n * c], vec![f64::NAN; n * c]);
    let mut tally = Tally::default();
    let per_call = (umbra::internals::light::RAYS_PER_BATCH / soft.samples.max(1) as usize).max(1);
    for start in (0..n).step_by(per_call) {
        if cancel.load(Ordering::Relaxed) {
            break;
        }
        let end = (start + per_call).min(n);
        let first = ray_id.wrapping_add(start as u64);
        for (k, r) in soft
            .answer_many(scene, &p[start..end], first, est, opts)
            .into_iter()
            .enumerate()
        {
            let row = start + k;
            let at = row * c..(row + 1) * c;
            let one = match r {
                Ok(a) => {
                    t[at.clone()].copy_from_slice(&a.estimate.value[..c]);
                    err[at].copy_from_slice(&a.estimate.std_err[..c]);
                    let mut answers = QueryTally::default();
                    answers.add(&a.estimate);
                    Tally {
                        answers,
                        ..Tally::default()
                    }
                }
                Err(e) => Tally {
                    failed: 1,
                    first: Some((row, cli_worded(e).to_string())),
                    ..Tally::default()
                },
            };
            tally = tally.merge(one);
        }
    }
    if let Some((row, msg)) = tally.first {
        return Err(format!(
            "{} of {n} points failed (first: row {row}: {msg})",
            tally.failed
        ));
    }
    Ok(Traced {
        channels: c,
        t,
        err,
        tau: vec![f64::NAN; n * c],
        tally: tally.answers,
    })
}

/// The arrays and warnings of what was traced.
fn out<'py>(py: Python<'py>, traced: Traced) -> PyResult<TraceOut<'py>> {
    let c = traced.channels;
    let n = traced.t.len() / c;
    let shape = |v: Vec<f64>| -> PyResult<Bound<'py, PyArray2<f64>>> {
        PyArray1::from_vec(py, v).reshape([n, c])
    };
    let warnings = traced
        .tally
        .warnings()
        .iter()
        .map(ToString::to_string)
        .collect();
    Ok((
        shape(traced.t)?,
        shape(traced.err)?,
        shape(traced.tau)?,
        warnings,
    ))
}
