//! The baking camera: which world ray each pixel traces, framed on the volume box.
//!
//! Notation: `W x H` pixels, pixel `(i, j)` is column `i`, row `j`, row 0 at the top. The camera
//! basis is `f` (forward, where the rays go), `r` (image right) and `u` (image up), unit and
//! orthogonal, with `r = normalise(f x a)` and `u = r x f` for the reference axis `a = +Y` (or `-Z`
//! when `|f . Y| > 0.999`, so a light straight above gives `+X` right and `-Z` up, like a top
//! view). `(r, u, f)` is left-handed in a right-handed world: OpenEXR's camera space.
//!
//! - **Orthographic** (`kind = "ortho"`): every pixel starts on the image plane and runs along
//!   `f = direction`:
//!   `origin(i, j) = origin + i step_x + j step_y`, ray `origin(i, j) + t f`, `t` in `[0, t_max]`,
//!   with `step_x = s r`, `step_y = -s u` for the pixel size `s` (world units).
//! - **Perspective** (`kind = "perspective"`): every ray starts at the light `origin = P` with
//!   direction `normalise(direction + i step_x + j step_y)`, `t` in `[0, t_max]`; `direction` is
//!   pixel (0, 0)'s centre on the image plane at distance 1 from `P` (not unit length), and
//!   `step_x = s r`, `step_y = -s u` are pixel steps on that plane.
//!
//! `t` is world distance along the unit ray direction, as everywhere in umbra.

use crate::error::{Error, Result};
use crate::ray::Ray;

/// Largest accepted image side.
pub const MAX_SIDE: u32 = 65_536;
/// Largest accepted pixel count (`2^28`, 1 GiB per f32 channel).
pub const MAX_PIXELS: u64 = 1 << 28;
/// Long side of the default resolution.
pub const DEFAULT_LONG_SIDE: u32 = 1024;

/// Projection of a baked map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// Parallel rays from a directional light (or a plane through a light position).
    Ortho,
    /// Rays from a point light through a pinhole image plane.
    Perspective,
}

/// What the user asked the camera to be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Projection.
    pub projection: Projection,
    /// Direction the light travels (from the light into the scene). Required for an ortho map
    /// without `light_pos`; aims a perspective map (default: at the volume box centre).
    pub light_dir: Option<[f64; 3]>,
    /// Light position: the pinhole of a perspective map, or a point of an ortho map's image plane.
    pub light_pos: Option<[f64; 3]>,
    /// Full field of view across the longer image side, in degrees (perspective only; default:
    /// the smallest symmetric view that holds the whole volume box).
    pub fov_deg: Option<f64>,
    /// `(W, H)`; default [`DEFAULT_LONG_SIDE`] on the long side with the framed box's aspect.
    pub res: Option<(u32, u32)>,
}

/// A framed camera: everything needed to rebuild every pixel's ray (the `camera` object of
/// `umbra bake --json` and the `umbra:camera_*` EXR attributes).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Camera {
    /// `ortho` or `perspective`.
    pub kind: Projection,
    /// Image width `W` in pixels.
    pub width: u32,
    /// Image height `H` in pixels.
    pub height: u32,
    /// Ortho: world start of pixel (0, 0)'s centre ray. Perspective: the light position.
    pub origin: [f64; 3],
    /// World step from one pixel centre to the next along a row (`s r`).
    pub step_x: [f64; 3],
    /// World step from one pixel centre to the next down a column (`-s u`).
    pub step_y: [f64; 3],
    /// Ortho: the unit ray direction. Perspective: pixel (0, 0)'s centre on the plane at
    /// distance 1, relative to `origin`.
    pub direction: [f64; 3],
    /// World distance each ray is traced: `t` in `[0, t_max]`.
    pub t_max: f64,
    /// No ray meets the volume box before this `t` (the start of the volume's depth range).
    pub t_near: f64,
    /// Forward axis `f` (unit).
    pub forward: [f64; 3],
    /// Right axis `r` (unit).
    pub right: [f64; 3],
    /// Up axis `u` (unit).
    pub up: [f64; 3],
    /// Pixel size `s`: world units (ortho) or on the plane at distance 1 (perspective).
    pub pixel_size: f64,
}

pub(crate) fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn mul(a: [f64; 3], k: f64) -> [f64; 3] {
    a.map(|v| v * k)
}
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// `v / |v|`, or `None` for a zero or non-finite vector.
pub(crate) fn normalise(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = dot(v, v).sqrt();
    (n > 0.0 && n.is_finite() && v.iter().all(|c| c.is_finite())).then(|| mul(v, 1.0 / n))
}

/// `+ 0.0` turns -0 into +0, so headers and JSON never show "-0".
fn clean(v: [f64; 3]) -> [f64; 3] {
    v.map(|c| c + 0.0)
}

fn bad(name: &str, reason: String) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason,
    }
}

/// The camera basis `(r, u)` for forward `f` (see the module docs).
fn basis(f: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if f[1].abs() > 0.999 {
        [0.0, 0.0, -1.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let r = normalise(cross(f, a)).unwrap_or([1.0, 0.0, 0.0]);
    (r, cross(r, f))
}

/// Check a resolution: both sides in `1..=MAX_SIDE`, at most [`MAX_PIXELS`] pixels.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `res`.
pub fn check_res(w: u32, h: u32) -> Result<()> {
    if w == 0 || h == 0 {
        return Err(bad("res", format!("{w}x{h} has no pixels")));
    }
    if w > MAX_SIDE || h > MAX_SIDE || u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(bad(
            "res",
            format!("{w}x{h} is too large (at most {MAX_SIDE} per side and {MAX_PIXELS} pixels)"),
        ));
    }
    Ok(())
}

/// Default `(W, H)` for a window of extent `ex x ey`: the long side gets `DEFAULT_LONG_SIDE`.
fn default_res(ex: f64, ey: f64) -> (u32, u32) {
    let short = |a: f64, b: f64| {
        let v = (f64::from(DEFAULT_LONG_SIDE) * a / b).round();
        v.clamp(1.0, f64::from(DEFAULT_LONG_SIDE)) as u32
    };
    if ex >= ey {
        (DEFAULT_LONG_SIDE, short(ey, ex))
    } else {
        (short(ex, ey), DEFAULT_LONG_SIDE)
    }
}

impl Camera {
    /// Frame `corners` (the volume box, see [`super::volume_corners`]) as `view` asks.
    ///
    /// Ortho: the corners project to `x = c . r`, `y = c . u`, `z = c . f`; the window is their
    /// `[x] x [y]` range, the pixel size `s = max(ex / W, ey / H)` (square pixels, the box
    /// centred), the image plane sits at `z0 = min z` (or at `z0 = P . f` through a light
    /// position, which must not be past `min z`), and `t_max = max z - z0`.
    ///
    /// Perspective: corner `c` projects to `x = (c - P) . r / z`, `y = (c - P) . u / z` with
    /// `z = (c - P) . f`; without a field of view the window is the symmetric
    /// `[-max|x|, max|x|] x [-max|y|, max|y|]` (all corners must be in front of the light);
    /// with one, `s = 2 tan(fov / 2) / max(W, H)`. `t_max = max |c - P|`, past which every
    /// ray has left the box.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a zero light direction, a missing light, a resolution out
    /// of range, a field of view outside `(0, 180)`, an ortho light inside or beside the box, or
    /// a perspective light inside the box without a field of view.
    pub fn frame(view: &View, corners: &[[f64; 3]; 8]) -> Result<Self> {
        if let Some((w, h)) = view.res {
            check_res(w, h)?;
        }
        let dir = match view.light_dir {
            Some(d) => Some(normalise(d).ok_or_else(|| {
                bad(
                    "light-dir",
                    format!("{d:?} has no length; give the direction the light travels"),
                )
            })?),
            None => None,
        };
        let centre = mul(corners.iter().fold([0.0; 3], |a, &c| add(a, c)), 0.125);
        let towards_centre = |p: [f64; 3]| {
            normalise(sub(centre, p)).ok_or_else(|| {
                bad(
                    "light-pos",
                    "the light is at the centre of the volume box; give --light-dir to aim it"
                        .into(),
                )
            })
        };
        match view.projection {
            Projection::Ortho => {
                let f = match (dir, view.light_pos) {
                    (Some(d), _) => d,
                    (None, Some(p)) => towards_centre(p)?,
                    (None, None) => {
                        return Err(bad(
                            "light-dir",
                            "an ortho map needs a light direction".into(),
                        ))
                    }
                };
                Self::ortho(f, view, corners)
            }
            Projection::Perspective => {
                let p = view.light_pos.ok_or_else(|| {
                    bad(
                        "light-pos",
                        "a perspective map needs a light position".into(),
                    )
                })?;
                let f = match dir {
                    Some(d) => d,
                    None => towards_centre(p)?,
                };
                Self::perspective(p, f, view, corners)
            }
        }
    }

    fn ortho(f: [f64; 3], view: &View, corners: &[[f64; 3]; 8]) -> Result<Self> {
        let (r, u) = basis(f);
        let range = |axis: [f64; 3]| {
            corners
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &c| {
                    let v = dot(c, axis);
                    (lo.min(v), hi.max(v))
                })
        };
        let ((x0, x1), (y0, y1), (z0, z1)) = (range(r), range(u), range(f));
        let plane = match view.light_pos {
            Some(p) => {
                let zp = dot(p, f);
                if zp > z0 {
                    return Err(bad(
                        "light-pos",
                        format!(
                            "the light at {p:?} is inside or beside the volume: an ortho map starts \
                             on the plane through the light, which cuts the volume box {:.6} world \
                             units deep; move the light back against the light direction",
                            zp - z0
                        ),
                    ));
                }
                zp
            }
            None => z0,
        };
        let (ex, ey) = (x1 - x0, y1 - y0);
        let (w, h) = view.res.unwrap_or_else(|| default_res(ex, ey));
        let s = (ex / f64::from(w)).max(ey / f64::from(h));
        let c = add(
            add(mul(r, 0.5 * (x0 + x1)), mul(u, 0.5 * (y0 + y1))),
            mul(f, plane),
        );
        let origin = add(
            add(c, mul(r, (0.5 - 0.5 * f64::from(w)) * s)),
            mul(u, (0.5 * f64::from(h) - 0.5) * s),
        );
        Ok(Self {
            kind: Projection::Ortho,
            width: w,
            height: h,
            origin: clean(origin),
            step_x: clean(mul(r, s)),
            step_y: clean(mul(u, -s)),
            direction: clean(f),
            t_max: z1 - plane,
            t_near: z0 - plane,
            forward: clean(f),
            right: clean(r),
            up: clean(u),
            pixel_size: s,
        })
    }

    fn perspective(p: [f64; 3], f: [f64; 3], view: &View, corners: &[[f64; 3]; 8]) -> Result<Self> {
        let (r, u) = basis(f);
        let rel: Vec<[f64; 3]> = corners.iter().map(|&c| sub(c, p)).collect();
        let z_min = rel.iter().map(|&v| dot(v, f)).fold(f64::INFINITY, f64::min);
        let t_max = rel.iter().map(|&v| dot(v, v).sqrt()).fold(0.0, f64::max);
        let (w, h, s) = match view.fov_deg {
            Some(fov) => {
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(bad("fov", format!("{fov} is not in (0, 180) degrees")));
                }
                let (w, h) = view.res.unwrap_or((DEFAULT_LONG_SIDE, DEFAULT_LONG_SIDE));
                let s = 2.0 * (0.5 * fov.to_radians()).tan() / f64::from(w.max(h));
                (w, h, s)
            }
            None => {
                if z_min <= 0.0 {
                    return Err(bad(
                        "light-pos",
                        format!(
                            "the light at {p:?} is inside or beside the volume box, so no view \
                             from it holds the whole box; give --fov DEG (and --light-dir to aim)"
                        ),
                    ));
                }
                let (mut ax, mut ay) = (0.0f64, 0.0f64);
                for &v in &rel {
                    let z = dot(v, f);
                    ax = ax.max((dot(v, r) / z).abs());
                    ay = ay.max((dot(v, u) / z).abs());
                }
                let (w, h) = view.res.unwrap_or_else(|| default_res(ax, ay));
                (w, h, (2.0 * ax / f64::from(w)).max(2.0 * ay / f64::from(h)))
            }
        };
        let direction = add(
            add(f, mul(r, (0.5 - 0.5 * f64::from(w)) * s)),
            mul(u, (0.5 * f64::from(h) - 0.5) * s),
        );
        Ok(Self {
            kind: Projection::Perspective,
            width: w,
            height: h,
            origin: clean(p),
            step_x: clean(mul(r, s)),
            step_y: clean(mul(u, -s)),
            direction: clean(direction),
            t_max,
            t_near: z_min.max(0.0),
            forward: clean(f),
            right: clean(r),
            up: clean(u),
            pixel_size: s,
        })
    }

    /// Pixel count `W x H`.
    #[must_use]
    pub fn pixels(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// The ray of pixel `(i, j)` (column, row), traced over `[0, t_max]` (see the module docs).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] only for a degenerate camera (non-finite values).
    pub fn pixel_ray(&self, i: u32, j: u32) -> Result<Ray> {
        let (x, y) = (f64::from(i), f64::from(j));
        let offset = add(mul(self.step_x, x), mul(self.step_y, y));
        match self.kind {
            Projection::Ortho => {
                Ray::new(add(self.origin, offset), self.direction, 0.0, self.t_max)
            }
            Projection::Perspective => {
                Ray::new(self.origin, add(self.direction, offset), 0.0, self.t_max)
            }
        }
    }

    /// Full horizontal and vertical fields of view in degrees (perspective only):
    /// `2 atan(W s / 2)` and `2 atan(H s / 2)`.
    #[must_use]
    pub fn fov_deg(&self) -> Option<(f64, f64)> {
        let a = |n: u32| 2.0 * (0.5 * f64::from(n) * self.pixel_size).atan().to_degrees();
        (self.kind == Projection::Perspective).then(|| (a(self.width), a(self.height)))
    }
}
