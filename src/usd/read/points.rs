//! Points of a shot and the per-point answers back into it: a `UsdGeom.Points` prim's
//! `points` or a `PointInstancer`'s `positions`, placed in the world at a time code, and the
//! layer that time-samples a transmittance primvar on the prim.

use super::super::StagePoints;
use super::{open_stage, with_panics, Reader};
use crate::error::{Error, Result};
use openusd::gf::Matrix4d;
use openusd::sdf::Value;
use openusd::usd::{Stage, TimeCode};
use std::path::Path;

/// The world positions of the points of `prim` at time code `time` (the stage's start time
/// code when `None`): `points` of a `Points` prim or `positions` of a `PointInstancer`,
/// each a row vector times the prim's local-to-world matrix, `p' = [p 1] M` (USD's
/// convention), in f64 from the authored f32.
///
/// # Errors
/// [`Error::Stage`] naming the stage, the time and the prim: a prim that does not exist (the
/// error lists the stage's `Points` and `PointInstancer` prims), a prim of another type, or an
/// attribute that is not a point array.
pub fn points_at(path: &Path, prim: &str, time: Option<f64>) -> Result<StagePoints> {
    with_panics(path, || {
        let stage = open_stage(path)?;
        let time = time.unwrap_or_else(|| stage.start_time_code());
        let r = Reader { path, stage, time };
        let prims = r.prims()?;
        let candidates: Vec<String> = prims
            .iter()
            .filter(|(_, t)| t == "Points" || t == "PointInstancer")
            .map(|(p, t)| format!("{p} ({t})"))
            .collect();
        let Some((_, ty)) = prims.iter().find(|(p, _)| p == prim) else {
            return Err(r.at(
                prim,
                format!(
                    "no such prim for --positions (the stage's point prims: {})",
                    if candidates.is_empty() {
                        "none".to_string()
                    } else {
                        candidates.join(", ")
                    }
                ),
            ));
        };
        let attr = match ty.as_str() {
            "Points" => "points",
            "PointInstancer" => "positions",
            other => {
                return Err(r.at(
                    prim,
                    format!(
                        "a {other}, not a Points or PointInstancer prim (--positions reads a \
                         Points prim's points or a PointInstancer's positions)"
                    ),
                ))
            }
        };
        let local: Vec<[f64; 3]> = match r.value(prim, attr)? {
            None => Vec::new(),
            Some(Value::Vec3fVec(v)) => v
                .iter()
                .map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)])
                .collect(),
            Some(Value::Vec3dVec(v)) => v.iter().map(|p| [p.x, p.y, p.z]).collect(),
            Some(other) => {
                return Err(r.at(
                    prim,
                    format!("{attr} is {}, not a point array", kind(&other)),
                ))
            }
        };
        // Every number read from a stage is finite, as every numeric flag is: a NaN point is
        // refused as authored, before a transform spreads it over the other components.
        if let Some((i, p)) = local
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
        {
            return Err(r.at(
                prim,
                format!(
                    "{attr}[{i}] is {}: give finite coordinates",
                    crate::math::short3(*p)
                ),
            ));
        }
        let m = r.local_to_world(prim)?;
        let world = local.iter().map(|p| transform(&m, *p)).collect();
        Ok(StagePoints {
            prim: prim.to_string(),
            type_name: ty.clone(),
            time,
            positions: world,
        })
    })
}

fn kind(v: &Value) -> String {
    format!("{v:?}").chars().take_while(|c| *c != '(').collect()
}

/// `[p 1] M` for a row-vector matrix (its last column is (0, 0, 0, 1) for an affine one; a
/// projective one divides by w, as USD's `Transform` does).
fn transform(m: &Matrix4d, p: [f64; 3]) -> [f64; 3] {
    let e = |r: usize, c: usize| m.0[4 * r + c];
    let v: [f64; 4] =
        std::array::from_fn(|c| p[0] * e(0, c) + p[1] * e(1, c) + p[2] * e(2, c) + e(3, c));
    if v[3] == 1.0 || v[3] == 0.0 {
        [v[0], v[1], v[2]]
    } else {
        [v[0] / v[3], v[1] / v[3], v[2] / v[3]]
    }
}

/// A `.usda` layer that, over `prim`, time-samples `float[]
/// primvars:umbra:transmittance:<light_name>` (interpolation `vertex`) with one array per
/// frame: `samples` are `(time code, values)`. Sublayered over the shot, each point carries the
/// fraction of the light that reaches it. With `errors` (toward a light with extent), `float[]
/// primvars:umbra:transmittance_std_err:<light_name>` beside it holds each answer's error bar,
/// time-sampled the same way.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `usd-out`) when `prim` is not a valid prim path or the
/// layer cannot be authored.
pub fn points_layer(
    prim: &str,
    light_name: &str,
    samples: &[(f64, Vec<f32>)],
    errors: Option<&[(f64, Vec<f32>)]>,
) -> Result<String> {
    let bad = |reason: String| Error::InvalidArgument {
        name: "usd-out".into(),
        reason,
    };
    let stage = Stage::builder()
        .in_memory("umbra_points.usda")
        .map_err(|e| bad(format!("{e:#}")))?;
    stage
        .override_prim(prim)
        .map_err(|e| bad(format!("{prim}: {e}")))?;
    let primvars = [
        ("transmittance", Some(samples)),
        ("transmittance_std_err", errors),
    ];
    for (what, arrays) in primvars {
        let Some(arrays) = arrays else { continue };
        let name = format!("{prim}.primvars:umbra:{what}:{light_name}");
        let mut attr = stage
            .create_attribute(name.as_str(), "float[]")
            .map_err(|e| bad(format!("{name}: {e}")))?;
        attr = attr
            .set_metadata("interpolation", Value::Token("vertex".into()))
            .map_err(|e| bad(format!("{name}: {e}")))?;
        for (t, values) in arrays {
            attr = attr
                .set_at(Value::FloatVec(values.clone()), TimeCode::new(*t))
                .map_err(|e| bad(format!("{name}: {e}")))?;
        }
    }
    let text = stage
        .root_layer()
        .export_to_string()
        .map_err(|e| bad(format!("{e:#}")))?;
    Ok(text)
}
