//! Cameras reused from files: exactly the camera of an earlier map, so a new map lines up with
//! it pixel for pixel.
//!
//! - **An umbra EXR map**: its `umbra:camera_kind` (text), `umbra:camera_origin`,
//!   `umbra:camera_step_x`, `umbra:camera_step_y`, `umbra:camera_direction` (`v3d`, three
//!   little-endian f64) and `umbra:camera_t_max` (double) attributes, and the size of its data
//!   window. The values are the f64 the map was traced with, so the camera is rebuilt bit for
//!   bit.
//! - **JSON**: the summary `umbra bake --json` prints (its `camera` object, `width`, `height`),
//!   or a bare `camera` object (`kind`, `origin`, `step_x`, `step_y`, `direction`, `t_max`,
//!   optionally `width` and `height`).
//!
//! The resolution comes from the file unless one is given: then the same window is kept at the
//! new size ([`Camera::with_resolution`]). A bare camera object without a size takes the given
//! `W x H` as is (its pixel steps fix the window).

use crate::bake::camera::{Camera, CameraSpec, Projection, Resolution};
use crate::error::{Error, Result};
use exr::meta::attribute::AttributeValue;
use std::path::Path;

/// OpenEXR's magic number, the first 4 bytes of every EXR file.
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

fn bad(path: &Path, reason: impl std::fmt::Display) -> Error {
    Error::InvalidArgument {
        name: "camera".into(),
        reason: format!("{}: {reason}", path.display()),
    }
}

/// The camera stored in `path` (an umbra EXR map or JSON, see the module docs), at the file's
/// resolution or at `res`.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read; [`Error::InvalidArgument`] (name `camera`,
/// naming the file) when it holds no camera, or one that [`Camera::from_spec`] refuses, or a
/// bare camera without a size and no `W x H` given; (name `res`) for a size out of range.
pub fn read_camera(path: &Path, res: Option<Resolution>) -> Result<Camera> {
    let io = |err| Error::Io {
        path: path.to_path_buf(),
        err,
    };
    // The first 4 bytes tell an EXR map (whose header alone is read) from JSON.
    let mut magic = [0u8; 4];
    let mut file = std::fs::File::open(path).map_err(io)?;
    let is_exr = std::io::Read::read_exact(&mut file, &mut magic).is_ok() && magic == EXR_MAGIC;
    let (spec, size) = if is_exr {
        from_exr(path)?
    } else {
        from_json(path, &std::fs::read(path).map_err(io)?)?
    };
    sized(path, spec, size, res)
}

/// The camera in `json` (a `bake --json` summary or a bare camera object, as in a file
/// [`read_camera`] reads), at its own resolution or at `res`; messages name it `label`.
///
/// # Errors
/// As [`read_camera`], but for reading a file.
pub fn camera_from_json(label: &str, json: &[u8], res: Option<Resolution>) -> Result<Camera> {
    let path = Path::new(label);
    let (spec, size) = from_json(path, json)?;
    sized(path, spec, size, res)
}

/// `spec` at the file's size or at `res`.
fn sized(
    path: &Path,
    spec: CameraSpec,
    size: Option<(u32, u32)>,
    res: Option<Resolution>,
) -> Result<Camera> {
    let with_size = |(width, height): (u32, u32)| {
        Camera::from_spec(&CameraSpec {
            width,
            height,
            ..spec
        })
        .map_err(|e| bad(path, e))
    };
    match (size, res) {
        (Some(wh), None) => with_size(wh),
        (Some(wh), Some(r)) => with_size(wh)?.with_resolution(r),
        (None, Some(Resolution::Exact(w, h))) => with_size((w, h)),
        (None, _) => Err(bad(
            path,
            "the camera has no width and height; give --res WxH (its pixel steps stay as they are)",
        )),
    }
}

/// The spec (its size still 0 x 0) and the size from an umbra EXR map's header.
fn from_exr(path: &Path) -> Result<(CameraSpec, Option<(u32, u32)>)> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| bad(path, format!("not a readable OpenEXR file: {e}")))?;
    let header = meta
        .headers
        .first()
        .ok_or_else(|| bad(path, "an OpenEXR file without a header"))?;
    let attrs = &header.own_attributes.other;
    let get = |k: &str| {
        attrs.get(&exr::meta::attribute::Text::from(
            format!("umbra:{k}").as_str(),
        ))
    };
    let missing = |k: &str| {
        bad(
            path,
            format!("no umbra:{k} attribute: not a map written by umbra bake"),
        )
    };
    let v3 = |k: &str| -> Result<[f64; 3]> {
        match get(k) {
            Some(AttributeValue::Custom { kind, bytes })
                if kind.as_slice() == b"v3d" && bytes.len() == 24 =>
            {
                Ok(std::array::from_fn(|a| {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(&bytes[8 * a..8 * a + 8]);
                    f64::from_le_bytes(b)
                }))
            }
            Some(_) => Err(bad(path, format!("umbra:{k} is not a v3d"))),
            None => Err(missing(k)),
        }
    };
    let kind = match get("camera_kind") {
        Some(AttributeValue::Text(t)) => match t.to_string().as_str() {
            "ortho" => Projection::Ortho,
            "perspective" => Projection::Perspective,
            "cube" => Projection::Cube,
            "latlong" => Projection::LatLong,
            other => return Err(bad(path, format!("unknown umbra:camera_kind '{other}'"))),
        },
        Some(_) => return Err(bad(path, "umbra:camera_kind is not text")),
        None => return Err(missing("camera_kind")),
    };
    let t_max = match get("camera_t_max") {
        Some(AttributeValue::F64(t)) => *t,
        Some(AttributeValue::F32(t)) => f64::from(*t),
        Some(_) => return Err(bad(path, "umbra:camera_t_max is not a number")),
        None => return Err(missing("camera_t_max")),
    };
    let size = header.layer_size;
    let (w, h) = (u32::try_from(size.0), u32::try_from(size.1));
    let size = match (w, h) {
        (Ok(w), Ok(h)) => (w, h),
        _ => return Err(bad(path, "the image is too large")),
    };
    Ok((
        CameraSpec {
            kind,
            width: 0,
            height: 0,
            origin: v3("camera_origin")?,
            step_x: v3("camera_step_x")?,
            step_y: v3("camera_step_y")?,
            direction: v3("camera_direction")?,
            t_max,
        },
        Some(size),
    ))
}

/// A bare camera object, its size optional.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonCamera {
    kind: Projection,
    origin: [f64; 3],
    step_x: [f64; 3],
    step_y: [f64; 3],
    direction: [f64; 3],
    t_max: f64,
    width: Option<u32>,
    height: Option<u32>,
}

/// The spec (its size 0 x 0 when the file has none) and the size from JSON: a `bake --json`
/// summary or a bare camera object.
fn from_json(path: &Path, bytes: &[u8]) -> Result<(CameraSpec, Option<(u32, u32)>)> {
    let value: serde_json::Value = serde_json::from_slice(bytes)
        .map_err(|e| bad(path, format!("neither an umbra EXR map nor JSON ({e})")))?;
    let (object, outer) = match value.get("camera") {
        Some(c) => (c.clone(), Some(&value)),
        None => (value.clone(), None),
    };
    let cam: JsonCamera = serde_json::from_value(object)
        .map_err(|e| bad(path, format!("not a camera object: {e}")))?;
    let dim = |k: &str| {
        outer
            .and_then(|o| o.get(k))
            .and_then(serde_json::Value::as_u64)
            .and_then(|v| u32::try_from(v).ok())
    };
    let size = match (cam.width.or(dim("width")), cam.height.or(dim("height"))) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        _ => return Err(bad(path, "give both width and height, or neither")),
    };
    Ok((
        CameraSpec {
            kind: cam.kind,
            width: 0,
            height: 0,
            origin: cam.origin,
            step_x: cam.step_x,
            step_y: cam.step_y,
            direction: cam.direction,
            t_max: cam.t_max,
        },
        size,
    ))
}
