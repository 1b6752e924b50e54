//! What umbra traces of a UsdLux light: an [`Emitter`] per light type it traces, and how each
//! is read from the light's world transform and attributes ([`Emitter::of_light`]). A light
//! kind's USD side lives here; how it is traced is `crate::light` (a light's centre,
//! `crate::light::Light`, and its extent, `crate::light::SoftLight::of_emitter`;
//! ARCHITECTURE.md, "Where to add things: a light kind").
//!
//! The attributes read, with the schema fallbacks that apply when they are unauthored (as
//! renderers apply them): `DistantLight.inputs:angle` (0.53 degrees), `SphereLight.inputs:radius`
//! (0.5) and `treatAsPoint` (false), `DiskLight.inputs:radius` (0.5), `RectLight.inputs:width`
//! and `inputs:height` (1), `CylinderLight.inputs:length` (1), `inputs:radius` (0.5) and
//! `treatAsLine` (false). Sizes are in the light's own space: its world transform scales and
//! turns them ([`Emitter`]'s `axes`). A shaped or textured light (`inputs:shaping:cone:angle`
//! below 90, `inputs:shaping:focus` not 0, `inputs:shaping:ies:file`, `inputs:texture:file`) does
//! not emit uniformly: it is refused, naming the attribute, when it is chosen.

#[cfg(feature = "usd")]
use crate::error::{Error, Result};

/// How a USD light shines, as umbra traces it. As JSON (Python's `usd_lights`, `info --json`):
/// its kind under `kind` beside its fields, `{"kind": "directional", "dir": [x, y, z],
/// "angle": 0.53}`. The local lights carry `pos` (the prim's world origin) and `axes`, the rows
/// X, Y, Z of its world matrix (scale included): what places the shape in the world.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Emitter {
    /// A distant light: the unit direction the light travels (world `-Z` of the prim) and its
    /// angular diameter in degrees (`inputs:angle`; 0 is a point).
    Directional {
        /// Direction of travel.
        dir: [f64; 3],
        /// Angular diameter, degrees in `[0, 180)`.
        angle: f64,
    },
    /// A local light traced as a point at the prim's world origin (`treatAsPoint`, or a
    /// shape of no size).
    Point {
        /// World position.
        pos: [f64; 3],
    },
    /// A sphere light (emits outward from its whole surface).
    Sphere {
        /// World position of its centre.
        pos: [f64; 3],
        /// Radius in the light's own space.
        radius: f64,
        /// Rows X, Y, Z of the world matrix.
        axes: [[f64; 3]; 3],
    },
    /// A disk light: a disk in its XY plane, emitting along its `-Z` (one side).
    Disk {
        /// World position of its centre.
        pos: [f64; 3],
        /// Radius in the light's own space.
        radius: f64,
        /// Rows X, Y, Z of the world matrix.
        axes: [[f64; 3]; 3],
    },
    /// A rect light: `width` along X by `height` along Y, emitting along its `-Z` (one side).
    Rect {
        /// World position of its centre.
        pos: [f64; 3],
        /// Size along X.
        width: f64,
        /// Size along Y.
        height: f64,
        /// Rows X, Y, Z of the world matrix.
        axes: [[f64; 3]; 3],
    },
    /// A cylinder light: its side along X (`length`), emitting outward, not from its caps;
    /// radius 0 is a line (`treatAsLine`).
    Cylinder {
        /// World position of its centre.
        pos: [f64; 3],
        /// Radius in the light's own space (0: a line).
        radius: f64,
        /// Length along X.
        length: f64,
        /// Rows X, Y, Z of the world matrix.
        axes: [[f64; 3]; 3],
    },
}

/// The schema fallback of `inputs:angle` (degrees): the sun's angular diameter.
#[cfg(feature = "usd")]
pub const DISTANT_ANGLE: f64 = 0.53;

impl Emitter {
    /// The light's centre: the prim's world origin, `None` for a distant light.
    #[must_use]
    pub fn position(&self) -> Option<[f64; 3]> {
        match *self {
            Self::Directional { .. } => None,
            Self::Point { pos }
            | Self::Sphere { pos, .. }
            | Self::Disk { pos, .. }
            | Self::Rect { pos, .. }
            | Self::Cylinder { pos, .. } => Some(pos),
        }
    }

    /// The emitter of a UsdLux light of schema type `type_name`, or `None` for a type umbra does
    /// not trace. `world` gives the prim's local-to-world matrix (row-major, row vectors: the
    /// translation in elements 12..15), asked only for a traced type; `number` a numeric
    /// attribute's value at the time code read, `flag` a bool's, `text` a string, token or
    /// asset path's (`None` when unauthored).
    ///
    /// # Errors
    /// What the readers return; `refuse(reason)` (an error naming the prim) for a degenerate
    /// transform, a position that is not finite, a size or angle out of range (naming the
    /// attribute), or a shaped or textured light (naming the attribute).
    #[cfg(feature = "usd")]
    pub(crate) fn of_light(
        type_name: &str,
        world: impl FnOnce() -> Result<[f64; 16]>,
        read: &Attributes<'_>,
        refuse: impl Fn(&str) -> Error,
    ) -> Result<Option<Self>> {
        const LOCAL: [&str; 4] = ["SphereLight", "DiskLight", "RectLight", "CylinderLight"];
        if type_name != "DistantLight" && !LOCAL.contains(&type_name) {
            return Ok(None);
        }
        refuse_shaping(type_name, read, &refuse)?;
        let m = world()?;
        let axes = [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]];
        let size = |attr: &str, fallback: f64| -> Result<f64> {
            let v = (read.number)(attr)?.unwrap_or(fallback);
            if v.is_finite() && v >= 0.0 {
                Ok(v)
            } else {
                Err(refuse(&format!(
                    "{attr} is {v}: a light's size is a finite number >= 0"
                )))
            }
        };
        let flag = |attr: &str| -> Result<bool> { Ok((read.flag)(attr)?.unwrap_or(false)) };
        if type_name == "DistantLight" {
            let d = [-m[8], -m[9], -m[10]];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if !(n.is_finite() && n > 0.0) {
                return Err(refuse("its world -Z axis is degenerate"));
            }
            let angle = size("inputs:angle", DISTANT_ANGLE)?;
            if angle >= 180.0 {
                return Err(refuse(&format!(
                    "inputs:angle is {angle} degrees: a distant light's angular diameter is \
                     below 180"
                )));
            }
            return Ok(Some(Self::Directional {
                dir: d.map(|c| c / n),
                angle,
            }));
        }
        let pos = [m[12], m[13], m[14]];
        if !pos.iter().all(|c| c.is_finite()) {
            return Err(refuse("its world position is not finite"));
        }
        if !axes.iter().flatten().all(|c| c.is_finite()) || det(&axes).abs() < f64::MIN_POSITIVE {
            return Err(refuse(
                "its world transform is degenerate (no size to place its shape)",
            ));
        }
        let point = Self::Point { pos };
        Ok(Some(match type_name {
            "SphereLight" => {
                let radius = size("inputs:radius", 0.5)?;
                if flag("treatAsPoint")? || radius == 0.0 {
                    point
                } else {
                    Self::Sphere { pos, radius, axes }
                }
            }
            "DiskLight" => match size("inputs:radius", 0.5)? {
                0.0 => point,
                radius => Self::Disk { pos, radius, axes },
            },
            "RectLight" => match (size("inputs:width", 1.0)?, size("inputs:height", 1.0)?) {
                (w, h) if w == 0.0 || h == 0.0 => point,
                (width, height) => Self::Rect {
                    pos,
                    width,
                    height,
                    axes,
                },
            },
            _ => {
                let length = size("inputs:length", 1.0)?;
                let radius = size("inputs:radius", 0.5)?;
                let radius = if flag("treatAsLine")? { 0.0 } else { radius };
                if length == 0.0 {
                    // A cylinder of no length has no side to emit from: its centre.
                    point
                } else {
                    Self::Cylinder {
                        pos,
                        radius,
                        length,
                        axes,
                    }
                }
            }
        }))
    }
}

/// How [`Emitter::of_light`] reads a light's attributes at the time code (`None` when
/// unauthored).
#[cfg(feature = "usd")]
pub(crate) struct Attributes<'a> {
    /// A numeric attribute.
    pub number: &'a dyn Fn(&str) -> Result<Option<f64>>,
    /// A bool attribute.
    pub flag: &'a dyn Fn(&str) -> Result<Option<bool>>,
    /// A string, token or asset path attribute (an asset path as authored).
    pub text: &'a dyn Fn(&str) -> Result<Option<String>>,
}

/// Refuse a light that does not emit uniformly over its surface: a ShapingAPI cone narrower
/// than the hemisphere, a focus, an IES profile, a texture.
#[cfg(feature = "usd")]
fn refuse_shaping(
    type_name: &str,
    read: &Attributes<'_>,
    refuse: &impl Fn(&str) -> Error,
) -> Result<()> {
    let why = "umbra averages over a light of uniform radiance (docs/lights.md); a shaped or \
               textured light is not one";
    if let Some(a) = (read.number)("inputs:shaping:cone:angle")? {
        if a < 90.0 {
            return Err(refuse(&format!(
                "inputs:shaping:cone:angle is {a} (below 90 degrees, a spot light): {why}"
            )));
        }
    }
    if let Some(f) = (read.number)("inputs:shaping:focus")? {
        if f != 0.0 {
            return Err(refuse(&format!("inputs:shaping:focus is {f}: {why}")));
        }
    }
    for attr in ["inputs:shaping:ies:file", "inputs:texture:file"] {
        if type_name == "DistantLight" && attr == "inputs:texture:file" {
            continue;
        }
        if let Some(t) = (read.text)(attr)? {
            if !t.is_empty() {
                return Err(refuse(&format!(
                    "{attr} is '{}': {why}",
                    crate::text::escape(&t)
                )));
            }
        }
    }
    Ok(())
}

/// The determinant of the 3x3 of rows `a`.
#[cfg(feature = "usd")]
fn det(a: &[[f64; 3]; 3]) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}
