//! A stage's lights: the point and distant lights it traces, their shadow links and the light
//! collections that choose which volumes cast shadows.

use super::super::emitter::Attributes;
use super::super::{Emitter, Link, Rule, Shadow, StageLight};
use super::Reader;
use crate::error::{Error, Result};
use openusd::sdf::Value;

impl Reader<'_> {
    /// The stage's active, visible `Volume` prims, in stage order.
    pub(super) fn visible_volumes(&self, prims: &[(String, String)]) -> Result<Vec<String>> {
        let mut v = Vec::new();
        for (p, ty) in prims {
            if ty == "Volume" && self.visible(p)? {
                v.push(p.clone());
            }
        }
        Ok(v)
    }

    pub(super) fn lights(
        &self,
        prims: &[(String, String)],
        volumes: &[String],
    ) -> Result<Vec<StageLight>> {
        let mut out = Vec::new();
        for (p, ty) in prims {
            let is_light = ty.ends_with("Light") || ty.starts_with("DomeLight");
            if !is_light || !self.visible(p)? {
                continue;
            }
            let read = Attributes {
                number: &|attr| self.number(p, attr),
                flag: &|attr| self.flag(p, attr),
                text: &|attr| self.text(p, attr),
            };
            // A light that cannot be traced (shaped, textured, a bad size) fails only when it
            // is chosen, as one whose shadow controls cannot be read.
            let (emitter, refused) = match Emitter::of_light(
                ty,
                || Ok(self.local_to_world(p)?.0),
                &read,
                |reason| self.at(p, reason),
            ) {
                Ok(e) => (e, None),
                Err(e) => (None, Some(unreadable(e))),
            };
            // A light whose controls cannot be read fails only when it is chosen.
            let shadow = self.shadow(p, volumes).unwrap_or_else(|e| Shadow {
                unreadable: Some(unreadable(e)),
                ..Shadow::default()
            });
            out.push(StageLight {
                prim: p.clone(),
                type_name: ty.clone(),
                emitter,
                refused,
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
    /// ComputeMembershipQuery` builds it ([`super::super::link`]): `root_fallback` is `includeRoot`
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
        let owner = self.prim(prim)?;
        // Every attribute of a collection is uniform: read at the default time, as
        // ComputeMembershipQuery does (time samples ignored).
        let uniform = |k: &str| self.uniform(&owner, &key(k));
        let token = |k: &str| -> Result<Option<String>> {
            Ok(match uniform(k)? {
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
        let include_root = match uniform("includeRoot")? {
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
            let authored = uniform("membershipExpression")?;
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
    pub(super) fn named_volumes(&self, prims: &[(String, String)], names: &[String]) -> Result<()> {
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
}

/// An error's reason, as a light refused when chosen words it.
fn unreadable(e: Error) -> String {
    match e {
        Error::Stage { reason, .. } => reason,
        other => other.to_string(),
    }
}
