//! Writing files so that a reader never sees a partial one: every output is written to a
//! temporary file in its own directory (`.NAME.umbra-PID-N.tmp`), flushed, synced and renamed
//! over the target only when complete. Several outputs of one command are staged first and
//! renamed together ([`commit_all`]), so they appear together or not at all.
//!
//! **Interruption.** Every temporary file is registered while it exists. A signal handler calls
//! [`remove_temporaries`]: it waits for a commit in progress to finish (renames happen under the
//! same lock, so a group of outputs is never half renamed), deletes every registered temporary
//! file and refuses any later stage or commit; the caller then exits. It reports what is on
//! disk ([`Interrupted`]): the temporaries removed and every output this process committed
//! before the signal (a signal at the very end of a command finds them all in place).

use crate::error::{Error, Result};
use std::collections::BTreeSet;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// Temporary files that exist now, the outputs committed so far, and whether output has been
/// shut down.
struct Live {
    temps: BTreeSet<PathBuf>,
    committed: Vec<PathBuf>,
    closed: bool,
}

static LIVE: Mutex<Live> = Mutex::new(Live {
    temps: BTreeSet::new(),
    committed: Vec::new(),
    closed: false,
});

/// What [`remove_temporaries`] found: how many temporary files it removed, and the outputs
/// this process had committed (complete, in place) before it ran, in commit order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Interrupted {
    /// Temporary files removed.
    pub removed: usize,
    /// Outputs renamed into place before output was shut down.
    pub committed: Vec<PathBuf>,
}

impl Interrupted {
    /// One line for a user: what an interrupted command leaves on disk, naming at most
    /// `show` committed outputs (`"no output was written"`, or `"2 outputs were complete and
    /// stay: a.exr, a.png"`).
    #[must_use]
    pub fn describe(&self, show: usize) -> String {
        let n = self.committed.len();
        if n == 0 {
            return "no output was written, no partial output left".into();
        }
        let mut names: Vec<String> = self
            .committed
            .iter()
            .take(show)
            .map(|p| crate::text::escape(&p.display().to_string()).into_owned())
            .collect();
        if n > show {
            names.push(format!("and {} more", n - show));
        }
        format!(
            "{n} output{} complete before the interrupt and stay{}: {}; no partial output left",
            if n == 1 { " was" } else { "s were" },
            if n == 1 { "s" } else { "" },
            names.join(", ")
        )
    }
}

fn live() -> MutexGuard<'static, Live> {
    // A panic while holding the lock cannot leave the set inconsistent (single operations).
    LIVE.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Delete every temporary file of this process and refuse all later writes; returns how many
/// files were removed and which outputs were committed before. For signal handlers: call it,
/// report it, then exit. A commit in progress finishes first.
pub fn remove_temporaries() -> Interrupted {
    let mut l = live();
    l.closed = true;
    let removed = l.temps.len();
    for p in std::mem::take(&mut l.temps) {
        let _ = std::fs::remove_file(p);
    }
    Interrupted {
        removed,
        committed: l.committed.clone(),
    }
}

fn closed_err(path: &Path) -> Error {
    output_err(path, "interrupted: output was shut down")
}

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
            let mut l = live();
            let _ = std::fs::remove_file(&p);
            l.temps.remove(&p);
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
    pub fn commit(self) -> Result<()> {
        commit_all(vec![self])
    }

    /// The rename, under the lock of the live set.
    fn commit_locked(&mut self, l: &mut Live) -> Result<()> {
        if l.closed {
            return Err(closed_err(&self.target));
        }
        let Some(tmp) = self.tmp.take() else {
            return Err(output_err(&self.target, "already committed"));
        };
        let renamed = std::fs::rename(&tmp, &self.target);
        if renamed.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        l.temps.remove(&tmp);
        if renamed.is_ok() {
            l.committed.push(self.target.clone());
        }
        renamed.map_err(|e| output_err(&self.target, format!("renaming into place: {e}")))
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
    remove_stale(&dir, &name);
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".{name}.umbra-{}-{n}.tmp", std::process::id()));
    let file = {
        let mut l = live();
        if l.closed {
            return Err(closed_err(path));
        }
        let f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| {
                output_err(
                    path,
                    format!("cannot create a file in {}: {e}", dir.display()),
                )
            })?;
        l.temps.insert(tmp.clone());
        f
    };
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

/// Remove temporary files `.NAME.umbra-PID-N.tmp` for this target left by a process that no
/// longer runs (a SIGKILL cannot be handled): Linux only (`/proc/PID`); elsewhere nothing is
/// removed.
fn remove_stale(dir: &Path, name: &str) {
    let prefix = format!(".{name}.umbra-");
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let file = e.file_name();
        let Some(f) = file.to_str() else { continue };
        let Some(rest) = f.strip_prefix(&prefix).and_then(|r| r.strip_suffix(".tmp")) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_file(e.path());
        }
    }
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
pub fn commit_all(mut staged: Vec<Staged>) -> Result<()> {
    for s in &staged {
        check_target(&s.target, s.overwrite)?;
    }
    let mut l = live();
    for s in &mut staged {
        s.commit_locked(&mut l)?;
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
    if path.as_os_str() == "-" {
        return Err(output_err(
            path,
            "writing to standard output is not supported for this file; give a file name",
        ));
    }
    if let Ok(m) = std::fs::metadata(path) {
        if m.is_dir() {
            return Err(output_err(path, "is a directory"));
        }
        if !m.is_file() {
            return Err(output_err(
                path,
                "is not a regular file (a device, pipe or socket); umbra only replaces files",
            ));
        }
        if !overwrite {
            return Err(Error::Exists {
                path: path.to_path_buf(),
            });
        }
    }
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d,
        None => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(output_err(path, format!("no directory {}", dir.display())));
    }
    if std::fs::metadata(dir).is_ok_and(|m| m.permissions().readonly()) {
        return Err(output_err(
            path,
            format!("directory {} is not writable", dir.display()),
        ));
    }
    Ok(())
}

/// Whether two paths name the same file (compared after resolving the directory, so `a.exr`,
/// `./a.exr` and an absolute spelling match).
#[must_use]
pub fn same_file(a: &Path, b: &Path) -> bool {
    let canon = |p: &Path| {
        let dir = match p.parent().filter(|d| !d.as_os_str().is_empty()) {
            Some(d) => d.to_path_buf(),
            None => PathBuf::from("."),
        };
        std::fs::canonicalize(&dir)
            .ok()
            .map(|d| d.join(p.file_name().unwrap_or_default()))
    };
    a == b || matches!((canon(a), canon(b)), (Some(x), Some(y)) if x == y)
}

/// Check, before a long computation, that `path` can be created: [`check_target`] plus a probe
/// file created and removed in its directory (what catches read-only mounts, `/sys`, missing
/// permissions for other users).
///
/// # Errors
/// [`Error::Output`] naming the problem.
pub fn check_writable(path: &Path, overwrite: bool) -> Result<()> {
    check_target(path, overwrite)?;
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d.to_path_buf(),
        None => PathBuf::from("."),
    };
    static PROBE: AtomicU64 = AtomicU64::new(0);
    let n = PROBE.fetch_add(1, Ordering::Relaxed);
    let probe = dir.join(format!(".umbra-probe-{}-{n}.tmp", std::process::id()));
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(f) => {
            drop(f);
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(output_err(
            path,
            format!("cannot create files in {}: {e}", dir.display()),
        )),
    }
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

/// A private copy of some bytes in the system's temporary directory, for a reader that needs a
/// file (a VDB packaged inside a `.usdz`): registered like a staged output, so a signal
/// removes it, and removed when dropped.
#[derive(Debug)]
pub struct Scratch {
    path: PathBuf,
}

impl Scratch {
    /// Copy everything `from` reads into a new scratch file; `hint` (a file name) ends its
    /// name so messages about it stay readable.
    ///
    /// # Errors
    /// [`Error::Output`] naming the scratch file if it cannot be created or written, or
    /// output was shut down.
    pub fn copy_from(hint: &str, from: &mut dyn std::io::Read) -> Result<Self> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let safe: String = hint
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '.' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let path = std::env::temp_dir().join(format!("umbra-{}-{n}-{safe}", std::process::id()));
        let file = {
            let mut l = live();
            if l.closed {
                return Err(closed_err(&path));
            }
            let f = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
                .map_err(|e| output_err(&path, format!("cannot create a scratch file: {e}")))?;
            l.temps.insert(path.clone());
            f
        };
        let scratch = Self { path };
        let mut w = BufWriter::new(file);
        std::io::copy(from, &mut w)
            .and_then(|_| std::io::Write::flush(&mut w))
            .map_err(|e| output_err(&scratch.path, format!("writing: {e}")))?;
        Ok(scratch)
    }

    /// Where the copy is.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let mut l = live();
        let _ = std::fs::remove_file(&self.path);
        l.temps.remove(&self.path);
    }
}
