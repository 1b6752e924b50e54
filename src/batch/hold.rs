//! Held frames (issue 68): two tasks of a sequence whose inputs have the same content (a held
//! frame of a simulation, a symlinked frame) and whose requests differ only by the frame bake
//! once; the other's output is a copy, the bytes its own bake would write (its map's source
//! file and key in the header), and its log record says which frame it holds (`holds`).
//!
//! **Which tasks hold.** The same [`super::TaskKey::hold_signature`]: the key without the frame
//! and the input's name, its files by content. A stage's tasks never hold (values sampled in
//! time, an animated transform, are not in the key), nor a transmittance volume's; a map that
//! is not whole in memory (deep, fixed-size deep, streamed in parts) is baked by each task.

use super::{BatchError, Freshness, Job, Task, TaskKey};
use crate::bake::BakeReport;
use std::collections::hash_map::{Entry, HashMap};

/// The tasks of `todo` in units, by index: each unit's first task bakes, the others hold its
/// frame (module docs); a task that holds nothing is a unit alone. Units keep task order.
pub(super) fn units(job: &Job, todo: &[(&Task, Freshness)]) -> Vec<Vec<usize>> {
    let mut units: Vec<Vec<usize>> = Vec::new();
    let mut leads: HashMap<String, usize> = HashMap::new();
    for (k, (t, f)) in todo.iter().enumerate() {
        let holds = !job.volume && t.frame.is_some() && !t.source.kind().is_stage();
        if let Some(sig) = f
            .key
            .as_ref()
            .filter(|_| holds)
            .map(TaskKey::hold_signature)
        {
            match leads.entry(sig) {
                Entry::Occupied(e) => {
                    units[*e.get()].push(k);
                    continue;
                }
                Entry::Vacant(e) => {
                    e.insert(units.len());
                }
            }
        }
        units.push(vec![k]);
    }
    units
}

impl Job {
    /// Write `task`'s map as a copy of `from`, the report of the bake of a task whose frame it
    /// holds: the same image under `task`'s source file and `key`
    /// ([`crate::bake::BakeJob::commit_copy`]). `Ok(false)` (nothing written) when `from`
    /// cannot be copied: the task must bake.
    ///
    /// # Errors
    /// [`BatchError::Task`] for a planning or write error.
    pub fn copy_task(
        &self,
        task: &Task,
        key: Option<&TaskKey>,
        from: &BakeReport,
    ) -> Result<bool, BatchError> {
        let mut job = self.bake_job(task, 1)?;
        job.key = key.map(TaskKey::to_text);
        job.commit_copy(from)
            .map(|p| p.is_some())
            .map_err(BatchError::Task)
    }
}
