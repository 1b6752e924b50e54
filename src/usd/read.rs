//! Reading a stage with `openusd`: volumes, lights, transforms and asset paths at a time code.

use super::{
    resolve_asset, Asset, Emitter, Link, Rule, Selection, Shadow, Shot, StageLight, StageVolume,
};
use crate::error::{Error, Result};
use crate::xform::Xform;
use openusd::gf::Matrix4d;
use openusd::sdf::Value;
use openusd::usd::{Prim, PrimPredicate, Stage, TimeCode};
use openusd_schemas::geom::{Imageable, ImageableExt, Visibility, XformOp};
use std::path::Path;

mod points;
pub use points::{points_at, points_layer};

/// `xformOpOrder`'s reset entry and the prefix of an inverted op.
const RESET_XFORM_STACK: &str = "!resetXformStack!";
const INVERT_PREFIX: &str = "!invert!";

/// Light types traced as points at their origin.
const POINT_LIGHTS: [&str; 4] = ["SphereLight", "DiskLight", "RectLight", "CylinderLight"];

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
        let order = prim
            .attribute("xformOpOrder")
            .get_at::<Value>(None)
            .map_err(|e| self.at(&path, format!("xformOpOrder: {e:#}")))?;
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

    fn value(&self, prim: &str, attr: &str) -> Result<Option<Value>> {
        self.prim(prim)?
            .attribute(attr)
            .get_at::<Value>(self.tc())
            .map_err(|e| self.at(prim, format!("{attr}: {e:#}")))
    }

    fn number(&self, prim: &str, attr: &str) -> Result<Option<f64>> {
        Ok(match self.value(prim, attr)? {
            None => None,
            Some(v) => Some(
                as_number(&v)
                    .ok_or_else(|| self.at(prim, format!("{attr}: {v:?} is not a number")))?,
            ),
        })
    }

    fn volume(&self, prim: &str, sel: &Selection) -> Result<StageVolume> {
        let rel = format!("field:{}", sel.field);
        let targets = self
            .prim(prim)?
            .relationship(rel.as_str())
            .targets()
            .map_err(|e| self.at(prim, format!("{rel}: {e:#}")))?;
        let field_prim = match targets.as_slice() {
            [one] => one.as_str().to_string(),
            [] => {
                let names = self.field_names(prim);
                return Err(self.at(
                    prim,
                    format!(
                        "no field '{}' (its fields: {}); choose one with field",
                        crate::text::escape(&sel.field),
                        if names.is_empty() {
                            "none".to_string()
                        } else {
                            names.join(", ")
                        }
                    ),
                ));
            }
            _ => {
                return Err(self.at(
                    prim,
                    format!("{rel} targets {} prims; umbra reads one", targets.len()),
                ))
            }
        };
        let ty = self
            .prim(field_prim.as_str())?
            .type_name()
            .map_err(|e| self.at(&field_prim, format!("{e:#}")))?
            .map(|t| t.as_str().to_string());
        match ty.as_deref() {
            Some("OpenVDBAsset") => {}
            Some("Field3DAsset") => {
                return Err(self.at(
                    &field_prim,
                    "a Field3DAsset: umbra reads OpenVDB fields (OpenVDBAsset)",
                ))
            }
            other => {
                return Err(self.at(
                    &field_prim,
                    format!(
                        "{rel} of {prim} targets a {}, not an OpenVDBAsset",
                        other.unwrap_or("prim that does not exist")
                    ),
                ))
            }
        }
        super::clips::check(&self.stage, prim).map_err(|r| self.err(r))?;
        super::clips::check(&self.stage, &field_prim).map_err(|r| self.err(r))?;
        let (authored, layer) = self.file_path(&field_prim)?;
        let asset = resolve_asset(&authored, &layer);
        if let Asset::File(f) = &asset {
            if !f.is_file() {
                return Err(self.at(
                    &field_prim,
                    format!(
                        "filePath @{authored}@ resolves to {}, which does not exist",
                        f.display()
                    ),
                ));
            }
        }
        let name = match self.value(&field_prim, "fieldName")? {
            Some(Value::Token(t)) => t.as_str().to_string(),
            Some(Value::String(s)) => s,
            _ => sel.field.clone(),
        };
        let index = match self.value(&field_prim, "fieldIndex")? {
            Some(v) => as_number(&v)
                .filter(|i| i.fract() == 0.0 && *i >= 0.0)
                .ok_or_else(|| self.at(&field_prim, format!("fieldIndex {v:?}")))?,
            None => 0.0,
        };
        let grid = if index == 0.0 {
            name
        } else {
            format!("{name}[{index}]")
        };
        let m = self.local_to_world(prim)?;
        let xform = Xform::new(std::array::from_fn(|r| {
            std::array::from_fn(|c| m.0[4 * c + r])
        }))
        .map_err(|e| self.at(prim, format!("its world transform: {}", reason(e))))?;
        let density_scale = self.number(prim, "umbra:densityScale")?.unwrap_or(1.0);
        let (sigma_t, rgb) = match self.value(prim, "umbra:sigmaT")? {
            None => (None, false),
            Some(v) => match (as_number(&v), as_triple(&v)) {
                (Some(s), _) => (Some([s; 3]), false),
                (None, Some(c)) => (Some(c), true),
                _ => {
                    return Err(self.at(
                        prim,
                        format!("umbra:sigmaT is {v:?}: give a number or a color3f"),
                    ))
                }
            },
        };
        let solid = match self.value(prim, "umbra:kind")? {
            None => false,
            Some(Value::Token(t)) if t.as_str() == "fog" => false,
            Some(Value::Token(t)) if t.as_str() == "solid" => true,
            Some(Value::String(s)) if s == "fog" => false,
            Some(Value::String(s)) if s == "solid" => true,
            Some(v) => {
                return Err(self.at(
                    prim,
                    format!("umbra:kind is {v:?}, not \"fog\" or \"solid\""),
                ))
            }
        };
        Ok(StageVolume {
            prim: prim.to_string(),
            field_prim,
            authored,
            asset,
            grid,
            xform,
            density_scale,
            sigma_t,
            rgb,
            solid,
        })
    }

    /// The field prim's `filePath` at the time code (as authored) and the layer that answered
    /// it, which anchors a relative path: a layer of the stage, or the value clip that
    /// supplied it.
    fn file_path(&self, field_prim: &str) -> Result<(String, String)> {
        let attr = self.prim(field_prim)?.attribute("filePath");
        let read = |attr: &openusd::usd::Attribute| {
            attr.get_at::<Value>(self.tc())
                .map_err(|e| self.at(field_prim, format!("filePath: {e:#}")))
        };
        let mut value = read(&attr)?;
        if value.is_none() && self.declare_for_clips(field_prim, &attr, "asset")? {
            value = read(&attr)?;
        }
        let authored = match value {
            Some(Value::AssetPath(a)) => a.authored_path,
            Some(Value::String(s)) => s,
            Some(other) => {
                return Err(self.at(
                    field_prim,
                    format!("filePath is {other:?}, not an asset path"),
                ))
            }
            None => return Err(self.at(field_prim, "no filePath at this time")),
        };
        if authored.is_empty() {
            return Err(self.at(field_prim, "filePath is empty at this time"));
        }
        let info = attr
            .resolve_info_at(self.tc())
            .map_err(|e| self.at(field_prim, format!("filePath: {e:#}")))?;
        let layer = match info.spec_site() {
            Some(site) => site.layer.clone(),
            None => attr
                .property_stack()
                .map_err(|e| self.at(field_prim, format!("filePath: {e:#}")))?
                .into_iter()
                .next()
                .map(|site| site.layer)
                .unwrap_or_else(|| self.path.display().to_string()),
        };
        Ok((authored, layer))
    }

    /// openusd 0.8 answers a schema attribute that no layer of the stage declares with its
    /// fallback, never consulting value clips (usd-core consults them: an `OpenVDBAsset`
    /// whose `filePath` comes only from clips reads there). Where the schema declares the
    /// attribute and nothing authors a spec for it, this declares it, without a value, in
    /// the stage's in-memory root layer (never saved), so clips answer; `true` when it did.
    fn declare_for_clips(
        &self,
        prim: &str,
        attr: &openusd::usd::Attribute,
        type_name: &str,
    ) -> Result<bool> {
        let fail = |e: &dyn std::fmt::Display| self.at(prim, format!("{}: {e:#}", attr.name()));
        if !attr.is_defined().map_err(|e| fail(&e))?
            || !attr.property_stack().map_err(|e| fail(&e))?.is_empty()
        {
            return Ok(false);
        }
        self.stage
            .create_attribute(attr.path().clone(), type_name)
            .map_err(|e| fail(&e))?;
        Ok(true)
    }

    fn field_names(&self, prim: &str) -> Vec<String> {
        let Ok(p) = self.stage.prim(prim) else {
            return Vec::new();
        };
        p.relationships()
            .unwrap_or_default()
            .iter()
            .filter_map(|r| {
                r.path()
                    .as_str()
                    .rsplit_once(".field:")
                    .map(|(_, n)| n.to_string())
            })
            .collect()
    }

    /// The stage's active, visible `Volume` prims, in stage order.
    fn visible_volumes(&self, prims: &[(String, String)]) -> Result<Vec<String>> {
        let mut v = Vec::new();
        for (p, ty) in prims {
            if ty == "Volume" && self.visible(p)? {
                v.push(p.clone());
            }
        }
        Ok(v)
    }

    fn lights(&self, prims: &[(String, String)], volumes: &[String]) -> Result<Vec<StageLight>> {
        let mut out = Vec::new();
        for (p, ty) in prims {
            let is_light = ty.ends_with("Light") || ty.starts_with("DomeLight");
            if !is_light || !self.visible(p)? {
                continue;
            }
            let emitter = if ty == "DistantLight" {
                let m = self.local_to_world(p)?;
                let d = [-m.0[8], -m.0[9], -m.0[10]];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if !(n.is_finite() && n > 0.0) {
                    return Err(self.at(p, "its world -Z axis is degenerate"));
                }
                Some(Emitter::Directional {
                    dir: d.map(|c| c / n),
                })
            } else if POINT_LIGHTS.contains(&ty.as_str()) {
                let m = self.local_to_world(p)?;
                let pos = [m.0[12], m.0[13], m.0[14]];
                if !pos.iter().all(|c| c.is_finite()) {
                    return Err(self.at(p, "its world position is not finite"));
                }
                Some(Emitter::Point { pos })
            } else {
                None
            };
            // A light whose controls cannot be read fails only when it is chosen.
            let shadow = self.shadow(p, volumes).unwrap_or_else(|e| Shadow {
                unreadable: Some(match e {
                    Error::Stage { reason, .. } => reason,
                    other => other.to_string(),
                }),
                ..Shadow::default()
            });
            out.push(StageLight {
                prim: p.clone(),
                type_name: ty.clone(),
                emitter,
                shadow,
            });
        }
        Ok(out)
    }

    /// A light's shadow controls: `inputs:shadow:enable` at the time code and the membership
    /// of its `collection:shadowLink`, applied to the stage's `volumes`.
    fn shadow(&self, light: &str, volumes: &[String]) -> Result<Shadow> {
        let attr = "inputs:shadow:enable";
        let enabled = match self.value(light, attr)? {
            None => true,
            Some(Value::Bool(b)) => b,
            Some(v) => {
                return Err(self.at(light, format!("{attr} is {v:?}, not a bool")));
            }
        };
        let mut seen = std::collections::BTreeSet::from([format!("{light}.collection:shadowLink")]);
        let link = self.collection(light, "shadowLink", true, &mut seen)?;
        let (linked, unlinked) = volumes.iter().cloned().partition(|v| link.includes(v));
        Ok(Shadow {
            enabled,
            link,
            linked,
            unlinked,
            unreadable: None,
        })
    }

    /// The membership of the collection `name` on `prim`, as `UsdCollectionAPI::
    /// ComputeMembershipQuery` builds it ([`super::link`]): `root_fallback` is `includeRoot`
    /// when unauthored (`true` for a light's link collections); `seen` holds the collections
    /// being expanded (an include cycle is skipped, as USD does).
    fn collection(
        &self,
        prim: &str,
        name: &str,
        root_fallback: bool,
        seen: &mut std::collections::BTreeSet<String>,
    ) -> Result<Link> {
        let key = |k: &str| format!("collection:{name}:{k}");
        let token = |k: &str| -> Result<Option<String>> {
            Ok(match self.value(prim, &key(k))? {
                None => None,
                Some(Value::Token(t)) => Some(t.as_str().to_string()),
                Some(Value::String(s)) => Some(s),
                Some(v) => return Err(self.at(prim, format!("{} is {v:?}", key(k)))),
            })
        };
        let rule = match token("expansionRule")? {
            None => Rule::ExpandPrims,
            Some(t) => Rule::from_token(&t).ok_or_else(|| {
                self.at(
                    prim,
                    format!(
                        "{} is '{}', not explicitOnly, expandPrims or expandPrimsAndProperties",
                        key("expansionRule"),
                        crate::text::escape(&t)
                    ),
                )
            })?,
        };
        let include_root = match self.value(prim, &key("includeRoot"))? {
            None => root_fallback,
            Some(Value::Bool(b)) => b,
            Some(v) => return Err(self.at(prim, format!("{} is {v:?}", key("includeRoot")))),
        };
        let targets = |k: &str| -> Result<Vec<String>> {
            let rel = key(k);
            Ok(self
                .prim(prim)?
                .relationship(rel.as_str())
                .targets()
                .map_err(|e| self.at(prim, format!("{rel}: {e:#}")))?
                .iter()
                .map(|p| p.as_str().to_string())
                .collect())
        };
        let (includes, excludes) = (targets("includes")?, targets("excludes")?);
        let mode = token("mode")?;
        let expression = match mode.as_deref() {
            Some("expression") => true,
            Some("relationship") => false,
            _ => includes.is_empty() && excludes.is_empty() && !include_root,
        };
        if expression {
            // Expression mode: only membershipExpression counts; an empty one holds nothing.
            let authored = self.value(prim, &key("membershipExpression"))?;
            let empty = match &authored {
                None => true,
                Some(Value::String(s)) => s.trim().is_empty(),
                Some(Value::Token(t)) => t.as_str().trim().is_empty(),
                Some(_) => false,
            };
            if !empty {
                return Err(self.at(
                    prim,
                    format!(
                        "{} is a path expression: umbra reads collections by includes, \
                         excludes and includeRoot",
                        key("membershipExpression")
                    ),
                ));
            }
            return Ok(Link::default());
        }
        let mut link = Link::default();
        if include_root && rule != Rule::ExplicitOnly {
            link.rules.insert("/".into(), rule);
        }
        for inc in includes {
            match inc.split_once(".collection:") {
                Some((owner, other)) => {
                    // A cycle, or a collection on a prim that does not exist, adds nothing
                    // (USD warns and goes on).
                    if seen.contains(&inc) || self.stage.prim(owner).is_err() {
                        continue;
                    }
                    seen.insert(inc.clone());
                    let fallback = self.is_light_link(owner, other);
                    let nested = self.collection(owner, other, fallback, seen);
                    seen.remove(&inc);
                    link.rules.extend(nested?.rules);
                }
                None => {
                    link.rules.insert(inc, rule);
                }
            }
        }
        for exc in excludes {
            link.rules.insert(exc, Rule::Exclude);
        }
        Ok(link)
    }

    /// Whether `name` on `prim` is a light's `lightLink` / `shadowLink` (or a light filter's
    /// `filterLink`), whose `includeRoot` falls back to `true` in UsdLux.
    fn is_light_link(&self, prim: &str, name: &str) -> bool {
        let ty = self
            .stage
            .prim(prim)
            .ok()
            .and_then(|p| p.type_name().ok().flatten())
            .map(|t| t.as_str().to_string())
            .unwrap_or_default();
        match name {
            "lightLink" | "shadowLink" => ty.ends_with("Light"),
            "filterLink" => ty.ends_with("LightFilter"),
            _ => false,
        }
    }

    /// Check that every prim of `names` is a composed `Volume`.
    fn named_volumes(&self, prims: &[(String, String)], names: &[String]) -> Result<()> {
        for n in names {
            match prims.iter().find(|(p, _)| p == n) {
                Some((_, ty)) if ty == "Volume" => {}
                Some((_, ty)) => {
                    return Err(self.at(n, format!("a {ty}, not a Volume")));
                }
                None => {
                    let vols: Vec<&str> = prims
                        .iter()
                        .filter(|(_, t)| t == "Volume")
                        .map(|(p, _)| p.as_str())
                        .collect();
                    return Err(self.at(
                        n,
                        format!(
                            "no such active prim (the stage's volumes: {})",
                            if vols.is_empty() {
                                "none".to_string()
                            } else {
                                vols.join(", ")
                            }
                        ),
                    ));
                }
            }
        }
        Ok(())
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
