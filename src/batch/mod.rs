//! Batch jobs: a TOML job file (inputs x lights, bake settings, an output pattern) expanded into
//! tasks in a deterministic order, sharded for farms, resumed by output age, and logged as JSON
//! lines. The rooms: `schema` (the job file's types, its JSON Schema), `parse` (`parse_job`), `patterns`
//! (frame tokens and output placeholders), `cameras` (shared cameras and their cache), `runner`
//! (workers, log, resume, skip, shards: [`run`]); this file holds the validated [`Job`], its
//! tasks and their log records.
//!
//! **Job file.** Relative paths are relative to the job file's directory, so a job runs the same
//! from any working directory (what a farm needs):
//!
//! ```toml
//! grid = "density"
//! output = "out/shadow_{light}.{frame:04}.exr"   # {light}, {frame}, {frame:0N}, {stem}
//!
//! [[inputs]]
//! pattern = "cache/cloud.####.vdb"               # or cloud.$F4.vdb, cloud.%04d.vdb; frames inclusive
//! frames = [1, 100]
//!
//! [[inputs]]
//! file = "hero.vdb"                              # an explicit file (frame: none)
//!
//! [[lights]]
//! name = "sun"
//! dir = [0.3, -1.0, 0.2]                         # directional: direction the light travels
//!
//! [[lights]]
//! name = "lamp"
//! pos = [0.0, 4.0, 0.0]                          # point light
//!
//! [bake]                                         # every option of `umbra bake` (BakeOptions)
//! res = [512, 512]
//! estimator = "regular"                          # step, kernel, points: its parameters
//! samples = 64                                   # alias spp
//! seed = 0
//! density_scale = 1.0
//! interp = "trilinear"
//! # preview = "out/shadow_{light}.{frame:04}.png", slices = 4 (or depths = [1.0, 2.0]),
//! # stderr = true, target_error = 0.01, max_spp = 4096, fov = 30.0, ortho = true,
//! # granularity = "leaf", global_majorant = false,
//! # up = [0.0, 0.0, 1.0], frame_box = [[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]],
//! # camera = "earlier_map.exr" (one light only), framing = "shared" | "per-frame"
//! ```
//!
//! **Framing.** By default (`framing = "shared"`) every map of one light across one sequence (an
//! `[[inputs]]` entry) uses one camera, framed on the union of the sequence's volume boxes
//! (read from headers and topology, no voxel values), so a sequence of maps does not swim; [`Job::share_cameras`] computes them
//! before any task runs. `framing = "per-frame"` frames each input on its own box. `camera`
//! fixes the camera outright.
//!
//! **Tasks.** Input-major: every input in file order (a sequence in frame order), then every
//! light in file order; task `i` is the `i`-th pair (0-based). Shard `I/N` runs the tasks with
//! `i % N == I - 1`. `[[positions]]` entries (per-point transmittance, [`PositionsTask`]) add one
//! task per frame after every bake task, split the same way.
//!
//! **Resume.** A task is up to date when its output exists and carries the task's key now
//! ([`TaskKey`], module `key`: the canonical request, the camera, the identity of every file it
//! reads, the format's version); outputs are written atomically with their key, so an existing
//! output is complete.

mod cameras;
mod checks;
pub mod emit;
mod hold;
mod key;
mod layer;
mod parse;
mod patterns;
mod positions;
mod read;
mod runner;
mod schema;
mod status;
pub use key::{
    hash_file, Change, FileId, Freshness, KeyCheck, Stale, Stored, TaskKey, FORMAT_VERSION,
    KEY_ATTRIBUTE, NOT_IN_KEY,
};
pub use parse::parse_job;
pub use patterns::{expand_pattern, fill_output, MAX_FRAMES, MAX_FRAME_PAD};
pub use positions::{PositionsSpec, PositionsTask};
pub use runner::{run, PointsOut, Progress, RunOptions, RunReport, Silent, UsdOut};
#[cfg(feature = "schema")]
pub use schema::job_schema;
pub use schema::{InputSpec, JobFile, LightSpec};
pub use status::{status, Status, TaskState};

use crate::bake::{BakeJob, BakeReport, Camera, Resolution};
pub use crate::request::Framing;
use crate::request::{BakeOptions, BakePlan, BakeRequest};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Why a job or a task failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BatchError {
    /// The job file could not be read.
    #[error("{}: cannot read: {err}", path.display())]
    Read {
        /// Job file.
        path: PathBuf,
        /// Underlying error.
        err: std::io::Error,
    },
    /// The job file is not valid TOML for a job (syntax, types, unknown keys).
    #[error("{}: {message}", path.display())]
    Syntax {
        /// Job file.
        path: PathBuf,
        /// The parser's message (with line and column).
        message: String,
    },
    /// A key of the job file has an invalid value.
    #[error("{}: {key}: {reason}", path.display())]
    Invalid {
        /// Job file.
        path: PathBuf,
        /// The key, e.g. `bake.step` or `lights[1].dir`.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// A task's bake failed (load, framing, settings, write).
    #[error(transparent)]
    Task(#[from] crate::error::Error),
    /// An option of the run ([`RunOptions`]: `task`, `shard`, `log`) is out of range: an
    /// [`crate::error::Error::InvalidArgument`] in the library's spelling, which each front end
    /// respells (the CLI `--task`, Python `task`).
    #[error(transparent)]
    Options(crate::error::Error),
    /// A task panicked (a bug): the panic message.
    #[error("task panicked: {0}")]
    Panic(String),
}

/// The message of a caught panic payload.
#[must_use]
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "a panic without a message".into()
    }
}

/// A validated job.
#[derive(Debug, Clone)]
pub struct Job {
    /// The job file (absolute when it could be made so).
    pub path: PathBuf,
    /// Grid to bake.
    pub grid: String,
    /// JSON-lines log path.
    pub log: PathBuf,
    /// Bake tasks in order.
    pub tasks: Vec<Task>,
    /// `[[positions]]` tasks (one per frame), numbered after the bake tasks.
    pub positions: Vec<PositionsTask>,
    /// The `[bake]` options every task shares, checked: the grid, the lights, the camera, the
    /// preview pattern and the framing are moved out into the job and its tasks.
    pub options: BakeOptions,
    /// How maps are framed.
    pub framing: Framing,
    /// A fixed camera for every task (`bake.camera`).
    pub camera: Option<Camera>,
    /// Transmittance volumes instead of maps (an output pattern ending in `.vdb`).
    pub volume: bool,
    /// `bake.usd_out`: one `.usda` layer that puts every stage-light task's map and camera on
    /// its light, time-sampled by frame, rewritten after each run (`layer`).
    pub usd_out: Option<PathBuf>,
    /// The shared camera of each (`[[inputs]]` entry, light name), once
    /// [`Job::share_cameras`] has run.
    pub shared: std::sync::OnceLock<std::collections::BTreeMap<(usize, String), Camera>>,
}

/// One bake: an input under one light.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Task {
    /// Index in the job (0-based).
    pub index: usize,
    /// Index of its `[[inputs]]` entry (the sequence it belongs to).
    pub sequence: usize,
    /// Input file.
    pub input: PathBuf,
    /// What the task reads: its input, its kind, and how it is read (the entry's read options
    /// over `[bake]`'s, toward the task's stage light at its frame).
    #[serde(skip)]
    pub source: crate::input::Source,
    /// Grid baked in the input (its `[[inputs]]` entry's, else the job's).
    pub grid: String,
    /// Density scale (its entry's, else `[bake]`'s).
    pub density_scale: f64,
    /// Level-set handling (its entry's, else `[bake]`'s).
    pub levelset: Option<crate::request::LevelSet>,
    /// Object transform, 16 numbers row-major (its entry's, else `[bake]`'s).
    pub xform: Option<Vec<f64>>,
    /// Frame number for sequence inputs.
    pub frame: Option<i64>,
    /// Light name.
    pub light: String,
    /// Direction the light travels.
    pub dir: Option<[f64; 3]>,
    /// Light position.
    pub pos: Option<[f64; 3]>,
    /// A USD stage light (prim path), read at the task's frame.
    pub usd_light: Option<String>,
    /// Output file.
    pub output: PathBuf,
    /// PNG preview file.
    pub preview: Option<PathBuf>,
}

impl Task {
    /// Put how this task reads its input (grid, density scale, level sets, transform) into
    /// `options`.
    pub fn read_into(&self, options: &mut BakeOptions) {
        options.source.grid.clone_from(&self.grid);
        options.source.density_scale = self.density_scale;
        options.source.levelset = self.levelset;
        options.source.xform.clone_from(&self.xform);
    }

    /// The time code a USD stage input is read at: the task's frame (`None` for other inputs,
    /// and for a stage without `frames`: its start time code).
    #[must_use]
    pub fn time(&self) -> Option<f64> {
        #[allow(clippy::cast_precision_loss)]
        self.frame
            .filter(|_| self.source.kind().is_stage())
            .map(|f| f as f64)
    }
}

/// What happened to a task (one JSON line of the log).
#[derive(Debug, Clone, Serialize)]
pub struct Record {
    /// Task index.
    pub task: usize,
    /// Input file.
    pub input: PathBuf,
    /// Grid.
    pub grid: String,
    /// Light name.
    pub light: String,
    /// Output file.
    pub output: PathBuf,
    /// `ok`, `skipped` or `failed`.
    pub status: &'static str,
    /// Wall time of the task.
    pub seconds: f64,
    /// Rays per second of the bake: map pixels, or voxels of a transmittance volume (0 when
    /// not baked).
    pub rays_per_second: f64,
    /// Error message of a failed task.
    pub error: Option<String>,
    /// Why a task was baked (`settings changed: bake.density_scale`, `input changed:
    /// cloud.0012.vdb`, `light sun changed`, `output missing`, `forced`) or skipped (`up to
    /// date`; a stage light that casts no shadows, [`Job::shadowless`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// A held frame: the frame whose bake this output copies (same input content, a request
    /// that differs only by the frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub holds: Option<i64>,
    /// Warnings of a finished task (bad voxels, capped samples, majorant violations).
    pub warnings: Vec<String>,
}

/// Read, parse and validate a job file.
///
/// # Errors
/// [`BatchError::Read`] when it cannot be read, else as [`parse_job`].
pub fn load_job(path: &Path) -> Result<Job, BatchError> {
    let text = std::fs::read_to_string(path).map_err(|err| BatchError::Read {
        path: path.to_path_buf(),
        err,
    })?;
    parse_job(path, &text)
}

/// Parse a shard `I/N` (1-based `I`).
///
/// # Errors
/// When it is not `I/N` with `1 <= I <= N`.
pub fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let parsed = s
        .split_once('/')
        .and_then(|(i, n)| Some((i.trim().parse().ok()?, n.trim().parse().ok()?)));
    match parsed {
        Some(shard) if valid_shard(shard) => Ok(shard),
        _ => Err(format!("expected I/N with 1 <= I <= N, got '{s}'")),
    }
}

/// Parse a task selection `I` or `I-J` (0-based, inclusive, `I <= J`) into `(I, J)`.
///
/// # Errors
/// When it is neither.
pub fn parse_tasks(s: &str) -> Result<(usize, usize), String> {
    let parsed = match s.split_once('-') {
        Some((a, b)) => a.trim().parse().ok().zip(b.trim().parse().ok()),
        None => s.trim().parse().ok().map(|i| (i, i)),
    };
    match parsed {
        Some((a, b)) if a <= b => Ok((a, b)),
        _ => Err(format!("expected I or I-J with I <= J, got '{s}'")),
    }
}

/// Whether `(i, n)` names a shard: `1 <= i <= n`.
#[must_use]
pub fn valid_shard((i, n): (usize, usize)) -> bool {
    n >= 1 && (1..=n).contains(&i)
}

/// Whether task `index` belongs to shard `i/n` (1-based `i`).
#[must_use]
pub fn in_shard(index: usize, (i, n): (usize, usize)) -> bool {
    index % n == i - 1
}

impl Job {
    /// The files a task's result depends on: its input and, for a scene file or a USD stage,
    /// the `.vdb` files its volumes name at the task's frame (`scene::file::sources`). `None`
    /// when they cannot be listed (the bake will say why).
    #[must_use]
    pub fn sources(&self, task: &Task) -> Option<Vec<PathBuf>> {
        task.source.files().ok()
    }

    /// Whether a task's output exists and carries the task's key now ([`Job::freshness`]
    /// with the default [`KeyCheck`]): any setting, light, camera or file content it depends
    /// on that changed makes it stale.
    #[must_use]
    pub fn up_to_date(&self, task: &Task) -> bool {
        self.freshness(task, KeyCheck::default()).stale.is_none()
    }

    /// The request of one task, as `umbra bake INPUT ... -o OUTPUT` would make it: the job's
    /// options with the task's light, preview and `threads`.
    #[must_use]
    pub fn request(&self, task: &Task, threads: usize) -> BakeRequest {
        let mut options = self.options.clone();
        task.read_into(&mut options);
        // With a fixed camera the light only names the outputs: the plan frames a view from it
        // that the fixed camera then replaces.
        options.light.light_dir = task.dir;
        options.light.light_pos = task.pos;
        options.source.light.clone_from(&task.usd_light);
        options.source.frame = task.time();
        options.preview.clone_from(&task.preview);
        options.threads = threads;
        options.force = true;
        BakeRequest {
            input: task.input.clone(),
            output: task.output.clone(),
            options,
        }
    }

    /// The plan of one task ([`Job::request`]), with the job's fixed or shared camera.
    ///
    /// # Errors
    /// [`BatchError::Task`] when the task cannot be planned (the job's options were checked on
    /// task 0, so only a reused camera that became unreadable).
    pub fn plan(&self, task: &Task, threads: usize) -> Result<BakePlan, BatchError> {
        let mut plan = self.request(task, threads).plan()?;
        if let BakePlan::Map(j) = &mut plan {
            j.camera = self.camera.or_else(|| {
                self.shared
                    .get()
                    .and_then(|m| m.get(&(task.sequence, task.light.clone())))
                    .copied()
            });
        }
        Ok(plan)
    }

    /// The bake of one task's map, as `umbra bake` would run it.
    ///
    /// # Errors
    /// As [`Job::plan`]; [`BatchError::Task`] for a job of transmittance volumes.
    pub fn bake_job(&self, task: &Task, threads: usize) -> Result<BakeJob, BatchError> {
        match self.plan(task, threads)? {
            BakePlan::Map(j) => Ok(*j),
            BakePlan::Volume(_) => Err(BatchError::Task(crate::error::Error::InvalidArgument {
                name: "output".into(),
                reason: "this job writes transmittance volumes, not maps".into(),
            })),
        }
    }

    /// Check every input of the job before any task runs: the file exists and holds its
    /// task's grid (its header and grid list only). A file that is there but cannot be parsed
    /// is left to its own task, which fails alone.
    ///
    /// # Errors
    /// [`BatchError::Task`] with [`crate::error::Error::Io`] or [`crate::error::Error::GridNotFound`],
    /// naming the first input that fails.
    pub fn check_inputs(&self) -> Result<(), BatchError> {
        let mut inputs: Vec<&Task> = self.tasks.iter().collect();
        inputs.dedup_by(|a, b| a.input == b.input && a.grid == b.grid);
        for task in inputs {
            let input = task.input.as_path();
            let kind = task.source.kind();
            let found = if kind.is_stage() {
                crate::usd::lights_at(input, None).map(|_| ())
            } else if kind.is_scene_file() {
                task.source.box_corners().map(|_| ())
            } else {
                crate::input::GridFile::open(input).and_then(|f| f.check_grid(&task.grid))
            };
            if let Err(
                e @ (crate::error::Error::Io { .. }
                | crate::error::Error::GridNotFound { .. }
                | crate::error::Error::Scene { .. }
                | crate::error::Error::Stage { .. }),
            ) = found
            {
                return Err(e.into());
            }
        }
        Ok(())
    }

    /// Why `task` bakes nothing: its stage light casts no shadows at the task's frame
    /// (`inputs:shadow:enable = false`), or its `collection:shadowLink` includes none of the
    /// volumes the job reads. Such a task is skipped, not missing: a run logs it as skipped,
    /// `--plan` and `--status` list it as skipped. `None`: the task bakes (a stage that cannot
    /// be read is left to the task, which fails on its own).
    #[must_use]
    pub fn shadowless(&self, task: &Task) -> Option<String> {
        let name = task.usd_light.as_deref()?;
        let shot = crate::usd::lights_at(&task.input, task.time()).ok()?;
        let l = shot
            .lights
            .iter()
            .find(|l| l.prim == name || l.name() == name)?;
        if l.shadow.unreadable.is_some() {
            return None; // the task fails, saying why
        }
        if !l.shadow.enabled {
            return Some(format!(
                "{}: inputs:shadow:enable is false (the light casts no shadows)",
                l.prim
            ));
        }
        let wanted = self.options.source.volume.as_deref();
        let read = |v: &&String| wanted.is_none_or(|w| w.contains(v));
        let any = l
            .shadow
            .linked
            .iter()
            .chain(&l.shadow.unlinked)
            .any(|v| read(&v));
        if any && !l.shadow.linked.iter().any(|v| read(&v)) {
            return Some(format!(
                "{}: its collection:shadowLink includes none of the volumes (nothing casts its \
                 shadows)",
                l.prim
            ));
        }
        None
    }

    /// Check every task as a run would before it bakes anything: every input holds its
    /// task's grid ([`Job::check_inputs`]) and every task's request plans
    /// ([`BakeRequest::plan`]), but those that bake nothing ([`Job::shadowless`]), which it
    /// returns with the reason. What `--plan` runs.
    ///
    /// # Errors
    /// As [`Job::check_inputs`]; [`BatchError::Invalid`] naming the first task whose request
    /// cannot be planned (key `tasks[I]`) and why.
    pub fn check_tasks(&self) -> Result<Vec<(usize, String)>, BatchError> {
        self.check_inputs()?;
        self.check_positions()?;
        let mut skipped = Vec::new();
        for task in &self.tasks {
            if let Some(why) = self.shadowless(task) {
                skipped.push((task.index, why));
                continue;
            }
            self.request(task, 0)
                .plan()
                .map_err(|e| parse::err(&self.path, &format!("tasks[{}]", task.index), e))?;
        }
        Ok(skipped)
    }

    /// Bake one task as `umbra bake` would, through the one entry point of a bake
    /// ([`BakeRequest::run_plan`] with the task's plan, [`Job::plan`]), and write its outputs
    /// atomically (overwriting stale ones). Loads only the job's grid of the task's input.
    /// `threads` as [`crate::bake::BakeSettings::threads`]; `progress` is told the task's work and receives
    /// finished units. `key` (the task's [`TaskKey`], [`Job::freshness`]) is written into the
    /// map's header as `umbra:key`. A panic inside the bake is caught and returned with its
    /// message.
    ///
    /// # Errors
    /// [`BatchError::Task`] for any load, framing, bake or write error (without the context a
    /// front end adds: the log names the input); [`BatchError::Panic`].
    pub fn run_task(
        &self,
        task: &Task,
        threads: usize,
        key: Option<&TaskKey>,
        progress: &dyn crate::progress::Progress,
    ) -> Result<BakeReport, BatchError> {
        let mut job = self.bake_job(task, threads)?;
        job.key = key.map(TaskKey::to_text);
        match self.run_planned(task, threads, BakePlan::Map(Box::new(job)), progress)? {
            crate::request::BakeOutcome::Map { report, .. } => Ok(*report),
            crate::request::BakeOutcome::Volume { .. } => {
                Err(BatchError::Task(crate::error::Error::InvalidArgument {
                    name: "output".into(),
                    reason: "this job writes maps, not transmittance volumes".into(),
                }))
            }
        }
    }

    /// Run a task's `plan` through [`BakeRequest::run_plan`], catching a panic.
    fn run_planned(
        &self,
        task: &Task,
        threads: usize,
        plan: BakePlan,
        progress: &dyn crate::progress::Progress,
    ) -> Result<crate::request::BakeOutcome, BatchError> {
        let request = self.request(task, threads);
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            request.run_plan(plan, progress)
        }))
        .map_err(|p| BatchError::Panic(panic_message(p.as_ref())))?
        .map_err(|e| BatchError::Task(e.error))
    }

    /// The transmittance volume of one task, as `umbra bake INPUT --light-dir D -o OUT.vdb`
    /// would write it.
    ///
    /// # Errors
    /// As [`Job::plan`]; [`BatchError::Task`] for a job of maps.
    pub fn volume_job(
        &self,
        task: &Task,
        threads: usize,
    ) -> Result<crate::bake::VolumeJob, BatchError> {
        match self.plan(task, threads)? {
            BakePlan::Volume(j) => Ok(*j),
            BakePlan::Map(_) => Err(BatchError::Task(crate::error::Error::InvalidArgument {
                name: "output".into(),
                reason: "this job writes maps, not transmittance volumes".into(),
            })),
        }
    }

    /// [`Job::run_task`] for a job of transmittance volumes ([`Job::volume_job`]).
    ///
    /// # Errors
    /// As [`Job::run_task`]; [`BatchError::Task`] (an invalid argument) for a job of maps.
    pub fn run_volume_task(
        &self,
        task: &Task,
        threads: usize,
        key: Option<&TaskKey>,
        progress: &dyn crate::progress::Progress,
    ) -> Result<crate::bake::VolumeReport, BatchError> {
        let mut job = self.volume_job(task, threads)?;
        job.key = key.map(TaskKey::to_text);
        match self.run_planned(task, threads, BakePlan::Volume(Box::new(job)), progress)? {
            crate::request::BakeOutcome::Volume { report, .. } => Ok(report),
            crate::request::BakeOutcome::Map { .. } => {
                Err(BatchError::Task(crate::error::Error::InvalidArgument {
                    name: "output".into(),
                    reason: "this job writes transmittance volumes, not maps".into(),
                }))
            }
        }
    }

    /// Pixels of a task's map when it is known without loading (fixed resolution).
    #[must_use]
    pub fn pixels_hint(&self) -> Option<u64> {
        match self.options.res {
            Some(Resolution::Exact(w, h)) => Some(u64::from(w) * u64::from(h)),
            _ => None,
        }
    }
}
