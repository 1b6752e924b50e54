//! `parse_job`: a job file checked into a [`Job`] of tasks, step by step (the TOML, the grid,
//! the inputs, the lights, the tasks, the options they share). Every error names its key
//! (`bake.step`, `lights[1].dir`) and, for a value of the wrong type, its line and column.

use super::checks::{check_usd_out, normalise, EntryRead};
pub(super) use super::checks::{err, frame_list};
use super::patterns::{expand_pattern, fill_output, pattern_pad, MAX_FRAME_PAD};
use super::read::{entry_read, read_toml};
use super::schema::{InputSpec, JobFile};
use super::{BatchError, Job, Task};
use crate::input::Source;
use crate::request::{BakeOptions, BakePlan, BakeRequest};
use std::path::{Path, PathBuf};

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

/// One file of a job: its path, its frame (patterns and frames of a stage), and the index of
/// its `[[inputs]]` entry.
type Input = (Source, Option<i64>, usize);

/// Parse and validate a job file's text; `path` is the job file (relative paths in it are
/// relative to its directory). The steps: the TOML, the grid, the inputs, the lights, the
/// tasks (one per input and light), and the options every task shares, checked once as the
/// first task would run them.
///
/// # Errors
/// [`BatchError::Syntax`] (with line and column) or [`BatchError::Invalid`] naming the key.
pub fn parse_job(path: &Path, text: &str) -> Result<Job, BatchError> {
    let file = read_toml(path, text)?;
    let path = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let resolve = |s: &str| base.join(s);
    let grid = job_grid(&path, &file)?;
    if file.inputs.is_empty() {
        // A job of [[positions]] only: the keys of a light with extent go in each entry,
        // beside the light they shape.
        if let Err(crate::error::Error::InvalidArgument { name, reason }) =
            file.bake.light.refuse_extent(
                "a job of [[positions]] only (give the keys in each entry, for its light)",
            )
        {
            return Err(err(
                &path,
                &format!("bake.{}", name.replace('-', "_")),
                reason,
            ));
        }
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
    let (inputs, reads) = inputs(&path, &file, &grid, &resolve)?;
    let stage_input = inputs
        .iter()
        .find(|(s, _, _)| s.kind().is_stage())
        .map(|(s, f, _)| (s.path().to_path_buf(), *f));
    let lights = lights(&path, &file, stage_input.as_ref())?;
    check_lights(&path, &lights, stage_input.is_some())?;
    if file.bake.camera.is_some() && lights.len() > 1 {
        return Err(err(
            &path,
            "bake.camera",
            "a fixed camera is one view: give one [[lights]] entry (it names the outputs)",
        ));
    }
    if lights.len() > 1 && !output_pattern.contains("{light}") {
        return Err(err(
            &path,
            "output",
            "several lights but no {light} in the pattern: outputs would collide",
        ));
    }
    let tasks = tasks(
        &path,
        (&inputs, &reads, &lights),
        &output_pattern,
        &file.bake,
        &resolve,
    )?;
    let log = match &file.log {
        Some(l) => resolve(l),
        None => tasks[0]
            .output
            .parent()
            .map(|d| d.join("umbra_batch.jsonl"))
            .unwrap_or_else(|| PathBuf::from("umbra_batch.jsonl")),
    };
    let shared = shared_options(&path, &file.bake, &grid, &tasks, &resolve)?;
    let positions = super::positions::tasks(
        &path,
        &file.positions,
        &shared.options,
        &grid,
        tasks.len(),
        &resolve,
    )?;
    if let Some(t) = positions
        .iter()
        .find(|t| shared.usd_out.as_ref() == Some(&t.usd_out))
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
        options: shared.options,
        framing: shared.framing,
        camera: shared.camera,
        volume: shared.volume,
        usd_out: shared.usd_out,
        shared: std::sync::OnceLock::new(),
    })
}

/// The grid every task bakes: at the top level (the original place) or in `[bake]`, once.
fn job_grid(path: &Path, file: &JobFile) -> Result<String, BatchError> {
    let grid = match (&file.grid, file.bake.source.grid.as_str()) {
        (Some(g), "density") => g.clone(),
        (Some(_), _) => {
            return Err(err(
                path,
                "bake.grid",
                "the grid is given at the top level too: give it once",
            ))
        }
        (None, g) => g.to_string(),
    };
    if grid.is_empty() {
        return Err(err(path, "grid", "must not be empty"));
    }
    Ok(grid)
}

/// Every file of the `[[inputs]]` entries, in order (a pattern or a stage expanded over its
/// frames), and how each entry's tasks read their files.
fn inputs(
    path: &Path,
    file: &JobFile,
    grid: &str,
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<(Vec<Input>, Vec<EntryRead>), BatchError> {
    let mut inputs: Vec<Input> = Vec::new();
    let mut reads: Vec<EntryRead> = Vec::new();
    for (i, inp) in file.inputs.iter().enumerate() {
        let key = |k: &str| format!("inputs[{i}].{k}");
        let (read, options) = entry_read(path, &key, inp, grid, &file.bake)?;
        reads.push(read);
        // Each file the entry names, read as the entry says.
        let source = |p: PathBuf| Source::new(p, options.clone());
        match (&inp.file, &inp.pattern, &inp.usd) {
            (None, None, Some(u)) => {
                if !source(resolve(u)).kind().is_stage() {
                    return Err(err(
                        path,
                        &key("usd"),
                        format!("'{u}' is not a USD stage (.usd, .usda, .usdc, .usdz)"),
                    ));
                }
                match inp.frames {
                    None => inputs.push((source(resolve(u)), None, i)),
                    Some(frames) => {
                        for f in frame_list(path, &key, frames, inp.step)? {
                            inputs.push((source(resolve(u)), Some(f), i));
                        }
                    }
                }
            }
            (Some(f), None, None) => {
                if inp.frames.is_some() || inp.step.is_some() {
                    return Err(err(
                        path,
                        &key("frames"),
                        "frames/step go with pattern, not file",
                    ));
                }
                inputs.push((source(resolve(f)), None, i));
            }
            (None, Some(p), None) => {
                for f in pattern_frames(path, &key, inp, p)? {
                    let name = expand_pattern(p, f).unwrap_or_default();
                    inputs.push((source(resolve(&name)), Some(f), i));
                }
            }
            _ => {
                return Err(err(
                    path,
                    &format!("inputs[{i}]"),
                    "give file = \"...\", pattern = \"...\" with frames, or usd = \"...\"",
                ))
            }
        }
    }
    Ok((inputs, reads))
}

/// The frames of a pattern entry, after checking its frame token.
fn pattern_frames(
    path: &Path,
    key: &dyn Fn(&str) -> String,
    inp: &InputSpec,
    p: &str,
) -> Result<Vec<i64>, BatchError> {
    let [first, last] = inp.frames.ok_or_else(|| {
        err(
            path,
            &key("frames"),
            "a pattern needs frames = [first, last]",
        )
    })?;
    match pattern_pad(p) {
        None => {
            return Err(err(
                path,
                &key("pattern"),
                format!("'{p}' has no frame token (####, $F4 or %04d)"),
            ))
        }
        Some(n) if n > MAX_FRAME_PAD => {
            return Err(err(
                path,
                &key("pattern"),
                format!("pads frames to {n} digits; at most {MAX_FRAME_PAD}"),
            ))
        }
        Some(_) => {}
    }
    frame_list(path, key, [first, last], inp.step)
}

/// The lights: `[[lights]]` entries, or one light in `[bake]`, or (neither, with a stage
/// input) every light of the first stage at its first frame.
fn lights(
    path: &Path,
    file: &JobFile,
    stage_input: Option<&(PathBuf, Option<i64>)>,
) -> Result<Vec<JobLight>, BatchError> {
    let b = &file.bake;
    Ok(
        match (file.lights.is_empty(), b.light.light_dir, b.light.light_pos) {
            (true, None, None) => {
                match stage_input {
                    Some((stage, frame)) if b.camera.is_none() && b.source.light.is_none() => {
                        stage_lights(path, stage, *frame)?
                    }
                    Some(_) if b.source.light.is_some() => vec![JobLight {
                        name: b
                            .source
                            .light
                            .as_deref()
                            .map_or("light", |l| l.rsplit('/').next().unwrap_or(l))
                            .to_string(),
                        dir: None,
                        pos: None,
                        usd: b.source.light.clone(),
                    }],
                    _ => return Err(err(
                        path,
                        "lights",
                        "give at least one [[lights]] entry, or light_dir / light_pos in [bake]",
                    )),
                }
            }
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
                let key = if b.light.light_dir.is_some() {
                    "bake.light_dir"
                } else {
                    "bake.light_pos"
                };
                return Err(err(
                    path,
                    key,
                    "the lights are given as [[lights]] too: give them in one place",
                ));
            }
        },
    )
}

/// Each light's name (usable in a file name, used once) and how it shines (a stage light, or
/// a finite non-zero direction or a finite position).
fn check_lights(path: &Path, lights: &[JobLight], has_stage: bool) -> Result<(), BatchError> {
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
                path,
                &key("name"),
                "must be a non-empty name without slashes or control characters, not . or ..",
            ));
        }
        if !names.insert(l.name.as_str()) {
            return Err(err(
                path,
                &key("name"),
                format!("'{}' is used twice", l.name),
            ));
        }
        if l.usd.is_some() {
            if l.dir.is_some() || l.pos.is_some() {
                return Err(err(
                    path,
                    &key("usd"),
                    "a stage light shines as the stage says: give usd, or dir / pos",
                ));
            }
            if !has_stage {
                return Err(err(
                    path,
                    &key("usd"),
                    "names a light of a USD stage, but no input is one (usd = \"...\")",
                ));
            }
            continue;
        }
        match (l.dir, l.pos) {
            (None, None) => {
                return Err(err(
                    path,
                    &format!("lights[{i}]"),
                    "give dir = [x, y, z] (directional), pos = [x, y, z] (point) or usd = \
                     \"/prim/path\" (a stage light)",
                ))
            }
            (dir, pos) => {
                if let Some(d) = dir {
                    if !d.iter().all(|c| c.is_finite()) || d.iter().all(|&c| c == 0.0) {
                        return Err(err(path, &key("dir"), "must be finite and non-zero"));
                    }
                }
                if let Some(p) = pos {
                    if !p.iter().all(|c| c.is_finite()) {
                        return Err(err(path, &key("pos"), "must be finite"));
                    }
                }
            }
        }
    }
    Ok(())
}

/// One task per input and light, in that order: its output and preview named by the patterns
/// (no two tasks writing one file, no preview on its map).
fn tasks(
    path: &Path,
    (inputs, reads, lights): (&[Input], &[EntryRead], &[JobLight]),
    output_pattern: &str,
    b: &BakeOptions,
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<Vec<Task>, BatchError> {
    let mut tasks = Vec::new();
    let mut seen = std::collections::HashMap::new();
    for (source, frame, sequence) in inputs {
        let input = source.path();
        let stem = input
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        for l in lights {
            let out = fill_output(output_pattern, &l.name, &stem, *frame)
                .map_err(|e| err(path, "output", e))?;
            let output = normalise(&resolve(&out));
            let preview = match &b.preview {
                Some(p) => Some(normalise(&resolve(
                    &fill_output(&p.to_string_lossy(), &l.name, &stem, *frame)
                        .map_err(|e| err(path, "bake.preview", e))?,
                ))),
                None => None,
            };
            if preview.as_ref() == Some(&output) {
                return Err(err(path, "bake.preview", "names the same file as output"));
            }
            let index = tasks.len();
            if let Some(prev) = seen.insert(output.clone(), index) {
                return Err(err(
                    path,
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
                input: input.to_path_buf(),
                source: task_source(source, *frame, l),
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
    Ok(tasks)
}

/// What a task reads: its input as its entry reads it, toward its stage light, at its frame
/// when the input is a stage.
fn task_source(source: &Source, frame: Option<i64>, l: &JobLight) -> Source {
    let mut s = source.clone();
    let stage = s.kind().is_stage();
    let o = s.options_mut();
    o.light.clone_from(&l.usd);
    #[allow(clippy::cast_precision_loss)]
    {
        o.frame = frame.filter(|_| stage).map(|f| f as f64);
    }
    s
}

/// What every task of a job shares: `[bake]` without the per-task parts, its framing, the
/// job's one USD layer, and whether the tasks bake maps (with a fixed camera) or volumes.
struct Shared {
    options: BakeOptions,
    framing: super::Framing,
    usd_out: Option<PathBuf>,
    camera: Option<crate::bake::Camera>,
    volume: bool,
}

/// The options every task shares, checked once as the first task would run them (an error
/// names the job file's key, `bake.step`).
fn shared_options(
    path: &Path,
    b: &BakeOptions,
    grid: &str,
    tasks: &[Task],
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<Shared, BatchError> {
    let mut options = b.clone();
    options.source.grid = grid.to_string();
    options.light.light_dir = None;
    options.light.light_pos = None;
    options.source.light = None;
    options.source.frame = None;
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
        template.light.light_dir = first.dir;
        template.light.light_pos = first.pos;
        template.source.light.clone_from(&first.usd_light);
    }
    template.source.frame = first.time();
    let plan = BakeRequest {
        input: first.input.clone(),
        output: first.output.clone(),
        options: template,
    }
    .plan()
    .map_err(|e| match e {
        crate::error::Error::InvalidArgument { name, reason } => {
            let key = match name.as_str() {
                "output" => "output".to_string(),
                n => format!("bake.{}", n.replace('-', "_")),
            };
            err(path, &key, reason)
        }
        other => err(path, "bake.camera", other),
    })?;
    let (volume, camera) = match plan {
        BakePlan::Map(j) => (false, j.camera),
        BakePlan::Volume(_) => (true, None),
    };
    options.camera = None;
    if let Some(u) = &usd_out {
        check_usd_out(path, u, volume, tasks)?;
    }
    Ok(Shared {
        options,
        framing,
        usd_out,
        camera,
        volume,
    })
}
