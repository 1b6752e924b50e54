//! A fixed camera (an earlier map's, a sequence's) against the volume it is now asked to see.
//!
//! A camera fixes the projection: which line in the world each pixel stands for. Where each
//! ray starts and how far it is traced (`origin` for ortho, `t_near`, `t_max`) only
//! parametrise that line, and they were chosen for the box the camera was framed on. A later
//! frame whose density reaches further toward or away from the light would be cut by them, so
//! [`Camera::covering`] extends them to the new box and the map gives, at every pixel, the `T`
//! a fresh bake with the same projection gives:
//!
//! - **Ortho**: with `z_c = (c - origin) . f` for the box corners `c`, the ray start moves back
//!   by `delta = max(0, -min z_c)` along `f` (`origin' = origin - delta f`), and
//!   `t_max' = max(t_max, max z_c) + delta`, `t_near' = max(0, min(t_near, min z_c) + delta)`.
//! - **Perspective**: rays start at the light and nothing lies behind it:
//!   `t_max' = max(t_max, max |c - P|)`, `t_near' = max(0, min(t_near, min (c - P) . f))`.
//!
//! Changes below `1e-9` of the depth range are rounding, not reach: a camera that already
//! covers the box is returned bit for bit.
//!
//! The window cannot be widened without changing the map, so [`Camera::outside`] says how far
//! the box reaches beyond it, in pixels and world units (at the box's nearest depth for a
//! perspective camera), for the bake's warnings.

use crate::bake::{Camera, Projection};
use glam::DVec3;

/// How far a box reaches outside a camera's window (see [`Camera::outside`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Outside {
    /// Largest distance of a box corner's projection beyond the window's edge, in pixels
    /// (`inf` for a corner behind a perspective camera's light).
    pub pixels: f64,
    /// The same in world units: `pixels x s` (ortho), `pixels x s x z` at the corner's depth
    /// `z` (perspective).
    pub world: f64,
}

impl Camera {
    /// This camera with its ray range extended to cover the points `corners` (module docs),
    /// and the distance `delta` its ortho ray start moved back (0 when unchanged). Depths
    /// measured along the rays of the returned camera are `delta` larger than along this one's.
    #[must_use]
    pub fn covering(&self, corners: &[DVec3]) -> (Camera, f64) {
        let v = DVec3::from_array;
        let f = v(self.forward);
        let mut c = *self;
        if corners.is_empty() || !corners.iter().all(|p| p.is_finite()) {
            return (c, 0.0);
        }
        match self.kind {
            Projection::Ortho => {
                let o = v(self.origin);
                let (z0, z1) = corners
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                        let z = (*p - o).dot(f);
                        (a.0.min(z), a.1.max(z))
                    });
                let tol = 1e-9 * self.t_max.max(z1 - z0).max(f64::MIN_POSITIVE);
                let delta = if z0 < -tol { -z0 } else { 0.0 };
                if delta > 0.0 {
                    c.origin = (o - f * delta + DVec3::ZERO).to_array();
                }
                if z1 > self.t_max + tol || delta > 0.0 {
                    c.t_max = self.t_max.max(z1) + delta;
                }
                if z0 < self.t_near - tol || delta > 0.0 {
                    c.t_near = (self.t_near.min(z0) + delta).max(0.0);
                }
                (c, delta)
            }
            Projection::Cube | Projection::LatLong => {
                let p = v(self.origin);
                let far = corners
                    .iter()
                    .map(|c| (*c - p).length())
                    .fold(0.0, f64::max);
                if far > self.t_max * (1.0 + 1e-9) {
                    c.t_max = far;
                }
                (c, 0.0)
            }
            Projection::Perspective => {
                let p = v(self.origin);
                let far = corners
                    .iter()
                    .map(|c| (*c - p).length())
                    .fold(0.0, f64::max);
                let near = corners
                    .iter()
                    .map(|c| (*c - p).dot(f))
                    .fold(f64::INFINITY, f64::min)
                    .max(0.0);
                let tol = 1e-9 * self.t_max.max(far).max(f64::MIN_POSITIVE);
                if far > self.t_max + tol {
                    c.t_max = far;
                }
                if near < self.t_near - tol {
                    c.t_near = near;
                }
                (c, 0.0)
            }
        }
    }

    /// How far the points `corners` (a volume box) project outside this camera's window, or
    /// `None` when every one lands inside it (within a thousandth of a pixel). The window is
    /// `[-1/2, W - 1/2] x [-1/2, H - 1/2]` in pixel coordinates, pixel `(i, j)`'s centre at
    /// `(i, j)`; a point `c` lands at `((c - o) . r / s, -(c - o) . u / s)` for ortho with
    /// `o` the ray start of pixel (0, 0), and for perspective its direction from the light
    /// scaled onto the plane at distance 1, `w = (c - P) / ((c - P) . f)`, lands at
    /// `((w - d0) . r / s, -(w - d0) . u / s)` with `d0` pixel (0, 0)'s `direction`.
    #[must_use]
    pub fn outside(&self, corners: &[DVec3]) -> Option<Outside> {
        let v = DVec3::from_array;
        let (r, u, f) = (v(self.right), v(self.up), v(self.forward));
        let s = self.pixel_size;
        let (w, h) = (f64::from(self.width), f64::from(self.height));
        let mut worst = Outside {
            pixels: 0.0,
            world: 0.0,
        };
        if super::is_omni(self.kind) {
            // Every direction is in the map.
            return None;
        }
        for c in corners {
            let (rel, scale) = match self.kind {
                Projection::Ortho => (*c - v(self.origin), s),
                Projection::Perspective => {
                    let d = *c - v(self.origin);
                    let z = d.dot(f);
                    if z <= 0.0 {
                        return Some(Outside {
                            pixels: f64::INFINITY,
                            world: f64::INFINITY,
                        });
                    }
                    (d / z - v(self.direction), s * z)
                }
                Projection::Cube | Projection::LatLong => return None,
            };
            let (x, y) = (rel.dot(r) / s, -rel.dot(u) / s);
            let out = (-0.5 - x)
                .max(x - (w - 0.5))
                .max(-0.5 - y)
                .max(y - (h - 0.5));
            if out > worst.pixels {
                worst = Outside {
                    pixels: out,
                    world: out * scale,
                };
            }
        }
        (worst.pixels > 1e-3).then_some(worst)
    }
}
