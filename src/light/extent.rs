//! Lights with extent, first slice (issue 60): a sun with an angular diameter (`light-angle`)
//! and a sphere light with a radius (`light-radius`), answered at one receiver point.
//!
//! **The quantity.** `T_L(x)` is the mean of `T(x -> y)` over the light's visible emitting
//! surface, uniform in the solid angle it subtends at `x` (an unshaped, untextured UsdLux
//! emitter is Lambertian of uniform radiance, so its intensity cancels). A sun is the cone of
//! half-angle `angle / 2` around the direction toward it, each direction traced like a
//! directional light's ray (until it leaves every volume's box); a sphere light seen from
//! outside is the cone toward its centre of half-angle `asin(r / d)`, each segment ending where
//! its direction first meets the sphere; a receiver inside the sphere (or on it) averages over
//! every direction, each segment ending on the sphere. Transmittance is averaged, never optical
//! depth. No receiver cosine: the receiver is a point, not a surface.
//!
//! **The sampling.** Randomised quasi-Monte Carlo: [`REPLICATES`] independent copies of a
//! 2D Fibonacci lattice of `m` points, `((i + 1/2) / m, i / phi) mod 1`, each shifted by its
//! own Cranley-Patterson rotation drawn from [`crate::rng::Rng`] keyed by the query's seed, the
//! replicate and the stage alone ([`Key`]): every receiver of a product traces the same point
//! set (the same directions for a sun, the same points on an area light), and the answers are
//! deterministic whatever the thread count. The lattice maps to the cone by the
//! area-preserving map `cos(theta) = 1 - u (1 - cos(theta_max))`, `phi = 2 pi v`. Each
//! direction's `T` is the chosen estimator's (exact with `regular`), its random streams keyed
//! by the receiver's ray id; its own noise is then inside the replicates' spread. The answer
//! is the mean over every direction, its error bar the replicates' ([`super::adaptive`]).
//!
//! **The count.** `light-samples N`: exactly `N` directions (at least [`MIN_LIGHT_SAMPLES`]).
//! Otherwise as many as the target error asks (Stein's two-stage rule, [`super::adaptive`]),
//! at most `light-max-samples`. A receiver whose whole cone provably misses every volume's
//! box and every solid's box is 1 without sampling, error bar 0.

use super::area::Area;
use super::cone::{misses_everything, safe_length, Cone};
use super::{Light, LightOptions};
use crate::error::{Error, Result};
use crate::ray::Ray;
use crate::rng::Rng;
use crate::scene::Scene;
use glam::DVec3;

/// Independent randomisations of the lattice: the error bar's degrees of freedom plus one.
/// Under normality a mean over `R` replicates is beyond 4 of its error bars `s_R / sqrt(R)`
/// 0.52% of the time at `R = 8` and 0.12% at `R = 16`; with few points per replicate the
/// replicates are far from normal (docs/lights.md), so 16.
pub const REPLICATES: u32 = 16;
/// The fewest points per replicate: `R = 16 x n = 4` kept the share beyond 4 error bars under
/// 0.3% in the research note's penumbrae, where `n = 1` reached 12% (docs/lights.md).
pub const MIN_POINTS: u32 = 4;
/// The fewest directions per receiver `light-samples` may ask for: [`REPLICATES`] x
/// [`MIN_POINTS`].
pub const MIN_LIGHT_SAMPLES: u32 = REPLICATES * MIN_POINTS;
/// The most directions per receiver when the count follows the target error
/// (`light-max-samples`' default), the pilot's included.
pub const DEFAULT_LIGHT_MAX_SAMPLES: u32 = 16384;
/// The error bar each receiver toward a light with extent must reach when neither
/// `light-samples` nor `target-error` is given.
pub const DEFAULT_TARGET_ERROR: f64 = 5e-3;
/// Most directions per receiver: 2^20.
pub const MAX_LIGHT_SAMPLES: u32 = 1 << 20;
/// The stream index of a replicate's rotation (beside the estimator's sample streams).
const ROTATION_STREAM: u64 = 0x5CA1_AB1E_0000_0000;
/// The key of the rotations in place of a ray id: every receiver shares them.
const SHARED_ROTATIONS: u64 = 0x005E_ED0F_D1EC_0000;
/// The stream index of a direction's ray id.
const DIRECTION_STREAM: u64 = 0xD1EC_7104_0000_0000;
/// `1 / phi`, the golden ratio's inverse.
const INV_GOLDEN: f64 = 0.618_033_988_749_894_9;

/// A light's extent: what a point light becomes.
// An area light's frame makes `Area` large; extents are few and copied rarely.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Extent {
    /// A sun of this angular diameter, degrees in (0, 180).
    Sun {
        /// Angular diameter, degrees.
        angle: f64,
    },
    /// A sphere light of this radius (world units, > 0).
    Sphere {
        /// Radius.
        radius: f64,
    },
    /// A disk, rect, cylinder or line light, or a sphere its transform does not keep round,
    /// sampled on its surface and weighted to be uniform in solid angle ([`Area`]).
    Area(Area),
}

/// The extent as reports and headers name it (`umbra:light_extent`, a bake's JSON): `sun
/// 0.53 degrees across`, `sphere of radius 0.5`, and the area lights' shapes and sizes in the
/// light's own space.
impl std::fmt::Display for Extent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use super::area::Shape;
        let n = crate::math::approx;
        match self {
            Self::Sun { angle } => write!(f, "sun {} degrees across", n(*angle)),
            Self::Sphere { radius } => write!(f, "sphere of radius {}", n(*radius)),
            Self::Area(a) => match a.shape() {
                Shape::Disk { radius } => write!(f, "disk of radius {}", n(radius)),
                Shape::Rect { width, height } => {
                    write!(f, "rect {} x {}", n(width), n(height))
                }
                Shape::Cylinder {
                    radius: 0.0,
                    length,
                } => write!(f, "line of length {}", n(length)),
                Shape::Cylinder { radius, length } => write!(
                    f,
                    "cylinder of radius {} and length {}",
                    n(radius),
                    n(length)
                ),
                Shape::Ellipsoid { radius } => {
                    write!(f, "sphere of radius {} under an uneven scale", n(radius))
                }
            },
        }
    }
}

/// A light with extent: its centre (a directional or point [`Light`]), its extent and how
/// many directions each receiver traces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftLight {
    /// The light's centre: `Directional` for a sun, `Point` for a sphere.
    pub light: Light,
    /// Its extent.
    pub extent: Extent,
    /// Directions per receiver (a multiple of [`REPLICATES`]): exactly these with no
    /// `target`, else the most a receiver may take, its pilot's included (`light-max-samples`).
    pub samples: u32,
    /// The error bar each receiver's count is chosen to reach (Stein's two-stage rule,
    /// [`super::adaptive`]); `None`: `samples` directions exactly (`light-samples`).
    pub target: Option<f64>,
}

/// How many directions a receiver traces: `(samples, target)` of [`SoftLight`].
pub type Count = (u32, Option<f64>);

/// The cone from a receiver that holds every segment toward the light, for a proof that no
/// segment meets density: every point `apex + t d`, `d` within `half` of `axis`, `0 <= t <=
/// length`.
#[derive(Debug, Clone, Copy)]
pub struct Reach {
    /// The receiver.
    pub apex: DVec3,
    /// The cone's axis (unit).
    pub axis: DVec3,
    /// Its half-angle, radians (`pi`: every direction).
    pub half: f64,
    /// How far the segments may run.
    pub length: f64,
}

fn bad(name: &str, reason: impl Into<String>) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason: reason.into(),
    }
}

/// The keys of a light with extent, each checked on its own (not yet against the light):
/// the angle, the radius and the directions per receiver (rounded up to a multiple of
/// [`REPLICATES`]).
pub(super) fn values(o: &LightOptions) -> Result<(Option<f64>, Option<f64>, Count)> {
    let value = |name: &str, v: Option<f64>| -> Result<Option<f64>> {
        match v {
            Some(x) if !x.is_finite() => Err(bad(
                name,
                format!("{} is not a finite number", crate::math::short(x)),
            )),
            Some(x) if x < 0.0 => Err(bad(name, format!("{} is negative", crate::math::short(x)))),
            _ => Ok(v),
        }
    };
    let angle = value("light-angle", o.light_angle)?;
    let radius = value("light-radius", o.light_radius)?;
    if let Some(a) = angle.filter(|a| *a >= 180.0) {
        return Err(bad(
            "light-angle",
            format!("{a} degrees is not below 180 (the sun's angular diameter, degrees)"),
        ));
    }
    // Directions per receiver: `light-samples` alone may go with a stage light, whose extent
    // the stage gives; with a given light it needs an angle or a radius (`check`).
    Ok((angle, radius, count(o)?))
}

/// [`LightOptions::soft`]: the keys of a light with extent, checked.
pub(super) fn check(o: &LightOptions) -> Result<Option<SoftLight>> {
    let (angle, radius, samples) = values(o)?;
    // The light the keys give: with light-pos (and light-dir aiming a map from it) the point
    // at light-pos, whose extent is a radius; light-dir alone, a sun.
    let light = match (o.light_dir, o.light_pos) {
        (_, Some(pos)) => Some(Light::Point { pos }),
        (Some(dir), None) => Some(Light::Directional { dir }),
        (None, None) => None,
    };
    if angle.is_some() && o.light_dir.is_some() && o.light_pos.is_some() {
        return Err(bad(
            "light-angle",
            "is a sun's angular diameter, and with light-pos the light is the point there \
             (light-dir only aims the map): give light-radius for its size",
        ));
    }
    if angle.is_some() && o.light_dir.is_none() {
        return Err(bad(
            "light-angle",
            "is a sun's angular diameter: it goes with light-dir",
        ));
    }
    if radius.is_some() && o.light_pos.is_none() {
        return Err(bad(
            "light-radius",
            "is a sphere light's radius: it goes with light-pos",
        ));
    }
    let count_key = [
        ("light-samples", o.light_samples.is_some()),
        ("light-max-samples", o.light_max_samples.is_some()),
    ]
    .into_iter()
    .find_map(|(k, given)| given.then_some(k));
    if let Some(k) = count_key.filter(|_| light.is_some() && angle.is_none() && radius.is_none()) {
        return Err(bad(
            k,
            "samples a light with extent: give light-angle or light-radius (or a stage's light)",
        ));
    }
    let extent = match (angle, radius) {
        (Some(a), _) if a > 0.0 => Extent::Sun { angle: a },
        (_, Some(r)) if r > 0.0 => Extent::Sphere { radius: r },
        _ => return Ok(None),
    };
    Ok(light.map(|light| SoftLight {
        light,
        extent,
        samples: samples.0,
        target: samples.1,
    }))
}

/// The directions traced per receiver from the `light-samples` and `light-max-samples` keys:
/// `light-samples` given, exactly that many (rounded up to a multiple of [`REPLICATES`]);
/// else as many as [`DEFAULT_TARGET_ERROR`] asks, at most `light-max-samples` (default
/// [`DEFAULT_LIGHT_MAX_SAMPLES`]).
///
/// # Errors
/// [`Error::InvalidArgument`] naming `light-samples` below [`MIN_LIGHT_SAMPLES`] or above
/// [`MAX_LIGHT_SAMPLES`], or `light-max-samples` below what the pilot and the least final
/// stage take or above [`MAX_LIGHT_SAMPLES`]; [`Error::Conflict`] for both keys.
pub fn count(o: &LightOptions) -> Result<Count> {
    let most = |name: &str, n: u32| {
        if n > MAX_LIGHT_SAMPLES {
            Err(bad(
                name,
                format!(
                    "{n} directions per receiver is beyond the work budget: at most \
                     {MAX_LIGHT_SAMPLES}"
                ),
            ))
        } else {
            Ok(n.div_ceil(REPLICATES) * REPLICATES)
        }
    };
    match (o.light_samples, o.light_max_samples) {
        (Some(_), Some(_)) => Err(Error::Conflict {
            names: vec!["light-samples".into(), "light-max-samples".into()],
            reason: "{0} asks for exactly that many directions, {1} caps the count the target \
                     error chooses: give one"
                .into(),
        }),
        (Some(n), None) if n < MIN_LIGHT_SAMPLES => Err(bad(
            "light-samples",
            format!(
                "{n} directions cannot give an honest error bar: at least {MIN_LIGHT_SAMPLES} \
                 ({REPLICATES} replicates of {MIN_POINTS} points; docs/lights.md)"
            ),
        )),
        (Some(n), None) => Ok((most("light-samples", n)?, None)),
        (None, max) => {
            let max = max.unwrap_or(DEFAULT_LIGHT_MAX_SAMPLES);
            // The pilot and as many again: room for the count to grow.
            let least = 2 * super::adaptive::LEAST_ADAPTIVE;
            if max < least {
                return Err(bad(
                    "light-max-samples",
                    format!(
                        "{max} leaves no room after the pilot's {} directions: at least \
                         {least}",
                        super::adaptive::LEAST_ADAPTIVE
                    ),
                ));
            }
            Ok((most("light-max-samples", max)?, Some(DEFAULT_TARGET_ERROR)))
        }
    }
}

/// Whether the rows `axes` are orthogonal and of one length (within `1e-9` relative): a
/// sphere under them stays a sphere, of radius times that length.
fn round(axes: &[[f64; 3]; 3]) -> Option<f64> {
    let v = axes.map(DVec3::from_array);
    let l = v.map(DVec3::length);
    let tol = 1e-9 * l[0];
    let same = (l[1] - l[0]).abs() <= tol && (l[2] - l[0]).abs() <= tol;
    let square = v[0].dot(v[1]).abs() <= tol * l[0]
        && v[0].dot(v[2]).abs() <= tol * l[0]
        && v[1].dot(v[2]).abs() <= tol * l[0];
    (same && square && l[0].is_finite() && l[0] > 0.0).then_some(l[0])
}

/// The rays of one receiver toward a light with extent, their ray ids, and the ray toward the
/// light's centre (what `length` reports).
#[derive(Debug, Clone)]
pub struct SoftRays {
    /// One ray per direction, replicate after replicate (empty when the cone provably misses
    /// everything: the answer is then 1).
    pub rays: Vec<Ray>,
    /// Each ray's id (its estimator's random streams).
    pub ids: Vec<u64>,
    /// Each ray's weight (an area light's, [`Area`]); empty when every ray weighs the same.
    pub weights: Vec<f64>,
    /// Where each replicate's rays end in `rays` (one entry per replicate; empty with no
    /// rays).
    pub ends: Vec<usize>,
    /// The ray toward the light's centre.
    pub centre: Ray,
    /// The receiver provably sees none of the light's emitting side (behind a one-sided
    /// light, inside a cylinder light): no light reaches it, and the answer is 1 by
    /// convention (docs/lights.md).
    pub unlit: bool,
}

impl SoftLight {
    /// The light with extent a stage's light is, traced with `samples` directions per
    /// receiver ([`count`]): its centre is `Light::from(e)`; `None` for a point (a distant
    /// light of angle 0, `treatAsPoint`, a shape of no size): today's point light, bit for
    /// bit. A sphere its transform keeps round is the exact cone of a sphere light of the
    /// scaled radius; any other shape is an [`Area`].
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a shape [`Area::new`] refuses.
    pub fn of_emitter(e: crate::usd::Emitter, samples: Count) -> Result<Option<Self>> {
        use super::area::Shape;
        use crate::usd::Emitter as E;
        let area = |shape, pos, axes| Area::new(shape, pos, axes).map(Extent::Area);
        let extent = match e {
            E::Directional { angle, .. } if angle > 0.0 => Extent::Sun { angle },
            E::Directional { .. } | E::Point { .. } => return Ok(None),
            E::Sphere { pos, radius, axes } => match round(&axes) {
                Some(scale) => Extent::Sphere {
                    radius: radius * scale,
                },
                None => area(Shape::Ellipsoid { radius }, pos, axes)?,
            },
            E::Disk { pos, radius, axes } => area(Shape::Disk { radius }, pos, axes)?,
            E::Rect {
                pos,
                width,
                height,
                axes,
            } => area(Shape::Rect { width, height }, pos, axes)?,
            E::Cylinder {
                pos,
                radius,
                length,
                axes,
            } => area(Shape::Cylinder { radius, length }, pos, axes)?,
        };
        Ok(Some(Self {
            light: Light::from(e),
            extent,
            samples: samples.0,
            target: samples.1,
        }))
    }

    /// The cone from `at` toward the light.
    fn cone(&self, at: DVec3) -> Result<Cone> {
        match (self.light, self.extent) {
            (Light::Directional { dir }, Extent::Sun { angle }) => {
                let axis = crate::math::normalise(-DVec3::from_array(dir)).ok_or_else(|| {
                    bad(
                        "light-dir",
                        format!("{dir:?} has no length; give the direction the light travels"),
                    )
                })?;
                let half = angle.to_radians() / 2.0;
                let s = (half / 2.0).sin();
                Ok(Cone::Cap {
                    axis,
                    axis_lo: DVec3::ZERO,
                    one_minus_cos: 2.0 * s * s,
                })
            }
            (Light::Point { pos }, Extent::Sphere { radius }) => {
                let pos = DVec3::from_array(pos);
                // What `pos - at` rounds away, so that a far receiver's cone keeps its axis.
                let lo = DVec3::from_array(std::array::from_fn(|k| {
                    crate::math::two_sum(pos[k], -at[k]).1
                }));
                Ok(Cone::toward(pos - at, lo, radius))
            }
            // The cone about the sphere that holds the whole surface: it holds every segment.
            (_, Extent::Area(a)) => Ok(Cone::toward(a.centre() - at, DVec3::ZERO, a.bound())),
            _ => Err(bad(
                "light-angle",
                "a sun's angle goes with light-dir, a sphere's radius with light-pos",
            )),
        }
    }

    /// The ray from `at` along the unit direction `d` (`d + d_lo` exactly) toward the light.
    fn ray(&self, scene: &Scene, at: DVec3, (d, d_lo): (DVec3, DVec3)) -> Result<Ray> {
        match (self.light, self.extent) {
            (Light::Point { pos }, Extent::Sphere { radius }) => {
                // In units of the distance to the centre, so a light at 1e300 does not
                // overflow: t = L (b - sqrt(b^2 - 1 + q^2)), q = r / L.
                let c = DVec3::from_array(pos) - at;
                let l = safe_length(c);
                let (b, q) = if l > 0.0 {
                    (d.dot(c / l), radius / l)
                } else {
                    (0.0, 1.0)
                };
                let root = (b * b - (1.0 - q * q)).max(0.0).sqrt();
                // Outside: the nearer crossing; inside: the only one ahead.
                let t = if l > radius {
                    l * (b - root)
                } else if l > 0.0 {
                    l * (b + root)
                } else {
                    radius
                };
                Ok(Ray::new(at, d, 0.0, t.max(0.0))?.along_exactly(d, d_lo))
            }
            _ => Light::Directional {
                dir: (-d).to_array(),
            }
            .ray_from_scene(scene, at.to_array()),
        }
    }

    /// The rays from the receiver `at` toward the light: `m` points per replicate, each
    /// replicate's lattice rotated by a draw keyed by `seed`, the replicate and `stage`
    /// alone (the same directions for every receiver: `(seed, stage)` name a point set), each
    /// direction's estimator streams keyed by `seed`, `ray_id`, `stage` and the direction.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a zero or non-finite direction, position or receiver.
    pub fn rays(&self, scene: &Scene, at: [f64; 3], key: Key, m: u32) -> Result<SoftRays> {
        self.replicates(scene, at, key, m, 0..REPLICATES)
    }

    /// [`SoftLight::rays`] for the replicates `reps` of the stage alone: replicate `r`'s
    /// rotation is keyed by `(seed, stage, r)`, so replicates `16..n` of a stage continue its
    /// first 16 with independent rotations of the same lattice (Stein's extra replicates,
    /// [`super::adaptive`]).
    ///
    /// # Errors
    /// As [`SoftLight::rays`].
    pub fn replicates(
        &self,
        scene: &Scene,
        at: [f64; 3],
        key: Key,
        m: u32,
        reps: std::ops::Range<u32>,
    ) -> Result<SoftRays> {
        let p = DVec3::from_array(at);
        if !p.is_finite() {
            return Err(bad(
                "at",
                format!("{} is not a finite point", crate::math::short3(at)),
            ));
        }
        let cone = self.cone(p)?;
        let centre = self
            .light
            .ray_from_scene(scene, at)
            .or_else(|_| self.ray(scene, p, cone.direction_dd(0.0, 0.0)))?;
        let unlit = matches!(self.extent, Extent::Area(a) if a.unlit(p));
        let mut out = SoftRays {
            rays: Vec::new(),
            ids: Vec::new(),
            weights: Vec::new(),
            ends: Vec::new(),
            centre,
            unlit,
        };
        if unlit || misses_everything(scene, p, cone) {
            return Ok(out);
        }
        let total = (reps.len() as u32 * m) as usize;
        out.rays.reserve(total);
        out.ids.reserve(total);
        for r in u64::from(reps.start)..u64::from(reps.end) {
            let mut rng = Rng::new(key.seed, SHARED_ROTATIONS | key.stage, ROTATION_STREAM | r);
            let (du, dv) = (rng.uniform(), rng.uniform());
            for i in 0..m {
                let fi = f64::from(i);
                let u = ((fi + 0.5) / f64::from(m) + du).fract();
                let v = (fi * INV_GOLDEN + dv).fract();
                let ray = match self.extent {
                    Extent::Area(a) => match a.point(p, u, v) {
                        (_, w) if w <= 0.0 => continue,
                        (y, w) => {
                            out.weights.push(w);
                            Ray::between(p, y)?
                        }
                    },
                    _ => self.ray(scene, p, cone.direction_dd(u, v))?,
                };
                out.rays.push(ray);
                let k = (key.stage << 40) | (r * u64::from(m) + u64::from(i));
                out.ids
                    .push(Rng::new(key.seed, key.ray_id, DIRECTION_STREAM | k).next_u64());
            }
            out.ends.push(out.rays.len());
        }
        Ok(out)
    }

    /// The cone from `at` that holds every segment toward the light, however it is sampled
    /// (what a proof that `T = 1` must cover): a sun's cap of half-angle `angle / 2`, as long
    /// as the farthest corner of the scene's boxes; the cone toward a sphere light's (or an area
    /// light's bounding) sphere of radius `r` at distance `d`, half-angle `asin(r / d)`, length
    /// `d + r`; every direction (`pi`) from inside it.
    ///
    /// # Errors
    /// As [`SoftLight::rays`].
    pub fn reach(&self, scene: &Scene, at: [f64; 3]) -> Result<Reach> {
        let p = DVec3::from_array(at);
        let cone = self.cone(p)?;
        let (axis, half) = match cone {
            Cone::Cap {
                axis,
                one_minus_cos,
                ..
            } => (
                axis,
                2.0 * (one_minus_cos / 2.0).clamp(0.0, 1.0).sqrt().asin(),
            ),
            Cone::All => (DVec3::Z, std::f64::consts::PI),
        };
        let far = |c: DVec3, r: f64| safe_length(c - p) + r;
        let length = match (self.light, self.extent) {
            (Light::Point { pos }, Extent::Sphere { radius }) => {
                far(DVec3::from_array(pos), radius)
            }
            (_, Extent::Area(a)) => far(a.centre(), a.bound()),
            _ => scene.world_box().map_or(0.0, |(lo, hi)| {
                (0..8)
                    .map(|k| {
                        let c = DVec3::new(
                            if k & 1 == 0 { lo.x } else { hi.x },
                            if k & 2 == 0 { lo.y } else { hi.y },
                            if k & 4 == 0 { lo.z } else { hi.z },
                        );
                        far(c, 0.0)
                    })
                    .fold(0.0, f64::max)
            }),
        };
        Ok(Reach {
            apex: p,
            axis,
            half,
            length,
        })
    }

    /// How far every segment of the light's `reach` from its apex runs at least (what a
    /// lower bound on optical depth may march, [`super::umbra`]): a sun's run until they
    /// leave every volume's box, as far as `reach`; a sphere light's end on the sphere, at
    /// least `d - r` away from a receiver outside it. `None` for a receiver inside the
    /// sphere and for area lights.
    #[must_use]
    pub fn shortest(&self, reach: &Reach) -> Option<f64> {
        match (self.light, self.extent) {
            (Light::Directional { .. }, Extent::Sun { .. }) => Some(reach.length),
            (Light::Point { pos }, Extent::Sphere { radius }) => {
                let d = (DVec3::from_array(pos) - reach.apex).length();
                (d > radius).then_some((d - radius) * (1.0 - 1e-12))
            }
            _ => None,
        }
    }

    /// This light with the error bar `target` each receiver's count is chosen to reach (a
    /// product's `target-error`); `None` keeps it as it is.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `name` for a target that is not a finite number in
    /// `(0, 1)`; [`Error::Conflict`] when `light-samples` fixed the count.
    pub fn with_target(self, target: Option<f64>, name: &str) -> Result<Self> {
        let Some(e) = target else {
            return Ok(self);
        };
        if !(e.is_finite() && e > 0.0 && e < 1.0) {
            return Err(bad(
                name,
                format!(
                    "{} is not an error bar in (0, 1) (a transmittance's standard error)",
                    crate::math::short(e)
                ),
            ));
        }
        if self.target.is_none() {
            return Err(Error::Conflict {
                names: vec![name.into(), "light-samples".into()],
                reason: "{1} asks for exactly that many directions per receiver, {0} for as \
                         many as its error bar needs: give one"
                    .into(),
            });
        }
        Ok(Self {
            target: Some(e),
            ..self
        })
    }
}

/// What keys a receiver's directions: the seed and the stage name the shared point set, the
/// ray id the receiver's own estimator streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Key {
    /// The query's seed.
    pub seed: u64,
    /// The receiver's ray id.
    pub ray_id: u64,
    /// The stage: 0 a fixed count, 1 a target error's replicates (its pilot's 16 and the
    /// extra ones the pilot asks for).
    pub stage: u64,
}
