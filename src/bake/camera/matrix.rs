//! The standard OpenEXR camera matrices of a [`Camera`]: `worldToCamera` and `worldToNDC`.

use crate::bake::camera::{Camera, Projection};
use glam::DVec3;

impl Camera {
    /// Camera-space origin: the image plane's centre (ortho) or the light (perspective).
    fn eye(&self) -> DVec3 {
        let v = DVec3::from_array;
        match self.kind {
            Projection::Ortho => {
                v(self.origin)
                    + (v(self.step_x) * (0.5 * f64::from(self.width) - 0.5)
                        + v(self.step_y) * (0.5 * f64::from(self.height) - 0.5))
            }
            _ => v(self.origin),
        }
    }

    /// OpenEXR `worldToCamera` as a column-vector 4x4 (`p_cam = M p`): rows `r`, `u`, `f` with
    /// translation `-axis . e`, where `e` is the image plane's centre (ortho) or the light
    /// (perspective). Camera space is OpenEXR's (RenderMan's): x right, y up, z forward.
    #[must_use]
    pub fn world_to_camera(&self) -> [[f64; 4]; 4] {
        let e = self.eye();
        let row = |a: [f64; 3]| [a[0], a[1], a[2], -DVec3::from_array(a).dot(e)];
        [
            row(self.right),
            row(self.up),
            row(self.forward),
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    /// OpenEXR `worldToNDC` as a column-vector 4x4 (`[X, Y, Z, w] = M [p, 1]`, NDC = `X/w, Y/w`):
    /// NDC `(0, 0)` is the top-left corner of the image and `(1, 1)` the bottom-right one, so
    /// pixel `(i, j)`'s centre is `((i + 0.5) / W, (j + 0.5) / H)`. With camera coordinates
    /// `(x, y, z)`:
    /// ortho `X = x / (W s) + 1/2`, `Y = -y / (H s) + 1/2`, `Z = z / t_max`, `w = 1`;
    /// perspective `X = x / (W s) + z / 2`, `Y = -y / (H s) + z / 2`, `Z = 1`, `w = z`.
    #[must_use]
    pub fn world_to_ndc(&self) -> [[f64; 4]; 4] {
        let c = self.world_to_camera();
        let (ws, hs) = (
            f64::from(self.width) * self.pixel_size,
            f64::from(self.height) * self.pixel_size,
        );
        let lin = |a: [f64; 4], ka: f64, b: [f64; 4], kb: f64| {
            std::array::from_fn(|k| a[k] * ka + b[k] * kb)
        };
        let one = [0.0, 0.0, 0.0, 1.0];
        match self.kind {
            Projection::Ortho => [
                lin(c[0], 1.0 / ws, one, 0.5),
                lin(c[1], -1.0 / hs, one, 0.5),
                lin(c[2], 1.0 / self.t_max.max(f64::MIN_POSITIVE), one, 0.0),
                one,
            ],
            _ => [
                lin(c[0], 1.0 / ws, c[2], 0.5),
                lin(c[1], -1.0 / hs, c[2], 0.5),
                one,
                c[2],
            ],
        }
    }
}
