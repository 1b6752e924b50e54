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
//! own Cranley-Patterson rotation drawn from [`crate::rng::Rng`] keyed by the query's seed and
//! ray id (deterministic whatever the thread count), mapped to the cone by the area-preserving
//! map `cos(theta) = 1 - u (1 - cos(theta_max))`, `phi = 2 pi v`. Each direction's `T` is the
//! chosen estimator's (exact with `regular`); its own noise is then inside the replicates'
//! spread. The answer is the mean over every direction.
//!
//! **The error bar.** `std_err` is the standard deviation of the `R` replicate means over
//! `sqrt(R)`. When every direction gave exactly the same `T0`, the spread is 0 and could hide a
//! feature between the points: a fraction `p <= min(1, 3 / N)` of the cone (the rule of three,
//! as for independent points) may differ by up to `max(T0, 1 - T0)`, so the error bar is then
//! `max(T0, 1 - T0) sqrt(p / N)`, never 0. It is 0 only when the sun's whole cone provably
//! misses every volume's box and every solid's box: the answer is then 1 without sampling.

use super::area::Area;
use super::{Light, LightOptions};
use crate::error::{Error, Result};
use crate::ray::Ray;
use crate::rng::Rng;
use crate::scene::{Scene, SceneEstimate};
use glam::DVec3;

/// Independent randomisations of the lattice: the error bar's degrees of freedom plus one.
pub const REPLICATES: u32 = 8;
/// Directions per receiver when `light-samples` is not given: 8 replicates of 32 points,
/// measured to reach `std_err <= 5e-3` in the penumbrae of `data/cloud.vdb` at density scale 4
/// (docs/lights.md).
pub const DEFAULT_LIGHT_SAMPLES: u32 = 256;
/// Most directions per receiver: 2^20.
pub const MAX_LIGHT_SAMPLES: u32 = 1 << 20;
/// The stream index of a replicate's rotation (beside the estimator's sample streams).
const ROTATION_STREAM: u64 = 0x5CA1_AB1E_0000_0000;
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

/// A light with extent: its centre (a directional or point [`Light`]), its extent and the
/// directions traced per receiver (a multiple of [`REPLICATES`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftLight {
    /// The light's centre: `Directional` for a sun, `Point` for a sphere.
    pub light: Light,
    /// Its extent.
    pub extent: Extent,
    /// Directions per receiver.
    pub samples: u32,
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
pub(super) fn values(o: &LightOptions) -> Result<(Option<f64>, Option<f64>, u32)> {
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
    Ok((angle, radius, samples(o.light_samples)?))
}

/// [`LightOptions::soft`]: the keys of a light with extent, checked.
pub(super) fn check(o: &LightOptions) -> Result<Option<SoftLight>> {
    let (angle, radius, samples) = values(o)?;
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
    if o.light_samples.is_some() && o.light().is_some() && angle.is_none() && radius.is_none() {
        return Err(bad(
            "light-samples",
            "samples a light with extent: give light-angle or light-radius (or a stage's light)",
        ));
    }
    let extent = match (angle, radius) {
        (Some(a), _) if a > 0.0 => Extent::Sun { angle: a },
        (_, Some(r)) if r > 0.0 => Extent::Sphere { radius: r },
        _ => return Ok(None),
    };
    Ok(o.light().map(|light| SoftLight {
        light,
        extent,
        samples,
    }))
}

/// The directions traced per receiver for the `light-samples` key: the default when it is not
/// given, else rounded up to a multiple of [`REPLICATES`].
///
/// # Errors
/// [`Error::InvalidArgument`] naming `light-samples` for 0 or more than
/// [`MAX_LIGHT_SAMPLES`].
pub fn samples(given: Option<u32>) -> Result<u32> {
    match given {
        None => Ok(DEFAULT_LIGHT_SAMPLES),
        Some(0) => Err(bad("light-samples", "must be at least 1")),
        Some(n) if n > MAX_LIGHT_SAMPLES => Err(bad(
            "light-samples",
            format!(
                "{n} directions per receiver is beyond the work budget: at most \
                 {MAX_LIGHT_SAMPLES}"
            ),
        )),
        Some(n) => Ok(n.div_ceil(REPLICATES) * REPLICATES),
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

/// The cone of directions from a receiver toward the light.
#[derive(Debug, Clone, Copy)]
enum Cone {
    /// Directions within `acos(1 - one_minus_cos)` of `axis` (`axis + axis_lo` in
    /// double-double: a sphere light 1e16 away subtends 1e-17 radians, below a unit vector's
    /// rounding, and its directions keep it only so).
    Cap {
        axis: DVec3,
        axis_lo: DVec3,
        one_minus_cos: f64,
    },
    /// Every direction (a receiver inside a sphere light).
    All,
}

impl Cone {
    /// The cone from a receiver that sees a sphere of radius `radius` at the offset `v`
    /// (`v + v_lo` exactly): every direction when the receiver is inside it.
    fn toward(v: DVec3, v_lo: DVec3, radius: f64) -> Self {
        let d = safe_length(v);
        if d.is_nan() || d <= radius {
            return Self::All;
        }
        let s = radius / d;
        let axis = v / d;
        Self::Cap {
            axis,
            axis_lo: crate::ray::unit_lo(v, v_lo, axis),
            one_minus_cos: s * s / (1.0 + (1.0 - s * s).max(0.0).sqrt()),
        }
    }

    /// `1 - cos(theta_max)`.
    fn one_minus_cos(self) -> f64 {
        match self {
            Self::Cap { one_minus_cos, .. } => one_minus_cos,
            Self::All => 2.0,
        }
    }

    /// The direction of the lattice point `(u, v)` in `[0, 1)^2`, uniform in solid angle:
    /// `b1 sin(theta) cos(phi) + b2 sin(theta) sin(phi) + axis cos(theta)`, with what
    /// rounding left out of it (`(hi, lo)`, double-double): the axis's own low half and the
    /// parts of `cos(theta)` and of the sum a tiny cone loses, so that a direction `1e-17`
    /// off the axis is still off it.
    fn direction_dd(self, u: f64, v: f64) -> (DVec3, DVec3) {
        let omc = self.one_minus_cos();
        let x = u * omc;
        let (cos, cos_lo) = crate::math::two_sum(1.0, -x);
        let sin = (x * (2.0 - x)).max(0.0).sqrt();
        let (s, c) = (std::f64::consts::TAU * v).sin_cos();
        let (axis, axis_lo) = match self {
            Self::Cap { axis, axis_lo, .. } => (axis, axis_lo),
            Self::All => (DVec3::Z, DVec3::ZERO),
        };
        let (b1, b2) = basis(axis);
        let off = b1 * (sin * c) + b2 * (sin * s);
        let hi = off + axis * cos;
        let lo = DVec3::from_array(std::array::from_fn(|k| {
            let (p, pe) = crate::math::two_prod(axis[k], cos);
            let (h, he) = crate::math::two_sum(off[k], p);
            (h - hi[k]) + he + pe + axis[k] * cos_lo + axis_lo[k] * cos
        }));
        (hi, lo)
    }
}

/// An orthonormal basis around the unit vector `n` (Duff et al. 2017, branchless).
pub(super) fn basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0_f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
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
    /// Where each replicate's rays end in `rays` ([`REPLICATES`] entries; empty with no
    /// rays).
    pub ends: Vec<usize>,
    /// The ray toward the light's centre.
    pub centre: Ray,
    /// The receiver provably sees none of the light's emitting side (behind a one-sided
    /// light, inside a cylinder light): no light reaches it, and the answer is 1 by
    /// convention (docs/lights.md).
    pub unlit: bool,
}

/// `|v|` without overflow or underflow in its squares (a light at 1e300).
fn safe_length(v: DVec3) -> f64 {
    let m = v.abs().max_element();
    if m > 0.0 && m.is_finite() {
        m * (v / m).length()
    } else {
        m
    }
}

impl SoftLight {
    /// The light with extent a stage's light is, traced with `samples` directions per
    /// receiver ([`samples`]): its centre is `Light::from(e)`; `None` for a point (a distant
    /// light of angle 0, `treatAsPoint`, a shape of no size): today's point light, bit for
    /// bit. A sphere its transform keeps round is the exact cone of a sphere light of the
    /// scaled radius; any other shape is an [`Area`].
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a shape [`Area::new`] refuses.
    pub fn of_emitter(e: crate::usd::Emitter, samples: u32) -> Result<Option<Self>> {
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
            samples,
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

    /// The rays from the receiver `at` toward the light, keyed by `seed` and `ray_id`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a zero or non-finite direction, position or receiver.
    pub fn rays(&self, scene: &Scene, at: [f64; 3], seed: u64, ray_id: u64) -> Result<SoftRays> {
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
        let m = self.samples / REPLICATES;
        out.rays.reserve(self.samples as usize);
        out.ids.reserve(self.samples as usize);
        for r in 0..u64::from(REPLICATES) {
            let mut rng = Rng::new(seed, ray_id, ROTATION_STREAM | r);
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
                let k = r * u64::from(m) + u64::from(i);
                out.ids
                    .push(Rng::new(seed, ray_id, DIRECTION_STREAM | k).next_u64());
            }
            out.ends.push(out.rays.len());
        }
        Ok(out)
    }
}

/// Whether every ray of the cone from `p` provably misses every volume's box and every
/// solid's box (each box's bounding sphere lies outside the cone): `T = 1` exactly. A sun's
/// rays, a sphere light's segments and an area light's all lie in their cone.
fn misses_everything(scene: &Scene, p: DVec3, cone: Cone) -> bool {
    let Cone::Cap {
        axis,
        one_minus_cos,
        ..
    } = cone
    else {
        return false;
    };
    // Angles from sines (`2 asin(sqrt(omc / 2))`, `atan2(|to x axis|, to . axis)`): an acos
    // of a cosine near 1 is off by 1e-8 radians, far more than a sphere light 1e16 away
    // subtends.
    let half = 2.0 * (one_minus_cos / 2.0).clamp(0.0, 1.0).sqrt().asin();
    let boxes = scene
        .fogs()
        .iter()
        .map(|f| f.volume().box_corners().ok())
        .chain(scene.solids().iter().map(|s| s.box_corners().ok()));
    boxes.flatten().all(|c| {
        let lo = c.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
        let hi = c.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
        let (centre, rho) = ((lo + hi) / 2.0, (hi - lo).length() / 2.0);
        let to = centre - p;
        let dist = to.length();
        if !dist.is_finite() || dist <= rho {
            return false;
        }
        let apart = to.cross(axis).length().atan2(to.dot(axis));
        apart > half + (rho / dist).asin() + 1e-9
    })
}

impl SoftRays {
    /// The answer at one receiver from its directions' estimates, in the order of
    /// [`SoftRays::rays`]: per channel the mean over every direction, the error bar from the
    /// replicates' spread (module docs). No direction: the cone missed everything, `T = 1`.
    #[must_use]
    pub fn combine(&self, channels: usize, per: &[SceneEstimate]) -> SceneEstimate {
        let mut out = SceneEstimate::exact(channels, [0.0; 3], 0, 0);
        out.tau = None;
        if per.is_empty() {
            out.value = [1.0; 3];
            return out;
        }
        let n = per.len();
        let weight = |i: usize| self.weights.get(i).copied().unwrap_or(1.0);
        for c in 0..3 {
            // Per replicate: the weighted sum of T and the weights' sum.
            let mut start = 0;
            let mut sums = Vec::with_capacity(self.ends.len());
            for &end in &self.ends {
                let end = end.min(n);
                let (wt, w) = (start..end).fold((0.0, 0.0), |(wt, w), i| {
                    (wt + weight(i) * per[i].value[c], w + weight(i))
                });
                sums.push((wt, w));
                start = end;
            }
            let total = sums.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            let means: Vec<f64> = sums
                .iter()
                .filter(|(_, w)| *w > 0.0)
                .map(|(wt, w)| wt / w)
                .collect();
            let mean = if self.weights.is_empty() {
                // Equal replicates: the mean of their means.
                means.iter().sum::<f64>() / means.len().max(1) as f64
            } else {
                total.0 / total.1
            };
            let r = means.len() as f64;
            let centre = means.iter().sum::<f64>() / r.max(1.0);
            let var = means.iter().map(|x| (x - centre).powi(2)).sum::<f64>() / (r - 1.0).max(1.0);
            let (lo, hi) = per
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
                    (a.min(e.value[c]), b.max(e.value[c]))
                });
            out.value[c] = mean;
            out.std_err[c] = if lo == hi {
                let p = (crate::estimate::error_bar::RULE_OF_THREE / n as f64).min(1.0);
                mean.max(1.0 - mean) * (p / n as f64).sqrt()
            } else if means.len() < 2 {
                // One replicate saw the light: no spread to measure, the widest bar.
                mean.max(1.0 - mean)
            } else {
                (var / r).sqrt()
            };
        }
        out.lookups = per.iter().map(|e| e.lookups).sum();
        out.segments = per.iter().map(|e| e.segments).sum();
        out.samples = per.iter().map(|e| e.samples).max().unwrap_or(1);
        out.capped = per.iter().map(|e| e.capped).sum();
        out.majorant_violations = per.iter().map(|e| e.majorant_violations).sum();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directions_stay_in_the_cone_and_are_unit() {
        let axis = DVec3::new(0.3, -0.8, 0.2).normalize();
        let omc = 1.0 - 4f64.to_radians().cos();
        let cone = Cone::Cap {
            axis,
            axis_lo: DVec3::ZERO,
            one_minus_cos: omc,
        };
        for (u, v) in [(0.0, 0.0), (0.999, 0.5), (0.5, 0.25), (1.0, 0.9)] {
            let d = cone.direction_dd(u, v).0;
            assert!((d.length() - 1.0).abs() < 1e-12);
            assert!(d.dot(axis) >= 1.0 - omc - 1e-12);
        }
        // u = 1 is the rim, u = 0 the axis.
        assert!((cone.direction_dd(1.0, 0.3).0.dot(axis) - (1.0 - omc)).abs() < 1e-12);
        assert!((cone.direction_dd(0.0, 0.3).0.dot(axis) - 1.0).abs() < 1e-12);
    }
}
