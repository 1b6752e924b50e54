//! What umbra traces of a UsdLux light: an [`Emitter`] per light type it traces, and how each
//! is read from the light's world transform and attributes ([`Emitter::of_light`]). A light
//! kind's USD side lives here; how it is traced is `crate::light::Light` (ARCHITECTURE.md,
//! "Where to add things: a light kind").

#[cfg(feature = "usd")]
use crate::error::{Error, Result};

/// How a USD light shines, as umbra traces it. As JSON (Python's `usd_lights`): its kind under
/// `kind` beside its fields, `{"kind": "directional", "dir": [x, y, z]}`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Emitter {
    /// A distant light: the unit direction the light travels (world `-Z` of the prim).
    Directional {
        /// Direction of travel.
        dir: [f64; 3],
    },
    /// A local light, traced as a point at the prim's world origin.
    Point {
        /// World position.
        pos: [f64; 3],
    },
}

/// Light types traced as points at their origin.
#[cfg(feature = "usd")]
const POINT_LIGHTS: [&str; 4] = ["SphereLight", "DiskLight", "RectLight", "CylinderLight"];

impl Emitter {
    /// The emitter of a UsdLux light of schema type `type_name`, or `None` for a type umbra does
    /// not trace. `world` gives the prim's local-to-world matrix (row-major, row vectors: the
    /// translation in elements 12..15), asked only for a traced type; `number` an attribute's
    /// value at the time code read (`None` when unauthored), for kinds whose attributes shape
    /// them (today's read none).
    ///
    /// # Errors
    /// What `world` returns; `refuse(reason)` (an error naming the prim) for a degenerate `-Z`
    /// axis or a position that is not finite.
    #[cfg(feature = "usd")]
    pub(crate) fn of_light(
        type_name: &str,
        world: impl FnOnce() -> Result<[f64; 16]>,
        _number: impl Fn(&str) -> Result<Option<f64>>,
        refuse: impl Fn(&str) -> Error,
    ) -> Result<Option<Self>> {
        let position = |m: &[f64; 16]| {
            let pos = [m[12], m[13], m[14]];
            if pos.iter().all(|c| c.is_finite()) {
                Ok(pos)
            } else {
                Err(refuse("its world position is not finite"))
            }
        };
        Ok(match type_name {
            "DistantLight" => {
                let m = world()?;
                let d = [-m[8], -m[9], -m[10]];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if !(n.is_finite() && n > 0.0) {
                    return Err(refuse("its world -Z axis is degenerate"));
                }
                Some(Self::Directional {
                    dir: d.map(|c| c / n),
                })
            }
            t if POINT_LIGHTS.contains(&t) => Some(Self::Point {
                pos: position(&world()?)?,
            }),
            _ => None,
        })
    }
}
