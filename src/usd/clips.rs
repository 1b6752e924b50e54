//! Value clips (USD's `clips` metadata, `UsdClipsAPI`): the checks umbra makes before it
//! trusts what a clip set answers, and the one place openusd 0.8 differs from usd-core.
//!
//! A clip set on a prim or an ancestor maps stage time `t` to a clip layer and a time in it:
//! `active = [(t_i, k_i)]` makes clip `k_i` answer from stage time `t_i` on, and `times =
//! [(t_j, c_j)]` maps stage time to clip time piecewise linearly between its points (two points
//! at one stage time are a jump). openusd resolves the values; umbra checks first that the
//! set is well formed, so a broken cache is one error naming the clip instead of "no value at
//! this time":
//!
//! - every clip asset path resolves to a layer that exists (anchored to the layers that author
//!   the prim, strongest first, as USD anchors the `clips` dictionary to its layer);
//! - `times` and `active` are ordered by stage time (`times` may repeat a stage time, for a
//!   jump; `active` may not), finite, and `active` names clips the set has.

use super::{resolve_asset, Asset};
use openusd::gf::Vec2d;
use openusd::usd::{ClipsAPI, Prim, Stage};

/// Checks every clip set authored on `prim` and its ancestors; `Err` is the reason, naming
/// the prim, the set and the field.
pub(super) fn check(stage: &Stage, prim: &str) -> Result<(), String> {
    let mut cur = openusd::sdf::Path::new(prim).ok();
    while let Some(p) = cur {
        if p.as_str() == "/" || p.as_str().is_empty() {
            break;
        }
        if let Ok(handle) = stage.prim(p.as_str()) {
            check_prim(&handle, p.as_str())?;
        }
        cur = p.parent();
    }
    Ok(())
}

fn check_prim(prim: &Prim, path: &str) -> Result<(), String> {
    let sets = prim
        .clip_set_names()
        .map_err(|e| format!("{path}: clips: {e:#}"))?;
    if sets.is_empty() {
        return Ok(());
    }
    let layers: Vec<String> = prim
        .prim_stack()
        .map_err(|e| format!("{path}: clips: {e:#}"))?
        .into_iter()
        .map(|s| s.layer)
        .collect();
    let api = ClipsAPI::from_prim_unchecked(prim.clone());
    for set in &sets {
        let field = |name: &str| format!("{path}: clips \"{set}\" {name}");
        let assets = api
            .clip_asset_paths(set)
            .map_err(|e| format!("{}: {e:#}", field("assetPaths")))?;
        for a in &assets {
            if let Some(missing) = missing_layer(&a.authored_path, &layers) {
                return Err(format!(
                    "{}: clip @{}@ resolves to {missing}, which does not exist",
                    field("assetPaths"),
                    a.authored_path
                ));
            }
        }
        let times = api
            .clip_times(set)
            .map_err(|e| format!("{}: {e:#}", field("times")))?;
        ordered(&times, true).map_err(|r| format!("{} (clipTimes): {r}", field("times")))?;
        let active = api
            .clip_active(set)
            .map_err(|e| format!("{}: {e:#}", field("active")))?;
        ordered(&active, false).map_err(|r| format!("{} (clipActive): {r}", field("active")))?;
        for v in &active {
            let k = v.y;
            if k.fract() != 0.0 || k < 0.0 || k >= assets.len() as f64 {
                return Err(format!(
                    "{} (clipActive): clip index {k} at stage time {} is not one of the set's \
                     {} clips",
                    field("active"),
                    v.x,
                    assets.len()
                ));
            }
        }
    }
    Ok(())
}

/// `Err` when the stage times (`x`) are not finite or go backwards (or repeat, unless
/// `repeats`, where a repeated stage time is a jump).
fn ordered(points: &[Vec2d], repeats: bool) -> Result<(), String> {
    if let Some(p) = points.iter().find(|p| !p.x.is_finite() || !p.y.is_finite()) {
        return Err(format!("({}, {}) is not finite", p.x, p.y));
    }
    for w in points.windows(2) {
        let back = if repeats {
            w[1].x < w[0].x
        } else {
            w[1].x <= w[0].x
        };
        if back {
            return Err(format!(
                "out of order: stage time {} follows {}",
                w[1].x, w[0].x
            ));
        }
    }
    Ok(())
}

/// `None` when `authored` resolves to an existing file through one of `layers` (or is a
/// member of a package, which the reader checks when it opens it); else where it resolves
/// through the strongest layer.
fn missing_layer(authored: &str, layers: &[String]) -> Option<String> {
    let mut first = None;
    for layer in layers {
        match resolve_asset(authored, layer) {
            Asset::File(f) if f.is_file() => return None,
            Asset::File(f) => {
                first.get_or_insert_with(|| f.display().to_string());
            }
            _ => return None,
        }
    }
    first
}
