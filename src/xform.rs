//! Object transforms: where an asset sits in its shot.
//!
//! A cache is stored in its own space (a Blender domain starts at the origin); `--xform M`
//! places it: `world = M object`, so a volume's `world_from_index` becomes
//! `M world_from_index`, and every world-space input (segments, lights, cameras, frame boxes)
//! stays in the shot's world space.

use crate::error::{Error, Result};
use glam::{DAffine3, DMat3, DVec3};

/// A world-from-object affine map: 4x4, row-major, column vectors, the translation in the last
/// column (`[m00 m01 m02 tx; m10 m11 m12 ty; m20 m21 m22 tz; 0 0 0 1]`), the convention of a
/// grid's `world_from_index` (README "Conventions").
///
/// Invariants (checked by [`Xform::new`]): finite entries, a last row of `0 0 0 1`, and an
/// invertible linear part (`|det| > 1e-300` with a finite inverse). Any affine map is
/// accepted: rotations, scales (uniform or not), shears, mirrors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Xform {
    rows: [[f64; 4]; 4],
}

fn bad(reason: String) -> Error {
    Error::InvalidArgument {
        name: "xform".into(),
        reason,
    }
}

impl Xform {
    /// The identity.
    pub const IDENTITY: Self = Self {
        rows: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };

    /// Check and wrap a matrix (see the type's invariants).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `xform`) naming what is wrong.
    pub fn new(rows: [[f64; 4]; 4]) -> Result<Self> {
        if !rows.iter().flatten().all(|v| v.is_finite()) {
            return Err(bad("non-finite entries".into()));
        }
        if rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(bad(format!(
                "the last row is {:?}, not 0,0,0,1: not an affine map (16 numbers, row-major, \
                 the translation in the last column)",
                rows[3]
            )));
        }
        let x = Self { rows };
        let m = x.affine().matrix3;
        // Flattening is a matter of shape, not size: the determinant of the columns made unit
        // (1 for a rotation or a uniform scale of any size, 0 when they are coplanar).
        // Lengths scaled by the largest component first: `x^2` of a 1e-200 axis underflows.
        let length = |v: glam::DVec3| {
            let big = v.abs().max_element();
            if big > 0.0 {
                big * (v / big).length()
            } else {
                0.0
            }
        };
        let lengths = [length(m.x_axis), length(m.y_axis), length(m.z_axis)];
        let shape = if lengths.iter().all(|&l| l > 0.0 && l.is_finite()) {
            glam::DMat3::from_cols(
                m.x_axis / lengths[0],
                m.y_axis / lengths[1],
                m.z_axis / lengths[2],
            )
            .determinant()
        } else {
            0.0
        };
        if shape.abs() < 1e-12 {
            return Err(bad(format!(
                "the linear part is singular (its axes are coplanar: unit-axis determinant \
                 {shape:e}): it flattens the volume"
            )));
        }
        let det = m.determinant();
        if !(det.abs() > 1e-300 && x.affine().inverse().is_finite()) {
            let (lo, hi) = lengths
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(a, b), &l| (a.min(l), b.max(l)));
            return Err(bad(format!(
                "it scales lengths by {lo:e} to {hi:e}: too far from 1 to invert in double \
                 precision (scale the volume's units, or its density, instead)"
            )));
        }
        Ok(x)
    }

    /// From 16 numbers, row-major.
    ///
    /// # Errors
    /// As [`Xform::new`], or when there are not exactly 16.
    pub fn from_row_major(v: &[f64]) -> Result<Self> {
        if v.len() != 16 {
            return Err(bad(format!(
                "{} numbers; give 16 (a 4x4 matrix, row-major, translation in the last column)",
                v.len()
            )));
        }
        Self::new(std::array::from_fn(|r| {
            std::array::from_fn(|c| v[4 * r + c])
        }))
    }

    /// The matrix, row-major.
    #[must_use]
    pub fn rows(&self) -> [[f64; 4]; 4] {
        self.rows
    }

    /// The map as a glam affine (`world = matrix3 object + translation`).
    #[must_use]
    pub fn affine(&self) -> DAffine3 {
        let r = &self.rows;
        DAffine3 {
            matrix3: DMat3::from_cols(
                DVec3::new(r[0][0], r[1][0], r[2][0]),
                DVec3::new(r[0][1], r[1][1], r[2][1]),
                DVec3::new(r[0][2], r[1][2], r[2][2]),
            ),
            translation: DVec3::new(r[0][3], r[1][3], r[2][3]),
        }
    }

    /// `M p` for a point.
    #[must_use]
    pub fn point(&self, p: impl Into<DVec3>) -> DVec3 {
        self.affine().transform_point3(p.into())
    }

    /// `M (a b)`: this map after `b` (a 3x4 affine, rows, column vectors).
    #[must_use]
    pub fn after(&self, b: &[[f64; 4]; 3]) -> [[f64; 4]; 3] {
        let a = &self.rows;
        std::array::from_fn(|r| {
            std::array::from_fn(|c| {
                let t = if c == 3 { a[r][3] } else { 0.0 };
                (0..3).map(|k| a[r][k] * b[k][c]).sum::<f64>() + t
            })
        })
    }
}
