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
            Some(x) if !x.is_finite() => Err(bad(name, format!("{x} is not a finite number"))),
            Some(x) if x < 0.0 => Err(bad(name, format!("{x} is negative"))),
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
    let samples = match o.light_samples {
        None => DEFAULT_LIGHT_SAMPLES,
        Some(_) if angle.is_none() && radius.is_none() => {
            return Err(bad(
                "light-samples",
                "samples a light with extent: give light-angle or light-radius",
            ))
        }
        Some(0) => return Err(bad("light-samples", "must be at least 1")),
        Some(n) if n > MAX_LIGHT_SAMPLES => {
            return Err(bad(
                "light-samples",
                format!("{n} directions per receiver is beyond the work budget: at most {MAX_LIGHT_SAMPLES}"),
            ))
        }
        Some(n) => n.div_ceil(REPLICATES) * REPLICATES,
    };
    Ok((angle, radius, samples))
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

/// The cone of directions from a receiver toward the light.
#[derive(Debug, Clone, Copy)]
enum Cone {
    /// Directions within `acos(1 - one_minus_cos)` of `axis`.
    Cap { axis: DVec3, one_minus_cos: f64 },
    /// Every direction (a receiver inside a sphere light).
    All,
}

impl Cone {
    /// `1 - cos(theta_max)`.
    fn one_minus_cos(self) -> f64 {
        match self {
            Self::Cap { one_minus_cos, .. } => one_minus_cos,
            Self::All => 2.0,
        }
    }

    /// The direction of the lattice point `(u, v)` in `[0, 1)^2`, uniform in solid angle.
    fn direction(self, u: f64, v: f64) -> DVec3 {
        let omc = self.one_minus_cos();
        let x = u * omc;
        let cos = 1.0 - x;
        let sin = (x * (2.0 - x)).max(0.0).sqrt();
        let (s, c) = (std::f64::consts::TAU * v).sin_cos();
        let axis = match self {
            Self::Cap { axis, .. } => axis,
            Self::All => DVec3::Z,
        };
        let (b1, b2) = basis(axis);
        b1 * (sin * c) + b2 * (sin * s) + axis * cos
    }
}

/// An orthonormal basis around the unit vector `n` (Duff et al. 2017, branchless).
fn basis(n: DVec3) -> (DVec3, DVec3) {
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
    /// The ray toward the light's centre.
    pub centre: Ray,
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
                    one_minus_cos: 2.0 * s * s,
                })
            }
            (Light::Point { pos }, Extent::Sphere { radius }) => {
                let v = DVec3::from_array(pos) - at;
                let d = safe_length(v);
                if d.is_nan() || d <= radius {
                    return Ok(Cone::All);
                }
                let s = radius / d;
                Ok(Cone::Cap {
                    axis: v / d,
                    one_minus_cos: s * s / (1.0 + (1.0 - s * s).max(0.0).sqrt()),
                })
            }
            _ => Err(bad(
                "light-angle",
                "a sun's angle goes with light-dir, a sphere's radius with light-pos",
            )),
        }
    }

    /// The ray from `at` along the unit direction `d` toward the light.
    fn ray(&self, scene: &Scene, at: DVec3, d: DVec3) -> Result<Ray> {
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
                Ray::new(at, d, 0.0, t.max(0.0))
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
            return Err(bad("at", format!("{at:?} is not a finite point")));
        }
        let cone = self.cone(p)?;
        let centre = self
            .light
            .ray_from_scene(scene, at)
            .or_else(|_| self.ray(scene, p, cone.direction(0.0, 0.0)))?;
        if misses_everything(scene, p, cone, self.extent) {
            return Ok(SoftRays {
                rays: Vec::new(),
                ids: Vec::new(),
                centre,
            });
        }
        let m = self.samples / REPLICATES;
        let mut rays = Vec::with_capacity(self.samples as usize);
        let mut ids = Vec::with_capacity(self.samples as usize);
        for r in 0..u64::from(REPLICATES) {
            let mut rng = Rng::new(seed, ray_id, ROTATION_STREAM | r);
            let (du, dv) = (rng.uniform(), rng.uniform());
            for i in 0..m {
                let fi = f64::from(i);
                let u = ((fi + 0.5) / f64::from(m) + du).fract();
                let v = (fi * INV_GOLDEN + dv).fract();
                rays.push(self.ray(scene, p, cone.direction(u, v))?);
                let k = r * u64::from(m) + u64::from(i);
                ids.push(Rng::new(seed, ray_id, DIRECTION_STREAM | k).next_u64());
            }
        }
        Ok(SoftRays { rays, ids, centre })
    }
}

/// Whether every ray of a sun's cone from `p` provably misses every volume's box and every
/// solid's box (each box's bounding sphere lies outside the cone): `T = 1` exactly. A sphere
/// light's segments are not bounded by the boxes, so it is always sampled.
fn misses_everything(scene: &Scene, p: DVec3, cone: Cone, extent: Extent) -> bool {
    let (
        Extent::Sun { .. },
        Cone::Cap {
            axis,
            one_minus_cos,
        },
    ) = (extent, cone)
    else {
        return false;
    };
    let half = (1.0 - one_minus_cos).clamp(-1.0, 1.0).acos();
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
        let apart = (to.dot(axis) / dist).clamp(-1.0, 1.0).acos();
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
        let m = (n / REPLICATES as usize).max(1);
        for c in 0..3 {
            let means: Vec<f64> = per
                .chunks(m)
                .map(|ch| ch.iter().map(|e| e.value[c]).sum::<f64>() / ch.len() as f64)
                .collect();
            let r = means.len() as f64;
            let mean = means.iter().sum::<f64>() / r;
            let var = means.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (r - 1.0).max(1.0);
            let (lo, hi) = per
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), e| {
                    (a.min(e.value[c]), b.max(e.value[c]))
                });
            out.value[c] = mean;
            out.std_err[c] = if lo == hi {
                let p = (crate::estimate::error_bar::RULE_OF_THREE / n as f64).min(1.0);
                mean.max(1.0 - mean) * (p / n as f64).sqrt()
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
            one_minus_cos: omc,
        };
        for (u, v) in [(0.0, 0.0), (0.999, 0.5), (0.5, 0.25), (1.0, 0.9)] {
            let d = cone.direction(u, v);
            assert!((d.length() - 1.0).abs() < 1e-12);
            assert!(d.dot(axis) >= 1.0 - omc - 1e-12);
        }
        // u = 1 is the rim, u = 0 the axis.
        assert!((cone.direction(1.0, 0.3).dot(axis) - (1.0 - omc)).abs() < 1e-12);
        assert!((cone.direction(0.0, 0.3).dot(axis) - 1.0).abs() < 1e-12);
    }
}
