//! One way to run a bake: [`BakeRequest::run`] plans the request and runs every step of it
//! (check the outputs and the `usd_out` layer, plan whole or in parts, load, trace, encode, and
//! commit every output together: the map or deep map, its preview and the layer; or the
//! transmittance volume), reporting to one [`Progress`]. The CLI, the Python module and batch
//! tasks all call it; a failure says the [`Step`] it stopped at, so each front end words it as
//! before (`loading grid 'density': ...`).

use super::{BakePlan, BakeRequest};
use crate::bake::{BakeError, BakeJob, BakeReport, Camera, Step, VolumeJob, VolumeReport};
use crate::error::Result;
use crate::output::Staged;
use crate::progress::Progress;
use std::path::{Path, PathBuf};

/// What a finished request made: the plan it ran (what a report describes) and its report.
#[derive(Debug, Clone)]
pub enum BakeOutcome {
    /// An EXR map (flat or deep) and its preview.
    Map {
        /// The planned job.
        job: Box<BakeJob>,
        /// What the bake produced.
        report: Box<BakeReport>,
        /// The `usd_out` layer written with the map, when the request asked for one.
        usd_out: Option<PathBuf>,
    },
    /// A transmittance volume.
    Volume {
        /// The planned job.
        job: Box<VolumeJob>,
        /// What it produced.
        report: VolumeReport,
    },
}

impl BakeRequest {
    /// Plan the request ([`BakeRequest::plan`]) and run it ([`BakeRequest::run_plan`]): the
    /// one entry point of a bake for every front end.
    ///
    /// # Errors
    /// [`BakeError`] at [`Step::Check`] for the request's options, outputs and settings, at
    /// [`Step::Load`] (with the context `loading grid 'NAME'` or `loading the scene` unless the
    /// error is about an argument or an output) for reading the input, at [`Step::Bake`] for
    /// tracing and writing. Nothing is written on error.
    pub fn run(&self, progress: &dyn Progress) -> std::result::Result<BakeOutcome, BakeError> {
        let plan = self.plan().map_err(|e| BakeError::at(Step::Check, e))?;
        self.run_plan(plan, progress)
    }

    /// Run `plan`, this request's plan (possibly with a camera set on it: a batch's shared
    /// camera): check the `usd_out` layer may be written, bake, and commit the map, its preview
    /// and the layer together; or compute and write the transmittance volume.
    ///
    /// # Errors
    /// As [`BakeRequest::run`].
    pub fn run_plan(
        &self,
        plan: BakePlan,
        progress: &dyn Progress,
    ) -> std::result::Result<BakeOutcome, BakeError> {
        match plan {
            BakePlan::Map(job) => {
                self.check_usd_out()
                    .map_err(|e| BakeError::at(Step::Check, e))?;
                let stage_layer = |r: &BakeReport| -> Result<Vec<Staged>> {
                    Ok(self.stage_usd_out(&r.map.camera)?.into_iter().collect())
                };
                let report = job.run_with(progress, &stage_layer)?;
                Ok(BakeOutcome::Map {
                    job,
                    report: Box::new(report),
                    usd_out: self.options.usd_out.clone(),
                })
            }
            BakePlan::Volume(job) => {
                let report = job.run_steps(progress)?;
                Ok(BakeOutcome::Volume { job, report })
            }
        }
    }

    /// `usd_out`: check before any work that the layer may be written (`force` to replace it).
    fn check_usd_out(&self) -> Result<()> {
        match &self.options.usd_out {
            Some(u) => crate::output::check_target(u, self.options.force),
            None => Ok(()),
        }
    }

    /// `usd_out`: the `.usda` layer that puts the map and its camera on the stage light it was
    /// baked from ([`crate::usd::shadow_layer`]), staged to be committed with the map. `None`
    /// when `usd_out` is not set.
    fn stage_usd_out(&self, camera: &Camera) -> Result<Option<Staged>> {
        let Some(layer) = &self.options.usd_out else {
            return Ok(None);
        };
        let sample = shadow_sample(
            &self.input,
            self.options.source.frame,
            self.options.source.light.as_deref(),
            layer,
            &self.output,
            camera,
        )?;
        let text = layer_text(&[sample])?;
        crate::output::stage(layer, self.options.force, |w| {
            std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
        })
        .map(Some)
    }
}

/// The map `map`, baked with `camera` from the light `light` (by prim path or name; the
/// stage's only light when `None`) of the stage `stage` at `time`, as the layer `layer` names
/// it: what a request's `usd_out` layer and a batch job's layer hold per map.
///
/// # Errors
/// As [`crate::usd::lights_at`] and [`crate::usd::Shot::light`].
pub(crate) fn shadow_sample(
    stage: &Path,
    time: Option<f64>,
    light: Option<&str>,
    layer: &Path,
    map: &Path,
    camera: &Camera,
) -> Result<crate::usd::ShadowSample> {
    let shot = crate::usd::lights_at(stage, time)?;
    let (light, _) = shot.light(light)?;
    Ok(crate::usd::ShadowSample {
        light: light.prim.clone(),
        time: shot.time,
        map: crate::usd::asset_name(layer, map),
        world_to_ndc: camera.world_to_ndc(),
    })
}

/// The layer's text ([`crate::usd::shadow_layer`]).
#[cfg(feature = "usd")]
fn layer_text(samples: &[crate::usd::ShadowSample]) -> Result<String> {
    crate::usd::shadow_layer(samples)
}

/// Without USD support no request has a stage light (its input fails to read first).
#[cfg(not(feature = "usd"))]
fn layer_text(_samples: &[crate::usd::ShadowSample]) -> Result<String> {
    Err(crate::error::Error::Unsupported {
        path: PathBuf::from("usd-out"),
        what: "USD layers (this umbra was built without the \"usd\" feature)".into(),
    })
}
