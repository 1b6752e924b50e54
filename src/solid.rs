//! Opaque solids from level sets: the region `phi < 0` of a signed distance grid's trilinear
//! field is an occluder (`T = 0` from the first point of a ray inside it, `T = 1` before).
//!
//! A level set (OpenVDB grid class `level set`) stores the signed distance `phi` to a surface,
//! negative inside, in a narrow band of voxels around the surface; its background is positive
//! (the half width of the band) and the interior is filled with tiles of negative value. umbra's
//! tree keeps those tiles and its hierarchical DDA ([`crate::traverse::walk`]) emits them as
//! constant segments (their value differs from the background), so the interior is found without
//! visiting its voxels.
//!
//! **The first hit** ([`Solid::first_hit`]) is the smallest `t` of the ray where the trilinear
//! field is negative:
//!
//! 1. If `phi` at the ray's start is negative the ray starts inside: the hit is `t_min`.
//! 2. The ray is walked at leaf granularity. Between segments `phi` is the background, positive.
//!    A segment whose minorant is `>= 0` cannot hold `phi < 0` (trilinear interpolation is a
//!    convex combination of the corners, which the segment's halo bounds) and is skipped. A
//!    constant segment with a negative value is hit at its start.
//! 3. Any other segment is cut into the trilinear dual cells it crosses (the unit DDA in index
//!    space, where dual cell `c` is `floor(q + t d)`). A cell none of whose 8 corners is
//!    negative is skipped (its field is a convex combination of them): where the field only
//!    touches 0 (band voxels beside a background of 0, as Blender writes a liquid's `phi`)
//!    round-off cannot make a hit. Inside one cell, with local coordinates
//!    `u(s) = u0 + d s` (`s = t - t_a`, `t_a` the cell entry), the trilinear field
//!    `f(x, y, z) = k + k_x x + k_y y + k_z z + k_xy xy + k_xz xz + k_yz yz + k_xyz xyz` is a cubic
//!    polynomial `p(s) = c0 + c1 s + c2 s^2 + c3 s^3` with
//!    - `c0 = f(u0)`,
//!    - `c1 = grad f(u0) . d`,
//!    - `c2 = k_xy dx dy + k_xz dx dz + k_yz dy dz + k_xyz (x0 dy dz + y0 dx dz + z0 dx dy)`,
//!    - `c3 = k_xyz dx dy dz`.
//!
//!    The real roots of `p'(s) = c1 + 2 c2 s + 3 c3 s^2` inside the cell split it into pieces on
//!    which `p` is monotone, so on each piece `p` is smallest at one of its ends: a piece whose
//!    end values are both `>= 0` holds no `phi < 0`. On the first piece whose far end is
//!    negative, bisection brackets the crossing until the bracket is shorter than
//!    [`BRACKET_VOXELS`] voxels (index-space length) and returns the bracket's upper end, where
//!    `p <= 0` up to round-off. The walk stops there.
//!
//! **Bad values.** Nothing is sanitised (negative values are the point), but the search treats a
//! NaN voxel as far outside (`+f32::MAX`) and infinite voxels as `+-f32::MAX`, so the cubic's
//! coefficients stay finite; node bounds already leave NaN out.

use crate::error::{Error, Result};
use crate::input::Grid;
use crate::math::floor_i64;
use crate::ray::Ray;
use crate::traverse::{dda, lookup_ray, walk, Cells, Granularity};
use crate::tree::{Accessor, Tree};
use crate::volume::{Interp, Volume};
use glam::DVec3;
use std::ops::ControlFlow;
use std::path::Path;

/// The crossing is located to a bracket shorter than this many voxels (index-space length).
pub const BRACKET_VOXELS: f64 = 1e-6;

/// Upper bound on bisection steps (a cell is at most `sqrt 3` voxels long, so about 21 are
/// needed; the bound only guards against round-off that would stall the bracket).
const MAX_BISECTIONS: u32 = 200;

/// An opaque occluder: the region `phi < 0` of a level set's trilinear field.
///
/// The grid must hold a signed distance (negative inside, positive outside, as OpenVDB level
/// sets do); its grid class is not checked because many files do not record one. A grid whose
/// background is negative would be "everything inside" (an inverted or malformed level set;
/// OpenVDB's backgrounds are positive) and is refused; a background of 0 (Blender's liquids)
/// reads as on the surface outside the band and is traced as outside
/// ([`crate::bake::Warning::SolidBackground`] says so).
#[derive(Debug, Clone)]
pub struct Solid {
    /// The raw signed distances (no bad-voxel policy), never traced as fog.
    vol: Volume,
}

impl Solid {
    /// Load grid `grid` of `path` as a solid (see [`Solid::new`]).
    ///
    /// # Errors
    /// Loading errors ([`crate::input::load_grid`]) and those of [`Solid::new`].
    pub fn load(path: impl AsRef<Path>, grid: &str) -> Result<Self> {
        let path = path.as_ref();
        Self::new(crate::input::load_grid(path, grid)?, path)
    }

    /// A solid from a loaded grid, which must be a signed distance field (negative inside).
    /// Any grid class is accepted (many files lack one); `path` names the file in errors.
    ///
    /// # Errors
    /// [`Error::Unsupported`] for non-scalar grids, frustum (non-affine) maps, and maps that
    /// cannot be traced (the checks of [`Volume::from_tree`]).
    pub fn new(grid: Grid, path: &Path) -> Result<Self> {
        if !grid.transform.is_affine() {
            return Err(crate::volume::non_affine(path, &grid.transform, &grid.name));
        }
        if !grid.value_type.is_scalar_real() {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                what: format!(
                    "a solid from a {} grid ('{}'); a level set must be a float or double grid",
                    grid.value_type.name(),
                    crate::text::escape(&grid.name)
                ),
            });
        }
        let m = grid.transform.world_from_index;
        let shown = crate::text::escape(&grid.name).into_owned();
        Self::from_tree(grid.name, grid.tree, [m[0], m[1], m[2]]).map_err(|e| match e {
            Error::InvalidArgument { name, reason } if name == "transform" => Error::Unsupported {
                path: path.to_path_buf(),
                what: format!("grid '{shown}' cannot be traced: its transform: {reason}"),
            },
            Error::InvalidArgument { name, reason } if name == "background" => Error::Unsupported {
                path: path.to_path_buf(),
                what: format!("a solid from grid '{shown}': {reason}"),
            },
            other => other,
        })
    }

    /// A solid from a tree of signed distances built in memory (see
    /// [`crate::tree::TreeBuilder`]) and a `world_from_index` affine map (3x4, column vectors:
    /// `world = M [i j k 1]^T`).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `transform`) for a map [`Volume::from_tree`] refuses.
    pub fn from_tree(name: String, tree: Tree, world_from_index: [[f64; 4]; 3]) -> Result<Self> {
        let bg = tree.background();
        if bg < 0.0 || bg.is_nan() {
            return Err(Error::InvalidArgument {
                name: "background".into(),
                reason: format!(
                    "level set '{}' has background {bg}: outside its narrow band it reads as \
                     inside, so every ray would start in the solid (a level set's background is \
                     its positive band half-width)",
                    crate::text::escape(&name)
                ),
            });
        }
        Ok(Self {
            vol: Volume::from_tree_raw(name, tree, world_from_index)?,
        })
    }

    /// The solid placed in its shot by the object transform `x` (see [`Volume::with_xform`]).
    ///
    /// # Errors
    /// As [`Volume::with_xform`].
    pub fn with_xform(self, x: &crate::xform::Xform) -> Result<Self> {
        Ok(Self {
            vol: self.vol.with_xform(x)?,
        })
    }

    /// Grid name.
    #[must_use]
    pub fn name(&self) -> &str {
        self.vol.name()
    }

    /// The grid's background: `phi` outside its narrow band (positive for OpenVDB's level
    /// sets; 0 in Blender's liquids, where it reads as on the surface; never negative, which
    /// [`Solid::from_tree`] refuses).
    #[must_use]
    pub fn background(&self) -> f64 {
        f64::from(self.vol.tree().background())
    }

    /// The 8 world corners of the box holding every value other than the background, grown by
    /// one voxel (see [`Volume::box_corners`]).
    ///
    /// # Errors
    /// As [`Volume::box_corners`]: the grid holds nothing but its background.
    pub fn box_corners(&self) -> Result<[DVec3; 8]> {
        self.vol.box_corners()
    }

    /// The object transform applied by [`Solid::with_xform`] (composed), if any.
    #[must_use]
    pub fn xform(&self) -> Option<crate::xform::Xform> {
        self.vol.xform()
    }

    /// Smallest world distance `t` in `[ray.t_min, ray.t_max]` where the trilinear `phi(t) < 0`,
    /// or `None` when the ray stays outside. The crossing is located to within
    /// [`BRACKET_VOXELS`] voxels of index-space length and the returned `t` is on the inside
    /// end of the final bracket (`phi(t) <= 0` up to round-off); a ray that starts inside gets
    /// `t_min`. The method is in the module documentation.
    #[must_use]
    pub fn first_hit(&self, ray: &Ray) -> Option<f64> {
        let t_min = ray.t_min();
        let (q, d) = lookup_ray(&self.vol, ray, Interp::Trilinear);
        let mut acc = Accessor::new(self.vol.tree());
        let start = [0, 1, 2].map(|a| q[a] + d[a] * t_min);
        if phi_at(&mut acc, start) < 0.0 {
            return Some(t_min);
        }
        let index_speed = DVec3::from_array(d).length();
        let mut hit = None;
        walk(&self.vol, ray, Interp::Trilinear, Granularity::Leaf, |s| {
            if s.mu_min >= 0.0 {
                return ControlFlow::Continue(());
            }
            hit = if s.is_constant() {
                Some(s.t_min)
            } else {
                cells_hit(&mut acc, q, d, s.t_min, s.t_max, index_speed)
            };
            if hit.is_some() {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        });
        hit
    }
}

/// A voxel value as the search reads it: NaN is far outside, infinities the largest finite
/// `f32` of their sign (so that the cubic's coefficients stay finite).
fn clean(v: f32) -> f64 {
    if v.is_nan() {
        f64::from(f32::MAX)
    } else {
        f64::from(v.clamp(-f32::MAX, f32::MAX))
    }
}

/// The 8 corner values of dual cell `c`, index `x << 2 | y << 1 | z`.
fn corners(acc: &mut Accessor<'_>, c: [i64; 3]) -> [f64; 8] {
    std::array::from_fn(|k| {
        clean(acc.value_at([
            c[0] + (k >> 2) as i64,
            c[1] + ((k >> 1) & 1) as i64,
            c[2] + (k & 1) as i64,
        ]))
    })
}

/// Trilinear interpolation of corners `v` at local coordinates `u` (in `[0, 1]^3`).
fn trilinear(v: &[f64; 8], u: [f64; 3]) -> f64 {
    let l = |a: f64, b: f64, w: f64| a + (b - a) * w;
    let x0 = l(l(v[0], v[1], u[2]), l(v[2], v[3], u[2]), u[1]);
    let x1 = l(l(v[4], v[5], u[2]), l(v[6], v[7], u[2]), u[1]);
    l(x0, x1, u[0])
}

/// `phi` at index point `p` (f64 arithmetic on the cleaned corners).
fn phi_at(acc: &mut Accessor<'_>, p: [f64; 3]) -> f64 {
    let c = p.map(floor_i64);
    let v = corners(acc, c);
    trilinear(&v, [0, 1, 2].map(|a| p[a] - c[a] as f64))
}

/// The first hit in `[t0, t1]`, dual cell by dual cell.
fn cells_hit(
    acc: &mut Accessor<'_>,
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    index_speed: f64,
) -> Option<f64> {
    let (lo, hi) = crate::regular::cell_range(q, d, t0, t1);
    let cells = Cells { size: 1.0, lo, hi };
    let mut hit = None;
    let _ = dda(q, d, (t0, t1), &cells, |c, ta, tb| {
        let v = corners(acc, c);
        // Trilinear interpolation is a convex combination of the corners: a cell without a
        // negative corner holds no phi < 0. Skipping it exactly keeps the cubic's round-off
        // (an end `s` a hair past the cell, where the polynomial extrapolates below a zero
        // corner) from inventing a hit where the field only touches 0.
        if v.iter().all(|&x| x >= 0.0) {
            return ControlFlow::Continue(());
        }
        let u0 = [0, 1, 2].map(|a| q[a] + d[a] * ta - c[a] as f64);
        hit = cell_hit(&cubic(&v, u0, d), ta, tb, index_speed);
        if hit.is_some() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    hit
}

/// The coefficients `[c0, c1, c2, c3]` of the trilinear field of corners `v` along
/// `u0 + d s` (local coordinates), `p(s) = c0 + c1 s + c2 s^2 + c3 s^3` (module docs).
fn cubic(v: &[f64; 8], u0: [f64; 3], d: [f64; 3]) -> [f64; 4] {
    let kx = v[4] - v[0];
    let ky = v[2] - v[0];
    let kz = v[1] - v[0];
    let kxy = v[6] - v[4] - v[2] + v[0];
    let kxz = v[5] - v[4] - v[1] + v[0];
    let kyz = v[3] - v[2] - v[1] + v[0];
    let kxyz = v[7] - v[6] - v[5] - v[3] + v[4] + v[2] + v[1] - v[0];
    let [x0, y0, z0] = u0;
    let [dx, dy, dz] = d;
    let c0 = trilinear(v, u0);
    let c1 = dx * (kx + kxy * y0 + kxz * z0 + kxyz * y0 * z0)
        + dy * (ky + kxy * x0 + kyz * z0 + kxyz * x0 * z0)
        + dz * (kz + kxz * x0 + kyz * y0 + kxyz * x0 * y0);
    let c2 = kxy * dx * dy
        + kxz * dx * dz
        + kyz * dy * dz
        + kxyz * (x0 * dy * dz + y0 * dx * dz + z0 * dx * dy);
    let c3 = kxyz * dx * dy * dz;
    [c0, c1, c2, c3]
}

/// `p(s)` by Horner's rule.
fn eval(c: &[f64; 4], s: f64) -> f64 {
    ((c[3] * s + c[2]) * s + c[1]) * s + c[0]
}

/// The real roots of `a s^2 + b s + c` (none, one or two; unsorted), by the cancellation-free
/// form `q = -(b + sign(b) sqrt(b^2 - 4ac)) / 2`, roots `q / a` and `c / q`; linear when
/// `a == 0`. Non-finite roots (from overflow) are dropped by the caller's range test.
fn quadratic_roots(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    if a == 0.0 {
        return [(b != 0.0).then(|| -c / b), None];
    }
    let disc = b * b - 4.0 * a * c;
    // NaN (overflow) counts as no root: the piece ends are still checked.
    if disc.is_nan() || disc < 0.0 {
        return [None, None];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    [Some(q / a), (q != 0.0).then(|| c / q)]
}

/// The first `t` in `[ta, tb]` where the cubic `c` (in `s = t - ta`) is negative, or `None`:
/// monotone pieces between the roots of `p'`, bisection on the first piece that ends below 0.
fn cell_hit(c: &[f64; 4], ta: f64, tb: f64, index_speed: f64) -> Option<f64> {
    let len = tb - ta;
    if eval(c, 0.0) < 0.0 {
        return Some(ta);
    }
    let mut ends = [len; 3];
    let mut n = 0;
    for r in quadratic_roots(3.0 * c[3], 2.0 * c[2], c[1])
        .into_iter()
        .flatten()
    {
        if r > 0.0 && r < len {
            ends[n] = r;
            n += 1;
        }
    }
    if n == 2 && ends[1] < ends[0] {
        ends.swap(0, 1);
    }
    let mut sa = 0.0;
    for &sb in &ends[..=n] {
        if eval(c, sb) < 0.0 {
            let (mut lo, mut hi) = (sa, sb);
            for _ in 0..MAX_BISECTIONS {
                if (hi - lo) * index_speed < BRACKET_VOXELS {
                    break;
                }
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if eval(c, mid) < 0.0 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            return Some((ta + hi).clamp(ta, tb));
        }
        sa = sb;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator in `[-1, 1)`.
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    #[test]
    fn the_cubic_is_the_trilinear_field() {
        let mut st = 7u64;
        for _ in 0..1000 {
            let v: [f64; 8] = std::array::from_fn(|_| lcg(&mut st) * 3.0);
            let u0 = [0, 1, 2].map(|_| 0.5 + 0.5 * lcg(&mut st));
            let d = [0, 1, 2].map(|_| lcg(&mut st));
            let c = cubic(&v, u0, d);
            for k in 0..5 {
                let s = f64::from(k) * 0.3;
                let u = [0, 1, 2].map(|a| u0[a] + d[a] * s);
                let want = trilinear(&v, u);
                assert!(
                    (eval(&c, s) - want).abs() < 1e-12,
                    "{} vs {want}",
                    eval(&c, s)
                );
            }
        }
    }

    #[test]
    fn a_dip_between_positive_ends_is_found() {
        // p(s) = (s - 0.5)^2 - 0.01: positive at both ends of [0, 1], negative in (0.4, 0.6).
        let c = [0.24, -1.0, 1.0, 0.0];
        let t = cell_hit(&c, 2.0, 3.0, 1.0).expect("the dip is found");
        assert!((t - 2.4).abs() < 1e-6 && eval(&c, t - 2.0) <= 0.0, "{t}");
        // Touching 0 without going below is no hit.
        assert_eq!(cell_hit(&[0.25, -1.0, 1.0, 0.0], 2.0, 3.0, 1.0), None);
        // A cubic with two interior extrema, positive at both ends, dipping below 0 between
        // the second and third roots: p(s) = 8 (s + 0.2)(s - 0.5)(s - 0.55) + 0.002, checked
        // against a fine scan.
        let c = cubic_from_roots(-0.2, 0.5, 0.55, 8.0, 0.002);
        assert!(eval(&c, 0.0) > 0.0 && eval(&c, 1.0) > 0.0);
        let scan = (0..=1_000_000)
            .map(|i| f64::from(i) * 1e-6)
            .find(|&s| eval(&c, s) < 0.0);
        let t = cell_hit(&c, 0.0, 1.0, 1.0);
        match (scan, t) {
            (Some(s), Some(t)) => assert!((s - t).abs() < 2e-6, "{s} vs {t}"),
            other => panic!("{other:?}"),
        }
    }

    /// `k (s - a)(s - b)(s - c) + e` as coefficients.
    fn cubic_from_roots(a: f64, b: f64, c: f64, k: f64, e: f64) -> [f64; 4] {
        [
            -k * a * b * c + e,
            k * (a * b + a * c + b * c),
            -k * (a + b + c),
            k,
        ]
    }

    #[test]
    fn degenerate_derivatives() {
        assert_eq!(quadratic_roots(0.0, 0.0, 1.0), [None, None]);
        assert_eq!(quadratic_roots(0.0, 2.0, -1.0), [Some(0.5), None]);
        assert_eq!(quadratic_roots(1.0, 0.0, 1.0), [None, None]);
        assert_eq!(quadratic_roots(1.0, 0.0, 0.0), [Some(0.0), None]);
        // Constant field: no hit when non-negative, hit at the entry when negative.
        assert_eq!(cell_hit(&[0.0; 4], 0.0, 1.0, 1.0), None);
        assert_eq!(cell_hit(&[-1.0, 0.0, 0.0, 0.0], 0.5, 1.0, 1.0), Some(0.5));
    }

    #[test]
    fn bad_values_are_finite() {
        assert_eq!(clean(f32::NAN), f64::from(f32::MAX));
        assert_eq!(clean(f32::NEG_INFINITY), -f64::from(f32::MAX));
        assert_eq!(clean(-2.5), -2.5);
    }
}
