//! Reading a job file: its TOML, with a bad key's line and column even when serde reports it at
//! its table's header (a key of a flattened set of options), and an `[[inputs]]` entry's read
//! keys over `[bake]`'s.

use super::checks::{err, key_at, EntryRead};
use super::schema::{InputSpec, JobFile};
use super::BatchError;
use crate::request::BakeOptions;
use std::path::Path;

/// The job file's TOML: a syntax or type error as one line, "line L, column C: key: message"
/// (the parser's own text quotes the source).
pub(super) fn read_toml(path: &Path, text: &str) -> Result<JobFile, BatchError> {
    toml::from_str(text).map_err(|e| {
        let message = match e.span() {
            Some(r) if r.start <= text.len() => {
                // A key of a flattened set (the read and estimator options in `[bake]`) is
                // reported at its table's header: find the key itself.
                let at = culprit_key(text, r.start).unwrap_or(r.start);
                let before = &text[..at];
                let line = before.matches('\n').count() + 1;
                let column = at - before.rfind('\n').map_or(0, |i| i + 1) + 1;
                let key = key_at(text, at)
                    .map(|k| format!("{k}: "))
                    .unwrap_or_default();
                format!("line {line}, column {column}: {key}{}", e.message().trim())
            }
            _ => e.message().trim().to_string(),
        };
        BatchError::Syntax {
            path: path.to_path_buf(),
            message: message.replace('\n', " "),
        }
    })
}

/// Where the key that fails stands, when a parse error points at the header of the table
/// holding it (`[bake]`, `[[positions]]`): serde reports the keys of a flattened set there.
/// Each key of that table is tried alone (every key has a default); the first whose value
/// fails alone is the culprit, and its line's start is returned. `None`: not at a header, or
/// no single key fails.
fn culprit_key(text: &str, at: usize) -> Option<usize> {
    let header = text[at..].lines().next()?.trim();
    if !header.starts_with('[') {
        return None;
    }
    let name = header
        .trim_matches(|c| c == '[' || c == ']')
        .trim()
        .to_string();
    let array = header.starts_with("[[");
    let nth = if array {
        text[..at].lines().filter(|l| l.trim() == header).count()
    } else {
        0
    };
    let root: toml::Table = toml::from_str(text).ok()?;
    let table = match root.get(&name)? {
        toml::Value::Table(t) => t.clone(),
        toml::Value::Array(a) => a.get(nth)?.as_table()?.clone(),
        _ => return None,
    };
    let bad = table.iter().find(|(k, v)| {
        let mut one = root.clone();
        let alone = toml::Table::from_iter([((*k).clone(), (*v).clone())]);
        match one.get_mut(&name) {
            Some(toml::Value::Array(a)) => a[nth] = toml::Value::Table(alone),
            Some(slot) => *slot = toml::Value::Table(alone),
            None => return false,
        }
        toml::Value::Table(one).try_into::<JobFile>().is_err()
    })?;
    // The key's line within the table's section.
    let section_end = text[at + header.len()..]
        .find("\n[")
        .map_or(text.len(), |i| at + header.len() + i);
    let mut pos = at;
    for line in text[at..section_end].split_inclusive('\n') {
        let key = line
            .split('=')
            .next()
            .unwrap_or("")
            .trim()
            .trim_matches('"');
        if key == bad.0 {
            return Some(pos + (line.len() - line.trim_start().len()));
        }
        pos += line.len();
    }
    None
}

/// How the tasks of `[[inputs]]` entry `inp` read their files: its read keys over `[bake]`'s
/// (`b`) and the job's `grid`, each checked as `[bake]`'s are (errors name `inputs[i].key`).
pub(super) fn entry_read(
    path: &Path,
    key: &dyn Fn(&str) -> String,
    inp: &InputSpec,
    grid: &str,
    b: &BakeOptions,
) -> Result<(EntryRead, crate::input::SourceOptions), BatchError> {
    for (k, why) in [
        (
            "frame",
            "give this entry's frames with frames = [first, last]",
        ),
        ("light", "the lights of a job are its [[lights]]"),
    ] {
        if inp.read.contains_key(k) {
            return Err(err(path, &key(k), why));
        }
    }
    let named = |e: crate::error::Error| match e {
        crate::error::Error::InvalidArgument { name, reason } => {
            err(path, &key(&name.replace('-', "_")), reason)
        }
        other => err(path, &key("file"), other),
    };
    crate::request::read_keys(&inp.read).map_err(named)?;
    let mut base = b.source.clone();
    base.grid = grid.to_string();
    let o = crate::request::overlaid(&base, &inp.read).map_err(named)?;
    if o.grid.is_empty() {
        return Err(err(path, &key("grid"), "must not be empty"));
    }
    if !(o.density_scale.is_finite() && o.density_scale >= 0.0) {
        return Err(err(
            path,
            &key("density_scale"),
            format!("{} is not a finite scale >= 0", o.density_scale),
        ));
    }
    if let Some(x) = &o.xform {
        crate::xform::Xform::from_row_major(x).map_err(|e| {
            let reason = match e {
                crate::error::Error::InvalidArgument { reason, .. } => reason,
                other => other.to_string(),
            };
            err(path, &key("xform"), reason)
        })?;
    }
    let read = EntryRead {
        grid: o.grid.clone(),
        density_scale: o.density_scale,
        levelset: o.levelset,
        xform: o.xform.clone(),
    };
    Ok((read, o))
}
