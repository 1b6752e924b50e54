//! One way to answer a query: [`QueryRequest::run`] checks the request, finds the light (a
//! stage's, by its shadow links), loads what the rays cross (lazily: only the leaves they
//! touch, unless the load mode or a grid-wide majorant wants the whole grid), checks the work
//! budget and answers every ray through the batch entry point (`scene::estimate_many`), so a
//! segment gets the same number however it is asked. A failure says the [`QueryStep`] it
//! stopped at, so each front end words it as before.

use super::{Asked, AskedLight, LoadMode, QueryRequest, RayRow};
use crate::bake::Warning;
use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use crate::input::Source;
use crate::points::PointAnswers;
use crate::scene::{Scene, SceneEstimate};
use crate::{Interp, Light, Ray};
use std::path::PathBuf;

/// What a finished query answered.
#[derive(Debug, Clone)]
pub enum QueryOutcome {
    /// A segment, a point toward a light, or the rows of a file of rays.
    Rays(RayAnswers),
    /// Every point of a stage's points prim, frame by frame.
    Points(PointsOutcome),
}

/// The answers to rays, in the order asked.
#[derive(Debug, Clone)]
pub struct RayAnswers {
    /// One per ray asked (per row of a file of rays, a bad row keeping its error).
    pub answers: Vec<Answer>,
    /// The estimator's name.
    pub estimator: String,
    /// The interpolation.
    pub interp: Interp,
    /// What the answers want their user to know: capped samples, majorant violations, every
    /// query missing every active voxel.
    pub warnings: Vec<Warning>,
    /// What reading the input changed (the bad-voxel policy, level sets, motion).
    pub load_warnings: Vec<Warning>,
}

/// One answered (or failed) ray.
#[derive(Debug, Clone)]
pub struct Answer {
    /// The row's line in the file of rays (`None` for a single query).
    pub line: Option<usize>,
    /// The answer, or why this ray has none (a bad row, an estimate that failed).
    pub result: std::result::Result<Answered, String>,
}

/// An answer: the ray traced, its estimate and the time it took (for a row, the batch's time
/// per ray).
#[derive(Debug, Clone)]
pub struct Answered {
    /// The ray.
    pub ray: Ray,
    /// Its estimate.
    pub estimate: SceneEstimate,
    /// Seconds.
    pub seconds: f64,
    /// Toward a light with extent: the directions traced (0 when the light's whole cone
    /// provably misses every volume and solid); `None` toward a point (and for segments).
    pub light_samples: Option<usize>,
    /// Toward a light with extent: the target error asked for more directions than
    /// `light-max-samples` allows (the error bar may be above the target).
    pub light_capped: bool,
}

/// The answers at every point of a stage's points prim.
#[derive(Debug, Clone)]
pub struct PointsOutcome {
    /// Every frame's answers.
    pub answers: PointAnswers,
    /// The estimator's name.
    pub estimator: String,
    /// The layer written, when `usd_out` asked for one.
    pub usd_out: Option<PathBuf>,
}

/// Where a query stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QueryStep {
    /// Checking the request and its options (errors name options: respell them).
    Check,
    /// Reading the stage's lights (the light toward which a point is answered, a
    /// `positions` request's start frame) and making a single query's ray (errors as the
    /// library says them).
    Ray,
    /// Reading the input (argument errors name options: respell them).
    Load,
    /// Writing what was answered (a `usd_out` layer). A ray whose estimate fails is not an
    /// error of the query: it is that ray's answer.
    Answer,
}

/// A query that failed: the library's error, the step it stopped at, the context a load error
/// is read in (`loading grid 'density'`, `loading the scene`, `loading the shot`), and what
/// reading the input said before the failure.
#[derive(Debug)]
pub struct QueryError {
    /// Where the query stopped.
    pub step: QueryStep,
    /// What was being loaded, for a load error that is not about an argument.
    pub context: Option<String>,
    /// The error.
    pub error: Error,
    /// The input's warnings, when it was read before the failure.
    pub load_warnings: Box<[Warning]>,
}

impl QueryError {
    /// `error` at `step`.
    pub(super) fn at(step: QueryStep, error: Error) -> Self {
        Self {
            step,
            context: None,
            error,
            load_warnings: Box::default(),
        }
    }

    /// The failure with an error about options worded by a front end (`f`: an option as its
    /// user types it), at the steps whose errors name options ([`QueryStep::Check`],
    /// [`QueryStep::Load`]); other steps' errors are as the library says them.
    #[must_use]
    pub fn worded(self, f: impl FnOnce(Error) -> Error) -> Self {
        match self.step {
            QueryStep::Check | QueryStep::Load => Self {
                error: f(self.error),
                ..self
            },
            QueryStep::Ray | QueryStep::Answer => self,
        }
    }
}

impl std::fmt::Display for QueryError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.context {
            Some(c) => write!(f, "{c}: {}", self.error),
            None => write!(f, "{}", self.error),
        }
    }
}

impl std::error::Error for QueryError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.error)
    }
}

type Step<T> = std::result::Result<T, QueryError>;

/// `Err` at `step`.
fn at(step: QueryStep) -> impl FnOnce(Error) -> QueryError {
    move |e| QueryError::at(step, e)
}

impl QueryRequest {
    /// Check the request and answer it, on `threads` workers: every front end's one entry
    /// point of a query. `on_frame` is called after each frame of a `positions` request (a
    /// front end prints as they come); other requests do not call it.
    ///
    /// # Errors
    /// [`QueryError`] at the step it stopped at: [`QueryStep::Check`] for the request and its
    /// options and the work budget, [`QueryStep::Ray`] for the stage light or a query's ray
    /// that cannot be made, [`QueryStep::Load`] for reading the input (and answering a `positions`
    /// request), [`QueryStep::Answer`] for writing a layer. A ray whose estimate fails
    /// (a single query's, or a row's) is not an error: it is that ray's answer.
    pub fn run(
        &self,
        on_frame: &mut (dyn FnMut(&crate::points::PointFrame) + Send),
    ) -> std::result::Result<QueryOutcome, QueryError> {
        if self.positions.is_some() {
            return self.run_points(on_frame).map(QueryOutcome::Points);
        }
        let asked = self.asked().map_err(at(QueryStep::Check))?;
        let (asked, light, toward) = self.light(asked)?;
        let (est, opts) = self.estimator().map_err(at(QueryStep::Check))?;
        let mut read = self.source.clone();
        read.options_mut().light = toward;
        let pool = self.pool().map_err(at(QueryStep::Check))?;
        pool.install(|| self.answer(asked, light, &read, (&est, &opts)))
            .map(QueryOutcome::Rays)
    }

    /// The estimator and its options at the request's interpolation, checked against the
    /// source's motion ([`crate::request::EstimatorOptions::motion`]).
    pub(crate) fn estimator(&self) -> Result<(Estimator, Options)> {
        let resolved = self
            .estimator
            .resolve(&self.params, self.source.options().interp)?;
        self.estimator.motion(self.source.options())?;
        Ok(resolved)
    }

    /// A pool of the request's workers.
    pub(crate) fn pool(&self) -> Result<rayon::ThreadPool> {
        crate::bake::check_threads(self.threads)?;
        rayon::ThreadPoolBuilder::new()
            .num_threads(self.threads)
            .build()
            .map_err(|e| Error::InvalidArgument {
                name: "threads".into(),
                reason: format!("cannot start worker threads: {e}"),
            })
    }

    /// The light a shading point is answered toward, and the stage light the scene is read
    /// toward (named, or the stage's only one): the scene holds only the volumes its shadow
    /// link includes. A stage light with extent (a distant light's angle, a sphere's radius,
    /// a disk, rect or cylinder) turns the question into one toward a light with extent.
    fn light(&self, asked: Asked) -> Step<(Asked, Option<Light>, Option<String>)> {
        let named = self.source.options().light.clone();
        match asked {
            Asked::Toward {
                light: AskedLight::Stage,
                ..
            } => {
                let shot = crate::usd::lights_at(self.source.path(), self.source.options().frame)
                    .map_err(at(QueryStep::Ray))?;
                let (l, e) = shot.light(named.as_deref()).map_err(at(QueryStep::Ray))?;
                // The flags' extent over the stage's (`light-angle`, `light-radius`), else the
                // stage light's own.
                let soft = self.light.soft_of_stage(e).map_err(|err| {
                    // An option's error is respelled; the stage's as the library says it.
                    let flag = matches!(&err, Error::InvalidArgument { name, .. }
                        if name.starts_with("light-"));
                    at(if flag {
                        QueryStep::Check
                    } else {
                        QueryStep::Ray
                    })(err)
                })?;
                let asked = match (asked, soft) {
                    (Asked::Toward { at, .. }, Some(s)) => Asked::Toward {
                        at,
                        light: AskedLight::Soft(s),
                    },
                    _ => asked,
                };
                Ok((asked, Some(Light::from(e)), Some(l.prim.clone())))
            }
            Asked::Toward {
                light: AskedLight::Given(l),
                ..
            } => Ok((asked, Some(l), named)),
            Asked::Toward {
                light: AskedLight::Soft(s),
                ..
            } => Ok((asked, Some(s.light), named)),
            Asked::Segment { .. } | Asked::Rows => Ok((asked, None, named)),
        }
    }

    /// Load what the rays cross, check the budget and answer.
    fn answer(
        &self,
        asked: Asked,
        light: Option<Light>,
        read: &Source,
        (est, opts): (&Estimator, &Options),
    ) -> Step<RayAnswers> {
        // The query's rays, made against the scene's boxes (a lazy load's shell): a single ray
        // that cannot be made keeps its error here and asks for nothing to be decoded.
        let mut ray_error = None;
        let mut soft_rays = None;
        let make_rays = |scene: &Scene| -> Vec<Ray> {
            if let Asked::Toward {
                at,
                light: AskedLight::Soft(s),
            } = asked
            {
                // The rays a lazy load decodes along: a fixed count's own; with a target
                // error the final directions follow the pilot, so the scene is read whole
                // (`load_scene`).
                let key = crate::light::extent::Key {
                    seed: opts.seed,
                    ray_id: self.ray_id,
                    stage: 0,
                };
                let m = s.samples / crate::light::extent::REPLICATES;
                soft_rays = Some((s, at));
                return match s.rays(scene, at, key, m) {
                    Ok(r) if s.target.is_none() => r.rays,
                    Ok(_) => Vec::new(),
                    Err(e) => {
                        ray_error = Some(e);
                        Vec::new()
                    }
                };
            }
            let ray = match (asked, light) {
                (Asked::Rows, _) => {
                    let rows = self.rays.as_deref().unwrap_or_default();
                    return rows
                        .iter()
                        .filter_map(|r| r.ray.as_ref().ok().copied())
                        .collect();
                }
                (Asked::Segment { from, to }, _) => Ray::between(from, to),
                (Asked::Toward { at, .. }, Some(l)) => l.ray_from_scene(scene, at),
                (Asked::Toward { .. }, None) => return Vec::new(),
            };
            ray.map_err(|e| ray_error = Some(e)).into_iter().collect()
        };
        let whole = matches!(
            asked,
            Asked::Toward {
                light: AskedLight::Soft(s),
                ..
            } if s.target.is_some()
        );
        let (scene, rays) = self.load_scene(read, opts, whole, make_rays)?;
        let load_warnings = load_warnings(&scene);
        let with_warnings = |e: QueryError| QueryError {
            load_warnings: load_warnings.clone().into(),
            ..e
        };
        if let Some(e) = ray_error {
            return Err(with_warnings(QueryError::at(QueryStep::Ray, e)));
        }
        // The work budget, up front: per ray and for every ray of the batch together.
        let n_rays = match &soft_rays {
            Some((s, _)) => s.samples.max(1) as usize,
            None => self.rays.as_ref().map_or(1, Vec::len),
        } as u64;
        check_budget(&scene, est, opts, n_rays)
            .map_err(|e| with_warnings(QueryError::at(QueryStep::Check, e)))?;
        let answers = match (asked, rays.first(), &soft_rays) {
            (_, _, Some((soft, at))) => {
                vec![answer_soft(&scene, soft, *at, self.ray_id, (est, opts))]
            }
            (Asked::Rows, ..) => answer_file(
                &scene,
                self.rays.as_deref().unwrap_or_default(),
                &rays,
                self.ray_id,
                (est, opts),
            ),
            (_, Some(ray), None) => vec![answer_one(&scene, ray, self.ray_id, (est, opts))],
            (_, None, None) => {
                let nothing = Error::Conflict {
                    names: Vec::new(),
                    reason: "nothing to query".into(),
                };
                return Err(with_warnings(QueryError::at(QueryStep::Ray, nothing)));
            }
        };
        let mut tally = QueryTally::default();
        for a in &answers {
            if let Ok(a) = &a.result {
                tally.add(&a.estimate);
            }
        }
        let mut warnings = tally.warnings();
        let far = rays.iter().filter(|r| scene.loses_precision(r)).count() as u64;
        if far > 0 {
            warnings.push(Warning::FarRays { rays: far });
        }
        Ok(RayAnswers {
            answers,
            estimator: est.name().to_string(),
            interp: self.source.options().interp,
            warnings,
            load_warnings,
        })
    }

    /// The scene and the query's rays: the whole grid (load `eager`, or a grid-wide majorant,
    /// which is every leaf's bound), else only what the rays cross.
    fn load_scene(
        &self,
        read: &Source,
        opts: &Options,
        whole: bool,
        make_rays: impl FnOnce(&Scene) -> Vec<Ray>,
    ) -> Step<(Scene, Vec<Ray>)> {
        let loaded = if self.load == LoadMode::Eager || opts.global_majorant || whole {
            read.load().map(|s| {
                let r = make_rays(&s);
                (s, r)
            })
        } else {
            let from = if self.load == LoadMode::Lazy {
                0
            } else {
                crate::scene::file::LAZY_MIN_BYTES
            };
            read.load_for_rays(opts.granularity, from, make_rays)
        };
        loaded.map_err(|e| self.loading(&read.options().grid, e))
    }

    /// A load error in the context of loading the input, unless it is about an argument.
    fn loading(&self, grid: &str, error: Error) -> QueryError {
        let kind = self.source.kind();
        let context = match error {
            Error::InvalidArgument { .. } | Error::Conflict { .. } => None,
            _ if kind.is_scene_file() => Some("loading the scene".to_string()),
            _ if kind.is_stage() => Some("loading the shot".to_string()),
            _ => Some(format!("loading grid '{grid}'")),
        };
        QueryError {
            context,
            ..QueryError::at(QueryStep::Load, error)
        }
    }
}

/// What reading `scene` changed: voxels the bad-voxel policy changed, level sets, motion.
fn load_warnings(scene: &Scene) -> Vec<Warning> {
    let mut w = crate::bake::volume_warnings(&scene.sanitized());
    w.extend(crate::bake::solid_warnings(scene));
    w.extend(crate::bake::motion_warnings(scene));
    w
}

/// The work budget of `rays` rays on every fog volume of `scene`: per ray and for them all
/// together.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `samples` or the estimator's option that makes it too
/// much work.
pub fn check_budget(scene: &Scene, est: &Estimator, opts: &Options, rays: u64) -> Result<()> {
    for f in scene.fogs() {
        crate::estimate::budget::check_job(
            f.volume(),
            est,
            rays,
            u64::from(opts.samples),
            "samples",
        )?;
    }
    Ok(())
}

/// Answer `rows` on `scene`, row `n` with ray id `first_id + n`: a row whose ray could not be
/// made keeps its error. The rays go to the library together (`scene::estimate_many`: exact
/// queries in batches on the SIMD kernel).
#[must_use]
pub fn answer_rows(
    scene: &Scene,
    rows: &[std::result::Result<Ray, String>],
    first_id: u64,
    est: &Estimator,
    opts: &Options,
) -> Vec<std::result::Result<SceneEstimate, String>> {
    let (rays, ids): (Vec<Ray>, Vec<u64>) = rows
        .iter()
        .enumerate()
        .filter_map(|(n, r)| {
            r.as_ref()
                .ok()
                .map(|r| (*r, first_id.wrapping_add(n as u64)))
        })
        .unzip();
    let mut answers = crate::scene::estimate_many(scene, &rays, &ids, est, opts).into_iter();
    rows.iter()
        .map(|r| {
            r.clone().and_then(|_| match answers.next() {
                Some(a) => a.map_err(|e| e.to_string()),
                None => Err("no answer for this row".to_string()),
            })
        })
        .collect()
}

/// A file's rows: row `n` has ray id `ray_id + n`; a row's `seconds` is the batch's time per
/// ray. `rays` are the rows' good rays, as made for the load.
fn answer_file(
    scene: &Scene,
    rows: &[RayRow],
    rays: &[Ray],
    ray_id: u64,
    (est, opts): (&Estimator, &Options),
) -> Vec<Answer> {
    // The good rows' ids; their rays are `rays`, in order (no copy of the rows: a file may hold
    // millions).
    let ids: Vec<u64> = rows
        .iter()
        .enumerate()
        .filter(|(_, r)| r.ray.is_ok())
        .map(|(n, _)| ray_id.wrapping_add(n as u64))
        .collect();
    let start = std::time::Instant::now();
    let results = crate::scene::estimate_many(scene, rays, &ids, est, opts);
    let per_ray = start.elapsed().as_secs_f64() / rays.len().max(1) as f64;
    let mut results = rays.iter().copied().zip(results);
    rows.iter()
        .map(|row| Answer {
            line: Some(row.line),
            result: match &row.ray {
                Err(e) => Err(e.clone()),
                Ok(_) => match results.next() {
                    Some((ray, Ok(estimate))) => Ok(Answered {
                        ray,
                        estimate,
                        seconds: per_ray,
                        light_samples: None,
                        light_capped: false,
                    }),
                    Some((_, Err(e))) => Err(e.to_string()),
                    None => Err("no answer for this row".to_string()),
                },
            },
        })
        .collect()
}

/// A single query, through the batch entry point like a file's rows and Python's arrays, so
/// one segment gets the same number however it is asked; an estimate that fails is the
/// answer's error.
fn answer_one(
    scene: &Scene,
    ray: &Ray,
    ray_id: u64,
    (est, opts): (&Estimator, &Options),
) -> Answer {
    let start = std::time::Instant::now();
    let mut r = answer_rows(scene, &[Ok(*ray)], ray_id, est, opts);
    let result = r
        .pop()
        .unwrap_or_else(|| Err("no answer for the query".to_string()))
        .map(|estimate| Answered {
            ray: *ray,
            estimate,
            seconds: start.elapsed().as_secs_f64(),
            light_samples: None,
            light_capped: false,
        });
    Answer { line: None, result }
}

/// A receiver toward a light with extent ([`crate::light::SoftLight::answer_each`], the path
/// every product takes: a texel at `at` with ray id `ray_id` is this answer); a direction whose
/// estimate fails is the answer's error.
fn answer_soft(
    scene: &Scene,
    soft: &crate::light::SoftLight,
    at: [f64; 3],
    ray_id: u64,
    (est, opts): (&Estimator, &Options),
) -> Answer {
    let start = std::time::Instant::now();
    let receiver = crate::light::Receiver { at, ray_id };
    let result = soft
        .answer_each(
            scene,
            &crate::light::Occupancy::of(scene),
            &[Some(receiver)],
            est,
            opts,
        )
        .pop()
        .flatten()
        .unwrap_or_else(|| {
            Err(Error::InvalidArgument {
                name: "at".into(),
                reason: "the receiver got no answer".into(),
            })
        })
        .map(|a| Answered {
            ray: a.centre,
            estimate: a.estimate,
            seconds: start.elapsed().as_secs_f64(),
            light_samples: Some(a.light_samples),
            light_capped: a.light_capped,
        })
        .map_err(|e| e.to_string());
    Answer { line: None, result }
}

/// What answers tell their user, counted over any number of answers (merged between
/// chunks): capped samples, majorant violations, and whether any answer met an active voxel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct QueryTally {
    /// Answers counted.
    pub answered: u64,
    /// Samples stopped at the collision cap.
    pub capped: u64,
    /// Lookups outside their segment's bounds.
    pub violations: u64,
    /// Answers whose ray met an active voxel (walked a segment, hit a solid or lost light).
    pub met: u64,
}

impl QueryTally {
    /// Count one answer.
    pub fn add(&mut self, e: &SceneEstimate) {
        let met =
            e.segments > 0 || e.hit.is_some() || e.value[..e.channels].iter().any(|v| *v != 1.0);
        self.answered += 1;
        self.capped += e.capped;
        self.violations += e.majorant_violations;
        self.met += u64::from(met);
    }

    /// Both tallies together.
    #[must_use]
    pub fn merge(self, o: Self) -> Self {
        Self {
            answered: self.answered + o.answered,
            capped: self.capped + o.capped,
            violations: self.violations + o.violations,
            met: self.met + o.met,
        }
    }

    /// The warnings: capped samples, majorant violations, and every answer missing every
    /// active voxel (each answered T = 1, no segment walked, no solid hit).
    #[must_use]
    pub fn warnings(&self) -> Vec<Warning> {
        let mut out = Vec::new();
        if self.capped > 0 {
            out.push(Warning::Capped {
                samples: self.capped,
            });
        }
        if self.violations > 0 {
            out.push(Warning::MajorantViolations {
                lookups: self.violations,
            });
        }
        if self.answered > 0 && self.met == 0 {
            out.push(Warning::MissedEveryVoxel {
                queries: self.answered,
            });
        }
        out
    }
}
