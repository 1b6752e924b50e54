//! Omnidirectional maps around a point light: every texel looks from the light `P` along a
//! direction of OpenEXR's environment-map layouts (`ImfEnvmap`), evaluated in double at
//! integer pixel positions (not pixel centres), so a map is read with OpenEXR's and
//! OpenImageIO's own environment lookups.
//!
//! Directions are in the map's axes `(X_m, Y_m, Z_m)`: the world's by default. A camera stores
//! them as its basis: `forward = Z_m`, `up = Y_m`, `right = -X_m` (left-handed `(r, u, f)` as
//! every umbra camera; the texel at the centre of a latlong map and of the `+Z` face looks
//! along `forward`, with `up` up and `right` to the right in the image).
//!
//! - **Latlong** (`W = 2N`, `H = N`): texel `(x, y)` has
//!   `lat = pi (1/2 - y / (H - 1))`, `lon = 2 pi (1/2 - x / (W - 1))` (0 for a side of one
//!   texel) and looks along `(sin lon cos lat, sin lat, cos lon cos lat)`.
//! - **Cube** (`W = N`, `H = 6N`): faces `+X, -X, +Y, -Y, +Z, -Z` stacked top to bottom; in
//!   face `f`, texel `(u, v)` (column, row within the face) looks along `c_f + u a_f + v b_f`
//!   with `k = 2 / (N - 1)` (0 for `N = 1`):
//!
//!   | face | `c_f` | `a_f` | `b_f` |
//!   |---|---|---|---|
//!   | +X | (1, 1, -1) | (0, 0, k) | (0, -k, 0) |
//!   | -X | (-1, 1, 1) | (0, 0, -k) | (0, -k, 0) |
//!   | +Y | (-1, 1, 1) | (k, 0, 0) | (0, 0, -k) |
//!   | -Y | (-1, -1, -1) | (k, 0, 0) | (0, 0, k) |
//!   | +Z | (1, 1, 1) | (-k, 0, 0) | (0, -k, 0) |
//!   | -Z | (-1, 1, -1) | (k, 0, 0) | (0, -k, 0) |
//!
//!   which is `CubeMap::direction` of the face position `pixelPosition` maps to texel
//!   `(u, v)`. Each face is a pinhole camera at `P` (direction `c_f`, pixel steps `a_f`,
//!   `b_f`), which is how the exact sweep bakes it.

use super::{bad, check_res, clean, Camera, Projection, Resolution};
use crate::error::Result;
use glam::DVec3;

/// The layout of an omnidirectional map (`omni`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Omni {
    /// Six `N x N` faces stacked `+X, -X, +Y, -Y, +Z, -Z` in one `N x 6N` image.
    Cube,
    /// One `2N x N` latitude-longitude image.
    Latlong,
}

impl Omni {
    /// The camera projection of this layout.
    #[must_use]
    pub fn projection(self) -> Projection {
        match self {
            Self::Cube => Projection::Cube,
            Self::Latlong => Projection::LatLong,
        }
    }
}

/// Default face side (cube) or height (latlong) of an omnidirectional map.
pub const DEFAULT_OMNI_SIDE: u32 = 512;

/// The face table of the module docs: `(c_f, a_f / k, b_f / k)` in the map's axes.
const FACES: [([f64; 3], [f64; 3], [f64; 3]); 6] = [
    ([1.0, 1.0, -1.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]),
    ([-1.0, 1.0, 1.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]),
    ([-1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
    ([-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
    ([1.0, 1.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]),
    ([-1.0, 1.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]),
];

/// Whether a projection is omnidirectional.
#[must_use]
pub fn is_omni(p: Projection) -> bool {
    matches!(p, Projection::Cube | Projection::LatLong)
}

/// `(W, H)` of an omnidirectional map of side `n`.
fn size(kind: Projection, n: u32) -> (u32, u32) {
    match kind {
        Projection::LatLong => (n.saturating_mul(2), n),
        _ => (n, n.saturating_mul(6)),
    }
}

/// `2 / (n - 1)`, or 0 for one texel.
fn step(n: u32) -> f64 {
    if n > 1 {
        2.0 / f64::from(n - 1)
    } else {
        0.0
    }
}

impl Camera {
    /// An omnidirectional camera (`kind` [`Projection::Cube`] or [`Projection::LatLong`]) at
    /// the light `pos`, its axes the world's, of side `res` (`N`: the face side of a cube, the
    /// height of a latlong map; `[W, H]` must be `N x 6N` or `2N x N`), its rays traced to
    /// `t_max = max |c - P|` over `corners` (past which every ray has left the box).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`](crate::error::Error::InvalidArgument) naming `res` for a size out of
    /// range or of the wrong shape, `light-pos` for a non-finite light.
    pub fn omni(
        kind: Projection,
        pos: [f64; 3],
        res: Option<Resolution>,
        corners: &[DVec3],
    ) -> Result<Self> {
        let p = DVec3::from_array(pos);
        if !p.is_finite() {
            return Err(bad("light-pos", format!("{pos:?} is not a finite point")));
        }
        let (w, h) = match res {
            None => size(kind, DEFAULT_OMNI_SIDE),
            Some(Resolution::LongSide(n)) => size(kind, n),
            Some(Resolution::Exact(w, h)) => {
                let n = if kind == Projection::LatLong { h } else { w };
                if size(kind, n) != (w, h) {
                    return Err(bad(
                        "res",
                        format!(
                            "{w}x{h} is not a {} map: give N ({})",
                            if kind == Projection::LatLong {
                                "latlong"
                            } else {
                                "cube"
                            },
                            if kind == Projection::LatLong {
                                "2N x N texels"
                            } else {
                                "six N x N faces, N x 6N texels"
                            }
                        ),
                    ));
                }
                (w, h)
            }
        };
        check_res(w, h)?;
        let t_max = corners
            .iter()
            .map(|c| (*c - p).length())
            .fold(0.0f64, f64::max);
        if !t_max.is_finite() {
            return Err(bad("grid", "no finite volume box to frame".into()));
        }
        // Nominal (a cube face's plane step, a latlong texel's angle); 1 for one texel.
        let s = match kind {
            Projection::LatLong => std::f64::consts::TAU * step(w) * 0.5,
            _ => step(w),
        };
        let s = if s > 0.0 { s } else { 1.0 };
        Ok(Self {
            kind,
            width: w,
            height: h,
            origin: clean(p),
            step_x: [-s, 0.0, 0.0],
            step_y: [0.0, -s, 0.0],
            direction: [0.0, 0.0, 1.0],
            t_max,
            t_near: 0.0,
            forward: [0.0, 0.0, 1.0],
            right: [-1.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
            pixel_size: s,
        })
    }

    /// Texel `(i, j)`'s direction in world space (not unit) for an omnidirectional camera
    /// (module docs); `None` for other projections.
    pub(crate) fn omni_direction(&self, i: u32, j: u32) -> Option<DVec3> {
        let local = match self.kind {
            Projection::LatLong => {
                let frac = |a: u32, n: u32| {
                    if n > 1 {
                        f64::from(a) / f64::from(n - 1)
                    } else {
                        0.5
                    }
                };
                let lat = std::f64::consts::PI * (0.5 - frac(j, self.height));
                let lon = std::f64::consts::TAU * (0.5 - frac(i, self.width));
                DVec3::new(lon.sin() * lat.cos(), lat.sin(), lon.cos() * lat.cos())
            }
            Projection::Cube => {
                let n = self.width;
                let (f, v) = ((j / n).min(5) as usize, j % n);
                let k = step(n);
                let (c, a, b) = FACES[f];
                let (c, a, b) = (
                    DVec3::from_array(c),
                    DVec3::from_array(a),
                    DVec3::from_array(b),
                );
                c + a * (k * f64::from(i)) + b * (k * f64::from(v))
            }
            _ => return None,
        };
        Some(self.map_to_world(local))
    }

    /// A direction in the map's axes, in world space: `x X_m + y Y_m + z Z_m` with
    /// `X_m = -right`, `Y_m = up`, `Z_m = forward`.
    fn map_to_world(&self, d: DVec3) -> DVec3 {
        let v = DVec3::from_array;
        -v(self.right) * d.x + v(self.up) * d.y + v(self.forward) * d.z
    }

    /// The six faces of a cube camera as pinhole cameras at the light (`+X, -X, +Y, -Y, +Z,
    /// -Z`), each `N x N` with face texel `(u, v)` looking along the cube texel
    /// `(u, f N + v)`'s direction, traced over the same `[0, t_max]`. `None` for other
    /// projections and for one-texel faces (no pinhole has a field of view of 180 degrees
    /// there... nor needs one: those are traced as rays).
    pub(crate) fn cube_faces(&self) -> Option<[Camera; 6]> {
        let n = self.width;
        if self.kind != Projection::Cube || n < 2 {
            return None;
        }
        let k = step(n);
        Some(std::array::from_fn(|f| {
            let (c, a, b) = FACES[f];
            let (c, a, b) = (
                self.map_to_world(DVec3::from_array(c)),
                self.map_to_world(DVec3::from_array(a)),
                self.map_to_world(DVec3::from_array(b)),
            );
            let fwd = (c + (a + b) * (0.5 * k * f64::from(n - 1))).normalize();
            Camera {
                kind: Projection::Perspective,
                width: n,
                height: n,
                origin: self.origin,
                step_x: clean(a * k),
                step_y: clean(b * k),
                direction: clean(c),
                t_max: self.t_max,
                t_near: 0.0,
                forward: clean(fwd),
                right: clean(a),
                up: clean(-b),
                pixel_size: k,
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(kind: Projection, n: u32) -> Camera {
        Camera::omni(
            kind,
            [0.5, -1.0, 2.0],
            Some(Resolution::LongSide(n)),
            &[DVec3::ZERO, DVec3::ONE],
        )
        .unwrap()
    }

    /// OpenEXR's `CubeMap::direction` of the face position its `pixelPosition` maps to texel
    /// `(x, y)`, written out from the inverse of that mapping per face.
    fn imf_cube(n: u32, x: u32, y: u32) -> DVec3 {
        let (f, u, v) = (y / n, f64::from(x), f64::from(y % n));
        let m = f64::from(n - 1);
        let (px, py) = match f {
            0 => (m - v, u),
            1 => (m - v, m - u),
            2 => (u, m - v),
            3 => (u, v),
            4 => (m - u, m - v),
            _ => (u, m - v),
        };
        let (a, b) = (px / m * 2.0 - 1.0, py / m * 2.0 - 1.0);
        match f {
            0 => DVec3::new(1.0, a, b),
            1 => DVec3::new(-1.0, a, b),
            2 => DVec3::new(a, 1.0, b),
            3 => DVec3::new(a, -1.0, b),
            4 => DVec3::new(a, b, 1.0),
            _ => DVec3::new(a, b, -1.0),
        }
    }

    #[test]
    fn cube_texels_look_where_openexr_says() {
        let c = cam(Projection::Cube, 5);
        assert_eq!((c.width, c.height), (5, 30));
        for y in 0..30 {
            for x in 0..5 {
                let d = c.omni_direction(x, y).unwrap();
                assert!((d - imf_cube(5, x, y)).length() < 1e-15, "{x} {y}");
            }
        }
    }

    #[test]
    fn cube_faces_are_pinholes_through_the_same_texels() {
        let c = cam(Projection::Cube, 4);
        let faces = c.cube_faces().unwrap();
        for (f, face) in faces.iter().enumerate() {
            let check = Camera::from_spec(&face.spec()).unwrap();
            assert!((DVec3::from(check.forward) - DVec3::from(face.forward)).length() < 1e-12);
            for v in 0..4 {
                for u in 0..4 {
                    let a = face.pixel_ray(u, v).unwrap().direction();
                    let b = c.pixel_ray(u, f as u32 * 4 + v).unwrap().direction();
                    assert!((a - b).length() < 1e-15);
                }
            }
        }
    }

    #[test]
    fn latlong_poles_seams_and_centre() {
        let c = cam(Projection::LatLong, 9);
        assert_eq!((c.width, c.height), (18, 9));
        let d = |x, y| c.omni_direction(x, y).unwrap();
        assert!((d(3, 0) - DVec3::Y).length() < 1e-15);
        assert!((d(3, 8) + DVec3::Y).length() < 1e-15);
        assert!((d(0, 4) - d(17, 4)).length() < 1e-15);
        assert!((d(0, 4) + DVec3::Z).length() < 1e-15);
        // lon = 2 pi (1/2 - x / 17), lat = pi (1/2 - y / 8).
        let (lat, lon) = (
            std::f64::consts::PI * (0.5 - 3.0 / 8.0),
            std::f64::consts::TAU * (0.5 - 5.0 / 17.0),
        );
        let want = DVec3::new(lon.sin() * lat.cos(), lat.sin(), lon.cos() * lat.cos());
        assert!((d(5, 3) - want).length() < 1e-15);
    }

    #[test]
    fn shapes_that_are_not_the_layout_are_refused() {
        let corners = [DVec3::ZERO];
        let r = |w, h| Some(Resolution::Exact(w, h));
        assert!(Camera::omni(Projection::Cube, [0.0; 3], r(8, 48), &corners).is_ok());
        assert!(Camera::omni(Projection::Cube, [0.0; 3], r(8, 40), &corners).is_err());
        assert!(Camera::omni(Projection::LatLong, [0.0; 3], r(16, 8), &corners).is_ok());
        assert!(Camera::omni(Projection::LatLong, [0.0; 3], r(16, 9), &corners).is_err());
    }
}
