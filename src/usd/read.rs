//! Reading a stage with `openusd`: volumes, lights, transforms and asset paths at a time code.

use super::{Selection, Shot};
use crate::error::{Error, Result};
use openusd::gf::Matrix4d;
use openusd::sdf::Value;
use openusd::usd::{Prim, PrimPredicate, Stage, TimeCode};
use openusd_schemas::geom::{Imageable, ImageableExt, Visibility, XformOp};
use std::path::Path;

mod field;
mod lights;
mod points;
pub use points::{points_at, points_layer};

/// `xformOpOrder`'s reset entry and the prefix of an inverted op.
const RESET_XFORM_STACK: &str = "!resetXformStack!";
const INVERT_PREFIX: &str = "!invert!";

struct Reader<'a> {
    path: &'a Path,
    stage: Stage,
    time: f64,
}

impl Reader<'_> {
    fn err(&self, reason: impl std::fmt::Display) -> Error {
        Error::Stage {
            path: self.path.to_path_buf(),
            reason: format!("at time {}: {reason}", self.time),
        }
    }

    fn at(&self, prim: &str, reason: impl std::fmt::Display) -> Error {
        self.err(format!("{prim}: {reason}"))
    }

    fn tc(&self) -> TimeCode {
        TimeCode::new(self.time)
    }

    /// Every composed prim (active, loaded, defined, concrete) with its type, in stage order.
    fn prims(&self) -> Result<Vec<(String, String)>> {
        let mut paths = Vec::new();
        self.stage
            .traverse(PrimPredicate::DEFAULT, |p| paths.push(p.clone()))
            .map_err(|e| self.err(format!("{e:#}")))?;
        let mut out = Vec::with_capacity(paths.len());
        for p in paths {
            let ty = self
                .prim(p.as_str())?
                .type_name()
                .map_err(|e| self.at(p.as_str(), format!("{e:#}")))?
                .map(|t| t.as_str().to_string())
                .unwrap_or_default();
            out.push((p.as_str().to_string(), ty));
        }
        Ok(out)
    }

    /// The composed prim handle at `path` (openusd 0.8's `Stage::prim` parses the path).
    fn prim(&self, path: &str) -> Result<Prim> {
        self.stage
            .prim(path)
            .map_err(|e| self.at(path, format!("{e:#}")))
    }

    /// `false` when USD computes the prim invisible at the time code (`ComputeVisibility`):
    /// it or an `Imageable` ancestor has `visibility = "invisible"` at that time (animated
    /// visibility is read at the time; an untyped `over` or a non-imageable prim has none).
    fn visible(&self, prim: &str) -> Result<bool> {
        let fail = |e: &dyn std::fmt::Display| self.at(prim, format!("visibility: {e:#}"));
        let Some(imageable) = Imageable::from_prim(self.prim(prim)?).map_err(|e| fail(&e))? else {
            return Ok(true);
        };
        let v = imageable
            .compute_visibility(self.tc())
            .map_err(|e| fail(&e))?;
        Ok(v != Visibility::Invisible)
    }

    /// The prim's local-to-parent matrix at the time code and whether its stack resets the
    /// parent's: `xformOpOrder` read on a prim of any type (`Xform`, `Scope`, untyped
    /// `over`s), each op evaluated by openusd-schemas' `XformOp`.
    fn local(&self, prim: &Prim) -> Result<(Matrix4d, bool)> {
        let path = prim.path().as_str().to_string();
        let order = self.uniform(prim, "xformOpOrder")?;
        let entries: Vec<String> = match order {
            None => Vec::new(),
            Some(Value::TokenVec(v)) => v.iter().map(|t| t.as_str().to_string()).collect(),
            Some(Value::StringVec(v)) => v,
            Some(other) => {
                return Err(self.at(&path, format!("xformOpOrder is {other:?}")));
            }
        };
        let mut ops = Vec::new();
        let mut resets = false;
        for entry in &entries {
            if entry == RESET_XFORM_STACK {
                resets = true;
                ops.clear();
                continue;
            }
            let (inverse, name) = match entry.strip_prefix(INVERT_PREFIX) {
                Some(n) => (true, n),
                None => (false, entry.as_str()),
            };
            let attr = prim.attribute(name);
            if attr
                .is_defined()
                .map_err(|e| self.at(&path, format!("{name}: {e:#}")))?
            {
                ops.push(XformOp::new(&attr, inverse));
            }
        }
        // Row vectors: the last op listed is the most local.
        let mut m = Matrix4d::IDENTITY;
        for op in ops.iter().rev() {
            let t = op
                .op_transform(self.tc())
                .map_err(|e| self.at(&path, format!("transform: {e:#}")))?;
            m = m * t;
        }
        Ok((m, resets))
    }

    /// The prim's local-to-world matrix at the time code (row vectors), parents composed up
    /// to the root or a `!resetXformStack!`.
    fn local_to_world(&self, prim: &str) -> Result<Matrix4d> {
        let mut m = Matrix4d::IDENTITY;
        let mut cur = Some(openusd::sdf::Path::new(prim).map_err(|e| self.at(prim, e))?);
        while let Some(p) = cur {
            if p.as_str() == "/" || p.as_str().is_empty() {
                break;
            }
            let (local, resets) = self.local(&self.prim(p.as_str())?)?;
            m = m * local;
            cur = if resets { None } else { p.parent() };
        }
        Ok(m)
    }

    /// A `uniform` attribute's value as usd-core's readers take it: at the default time, time
    /// samples ignored (`UsdCollectionAPI::ComputeMembershipQuery` and
    /// `UsdGeomXformable::GetOrderedXformOps` read `Get(UsdTimeCode::Default())`). An attribute
    /// with only time samples reads as its schema fallback, or as unauthored where the schema
    /// gives none. The uniform attributes umbra reads: `xformOpOrder` (UsdGeomXformable) and a
    /// collection's `includeRoot`, `expansionRule`, `mode` and `membershipExpression`
    /// (UsdCollectionAPI, a light's `shadowLink` and the collections it includes); every other
    /// attribute it reads is varying ([`Reader::value`]).
    fn uniform(&self, prim: &Prim, attr: &str) -> Result<Option<Value>> {
        prim.attribute(attr)
            .get_at::<Value>(None)
            .map_err(|e| self.at(prim.path().as_str(), format!("{attr}: {e:#}")))
    }

    /// A varying attribute's value at the time code (`UsdAttribute::Get(time)`): the schemas'
    /// varying attributes and umbra's own `umbra:*` ones, whatever variability a layer
    /// declares for those.
    fn value(&self, prim: &str, attr: &str) -> Result<Option<Value>> {
        self.prim(prim)?
            .attribute(attr)
            .get_at::<Value>(self.tc())
            .map_err(|e| self.at(prim, format!("{attr}: {e:#}")))
    }

    /// A numeric attribute at the time code: a finite number, as every numeric flag is
    /// (a NaN or an infinity is refused here, naming the attribute, whatever reads it).
    fn number(&self, prim: &str, attr: &str) -> Result<Option<f64>> {
        Ok(match self.value(prim, attr)? {
            None => None,
            Some(v) => {
                let x = as_number(&v)
                    .ok_or_else(|| self.at(prim, format!("{attr}: {v:?} is not a number")))?;
                if !x.is_finite() {
                    return Err(self.at(
                        prim,
                        format!("{attr} is {}: give a finite number", crate::math::short(x)),
                    ));
                }
                Some(x)
            }
        })
    }

    fn flag(&self, prim: &str, attr: &str) -> Result<Option<bool>> {
        match self.value(prim, attr)? {
            None => Ok(None),
            Some(Value::Bool(b)) => Ok(Some(b)),
            Some(v) => Err(self.at(prim, format!("{attr}: {v:?} is not a bool"))),
        }
    }

    /// A string, token or asset path attribute (the asset path as authored).
    fn text(&self, prim: &str, attr: &str) -> Result<Option<String>> {
        match self.value(prim, attr)? {
            None => Ok(None),
            Some(Value::String(s)) => Ok(Some(s)),
            Some(Value::Token(t)) => Ok(Some(t.as_str().to_string())),
            Some(Value::AssetPath(a)) => Ok(Some(a.authored_path)),
            Some(v) => Err(self.at(prim, format!("{attr}: {v:?} is not a string"))),
        }
    }

    fn up(&self) -> Result<[f64; 3]> {
        let v = self
            .stage
            .stage_metadata("upAxis")
            .map_err(|e| self.err(format!("upAxis: {e:#}")))?;
        let axis = match &v {
            None => "Y".to_string(),
            Some(Value::Token(t)) => t.as_str().to_string(),
            Some(Value::String(s)) => s.clone(),
            Some(other) => return Err(self.err(format!("upAxis is {other:?}"))),
        };
        match axis.as_str() {
            "Y" => Ok([0.0, 1.0, 0.0]),
            "Z" => Ok([0.0, 0.0, 1.0]),
            other => Err(self.err(format!("upAxis is '{other}', not Y or Z"))),
        }
    }
}

fn reason(e: Error) -> String {
    match e {
        Error::InvalidArgument { reason, .. } => reason,
        other => other.to_string(),
    }
}

fn as_number(v: &Value) -> Option<f64> {
    match v {
        Value::Float(x) => Some(f64::from(*x)),
        Value::Double(x) => Some(*x),
        Value::Half(x) => Some(f64::from(x.to_f32())),
        Value::Int(x) => Some(f64::from(*x)),
        Value::Int64(x) => Some(*x as f64),
        Value::Uint(x) => Some(f64::from(*x)),
        _ => None,
    }
}

fn as_triple(v: &Value) -> Option<[f64; 3]> {
    match v {
        Value::Vec3f(c) => Some([c.x, c.y, c.z].map(f64::from)),
        Value::Vec3d(c) => Some([c.x, c.y, c.z]),
        _ => None,
    }
}

/// Open `path` as a USD stage, turning a panic inside the USD reader on a corrupt file into
/// an error naming the file.
fn open_stage(path: &Path) -> Result<Stage> {
    let fail = |reason: String| Error::Stage {
        path: path.to_path_buf(),
        reason,
    };
    let meta = std::fs::metadata(path).map_err(|err| Error::Io {
        path: path.to_path_buf(),
        err,
    })?;
    if meta.is_dir() {
        return Err(fail("a directory, not a USD stage".into()));
    }
    let s = path
        .to_str()
        .ok_or_else(|| fail("the path is not UTF-8".into()))?
        .to_string();
    // The schema registry (UsdGeom, UsdVol, UsdLux) makes schema attributes exist where the
    // stage authors no spec (an `OpenVDBAsset`'s `filePath` given only by value clips), and
    // gives unauthored attributes their schema fallbacks, as usd-core does.
    // No guard in front of the crate reader any more: openusd 0.8 checks every count against
    // the bytes that hold it, bounds LZ4 output and nesting and refuses a value inside
    // itself (tests/library/usd_corrupt.rs re-runs 0.6's aborts on it; docs/usd.md#limits).
    let opened = std::panic::catch_unwind(|| {
        Stage::builder()
            .schema_registry(openusd_schemas::schema_registry())
            .open(&s)
    });
    match opened {
        Ok(Ok(stage)) => Ok(stage),
        Ok(Err(e)) => {
            let msg = format!("{e:#}");
            // openusd 0.8 reads time-sampled asset values in .usda (0.6 refused them, and
            // umbra hinted at .usdc here).
            Err(fail(format!("cannot open the stage: {msg}")))
        }
        Err(p) => Err(fail(format!(
            "cannot open the stage: the USD reader failed ({})",
            panic_text(&p)
        ))),
    }
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into())
}

fn with_panics<T>(path: &Path, f: impl FnOnce() -> Result<T>) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => Err(Error::Stage {
            path: path.to_path_buf(),
            reason: format!("the USD reader failed ({})", panic_text(&p)),
        }),
    }
}

/// Read the volumes and lights of the stage at `path` at `sel.time` (the stage's start time
/// code when `None`).
///
/// # Errors
/// [`Error::Io`] when the file cannot be read, [`Error::Stage`] naming the prim and the time
/// for everything the stage gets wrong (no volume, a volume without the field, a field that is
/// not an `OpenVDBAsset`, a missing asset, an unknown prim, a transform umbra cannot place).
pub fn read(path: &Path, sel: &Selection) -> Result<Shot> {
    with_panics(path, || {
        let stage = open_stage(path)?;
        let time = sel.time.unwrap_or_else(|| stage.start_time_code());
        if !time.is_finite() {
            return Err(Error::InvalidArgument {
                name: "frame".into(),
                reason: format!("{time} is not a finite time code"),
            });
        }
        let r = Reader { path, stage, time };
        let prims = r.prims()?;
        let visible = r.visible_volumes(&prims)?;
        let names: Vec<String> = if sel.volumes.is_empty() {
            if visible.is_empty() {
                return Err(r.err("no active, visible Volume prim"));
            }
            visible.clone()
        } else {
            r.named_volumes(&prims, &sel.volumes)?;
            sel.volumes.clone()
        };
        let mut shot = Shot {
            path: path.to_path_buf(),
            time,
            up: r.up()?,
            volumes: Vec::new(),
            lights: r.lights(&prims, &visible)?,
            fps: r.stage.time_codes_per_second(),
        };
        let names = match &sel.light {
            Some(l) => shot.linked(l, names)?,
            None => names,
        };
        shot.volumes = names
            .iter()
            .map(|p| r.volume(p, sel))
            .collect::<Result<Vec<_>>>()?;
        Ok(shot)
    })
}

/// The lights of the stage at `path` at `time` (no volume is read: a query toward a light, or
/// a listing, needs none).
///
/// # Errors
/// As [`read`], for what reading lights can find.
pub fn lights_at(path: &Path, time: Option<f64>) -> Result<Shot> {
    with_panics(path, || {
        let stage = open_stage(path)?;
        let time = time.unwrap_or_else(|| stage.start_time_code());
        let r = Reader { path, stage, time };
        let prims = r.prims()?;
        let visible = r.visible_volumes(&prims)?;
        let lights = r.lights(&prims, &visible)?;
        let up = r.up()?;
        Ok(Shot {
            path: path.to_path_buf(),
            time,
            up,
            volumes: Vec::new(),
            lights,
            fps: r.stage.time_codes_per_second(),
        })
    })
}

/// Copy the member `member` of the `.usdz` package `package` into a scratch file.
pub(super) fn extract(package: &Path, member: &str) -> Result<crate::output::Scratch> {
    let bad = |reason: String| Error::Stage {
        path: package.to_path_buf(),
        reason,
    };
    let file = std::fs::File::open(package).map_err(|err| Error::Io {
        path: package.to_path_buf(),
        err,
    })?;
    let mut zip = zip::ZipArchive::new(file)
        .map_err(|e| bad(format!("not a readable .usdz package: {e}")))?;
    let names: Vec<String> = zip.file_names().map(str::to_string).collect();
    let mut entry = zip.by_name(member).map_err(|_| {
        bad(format!(
            "no member '{}' in the package (it holds: {})",
            crate::text::escape(member),
            names.join(", ")
        ))
    })?;
    let hint = member.rsplit('/').next().unwrap_or(member).to_string();
    crate::output::Scratch::copy_from(&hint, &mut entry)
}

/// A `.usda` layer that hands baked maps back to the shot: over each light prim, the
/// time-sampled `asset umbra:shadowMap` (the map baked at that time code) and `matrix4d
/// umbra:worldToShadow` (its camera's `worldToNDC`, row-vector convention). Sublayer it over the
/// shot and lighting tools find each light's maps.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `usd-out`) when a prim path is not a valid USD path or the
/// layer cannot be authored.
pub fn shadow_layer(samples: &[super::ShadowSample]) -> Result<String> {
    let bad = |reason: String| Error::InvalidArgument {
        name: "usd-out".into(),
        reason,
    };
    let stage = Stage::builder()
        .in_memory("umbra_shadows.usda")
        .map_err(|e| bad(format!("{e:#}")))?;
    for s in samples {
        let t = TimeCode::new(s.time);
        stage
            .override_prim(s.light.as_str())
            .map_err(|e| bad(format!("{}: {e}", s.light)))?;
        let m = s.world_to_ndc;
        let rows = Matrix4d(std::array::from_fn(|i| m[i % 4][i / 4]));
        stage
            .create_attribute(format!("{}.umbra:shadowMap", s.light).as_str(), "asset")
            .and_then(|a| {
                a.set_at(
                    Value::AssetPath(openusd::sdf::AssetPath::new(s.map.clone())),
                    t,
                )
            })
            .map_err(|e| bad(format!("{}: {e}", s.light)))?;
        stage
            .create_attribute(
                format!("{}.umbra:worldToShadow", s.light).as_str(),
                "matrix4d",
            )
            .and_then(|a| a.set_at(Value::Matrix4d(rows), t))
            .map_err(|e| bad(format!("{}: {e}", s.light)))?;
    }
    let text = stage
        .root_layer()
        .export_to_string()
        .map_err(|e| bad(format!("{e:#}")))?;
    Ok(text)
}
