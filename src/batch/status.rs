//! Where a job stands (`umbra batch JOB --status`): every task done, failed or not yet run,
//! from the outputs on disk and the runs' logs.
//!
//! A task toward a stage light without shadows is **skipped** ([`Job::shadowless`]: it bakes
//! nothing). Any other task is **done** when its output exists and carries the task's key now
//! ([`Job::freshness`]), whichever run, shard or machine baked it; else **failed** when a log
//! records it failing (the last such record's error); else **stale** when its output is there
//! but baked with other settings, other inputs, without a key, or is unreadable (`reason`
//! says which); else **missing**. Logs are JSON lines; a line a killed run left half-written
//! is ignored.

use super::{Freshness, Job, KeyCheck, Stale};
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
    /// Why a stale or missing task would be baked (`settings changed: bake.res`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// Every task of a job, by where it stands.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Status {
    /// Tasks whose output is on disk and up to date.
    pub done: Vec<TaskState>,
    /// Tasks a log records failing, without an up-to-date output.
    pub failed: Vec<TaskState>,
    /// Tasks not yet run: no output.
    pub missing: Vec<TaskState>,
    /// Tasks whose output is there but stale (`reason` says why).
    pub stale: Vec<TaskState>,
    /// Tasks that bake nothing: their stage light casts no shadows (`error` says why).
    pub skipped: Vec<TaskState>,
}

impl Status {
    /// Whether every task is done (or skipped: it bakes nothing).
    #[must_use]
    pub fn complete(&self) -> bool {
        self.failed.is_empty() && self.missing.is_empty() && self.stale.is_empty()
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

/// Where every task of `job` stands, from its outputs (their keys checked as `check` says)
/// and the logs `logs` (the job's own log is always read). The shared cameras a key holds are
/// read from the job's camera cache, or framed (a job that cannot be framed leaves every
/// output of shared framing stale: its run fails saying why).
#[must_use]
pub fn status(job: &Job, logs: &[PathBuf], check: KeyCheck) -> Status {
    let mut all: Vec<PathBuf> = vec![job.log.clone()];
    all.extend(logs.iter().filter(|l| **l != job.log).cloned());
    let failed = failures(&all);
    let stem = job.log.file_stem().map_or_else(
        || "umbra_batch".into(),
        |s| s.to_string_lossy().into_owned(),
    );
    let cache = job.log.with_file_name(format!("{stem}.cameras.json"));
    let _ = job.share_cameras_cached(&cache);
    let state = |task: usize, input: &PathBuf, light: String, output: &PathBuf| TaskState {
        task,
        input: input.clone(),
        light,
        output: output.clone(),
        error: None,
        reason: None,
    };
    let mut s = Status::default();
    let mut place = |st: TaskState, f: Freshness| {
        let Some(why) = f.stale else {
            s.done.push(st);
            return;
        };
        if let Some(e) = failed.get(&st.task) {
            s.failed.push(TaskState {
                error: Some(e.clone()),
                reason: Some(why.to_string()),
                ..st
            });
            return;
        }
        let st = TaskState {
            reason: Some(why.to_string()),
            ..st
        };
        match why {
            Stale::Missing => s.missing.push(st),
            _ => s.stale.push(st),
        }
    };
    let mut skipped = Vec::new();
    for t in &job.tasks {
        let st = state(t.index, &t.input, t.light.clone(), &t.output);
        if let Some(why) = job.shadowless(t) {
            skipped.push(TaskState {
                error: Some(why),
                ..st
            });
        } else {
            place(st, job.freshness(t, check));
        }
    }
    for t in &job.positions {
        let st = state(t.index, &t.stage, t.light_name(), &t.output);
        place(st, job.positions_freshness(t, check));
    }
    s.skipped = skipped;
    s
}
