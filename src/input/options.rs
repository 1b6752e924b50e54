//! [`SourceOptions`]: how a job reads its input, the one definition of the read keys. Every
//! front end flattens it: `umbra bake`, `query` and `compare` as flags, a job file's `[bake]`
//! table (and its `[[positions]]` entries, as overrides) as keys, the Python functions as
//! keywords; a key is the long flag with `-` turned into `_` (`--density-scale`,
//! `density_scale = 2`, `density_scale=2`).
//!
//! The grid or stage selection (`grid`; `frame`, `volume`, `field`, `light`), what the values
//! mean (`interp`, `density_scale`, `sigma_t`, `levelset`), where the volume stands (`xform`)
//! and how it moves (`velocity`, `shutter`, `fps`, `velocity_scale`, `time_samples`) describe
//! the input, not the estimator, so they sit here and a [`super::Source`] carries them with its
//! path.

use serde::{Deserialize, Serialize};

/// How the density between voxel centres is defined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Interp {
    /// OpenVDB `PointSampler`: the voxel `floor(p + 0.5)`, piecewise constant.
    Nearest,
    /// OpenVDB `BoxSampler`: trilinear interpolation of the 8 voxels around `p`.
    Trilinear,
}

impl Interp {
    /// Offset added to index coordinates so that the lookup cell is `floor(q)`: nearest lookups
    /// own `[i - 0.5, i + 0.5)`, trilinear ones the dual cell `[i, i + 1)`.
    #[must_use]
    pub fn shift(self) -> f64 {
        match self {
            Self::Nearest => 0.5,
            Self::Trilinear => 0.0,
        }
    }
}

/// What to do with a level-set grid (`levelset`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum LevelSet {
    /// An opaque occluder: T = 0 from where a ray first enters phi < 0.
    Solid,
}

/// How a job reads its input: which grid or which part of a stage, what its values mean,
/// where it stands and how it moves. Every field has its default, so a request names only
/// what it changes ([`SourceOptions::default`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default)]
pub struct SourceOptions {
    /// Grid to trace (display name such as `density[1]`; unnamed grids, as Warp writes them,
    /// are `[0]`, `[1]`, ... in file order; or the stored name).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value = "density", value_parser = clap::builder::NonEmptyStringValueParser::new())
    )]
    pub grid: String,
    /// Place the volume in the shot: a world-from-object 4x4 matrix, 16 numbers, row-major, the
    /// translation in the last column.
    // A fully qualified `Vec`: clap reads the 16 numbers as one value, checked whole.
    #[cfg_attr(feature = "cli", arg(long, value_parser = parse_xform, allow_hyphen_values = true))]
    pub xform: Option<::std::vec::Vec<f64>>,
    /// USD stage inputs: the time code to read (default: the stage's startTimeCode).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub frame: Option<f64>,
    /// USD stage inputs: a Volume prim to trace, by path (repeatable; default: every active,
    /// visible Volume of the stage).
    #[cfg_attr(feature = "cli", arg(long, value_name = "PRIM"))]
    pub volume: Option<Vec<String>>,
    /// USD stage inputs: the field a Volume's density is (its field:NAME relationship; default
    /// density).
    #[cfg_attr(feature = "cli", arg(long, value_name = "NAME"))]
    pub field: Option<String>,
    /// USD stage inputs: the UsdLux light, by prim path or name (default: the stage's only
    /// light; light-dir / light-pos override it); its shadow link picks the volumes.
    #[cfg_attr(feature = "cli", arg(long, value_name = "PRIM"))]
    pub light: Option<String>,
    /// How the density between voxel centres is defined.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "trilinear"))]
    pub interp: Interp,
    /// mu_t = S x value, per world unit.
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 1.0, allow_negative_numbers = true)
    )]
    pub density_scale: f64,
    /// Extinction colour R,G,B: T per channel (an RGB answer), mu_c = sigma_t[c] x
    /// density-scale x value (multiplies a scene's own sigma_t).
    #[cfg_attr(feature = "cli", arg(long, value_parser = parse_vec3, allow_hyphen_values = true))]
    pub sigma_t: Option<[f64; 3]>,
    /// `solid`: trace a level-set grid as an opaque solid (T = 0 from where a ray enters it)
    /// instead of refusing it.
    #[cfg_attr(feature = "cli", arg(long, value_enum))]
    pub levelset: Option<LevelSet>,
    /// Motion blur: the vec3 velocity grid of the density's file (cell-centred, or staggered as
    /// its class says; world units per second unless it is marked local-space): T is the
    /// shutter mean through rho(x - S v(x) t / F). Needs a marching or null-collision estimator
    /// (docs/motion.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "GRID"))]
    pub velocity: Option<String>,
    /// With velocity: the shutter OPEN,CLOSE in frames relative to the baked frame (default
    /// -0.25,0.25).
    #[cfg_attr(
        feature = "cli",
        arg(long, value_parser = parse_pair, allow_hyphen_values = true)
    )]
    pub shutter: Option<[f64; 2]>,
    /// With velocity: frames per second (default 24; a USD shot's timeCodesPerSecond).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub fps: Option<f64>,
    /// With velocity: the velocity scale S (default 1).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub velocity_scale: Option<f64>,
    /// With velocity: stratified shutter times per sample of a marching estimator (default 8;
    /// 1 leaves the error bar unknown); refused for the null-collision estimators, which draw
    /// one time per sample.
    #[cfg_attr(feature = "cli", arg(long))]
    pub time_samples: Option<u32>,
}

impl Default for SourceOptions {
    /// Grid `density`, no placement, the stage's defaults, trilinear, scale 1, grey, level sets
    /// refused, still.
    fn default() -> Self {
        Self {
            grid: "density".into(),
            xform: None,
            frame: None,
            volume: None,
            field: None,
            light: None,
            interp: Interp::Trilinear,
            density_scale: 1.0,
            sigma_t: None,
            levelset: None,
            velocity: None,
            shutter: None,
            fps: None,
            velocity_scale: None,
            time_samples: None,
        }
    }
}

impl SourceOptions {
    /// The keys of the motion blur, in the library's spelling, with whether each is given.
    #[must_use]
    pub fn motion_keys(&self) -> [(&'static str, bool); 5] {
        [
            ("velocity", self.velocity.is_some()),
            ("shutter", self.shutter.is_some()),
            ("fps", self.fps.is_some()),
            ("velocity-scale", self.velocity_scale.is_some()),
            ("time-samples", self.time_samples.is_some()),
        ]
    }
}

/// Parse `A,B` into two numbers (`--shutter`; finiteness is the motion spec's check).
///
/// # Errors
/// A message naming what is wrong.
pub fn parse_pair(s: &str) -> std::result::Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    if v.len() != 2 {
        return Err(format!("expected two numbers A,B, got '{s}'"));
    }
    let n = |t: &str| {
        t.trim()
            .parse::<f64>()
            .map_err(|_| format!("'{}' is not a number", t.trim()))
    };
    Ok([n(v[0])?, n(v[1])?])
}

/// Parse `--xform`: 16 comma-separated numbers, row-major, a valid placement
/// ([`crate::xform::Xform::from_row_major`]).
///
/// # Errors
/// A message naming what is wrong.
pub fn parse_xform(s: &str) -> std::result::Result<Vec<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("'{s}': expected 16 comma-separated numbers"))?;
    crate::xform::Xform::from_row_major(&v).map_err(|e| match e {
        crate::error::Error::InvalidArgument { reason, .. } => reason,
        other => other.to_string(),
    })?;
    Ok(v)
}

/// Parse `X,Y,Z` into three finite numbers (`--light-dir`, `--up`, `--sigma-t`).
///
/// # Errors
/// A message naming what is wrong.
pub fn parse_vec3(s: &str) -> std::result::Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>().map_err(|e| format!("'{c}': {e}")))
        .collect::<std::result::Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
        _ => Err(format!("expected three finite numbers X,Y,Z, got '{s}'")),
    }
}
