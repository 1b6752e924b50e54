//! Lights: where a shading point's light comes from, and the ray toward it.

use crate::error::{Error, Result};
use crate::ray::{clip_box, Ray};
use crate::volume::Volume;

pub mod adaptive;
pub mod area;
mod cone;
pub mod extent;
mod occupancy;
mod receivers;
mod umbra;
pub use area::{Area, Shape};
pub use extent::{Extent, Reach, SoftLight};
pub use occupancy::Occupancy;
pub use receivers::{Receiver, SoftAnswer, RAYS_PER_BATCH};

/// The light a job names by position or direction (a USD stage's own lights are read from the
/// stage, `light` of the read options): the one declaration of the light keys, flattened into
/// `umbra bake`'s and `umbra query`'s flags, a job's `[bake]` and the Python keywords.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default)]
pub struct LightOptions {
    /// Direction the light travels, DX,DY,DZ (a sun): a map is orthographic, framing the
    /// volume box (with light-pos it aims the perspective map); a query traces from --at
    /// against it until the ray leaves the volume box; a transmittance volume is lit by it.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_parser = crate::input::parse_vec3, allow_hyphen_values = true)
    )]
    pub light_dir: Option<[f64; 3]>,
    /// Light position X,Y,Z (a point light): a map is a perspective map from it (aimed at the
    /// volume box centre unless light-dir is given); a query traces the segment from --at to
    /// it; a transmittance volume is lit by it.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_parser = crate::input::parse_vec3, allow_hyphen_values = true)
    )]
    pub light_pos: Option<[f64; 3]>,
    /// With light-dir (or a stage's distant light, over its own `inputs:angle`): the sun's
    /// angular diameter, degrees in [0, 180) (USD's `inputs:angle`; the sun is about 0.53).
    /// Queries (`--at`, `--positions`), maps (each texel at its receiver, receiver-depth) and
    /// transmittance volumes (each voxel centre) then answer the mean transmittance over the
    /// sun's disc (docs/lights.md); 0 is the point light exactly.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "DEG", allow_negative_numbers = true)
    )]
    pub light_angle: Option<f64>,
    /// With light-pos (or a stage light at a position, over its own size): a sphere light's
    /// radius (world units). Queries, maps and transmittance volumes then answer the mean
    /// transmittance over the sphere's visible surface at each receiver (docs/lights.md); 0 is
    /// the point light exactly.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "R", allow_negative_numbers = true)
    )]
    pub light_radius: Option<f64>,
    /// With light-angle or light-radius: exactly N directions per receiver, in 16 randomised
    /// quasi-Monte Carlo replicates (rounded up to a multiple of 16; at least 64, at most
    /// 1048576). Without it each receiver traces as many as its error bar needs to reach
    /// target-error (default 5e-3; docs/lights.md).
    #[cfg_attr(feature = "cli", arg(long, value_name = "N"))]
    pub light_samples: Option<u32>,
    /// With light-angle or light-radius and no light-samples: the most directions a receiver
    /// may trace to reach the target error, its pilot's included (default 16384, at least 128);
    /// receivers that reach it are counted in the report.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N"))]
    pub light_max_samples: Option<u32>,
}

impl LightOptions {
    /// The light these options give when exactly one of `light_dir` (a directional light)
    /// and `light_pos` (a point light) is: the one place the light keys become a [`Light`].
    /// `None` when neither or both are given (each product words what it needs).
    #[must_use]
    pub fn light(&self) -> Option<Light> {
        match (self.light_dir, self.light_pos) {
            (Some(dir), None) => Some(Light::Directional { dir }),
            (None, Some(pos)) => Some(Light::Point { pos }),
            _ => None,
        }
    }

    /// The first key of a light with extent that is given (`light-angle`, `light-radius`,
    /// `light-samples`, `light-max-samples`), by the library's name.
    #[must_use]
    pub fn extent_key(&self) -> Option<&'static str> {
        [
            ("light-angle", self.light_angle.is_some()),
            ("light-radius", self.light_radius.is_some()),
            ("light-samples", self.light_samples.is_some()),
            ("light-max-samples", self.light_max_samples.is_some()),
        ]
        .into_iter()
        .find_map(|(k, given)| given.then_some(k))
    }

    /// Refuse the keys of a light with extent for a product that does not answer them yet
    /// (`what`: the product and where the keys go instead): never silently dropped.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the first such key given.
    pub fn refuse_extent(&self, what: &str) -> Result<()> {
        match self.extent_key() {
            Some(k) => Err(Error::InvalidArgument {
                name: k.into(),
                reason: format!("does not apply to {what} (lights with extent: docs/lights.md)"),
            }),
            None => Ok(()),
        }
    }

    /// The light with extent these options give ([`SoftLight`]), checked: `None` when no
    /// extent is given or it is 0 (the point light, answered as today, bit for bit).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `light-angle`, `light-radius` or `light-samples`:
    /// negative or non-finite values, an angle of 180 degrees or more, an angle without
    /// light-dir, a radius without light-pos, samples without either, 0 samples or more than
    /// [`extent::MAX_LIGHT_SAMPLES`].
    pub fn soft(&self) -> Result<Option<SoftLight>> {
        extent::check(self)
    }

    /// The keys of a light with extent applied to a light given elsewhere (a USD stage's
    /// light, toward which `query --positions` and a query at a point on a stage answer):
    /// `light-angle` makes a directional light a sun of that angular diameter, `light-radius`
    /// makes a light at a position a sphere light; these options' own `light-dir` and
    /// `light-pos` are not read. `None` when no extent is given or it is 0 (the light as a
    /// point, bit for bit).
    ///
    /// # Errors
    /// As [`LightOptions::soft`], and [`Error::InvalidArgument`] naming `light-angle` for a
    /// light at a position or `light-radius` for a directional light.
    pub fn soft_toward(&self, light: Light) -> Result<Option<SoftLight>> {
        self.check_extent()?;
        let wrong = |name: &str, reason: &str| Error::InvalidArgument {
            name: name.into(),
            reason: format!("{reason} ({light})"),
        };
        match light {
            Light::Point { .. } if self.light_angle.is_some() => Err(wrong(
                "light-angle",
                "is a sun's angular diameter, and the light is at a position: give light-radius",
            )),
            Light::Directional { .. } if self.light_radius.is_some() => Err(wrong(
                "light-radius",
                "is a sphere light's radius, and the light is directional: give light-angle",
            )),
            _ => Self {
                light_dir: light.direction(),
                light_pos: light.position(),
                ..self.clone()
            }
            .soft(),
        }
    }

    /// The light with extent toward a stage light `e`: the flags' extent over the stage's
    /// (`light-angle` or `light-radius` given: [`LightOptions::soft_toward`], 0 tracing it as
    /// a point), else the stage light's own ([`SoftLight::of_emitter`]: a distant light's
    /// angle, a sphere's radius, a disk, rect or cylinder) with `light-samples` directions.
    /// `None`: the light as a point.
    ///
    /// # Errors
    /// As [`LightOptions::soft_toward`] and [`SoftLight::of_emitter`].
    pub fn soft_of_stage(&self, e: crate::usd::Emitter) -> Result<Option<SoftLight>> {
        if self.light_angle.is_some() || self.light_radius.is_some() {
            return self.soft_toward(Light::from(e));
        }
        SoftLight::of_emitter(e, extent::count(self)?)
    }

    /// Check the keys of a light with extent before the light they apply to is known (a
    /// stage's): each value on its own, and not both an angle and a radius.
    ///
    /// # Errors
    /// As [`LightOptions::soft`]; [`Error::Conflict`] for both `light-angle` and
    /// `light-radius`.
    pub fn check_extent(&self) -> Result<()> {
        extent::values(self)?;
        if self.light_angle.is_some() && self.light_radius.is_some() {
            return Err(Error::Conflict {
                names: vec!["light-angle".into(), "light-radius".into()],
                reason: "give {0} (a sun) or {1} (a sphere light), not both".into(),
            });
        }
        Ok(())
    }
}

/// Where a shading point's light comes from.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Light {
    /// A directional light travelling along `dir` (from the light into the scene).
    Directional {
        /// Direction the light travels (any length but zero).
        dir: [f64; 3],
    },
    /// A point light at `pos`.
    Point {
        /// World position.
        pos: [f64; 3],
    },
}

impl From<crate::usd::Emitter> for Light {
    /// The light a stage light is traced as: every site that answers toward a stage light
    /// (queries, per-point answers, bakes through [`Light::direction`] / [`Light::position`])
    /// maps its emitter here.
    fn from(e: crate::usd::Emitter) -> Self {
        match e {
            crate::usd::Emitter::Directional { dir, .. } => Self::Directional { dir },
            crate::usd::Emitter::Point { pos }
            | crate::usd::Emitter::Sphere { pos, .. }
            | crate::usd::Emitter::Disk { pos, .. }
            | crate::usd::Emitter::Rect { pos, .. }
            | crate::usd::Emitter::Cylinder { pos, .. } => Self::Point { pos },
        }
    }
}

/// The light as a transmittance volume's `umbra:light` metadata names it
/// (`directional [x, y, z]`, `point [x, y, z]`).
impl std::fmt::Display for Light {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Directional { dir } => write!(f, "directional {dir:?}"),
            Self::Point { pos } => write!(f, "point {pos:?}"),
        }
    }
}

impl Light {
    /// The direction a directional light travels (a bake's `light-dir`); `None` for a light
    /// at a position.
    #[must_use]
    pub fn direction(&self) -> Option<[f64; 3]> {
        match *self {
            Self::Directional { dir } => Some(dir),
            Self::Point { .. } => None,
        }
    }

    /// Where a light at a position is traced from (a bake's `light-pos`); `None` for a
    /// directional light.
    #[must_use]
    pub fn position(&self) -> Option<[f64; 3]> {
        match *self {
            Self::Directional { .. } => None,
            Self::Point { pos } => Some(pos),
        }
    }

    /// The ray from the world point `at` toward the light: for a point light the segment from
    /// `at` to the light; for a directional light the ray `at - t dir / |dir|`, `t` in
    /// `[0, t_exit]`, where `t_exit` is where it leaves the volume box (0 if it never meets it),
    /// so a non-zero background counts only inside the box.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a zero or non-finite direction or point.
    pub fn ray_from(&self, vol: &Volume, at: [f64; 3]) -> Result<Ray> {
        self.ray_from_boxes(at, |back| {
            vol.box_index()
                .and_then(|(lo, hi)| clip_box(vol.to_index(at), vol.to_index_dir(back), lo, hi))
                .map_or(0.0, |(_, t1)| t1.max(0.0))
        })
    }

    /// The ray from `at` toward the light through a scene: for a directional light, until it
    /// leaves every volume's box (fog volumes: their index boxes; solids: the world bounding
    /// box of their corners).
    ///
    /// # Errors
    /// As [`Light::ray_from`].
    pub fn ray_from_scene(&self, scene: &crate::scene::Scene, at: [f64; 3]) -> Result<Ray> {
        // From a point farther than `scene::FAR` box sizes, the exit is computed to a few
        // ulps of `t` (2 world units at 1e16): it is taken 8 ulps on, and the walk, moved next
        // to the boxes (`Scene::localise`), clips the ray to each box itself.
        let size = scene
            .world_box()
            .map_or(f64::INFINITY, |(lo, hi)| (hi - lo).max_element());
        self.ray_from_boxes(at, |back| {
            scene
                .box_exit(glam::DVec3::from_array(at), back)
                .map_or(0.0, |t| {
                    if t > crate::scene::FAR * size {
                        t + 8.0 * f64::EPSILON * t
                    } else {
                        t
                    }
                })
        })
    }

    /// The ray from `at` toward the light; a directional light's ends at `exit(back)`.
    fn ray_from_boxes(&self, at: [f64; 3], exit: impl Fn(glam::DVec3) -> f64) -> Result<Ray> {
        match *self {
            Self::Point { pos } => Ray::between(at, pos),
            Self::Directional { dir } => {
                let d = crate::math::normalise(glam::DVec3::from_array(dir))
                    .map(|v| v.to_array())
                    .ok_or_else(|| Error::InvalidArgument {
                        name: "light-dir".into(),
                        reason: format!(
                            "{dir:?} has no length; give the direction the light travels"
                        ),
                    })?;
                let back = -glam::DVec3::from_array(d);
                // The line as given: its low direction from `-dir` itself, not the rounded unit.
                Ok(Ray::new(at, back, 0.0, exit(back))?
                    .along_exactly(-glam::DVec3::from_array(dir), glam::DVec3::ZERO))
            }
        }
    }
}
