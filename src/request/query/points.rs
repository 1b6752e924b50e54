//! A `positions` request: every point of a stage's `Points` prim or `PointInstancer` toward
//! the stage light (with `light-angle` or `light-radius`, that light with extent), frame by
//! frame ([`crate::points::point_transmittance`]), and with `usd_out` the `.usda` layer that
//! time-samples the answers as a primvar on the prim.

use super::run::{PointsOutcome, QueryError, QueryStep};
use super::QueryRequest;
use crate::error::Error;
use crate::points::{PointFrame, PointQuery};

impl QueryRequest {
    /// Answer a request with `positions` ([`QueryRequest::run`]): its frames are `frames`,
    /// else `read.stage.time`, else the stage's start time code.
    pub(super) fn run_points(
        &self,
        on_frame: &mut (dyn FnMut(&PointFrame) + Send),
    ) -> Result<PointsOutcome, QueryError> {
        let at = |step| move |e| QueryError::at(step, e);
        self.check().map_err(at(QueryStep::Check))?;
        let prim = self.positions.as_deref().unwrap_or_default();
        let frames = match (&self.frames, self.source.options().frame) {
            (Some(f), _) => f.clone(),
            (None, Some(f)) => vec![f],
            (None, None) => vec![
                crate::usd::lights_at(self.source.path(), None)
                    .map_err(at(QueryStep::Ray))?
                    .time,
            ],
        };
        let (est, opts) = self.estimator().map_err(at(QueryStep::Check))?;
        // The light and the time are set per frame (`point_transmittance`); `check` refused
        // an xform.
        let pool = self.pool().map_err(at(QueryStep::Check))?;
        self.check_usd_out().map_err(at(QueryStep::Check))?;
        let q = PointQuery {
            stage: self.source.path(),
            prim,
            light: self.source.options().light.as_deref(),
            frames: &frames,
            extent: &self.light,
        };
        let answers = pool
            .install(|| crate::points::point_transmittance(&q, &self.source, &est, &opts, on_frame))
            .map_err(at(QueryStep::Load))?;
        if let Some(layer) = &self.usd_out {
            let text = crate::points::layer_text(&answers).map_err(at(QueryStep::Answer))?;
            crate::output::write_atomic(layer, self.force, |w| {
                std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
            })
            .map_err(at(QueryStep::Answer))?;
        }
        Ok(PointsOutcome {
            answers,
            estimator: est.name().to_string(),
            usd_out: self.usd_out.clone(),
        })
    }

    /// `usd_out`: a `.usda` layer that may be written (`force` to replace it).
    fn check_usd_out(&self) -> crate::error::Result<()> {
        let Some(layer) = &self.usd_out else {
            return Ok(());
        };
        if !crate::input::is_usda_layer(layer) {
            return Err(Error::InvalidArgument {
                name: "usd-out".into(),
                reason: format!("{} is not a .usda layer", layer.display()),
            });
        }
        crate::output::check_target(layer, self.force)
    }
}
