//! What a baked map is, as data: the [`MapSummary`] that `umbra bake --json` prints (with the
//! run's timings added) and the Python module returns as a map's `camera` dict, and the way
//! back from it and the pixels to a [`Map`] that [`crate::bake::write_exr`] writes as the same file
//! the CLI writes.
//!
//! The summary holds everything the EXR header holds besides the pixels: the camera (the
//! `camera` object [`crate::bake::read_camera`] reads back), the provenance, the estimator with its
//! parameters, the sampling settings and the sample counts behind `umbra:mean_spp`
//! (`samples / max(rays, 1)`).

use crate::bake::camera::{Camera, CameraSpec, Projection};
use crate::bake::encode::exr::Provenance;
use crate::bake::map::channel_names;
use crate::bake::map::{BakeSettings, BakeStats, Channel, Depths, Map};
use crate::error::{Error, Result};
use crate::estimate::{ColourWalk, Estimator, Options};
use crate::Interp;

/// The camera object of a summary: what [`Camera::from_spec`] needs besides the size.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SummaryCamera {
    /// `ortho` or `perspective`.
    pub kind: Projection,
    /// Ortho: world start of pixel (0, 0)'s centre ray. Perspective: the light position.
    pub origin: [f64; 3],
    /// World step from one pixel centre to the next along a row.
    pub step_x: [f64; 3],
    /// World step from one pixel centre to the next down a column.
    pub step_y: [f64; 3],
    /// Ortho: the ray direction. Perspective: pixel (0, 0)'s centre at distance 1.
    pub direction: [f64; 3],
    /// World distance each ray is traced.
    pub t_max: f64,
}

/// A baked map described: the keys of `umbra bake --json` that describe the map (the CLI adds
/// `output`, `preview`, `threads` and the run's timings and counters).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MapSummary {
    /// Source file as given.
    pub file: String,
    /// Grid name(s) traced.
    pub grid: String,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Every pixel's ray, rebuilt bit for bit by [`Camera::from_spec`].
    pub camera: SummaryCamera,
    /// Light direction as given (the direction the light travels).
    pub light_dir: Option<[f64; 3]>,
    /// Light position as given.
    pub light_pos: Option<[f64; 3]>,
    /// World-from-object transform the volume was placed with, row-major.
    pub xform: Option<[[f64; 4]; 4]>,
    /// Extinction colour given with the input.
    #[serde(default)]
    pub sigma_t: Option<[f64; 3]>,
    /// Perspective field of view across width and height, degrees.
    pub fov_deg: Option<[f64; 2]>,
    /// The EXR channels, in file order.
    pub channels: Vec<String>,
    /// Slice depths (world distance along each ray).
    pub depths: Vec<f64>,
    /// Estimator name.
    pub estimator: String,
    /// The estimator with its parameters (`{"name": ..., PARAM: VALUE}`).
    pub estimator_params: serde_json::Value,
    /// Lookup interpolation.
    pub interp: Interp,
    /// Samples per pixel asked for.
    pub spp: u32,
    /// Adaptive sampling's target standard error.
    pub target_error: Option<f64>,
    /// Adaptive sampling's cap.
    pub max_spp: u32,
    /// Seed of the random streams.
    pub seed: u64,
    /// How a colour map's channels were tracked (`--colour-walk`).
    #[serde(default)]
    pub colour_walk: ColourWalk,
    /// `mu_t = density_scale x value`.
    pub density_scale: f64,
    /// Pixel rays traced.
    pub rays: u64,
    /// Samples taken over all pixels.
    #[serde(default)]
    pub samples: u64,
    /// `samples / max(rays, 1)`.
    pub mean_spp: f64,
    /// A map toward a light with extent: the light and its receivers (absent for a point
    /// light).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<SummaryLight>,
}

/// The light of a map toward a light with extent, as a summary says it (docs/lights.md).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SummaryLight {
    /// The extent as the library spells it (`umbra:light_extent`).
    pub extent: String,
    /// Directions per receiver: exactly these with no `target_error`, else the most a
    /// receiver may trace (`light-max-samples`).
    pub samples: u32,
    /// The error bar each receiver's count was chosen to reach; absent for a fixed count.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_error: Option<f64>,
    /// Mean directions per sampled receiver (a pilot's included).
    #[serde(default)]
    pub mean_directions: f64,
    /// 99th percentile of directions per sampled receiver.
    #[serde(default)]
    pub p99_directions: u64,
    /// Receivers the target asked more directions of than `light-max-samples` allows.
    #[serde(default)]
    pub capped: u64,
    /// `box exit` or `depth D` (`umbra:receiver`).
    pub receiver: String,
    /// Receivers: texels times `1 + slices`.
    pub receivers: u64,
    /// Receivers whose light was sampled (the others provably meet no density).
    pub sampled: u64,
    /// `sampled / receivers`.
    pub sampled_fraction: f64,
    /// Receivers answered by a bound on every direction's optical depth (their cones only
    /// graze density; `T = 1` with the bound as its error bar), not sampled.
    #[serde(default)]
    pub bounded: u64,
}

impl SummaryLight {
    /// The light of `map`, `None` toward a point light.
    fn of(map: &Map) -> Option<Self> {
        let soft = map.settings.soft.as_ref()?;
        let [sampled, receivers] = map.stats.light_sampled.unwrap_or([0, 0]);
        let d = map.stats.light_directions.unwrap_or_default();
        Some(Self {
            extent: soft.light.extent.to_string(),
            samples: soft.light.samples,
            target_error: soft.light.target,
            mean_directions: d.mean,
            p99_directions: d.p99,
            capped: d.capped,
            receiver: soft.receiver.to_string(),
            receivers,
            sampled,
            sampled_fraction: sampled as f64 / receivers.max(1) as f64,
            bounded: map.stats.light_bounded.unwrap_or(0),
        })
    }
}

impl MapSummary {
    /// The summary of `map` baked from what `prov` says.
    #[must_use]
    pub fn new(map: &Map, prov: &Provenance) -> Self {
        let c = &map.camera;
        let s = &map.settings;
        Self {
            file: prov.source_file.clone(),
            grid: prov.grid.clone(),
            width: c.width(),
            height: c.height(),
            camera: SummaryCamera {
                kind: c.kind(),
                origin: c.origin(),
                step_x: c.step_x(),
                step_y: c.step_y(),
                direction: c.direction(),
                t_max: c.t_max(),
            },
            light_dir: prov.light_dir,
            light_pos: prov.light_pos,
            xform: prov.xform,
            sigma_t: prov.sigma_t,
            fov_deg: c.fov_deg().map(|f| [f.0, f.1]),
            channels: channel_names(map.channels(), map.std_err.is_some(), map.slices.len()),
            depths: map.depths.clone(),
            estimator: s.estimator.name().to_string(),
            estimator_params: serde_json::to_value(s.estimator).unwrap_or_default(),
            interp: s.options.interp,
            spp: s.options.samples,
            target_error: s.target_error,
            max_spp: s.max_spp,
            seed: s.options.seed,
            colour_walk: s.options.colour_walk,
            density_scale: prov.density_scale,
            rays: map.stats.rays,
            samples: map.stats.samples,
            mean_spp: map.stats.samples as f64 / map.stats.rays.max(1) as f64,
            light: SummaryLight::of(map),
        }
    }

    /// The camera, validated ([`Camera::from_spec`]).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `camera`) when the camera is not one.
    pub fn camera(&self) -> Result<Camera> {
        let c = &self.camera;
        Camera::from_spec(&CameraSpec {
            kind: c.kind,
            width: self.width,
            height: self.height,
            origin: c.origin,
            step_x: c.step_x,
            step_y: c.step_y,
            direction: c.direction,
            t_max: c.t_max,
        })
        .map_err(|e| bad(e.to_string()))
    }

    /// The map these pixels make with this summary: `t` (`W x H`, row 0 at the top; red for a
    /// colour map), `std_err` when the summary lists a `.stderr` channel, `color` (green and
    /// blue) when it lists `R`, `G`, `B`. Slices are not rebuilt (the summary must list none).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `camera`) when the summary does not hold together (an
    /// unknown estimator or parameter, a camera [`Camera::from_spec`] refuses, slices) and
    /// (name `image`) when the pixels do not match its size and channels.
    pub fn to_map(
        &self,
        t: Vec<f32>,
        std_err: Option<Vec<f32>>,
        color: Option<Box<[Channel; 2]>>,
    ) -> Result<(Map, Provenance)> {
        let camera = self.camera()?;
        if self.light.is_some() {
            return Err(bad(
                "a map toward a light with extent cannot be rebuilt from its summary yet (its \
                 light is described, not given as the library reads it)",
            ));
        }
        if !self.depths.is_empty() {
            return Err(bad(
                "a map with depth slices cannot be rebuilt from its summary",
            ));
        }
        let rgb = self.channels.first().is_some_and(|c| c == "R");
        let with_err = self.channels.iter().any(|c| c.ends_with(".stderr"));
        let want = channel_names(if rgb { 3 } else { 1 }, with_err, 0);
        if self.channels != want {
            return Err(bad(format!(
                "unexpected channels {:?} (expected {want:?})",
                self.channels
            )));
        }
        let image = |reason: String| Error::InvalidArgument {
            name: "image".into(),
            reason,
        };
        if rgb != color.is_some() {
            return Err(image(format!(
                "the camera describes a {} map, the image has {} channel(s)",
                if rgb { "colour (R, G, B)" } else { "grey (T)" },
                if color.is_some() { 3 } else { 1 }
            )));
        }
        if with_err != std_err.is_some() {
            return Err(image(if with_err {
                "the camera lists a .stderr channel: give the standard error image too".into()
            } else {
                "the camera lists no .stderr channel, but a standard error image was given".into()
            }));
        }
        let n = camera.pixels();
        let sizes = std::iter::once(t.len())
            .chain(std_err.as_ref().map(Vec::len))
            .chain(color.iter().flat_map(|c| {
                c.iter().flat_map(|ch| {
                    std::iter::once(ch.t.len()).chain(ch.std_err.as_ref().map(Vec::len))
                })
            }));
        for len in sizes {
            if len as u64 != n {
                return Err(image(format!(
                    "{len} pixels for a {} x {} camera",
                    self.width, self.height
                )));
            }
        }
        let name = self
            .estimator_params
            .get("name")
            .and_then(serde_json::Value::as_str)
            .unwrap_or(&self.estimator);
        if name != self.estimator {
            return Err(bad(format!(
                "estimator '{}' but estimator_params name '{name}'",
                self.estimator
            )));
        }
        let params: Vec<(&str, f64)> = match self.estimator_params.as_object() {
            Some(m) => m
                .iter()
                .filter(|(k, _)| k.as_str() != "name")
                .map(|(k, v)| {
                    v.as_f64()
                        .map(|v| (k.as_str(), v))
                        .ok_or_else(|| bad(format!("estimator parameter '{k}' is not a number")))
                })
                .collect::<Result<_>>()?,
            None => Vec::new(),
        };
        let estimator =
            Estimator::with_params(&self.estimator, &params).map_err(|e| bad(e.to_string()))?;
        let options = Options {
            interp: self.interp,
            samples: self.spp,
            seed: self.seed,
            colour_walk: self.colour_walk,
            ..Options::default()
        };
        let settings = BakeSettings {
            target_error: self.target_error,
            max_spp: self.max_spp,
            depths: Depths::None,
            std_err: with_err,
            ..BakeSettings::new(estimator, options)
        };
        let map = Map {
            camera,
            settings,
            t,
            std_err,
            depths: Vec::new(),
            slices: Vec::new(),
            color,
            stats: BakeStats {
                rays: self.rays,
                samples: self.samples,
                ..BakeStats::default()
            },
        };
        let prov = Provenance {
            source_file: self.file.clone(),
            grid: self.grid.clone(),
            density_scale: self.density_scale,
            light_dir: self.light_dir,
            light_pos: self.light_pos,
            xform: self.xform,
            sigma_t: self.sigma_t,
            key: None,
        };
        Ok((map, prov))
    }
}

fn bad(reason: impl Into<String>) -> Error {
    Error::InvalidArgument {
        name: "camera".into(),
        reason: reason.into(),
    }
}
