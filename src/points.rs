//! Per-point attenuation over a shot: what fraction of a stage light reaches each point of a
//! `Points` prim or a `PointInstancer`, frame by frame (trees, rocks, crowds or instanced
//! lights under a cloud layer).
//!
//! At frame `t` the points are placed by the prim's local-to-world matrix at `t`
//! ([`crate::usd::points_at`]), the stage's volumes are read at `t` toward the light (its
//! shadow links honoured, as for a query), and point `i` is answered along the ray from it
//! toward the light ([`crate::Light::ray_from_scene`]: to a point light's position, or against
//! a sun's direction until the ray leaves every volume) with ray id `i`, so a stochastic
//! estimator gives the same answer whatever the thread count. `T_i = exp(-tau_i)` for the exact
//! estimator, its estimate otherwise.

use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use crate::input::Source;
use crate::light::SoftLight;
use crate::Light;
use std::path::Path;

/// The answers of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PointFrame {
    /// The time code.
    pub frame: f64,
    /// The points in world space, in authored order.
    pub positions: Vec<[f64; 3]>,
    /// Transmittance toward the light, one per point.
    pub transmittance: Vec<f64>,
    /// Error bar of each answer (0 for deterministic estimators; toward a light with extent
    /// the replicates' error bar, docs/lights.md).
    pub std_err: Vec<f64>,
    /// Toward a light with extent: how many points were sampled (the others' whole cone
    /// provably misses every volume, `T = 1` without sampling); `None` toward a point.
    pub sampled: Option<usize>,
}

/// Every frame's answers toward one light.
#[derive(Debug, Clone, PartialEq)]
pub struct PointAnswers {
    /// The points prim.
    pub prim: String,
    /// `Points` or `PointInstancer`.
    pub type_name: String,
    /// The light's prim path.
    pub light: String,
    /// The light's prim name (the primvar's suffix).
    pub light_name: String,
    /// The frames, in the order asked.
    pub frames: Vec<PointFrame>,
    /// Things the caller should say (a point count that changes between frames).
    pub warnings: Vec<String>,
    /// Toward a light with extent: the directions traced per sampled point; `None` toward a
    /// point.
    pub light_samples: Option<u32>,
}

/// What to answer: the points prim of a stage, toward which light, at which frames.
#[derive(Debug, Clone, Copy)]
pub struct PointQuery<'a> {
    /// The USD stage.
    pub stage: &'a Path,
    /// The `Points` or `PointInstancer` prim.
    pub prim: &'a str,
    /// The stage light (a prim path or a name); the stage's only light when `None`.
    pub light: Option<&'a str>,
    /// The time codes, answered in this order.
    pub frames: &'a [f64],
    /// The keys of a light with extent for the stage light
    /// ([`crate::light::LightOptions::soft_of_stage`]: an angle for a distant light, a radius
    /// for a light at a position, over the stage's own extent; without them the stage light's
    /// own extent); zero extent traces each point's ray toward the light as a point, bit for
    /// bit.
    pub extent: &'a crate::light::LightOptions,
}

/// Answer every point of `q.prim` toward `q.light` at each of `q.frames`. `source` is the stage with its
/// read options (grid, density scale, sigma, field; its frame and light are set per frame); `on_frame` is called after each
/// frame (progress).
///
/// # Errors
/// [`Error::Stage`] for a prim or light the stage does not have or a prim of another type;
/// [`Error::InvalidArgument`] (name `frames`) for no frames; a light with shadows disabled is
/// refused as for a query; an RGB stage (a colour `umbra:sigmaT`) is refused (the answers are
/// grey); any error of loading or estimating a frame.
pub fn point_transmittance(
    q: &PointQuery<'_>,
    source: &Source,
    est: &Estimator,
    opts: &Options,
    on_frame: &mut dyn FnMut(&PointFrame),
) -> Result<PointAnswers> {
    let PointQuery {
        stage,
        prim,
        light,
        frames,
        extent,
    } = *q;
    if frames.is_empty() {
        return Err(Error::InvalidArgument {
            name: "frames".into(),
            reason: "no frames to answer".into(),
        });
    }
    let mut out: Option<PointAnswers> = None;
    for &t in frames {
        let points = crate::usd::points_at(stage, prim, Some(t))?;
        let shot = crate::usd::lights_at(stage, Some(t))?;
        let (l, emitter) = shot.light(light)?;
        let lamp = Light::from(emitter);
        let mut so = source.clone();
        so.options_mut().frame = Some(t);
        // Toward the light: only the volumes its shadow link includes.
        so.options_mut().light = Some(l.prim.clone());
        let sc = so.load()?;
        if sc.channels() != 1 {
            return Err(Error::Stage {
                path: stage.to_path_buf(),
                reason: format!(
                    "at time {t}: per-point answers are grey, and this stage's volumes are RGB \
                     (a colour umbra:sigmaT)"
                ),
            });
        }
        let soft = extent.soft_of_stage(emitter)?;
        let at_point = |i: usize, p: &[f64; 3], e: Error| Error::Stage {
            path: stage.to_path_buf(),
            reason: format!(
                "at time {t}: {prim}: point {i} {}: {e}",
                crate::math::short3(*p)
            ),
        };
        let (transmittance, std_err, sampled) = match &soft {
            Some(s) => soft_answers(&sc, s, &points.positions, (est, opts), at_point)?,
            None => hard_answers(&sc, lamp, &points.positions, (est, opts), at_point)?,
        };
        let frame = PointFrame {
            frame: t,
            positions: points.positions,
            transmittance,
            std_err,
            sampled,
        };
        on_frame(&frame);
        let all = out.get_or_insert_with(|| PointAnswers {
            prim: points.prim.clone(),
            type_name: points.type_name.clone(),
            light: l.prim.clone(),
            light_name: l.name().to_string(),
            frames: Vec::new(),
            warnings: Vec::new(),
            light_samples: soft.map(|s| s.samples),
        });
        if let Some(prev) = all.frames.last() {
            if prev.positions.len() != frame.positions.len() {
                all.warnings.push(format!(
                    "{prim} has {} points at frame {} and {} at frame {t}: each frame is \
                     answered as authored",
                    prev.positions.len(),
                    prev.frame,
                    frame.positions.len()
                ));
            }
        }
        all.frames.push(frame);
    }
    out.ok_or_else(|| Error::InvalidArgument {
        name: "frames".into(),
        reason: "no frames to answer".into(),
    })
}

/// A frame's answers, error bars and sampled count.
type Answered = (Vec<f64>, Vec<f64>, Option<usize>);

/// Every point toward the light as a point: point `i` along its ray with ray id `i`.
fn hard_answers(
    sc: &crate::scene::Scene,
    lamp: Light,
    positions: &[[f64; 3]],
    (est, opts): (&Estimator, &Options),
    at_point: impl Fn(usize, &[f64; 3], Error) -> Error,
) -> Result<Answered> {
    let rays = positions
        .iter()
        .enumerate()
        .map(|(i, p)| lamp.ray_from_scene(sc, *p).map_err(|e| at_point(i, p, e)))
        .collect::<Result<Vec<_>>>()?;
    let ids: Vec<u64> = (0..rays.len() as u64).collect();
    let answers = crate::scene::estimate_many(sc, &rays, &ids, est, opts)
        .into_iter()
        .collect::<Result<Vec<_>>>()?;
    Ok((
        answers.iter().map(|a| a.value[0]).collect(),
        answers.iter().map(|a| a.std_err[0]).collect(),
        None,
    ))
}

/// Every point toward a light with extent ([`SoftLight::answer_many`]): point `i` with ray id
/// `i`, so its answer is `query --at` at that point with `--ray-id i`, bit for bit. The work
/// budget is checked up front ([`SoftLight::check_budget`]).
fn soft_answers(
    sc: &crate::scene::Scene,
    soft: &SoftLight,
    positions: &[[f64; 3]],
    (est, opts): (&Estimator, &Options),
    at_point: impl Fn(usize, &[f64; 3], Error) -> Error,
) -> Result<Answered> {
    soft.check_budget(sc, positions.len() as u64, est, opts)?;
    let (mut t, mut err, mut sampled) = (Vec::new(), Vec::new(), 0);
    for (i, (a, p)) in soft
        .answer_many(sc, positions, 0, est, opts)
        .into_iter()
        .zip(positions)
        .enumerate()
    {
        let a = a.map_err(|e| at_point(i, p, e))?;
        t.push(a.estimate.value[0]);
        err.push(a.estimate.std_err[0]);
        sampled += usize::from(a.light_samples > 0);
    }
    Ok((t, err, Some(sampled)))
}

/// The `.usda` layer of `answers`: an `over` on the points prim holding `float[]
/// primvars:umbra:transmittance:<light name>` (interpolation `vertex`), one time sample per
/// frame, and toward a light with extent `primvars:umbra:transmittance_std_err:<light name>`
/// beside it, each point's error bar ([`crate::usd::points_layer`]).
///
/// # Errors
/// As [`crate::usd::points_layer`].
pub fn layer_text(answers: &PointAnswers) -> Result<String> {
    let arrays = |of: fn(&PointFrame) -> &Vec<f64>| -> Vec<(f64, Vec<f32>)> {
        answers
            .frames
            .iter()
            .map(|f| (f.frame, of(f).iter().map(|&v| v as f32).collect()))
            .collect()
    };
    let samples = arrays(|f| &f.transmittance);
    let errors = answers.light_samples.map(|_| arrays(|f| &f.std_err));
    crate::usd::points_layer(
        &answers.prim,
        &answers.light_name,
        &samples,
        errors.as_deref(),
    )
}
