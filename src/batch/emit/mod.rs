//! Farm specs for a job: the engines studios queue work on run `umbra batch JOB --task I`
//! (or `--shard I/N` for chunks) once per task, so a TD submits the job without writing the
//! spec by hand.
//!
//! - **Open Job Description** (`jobtemplate-2023-09`, AWS Deadline Cloud; `openjd check` and
//!   `openjd run` take it locally): job parameters `Umbra` (STRING, the binary's absolute
//!   path), `JobFile` (PATH, IN) and `OutputDir` (PATH, OUT) whose defaults are relative to the
//!   template's directory (the spec's path mapping moves them between hosts), so no path is
//!   ever part of a format string the engine expands (`{{...}}` in a path runs as written);
//!   one step whose task parameter spans the tasks (or the chunks), run with
//!   `--progress openjd` so the session reads each task's `openjd_progress: N` lines;
//!   the job's thread count as a `amount.worker.vcpu` host requirement. Written as JSON, which
//!   is also valid YAML: every path and argument is a JSON string, so spaces, quotes and
//!   non-ASCII need no shell quoting (the engine passes arguments without a shell).
//! - **OpenCue**: the job spec (`cjsl-1.15` XML) `opencue-pyoutline` writes for one layer whose
//!   frames are the job's tasks, in the engine's own chunks (`--task #FRAME_START#-#FRAME_END#`).
//!   cuebot replaces its `#TOKEN#` placeholders anywhere in a layer's command, so the paths
//!   travel in the layer's environment (`UMBRA`, `UMBRA_JOB`), which it leaves alone, and the
//!   command names them as `"$UMBRA"` and `"$UMBRA_JOB"`.
//! - **Slurm**: a job-array script (`#SBATCH --array=0-N`) run by a plain `sbatch`.
//!
//! The command names umbra by the absolute path given (the CLI passes its own), as `--plan`
//! does: a farm worker's `PATH` is not the TD's. Nothing from the environment is embedded.

mod opencue;
mod openjd;
mod slurm;

pub use opencue::{opencue, CueIdentity};
pub use openjd::openjd;
pub use slurm::slurm;

use super::Job;
use std::path::{Component, Path, PathBuf};

/// The job's name: its file's stem (`job` when it has none).
fn job_name(job: &Job) -> String {
    job.path
        .file_stem()
        .map_or_else(|| "job".into(), |s| s.to_string_lossy().into_owned())
}

/// `s` as a name engines take anywhere (ASCII letters, digits, `_` and `-`; others become `_`).
fn token(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// How tasks are grouped into farm tasks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Chunks {
    /// Farm tasks (each a shard `i/count` of the job's tasks).
    pub count: usize,
}

impl Chunks {
    /// Chunks of at most `size` tasks of `job` (`None` or 1: one farm task per task).
    #[must_use]
    pub fn of(job: &Job, size: Option<usize>) -> Option<Self> {
        let size = size.filter(|&s| s > 1)?;
        Some(Self {
            count: job.task_count().div_ceil(size),
        })
    }
}

/// `to` relative to the directory `from` (both made absolute lexically), with `..` where it
/// climbs; `.` for the directory itself.
#[must_use]
pub fn relative(to: &Path, from: &Path) -> PathBuf {
    let abs = |p: &Path| {
        let a = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        let mut out = PathBuf::new();
        for c in a.components() {
            match c {
                Component::CurDir => {}
                Component::ParentDir => {
                    out.pop();
                }
                c => out.push(c),
            }
        }
        out
    };
    let (to, from) = (abs(to), abs(from));
    let (a, b): (Vec<_>, Vec<_>) = (to.components().collect(), from.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..b.len() {
        out.push("..");
    }
    for c in &a[common..] {
        out.push(c);
    }
    if out.as_os_str().is_empty() {
        PathBuf::from(".")
    } else {
        out
    }
}

/// `s` quoted for a POSIX shell (single quotes; `'` as `'\''`).
#[must_use]
pub fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+=:,@".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_climb_and_descend() {
        let r = |a: &str, b: &str| relative(Path::new(a), Path::new(b));
        assert_eq!(r("/s/a/job.toml", "/s/a"), PathBuf::from("job.toml"));
        assert_eq!(
            r("/s/a/job.toml", "/s/b/farm"),
            PathBuf::from("../../a/job.toml")
        );
        assert_eq!(r("/s/a", "/s/a"), PathBuf::from("."));
        assert_eq!(
            r("/s/a/x/../job.toml", "/s/a/./"),
            PathBuf::from("job.toml")
        );
    }

    #[test]
    fn shell_quoting_survives_quotes_and_spaces() {
        assert_eq!(shell_quote("/a/b.toml"), "/a/b.toml");
        assert_eq!(shell_quote("it's a job"), "'it'\\''s a job'");
        assert_eq!(shell_quote(""), "''");
    }
}
