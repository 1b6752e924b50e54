//! Loading a scene: a `.vdb` file (one grid) or a `.toml` scene file.
//!
//! A scene file holds one or more `[[volume]]` tables:
//!
//! ```toml
//! [[volume]]
//! file = "cloud.vdb"            # relative to the scene file's directory
//! grid = "density"              # or: grids = ["density", "flame"], weights = [1.0, 0.5]
//! density_scale = 2.0           # default 1
//! sigma_t = [0.9, 1.0, 1.2]     # per channel (an RGB scene), or one number (grey); default 1
//! xform = [1,0,0,5, 0,1,0,0, 0,0,1,0, 0,0,0,1]   # world-from-object, row-major
//! kind = "fog"                  # or "solid": a level set traced as an opaque occluder
//! ```
//!
//! A fog volume's extinction is `mu_c = density_scale x sigma_t[c] x sum_g weight_g value_g`:
//! each weighted grid is its own volume with scale `density_scale x weight_g` (the sum is
//! exact, and each grid keeps its own tree and bounds). Options given with the scene
//! ([`SceneOptions`], the command line's `--density-scale`, `--sigma-t`, `--xform`) apply on top
//! of every volume's own: scales and colours multiply, the transform is applied after the
//! volume's (`world = X_scene X_volume object`). Only the grids the scene names are decoded.

use super::{check_sigma, Fog, Scene};
use crate::error::{Error, Result};
use crate::input::InputKind;
use crate::solid::Solid;
use crate::volume::Volume;
use crate::xform::Xform;
use glam::DVec3;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// How to read a scene, and what applies on top of it: a [`Source`]'s read options, checked
/// ([`SceneOptions::of`]).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SceneOptions {
    /// What kind of input the path is (the source's).
    pub kind: InputKind,
    /// Grid of a `.vdb` input (ignored by scene files, which name their grids).
    pub grid: String,
    /// Multiplies every volume's density scale.
    pub density_scale: f64,
    /// Multiplies every volume's extinction colour; makes the scene RGB.
    pub sigma_t: Option<[f64; 3]>,
    /// Applied after every volume's own transform.
    pub xform: Option<Xform>,
    /// A level-set grid of a `.vdb` input is traced as an opaque solid (`--levelset solid`)
    /// instead of being refused.
    pub levelset_solid: bool,
    /// What to read of a USD stage input (time code, volumes, field); ignored otherwise.
    pub stage: crate::usd::Selection,
    /// Motion blur: every fog volume blurred by the velocity grid of this name in its own file
    /// (`crate::motion`); such inputs are loaded whole.
    pub motion: Option<crate::motion::MotionRequest>,
}

/// Blur `vol` by motion `m`, its velocity grid read from `file` (or the request's own file):
/// the one place a volume is set moving.
///
/// # Errors
/// As [`crate::motion::MotionRequest::field`] and [`Volume::with_motion`].
pub(crate) fn blurred(
    vol: Volume,
    m: &crate::motion::MotionRequest,
    file: &Path,
) -> Result<Volume> {
    vol.with_motion(m.spec, m.field(file)?)
}

/// Load the scene at `path`: a scene file (`.toml`), a USD stage (`.usd`, `.usda`, `.usdc`,
/// `.usdz`: its volumes at `opts.stage`'s time code, [`crate::usd`]) or one grid of a `.vdb`
/// file.
///
/// # Errors
/// Every loading error of the files it names ([`Volume::load`], [`Solid::load`]), and
/// [`Error::Scene`] naming the scene file and the `[[volume]]` entry for a malformed scene.
pub(crate) fn load(path: impl AsRef<Path>, opts: &SceneOptions) -> Result<Scene> {
    let path = path.as_ref();
    crate::volume::check_density_scale(opts.density_scale)?;
    if let Some(s) = opts.sigma_t {
        check_sigma(s)?;
    }
    if !opts.kind.is_grid_file() {
        return load_file(path, opts);
    }
    let grid = crate::input::load_grid(path, &opts.grid)?;
    scene_of_grid(grid, path, opts)
}

/// [`load`] for a job whose rays are known before it traces: a `.vdb` input with at least
/// `lazy_from` bytes of leaf data (0: any; [`LAZY_MIN_BYTES`]: what `umbra query` does by
/// default) is opened lazily ([`crate::input::GridFile::lazy`]), `rays` makes the job's rays from a
/// shell scene (topology and boxes right, values unloaded: tracing it gives no number), and
/// only the leaves those rays touch under `interp` at `gran` are decoded
/// ([`crate::demand::leaves_touched`]). Answers on those rays equal an eager [`load`]'s bit for
/// bit. Scene files, level sets traced as solids and smaller grids are loaded whole. A caller
/// whose rays cannot be made keeps its own error and returns no rays (nothing is then decoded).
///
/// # Errors
/// As [`load`], and decoding errors of the touched leaves (naming the file, the leaf and the
/// byte offset of its buffer).
pub(crate) fn load_for_rays(
    path: impl AsRef<Path>,
    opts: &SceneOptions,
    interp: crate::volume::Interp,
    gran: crate::traverse::Granularity,
    lazy_from: u64,
    rays: impl FnOnce(&Scene) -> Vec<crate::ray::Ray>,
) -> Result<(Scene, Vec<crate::ray::Ray>)> {
    let path = path.as_ref();
    crate::volume::check_density_scale(opts.density_scale)?;
    if let Some(s) = opts.sigma_t {
        check_sigma(s)?;
    }
    if !opts.kind.is_grid_file() {
        let scene = load_file(path, opts)?;
        let r = rays(&scene);
        return Ok((scene, r));
    }
    let file = crate::input::GridFile::open(path)?;
    let lazy = match opts.motion {
        // The velocity moves density anywhere its reach allows: load whole.
        Some(_) => None,
        None => file.lazy(&opts.grid)?,
    };
    let Some(lazy) = lazy else {
        // A format without partial reads loads whole.
        let scene = scene_of_grid(file.load(&opts.grid)?, path, opts)?;
        let r = rays(&scene);
        return Ok((scene, r));
    };
    let solid = opts.levelset_solid && lazy.shell().class.as_deref() == Some("level set");
    // A small grid decodes faster whole than its rays can be planned: the same answers.
    if solid || lazy.buffer_bytes() < lazy_from {
        let scene = scene_of_grid(lazy.load_all()?, path, opts)?;
        let r = rays(&scene);
        return Ok((scene, r));
    }
    let shell = scene_of_grid(lazy.shell().clone(), path, opts)?;
    let r = rays(&shell);
    let leaves = match shell.fogs().first() {
        Some(f) => crate::demand::leaves_touched(f.volume(), &r, interp, gran),
        None => Vec::new(),
    };
    drop(shell);
    let scene = scene_of_grid(lazy.into_partial(&leaves)?, path, opts)?;
    Ok((scene, r))
}

/// Grids with fewer bytes of leaf buffers than this are loaded whole by `umbra query`
/// ([`load_for_rays`]): below it a whole decode costs about 0.05 s on 2 cores (the 0.96 GB
/// hero cache decodes in 2.9 s), no more than planning a batch of rays does (20 000 rays
/// through the 0.5 MB sample cloud: 0.07 s planned, 0.05 s whole).
pub const LAZY_MIN_BYTES: u64 = 16 << 20;

/// The scene of one grid of a `.vdb` file, with `opts` applied.
fn scene_of_grid(grid: crate::input::Grid, path: &Path, opts: &SceneOptions) -> Result<Scene> {
    let rgb = opts.sigma_t.is_some();
    let (mut fogs, mut solids) = (Vec::new(), Vec::new());
    if opts.levelset_solid && grid.class.as_deref() == Some("level set") {
        let mut s = Solid::new(grid, path)?;
        if let Some(x) = &opts.xform {
            s = s.with_xform(x)?;
        }
        solids.push(s);
    } else {
        let mut v = Volume::new(grid, opts.density_scale, path)?;
        if let Some(x) = &opts.xform {
            v = v.with_xform(x)?;
        }
        if let Some(m) = &opts.motion {
            v = blurred(v, m, path)?;
        }
        fogs.push(Fog::new(v, opts.sigma_t.unwrap_or([1.0; 3]))?);
    }
    Scene::new(fogs, solids, rgb)
}

/// `sigma_t` in a scene file: one number (grey) or three (RGB).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(untagged)]
enum SigmaSpec {
    Grey(f64),
    Rgb([f64; 3]),
}

/// One `[[volume]]` table.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct VolumeSpec {
    file: String,
    grid: Option<String>,
    grids: Option<Vec<String>>,
    weights: Option<Vec<f64>>,
    density_scale: Option<f64>,
    sigma_t: Option<SigmaSpec>,
    xform: Option<Vec<f64>>,
    kind: Option<String>,
}

/// The scene file as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    volume: Vec<VolumeSpec>,
}

fn scene_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Scene {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// One grid of a scene file, resolved: where it is, how it is scaled, coloured and placed.
#[derive(Debug, Clone)]
struct Entry {
    file: crate::usd::Asset,
    grid: String,
    solid: bool,
    /// Full density scale (scene option x volume x weight).
    scale: f64,
    sigma: [f64; 3],
    /// Volume transform, then the scene option's.
    xform: Option<Xform>,
    /// `volume[i] (file)` (a stage: `at time t: /prim (file)`), for messages.
    at: String,
    /// A stage volume's velocity field (asset and grid), when motion blur asked for it.
    velocity: Option<(crate::usd::Asset, String)>,
    /// A stage's `timeCodesPerSecond`, for a shutter given without fps.
    fps: Option<f64>,
}

/// The grids of a USD stage at the selection's time code, with `opts` applied on top.
fn stage_entries(path: &Path, opts: &SceneOptions) -> Result<(Vec<Entry>, bool)> {
    // Motion blur names each volume's velocity field (`field:<velocity>`).
    let sel = crate::usd::Selection {
        velocity: opts.motion.as_ref().map(|m| m.velocity.clone()),
        ..opts.stage.clone()
    };
    let shot = crate::usd::read(path, &sel)?;
    let mut rgb = opts.sigma_t.is_some();
    let tint = opts.sigma_t.unwrap_or([1.0; 3]);
    let mut entries = Vec::new();
    for v in shot.volumes {
        let at = format!("at time {}: {} ({})", shot.time, v.prim, v.asset.display());
        let here = |what: &str, e: Error| scene_err(path, format!("{at}: {what}{}", reason(e)));
        let xform = match &opts.xform {
            Some(b) => Xform::new(compose(&b.rows(), &v.xform.rows()))
                .map_err(|e| here("its transform with xform: ", e))?,
            None => v.xform,
        };
        crate::volume::check_density_scale(v.density_scale)
            .map_err(|e| here("umbra:densityScale: ", e))?;
        let sigma = v.sigma_t.unwrap_or([1.0; 3]);
        check_sigma(sigma).map_err(|e| here("umbra:sigmaT: ", e))?;
        rgb |= v.rgb;
        entries.push(Entry {
            file: v.asset,
            grid: v.grid,
            solid: v.solid,
            scale: opts.density_scale * v.density_scale,
            sigma: std::array::from_fn(|c| sigma[c] * tint[c]),
            xform: Some(xform),
            at,
            velocity: v.velocity,
            fps: Some(shot.fps),
        });
    }
    if entries.iter().filter(|e| !e.solid).count() > super::MAX_VOLUMES {
        return Err(scene_err(
            path,
            format!("more than {} fog volumes", super::MAX_VOLUMES),
        ));
    }
    Ok((entries, rgb))
}

/// The files a load of `path` reads: the file itself and, for a scene file or a USD stage, the
/// `.vdb` files (or `.usdz` packages) its volumes name at the selection's time code. A baked
/// output older than any of them is stale.
///
/// # Errors
/// As reading the scene file or the stage.
pub(crate) fn sources(path: &Path, opts: &SceneOptions) -> Result<Vec<PathBuf>> {
    let mut out = vec![path.to_path_buf()];
    if !opts.kind.is_grid_file() {
        for e in entries(path, opts)?.0 {
            out.push(match e.file {
                crate::usd::Asset::File(p) => p,
                crate::usd::Asset::Packaged { package, .. } => package,
            });
        }
    }
    out.dedup();
    Ok(out)
}

/// The grids of a scene file or a USD stage.
fn entries(path: &Path, opts: &SceneOptions) -> Result<(Vec<Entry>, bool)> {
    if opts.kind.is_stage() {
        stage_entries(path, opts)
    } else {
        parse(path, opts)
    }
}

/// An error loading a stage's asset, naming the stage, the time, the prim and the asset (not
/// the scratch copy a packaged member is read from).
fn asset_err(path: &Path, stage: bool, e: &Entry, opened: &Path, err: Error) -> Error {
    if !stage {
        return err;
    }
    let msg = err
        .to_string()
        .replace(&opened.display().to_string(), &e.file.display());
    scene_err(path, format!("{}: {msg}", e.at))
}

/// A scene file's TOML; a syntax or type error names its line.
fn read_scene_file(path: &Path) -> Result<SceneFile> {
    let text = std::fs::read_to_string(path).map_err(|err| Error::Io {
        path: path.to_path_buf(),
        err,
    })?;
    toml::from_str(&text).map_err(|e| {
        let msg = e.message().to_string();
        match e.span() {
            Some(span) => {
                let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
                scene_err(path, format!("line {line}: {msg}"))
            }
            None => scene_err(path, msg),
        }
    })
}

/// A fog volume's grids and their weights (`grid`, or `grids` with as many finite,
/// non-negative `weights`; `density` when neither is given). `here` words an error at the
/// volume.
fn fog_grids(
    v: &VolumeSpec,
    here: &dyn Fn(&str, String) -> Error,
) -> Result<(Vec<String>, Vec<f64>)> {
    let grids = match (&v.grid, &v.grids) {
        (Some(_), Some(_)) => return Err(here("", "give 'grid' or 'grids', not both".into())),
        (Some(g), None) => vec![g.clone()],
        (None, Some(g)) if g.is_empty() => return Err(here("grids: ", "an empty list".into())),
        (None, Some(g)) => g.clone(),
        (None, None) => vec!["density".into()],
    };
    let weights = match &v.weights {
        None => vec![1.0; grids.len()],
        Some(w) if v.grids.is_none() => {
            return Err(here(
                "weights: ",
                format!("{w:?} given with 'grid'; weights go with 'grids'"),
            ))
        }
        Some(w) if w.len() != grids.len() => {
            return Err(here(
                "weights: ",
                format!("{} weights for {} grids", w.len(), grids.len()),
            ))
        }
        Some(w) => w.clone(),
    };
    if let Some(w) = weights.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
        return Err(here(
            "weights: ",
            format!("{w} is not a finite, non-negative number"),
        ));
    }
    Ok((grids, weights))
}

/// Parse a scene file into its grids (nothing is decoded) and whether it is RGB.
fn parse(path: &Path, opts: &SceneOptions) -> Result<(Vec<Entry>, bool)> {
    let file = read_scene_file(path)?;
    if file.volume.is_empty() {
        return Err(scene_err(path, "no [[volume]] tables"));
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut rgb = opts.sigma_t.is_some();
    let mut entries = Vec::new();
    for (i, v) in file.volume.iter().enumerate() {
        let at = format!("volume[{i}] ({})", v.file);
        let here = |what: &str, reason: String| scene_err(path, format!("{at}: {what}{reason}"));
        let file_path = resolve(dir, &v.file);
        let own = match &v.xform {
            Some(m) => Some(Xform::from_row_major(m).map_err(|e| here("xform: ", reason(e)))?),
            None => None,
        };
        let xform = match (own, &opts.xform) {
            (Some(a), Some(b)) => Some(
                Xform::new(compose(&b.rows(), &a.rows()))
                    .map_err(|e| here("xform: ", reason(e)))?,
            ),
            (Some(a), None) => Some(a),
            (None, b) => *b,
        };
        let entry = |grid: String, solid: bool, scale: f64, sigma: [f64; 3]| Entry {
            file: crate::usd::Asset::File(file_path.clone()),
            grid,
            solid,
            scale,
            sigma,
            xform,
            at: at.clone(),
            velocity: None,
            fps: None,
        };
        match v.kind.as_deref().unwrap_or("fog") {
            "solid" => {
                let extra = [
                    ("grids", v.grids.is_some()),
                    ("weights", v.weights.is_some()),
                    ("density_scale", v.density_scale.is_some()),
                    ("sigma_t", v.sigma_t.is_some()),
                ];
                if let Some((k, _)) = extra.iter().find(|(_, given)| *given) {
                    return Err(here(
                        "",
                        format!("'{k}' has no meaning for a solid (kind = \"solid\" is opaque)"),
                    ));
                }
                let grid = v.grid.clone().unwrap_or_else(|| "density".into());
                entries.push(entry(grid, true, 1.0, [1.0; 3]));
            }
            "fog" => {
                let (grids, weights) = fog_grids(v, &here)?;
                let scale = v.density_scale.unwrap_or(1.0);
                crate::volume::check_density_scale(scale)
                    .map_err(|e| here("density_scale: ", reason(e)))?;
                let sigma = match v.sigma_t {
                    None => [1.0; 3],
                    Some(SigmaSpec::Grey(s)) => [s; 3],
                    Some(SigmaSpec::Rgb(s)) => {
                        rgb = true;
                        s
                    }
                };
                check_sigma(sigma).map_err(|e| here("sigma_t: ", reason(e)))?;
                let tint = opts.sigma_t.unwrap_or([1.0; 3]);
                let sigma = std::array::from_fn(|c| sigma[c] * tint[c]);
                for (g, w) in grids.iter().zip(&weights) {
                    entries.push(entry(
                        g.clone(),
                        false,
                        opts.density_scale * scale * w,
                        sigma,
                    ));
                }
            }
            other => {
                return Err(here(
                    "kind: ",
                    format!(
                        "'{}' is not \"fog\" or \"solid\"",
                        crate::text::escape(other)
                    ),
                ))
            }
        }
    }
    if entries.iter().filter(|e| !e.solid).count() > super::MAX_VOLUMES {
        return Err(scene_err(
            path,
            format!("more than {} fog grids", super::MAX_VOLUMES),
        ));
    }
    Ok((entries, rgb))
}

fn load_file(path: &Path, opts: &SceneOptions) -> Result<Scene> {
    let (entries, rgb) = entries(path, opts)?;
    let (mut fogs, mut solids) = (Vec::new(), Vec::new());
    for e in entries {
        let placed = |err: Error| scene_err(path, format!("{}: xform: {}", e.at, reason(err)));
        let opened = e.file.open()?;
        let file = opened.path();
        let failed = |err: Error| asset_err(path, opts.kind.is_stage(), &e, file, err);
        if e.solid {
            let mut s = Solid::load(file, &e.grid).map_err(failed)?;
            if let Some(x) = &e.xform {
                s = s.with_xform(x).map_err(placed)?;
            }
            solids.push(s);
        } else {
            let mut vol = Volume::load(file, &e.grid, e.scale).map_err(failed)?;
            if let Some(x) = &e.xform {
                vol = vol.with_xform(x).map_err(placed)?;
            }
            if let Some(m) = &opts.motion {
                let mut m = m.clone();
                if let (false, Some(fps)) = (m.fps_given, e.fps) {
                    m.spec = m.spec.with_fps(fps)?;
                }
                // A stage's velocity field: its grid in its own asset.
                let velocity_asset = match &e.velocity {
                    Some((asset, grid)) => {
                        m.velocity.clone_from(grid);
                        Some(asset.open()?)
                    }
                    None => None,
                };
                let vfile = velocity_asset.as_ref().map_or(file, |o| o.path());
                vol = blurred(vol, &m, vfile).map_err(failed)?;
            }
            fogs.push(Fog::new(vol, e.sigma)?);
        }
    }
    Scene::new(fogs, solids, rgb).map_err(|e| scene_err(path, reason(e)))
}

/// The world corners of every grid box of the scene at `path` (a `.vdb` file: its grid's),
/// read from headers and topology without decoding voxel values (what framing a sequence
/// needs). Grids holding only their background add nothing.
///
/// # Errors
/// As [`load`], for what reading topology can find.
pub(crate) fn read_box_corners(path: impl AsRef<Path>, opts: &SceneOptions) -> Result<Vec<DVec3>> {
    let path = path.as_ref();
    if opts.motion.is_some() {
        // Where blurred density reaches depends on the velocity's values: load it.
        return load(path, opts)?.box_corners();
    }
    let entries = if !opts.kind.is_grid_file() {
        entries(path, opts)?.0
    } else {
        vec![Entry {
            file: crate::usd::Asset::File(path.to_path_buf()),
            grid: opts.grid.clone(),
            solid: false,
            scale: 1.0,
            sigma: [1.0; 3],
            xform: opts.xform,
            at: String::new(),
            velocity: None,
            fps: None,
        }]
    };
    let mut out = Vec::new();
    for e in entries {
        let opened = e.file.open()?;
        let corners = Volume::read_box_corners(opened.path(), &e.grid)
            .map_err(|err| asset_err(path, opts.kind.is_stage(), &e, opened.path(), err))?;
        if let Some(c) = corners {
            match &e.xform {
                Some(x) => out.extend(c.map(|p| x.point(p))),
                None => out.extend(c),
            }
        }
    }
    Ok(out)
}

/// The reason of an argument error (its message otherwise).
fn reason(e: Error) -> String {
    match e {
        Error::InvalidArgument { reason, .. } => reason,
        other => other.to_string(),
    }
}

/// A path in a scene file, relative to the scene file's directory unless absolute.
fn resolve(dir: &Path, file: &str) -> PathBuf {
    let p = Path::new(file);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        dir.join(p)
    }
}

/// `a b` for row-major 4x4 affine matrices.
fn compose(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..4).map(|k| a[r][k] * b[k][c]).sum()))
}
