//! Open Job Description (`jobtemplate-2023-09`: AWS Deadline Cloud) templates.

use super::{job_name, relative, token, Chunks};
use crate::batch::Job;
use std::path::Path;

/// The job's Open Job Description template. `exe`: the umbra to run; `dir`: the directory the
/// template will be written to (its parameters' defaults are relative to it).
///
/// Every path goes in as a job parameter's default (`Umbra`, a `STRING`: OpenJD requires
/// `PATH` defaults to be relative; `JobFile` and `OutputDir`, `PATH`s), never into a format
/// string: OpenJD expands `{{...}}` in a step's `command` and `args` once, and substitutes a
/// parameter's value without expanding it again, so a path holding `{{Task.Param.Task}}` runs
/// as written. The job's `name` (a format string too) takes the job file's stem with every
/// character but ASCII letters, digits, `_` and `-` as `_`.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] (name `output`) when `dir` is below the job file's
/// directory: the spec's path defaults may not climb out of the template's directory.
pub fn openjd(
    job: &Job,
    exe: &Path,
    dir: &Path,
    chunks: Option<Chunks>,
) -> crate::error::Result<String> {
    let job_dir = job.path.parent().unwrap_or(Path::new("."));
    if relative(&job.path, dir).starts_with("..") {
        return Err(crate::error::Error::InvalidArgument {
            name: "output".into(),
            reason: format!(
                "an Open Job Description template's path defaults are relative to its \
                 directory and may not climb out of it: write the template in {} or a \
                 directory above it",
                job_dir.display()
            ),
        });
    }
    let name = job_name(job);
    let last = job.task_count().saturating_sub(1);
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
        // The session's progress lines (`openjd_progress: N`), whatever the environment says.
        "--progress".to_string(),
        "openjd".to_string(),
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
                "onRun": { "command": "{{Param.Umbra}}", "args": args }
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
        "name": format!("umbra batch {}", token(&name)),
        "description": format!(
            "Shadow maps of {} ({} tasks), written by umbra {}.",
            job.path.display(),
            job.task_count(),
            env!("CARGO_PKG_VERSION")
        ),
        "parameterDefinitions": [
            {
                "name": "Umbra",
                "type": "STRING",
                "default": exe.display().to_string(),
                "description": "The umbra binary the workers run (an absolute path)."
            },
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
