//! `[[positions]]` entries: per-point transmittance over a shot ([`crate::points`]) as job
//! tasks, one per frame, numbered after the bake tasks so shards and `--task` split them like
//! bakes.
//!
//! Each task answers one frame and writes it atomically to `<usd_out stem>.points/<frame>.json`
//! beside the entry's layer; a task is up to date when that file is not older than the stage
//! and the `.vdb` files its volumes name at the frame. After every run each entry's `usd_out`
//! layer is rebuilt from every per-frame file on disk (this run's, earlier runs', other
//! shards'), so the last shard to finish writes the whole layer: the same text as `umbra query
//! STAGE --positions PRIM --frames A-B --usd-out LAYER` for those frames.

use super::checks::{err, frame_list};
use super::{BatchError, Job};
use crate::request::BakeOptions;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// One `[[positions]]` entry: the transmittance toward a stage light at every point of a
/// `Points` prim or `PointInstancer`, frame by frame, written as a time-sampled primvar layer.
/// Estimator keys not given are `[bake]`'s.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
// No serde `deny_unknown_fields`: the flattened map takes every other key, checked when the
// job is read (serde would refuse them before the map saw them). The schema still says no
// other key is allowed.
#[cfg_attr(feature = "schema", schemars(deny_unknown_fields))]
pub struct PositionsSpec {
    /// The USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`).
    pub usd: String,
    /// The `Points` or `PointInstancer` prim (path).
    pub prim: String,
    /// Inclusive frame range `[first, last]` (time codes, one task each; one frame:
    /// `[F, F]`); without it, the stage's start time code.
    pub frames: Option<[i64; 2]>,
    /// The `.usda` layer written: `float[] primvars:umbra:transmittance:<light>` on the prim,
    /// one time sample per frame. Per-frame answers go to `<stem>.points/<frame>.json` beside it.
    pub usd_out: String,
    /// The entry's own read and estimator keys, over `[bake]`'s: any key of the read options
    /// ([`crate::input::SourceOptions`]: `light`, the stage light (a prim path or a name; the
    /// stage's only light when not given, not `[bake]`'s), `volume`, `field`,
    /// `density_scale`, `interp`, the motion keys, ...), of the estimator options and of its
    /// parameters ([`crate::request::TraceOptions`]), each declared there once; `frame` and
    /// `xform` do not apply (`frames`; points stand in the world).
    /// The keys of a light with extent applied to the stage light (`light_angle` for a
    /// `DistantLight`, `light_radius` for a light at a position, `light_samples`) are the
    /// entry's own too, not `[bake]`'s.
    #[serde(flatten)]
    #[cfg_attr(feature = "schema", schemars(with = "EntryKeys"))]
    pub overrides: serde_json::Map<String, serde_json::Value>,
}

/// The keys of a `[[positions]]` entry besides its own (the JSON Schema's view of
/// [`PositionsSpec::overrides`]): the read and estimator keys, and the keys of a light with
/// extent for the stage light.
#[cfg(feature = "schema")]
#[derive(schemars::JsonSchema)]
#[allow(dead_code)]
struct EntryKeys {
    #[serde(flatten)]
    trace: crate::request::TraceOptions,
    /// The stage `DistantLight`'s angular diameter, degrees in [0, 180): each point's mean
    /// transmittance over the sun's disc (docs/lights.md); 0 is the point light exactly.
    light_angle: Option<f64>,
    /// A stage light at a position as a sphere light of this radius (world units).
    light_radius: Option<f64>,
    /// With light_angle or light_radius: directions per point (default 256, a multiple of 8,
    /// at most 1048576).
    light_samples: Option<u32>,
}

impl PositionsSpec {
    /// The stage light the entry names (its own `light` key).
    #[must_use]
    pub fn light(&self) -> Option<String> {
        self.overrides
            .get("light")
            .and_then(|l| l.as_str())
            .map(str::to_string)
    }
}

/// One frame of one `[[positions]]` entry.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PositionsTask {
    /// Index in the job (after every bake task).
    pub index: usize,
    /// Index of its `[[positions]]` entry.
    pub entry: usize,
    /// The USD stage.
    pub stage: PathBuf,
    /// The points prim.
    pub prim: String,
    /// The stage light asked for (`None`: the stage's only light).
    pub light: Option<String>,
    /// The frame (time code).
    pub frame: i64,
    /// The per-frame answers file.
    pub output: PathBuf,
    /// The entry's layer.
    pub usd_out: PathBuf,
    /// The estimator and read keys (the entry's, else `[bake]`'s).
    #[serde(skip)]
    pub options: BakeOptions,
}

impl PositionsTask {
    /// The light's name as logged: the given light's last path component, else `light`.
    #[must_use]
    pub fn light_name(&self) -> String {
        self.light
            .as_deref()
            .map_or("light", |l| l.rsplit('/').next().unwrap_or(l))
            .to_string()
    }

    /// How the stage is read at this task's frame.
    pub(super) fn source(&self) -> crate::input::Source {
        let mut s = crate::input::Source::new(&self.stage, self.options.source.clone());
        #[allow(clippy::cast_precision_loss)]
        {
            s.options_mut().frame = Some(self.frame as f64);
        }
        s
    }
}

/// The tasks of every `[[positions]]` entry, numbered from `first`; every key checked (errors
/// name `positions[i].key`). `b` is the job's `[bake]`, `grid` its grid, `resolve` makes a
/// job-relative path absolute.
pub(super) fn tasks(
    path: &Path,
    specs: &[PositionsSpec],
    b: &BakeOptions,
    grid: &str,
    first: usize,
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<Vec<PositionsTask>, BatchError> {
    let mut out = Vec::new();
    let mut layers = std::collections::HashMap::new();
    for (i, s) in specs.iter().enumerate() {
        let key = |k: &str| format!("positions[{i}].{k}");
        if !crate::input::Source::new(&s.usd, b.source.clone())
            .kind()
            .is_stage()
        {
            return Err(err(
                path,
                &key("usd"),
                format!("'{}' is not a USD stage (.usd, .usda, .usdc, .usdz)", s.usd),
            ));
        }
        if !s.prim.starts_with('/') {
            return Err(err(path, &key("prim"), "give the prim's path (/World/...)"));
        }
        let usd_out = resolve(&s.usd_out);
        if !crate::input::is_usda_layer(&usd_out) {
            return Err(err(
                path,
                &key("usd_out"),
                format!("{} is not a .usda layer", usd_out.display()),
            ));
        }
        if let Some(j) = layers.insert(usd_out.clone(), i) {
            return Err(err(
                path,
                &key("usd_out"),
                format!("positions[{j}] writes {} too", usd_out.display()),
            ));
        }
        let options = entry_options(path, &key, s, b, grid)?;
        let frames = match s.frames {
            Some(f) => frame_list(path, &key, f, None)?,
            None => vec![start_frame(path, &key, &resolve(&s.usd))?],
        };
        let dir = frames_dir(&usd_out);
        for f in frames {
            out.push(PositionsTask {
                index: first + out.len(),
                entry: i,
                stage: resolve(&s.usd),
                prim: s.prim.clone(),
                light: s.light(),
                frame: f,
                output: dir.join(format!("{f}.json")),
                usd_out: usd_out.clone(),
                options: options.clone(),
            });
        }
    }
    Ok(out)
}

/// A job of `[[positions]]` entries only (no `[[inputs]]`): `[bake]` gives the estimator
/// keys; its log defaults to `umbra_batch.jsonl` beside the first entry's layer.
pub(super) fn job(
    path: PathBuf,
    (bake, specs, log): (&BakeOptions, &[PositionsSpec], Option<&str>),
    grid: String,
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<Job, BatchError> {
    let mut options = bake.clone();
    if options.usd_out.is_some() {
        return Err(err(
            &path,
            "bake.usd_out",
            "puts maps on their stage lights, and this job bakes none ([[positions]] entries \
             give their own usd_out)",
        ));
    }
    options.source.grid.clone_from(&grid);
    let framing = options.framing.take().unwrap_or_default();
    options.camera = None;
    options.preview = None;
    let positions = tasks(&path, specs, &options, &grid, 0, resolve)?;
    let log = match log {
        Some(l) => resolve(l),
        None => positions
            .first()
            .and_then(|t| t.usd_out.parent())
            .map_or_else(
                || PathBuf::from("umbra_batch.jsonl"),
                |d| d.join("umbra_batch.jsonl"),
            ),
    };
    Ok(Job {
        path,
        grid,
        log,
        tasks: Vec::new(),
        positions,
        options,
        framing,
        camera: None,
        volume: false,
        usd_out: None,
        shared: std::sync::OnceLock::new(),
    })
}

/// The stage's start time code, as a whole frame.
fn start_frame(path: &Path, key: &dyn Fn(&str) -> String, stage: &Path) -> Result<i64, BatchError> {
    let t = crate::usd::lights_at(stage, None)
        .map_err(|e| err(path, &key("usd"), e))?
        .time;
    if t.fract() != 0.0 || !t.is_finite() {
        return Err(err(
            path,
            &key("frames"),
            format!("the stage starts at time {t}: give frames = [first, last]"),
        ));
    }
    #[allow(clippy::cast_possible_truncation)]
    Ok(t as i64)
}

/// The directory of an entry's per-frame files: `<stem>.points` beside its layer.
fn frames_dir(usd_out: &Path) -> PathBuf {
    let stem = usd_out
        .file_stem()
        .map_or_else(|| "points".into(), |s| s.to_string_lossy().into_owned());
    usd_out.with_file_name(format!("{stem}.points"))
}

/// `[bake]` with the entry's read and estimator keys over it, checked (errors name the
/// entry's key).
fn entry_options(
    path: &Path,
    key: &dyn Fn(&str) -> String,
    s: &PositionsSpec,
    b: &BakeOptions,
    grid: &str,
) -> Result<BakeOptions, BatchError> {
    let named = |e: crate::error::Error| match e {
        crate::error::Error::InvalidArgument { name, reason } => {
            err(path, &key(&name.replace('-', "_")), reason)
        }
        other => err(path, &key("estimator"), other),
    };
    for (k, why) in [
        (
            "frame",
            "give the frames to answer with frames = [first, last]",
        ),
        (
            "xform",
            "does not apply to points, which stand in the world",
        ),
    ] {
        if s.overrides.contains_key(k) {
            return Err(err(path, &key(k), why));
        }
    }
    // The keys of a light with extent are the entry's own, like its light; the others only
    // read and estimator keys, each of its type.
    let (extent, overrides) = extent_keys(s);
    let light: crate::light::LightOptions =
        crate::request::overlaid(&crate::light::LightOptions::default(), &extent).map_err(named)?;
    light.check_extent().map_err(|e| match e {
        crate::error::Error::Conflict { .. } => err(path, &key("light_radius"), e),
        e => named(e),
    })?;
    let keys = serde_json::Value::Object(overrides.clone()).to_string();
    crate::request::TraceOptions::from_json(&keys).map_err(named)?;
    let mut o = b.clone();
    o.source.grid = grid.to_string();
    o.source.frame = None;
    o.source.light = None;
    let mut o = o.with_overrides(&overrides).map_err(named)?;
    o.light = light;
    if !(o.source.density_scale.is_finite() && o.source.density_scale >= 0.0) {
        return Err(err(
            path,
            &key("density_scale"),
            format!("{} is not a finite scale >= 0", o.source.density_scale),
        ));
    }
    o.resolve_estimator().map_err(named)?;
    o.motion().map_err(named)?;
    Ok(o)
}

/// The keys of a light with extent of an entry (`light_angle`, `light_radius`,
/// `light_samples`: they apply to its stage light), and its other keys.
type Keys = serde_json::Map<String, serde_json::Value>;
fn extent_keys(s: &PositionsSpec) -> (Keys, Keys) {
    s.overrides
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .partition(|(k, _)| EXTENT_KEYS.contains(&k.as_str()))
}

/// The keys of a light with extent an entry takes.
const EXTENT_KEYS: [&str; 3] = ["light_angle", "light_radius", "light_samples"];

/// One frame's answers as written to disk.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct FrameFile {
    prim: String,
    #[serde(rename = "type")]
    type_name: String,
    light: String,
    light_name: String,
    estimator: String,
    frame: f64,
    #[serde(rename = "T")]
    transmittance: Vec<f64>,
    std_err: Vec<f64>,
    positions: Vec<[f64; 3]>,
    /// Toward a light with extent: directions per sampled point.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    light_samples: Option<u32>,
    /// Toward a light with extent: the points sampled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sampled: Option<usize>,
    /// The task's key ([`super::TaskKey`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    key: Option<super::TaskKey>,
}

impl Job {
    /// Every task index of the job: bakes, then positions.
    #[must_use]
    pub fn task_count(&self) -> usize {
        self.tasks.len() + self.positions.len()
    }

    /// The files a positions task's answers depend on: the stage and the `.vdb` files its
    /// volumes name at the frame. `None` when they cannot be listed.
    #[must_use]
    pub fn positions_sources(&self, t: &PositionsTask) -> Option<Vec<PathBuf>> {
        t.source().files().ok()
    }

    /// Whether a positions task's per-frame file exists and carries the task's key now
    /// ([`Job::positions_freshness`] with the default [`super::KeyCheck`]).
    #[must_use]
    pub fn positions_up_to_date(&self, t: &PositionsTask) -> bool {
        self.positions_freshness(t, super::KeyCheck::default())
            .stale
            .is_none()
    }

    /// Check every `[[positions]]` entry as its first frame would run: the stage has the
    /// prim (a `Points` or `PointInstancer`) and the light.
    ///
    /// # Errors
    /// [`BatchError::Invalid`] naming `positions[i]` and why.
    pub fn check_positions(&self) -> Result<(), BatchError> {
        let mut seen = std::collections::HashSet::new();
        for t in self.positions.iter().filter(|t| seen.insert(t.entry)) {
            #[allow(clippy::cast_precision_loss)]
            let time = Some(t.frame as f64);
            let key = format!("positions[{}]", t.entry);
            crate::usd::points_at(&t.stage, &t.prim, time).map_err(|e| err(&self.path, &key, e))?;
            let shot =
                crate::usd::lights_at(&t.stage, time).map_err(|e| err(&self.path, &key, e))?;
            let (_, emitter) = shot
                .light(t.light.as_deref())
                .map_err(|e| err(&self.path, &key, e))?;
            // The flags: an angle for a distant light, a radius for a light at a position.
            if let Err(crate::error::Error::InvalidArgument { name, reason }) =
                t.options.light.soft_of_stage(emitter)
            {
                let k = format!("{key}.{}", name.replace('-', "_"));
                return Err(err(&self.path, &k, reason));
            }
        }
        Ok(())
    }

    /// Answer one positions task (one frame) and write its per-frame file atomically, with
    /// `key` (its [`super::TaskKey`], [`Job::positions_freshness`]); how many points it
    /// answered.
    ///
    /// # Errors
    /// [`BatchError::Task`] for any error reading the stage, estimating or writing.
    pub fn run_positions_task(
        &self,
        t: &PositionsTask,
        key: Option<&super::TaskKey>,
    ) -> Result<usize, BatchError> {
        #[allow(clippy::cast_precision_loss)]
        let frame = t.frame as f64;
        let o = &t.options;
        let mut source = t.source();
        source.options_mut().light.clone_from(&t.light);
        source.options_mut().frame = None;
        let request = crate::request::QueryRequest {
            positions: Some(t.prim.clone()),
            frames: Some(vec![frame]),
            light: o.light.clone(),
            estimator: o.estimator.clone(),
            params: o.params.clone(),
            // Tasks run one after another, each on every core.
            threads: 0,
            ..crate::request::QueryRequest::new(source)
        };
        let outcome = request.run(&mut |_| {}).map_err(|e| e.error)?;
        let crate::request::QueryOutcome::Points(p) = outcome else {
            return Ok(0);
        };
        let (answers, estimator) = (p.answers, p.estimator);
        let Some(f) = answers.frames.into_iter().next() else {
            return Ok(0);
        };
        let n = f.transmittance.len();
        let file = FrameFile {
            prim: answers.prim,
            type_name: answers.type_name,
            light: answers.light,
            light_name: answers.light_name,
            estimator,
            frame: f.frame,
            transmittance: f.transmittance,
            std_err: f.std_err,
            positions: f.positions,
            light_samples: answers.light_samples,
            sampled: f.sampled,
            key: key.cloned(),
        };
        if let Some(d) = t.output.parent() {
            std::fs::create_dir_all(d).map_err(|e| crate::error::Error::Io {
                path: d.to_path_buf(),
                err: e,
            })?;
        }
        crate::output::write_atomic(&t.output, true, |w| {
            serde_json::to_writer(w, &file).map_err(|e| e.to_string())
        })?;
        Ok(n)
    }

    /// Rebuild every `[[positions]]` entry's layer from the per-frame files on disk (in frame
    /// order); each layer written and how many frames it holds. An entry with no file yet is
    /// left alone.
    ///
    /// # Errors
    /// A per-frame file that cannot be read or parsed (naming it), or a layer that cannot be
    /// written.
    pub fn write_positions_layers(&self) -> Result<Vec<(PathBuf, usize)>, BatchError> {
        let mut out = Vec::new();
        let entries: std::collections::BTreeSet<usize> =
            self.positions.iter().map(|t| t.entry).collect();
        for e in entries {
            let mut answers: Option<crate::points::PointAnswers> = None;
            let mut layer = PathBuf::new();
            for t in self.positions.iter().filter(|t| t.entry == e) {
                layer.clone_from(&t.usd_out);
                if !t.output.is_file() {
                    continue;
                }
                let f = read_frame(&t.output)?;
                let all = answers.get_or_insert_with(|| crate::points::PointAnswers {
                    prim: f.prim.clone(),
                    type_name: f.type_name.clone(),
                    light: f.light.clone(),
                    light_name: f.light_name.clone(),
                    frames: Vec::new(),
                    warnings: Vec::new(),
                    light_samples: f.light_samples,
                });
                all.frames.push(crate::points::PointFrame {
                    frame: f.frame,
                    positions: f.positions,
                    transmittance: f.transmittance,
                    std_err: f.std_err,
                    sampled: f.sampled,
                });
            }
            let Some(mut answers) = answers else { continue };
            answers.frames.sort_by(|a, b| a.frame.total_cmp(&b.frame));
            let text = crate::points::layer_text(&answers)?;
            crate::output::write_atomic(&layer, true, |w| {
                std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
            })?;
            out.push((layer, answers.frames.len()));
        }
        Ok(out)
    }
}

fn read_frame(p: &Path) -> Result<FrameFile, BatchError> {
    let text = std::fs::read_to_string(p).map_err(|e| crate::error::Error::Io {
        path: p.to_path_buf(),
        err: e,
    })?;
    serde_json::from_str(&text).map_err(|e| {
        BatchError::Task(crate::error::Error::InvalidArgument {
            name: p.display().to_string(),
            reason: format!("not a per-frame answers file: {e}"),
        })
    })
}

/// Positions tasks' keys ([`super::TaskKey`]).
impl Job {
    /// The key of positions task `t` now: its options, stage, prim, light and frame, and the
    /// files it reads.
    ///
    /// # Errors
    /// As [`Job::task_key`].
    pub fn positions_key(
        &self,
        t: &PositionsTask,
        recorded: Option<&super::TaskKey>,
        check: super::KeyCheck,
    ) -> Result<super::TaskKey, BatchError> {
        let mut m = super::key::canonical(&t.options);
        m.insert(
            "stage".into(),
            serde_json::Value::from(t.stage.display().to_string()),
        );
        m.insert("prim".into(), serde_json::Value::from(t.prim.clone()));
        m.insert(
            "light".into(),
            t.light
                .clone()
                .map_or(serde_json::Value::Null, serde_json::Value::from),
        );
        m.insert("frame".into(), serde_json::Value::from(t.frame));
        let files = t.source().files()?;
        Ok(super::TaskKey {
            format: format!("points/{}", super::FORMAT_VERSION),
            request: m,
            camera: None,
            files: super::key::identify(&files, recorded, check)?,
        })
    }

    /// [`Job::freshness`] of positions task `t`.
    #[must_use]
    pub fn positions_freshness(
        &self,
        t: &PositionsTask,
        check: super::KeyCheck,
    ) -> super::Freshness {
        let stored = super::Stored::read(&t.output);
        let now = self
            .positions_key(t, stored.key(), check)
            .map_err(|e| e.to_string());
        let base = super::key::canonical(&self.options);
        super::key::compare(&stored, now, check, &|k| {
            if super::key::LIGHT_KEYS.contains(&k) {
                return super::Change::Light(t.light_name());
            }
            let mine = super::key::canonical(&t.options);
            let name = if mine.get(k) != base.get(k) || matches!(k, "stage" | "prim") {
                format!("positions[{}].{k}", t.entry)
            } else if k == "frame" {
                "frame".into()
            } else {
                format!("bake.{k}")
            };
            super::Change::Settings(vec![name])
        })
    }
}
