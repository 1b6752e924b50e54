//! Where a job stands (`umbra batch JOB --status`): every task done, failed or not yet run,
//! from the outputs on disk and the runs' logs.
//!
//! A task toward a stage light without shadows is **skipped** ([`Job::shadowless`]: it bakes
//! nothing). Any other task is **done** when its output exists and is up to date
//! ([`Job::up_to_date`]: not older
//! than any file it reads), whichever run, shard or machine baked it; else **failed** when a log
//! records it failing (the last such record's error); else **missing**. Logs are JSON lines;
//! a line a killed run left half-written is ignored.

use super::{Job, Task};
use serde::Serialize;
use std::path::PathBuf;

/// One task in a [`Status`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskState {
    /// Task index.
    pub task: usize,
    /// Input file.
    pub input: PathBuf,
    /// Light name.
    pub light: String,
    /// Output file.
    pub output: PathBuf,
    /// The failure's message (failed tasks), or why a skipped task bakes nothing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// Every task of a job, by where it stands.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Status {
    /// Tasks whose output is on disk and up to date.
    pub done: Vec<TaskState>,
    /// Tasks a log records failing, without an up-to-date output.
    pub failed: Vec<TaskState>,
    /// Tasks not yet run (or whose output went stale).
    pub missing: Vec<TaskState>,
    /// Tasks that bake nothing: their stage light casts no shadows (`error` says why).
    pub skipped: Vec<TaskState>,
}

impl Status {
    /// Whether every task is done (or skipped: it bakes nothing).
    #[must_use]
    pub fn complete(&self) -> bool {
        self.failed.is_empty() && self.missing.is_empty()
    }
}

/// The last failure each task index has in `logs` (files that do not exist are skipped).
fn failures(logs: &[PathBuf]) -> std::collections::BTreeMap<usize, String> {
    let mut out = std::collections::BTreeMap::new();
    for log in logs {
        let Ok(text) = std::fs::read_to_string(log) else {
            continue;
        };
        for line in text.lines() {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
                continue;
            };
            let Some(task) = v["task"].as_u64().and_then(|t| usize::try_from(t).ok()) else {
                continue;
            };
            match v["status"].as_str() {
                Some("failed") => {
                    let e = v["error"].as_str().unwrap_or("failed").to_string();
                    out.insert(task, e);
                }
                Some("ok") => {
                    out.remove(&task);
                }
                _ => {}
            }
        }
    }
    out
}

/// Where every task of `job` stands, from its outputs and the logs `logs` (the job's own log
/// is always read).
#[must_use]
pub fn status(job: &Job, logs: &[PathBuf]) -> Status {
    let mut all: Vec<PathBuf> = vec![job.log.clone()];
    all.extend(logs.iter().filter(|l| **l != job.log).cloned());
    let failed = failures(&all);
    let state = |t: &Task, error: Option<String>| TaskState {
        task: t.index,
        input: t.input.clone(),
        light: t.light.clone(),
        output: t.output.clone(),
        error,
    };
    let mut s = Status::default();
    for t in &job.tasks {
        if let Some(why) = job.shadowless(t) {
            s.skipped.push(state(t, Some(why)));
        } else if job.up_to_date(t) {
            s.done.push(state(t, None));
        } else if let Some(e) = failed.get(&t.index) {
            s.failed.push(state(t, Some(e.clone())));
        } else {
            s.missing.push(state(t, None));
        }
    }
    for t in &job.positions {
        let st = TaskState {
            task: t.index,
            input: t.stage.clone(),
            light: t.light_name(),
            output: t.output.clone(),
            error: None,
        };
        if job.positions_up_to_date(t) {
            s.done.push(st);
        } else if let Some(e) = failed.get(&t.index) {
            s.failed.push(TaskState {
                error: Some(e.clone()),
                ..st
            });
        } else {
            s.missing.push(st);
        }
    }
    s
}
