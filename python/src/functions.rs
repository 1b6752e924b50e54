//! The module's free functions: reports, jobs, farm specs, EXR writing, USD lights and
//! points, and a bake from a file.

use crate::errors::*;
use crate::native::*;
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;
use std::path::PathBuf;
use umbra::bake::{Channel, MapSummary};
use umbra::request::{
    BakeOptions, BakeOutcome, BakeRequest, EstimatorOptions, PointsOutcome, QueryOutcome,
    QueryRequest,
};

/// The `umbra info --json` report on `path` (every grid, or only `grid`), as JSON text.
#[pyfunction]
#[pyo3(signature = (path, grid=None))]
pub(crate) fn info_json(py: Python<'_>, path: PathBuf, grid: Option<String>) -> PyResult<String> {
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
#[pyo3(signature = (path, task, shard, force, log, jobs, progress, keep_unkeyed=false, verify=false))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_job(
    py: Python<'_>,
    path: PathBuf,
    task: Option<usize>,
    shard: Option<(usize, usize)>,
    force: bool,
    log: Option<PathBuf>,
    jobs: usize,
    progress: Option<Py<PyAny>>,
    keep_unkeyed: bool,
    verify: bool,
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
        check: umbra::batch::KeyCheck {
            keep_unkeyed,
            verify,
        },
    };
    let callback = PyProgress::new(progress);
    let report = py
        .detach(|| umbra::batch::run(&job, &opts, &callback))
        .map_err(batch_err)?;
    serde_json::to_string(&report).map_err(|e| raise(Class::Other, e.to_string()))
}

/// Where a job stands (`umbra batch JOB --status --json`), reading the job's log and `logs`.
#[pyfunction]
#[pyo3(signature = (path, logs, keep_unkeyed=false, verify=false))]
pub(crate) fn job_status(
    py: Python<'_>,
    path: PathBuf,
    logs: Vec<PathBuf>,
    keep_unkeyed: bool,
    verify: bool,
) -> PyResult<String> {
    let job = py
        .detach(|| umbra::batch::load_job(&path))
        .map_err(|e| raise(Class::File, e.to_string()))?;
    let check = umbra::batch::KeyCheck {
        keep_unkeyed,
        verify,
    };
    let s = py.detach(|| umbra::batch::status(&job, &logs, check));
    serde_json::to_string(&s).map_err(|e| raise(Class::Other, e.to_string()))
}

/// A farm spec for a job (`umbra batch JOB --emit ENGINE`): `engine` `openjd`, `opencue` or
/// `slurm`, running the umbra CLI at `exe`, its path defaults relative to `directory`
/// (openjd); `cue`: OpenCue's (show, shot, user, uid).
#[pyfunction]
#[pyo3(signature = (path, engine, exe, directory, chunk, cue))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn emit_job(
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
pub(crate) struct PyProgress {
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
pub(crate) fn estimators_json() -> PyResult<String> {
    serde_json::to_string(umbra::estimate::REGISTRY).map_err(|e| raise(Class::Other, e.to_string()))
}

/// The estimator options with their defaults (`request::EstimatorOptions::default()`), as a
/// JSON object in field order: the one list the Python module's estimator keywords are
/// taken from (and `python/tests/test_keywords.py` holds them to).
#[pyfunction]
pub(crate) fn estimator_options_json() -> PyResult<String> {
    // The estimator options, then the motion keys of the read options (what a traced
    // query of a moving volume takes), in field order.
    let err = |e: serde_json::Error| raise(Class::Other, e.to_string());
    let text = serde_json::to_string(&EstimatorOptions::default()).map_err(err)?;
    let params = serde_json::to_string(&umbra::request::EstimatorParams::default()).map_err(err)?;
    let read = serde_json::to_value(umbra::input::SourceOptions::default()).map_err(err)?;
    let mut out = text.trim_end_matches('}').to_string();
    out.push(',');
    out.push_str(params.trim_start_matches('{').trim_end_matches('}'));
    for (k, _) in umbra::input::SourceOptions::default().motion_keys() {
        let k = k.replace('-', "_");
        let v = serde_json::to_string(&read[k.as_str()]).map_err(err)?;
        out.push_str(&format!(",\"{k}\":{v}"));
    }
    out.push('}');
    Ok(out)
}

/// Write an image and its summary (a map's `camera` dict, as JSON text) as the OpenEXR file
/// `umbra bake` writes. `t`/`err` hold `C` channels of `W x H` pixels, channel-major.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (path, summary, t, err, channels, overwrite, tile, mipmap))]
pub(crate) fn write_exr(
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

/// The lights of the USD stage `path` at `time` as JSON: `{"time", "up", "lights": [{"prim",
/// "name", "type", "kind", "dir" | "pos", "shadow_enable", "linked"}]}` (`kind` null for a
/// type umbra does not trace; `linked`: the volumes its shadow link includes).
#[pyfunction]
#[pyo3(signature = (path, time))]
pub(crate) fn usd_lights_json(
    py: Python<'_>,
    path: PathBuf,
    time: Option<f64>,
) -> PyResult<String> {
    let shot = py
        .detach(|| umbra::usd::lights_at(&path, time))
        .map_err(py_err)?;
    let mut lights = Vec::with_capacity(shot.lights.len());
    for l in &shot.lights {
        let mut o = serde_json::json!({
            "prim": l.prim, "name": l.name(), "type": l.type_name, "kind": null,
            "shadow_enable": l.shadow.enabled, "linked": l.shadow.linked,
            "refused": l.refused,
        });
        // The emitter's own JSON: its `kind` and its fields (`dir`, `pos`, ...).
        if let Some(e) = l.emitter {
            if let serde_json::Value::Object(m) =
                serde_json::to_value(e).map_err(|e| raise(Class::Other, e.to_string()))?
            {
                for (k, v) in m {
                    o[k.as_str()] = v;
                }
            }
        }
        lights.push(o);
    }
    Ok(serde_json::json!({"time": shot.time, "up": shot.up, "lights": lights}).to_string())
}

/// Every point of the points prim `prim` of the stage `stage` toward `light` at each of
/// `frames` (the stage's start time code when empty), with the estimator and scene options of
/// `options` (bake options JSON): `({"prim", "type", "light", "frames": [{"frame", "T",
/// "std_err"}]}` as JSON, warnings)`, as `umbra query --positions` answers.
#[pyfunction]
#[pyo3(signature = (stage, prim, light, frames, options))]
pub(crate) fn usd_points_json(
    py: Python<'_>,
    stage: PathBuf,
    prim: String,
    light: Option<String>,
    frames: Vec<f64>,
    options: &str,
) -> PyResult<(String, Vec<String>)> {
    let o = BakeOptions::from_json(options).map_err(py_err)?;
    o.resolve_estimator().map_err(py_err)?;
    // The keys of a light with extent apply to the stage light.
    o.light.check_extent().map_err(py_err)?;
    let mut source = umbra::input::Source::new(&stage, o.source.clone());
    source.options_mut().light = light;
    let request = QueryRequest {
        positions: Some(prim),
        frames: (!frames.is_empty()).then_some(frames),
        light: o.light.clone(),
        estimator: o.estimator.clone(),
        params: o.params.clone(),
        threads: o.threads,
        ..QueryRequest::new(source)
    };
    let outcome = py
        .detach(|| request.run(&mut |_| {}))
        .map_err(|e| py_err(e.error))?;
    let QueryOutcome::Points(PointsOutcome { answers, .. }) = outcome else {
        return Err(raise(
            Class::Other,
            "a positions query answered rays".into(),
        ));
    };
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
pub(crate) fn bake_file(
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
