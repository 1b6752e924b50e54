//! Lights: where a shading point's light comes from, and the ray toward it.

use crate::error::{Error, Result};
use crate::ray::{clip_box, Ray};
use crate::volume::Volume;

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

impl Light {
    /// The ray from the world point `at` toward the light: for a point light the segment from
    /// `at` to the light; for a directional light the ray `at - t dir / |dir|`, `t` in
    /// `[0, t_exit]`, where `t_exit` is where it leaves the volume box (0 if it never meets it),
    /// so a non-zero background counts only inside the box.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a zero or non-finite direction or point.
    pub fn ray_from(&self, vol: &Volume, at: [f64; 3]) -> Result<Ray> {
        match *self {
            Self::Point { pos } => Ray::between(at, pos),
            Self::Directional { dir } => {
                let d = crate::bake::normalise(glam::DVec3::from_array(dir))
                    .map(|v| v.to_array())
                    .ok_or_else(|| Error::InvalidArgument {
                        name: "light-dir".into(),
                        reason: format!(
                            "{dir:?} has no length; give the direction the light travels"
                        ),
                    })?;
                let back = -glam::DVec3::from_array(d);
                let t_exit = vol
                    .box_index()
                    .and_then(|(lo, hi)| clip_box(vol.to_index(at), vol.to_index_dir(back), lo, hi))
                    .map_or(0.0, |(_, t1)| t1.max(0.0));
                Ray::new(at, back, 0.0, t_exit)
            }
        }
    }
}
