//! A stage's volume prims: the field a volume's relationship targets, its OpenVDB asset and
//! grid, and the volume's transform, extinction and kind.

use super::super::{resolve_asset, Asset, Selection, StageVolume};
use super::{as_number, as_triple, reason, Reader};
use crate::error::Result;
use crate::xform::Xform;
use openusd::sdf::Value;

impl Reader<'_> {
    /// The volume prim `prim` as the selection reads it: the OpenVDB field its `field:<name>`
    /// relationship targets (asset and grid), its world transform, density scale, `sigma_t`
    /// and kind.
    pub(super) fn volume(&self, prim: &str, sel: &Selection) -> Result<StageVolume> {
        let rel = format!("field:{}", sel.field);
        let field_prim = self.field_prim(prim, sel, &rel)?;
        self.check_field_type(prim, &field_prim, &rel)?;
        super::super::clips::check(&self.stage, prim).map_err(|r| self.err(r))?;
        super::super::clips::check(&self.stage, &field_prim).map_err(|r| self.err(r))?;
        let (authored, asset) = self.field_asset(&field_prim)?;
        let grid = self.grid_name(&field_prim, sel)?;
        let xform = self.world_xform(prim)?;
        let density_scale = self.number(prim, "umbra:densityScale")?.unwrap_or(1.0);
        let (sigma_t, rgb) = self.sigma_t(prim)?;
        let solid = self.solid(prim)?;
        let velocity = match &sel.velocity {
            Some(name) => Some(self.velocity(prim, sel, name)?),
            None => None,
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
            velocity,
        })
    }

    /// The velocity field of volume `prim`: the asset and grid its `field:<name>`
    /// relationship targets, checked as the density's field is.
    fn velocity(&self, prim: &str, sel: &Selection, name: &str) -> Result<(Asset, String)> {
        let sel = Selection {
            field: name.to_string(),
            ..sel.clone()
        };
        let rel = format!("field:{name}");
        let field_prim = self.field_prim(prim, &sel, &rel)?;
        self.check_field_type(prim, &field_prim, &rel)?;
        super::super::clips::check(&self.stage, &field_prim).map_err(|r| self.err(r))?;
        let (_, asset) = self.field_asset(&field_prim)?;
        Ok((asset, self.grid_name(&field_prim, &sel)?))
    }

    /// The one prim the volume's relationship `rel` (`field:<name>` of the selection) targets.
    fn field_prim(&self, prim: &str, sel: &Selection, rel: &str) -> Result<String> {
        let targets = self
            .prim(prim)?
            .relationship(rel)
            .targets()
            .map_err(|e| self.at(prim, format!("{rel}: {e:#}")))?;
        match targets.as_slice() {
            [one] => Ok(one.as_str().to_string()),
            [] => {
                let names = self.field_names(prim);
                Err(self.at(
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
                ))
            }
            _ => Err(self.at(
                prim,
                format!("{rel} targets {} prims; umbra reads one", targets.len()),
            )),
        }
    }

    /// That the field prim (the target of `prim`'s `rel`) is an `OpenVDBAsset`.
    fn check_field_type(&self, prim: &str, field_prim: &str, rel: &str) -> Result<()> {
        let ty = self
            .prim(field_prim)?
            .type_name()
            .map_err(|e| self.at(field_prim, format!("{e:#}")))?
            .map(|t| t.as_str().to_string());
        match ty.as_deref() {
            Some("OpenVDBAsset") => Ok(()),
            Some("Field3DAsset") => Err(self.at(
                field_prim,
                "a Field3DAsset: umbra reads OpenVDB fields (OpenVDBAsset)",
            )),
            other => Err(self.at(
                field_prim,
                format!(
                    "{rel} of {prim} targets a {}, not an OpenVDBAsset",
                    other.unwrap_or("prim that does not exist")
                ),
            )),
        }
    }

    /// The field prim's `filePath` as authored and the asset it resolves to (a file that
    /// must exist).
    fn field_asset(&self, field_prim: &str) -> Result<(String, Asset)> {
        let (authored, layer) = self.file_path(field_prim)?;
        let asset = resolve_asset(&authored, &layer);
        if let Asset::File(f) = &asset {
            if !f.is_file() {
                return Err(self.at(
                    field_prim,
                    format!(
                        "filePath @{authored}@ resolves to {}, which does not exist",
                        f.display()
                    ),
                ));
            }
        }
        Ok((authored, asset))
    }

    /// The grid the field prim names: its `fieldName` (else the selection's field), with
    /// `[fieldIndex]` when that is not 0.
    fn grid_name(&self, field_prim: &str, sel: &Selection) -> Result<String> {
        let name = match self.value(field_prim, "fieldName")? {
            Some(Value::Token(t)) => t.as_str().to_string(),
            Some(Value::String(s)) => s,
            _ => sel.field.clone(),
        };
        let index = match self.value(field_prim, "fieldIndex")? {
            Some(v) => as_number(&v)
                .filter(|i| i.fract() == 0.0 && *i >= 0.0)
                .ok_or_else(|| self.at(field_prim, format!("fieldIndex {v:?}")))?,
            None => 0.0,
        };
        Ok(if index == 0.0 {
            name
        } else {
            format!("{name}[{index}]")
        })
    }

    /// The prim's world-from-local transform as an [`Xform`] (USD's row vectors transposed).
    fn world_xform(&self, prim: &str) -> Result<Xform> {
        let m = self.local_to_world(prim)?;
        Xform::new(std::array::from_fn(|r| {
            std::array::from_fn(|c| m.0[4 * c + r])
        }))
        .map_err(|e| self.at(prim, format!("its world transform: {}", reason(e))))
    }

    /// `umbra:sigmaT`: a number (grey) or a `color3f` (`rgb`), or none.
    fn sigma_t(&self, prim: &str) -> Result<(Option<[f64; 3]>, bool)> {
        Ok(match self.value(prim, "umbra:sigmaT")? {
            None => (None, false),
            Some(v) => match (as_number(&v), as_triple(&v)) {
                (Some(s), _) if s.is_finite() => (Some([s; 3]), false),
                (None, Some(c)) if c.iter().all(|x| x.is_finite()) => (Some(c), true),
                (Some(_), _) | (None, Some(_)) => {
                    return Err(self.at(prim, format!("umbra:sigmaT is {v:?}: give finite numbers")))
                }
                _ => {
                    return Err(self.at(
                        prim,
                        format!("umbra:sigmaT is {v:?}: give a number or a color3f"),
                    ))
                }
            },
        })
    }

    /// `umbra:kind`: true for `solid`, false for `fog` (the default).
    fn solid(&self, prim: &str) -> Result<bool> {
        Ok(match self.value(prim, "umbra:kind")? {
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
}
