//! Farm specs for a job: the engines studios queue work on run `umbra batch JOB --task I`
//! (or `--shard I/N` for chunks) once per task, so a TD submits the job without writing the
//! spec by hand.
//!
//! - **Open Job Description** (`jobtemplate-2023-09`, AWS Deadline Cloud; `openjd check` and
//!   `openjd run` take it locally): job parameters `JobFile` (PATH, IN) and `OutputDir` (PATH,
//!   OUT) whose defaults are relative to the template's directory (the spec's path mapping
//!   moves them between hosts); one step whose task parameter spans the tasks (or the chunks);
//!   the job's thread count as a `amount.worker.vcpu` host requirement. Written as JSON, which
//!   is also valid YAML: every path and argument is a JSON string, so spaces, quotes and
//!   non-ASCII need no shell quoting (the engine passes arguments without a shell).
//! - **Slurm**: a job-array script (`#SBATCH --array=0-N`) run by a plain `sbatch`.
//!
//! The command names umbra by the absolute path given (the CLI passes its own), as `--plan`
//! does: a farm worker's `PATH` is not the TD's. Nothing from the environment is embedded.

use super::Job;
use std::path::{Component, Path, PathBuf};

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
            count: job.tasks.len().div_ceil(size),
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

/// The job's Open Job Description template. `exe`: the umbra to run; `dir`: the directory the
/// template will be written to (its parameters' defaults are relative to it).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] (name `output`) when `dir` is below the job file's
/// directory: the spec's path defaults may not climb out of the template's directory.
pub fn openjd(job: &Job, exe: &Path, dir: &Path, chunks: Option<Chunks>) -> crate::Result<String> {
    let job_dir = job.path.parent().unwrap_or(Path::new("."));
    if relative(&job.path, dir).starts_with("..") {
        return Err(crate::Error::InvalidArgument {
            name: "output".into(),
            reason: format!(
                "an Open Job Description template's path defaults are relative to its \
                 directory and may not climb out of it: write the template in {} or a \
                 directory above it",
                job_dir.display()
            ),
        });
    }
    let name = job
        .path
        .file_stem()
        .map_or_else(|| "job".into(), |s| s.to_string_lossy().into_owned());
    let last = job.tasks.len().saturating_sub(1);
    let (param, range, selector) = match chunks {
        Some(c) => (
            "Shard",
            format!("1-{}", c.count),
            vec![
                "--shard".to_string(),
                format!("{{{{Task.Param.Shard}}}}/{}", c.count),
            ],
        ),
        None => (
            "Task",
            format!("0-{last}"),
            vec!["--task".to_string(), "{{Task.Param.Task}}".to_string()],
        ),
    };
    let mut args = vec![
        "batch".to_string(),
        "{{Param.JobFile}}".to_string(),
        "--quiet".to_string(),
    ];
    args.extend(selector);
    let mut step = serde_json::json!({
        "name": "bake",
        "description": "One umbra batch task per farm task (its maps, log line and exit code).",
        "parameterSpace": {
            "taskParameterDefinitions": [
                { "name": param, "type": "INT", "range": range }
            ]
        },
        "script": {
            "actions": {
                "onRun": { "command": exe.display().to_string(), "args": args }
            }
        }
    });
    if job.options.threads > 0 {
        step["hostRequirements"] = serde_json::json!({
            "amounts": [{ "name": "amount.worker.vcpu", "min": job.options.threads }]
        });
    }
    let template = serde_json::json!({
        "specificationVersion": "jobtemplate-2023-09",
        "name": format!("umbra batch {name}"),
        "description": format!(
            "Shadow maps of {} ({} tasks), written by umbra {}.",
            job.path.display(),
            job.tasks.len(),
            env!("CARGO_PKG_VERSION")
        ),
        "parameterDefinitions": [
            {
                "name": "JobFile",
                "type": "PATH",
                "objectType": "FILE",
                "dataFlow": "IN",
                "default": relative(&job.path, dir).display().to_string(),
                "description": "The umbra job file (its output pattern names the maps, relative to it)."
            },
            {
                "name": "OutputDir",
                "type": "PATH",
                "objectType": "DIRECTORY",
                "dataFlow": "OUT",
                "default": relative(job_dir, dir).display().to_string(),
                "description": "The job file's directory, where its output pattern resolves."
            }
        ],
        "steps": [step]
    });
    Ok(serde_json::to_string_pretty(&template).unwrap_or_default() + "\n")
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

/// The job's Slurm array script: `sbatch job.sbatch` runs every task (or chunk) as one element
/// of the array.
#[must_use]
pub fn slurm(job: &Job, exe: &Path, chunks: Option<Chunks>) -> String {
    let name = job
        .path
        .file_stem()
        .map_or_else(|| "job".into(), |s| s.to_string_lossy().into_owned());
    let (range, select) = match chunks {
        Some(c) => (
            format!("1-{}", c.count),
            format!("--shard \"${{SLURM_ARRAY_TASK_ID}}/{}\"", c.count),
        ),
        None => (
            format!("0-{}", job.tasks.len().saturating_sub(1)),
            "--task \"$SLURM_ARRAY_TASK_ID\"".to_string(),
        ),
    };
    let cpus = if job.options.threads > 0 {
        format!("#SBATCH --cpus-per-task={}\n", job.options.threads)
    } else {
        String::new()
    };
    let safe_name: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!(
        "#!/bin/bash\n\
         # Shadow maps of {job} ({n} tasks): one array element per task, written by umbra {v}.\n\
         # Submit: sbatch THIS_FILE. Where the job stands: umbra batch JOB.toml --status\n\
         #SBATCH --job-name=umbra_{safe_name}\n\
         #SBATCH --array={range}\n\
         {cpus}\
         set -euo pipefail\n\
         exec {exe_q} batch {job_q} --quiet {select}\n",
        // The comment lines hold the path escaped (a newline in it would end the comment).
        job = crate::text::escape(&job.path.display().to_string()),
        n = job.tasks.len(),
        v = env!("CARGO_PKG_VERSION"),
        exe_q = shell_quote(&exe.display().to_string()),
        job_q = shell_quote(&job.path.display().to_string()),
    )
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
