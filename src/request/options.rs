//! [`BakeOptions`]: everything a bake can be asked for besides its input and output, its
//! defaults, the options a transmittance volume reads, and the checks and views every plan
//! starts from (the module docs of [`crate::request`] give the naming rule).

use crate::bake::{Omni, Order, Projection, Resolution, View};
use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

use super::estimator::{from_json_object, EstimatorOptions, EstimatorParams};
use super::{CameraSource, Framing};
use crate::input::SourceOptions;

/// Everything a bake can be asked for besides its input and output: the one definition of a
/// bake's options. Fields are the options' canonical names (see the module docs for the
/// naming rule); every field has its default, so a request names only what it changes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields, default)]
pub struct BakeOptions {
    /// How the input is read: grid or stage selection, interpolation, scale, colour, level
    /// sets, placement, motion ([`SourceOptions`]).
    #[cfg_attr(feature = "cli", command(flatten))]
    #[serde(flatten)]
    pub source: SourceOptions,
    /// The light, by direction or position ([`crate::light::LightOptions`]).
    #[cfg_attr(feature = "cli", command(flatten))]
    #[serde(flatten)]
    pub light: crate::light::LightOptions,
    /// With light-pos: an orthographic map whose image plane passes through the light.
    #[cfg_attr(feature = "cli", arg(long))]
    pub ortho: bool,
    /// With light-pos: an omnidirectional map around the light, inside, beside or outside the
    /// volume, in the world's axes: `cube` (six N x N faces in one N x 6N image, OpenEXR's
    /// `envmap = cube`) or `latlong` (2N x N, `envmap = latlong`); res gives N (default 512).
    #[cfg_attr(feature = "cli", arg(long, value_enum))]
    pub omni: Option<Omni>,
    /// Perspective field of view across the longer image side, degrees in (0, 180) (default:
    /// just holds the volume box).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub fov: Option<f64>,
    /// The world direction that is up in the map, X,Y,Z (default 0,1,0; when it is parallel to
    /// the light, the default's rule applies).
    #[cfg_attr(feature = "cli", arg(long, value_parser = crate::input::parse_vec3, allow_hyphen_values = true))]
    pub up: Option<[f64; 3]>,
    /// Frame this world box instead of the volume box (the rays still cover the whole volume in
    /// depth): X0,Y0,Z0,X1,Y1,Z1 on the command line, [[x0, y0, z0], [x1, y1, z1]] as data.
    #[cfg_attr(feature = "cli", arg(long, value_parser = parse_box, allow_hyphen_values = true))]
    pub frame_box: Option<[[f64; 3]; 2]>,
    /// USD stage inputs: also write a .usda layer that puts the map and its camera on the light
    /// prim (time-sampled umbra:shadowMap and umbra:worldToShadow), to sublayer over the shot.
    #[cfg_attr(feature = "cli", arg(long, value_name = "LAYER.usda"))]
    pub usd_out: Option<PathBuf>,
    /// Reuse exactly the camera of an earlier umbra map (.exr), of a JSON file holding the
    /// `camera` object `bake --json` prints, or (as data) that object; its resolution unless
    /// res is given (then the same window at that size).
    #[cfg_attr(feature = "cli", arg(long))]
    pub camera: Option<CameraSource>,
    /// Resolution: WxH, or N for N pixels on the long side with the framed box's aspect
    /// (default 1024); as data also [W, H].
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub res: Option<Resolution>,
    /// Write a tiled EXR with N x N tiles (renderers page large maps in by tile).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N"))]
    pub tile: Option<u32>,
    /// With tile: also write box-filtered mip levels of every channel (round-down, down to
    /// 1x1; each level pixel the mean of T over its footprint).
    #[cfg_attr(feature = "cli", arg(long))]
    pub mipmap: bool,
    /// Write a deep OpenEXR map: per pixel the whole transmittance function along its ray as
    /// volumetric samples (channels A, Z, ZBack; AR, AG, AB, OpenEXR's per-channel
    /// opacities, with colour).
    #[cfg_attr(feature = "cli", arg(long))]
    pub deep: bool,
    /// With deep: the bound E on |T_deep(z) - T(z)| at every depth z (default 0.002).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub deep_error: Option<f64>,
    /// A deep map at a fixed size per texel, as channels of a flat EXR next to T:
    /// fourier:K (K odd, 3-63), moments:4, moments:6 or avsm:K (K nodes, 2-32); the error in
    /// T it reaches is in the header (umbra:deep_max_error).
    #[cfg_attr(feature = "cli", arg(long, value_name = "FORMAT"))]
    pub deep_format: Option<String>,
    /// A transmittance volume (.vdb output): the name of the written grid (default
    /// `transmittance`).
    #[cfg_attr(feature = "cli", arg(long))]
    pub out_grid: Option<String>,
    /// A transmittance volume (.vdb output): store 16-bit half floats.
    #[cfg_attr(feature = "cli", arg(long))]
    pub half: bool,
    /// Also write an 8-bit grayscale PNG preview of T here (.png; in a job, a pattern like the
    /// output's).
    #[cfg_attr(feature = "cli", arg(long))]
    pub preview: Option<PathBuf>,
    /// K extra channels `sliceNN.T`: T at K depths evenly spaced across the volume's depth range.
    #[cfg_attr(feature = "cli", arg(long))]
    pub slices: Option<usize>,
    /// Extra channels `sliceNN.T` at these depths (world distance along each ray): a,b,c.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_delimiter = ',', num_args = 1, allow_hyphen_values = true)
    )]
    pub depths: Option<Vec<f64>>,
    /// Also write each pixel's standard error (`T.stderr`).
    #[cfg_attr(feature = "cli", arg(long))]
    pub stderr: bool,
    /// With light-angle or light-radius: each texel's receiver at this world distance along
    /// its ray (as depths measures it) instead of where the ray leaves the volume box
    /// (`umbra:receiver`; docs/lights.md). Finite, >= 0.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "D", allow_negative_numbers = true)
    )]
    pub receiver_depth: Option<f64>,
    /// Adaptive sampling: double a pixel's samples until its standard error is below E.
    /// Toward a light with extent (without light-samples): the error bar each receiver's
    /// count of directions is chosen to reach, in (0, 1) (default 5e-3; docs/lights.md).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub target_error: Option<f64>,
    /// Cap on samples per pixel for target-error.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 65_536))]
    pub max_spp: u32,
    /// Which estimator answers, with its parameters and sampling ([`EstimatorOptions`]).
    #[cfg_attr(feature = "cli", command(flatten))]
    #[serde(flatten)]
    pub estimator: EstimatorOptions,
    /// The estimator's parameters (`step`, `kernel`, `points`; [`EstimatorParams`]).
    #[cfg_attr(feature = "cli", command(flatten))]
    #[serde(flatten)]
    pub params: EstimatorParams,
    /// Tracing order of a map: `auto` (object order where the sweep takes the map: exact,
    /// ray-marched and null-collision maps) or `rays` (one ray per pixel; a pixel of a
    /// null-collision map is then what `query --ray-id` answers).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "auto"))]
    pub order: Order,
    /// Worker threads (0: all cores).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub threads: usize,
    /// Memory budget (bytes, or with K, M, G: `512M`, `1.5G`; powers of 1024). When the
    /// decoded grid and the image would not fit, the map is baked a part of the grid at a time
    /// (the same map, bit for bit); a budget below the least part is refused before any work.
    /// Without it, exact maps of caches over 1 GiB decoded go in parts of 1 GiB; a larger
    /// budget holds them whole.
    #[cfg_attr(feature = "cli", arg(long, value_parser = parse_size))]
    pub max_memory: Option<String>,
    /// Replace existing outputs (alias overwrite).
    #[cfg_attr(feature = "cli", arg(long, visible_alias = "overwrite"))]
    #[serde(alias = "overwrite")]
    pub force: bool,
    /// Batch jobs only: `shared` (one camera per light for a whole sequence) or `per-frame`.
    #[cfg_attr(feature = "cli", arg(skip))]
    pub framing: Option<Framing>,
}

impl Default for BakeOptions {
    /// The read options' and the estimator options' defaults are theirs.
    fn default() -> Self {
        Self {
            source: SourceOptions::default(),
            light: crate::light::LightOptions::default(),
            ortho: false,
            omni: None,
            fov: None,
            up: None,
            frame_box: None,
            usd_out: None,
            camera: None,
            res: None,
            tile: None,
            mipmap: false,
            deep: false,
            deep_error: None,
            deep_format: None,
            out_grid: None,
            half: false,
            preview: None,
            slices: None,
            depths: None,
            stderr: false,
            receiver_depth: None,
            target_error: None,
            max_spp: 65_536,
            estimator: EstimatorOptions::default(),
            params: EstimatorParams::default(),
            order: Order::Auto,
            threads: 0,
            max_memory: None,
            force: false,
            framing: None,
        }
    }
}

/// The options a transmittance volume reads; any other option set is refused.
pub const VOLUME_OPTIONS: &[&str] = &[
    "grid",
    "light_dir",
    "light_pos",
    "light_angle",
    "light_radius",
    "light_samples",
    "light_max_samples",
    "xform",
    "out_grid",
    "half",
    "interp",
    "density_scale",
    "estimator",
    "samples",
    "seed",
    "step",
    "kernel",
    "points",
    "granularity",
    "global_majorant",
    "velocity",
    "shutter",
    "fps",
    "velocity_scale",
    "time_samples",
    "threads",
    "force",
    "frame",
    "volume",
    "field",
    "light",
];

/// The options only a transmittance volume reads; a map refuses them.
pub(super) const VOLUME_ONLY: &[&str] = &["out_grid", "half"];

pub(super) fn bad(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason: reason.into(),
    }
}

/// Parse `X0,Y0,Z0,X1,Y1,Z1` (`--frame-box`).
///
/// # Errors
/// A message naming what is wrong.
pub fn parse_box(s: &str) -> std::result::Result<[[f64; 3]; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| v.len() == 6)
        .ok_or_else(|| format!("'{s}': expected X0,Y0,Z0,X1,Y1,Z1 (six numbers)"))?;
    Ok([[v[0], v[1], v[2]], [v[3], v[4], v[5]]])
}

/// Check a size such as `512M` (`--max-memory`), keeping its text.
///
/// # Errors
/// A message naming what is wrong.
pub fn parse_size(s: &str) -> std::result::Result<String, String> {
    crate::math::parse_bytes(s).map(|_| s.to_string())
}

impl BakeOptions {
    /// The options set to something other than their default, by canonical name, in
    /// alphabetical order.
    #[must_use]
    pub fn changed(&self) -> Vec<String> {
        let (Ok(serde_json::Value::Object(mine)), Ok(serde_json::Value::Object(base))) = (
            serde_json::to_value(self),
            serde_json::to_value(Self::default()),
        ) else {
            return Vec::new();
        };
        mine.into_iter()
            .filter(|(k, v)| base.get(k) != Some(v))
            .map(|(k, _)| k)
            .collect()
    }

    /// Options from a JSON object, as the Python module passes its keywords: a value of the
    /// wrong type or an unknown name is an [`Error::InvalidArgument`] naming that option.
    ///
    /// # Errors
    /// As above.
    pub fn from_json(text: &str) -> Result<Self> {
        from_json_object(text)
    }

    /// The estimator these options select, with its parameters, for lookups by the read
    /// options' `interp`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `estimator` or a parameter it does not take.
    pub fn resolve_estimator(&self) -> Result<(Estimator, Options)> {
        self.estimator.resolve(&self.params, self.source.interp)
    }

    /// The motion blur these options ask for, checked ([`EstimatorOptions::motion`]).
    ///
    /// # Errors
    /// As [`EstimatorOptions::motion`].
    pub fn motion(&self) -> Result<Option<crate::motion::MotionRequest>> {
        self.estimator.motion(&self.source)
    }

    /// These options with `keys` (a JSON object of read and estimator options by name, as a
    /// job's `[[positions]]` entry gives them) over them ([`super::overlaid`]: an alias
    /// replaces its canonical key).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming a key that is no read or estimator option, or whose
    /// value does not parse.
    pub fn with_overrides(
        &self,
        keys: &serde_json::Map<String, serde_json::Value>,
    ) -> Result<Self> {
        let trace = super::TraceOptions {
            source: self.source.clone(),
            estimator: self.estimator.clone(),
            params: self.params.clone(),
        };
        let t = super::overlaid(&trace, keys)?;
        Ok(Self {
            source: t.source,
            estimator: t.estimator,
            params: t.params,
            ..self.clone()
        })
    }

    /// The memory budget in bytes.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `max-memory`.
    pub fn max_memory(&self) -> Result<Option<u64>> {
        self.max_memory
            .as_deref()
            .map(|m| crate::math::parse_bytes(m).map_err(|r| bad("max-memory", r)))
            .transpose()
    }

    /// The checks every product shares: scale, transform, estimator, threads.
    pub(super) fn check_common(&self) -> Result<()> {
        let s = &self.source;
        if s.grid.is_empty() {
            return Err(bad("grid", "must not be empty"));
        }
        if !(s.density_scale.is_finite() && s.density_scale >= 0.0) {
            return Err(bad(
                "density-scale",
                format!("{} is not a finite non-negative number", s.density_scale),
            ));
        }
        crate::bake::check_threads(self.threads)?;
        if self.framing.is_some() {
            return Err(bad(
                "framing",
                "applies to batch jobs (how the maps of a sequence are framed)",
            ));
        }
        Ok(())
    }

    /// The view of an omnidirectional map: a light position and a size, nothing that aims or
    /// frames.
    fn omni_view(&self, omni: Omni) -> Result<View> {
        if self.light.light_pos.is_none() {
            return Err(bad(
                "omni",
                "an omnidirectional map is seen from a point light: give light-pos",
            ));
        }
        let aims = [
            ("light-dir", self.light.light_dir.is_some()),
            ("ortho", self.ortho),
            ("fov", self.fov.is_some()),
            ("up", self.up.is_some()),
            ("frame-box", self.frame_box.is_some()),
            ("mipmap", self.mipmap),
            ("usd-out", self.usd_out.is_some()),
        ];
        if let Some((k, _)) = aims.iter().find(|(_, set)| *set) {
            return Err(bad(
                k,
                "does not apply to an omnidirectional map (every direction from the light, in \
                 the world's axes, one mip level)",
            ));
        }
        Ok(View {
            projection: omni.projection(),
            light_pos: self.light.light_pos,
            res: self.res,
            ..View::default()
        })
    }

    /// The camera request of a map (no fixed camera): the light-to-projection rule.
    pub(super) fn view(&self) -> Result<View> {
        if let Some(omni) = self.omni {
            return self.omni_view(omni);
        }
        let projection = match (self.light.light_dir, self.light.light_pos) {
            (None, None) => {
                return Err(bad(
                    "light-dir",
                    "no light: give the direction the light travels (an orthographic map), \
                     light-pos (a perspective map) or camera",
                ))
            }
            (_, Some(_)) if !self.ortho => Projection::Perspective,
            _ => Projection::Ortho,
        };
        if let Some(f) = self.fov {
            if projection == Projection::Ortho {
                return Err(bad(
                    "fov",
                    "applies to perspective maps (light-pos without ortho)",
                ));
            }
            if !(f.is_finite() && f > 0.0 && f < 180.0) {
                let shown = if f.abs() >= 1e6 {
                    format!("{f:e}")
                } else {
                    format!("{f}")
                };
                return Err(bad("fov", format!("{shown} is not in (0, 180) degrees")));
            }
        }
        if let Some(u) = self.up {
            if !u.iter().all(|c| c.is_finite()) || u.iter().all(|&c| c == 0.0) {
                return Err(bad("up", "must be finite and non-zero"));
            }
        }
        if let Some(fb) = self.frame_box {
            if !(0..3).all(|a| fb[0][a].is_finite() && fb[1][a].is_finite() && fb[0][a] < fb[1][a])
            {
                return Err(bad(
                    "frame-box",
                    "must be finite, with x0 < x1, y0 < y1, z0 < z1",
                ));
            }
        }
        Ok(View {
            projection,
            light_dir: self.light.light_dir,
            light_pos: self.light.light_pos,
            fov_deg: self.fov,
            res: self.res,
            up: self.up,
            frame_box: self.frame_box,
        })
    }
}
