//! The baking camera: which world ray each pixel traces, framed on the volume box.
//!
//! Notation: `W x H` pixels, pixel `(i, j)` is column `i`, row `j`, row 0 at the top. The camera
//! basis is `f` (forward, where the rays go), `r` (image right) and `u` (image up), unit and
//! orthogonal, with `r = normalise(f x a)` and `u = r x f` for the reference axis `a`: the
//! requested up direction ([`View::up`], default `+Y`), or, when that is within 2.6 degrees of
//! the light (`|f . a| > 0.999`), the default's fallback: `+Y`, or `-Z` when `|f . Y| > 0.999`,
//! so a light straight above gives `+X` right and `-Z` up, like a top view. So `u` is the part
//! of `a` across the light, and `a` reads as up in the map. `(r, u, f)` is left-handed in a
//! right-handed world: OpenEXR's camera space.
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
//! - **Cube** and **latlong** (`kind = "cube"`, `"latlong"`): omnidirectional maps around a
//!   point light: every ray starts at `origin = P` along the direction of its texel in
//!   OpenEXR's environment-map layouts ([`omni`]); `direction`, `step_x`, `step_y` hold the
//!   map's axes (`forward`, `right` and `-up` times a nominal texel size).
//!
//! `t` is world distance along the unit ray direction, as everywhere in umbra.

pub(crate) mod file;
mod matrix;
pub mod omni;
pub(crate) mod reach;
pub use file::{camera_from_json, read_camera};
pub use omni::{is_omni, Omni, DEFAULT_OMNI_SIDE};
pub use reach::Outside;

use crate::error::{Error, Result};
use crate::math::normalise;
use crate::ray::Ray;
use glam::DVec3;

/// Largest accepted image side.
pub const MAX_SIDE: u32 = 65_536;
/// Largest accepted pixel count (`2^28`, 1 GiB per f32 channel).
pub const MAX_PIXELS: u64 = 1 << 28;
/// Long side of the default resolution.
pub const DEFAULT_LONG_SIDE: u32 = 1024;

/// Projection of a baked map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// Parallel rays from a directional light (or a plane through a light position).
    Ortho,
    /// Rays from a point light through a pinhole image plane.
    Perspective,
    /// Rays from a point light in every direction: six cube faces stacked in one `N x 6N`
    /// image, as OpenEXR's `envmap = cube` (`camera::omni`).
    Cube,
    /// Rays from a point light in every direction: a `2N x N` latitude-longitude image, as
    /// OpenEXR's `envmap = latlong` (`camera::omni`).
    #[serde(rename = "latlong")]
    LatLong,
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
    /// The image size; default [`DEFAULT_LONG_SIDE`] on the long side with the framed box's
    /// aspect.
    pub res: Option<Resolution>,
    /// The world direction that is up in the map (default `+Y`; see the module docs for the
    /// fallback when it is parallel to the light).
    pub up: Option<[f64; 3]>,
    /// Frame this world box `[lo, hi]` instead of the volume box.
    pub frame_box: Option<[[f64; 3]; 2]>,
}

impl Default for View {
    /// An orthographic view with nothing set: give it a light.
    fn default() -> Self {
        Self {
            projection: Projection::Ortho,
            light_dir: None,
            light_pos: None,
            fov_deg: None,
            res: None,
            up: None,
            frame_box: None,
        }
    }
}

/// How large a map is. As data (job files, JSON): `N`, `[W, H]`, or the command line's
/// `"WxH"` / `"N"` text; anything else is refused saying which forms are accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(untagged)]
pub enum Resolution {
    /// Exactly `W x H` pixels (`[W, H]` in job files).
    Exact(u32, u32),
    /// `N` pixels on the long side, the other side from the framed box's aspect (`N` in job
    /// files, `--res N` on the command line).
    LongSide(u32),
}

impl std::str::FromStr for Resolution {
    type Err = String;

    /// `WxH` (exactly that size) or `N` (the long side), as `--res` takes it.
    fn from_str(text: &str) -> std::result::Result<Self, String> {
        let t = text.trim();
        let num = |v: &str| v.trim().parse::<u32>().ok();
        let parsed = match t.split_once(['x', 'X']) {
            Some((w, h)) => num(w).zip(num(h)).map(|(w, h)| Self::Exact(w, h)),
            None => num(t).map(Self::LongSide),
        };
        parsed.ok_or_else(|| {
            format!(
                "'{text}': expected WxH (such as 1024x768) or N (pixels on the long side), \
                 whole positive numbers"
            )
        })
    }
}

/// As data: `N`, `[W, H]` or `"WxH"` / `"N"`.
#[cfg(feature = "schema")]
impl schemars::JsonSchema for Resolution {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        "Resolution".into()
    }

    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        schemars::json_schema!({
            "description": "N pixels on the long side, [W, H], or the command line's \"WxH\" / \"N\"",
            "oneOf": [
                {"type": "integer", "minimum": 1},
                {"type": "array", "items": {"type": "integer", "minimum": 1},
                 "minItems": 2, "maxItems": 2},
                {"type": "string", "pattern": "^\\s*[0-9]+\\s*([xX]\\s*[0-9]+\\s*)?$"}
            ]
        })
    }
}

impl<'de> serde::Deserialize<'de> for Resolution {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Resolution;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("N (the long side), [W, H] or \"WxH\"")
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<Resolution, E> {
                u32::try_from(v)
                    .map(Resolution::LongSide)
                    .map_err(|_| E::custom(format!("{v} pixels is too large a resolution")))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<Resolution, E> {
                u64::try_from(v).map_or_else(
                    |_| {
                        Err(E::custom(format!(
                            "{v} is not a resolution: sides are positive"
                        )))
                    },
                    |v| self.visit_u64(v),
                )
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<Resolution, E> {
                v.parse()
                    .map_err(|e: String| E::custom(format!("res {e}, or [W, H]")))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> std::result::Result<Resolution, A::Error> {
                use serde::de::Error;
                let bad = || A::Error::custom("give [W, H]: two positive integers");
                let w: u32 = seq.next_element()?.ok_or_else(bad)?;
                let h: u32 = seq.next_element()?.ok_or_else(bad)?;
                if seq.next_element::<u32>()?.is_some() {
                    return Err(bad());
                }
                Ok(Resolution::Exact(w, h))
            }
        }
        d.deserialize_any(V)
    }
}

impl Resolution {
    /// Check the size: sides in `1..=MAX_SIDE`, at most [`MAX_PIXELS`] pixels.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `res`.
    pub fn check(self) -> Result<()> {
        match self {
            Self::Exact(w, h) => check_res(w, h),
            Self::LongSide(0) => Err(bad("res", "a long side of 0 pixels has no pixels".into())),
            Self::LongSide(n) if n > MAX_SIDE => Err(bad(
                "res",
                format!("a long side of {n} pixels is too large: at most {MAX_SIDE}"),
            )),
            Self::LongSide(_) => Ok(()),
        }
    }

    /// The exact size for a window of extent `ex x ey`.
    fn size(view: Option<Self>, ex: f64, ey: f64) -> (u32, u32) {
        match view {
            Some(Self::Exact(w, h)) => (w, h),
            Some(Self::LongSide(n)) => default_res(ex, ey, n),
            None => default_res(ex, ey, DEFAULT_LONG_SIDE),
        }
    }
}

/// What a camera is made of, as `umbra bake --json` prints it under `camera` and the
/// `umbra:camera_*` EXR attributes store it: everything needed to rebuild every pixel's ray
/// (see the module docs). Plain data; [`Camera::from_spec`] validates it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraSpec {
    /// `ortho` or `perspective`.
    pub kind: Projection,
    /// Image width `W` in pixels.
    pub width: u32,
    /// Image height `H` in pixels.
    pub height: u32,
    /// Ortho: world start of pixel (0, 0)'s centre ray. Perspective: the light position.
    pub origin: [f64; 3],
    /// World step from one pixel centre to the next along a row.
    pub step_x: [f64; 3],
    /// World step from one pixel centre to the next down a column.
    pub step_y: [f64; 3],
    /// Ortho: the ray direction. Perspective: pixel (0, 0)'s centre on the plane at distance
    /// 1, relative to `origin`.
    pub direction: [f64; 3],
    /// World distance each ray is traced: `t` in `[0, t_max]`.
    pub t_max: f64,
}

/// A framed camera: everything needed to rebuild every pixel's ray (the `camera` object of
/// `umbra bake --json` and the `umbra:camera_*` EXR attributes), plus its basis.
///
/// Invariants (checked by [`Camera::frame`] and [`Camera::from_spec`], so the fields are
/// private): a resolution within [`check_res`], finite vectors, a unit orthonormal basis
/// `(right, up, forward)` with `step_x = s right` and `step_y = -s up` for the pixel size
/// `s > 0`, and `0 <= t_near <= t_max` finite.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Camera {
    pub(crate) kind: Projection,
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) origin: [f64; 3],
    pub(crate) step_x: [f64; 3],
    pub(crate) step_y: [f64; 3],
    pub(crate) direction: [f64; 3],
    pub(crate) t_max: f64,
    pub(crate) t_near: f64,
    pub(crate) forward: [f64; 3],
    pub(crate) right: [f64; 3],
    pub(crate) up: [f64; 3],
    pub(crate) pixel_size: f64,
}

impl Camera {
    /// `ortho` or `perspective`.
    #[must_use]
    pub fn kind(&self) -> Projection {
        self.kind
    }
    /// Image width `W` in pixels.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }
    /// Image height `H` in pixels.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Ortho: world start of pixel (0, 0)'s centre ray. Perspective: the light position.
    #[must_use]
    pub fn origin(&self) -> [f64; 3] {
        self.origin
    }
    /// World step from one pixel centre to the next along a row (`s r`).
    #[must_use]
    pub fn step_x(&self) -> [f64; 3] {
        self.step_x
    }
    /// World step from one pixel centre to the next down a column (`-s u`).
    #[must_use]
    pub fn step_y(&self) -> [f64; 3] {
        self.step_y
    }
    /// Ortho: the unit ray direction. Perspective: pixel (0, 0)'s centre on the plane at
    /// distance 1, relative to `origin`.
    #[must_use]
    pub fn direction(&self) -> [f64; 3] {
        self.direction
    }
    /// World distance each ray is traced: `t` in `[0, t_max]`.
    #[must_use]
    pub fn t_max(&self) -> f64 {
        self.t_max
    }
    /// No ray meets the volume box before this `t` (the start of the volume's depth range).
    #[must_use]
    pub fn t_near(&self) -> f64 {
        self.t_near
    }
    /// Forward axis `f` (unit).
    #[must_use]
    pub fn forward(&self) -> [f64; 3] {
        self.forward
    }
    /// Right axis `r` (unit).
    #[must_use]
    pub fn right(&self) -> [f64; 3] {
        self.right
    }
    /// Up axis `u` (unit).
    #[must_use]
    pub fn up(&self) -> [f64; 3] {
        self.up
    }
    /// Pixel size `s`: world units (ortho) or on the plane at distance 1 (perspective).
    #[must_use]
    pub fn pixel_size(&self) -> f64 {
        self.pixel_size
    }

    /// The plain data of this camera.
    #[must_use]
    pub fn spec(&self) -> CameraSpec {
        CameraSpec {
            kind: self.kind,
            width: self.width,
            height: self.height,
            origin: self.origin,
            step_x: self.step_x,
            step_y: self.step_y,
            direction: self.direction,
            t_max: self.t_max,
        }
    }

    /// A camera from its plain data (an earlier map's, or made by hand). The basis is derived:
    /// `right = step_x / |step_x|`, `up = -step_y / |step_y|`, `s = |step_x|`; `forward` is the
    /// ortho direction (normalised), or the perspective image centre's direction
    /// `normalise(direction + step_x (W - 1) / 2 + step_y (H - 1) / 2)`. `t_near` is 0.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `camera`, or `res`) for a resolution out of range,
    /// non-finite values, a negative `t_max`, pixel steps that are zero, of different lengths
    /// or not orthogonal to each other and to the forward axis (relative tolerance 1e-6).
    pub fn from_spec(c: &CameraSpec) -> Result<Self> {
        check_res(c.width, c.height)?;
        let v = DVec3::from_array;
        let (sx, sy, dir) = (v(c.step_x), v(c.step_y), v(c.direction));
        let finite = v(c.origin).is_finite() && sx.is_finite() && sy.is_finite() && dir.is_finite();
        if !(finite && c.t_max.is_finite() && c.t_max >= 0.0) {
            return Err(bad(
                "camera",
                format!("non-finite or negative values in {c:?}"),
            ));
        }
        let s = sx.length();
        let (Some(r), Some(u_neg)) = (normalise(sx), normalise(sy)) else {
            return Err(bad("camera", "a pixel step is zero".into()));
        };
        let u = -u_neg;
        let centre = match c.kind {
            Projection::Ortho | Projection::Cube | Projection::LatLong => dir,
            Projection::Perspective => {
                dir + sx * (0.5 * (f64::from(c.width) - 1.0))
                    + sy * (0.5 * (f64::from(c.height) - 1.0))
            }
        };
        let Some(f) = normalise(centre) else {
            return Err(bad("camera", "the view direction is zero".into()));
        };
        let tol = 1e-6;
        if ((sy.length() - s) / s).abs() > tol
            || r.dot(u).abs() > tol
            || r.dot(f).abs() > tol
            || u.dot(f).abs() > tol
        {
            return Err(bad(
                "camera",
                "pixel steps must have one length and be orthogonal to each other and to the \
                 view direction"
                    .into(),
            ));
        }
        Ok(Self {
            kind: c.kind,
            width: c.width,
            height: c.height,
            origin: c.origin,
            step_x: c.step_x,
            step_y: c.step_y,
            // An ortho direction that is already unit (an earlier map's) is kept bit for bit,
            // so a reused camera writes the same attributes.
            direction: match c.kind {
                Projection::Ortho if (dir.length() - 1.0).abs() <= 4.0 * f64::EPSILON => {
                    c.direction
                }
                Projection::Ortho => clean(f),
                Projection::Perspective | Projection::Cube | Projection::LatLong => c.direction,
            },
            t_max: c.t_max,
            t_near: 0.0,
            forward: clean(f),
            right: clean(r),
            up: clean(u),
            pixel_size: s,
        })
    }
}

/// Every field of a [`Camera`], as a cache stores it (see [`Camera::restore`]).
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub(crate) struct CameraParts {
    spec: CameraSpec,
    t_near: f64,
    forward: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    pixel_size: f64,
}

impl Camera {
    /// This camera's fields, for [`Camera::restore`].
    pub(crate) fn parts(&self) -> CameraParts {
        CameraParts {
            spec: self.spec(),
            t_near: self.t_near,
            forward: self.forward,
            right: self.right,
            up: self.up,
            pixel_size: self.pixel_size,
        }
    }

    /// A camera stored by [`Camera::parts`], bit for bit: the spec passes
    /// [`Camera::from_spec`], and the stored basis, pixel size and `t_near` must agree with
    /// what it derives (to 1e-9 relative) and lie in `[0, t_max]`; then the stored values are
    /// kept exactly, so the camera equals the one that was stored.
    pub(crate) fn restore(p: &CameraParts) -> Result<Self> {
        let derived = Self::from_spec(&p.spec)?;
        let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() <= 1e-9);
        let ok = near(p.forward, derived.forward)
            && near(p.right, derived.right)
            && near(p.up, derived.up)
            && (p.pixel_size - derived.pixel_size).abs() <= 1e-9 * derived.pixel_size
            && (0.0..=p.spec.t_max).contains(&p.t_near);
        if !ok {
            return Err(bad(
                "camera",
                "stored basis, pixel size or t_near disagree with the camera".into(),
            ));
        }
        Ok(Self {
            t_near: p.t_near,
            forward: p.forward,
            right: p.right,
            up: p.up,
            pixel_size: p.pixel_size,
            direction: p.spec.direction,
            ..derived
        })
    }
}

/// `+ 0.0` turns -0 into +0, so headers and JSON never show "-0".
fn clean(v: DVec3) -> [f64; 3] {
    (v + DVec3::ZERO).to_array()
}

fn bad(name: &str, reason: String) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason,
    }
}

/// The camera basis `(r, u)` for forward `f` and the unit up direction `up` (see the module
/// docs).
fn basis(f: DVec3, up: Option<DVec3>) -> (DVec3, DVec3) {
    let a = match up {
        Some(a) if f.dot(a).abs() <= 0.999 => a,
        _ if f.y.abs() > 0.999 => DVec3::NEG_Z,
        _ => DVec3::Y,
    };
    let r = normalise(f.cross(a)).unwrap_or(DVec3::X);
    (r, r.cross(f))
}

/// The 8 corners of the world box `[lo, hi]` (a frame box, a union of volume boxes), in the
/// order of [`crate::Volume::box_corners`].
pub use crate::math::box_corners as world_box_corners;

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

/// `(W, H)` for a window of extent `ex x ey`: the long side gets `long`, the short one
/// `round(long x short extent / long extent)` (at least 1).
fn default_res(ex: f64, ey: f64, long: u32) -> (u32, u32) {
    let short = |a: f64, b: f64| {
        let v = (f64::from(long) * a / b).round();
        if v.is_finite() {
            v.clamp(1.0, f64::from(long)) as u32
        } else {
            long
        }
    };
    if ex >= ey {
        (long, short(ey, ex))
    } else {
        (short(ex, ey), long)
    }
}

impl Camera {
    /// Frame `corners` (the volume box, see [`crate::Volume::box_corners`], or the corners of
    /// several boxes: what a shared camera frames) as `view` asks:
    /// the window holds `view.frame_box` instead when it is given, while the depth range (the
    /// ortho image plane, `t_near`, `t_max`) still covers the volume box as well. The basis
    /// follows `view.up` (module docs).
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
    /// [`Error::InvalidArgument`] for no corners or non-finite ones, a zero light direction or
    /// up direction, an empty or non-finite frame box, a missing light, a resolution out of
    /// range, a field of view outside `(0, 180)`, an ortho light inside or beside the box, or a
    /// perspective light inside the box without a field of view.
    pub fn frame(view: &View, corners: &[DVec3]) -> Result<Self> {
        if corners.is_empty() || !corners.iter().all(|c| c.is_finite()) {
            return Err(bad("grid", "no finite volume box to frame".into()));
        }
        if let Some(r) = view.res {
            r.check()?;
        }
        if is_omni(view.projection) {
            return Self::frame_omni(view, corners);
        }
        let volume = corners;
        let boxed;
        let corners = match view.frame_box {
            Some(b) => {
                let ok =
                    (0..3).all(|a| b[0][a].is_finite() && b[1][a].is_finite() && b[0][a] < b[1][a]);
                if !ok {
                    return Err(bad(
                        "frame-box",
                        format!(
                            "{:?}: give X0,Y0,Z0,X1,Y1,Z1 with finite values and X0 < X1, Y0 < Y1, \
                             Z0 < Z1",
                            [b[0], b[1]].concat()
                        ),
                    ));
                }
                boxed = world_box_corners(b);
                &boxed[..]
            }
            None => corners,
        };
        // Depth (the image plane, `t_max`) covers the volume too, so a framed region still
        // sees all the density in front of and behind it.
        let depth: Vec<DVec3> = match view.frame_box {
            Some(_) => corners.iter().chain(volume).copied().collect(),
            None => volume.to_vec(),
        };
        let up = match view.up {
            Some(u) => Some(normalise(DVec3::from_array(u)).ok_or_else(|| {
                bad(
                    "up",
                    format!(
                        "{u:?} has no direction; give the world direction that is up in the map"
                    ),
                )
            })?),
            None => None,
        };
        let dir = match view.light_dir {
            Some(d) => Some(normalise(DVec3::from_array(d)).ok_or_else(|| {
                bad(
                    "light-dir",
                    format!("{d:?} has no length; give the direction the light travels"),
                )
            })?),
            None => None,
        };
        // The centre of the points' bounding box (a box's own centre, by its symmetry).
        let (lo, hi) = corners.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &c| (lo.min(c), hi.max(c)),
        );
        let centre = (lo + hi) * 0.5;
        let towards_centre = |p: DVec3| {
            normalise(centre - p).ok_or_else(|| {
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
                    (None, Some(p)) => towards_centre(DVec3::from_array(p))?,
                    (None, None) => {
                        return Err(bad(
                            "light-dir",
                            "an ortho map needs a light direction".into(),
                        ))
                    }
                };
                Self::ortho(f, up, view, corners, &depth)
            }
            Projection::Cube | Projection::LatLong => Self::frame_omni(view, corners),
            Projection::Perspective => {
                let p = DVec3::from_array(view.light_pos.ok_or_else(|| {
                    bad(
                        "light-pos",
                        "a perspective map needs a light position".into(),
                    )
                })?);
                let f = match dir {
                    Some(d) => d,
                    None => towards_centre(p)?,
                };
                Self::perspective(p, f, up, view, corners, &depth)
            }
        }
    }

    fn ortho(
        f: DVec3,
        up: Option<DVec3>,
        view: &View,
        corners: &[DVec3],
        depth: &[DVec3],
    ) -> Result<Self> {
        let (r, u) = basis(f, up);
        let range = |points: &[DVec3], axis: DVec3| {
            points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &c| {
                    let v = c.dot(axis);
                    (lo.min(v), hi.max(v))
                })
        };
        let ((x0, x1), (y0, y1), (z0, z1)) =
            (range(corners, r), range(corners, u), range(depth, f));
        let plane = match view.light_pos {
            Some(p) => {
                let zp = DVec3::from_array(p).dot(f);
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
        let (w, h) = Resolution::size(view.res, ex, ey);
        let s = (ex / f64::from(w)).max(ey / f64::from(h));
        let c = (r * (0.5 * (x0 + x1)) + u * (0.5 * (y0 + y1))) + f * plane;
        let origin =
            (c + r * ((0.5 - 0.5 * f64::from(w)) * s)) + u * ((0.5 * f64::from(h) - 0.5) * s);
        Ok(Self {
            kind: Projection::Ortho,
            width: w,
            height: h,
            origin: clean(origin),
            step_x: clean(r * s),
            step_y: clean(u * -s),
            direction: clean(f),
            t_max: z1 - plane,
            t_near: z0 - plane,
            forward: clean(f),
            right: clean(r),
            up: clean(u),
            pixel_size: s,
        })
    }

    fn perspective(
        p: DVec3,
        f: DVec3,
        up: Option<DVec3>,
        view: &View,
        corners: &[DVec3],
        depth: &[DVec3],
    ) -> Result<Self> {
        let (r, u) = basis(f, up);
        let rel: Vec<DVec3> = corners.iter().map(|&c| c - p).collect();
        let z_min = rel.iter().map(|&v| v.dot(f)).fold(f64::INFINITY, f64::min);
        let t_max = depth.iter().map(|&c| (c - p).length()).fold(0.0, f64::max);
        let z_near = depth
            .iter()
            .map(|&c| (c - p).dot(f))
            .fold(f64::INFINITY, f64::min);
        let (w, h, s) = match view.fov_deg {
            Some(fov) => {
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(bad(
                        "fov",
                        format!("{} is not in (0, 180) degrees", crate::math::short(fov)),
                    ));
                }
                let (w, h) = Resolution::size(view.res, 1.0, 1.0);
                let s = 2.0 * (0.5 * fov.to_radians()).tan() / f64::from(w.max(h));
                (w, h, s)
            }
            None => {
                if z_min <= 0.0 {
                    return Err(bad(
                        "light-pos",
                        format!(
                            "the light at {:?} is inside or beside the volume box, so no view \
                             from it holds the whole box; give --omni cube|latlong (every direction), or --fov DEG \
                             (and --light-dir to aim)",
                            p.to_array()
                        ),
                    ));
                }
                let (mut ax, mut ay) = (0.0f64, 0.0f64);
                for &v in &rel {
                    let z = v.dot(f);
                    ax = ax.max((v.dot(r) / z).abs());
                    ay = ay.max((v.dot(u) / z).abs());
                }
                let (w, h) = Resolution::size(view.res, ax, ay);
                (w, h, (2.0 * ax / f64::from(w)).max(2.0 * ay / f64::from(h)))
            }
        };
        let direction =
            (f + r * ((0.5 - 0.5 * f64::from(w)) * s)) + u * ((0.5 * f64::from(h) - 0.5) * s);
        Ok(Self {
            kind: Projection::Perspective,
            width: w,
            height: h,
            origin: clean(p),
            step_x: clean(r * s),
            step_y: clean(u * -s),
            direction: clean(direction),
            t_max,
            t_near: z_near.max(0.0),
            forward: clean(f),
            right: clean(r),
            up: clean(u),
            pixel_size: s,
        })
    }

    /// The same view at another resolution: the window (its centre, basis and extent
    /// `W s x H s`) is kept and the new pixels are square, `s' = max(W s / W', H s / H')`, so
    /// the old window fits the new image, centred, when the aspect differs (`res = N` keeps the
    /// aspect). The ray start (`origin` for ortho) or pixel (0, 0)'s direction (perspective) is
    /// `centre - r s' (W' - 1) / 2 + u s' (H' - 1) / 2`. The same size gives the camera back
    /// unchanged.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `res` for a size out of range.
    pub fn with_resolution(&self, res: Resolution) -> Result<Self> {
        res.check()?;
        if is_omni(self.kind) {
            let mut c = Self::omni(self.kind, self.origin, Some(res), &[])?;
            (c.t_max, c.right, c.up, c.forward) = (self.t_max, self.right, self.up, self.forward);
            let s = c.pixel_size;
            let v = DVec3::from_array;
            (c.step_x, c.step_y) = (clean(v(c.right) * s), clean(v(c.up) * -s));
            c.direction = c.forward;
            return Ok(c);
        }
        let s = self.pixel_size;
        let (ex, ey) = (f64::from(self.width) * s, f64::from(self.height) * s);
        let (w, h) = Resolution::size(Some(res), ex, ey);
        if (w, h) == (self.width, self.height) {
            return Ok(*self);
        }
        let v = DVec3::from_array;
        let (r, u) = (v(self.right), v(self.up));
        let anchor = match self.kind {
            Projection::Ortho => v(self.origin),
            _ => v(self.direction),
        };
        let half = |n: u32| 0.5 * (f64::from(n) - 1.0);
        let centre =
            anchor + v(self.step_x) * half(self.width) + v(self.step_y) * half(self.height);
        let s2 = (ex / f64::from(w)).max(ey / f64::from(h));
        let moved = centre - r * (s2 * half(w)) + u * (s2 * half(h));
        let mut c = *self;
        (c.width, c.height, c.pixel_size) = (w, h, s2);
        (c.step_x, c.step_y) = (clean(r * s2), clean(u * -s2));
        match self.kind {
            Projection::Ortho => c.origin = clean(moved),
            _ => c.direction = clean(moved),
        }
        Ok(c)
    }

    /// [`Camera::frame`] for an omnidirectional view: the light position and the size only.
    fn frame_omni(view: &View, corners: &[DVec3]) -> Result<Self> {
        let Some(pos) = view.light_pos else {
            return Err(bad(
                "omni",
                "an omnidirectional map is seen from a point light: give --light-pos".into(),
            ));
        };
        let set = [
            ("light-dir", view.light_dir.is_some()),
            ("fov", view.fov_deg.is_some()),
            ("frame-box", view.frame_box.is_some()),
            ("up", view.up.is_some()),
        ];
        if let Some((name, _)) = set.iter().find(|(_, on)| *on) {
            return Err(bad(
                name,
                "an omnidirectional map sees every direction from the light, in the world's \
                 axes: leave it out"
                    .into(),
            ));
        }
        Self::omni(view.projection, pos, view.res, corners)
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
        let v = DVec3::from_array;
        let offset = v(self.step_x) * x + v(self.step_y) * y;
        match self.kind {
            Projection::Ortho => {
                Ray::new(v(self.origin) + offset, v(self.direction), 0.0, self.t_max)
            }
            Projection::Perspective => {
                Ray::new(v(self.origin), v(self.direction) + offset, 0.0, self.t_max)
            }
            Projection::Cube | Projection::LatLong => {
                let d = self.omni_direction(i, j).unwrap_or(DVec3::Z);
                Ray::new(v(self.origin), d, 0.0, self.t_max)
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
