//! Slurm job-array scripts.

use super::{job_name, shell_quote, token, Chunks};
use crate::batch::Job;
use std::path::Path;

/// The job's Slurm array script: `sbatch job.sbatch` runs every task (or chunk) as one element
/// of the array.
#[must_use]
pub fn slurm(job: &Job, exe: &Path, chunks: Option<Chunks>) -> String {
    let (range, select) = match chunks {
        Some(c) => (
            format!("1-{}", c.count),
            format!("--shard \"${{SLURM_ARRAY_TASK_ID}}/{}\"", c.count),
        ),
        None => (
            format!("0-{}", job.task_count().saturating_sub(1)),
            "--task \"$SLURM_ARRAY_TASK_ID\"".to_string(),
        ),
    };
    let cpus = if job.options.threads > 0 {
        format!("#SBATCH --cpus-per-task={}\n", job.options.threads)
    } else {
        String::new()
    };
    let safe_name = token(&job_name(job));
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
        n = job.task_count(),
        v = env!("CARGO_PKG_VERSION"),
        exe_q = shell_quote(&exe.display().to_string()),
        job_q = shell_quote(&job.path.display().to_string()),
    )
}
