//! The job's USD layer (`bake.usd_out`): every map baked from a stage light, on its light,
//! each as a request's own `usd_out` layer holds its map (`request::shadow_sample`).
//!
//! The layer is rebuilt from the maps on disk after each run: this run's, an earlier run's
//! (resume, skipped as up to date) and other shards'. Each map's camera is read back from its
//! own header (`worldToNDC`), its time code and light prim from the stage, so whichever shard
//! finishes last writes a layer that holds every map. Written atomically, replaced each run.

use super::{BatchError, Job};
use std::path::Path;

/// Write `layer` from every stage-light task of `job` whose map exists; how many maps it
/// holds.
///
/// # Errors
/// Reading a task's stage or a map's camera fails (naming the file), or the layer cannot be
/// written.
#[cfg(feature = "usd")]
pub(super) fn write(job: &Job, layer: &Path) -> Result<usize, BatchError> {
    let mut samples = Vec::new();
    for t in &job.tasks {
        let Some(name) = t.usd_light.as_deref().filter(|_| t.output.is_file()) else {
            continue;
        };
        // A map left from before the light's shadows were turned off is not its map now.
        if job.shadowless(t).is_some() {
            continue;
        }
        let camera = crate::bake::read_camera(&t.output, None)?;
        samples.push(crate::request::shadow_sample(
            &t.input,
            t.time(),
            Some(name),
            layer,
            &t.output,
            &camera,
        )?);
    }
    let text = crate::usd::shadow_layer(&samples)?;
    crate::output::write_atomic(layer, true, |w| {
        std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
    })?;
    Ok(samples.len())
}

/// Without USD support no job has stage lights (their inputs are refused when parsed).
#[cfg(not(feature = "usd"))]
pub(super) fn write(_job: &Job, _layer: &Path) -> Result<usize, BatchError> {
    Ok(0)
}
