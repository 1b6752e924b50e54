//! An area light's emitting surface (a UsdLux disk, rect, cylinder or line, or a sphere its
//! transform does not keep round), and the points a receiver's rays end on.
//!
//! **Uniform in solid angle by weighting.** The lattice point `(u, v)` maps to a point `q` of
//! the shape in the light's own space, uniform in area there, with `n` its unit normal on the
//! emitting side. The light's world matrix `A` (columns: its X, Y, Z axes, scale included)
//! places it at `p = c + A q`; the normal becomes `m = A^-T n`, whose length is the local
//! area's stretch (up to the constant `|det A|`). A receiver `x` sees the area element under
//! the solid angle `dw = cos(theta) dA / d^2`, so with `s = x - p`, `d = |s|`, the point's
//! weight is `w = max(0, m . s) / d^3`, proportional to `dw` per unit of the lattice's
//! measure, and `T_L(x) = sum w T / sum w` is the mean over the visible surface uniform in
//! solid angle (the ratio estimator; `crate::light::extent` forms it). A point of the back
//! side has weight 0 and is not traced.
//!
//! The shapes, in the light's own space: a disk of radius `r` in the XY plane and a `w x h`
//! rect there, both emitting along `-Z` only (one side); a cylinder's side along X of length
//! `l` and radius `r`, emitting outward, not from its caps; a sphere (an ellipsoid in the
//! world) emitting outward, over its whole surface for a receiver inside it. A cylinder of
//! radius 0 is a line (`treatAsLine`): the limit of the cylinder's weight, integrated round it,
//! is `w = |A_x x s| / d^3` (the projected width `2 r sin(angle to the axis)`).

use crate::error::{Error, Result};
use glam::{DMat3, DVec3};
use std::f64::consts::TAU;

/// A shape in the light's own space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// A disk in the XY plane, emitting along `-Z`.
    Disk {
        /// Radius.
        radius: f64,
    },
    /// A rectangle in the XY plane (`width` along X, `height` along Y), emitting along `-Z`.
    Rect {
        /// Size along X.
        width: f64,
        /// Size along Y.
        height: f64,
    },
    /// A cylinder's side along X, emitting outward; radius 0 is a line.
    Cylinder {
        /// Radius (0: a line).
        radius: f64,
        /// Length along X.
        length: f64,
    },
    /// A sphere, emitting outward.
    Ellipsoid {
        /// Radius in the light's own space.
        radius: f64,
    },
}

/// An area light: a [`Shape`] placed in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Area {
    shape: Shape,
    centre: DVec3,
    /// Columns: the light's X, Y, Z axes in the world.
    axes: DMat3,
    /// `axes^-1`: world offsets into the light's own space.
    inverse: DMat3,
    /// `axes^-T`: normals into the world.
    normals: DMat3,
}

impl Area {
    /// The shape `shape` at the world point `centre`, its own X, Y, Z axes the rows of
    /// `axes` (a UsdLux light's world matrix rows, scale included).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (named `light`) for a size that is negative or not finite,
    /// a centre or axes not finite, or axes with no volume.
    pub fn new(shape: Shape, centre: [f64; 3], axes: [[f64; 3]; 3]) -> Result<Self> {
        let bad = |reason: String| Error::InvalidArgument {
            name: "light".into(),
            reason,
        };
        let sizes: &[f64] = match &shape {
            Shape::Disk { radius } | Shape::Ellipsoid { radius } => &[*radius],
            Shape::Rect { width, height } => &[*width, *height],
            Shape::Cylinder { radius, length } => &[*radius, *length],
        };
        if sizes.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(bad(format!("{shape:?}: a size is negative or not finite")));
        }
        let a = DMat3::from_cols(
            DVec3::from_array(axes[0]),
            DVec3::from_array(axes[1]),
            DVec3::from_array(axes[2]),
        );
        let c = DVec3::from_array(centre);
        let det = a.determinant();
        if !(c.is_finite() && a.is_finite() && det.is_finite() && det != 0.0) {
            return Err(bad(format!(
                "a light at {centre:?} with axes {axes:?} has no place or no size"
            )));
        }
        let inverse = a.inverse();
        if !inverse.is_finite() {
            return Err(bad(format!("the axes {axes:?} cannot be inverted")));
        }
        Ok(Self {
            shape,
            centre: c,
            axes: a,
            inverse,
            normals: inverse.transpose(),
        })
    }

    /// The shape.
    #[must_use]
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// The radius of a sphere about the centre that holds the whole surface.
    #[must_use]
    pub fn bound(&self) -> f64 {
        let (x, y, z) = (
            self.axes.x_axis.length(),
            self.axes.y_axis.length(),
            self.axes.z_axis.length(),
        );
        match self.shape {
            Shape::Disk { radius } => radius * (x + y),
            Shape::Rect { width, height } => 0.5 * (width * x + height * y),
            Shape::Cylinder { radius, length } => 0.5 * length * x + radius * (y + z),
            Shape::Ellipsoid { radius } => radius * (x + y + z),
        }
    }

    /// The centre.
    #[must_use]
    pub fn centre(&self) -> DVec3 {
        self.centre
    }

    /// Whether the receiver `x` provably sees none of the emitting side: behind a disk's or a
    /// rect's plane (or in it), or within a cylinder's radius (its outward side faces away).
    #[must_use]
    pub fn unlit(&self, x: DVec3) -> bool {
        let q = self.inverse * (x - self.centre);
        match self.shape {
            Shape::Disk { .. } | Shape::Rect { .. } => q.z >= 0.0,
            Shape::Cylinder { radius, .. } => q.y.hypot(q.z) <= radius,
            Shape::Ellipsoid { .. } => false,
        }
    }

    /// The point of the lattice point `(u, v)` in `[0, 1)^2` and its weight seen from `x`
    /// (module docs): 0 for a point of the back side. A cylinder's and a sphere's lattice covers
    /// only the part `x` can see: a point `q` of either faces `x` when `n . (q_x - q) > 0`, `q_x`
    /// the receiver in the light's own space (an affine map keeps which side a point is on),
    /// that is the arc `|phi - phi_x| < acos(r / rho_x)` round a cylinder and the cap
    /// `n . q_x / |q_x| > r / |q_x|` of a sphere; both are uniform in local area over that
    /// part, whose size is the same for every lattice point of one receiver (it cancels).
    #[must_use]
    pub fn point(&self, x: DVec3, u: f64, v: f64) -> (DVec3, f64) {
        let qx = self.inverse * (x - self.centre);
        let mut inside = false;
        let (q, n) = match self.shape {
            Shape::Disk { radius } => {
                let r = radius * u.sqrt();
                let (s, c) = (TAU * v).sin_cos();
                (DVec3::new(r * c, r * s, 0.0), DVec3::NEG_Z)
            }
            Shape::Rect { width, height } => (
                DVec3::new((u - 0.5) * width, (v - 0.5) * height, 0.0),
                DVec3::NEG_Z,
            ),
            Shape::Cylinder { radius, length } => {
                let rho = qx.y.hypot(qx.z);
                let phi = if radius > 0.0 && rho > radius {
                    qx.z.atan2(qx.y) + (2.0 * v - 1.0) * (radius / rho).clamp(-1.0, 1.0).acos()
                } else {
                    TAU * v
                };
                let (s, c) = phi.sin_cos();
                (
                    DVec3::new((u - 0.5) * length, radius * c, radius * s),
                    DVec3::new(0.0, c, s),
                )
            }
            Shape::Ellipsoid { radius } => {
                let l = qx.length();
                // Outside: the visible cap about q_x; inside: the whole sphere, whose inner
                // surface the receiver sees.
                inside = l <= radius;
                let (axis, lowest) = if l > radius {
                    (qx / l, radius / l)
                } else {
                    (DVec3::Z, -1.0)
                };
                let z = 1.0 - u * (1.0 - lowest);
                let r = (1.0 - z * z).max(0.0).sqrt();
                let (s, c) = (TAU * v).sin_cos();
                let (b1, b2) = super::cone::basis(axis);
                let n = b1 * (r * c) + b2 * (r * s) + axis * z;
                (n * radius, n)
            }
        };
        let p = self.centre + self.axes * q;
        let to = x - p;
        let d = to.length();
        if !(d > 0.0 && d.is_finite()) {
            return (p, 0.0);
        }
        let w = match self.shape {
            Shape::Cylinder { radius: 0.0, .. } => {
                self.axes.x_axis.cross(to).length() / (d * d * d)
            }
            _ => {
                let cos = (self.normals * n).dot(to);
                let cos = if inside { cos.abs() } else { cos };
                cos.max(0.0) / (d * d * d)
            }
        };
        (p, if w.is_finite() { w } else { 0.0 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const I: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    #[test]
    fn a_rect_emits_on_its_minus_z_side_only() {
        let a = Area::new(
            Shape::Rect {
                width: 2.0,
                height: 1.0,
            },
            [0.0; 3],
            I,
        )
        .unwrap();
        assert!(a.unlit(DVec3::new(0.0, 0.0, 1.0)));
        assert!(!a.unlit(DVec3::new(0.0, 0.0, -1.0)));
        let (_, w) = a.point(DVec3::new(0.0, 0.0, -1.0), 0.3, 0.6);
        assert!(w > 0.0);
        let (_, w) = a.point(DVec3::new(0.0, 0.0, 1.0), 0.3, 0.6);
        assert_eq!(w, 0.0);
    }

    #[test]
    fn a_mirrored_transform_keeps_the_emitting_side() {
        // Z flipped: the local -Z side is the world +Z side.
        let m = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]];
        let a = Area::new(Shape::Disk { radius: 1.0 }, [0.0; 3], m).unwrap();
        assert!(!a.unlit(DVec3::new(0.0, 0.0, 2.0)));
        assert!(a.point(DVec3::new(0.0, 0.0, 2.0), 0.2, 0.1).1 > 0.0);
        assert_eq!(a.point(DVec3::new(0.0, 0.0, -2.0), 0.2, 0.1).1, 0.0);
    }

    #[test]
    fn weights_sum_to_the_solid_angle() {
        // A unit disk seen on axis from distance h subtends 2 pi (1 - h / sqrt(h^2 + 1));
        // the mean weight times the area is that solid angle (w = cos dA / d^2 per unit area).
        let a = Area::new(Shape::Disk { radius: 1.0 }, [0.0; 3], I).unwrap();
        let x = DVec3::new(0.0, 0.0, -2.0);
        let n = 400;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let (u, v) = ((f64::from(i) + 0.5) / 400.0, (f64::from(j) + 0.5) / 400.0);
                sum += a.point(x, u, v).1;
            }
        }
        let omega = sum / f64::from(n * n) * std::f64::consts::PI;
        let exact = TAU * (1.0 - 2.0 / 5f64.sqrt());
        assert!((omega - exact).abs() < 1e-4 * exact, "{omega} vs {exact}");
    }

    #[test]
    fn bad_shapes_are_refused() {
        assert!(Area::new(Shape::Disk { radius: -1.0 }, [0.0; 3], I).is_err());
        assert!(Area::new(Shape::Disk { radius: f64::NAN }, [0.0; 3], I).is_err());
        assert!(Area::new(Shape::Disk { radius: 1.0 }, [0.0; 3], [[0.0; 3]; 3]).is_err());
        assert!(Area::new(Shape::Disk { radius: 1.0 }, [f64::INFINITY, 0.0, 0.0], I).is_err());
    }
}
