//! The job file: its types as written (`JobFile`, `[[inputs]]`, `[[lights]]`, `[bake]` as the
//! one [`BakeOptions`] type), their JSON Schema, and `parse_job`, which checks a job file into
//! a [`Job`] of tasks: every error names its key (`bake.step`, `lights[1].dir`) and, for a
//! value of the wrong type, its line and column.

use super::checks::{check_usd_out, key_at, normalise, EntryRead};
pub(super) use super::checks::{err, frame_list};
use super::patterns::{expand_pattern, fill_output, pattern_pad, MAX_FRAME_PAD};
use super::{BatchError, Job, Task};
use crate::input::InputKind;
use crate::request::{BakeOptions, BakePlan, BakeRequest, LevelSet};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// The job file as written. Its JSON Schema ([`job_schema`], `umbra batch --schema`) is
/// generated from this type.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    /// Grid to bake in every input (default `density`; or `grid` in `[bake]`).
    pub grid: Option<String>,
    /// Output path pattern: `{light}`, `{stem}`, `{frame}`, `{frame:0N}`; ending in `.vdb`,
    /// transmittance volumes, else EXR maps. Required with `[[inputs]]`.
    pub output: Option<String>,
    /// JSON-lines log (default: `umbra_batch.jsonl` in the first output's directory).
    pub log: Option<String>,
    /// Inputs, in order (none for a job of `[[positions]]` only).
    #[serde(default)]
    pub inputs: Vec<InputSpec>,
    /// Per-point transmittance over a shot, one task per frame after the bakes.
    #[serde(default)]
    pub positions: Vec<super::positions::PositionsSpec>,
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
    /// A USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`): its volumes at every frame of `frames`
    /// (time codes; without `frames`, its start time code).
    pub usd: Option<String>,
    /// The grid to bake in this entry's files (default: the job's `grid`): a liquid's `phi`
    /// beside a smoke's `density` in one job.
    pub grid: Option<String>,
    /// `density_scale` for this entry's files (default: `[bake]`'s).
    pub density_scale: Option<f64>,
    /// `levelset` for this entry's files (default: `[bake]`'s): `solid` traces its grid as
    /// an opaque occluder.
    pub levelset: Option<LevelSet>,
    /// `xform` for this entry's files (default: `[bake]`'s): 16 numbers, row-major.
    pub xform: Option<Vec<f64>>,
}

/// One `[[lights]]` entry.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Name used by `{light}` (default for a `usd` light: the prim's name).
    pub name: Option<String>,
    /// Direction the light travels (directional light, orthographic map; with `pos`, where a
    /// perspective map from the light looks), as `umbra bake --light-dir`.
    pub dir: Option<[f64; 3]>,
    /// Light position (point light, perspective map), as `umbra bake --light-pos`.
    pub pos: Option<[f64; 3]>,
    /// A UsdLux light of the job's USD stage inputs, by prim path (as `umbra bake --light`),
    /// read at each task's frame.
    pub usd: Option<String>,
}

/// A light of a job, resolved: its name, and how it shines.
#[derive(Debug, Clone)]
struct JobLight {
    name: String,
    dir: Option<[f64; 3]>,
    pos: Option<[f64; 3]>,
    usd: Option<String>,
}

/// Every light umbra traces of the first USD stage input at its first frame: a job of stage
/// inputs without `[[lights]]`.
fn stage_lights(
    path: &Path,
    stage: &Path,
    frame: Option<i64>,
) -> Result<Vec<JobLight>, BatchError> {
    #[allow(clippy::cast_precision_loss)]
    let shot = crate::usd::lights_at(stage, frame.map(|f| f as f64))
        .map_err(|e| err(path, "inputs", e))?;
    let lights: Vec<JobLight> = shot
        .lights
        .iter()
        .filter(|l| l.emitter.is_some())
        .map(|l| JobLight {
            name: l.name().to_string(),
            dir: None,
            pos: None,
            usd: Some(l.prim.clone()),
        })
        .collect();
    if lights.is_empty() {
        return Err(err(
            path,
            "lights",
            format!(
                "{} has no light umbra traces: give [[lights]] entries",
                stage.display()
            ),
        ));
    }
    Ok(lights)
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
    if file.inputs.is_empty() {
        if file.positions.is_empty() {
            return Err(err(
                &path,
                "inputs",
                "give at least one [[inputs]] or [[positions]] entry",
            ));
        }
        return super::positions::job(
            path,
            (&file.bake, &file.positions, file.log.as_deref()),
            grid,
            &resolve,
        );
    }
    let Some(output_pattern) = file.output.clone() else {
        return Err(err(
            &path,
            "output",
            "give an output pattern for [[inputs]]",
        ));
    };
    // (file, frame, index of its [[inputs]] entry)
    let mut inputs: Vec<(PathBuf, Option<i64>, usize)> = Vec::new();
    let mut reads: Vec<EntryRead> = Vec::new();
    for (i, inp) in file.inputs.iter().enumerate() {
        let key = |k: &str| format!("inputs[{i}].{k}");
        reads.push(entry_read(&path, &key, inp, &grid, b)?);
        match (&inp.file, &inp.pattern, &inp.usd) {
            (None, None, Some(u)) => {
                if !InputKind::of(Path::new(u)).is_stage() {
                    return Err(err(
                        &path,
                        &key("usd"),
                        format!("'{u}' is not a USD stage (.usd, .usda, .usdc, .usdz)"),
                    ));
                }
                match inp.frames {
                    None => inputs.push((resolve(u), None, i)),
                    Some(frames) => {
                        for f in frame_list(&path, &key, frames, inp.step)? {
                            inputs.push((resolve(u), Some(f), i));
                        }
                    }
                }
            }
            (Some(f), None, None) => {
                if inp.frames.is_some() || inp.step.is_some() {
                    return Err(err(
                        &path,
                        &key("frames"),
                        "frames/step go with pattern, not file",
                    ));
                }
                inputs.push((resolve(f), None, i));
            }
            (None, Some(p), None) => {
                let [first, last] = inp.frames.ok_or_else(|| {
                    err(
                        &path,
                        &key("frames"),
                        "a pattern needs frames = [first, last]",
                    )
                })?;
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
                for f in frame_list(&path, &key, [first, last], inp.step)? {
                    let name = expand_pattern(p, f).unwrap_or_default();
                    inputs.push((resolve(&name), Some(f), i));
                }
            }
            _ => {
                return Err(err(
                    &path,
                    &format!("inputs[{i}]"),
                    "give file = \"...\", pattern = \"...\" with frames, or usd = \"...\"",
                ))
            }
        }
    }
    // The lights: [[lights]] entries, or one light in [bake].
    let stage_input = inputs
        .iter()
        .find(|(p, _, _)| InputKind::of(p).is_stage())
        .map(|(p, f, _)| (p.clone(), *f));
    let lights = match (file.lights.is_empty(), b.light_dir, b.light_pos) {
        (true, None, None) => match &stage_input {
            Some((stage, frame)) if b.camera.is_none() && b.light.is_none() => {
                stage_lights(&path, stage, *frame)?
            }
            Some(_) if b.light.is_some() => vec![JobLight {
                name: b
                    .light
                    .as_deref()
                    .map_or("light", |l| l.rsplit('/').next().unwrap_or(l))
                    .to_string(),
                dir: None,
                pos: None,
                usd: b.light.clone(),
            }],
            _ => {
                return Err(err(
                    &path,
                    "lights",
                    "give at least one [[lights]] entry, or light_dir / light_pos in [bake]",
                ))
            }
        },
        (true, dir, pos) => vec![JobLight {
            name: "light".into(),
            dir,
            pos,
            usd: None,
        }],
        (false, None, None) => file
            .lights
            .iter()
            .map(|l| JobLight {
                name: l.name.clone().unwrap_or_else(|| {
                    l.usd
                        .as_deref()
                        .map(|u| u.rsplit('/').next().unwrap_or(u).to_string())
                        .unwrap_or_default()
                }),
                dir: l.dir,
                pos: l.pos,
                usd: l.usd.clone(),
            })
            .collect(),
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
        if l.usd.is_some() {
            if l.dir.is_some() || l.pos.is_some() {
                return Err(err(
                    &path,
                    &key("usd"),
                    "a stage light shines as the stage says: give usd, or dir / pos",
                ));
            }
            if stage_input.is_none() {
                return Err(err(
                    &path,
                    &key("usd"),
                    "names a light of a USD stage, but no input is one (usd = \"...\")",
                ));
            }
            continue;
        }
        match (l.dir, l.pos) {
            (None, None) => {
                return Err(err(
                    &path,
                    &format!("lights[{i}]"),
                    "give dir = [x, y, z] (directional), pos = [x, y, z] (point) or usd = \
                     \"/prim/path\" (a stage light)",
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
    if lights.len() > 1 && !output_pattern.contains("{light}") {
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
            let out = fill_output(&output_pattern, &l.name, &stem, *frame)
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
            let read = &reads[*sequence];
            tasks.push(Task {
                index,
                sequence: *sequence,
                input: input.clone(),
                grid: read.grid.clone(),
                density_scale: read.density_scale,
                levelset: read.levelset,
                xform: read.xform.clone(),
                frame: *frame,
                light: l.name.clone(),
                dir: l.dir,
                pos: l.pos,
                usd_light: l.usd.clone(),
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
    options.light = None;
    options.frame = None;
    options.preview = None;
    let framing = options.framing.take().unwrap_or_default();
    // One layer for the whole job, written by the runner: no task writes its own.
    let usd_out = options
        .usd_out
        .take()
        .map(|u| resolve(&u.to_string_lossy()));
    if let Some(crate::request::CameraSource::File(c)) = &mut options.camera {
        *c = resolve(&c.to_string_lossy());
    }
    let first = &tasks[0];
    let mut template = options.clone();
    first.read_into(&mut template);
    template.preview.clone_from(&first.preview);
    if template.camera.is_none() {
        template.light_dir = first.dir;
        template.light_pos = first.pos;
        template.light.clone_from(&first.usd_light);
    }
    template.frame = first.time();
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
    if let Some(u) = &usd_out {
        check_usd_out(&path, u, volume, &tasks)?;
    }
    let positions = super::positions::tasks(
        &path,
        &file.positions,
        &options,
        &grid,
        tasks.len(),
        &resolve,
    )?;
    if let Some(t) = positions
        .iter()
        .find(|t| usd_out.as_ref() == Some(&t.usd_out))
    {
        return Err(err(
            &path,
            &format!("positions[{}].usd_out", t.entry),
            "is bake.usd_out's layer too: give each its own",
        ));
    }
    Ok(Job {
        path,
        grid,
        log,
        tasks,
        positions,
        options,
        framing,
        camera,
        volume,
        usd_out,
        shared: std::sync::OnceLock::new(),
    })
}

/// How the tasks of `[[inputs]]` entry `inp` read their files: its `grid`, `density_scale`,
/// `levelset` and `xform`, each checked as `[bake]`'s are, else the job's (`grid`, `b`).
pub(super) fn entry_read(
    path: &Path,
    key: &dyn Fn(&str) -> String,
    inp: &InputSpec,
    grid: &str,
    b: &BakeOptions,
) -> Result<EntryRead, BatchError> {
    if inp.grid.as_deref() == Some("") {
        return Err(err(path, &key("grid"), "must not be empty"));
    }
    if let Some(s) = inp.density_scale {
        if !(s.is_finite() && s >= 0.0) {
            return Err(err(
                path,
                &key("density_scale"),
                format!("{s} is not a finite scale >= 0"),
            ));
        }
    }
    if let Some(x) = &inp.xform {
        crate::xform::Xform::from_row_major(x).map_err(|e| {
            let reason = match e {
                crate::Error::InvalidArgument { reason, .. } => reason,
                other => other.to_string(),
            };
            err(path, &key("xform"), reason)
        })?;
    }
    Ok(EntryRead {
        grid: inp.grid.clone().unwrap_or_else(|| grid.to_string()),
        density_scale: inp.density_scale.unwrap_or(b.density_scale),
        levelset: inp.levelset.or(b.levelset),
        xform: inp.xform.clone().or_else(|| b.xform.clone()),
    })
}
