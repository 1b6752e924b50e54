//! Batch jobs: a TOML job file (inputs x lights, bake settings, an output pattern) expanded into
//! tasks in a deterministic order, sharded for farms, resumed by output age, and logged as JSON
//! lines.
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
//! [bake]                                         # every option of `umbra bake`
//! res = [512, 512]
//! estimator = "regular"                          # step, kernel, points: its parameters
//! spp = 64
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
//! `i % N == I - 1`.
//!
//! **Resume.** A task is up to date when its output exists and its modification time is not
//! older than its input's; outputs are written atomically, so an existing output is complete.

mod runner;
pub use runner::{run, Progress, RunOptions, RunReport, Silent};

use crate::bake::{BakeJob, BakeReport, Camera, Resolution};
pub use crate::request::Framing;
use crate::request::{BakeOptions, BakePlan, BakeRequest};
use serde::{Deserialize, Serialize};
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
    Task(#[from] crate::Error),
    /// An option of the run ([`RunOptions`]: `task`, `shard`, `log`) is out of range: an
    /// [`crate::Error::InvalidArgument`] in the library's spelling, which each front end
    /// respells ([`crate::Error::for_front`]: `--task` / `task`).
    #[error(transparent)]
    Options(crate::Error),
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

/// The job file as written. Its JSON Schema ([`job_schema`], `umbra batch --schema`) is
/// generated from this type.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    /// Grid to bake in every input (default `density`; or `grid` in `[bake]`).
    pub grid: Option<String>,
    /// Output path pattern: `{light}`, `{stem}`, `{frame}`, `{frame:0N}`; ending in `.vdb`,
    /// transmittance volumes, else EXR maps.
    pub output: String,
    /// JSON-lines log (default: `umbra_batch.jsonl` in the first output's directory).
    pub log: Option<String>,
    /// Inputs, in order.
    pub inputs: Vec<InputSpec>,
    /// Lights, in order (or one light as `light_dir` / `light_pos` in `[bake]`).
    #[serde(default)]
    pub lights: Vec<LightSpec>,
    /// The options of every bake: `umbra bake`'s, with the same names (`_` for `-`) and
    /// defaults ([`BakeOptions`]), plus `framing`.
    #[serde(default)]
    pub bake: BakeOptions,
}

/// The JSON Schema (draft 2020-12) of job files, generated from [`JobFile`] and
/// [`BakeOptions`]: what `umbra batch --schema` prints.
#[cfg(feature = "schema")]
#[must_use]
pub fn job_schema() -> serde_json::Value {
    let schema = schemars::generate::SchemaSettings::draft2020_12()
        .into_generator()
        .into_root_schema_for::<JobFile>();
    serde_json::to_value(schema).unwrap_or_default()
}

/// One `[[inputs]]` entry: `file`, or `pattern` with `frames`.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// An explicit file.
    pub file: Option<String>,
    /// A sequence pattern: `####` (padding = number of `#`), `$F4` / `$F`, or `%04d` / `%d`.
    pub pattern: Option<String>,
    /// Inclusive frame range `[first, last]` of a pattern.
    pub frames: Option<[i64; 2]>,
    /// Frame step of a pattern (default 1).
    pub step: Option<i64>,
}

/// One `[[lights]]` entry.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Name used by `{light}`.
    pub name: String,
    /// Direction the light travels (directional light, orthographic map; with `pos`, where a
    /// perspective map from the light looks), as `umbra bake --light-dir`.
    pub dir: Option<[f64; 3]>,
    /// Light position (point light, perspective map), as `umbra bake --light-pos`.
    pub pos: Option<[f64; 3]>,
}

/// The shared cameras of a job as its cache file stores them.
#[derive(Serialize, Deserialize)]
struct CameraCache {
    fingerprint: String,
    cameras: Vec<CachedCamera>,
}

/// One shared camera: its sequence, light and fields.
#[derive(Serialize, Deserialize)]
struct CachedCamera {
    sequence: usize,
    light: String,
    camera: crate::bake::CameraParts,
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
    /// Tasks in order.
    pub tasks: Vec<Task>,
    /// The `[bake]` options every task shares, checked: the grid, the lights, the camera, the
    /// preview pattern and the framing are moved out into the job and its tasks.
    pub options: BakeOptions,
    /// How maps are framed.
    pub framing: Framing,
    /// A fixed camera for every task (`bake.camera`).
    pub camera: Option<Camera>,
    /// Transmittance volumes instead of maps (an output pattern ending in `.vdb`).
    pub volume: bool,
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
    /// Frame number for sequence inputs.
    pub frame: Option<i64>,
    /// Light name.
    pub light: String,
    /// Direction the light travels.
    pub dir: Option<[f64; 3]>,
    /// Light position.
    pub pos: Option<[f64; 3]>,
    /// Output file.
    pub output: PathBuf,
    /// PNG preview file.
    pub preview: Option<PathBuf>,
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
    /// Warnings of a finished task (bad voxels, capped samples, majorant violations).
    pub warnings: Vec<String>,
}

fn err(path: &Path, key: &str, reason: impl std::fmt::Display) -> BatchError {
    BatchError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        reason: reason.to_string(),
    }
}

/// Expand a sequence pattern for one frame: `#...#` (zero-padded to the number of `#`),
/// `$F` / `$FN` (padded to N) or printf's `%d` / `%0Nd` (padded to N). `None` when the pattern
/// has no frame token.
#[must_use]
pub fn expand_pattern(pattern: &str, frame: i64) -> Option<String> {
    let (start, len, pad) = frame_token(pattern)?;
    let n = pad.min(MAX_FRAME_PAD);
    Some(format!(
        "{}{frame:0n$}{}",
        &pattern[..start],
        &pattern[start + len..]
    ))
}

/// The first frame token of a pattern: its byte offset, its length and the padding it asks
/// for (a huge `N` saturates). `####` wins over `$F`, which wins over `%0Nd`.
fn frame_token(pattern: &str) -> Option<(usize, usize, usize)> {
    let digits_after = |at: usize| -> String {
        pattern[at..]
            .chars()
            .take_while(char::is_ascii_digit)
            .collect()
    };
    let pad_of = |d: &str| {
        if d.is_empty() {
            0
        } else {
            d.parse::<usize>().unwrap_or(usize::MAX)
        }
    };
    if let Some(start) = pattern.find('#') {
        let n = pattern[start..].chars().take_while(|&c| c == '#').count();
        return Some((start, n, n));
    }
    if let Some(start) = pattern.find("$F") {
        let d = digits_after(start + 2);
        return Some((start, 2 + d.len(), pad_of(&d)));
    }
    let mut from = 0;
    while let Some(off) = pattern[from..].find('%') {
        let start = from + off;
        let d = digits_after(start + 1);
        if pattern[start + 1 + d.len()..].starts_with('d') && (d.is_empty() || d.starts_with('0')) {
            return Some((start, 2 + d.len(), pad_of(&d)));
        }
        from = start + 1;
    }
    None
}

/// Widest frame-number padding accepted (`####`, `$FN`, `{frame:0N}`).
pub const MAX_FRAME_PAD: usize = 32;
/// Most frames one `[[inputs]]` sequence may expand to.
pub const MAX_FRAMES: i64 = 1_000_000;

/// The padding a sequence pattern asks for (`None` without a frame token; a huge `N`
/// saturates).
fn pattern_pad(pattern: &str) -> Option<usize> {
    frame_token(pattern).map(|(_, _, pad)| pad)
}

/// Fill an output pattern: `{light}`, `{stem}`, `{frame}`, `{frame:0N}`.
///
/// # Errors
/// An unknown placeholder, or `{frame}` for an input that has no frame.
pub fn fill_output(
    pattern: &str,
    light: &str,
    stem: &str,
    frame: Option<i64>,
) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = pattern;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let close = rest[open..]
            .find('}')
            .ok_or_else(|| format!("unclosed '{{' in '{pattern}'"))?
            + open;
        let key = &rest[open + 1..close];
        match key {
            "light" => out.push_str(light),
            "stem" => out.push_str(stem),
            _ if key == "frame" || key.starts_with("frame:") => {
                let f = frame.ok_or_else(|| {
                    format!("'{{{key}}}' but input '{stem}' is not from a sequence")
                })?;
                let width = match key.strip_prefix("frame:") {
                    None => 0,
                    Some(w) => w
                        .parse::<usize>()
                        .ok()
                        .filter(|&w| w <= MAX_FRAME_PAD)
                        .ok_or_else(|| {
                            format!(
                                "'{{{key}}}': expected {{frame:0N}} with N at most {MAX_FRAME_PAD}"
                            )
                        })?,
                };
                out.push_str(&format!("{f:0width$}"));
            }
            _ => {
                return Err(format!(
                    "unknown placeholder '{{{key}}}' (known: {{light}}, {{stem}}, {{frame}}, {{frame:04}})"
                ))
            }
        }
        rest = &rest[close + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// The key (`bake.levelset`) whose value starts the line holding byte `at` of a job file: the
/// text before `=` on that line, after the last `[table]` header above it. `None` for a line
/// that is not `key = value`.
fn key_at(text: &str, at: usize) -> Option<String> {
    let start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let line = text[start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    let bare = |k: &str| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
    };
    if !bare(key) {
        return None;
    }
    let table = text[..start]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_string());
    Some(match table {
        Some(t) if !t.is_empty() => format!("{t}.{key}"),
        _ => key.to_string(),
    })
}

/// Parse and validate a job file's text; `path` is the job file (relative paths in it are
/// relative to its directory).
///
/// # Errors
/// [`BatchError::Syntax`] (with line and column) or [`BatchError::Invalid`] naming the key.
pub fn parse_job(path: &Path, text: &str) -> Result<Job, BatchError> {
    let file: JobFile = toml::from_str(text).map_err(|e| {
        // One line: "line L, column C: message" (the parser's own text quotes the source).
        let message = match e.span() {
            Some(r) if r.start <= text.len() => {
                let before = &text[..r.start];
                let line = before.matches('\n').count() + 1;
                let column = r.start - before.rfind('\n').map_or(0, |i| i + 1) + 1;
                let key = key_at(text, r.start)
                    .map(|k| format!("{k}: "))
                    .unwrap_or_default();
                format!("line {line}, column {column}: {key}{}", e.message().trim())
            }
            _ => e.message().trim().to_string(),
        };
        BatchError::Syntax {
            path: path.to_path_buf(),
            message: message.replace('\n', " "),
        }
    })?;
    let path = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let resolve = |s: &str| base.join(s);
    let b = &file.bake;
    // The grid: top level (the original place) or in [bake], once.
    let grid = match (&file.grid, b.grid.as_str()) {
        (Some(g), "density") => g.clone(),
        (Some(_), _) => {
            return Err(err(
                &path,
                "bake.grid",
                "the grid is given at the top level too: give it once",
            ))
        }
        (None, g) => g.to_string(),
    };
    if grid.is_empty() {
        return Err(err(&path, "grid", "must not be empty"));
    }
    // The lights: [[lights]] entries, or one light in [bake].
    let lights = match (file.lights.is_empty(), b.light_dir, b.light_pos) {
        (true, None, None) => {
            return Err(err(
                &path,
                "lights",
                "give at least one [[lights]] entry, or light_dir / light_pos in [bake]",
            ))
        }
        (true, dir, pos) => vec![LightSpec {
            name: "light".into(),
            dir,
            pos,
        }],
        (false, None, None) => file.lights.clone(),
        (false, ..) => {
            let key = if b.light_dir.is_some() {
                "bake.light_dir"
            } else {
                "bake.light_pos"
            };
            return Err(err(
                &path,
                key,
                "the lights are given as [[lights]] too: give them in one place",
            ));
        }
    };
    if b.camera.is_some() && lights.len() > 1 {
        return Err(err(
            &path,
            "bake.camera",
            "a fixed camera is one view: give one [[lights]] entry (it names the outputs)",
        ));
    }
    let mut names = std::collections::HashSet::new();
    for (i, l) in lights.iter().enumerate() {
        let key = |k: &str| format!("lights[{i}].{k}");
        if l.name.is_empty()
            || l.name == "."
            || l.name == ".."
            || l.name.contains(['/', '\\'])
            || l.name.chars().any(char::is_control)
        {
            return Err(err(
                &path,
                &key("name"),
                "must be a non-empty name without slashes or control characters, not . or ..",
            ));
        }
        if !names.insert(l.name.as_str()) {
            return Err(err(
                &path,
                &key("name"),
                format!("'{}' is used twice", l.name),
            ));
        }
        match (l.dir, l.pos) {
            (None, None) => {
                return Err(err(
                    &path,
                    &format!("lights[{i}]"),
                    "give dir = [x, y, z] (directional) or pos = [x, y, z] (point)",
                ))
            }
            (dir, pos) => {
                if let Some(d) = dir {
                    if !d.iter().all(|c| c.is_finite()) || d.iter().all(|&c| c == 0.0) {
                        return Err(err(&path, &key("dir"), "must be finite and non-zero"));
                    }
                }
                if let Some(p) = pos {
                    if !p.iter().all(|c| c.is_finite()) {
                        return Err(err(&path, &key("pos"), "must be finite"));
                    }
                }
            }
        }
    }
    if file.inputs.is_empty() {
        return Err(err(&path, "inputs", "give at least one [[inputs]] entry"));
    }
    // (file, frame, index of its [[inputs]] entry)
    let mut inputs: Vec<(PathBuf, Option<i64>, usize)> = Vec::new();
    for (i, inp) in file.inputs.iter().enumerate() {
        let key = |k: &str| format!("inputs[{i}].{k}");
        match (&inp.file, &inp.pattern) {
            (Some(f), None) => {
                if inp.frames.is_some() || inp.step.is_some() {
                    return Err(err(
                        &path,
                        &key("frames"),
                        "frames/step go with pattern, not file",
                    ));
                }
                inputs.push((resolve(f), None, i));
            }
            (None, Some(p)) => {
                let [first, last] = inp.frames.ok_or_else(|| {
                    err(
                        &path,
                        &key("frames"),
                        "a pattern needs frames = [first, last]",
                    )
                })?;
                let step = inp.step.unwrap_or(1);
                if step < 1 {
                    return Err(err(&path, &key("step"), "must be at least 1"));
                }
                if last < first {
                    return Err(err(&path, &key("frames"), "last frame before the first"));
                }
                match pattern_pad(p) {
                    None => {
                        return Err(err(
                            &path,
                            &key("pattern"),
                            format!("'{p}' has no frame token (####, $F4 or %04d)"),
                        ))
                    }
                    Some(n) if n > MAX_FRAME_PAD => {
                        return Err(err(
                            &path,
                            &key("pattern"),
                            format!("pads frames to {n} digits; at most {MAX_FRAME_PAD}"),
                        ))
                    }
                    Some(_) => {}
                }
                let count = (i128::from(last) - i128::from(first)) / i128::from(step) + 1;
                if count > i128::from(MAX_FRAMES) {
                    return Err(err(
                        &path,
                        &key("frames"),
                        format!("{count} frames; at most {MAX_FRAMES} per sequence"),
                    ));
                }
                let mut f = first;
                loop {
                    let name = expand_pattern(p, f).unwrap_or_default();
                    inputs.push((resolve(&name), Some(f), i));
                    match f.checked_add(step) {
                        Some(next) if next <= last => f = next,
                        _ => break,
                    }
                }
            }
            _ => {
                return Err(err(
                    &path,
                    &format!("inputs[{i}]"),
                    "give file = \"...\" or pattern = \"...\" with frames",
                ))
            }
        }
    }
    if lights.len() > 1 && !file.output.contains("{light}") {
        return Err(err(
            &path,
            "output",
            "several lights but no {light} in the pattern: outputs would collide",
        ));
    }
    let mut tasks = Vec::new();
    let mut seen = std::collections::HashMap::new();
    for (input, frame, sequence) in &inputs {
        let stem = input
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        for l in &lights {
            let out = fill_output(&file.output, &l.name, &stem, *frame)
                .map_err(|e| err(&path, "output", e))?;
            let output = normalise(&resolve(&out));
            let preview = match &b.preview {
                Some(p) => Some(normalise(&resolve(
                    &fill_output(&p.to_string_lossy(), &l.name, &stem, *frame)
                        .map_err(|e| err(&path, "bake.preview", e))?,
                ))),
                None => None,
            };
            if preview.as_ref() == Some(&output) {
                return Err(err(&path, "bake.preview", "names the same file as output"));
            }
            let index = tasks.len();
            if let Some(prev) = seen.insert(output.clone(), index) {
                return Err(err(
                    &path,
                    "output",
                    format!(
                        "tasks {prev} and {index} both write {} (add {{stem}} or {{frame:04}})",
                        output.display()
                    ),
                ));
            }
            tasks.push(Task {
                index,
                sequence: *sequence,
                input: input.clone(),
                frame: *frame,
                light: l.name.clone(),
                dir: l.dir,
                pos: l.pos,
                output,
                preview,
            });
        }
    }
    let log = match &file.log {
        Some(l) => resolve(l),
        None => tasks[0]
            .output
            .parent()
            .map(|d| d.join("umbra_batch.jsonl"))
            .unwrap_or_else(|| PathBuf::from("umbra_batch.jsonl")),
    };
    // Check the options once, as task 0 would run them; keep what every task shares.
    let mut options = b.clone();
    options.grid.clone_from(&grid);
    options.light_dir = None;
    options.light_pos = None;
    options.preview = None;
    let framing = options.framing.take().unwrap_or_default();
    if let Some(crate::request::CameraSource::File(c)) = &mut options.camera {
        *c = resolve(&c.to_string_lossy());
    }
    let first = &tasks[0];
    let mut template = options.clone();
    template.preview.clone_from(&first.preview);
    if template.camera.is_none() {
        template.light_dir = first.dir;
        template.light_pos = first.pos;
    }
    let plan = BakeRequest {
        input: first.input.clone(),
        output: first.output.clone(),
        options: template,
    }
    .plan()
    .map_err(|e| match e {
        crate::Error::InvalidArgument { name, reason } => {
            let key = match name.as_str() {
                "output" => "output".to_string(),
                n => format!("bake.{}", n.replace('-', "_")),
            };
            err(&path, &key, reason)
        }
        other => err(&path, "bake.camera", other),
    })?;
    let (volume, camera) = match plan {
        BakePlan::Map(j) => (false, j.camera),
        BakePlan::Volume(_) => (true, None),
    };
    options.camera = None;
    Ok(Job {
        path,
        grid,
        log,
        tasks,
        options,
        framing,
        camera,
        volume,
        shared: std::sync::OnceLock::new(),
    })
}

/// `p` with `.` and `name/..` components removed lexically (no file system access), so two
/// spellings of one output path compare equal.
fn normalise(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
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

/// Whether a task's output exists and is not older than its input.
#[must_use]
pub fn up_to_date(task: &Task) -> bool {
    let mtime = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    match (mtime(&task.output), mtime(&task.input)) {
        (Some(out), Some(inp)) => out >= inp,
        _ => false,
    }
}

impl Job {
    /// The request of one task, as `umbra bake INPUT ... -o OUTPUT` would make it: the job's
    /// options with the task's light, preview and `threads`.
    #[must_use]
    pub fn request(&self, task: &Task, threads: usize) -> BakeRequest {
        let mut options = self.options.clone();
        // With a fixed camera the light only names the outputs: the plan frames a view from it
        // that the fixed camera then replaces.
        options.light_dir = task.dir;
        options.light_pos = task.pos;
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
            BakePlan::Volume(_) => Err(BatchError::Task(crate::Error::InvalidArgument {
                name: "output".into(),
                reason: "this job writes transmittance volumes, not maps".into(),
            })),
        }
    }

    /// Check every input of the job before any task runs: the file exists and holds the job's
    /// grid (its header and grid list only). A file that is there but cannot be parsed is left
    /// to its own task, which fails alone.
    ///
    /// # Errors
    /// [`BatchError::Task`] with [`crate::Error::Io`] or [`crate::Error::GridNotFound`],
    /// naming the first input that fails.
    pub fn check_inputs(&self) -> Result<(), BatchError> {
        let mut inputs: Vec<&Path> = self.tasks.iter().map(|t| t.input.as_path()).collect();
        inputs.dedup();
        for input in inputs {
            let found = if crate::scene::is_scene_file(input) {
                crate::scene::read_box_corners(input, &self.scene_options()).map(|_| ())
            } else {
                crate::vdb::open(input).and_then(|a| a.find_grid(&self.grid).map(|_| ()))
            };
            if let Err(
                e @ (crate::Error::Io { .. }
                | crate::Error::GridNotFound { .. }
                | crate::Error::Scene { .. }),
            ) = found
            {
                return Err(e.into());
            }
        }
        Ok(())
    }

    /// How every task reads its input (grid, scale, colour, transform, level sets).
    #[must_use]
    pub fn scene_options(&self) -> crate::scene::SceneOptions {
        crate::scene::SceneOptions {
            grid: self.grid.clone(),
            density_scale: self.options.density_scale,
            sigma_t: self.options.sigma_t,
            // Checked when the job was parsed.
            xform: self.options.xform().ok().flatten(),
            levelset_solid: self.options.levelset == Some(crate::request::LevelSet::Solid),
        }
    }

    /// With `framing = "shared"` (and no fixed camera): frame one camera per sequence (one
    /// `[[inputs]]` entry) and light on the union of the sequence's volume boxes, so all maps
    /// of a light across the sequence line up. The boxes come from
    /// each file's header and topology (no voxel values; [`crate::Volume::read_box_corners`]);
    /// the camera frames all their corners together (a single input: exactly its own box). Inputs whose grid holds only its
    /// background add nothing, nor do inputs that cannot be decoded (their tasks then fail
    /// alone, as without sharing). Runs before any task, so a missing input or grid fails the
    /// whole job up front.
    ///
    /// # Errors
    /// [`BatchError::Task`] naming the input that cannot be read; [`BatchError::Invalid`]
    /// naming a light that cannot frame the union (for example a light inside it).
    pub fn share_cameras(&self) -> Result<(), BatchError> {
        if self.framing != Framing::Shared || self.camera.is_some() || self.volume {
            return Ok(());
        }
        let mut shared = std::collections::BTreeMap::new();
        let sequences = self.tasks.last().map_or(0, |t| t.sequence + 1);
        for sequence in 0..sequences {
            let tasks: Vec<&Task> = self
                .tasks
                .iter()
                .filter(|t| t.sequence == sequence)
                .collect();
            let mut inputs: Vec<&Path> = tasks.iter().map(|t| t.input.as_path()).collect();
            inputs.dedup();
            let mut union = Vec::new();
            for input in inputs {
                match crate::scene::read_box_corners(input, &self.scene_options()) {
                    Ok(c) => union.extend(c),
                    // A missing file or grid, or a malformed scene, fails the job before any
                    // task runs.
                    Err(
                        e @ (crate::Error::Io { .. }
                        | crate::Error::GridNotFound { .. }
                        | crate::Error::Scene { .. }),
                    ) => return Err(e.into()),
                    // A corrupt or unsupported frame adds nothing here and fails alone.
                    Err(_) => {}
                }
            }
            if union.is_empty() {
                continue; // nothing to frame anywhere: each task reports it
            }
            for t in tasks {
                if let std::collections::btree_map::Entry::Vacant(e) =
                    shared.entry((sequence, t.light.clone()))
                {
                    let view = self.bake_job(t, 0)?.view;
                    let camera = Camera::frame(&view, &union).map_err(|e| {
                        err(
                            &self.path,
                            &format!("lights '{}'", t.light),
                            format!("cannot frame the shared camera of inputs[{sequence}]: {e}"),
                        )
                    })?;
                    e.insert(camera);
                }
            }
        }
        // A second call finds the same cameras (same files), so a set map stays.
        let _ = self.shared.set(shared);
        Ok(())
    }

    /// [`Job::share_cameras`] through a cache file, so that the many processes of a farm job
    /// (`--task`, `--shard`) read every frame's topology once between them rather than once
    /// each. The cache (JSON: a fingerprint of everything framing depends on, and each
    /// camera's fields) is used when its fingerprint matches and it is not older than the job
    /// file or any input; otherwise the cameras are computed and the cache rewritten
    /// atomically. A cache that cannot be read or written is only a lost shortcut: the cameras
    /// are then computed as without it. Returns whether the cache was used.
    ///
    /// # Errors
    /// As [`Job::share_cameras`].
    pub fn share_cameras_cached(&self, cache: &Path) -> Result<bool, BatchError> {
        if self.framing != Framing::Shared
            || self.camera.is_some()
            || self.volume
            || self.shared.get().is_some()
        {
            return Ok(false);
        }
        let fingerprint = self.framing_fingerprint();
        if let Some(cameras) = self.read_camera_cache(cache, &fingerprint) {
            let _ = self.shared.set(cameras);
            return Ok(true);
        }
        self.share_cameras()?;
        if let Some(cameras) = self.shared.get() {
            let stored = CameraCache {
                fingerprint,
                cameras: cameras
                    .iter()
                    .map(|((sequence, light), c)| CachedCamera {
                        sequence: *sequence,
                        light: light.clone(),
                        camera: c.parts(),
                    })
                    .collect(),
            };
            if let Ok(text) = serde_json::to_string_pretty(&stored) {
                // Best effort: a farm node that cannot write beside the log still runs. The
                // job is valid by now (the cameras are framed), so its log directory may be
                // made here.
                if let Some(d) = cache.parent().filter(|d| !d.as_os_str().is_empty()) {
                    let _ = std::fs::create_dir_all(d);
                }
                let _ = crate::output::write_atomic(cache, true, |w| {
                    std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
                });
            }
        }
        Ok(false)
    }

    /// Everything the shared cameras depend on, as text.
    fn framing_fingerprint(&self) -> String {
        let tasks: Vec<_> = self
            .tasks
            .iter()
            .map(|t| (t.sequence, &t.input, &t.light, t.dir, t.pos))
            .collect();
        let o = &self.options;
        serde_json::json!({
            "version": 1,
            "grid": self.grid,
            "res": o.res,
            "fov_deg": o.fov,
            "ortho": o.ortho,
            "up": o.up,
            "frame_box": o.frame_box,
            "xform": o.xform,
            "tasks": tasks,
        })
        .to_string()
    }

    /// The cached cameras, when the cache is valid (see [`Job::share_cameras_cached`]).
    fn read_camera_cache(
        &self,
        cache: &Path,
        fingerprint: &str,
    ) -> Option<std::collections::BTreeMap<(usize, String), Camera>> {
        let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
        let at = modified(cache)?;
        let sources = std::iter::once(self.path.as_path())
            .chain(self.tasks.iter().map(|t| t.input.as_path()));
        for p in sources {
            if modified(p)? > at {
                return None;
            }
        }
        let stored: CameraCache = serde_json::from_slice(&std::fs::read(cache).ok()?).ok()?;
        if stored.fingerprint != fingerprint {
            return None;
        }
        stored
            .cameras
            .iter()
            .map(|c| {
                Some((
                    (c.sequence, c.light.clone()),
                    Camera::restore(&c.camera).ok()?,
                ))
            })
            .collect()
    }

    /// Bake one task through the shared pipeline ([`BakeJob::run`]) and write its outputs
    /// atomically (overwriting stale ones). Loads only the job's grid of the task's input.
    /// `threads` as [`BakeSettings::threads`]; `progress` receives finished pixel counts. A
    /// panic inside the bake is caught and returned with its message.
    ///
    /// # Errors
    /// [`BatchError::Task`] for any load, framing, bake or write error; [`BatchError::Panic`].
    pub fn run_task(
        &self,
        task: &Task,
        threads: usize,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<BakeReport, BatchError> {
        let job = self.bake_job(task, threads)?;
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job.run(progress)))
            .map_err(|p| BatchError::Panic(panic_message(p.as_ref())))?
            .map_err(BatchError::Task)
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
            BakePlan::Map(_) => Err(BatchError::Task(crate::Error::InvalidArgument {
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
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<crate::bake::VolumeReport, BatchError> {
        let job = self.volume_job(task, threads)?;
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job.run(progress)))
            .map_err(|p| BatchError::Panic(panic_message(p.as_ref())))?
            .map_err(BatchError::Task)
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
