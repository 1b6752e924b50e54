//! One query request for every front end, beside the bake request: [`QueryRequest`] is what a
//! TD asks of `umbra query` (a segment, a shading point toward a light, the rows of a file of
//! rays, or every point of a stage's points prim toward a stage light) with how the input is
//! read and estimated, and [`QueryRequest::run`] answers it (`query/run.rs`; the stage points
//! in `query/points.rs`): the CLI's `query`, the Python module and batch `[[positions]]` tasks
//! call it.
//!
//! **One set of checks.** [`QueryRequest::check`] refuses a request whose parts do not go
//! together (exactly one of a segment, a point toward a light, rows of rays or stage
//! positions; `frames`, `usd-out` and `force` only with positions) with
//! [`Error::Conflict`] or [`Error::InvalidArgument`] naming the options in the library's
//! spelling (`light-dir`); each front end respells them (`--light-dir`).

use crate::error::{Error, Result};
use crate::input::Source;
use crate::request::{EstimatorOptions, EstimatorParams};
use crate::Ray;
use std::path::PathBuf;

mod points;
mod run;
pub use run::{
    answer_rows, check_budget, Answer, Answered, PointsOutcome, QueryError, QueryOutcome,
    QueryStep, QueryTally, RayAnswers,
};

/// How much of a `.vdb` grid a query decodes (`load`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum LoadMode {
    /// Lazy for large grids, whole for small ones.
    #[default]
    Auto,
    /// Only the leaves the rays touch.
    Lazy,
    /// The whole grid.
    Eager,
}

/// One row of a file of rays: its line number and its ray, or why the line is not one (kept
/// and answered as that row's error).
#[derive(Debug, Clone, PartialEq)]
pub struct RayRow {
    /// The line of the file (1-based).
    pub line: usize,
    /// The segment, or why the line is bad.
    pub ray: std::result::Result<Ray, String>,
}

/// One query: the input, what is asked of it, how it is read and how it is estimated.
///
/// What is asked is one of: a segment (`from` and `to`); a shading point `at` toward a light
/// (`light_dir`, `light_pos`, or a USD stage's light, `read.stage.light` or the stage's only
/// light, whose shadow links pick the volumes); `rays`, the rows of a file of segments; or
/// `positions`, every point of a stage's points prim at `frames` (or `read.stage.time`, or the
/// stage's start) toward the stage light, with an optional `usd_out` layer.
#[derive(Debug, Clone, PartialEq)]
pub struct QueryRequest {
    /// What is read: the `.vdb` or `.nvdb` file, a `.toml` scene file or a USD stage, its
    /// kind, and how it is read (grid, interpolation, scale, colour, placement, level sets,
    /// the stage selection, whose `light` is the stage light asked for, and the motion).
    pub source: Source,
    /// Segment start, world space (with `to`).
    pub from: Option<[f64; 3]>,
    /// Segment end, world space (with `from`).
    pub to: Option<[f64; 3]>,
    /// Shading point, world space (toward a light).
    pub at: Option<[f64; 3]>,
    /// The light, by direction or position (or, neither given, the stage light).
    pub light: crate::light::LightOptions,
    /// The rows of a file of segments, answered in order (row `n` with ray id `ray_id + n`).
    pub rays: Option<Vec<RayRow>>,
    /// A stage's `Points` prim or `PointInstancer`: answer every point toward the stage light.
    pub positions: Option<String>,
    /// With `positions`: the frames (time codes), instead of `read.stage.time`.
    pub frames: Option<Vec<f64>>,
    /// With `positions`: the `.usda` layer written with the answers as a primvar.
    pub usd_out: Option<PathBuf>,
    /// With `usd_out`: replace an existing layer.
    pub force: bool,
    /// The estimator and its options.
    pub estimator: EstimatorOptions,
    /// The estimator's parameters.
    pub params: EstimatorParams,
    /// Ray id of the query (selects its random streams).
    pub ray_id: u64,
    /// Worker threads (0: every core).
    pub threads: usize,
    /// How much of a `.vdb` grid is decoded.
    pub load: LoadMode,
}

impl QueryRequest {
    /// A request on `source` asking nothing yet, with every default: set what is asked.
    #[must_use]
    pub fn new(source: Source) -> Self {
        Self {
            source,
            from: None,
            to: None,
            at: None,
            light: crate::light::LightOptions::default(),
            rays: None,
            positions: None,
            frames: None,
            usd_out: None,
            force: false,
            estimator: EstimatorOptions::default(),
            params: EstimatorParams::default(),
            ray_id: 0,
            threads: 0,
            load: LoadMode::Auto,
        }
    }

    /// Check that what is asked goes together. Reads nothing.
    ///
    /// # Errors
    /// [`Error::Conflict`] for options that do not go together or one missing another;
    /// [`Error::InvalidArgument`] (`positions`) for positions on an input that is not a stage.
    pub fn check(&self) -> Result<()> {
        match self.positions {
            Some(_) => self.check_positions(),
            None => self.asked().map(|_| ()),
        }?;
        // The stage options only for a stage.
        self.source.check()
    }

    /// What a request without `positions` asks, checked.
    pub(crate) fn asked(&self) -> Result<Asked> {
        for (name, given) in [
            ("frames", self.frames.is_some()),
            ("usd-out", self.usd_out.is_some()),
            ("force", self.force),
        ] {
            if given {
                return Err(conflict(
                    &[name, "positions"],
                    "invalid argument '{0}': goes with {1} PRIM",
                ));
            }
        }
        // The keys of a light with extent, checked: they go with a given light, or apply to
        // the stage light a point is answered toward (resolved when the stage is read).
        let toward_stage = self.at.is_some()
            && self.source.kind().is_stage()
            && self.light.light_dir.is_none()
            && self.light.light_pos.is_none();
        let soft = if toward_stage {
            self.light.check_extent()?;
            None
        } else {
            self.light.soft()?
        };
        let segment = match (self.from, self.to, self.at) {
            (Some(from), Some(to), None) => Some((from, to)),
            (Some(_), None, _) | (None, Some(_), _) => {
                return Err(conflict(
                    &["from", "to"],
                    "{0} and {1} go together (a segment from one point to the other)",
                ))
            }
            _ => None,
        };
        let stage_light = self.source.options().light.is_some();
        let light = match (self.light.light_dir, self.light.light_pos) {
            (Some(_), Some(_)) => {
                return Err(conflict(
                    &["light-dir", "light-pos"],
                    "give {0} or {1}, not both",
                ))
            }
            (Some(_), None) | (None, Some(_)) if stage_light => {
                return Err(conflict(
                    &["light", "light-dir", "light-pos"],
                    "give {0} (a stage light) or {1} / {2}, not both",
                ))
            }
            (Some(_), None) | (None, Some(_)) => match soft {
                Some(s) => Some(AskedLight::Soft(s)),
                None => self.light.light().map(AskedLight::Given),
            },
            (None, None) if self.at.is_some() && self.source.kind().is_stage() => {
                Some(AskedLight::Stage)
            }
            (None, None) => None,
        };
        let modes = usize::from(segment.is_some())
            + usize::from(self.at.is_some())
            + usize::from(self.rays.is_some());
        if modes != 1 || (self.from.is_some() && self.at.is_some()) {
            return Err(conflict(
                &["from", "to", "at", "light-dir", "light-pos", "rays"],
                "give exactly one of {0}/{1}, {2} with {3} or {4}, or {5} FILE",
            ));
        }
        if self.at.is_some() != light.is_some() {
            return Err(conflict(
                &["at", "light-dir", "light-pos"],
                "{0} needs {1} DX,DY,DZ or {2} X,Y,Z (or a stage's light), and those need {0}",
            ));
        }
        Ok(match (segment, self.at, light, &self.rays) {
            (Some((from, to)), ..) => Asked::Segment { from, to },
            (None, Some(at), Some(light), _) => Asked::Toward { at, light },
            _ => Asked::Rows,
        })
    }

    /// The checks of a request with `positions`.
    fn check_positions(&self) -> Result<()> {
        // The keys of a light with extent apply to the stage light (resolved per frame).
        self.light.check_extent()?;
        if !self.source.kind().is_stage() {
            return Err(Error::InvalidArgument {
                name: "positions".into(),
                reason: self.source.not_a_stage(),
            });
        }
        let others = [
            ("from", self.from.is_some()),
            ("to", self.to.is_some()),
            ("at", self.at.is_some()),
            ("rays", self.rays.is_some()),
            ("light-dir", self.light.light_dir.is_some()),
            ("light-pos", self.light.light_pos.is_some()),
            ("xform", self.source.options().xform.is_some()),
        ];
        if let Some((name, _)) = others.iter().find(|(_, g)| *g) {
            return Err(conflict(
                &[name, "positions"],
                "invalid argument '{0}': {1} answers every point toward a stage light",
            ));
        }
        if self.frames.is_some() && self.source.options().frame.is_some() {
            return Err(conflict(
                &["frame", "frames"],
                "give {0} F or {1} A-B, not both",
            ));
        }
        Ok(())
    }
}

/// What a request without `positions` asks, once checked.
// A light with extent (an area light's frame) makes `Toward` large; the value lives for one
// query, copied a few times.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub(crate) enum Asked {
    /// A segment.
    Segment { from: [f64; 3], to: [f64; 3] },
    /// A shading point toward a light.
    Toward { at: [f64; 3], light: AskedLight },
    /// The rows of a file of rays.
    Rows,
}

/// The light a shading point is answered toward.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub(crate) enum AskedLight {
    /// A light given by its direction or position.
    Given(crate::Light),
    /// A sun with an angle or a sphere light with a radius (`light-angle`, `light-radius`).
    Soft(crate::light::SoftLight),
    /// The stage's light (`read.stage.light`, or its only one).
    Stage,
}

/// An [`Error::Conflict`] between `names` (library spelling), `reason` naming them `{i}`.
fn conflict(names: &[&str], reason: &str) -> Error {
    Error::Conflict {
        names: names.iter().map(ToString::to_string).collect(),
        reason: reason.to_string(),
    }
}
