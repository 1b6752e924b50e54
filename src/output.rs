//! Writing files so that a reader never sees a partial one: every output is written to a
//! temporary file in its own directory (`.NAME.umbra-PID-N.tmp`), flushed, synced and renamed
//! over the target only when complete. Several outputs of one command are staged first and
//! renamed together ([`commit_all`]), so they appear together or not at all.

use crate::error::{Error, Result};
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

fn output_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// A complete temporary file waiting to be renamed over its target. Dropping it without
/// [`Staged::commit`] removes the temporary file.
#[derive(Debug)]
pub struct Staged {
    tmp: Option<PathBuf>,
    target: PathBuf,
    overwrite: bool,
}

impl Drop for Staged {
    fn drop(&mut self) {
        if let Some(p) = self.tmp.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

impl Staged {
    /// The file this will become.
    #[must_use]
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Rename the temporary file over the target (re-checking that it may be written).
    ///
    /// # Errors
    /// [`Error::Output`] when the target may no longer be written or the rename fails; the
    /// temporary file is removed.
    pub fn commit(mut self) -> Result<()> {
        check_target(&self.target, self.overwrite)?;
        let Some(tmp) = self.tmp.as_ref() else {
            return Err(output_err(&self.target, "already committed"));
        };
        std::fs::rename(tmp, &self.target)
            .map_err(|e| output_err(&self.target, format!("renaming into place: {e}")))?;
        self.tmp = None;
        Ok(())
    }
}

/// Write `path`'s future content to a temporary file beside it: `write` fills it, then it is
/// flushed and synced. Nothing is visible at `path` until [`Staged::commit`].
///
/// # Errors
/// [`Error::Output`] if `path` exists and `overwrite` is false, is a directory, its directory
/// does not exist, or the temporary file cannot be created or written (`write`'s message is the
/// reason). The temporary file is removed on any error or panic.
pub fn stage(
    path: &Path,
    overwrite: bool,
    write: impl FnOnce(&mut BufWriter<std::fs::File>) -> std::result::Result<(), String>,
) -> Result<Staged> {
    check_target(path, overwrite)?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| output_err(path, "not a file name"))?;
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".{name}.umbra-{}-{n}.tmp", std::process::id()));
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .map_err(|e| {
            output_err(
                path,
                format!("cannot create a file in {}: {e}", dir.display()),
            )
        })?;
    let staged = Staged {
        tmp: Some(tmp),
        target: path.to_path_buf(),
        overwrite,
    };
    let mut w = BufWriter::new(file);
    write(&mut w).map_err(|e| output_err(path, e))?;
    let file = w
        .into_inner()
        .map_err(|e| output_err(path, format!("writing: {}", e.error())))?;
    file.sync_all()
        .map_err(|e| output_err(path, format!("writing: {e}")))?;
    Ok(staged)
}

/// Write `path` atomically: [`stage`] then [`Staged::commit`].
///
/// # Errors
/// As [`stage`] and [`Staged::commit`]; `path` is untouched on error.
pub fn write_atomic(
    path: &Path,
    overwrite: bool,
    write: impl FnOnce(&mut BufWriter<std::fs::File>) -> std::result::Result<(), String>,
) -> Result<()> {
    stage(path, overwrite, write)?.commit()
}

/// Commit every staged file, after checking that all targets may still be written (so a
/// late problem with one leaves none of them written).
///
/// # Errors
/// The first target that may not be written (nothing renamed), or a failed rename.
pub fn commit_all(staged: Vec<Staged>) -> Result<()> {
    for s in &staged {
        check_target(&s.target, s.overwrite)?;
    }
    for s in staged {
        s.commit()?;
    }
    Ok(())
}

/// Check that `path` may be written: not a directory, not an existing file unless `overwrite`,
/// in an existing directory. [`stage`] and [`Staged::commit`] check this; callers check it
/// before a long computation.
///
/// # Errors
/// [`Error::Output`] naming the problem.
pub fn check_target(path: &Path, overwrite: bool) -> Result<()> {
    if let Ok(m) = std::fs::symlink_metadata(path) {
        if m.is_dir() {
            return Err(output_err(path, "is a directory"));
        }
        if !overwrite {
            return Err(output_err(
                path,
                "already exists (use --force to overwrite)",
            ));
        }
    }
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !d.is_dir() {
            return Err(output_err(path, format!("no directory {}", d.display())));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn staged_files_appear_together_or_not_at_all() {
        let dir = std::env::temp_dir().join(format!("umbra-output-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        let (a, b) = (dir.join("a.txt"), dir.join("b.txt"));
        let sa = stage(&a, false, |_| Ok(())).expect("stage a");
        let fail = stage(&b, false, |_| Err("encoder failed".into()));
        assert!(fail.is_err());
        drop(sa);
        let left: Vec<_> = std::fs::read_dir(&dir).expect("read").collect();
        assert!(left.is_empty(), "{left:?}");
        let sa = stage(&a, false, |_| Ok(())).expect("stage a");
        let sb = stage(&b, false, |_| Ok(())).expect("stage b");
        commit_all(vec![sa, sb]).expect("commit");
        assert!(a.exists() && b.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
