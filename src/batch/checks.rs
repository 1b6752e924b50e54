//! Checks shared by the job file's parsers (`schema`, `positions`): error values naming their
//! key, frame ranges, the key under a byte of the text, how an `[[inputs]]` entry reads its
//! files (`EntryRead`), `bake.usd_out`, and lexical path normalisation.

use super::patterns::MAX_FRAMES;
use super::{BatchError, Task};
use crate::request::LevelSet;
use std::path::{Path, PathBuf};

/// How the tasks of one `[[inputs]]` entry read their files: the entry's own values, else
/// the job's.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct EntryRead {
    pub(super) grid: String,
    pub(super) density_scale: f64,
    pub(super) levelset: Option<LevelSet>,
    pub(super) xform: Option<Vec<f64>>,
}

/// A job error naming `key` of the job file `path`.
pub(super) fn err(path: &Path, key: &str, reason: impl std::fmt::Display) -> BatchError {
    BatchError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        reason: reason.to_string(),
    }
}

/// The frames `[first, last]` by `step` (default 1) of a sequence, bounded by [`MAX_FRAMES`];
/// `key` names an entry's keys (`inputs[0].frames`) in errors.
pub(super) fn frame_list(
    path: &Path,
    key: &dyn Fn(&str) -> String,
    [first, last]: [i64; 2],
    step: Option<i64>,
) -> Result<Vec<i64>, BatchError> {
    let step = step.unwrap_or(1);
    if step < 1 {
        return Err(err(path, &key("step"), "must be at least 1"));
    }
    if last < first {
        return Err(err(path, &key("frames"), "last frame before the first"));
    }
    let count = (i128::from(last) - i128::from(first)) / i128::from(step) + 1;
    if count > i128::from(MAX_FRAMES) {
        return Err(err(
            path,
            &key("frames"),
            format!("{count} frames; at most {MAX_FRAMES} per sequence"),
        ));
    }
    let mut out = Vec::new();
    let mut f = first;
    loop {
        out.push(f);
        match f.checked_add(step) {
            Some(next) if next <= last => f = next,
            _ => break,
        }
    }
    Ok(out)
}

/// The key (`bake.levelset`) whose value starts the line holding byte `at` of a job file: the
/// text before `=` on that line, after the last `[table]` header above it. `None` for a line
/// that is not `key = value`.
pub(super) fn key_at(text: &str, at: usize) -> Option<String> {
    let start = text[..at].rfind('\n').map_or(0, |i| i + 1);
    let line = text[start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    let bare = |k: &str| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
    };
    if !bare(key) {
        return None;
    }
    let table = text[..start]
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .map(|l| l.trim_matches(|c| c == '[' || c == ']').trim().to_string());
    Some(match table {
        Some(t) if !t.is_empty() => format!("{t}.{key}"),
        _ => key.to_string(),
    })
}

/// `bake.usd_out` names a `.usda` layer, for maps, of a job with stage lights.
pub(super) fn check_usd_out(
    path: &Path,
    u: &Path,
    volume: bool,
    tasks: &[Task],
) -> Result<(), BatchError> {
    let reason = if !crate::input::is_usda_layer(u) {
        format!("{} is not a .usda layer", u.display())
    } else if volume {
        "puts maps on their stage lights; transmittance volumes (.vdb) have no camera".into()
    } else if tasks.iter().all(|t| t.usd_light.is_none()) {
        "puts maps on their stage lights, and this job bakes from none (give [[inputs]] usd = \
         with its lights)"
            .into()
    } else {
        return crate::output::check_target(u, true).map_err(|e| err(path, "bake.usd_out", e));
    };
    Err(err(path, "bake.usd_out", reason))
}

/// `p` with `.` and `name/..` components removed lexically (no file system access), so two
/// spellings of one output path compare equal.
pub(super) fn normalise(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
}
