//! Deep maps at a fixed size per texel (`bake --deep-format`): every pixel's transmittance
//! function encoded by a [`DeepFormat`] into a fixed number of f32 channels of a flat OpenEXR
//! map (see `bake/encode/fixed/` for the formats and the error bound).
//!
//! **Source.** The profile a texel is built from is the deep map's
//! ([`crate::bake::bake_deep`]): exact with regular tracking (piecewise linear within
//! [`PROFILE_ERROR`] in T of the exact `tau(t)`), else the estimator's own deep function from
//! its 64 slices. A colour map encodes each of R, G, B on its own.
//!
//! **Error.** Two passes. The first encodes every texel and bounds its error on a coarse grid
//! (`texel_error` without refinement), giving the largest error seen at any evaluated depth,
//! `G`. The second revisits only the texels whose coarse bound exceeds `1.01 G + 1e-6` and
//! refines their intervals until each bound is below that threshold. So the reported
//! `umbra:deep_max_error` is an upper bound on `sup |T_rec - T_prof|` over every texel and
//! depth, within 1 % of the true supremum, plus [`PROFILE_ERROR`] for exact maps (the profile
//! against the exact `T`). `umbra:deep_rms_error` is the root mean square of the error at 65
//! uniform depths of every texel (and colour channel) whose ray meets extinction.

use super::deep_map::{pixel_profile, PROFILE_SHARE};
use crate::bake::encode::fixed::{texel_error, DeepFormat, NormProfile, ERROR_GRID};
use crate::bake::trace::in_pool;
use crate::bake::{Map, STOCHASTIC_DEPTHS};
use crate::error::{Error, Result};
use crate::estimate::Estimator;
use crate::scene::Scene;
use exr::meta::attribute::{AttributeValue, Text};
use rayon::prelude::*;

/// The bound in T on an exact profile a fixed-size texel is built from: well below every
/// format's own error (1e-2 and more at the sizes offered), so finer would only cost time (the
/// profile's breakpoints drive every encoder's cost; 1e-4 took 3-7x longer for the same RMS).
pub const PROFILE_ERROR: f64 = 1e-3;

/// What a fixed-size deep map holds and what it cost.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FixedStats {
    /// The format, as `--deep-format` spells it.
    pub format: String,
    /// f32 channels per texel (all colour channels; the flat `T` or `R`, `G`, `B` not counted).
    pub channels: usize,
    /// Bytes per texel of those channels.
    pub bytes_per_texel: usize,
    /// Upper bound on `|T_rec(z) - T(z)|` over every texel and depth (module docs).
    pub max_error: f64,
    /// RMS of the error over 65 uniform depths of every texel (and colour channel) whose ray
    /// meets extinction.
    pub rms_error: f64,
    /// The part of `max_error` that is the profile's own bound (0 for a stochastic map).
    pub profile_error: f64,
    /// The depth range `[near, far]` the texels' depth is normalised to.
    pub near: f64,
    /// See `near`.
    pub far: f64,
    /// Texels the second pass refined.
    pub refined_texels: u64,
    /// Wall time of the deep pass, seconds.
    pub seconds: f64,
}

/// A baked fixed-size deep map: its channels (name, one value per pixel) and counts.
#[derive(Debug)]
pub struct FixedMap {
    /// The format.
    pub format: DeepFormat,
    /// The channels, named `deep.<name>` (grey) or `deepR.<name>`, ... (colour).
    pub planes: Vec<(String, Vec<f32>)>,
    /// Counts and cost.
    pub stats: FixedStats,
}

/// Layer names of the channels of a map with `channels` colours.
fn layers(channels: usize) -> &'static [&'static str] {
    if channels == 3 {
        &["deepR", "deepG", "deepB"]
    } else {
        &["deep"]
    }
}

/// One row's texels: per colour channel and format channel, the values; per pixel the coarse
/// bound; the largest error seen and the squared errors.
struct Row {
    values: Vec<Vec<f32>>,
    coarse: Vec<f64>,
    seen: f64,
    sum_sq: f64,
    lit: u64,
}

/// The progress units [`bake_fixed`] reports for a map of `pixels` pixels: one per texel of
/// the first pass, and an eighth of that for the second (which revisits the flagged texels:
/// from none to a third of them, each costing about what it did in the first pass).
pub(crate) fn fixed_units(pixels: u64) -> u64 {
    pixels + pixels / 8
}

/// The fixed-size deep map of `scene` seen by `flat`'s camera in `format` (`flat` as for
/// [`crate::bake::bake_deep`]). `progress` gets `fixed_units` in all: a texel per texel of
/// the first pass, then the second pass's share as its flagged texels finish.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `deep`) for a stochastic map without its slices; tracing
/// errors of a pixel.
pub fn bake_fixed(
    scene: &Scene,
    flat: &Map,
    format: DeepFormat,
    progress: &dyn crate::progress::Progress,
) -> Result<FixedMap> {
    let start = std::time::Instant::now();
    let exact = flat.settings.estimator == Estimator::REGULAR;
    if !exact && flat.slices.len() != STOCHASTIC_DEPTHS {
        return Err(Error::InvalidArgument {
            name: "deep".into(),
            reason: format!(
                "a {} deep map is built from {STOCHASTIC_DEPTHS} depth slices; the map has {}",
                flat.settings.estimator.name(),
                flat.slices.len()
            ),
        });
    }
    let camera = &flat.camera;
    let texels = Texels {
        scene,
        flat,
        range: (camera.t_near().max(0.0), camera.t_max()),
        format,
        per: format.channels(),
    };
    let rows = in_pool(flat.settings.threads, || {
        texels.first_pass(&|n| progress.advance(n))
    })?;
    let coarse = Coarse::join(rows, camera.pixels() as usize, flat.channels() * texels.per);
    let threshold = 1.01 * coarse.seen + 1e-6;
    // Second pass: the texels whose coarse bound is above the threshold, refined.
    let flagged: Vec<usize> = (0..coarse.bound.len())
        .filter(|&p| coarse.bound[p] > threshold)
        .collect();
    let refined = in_pool(flat.settings.threads, || {
        texels.refine(&coarse.values, &flagged, threshold, &|n| {
            progress.advance(n)
        })
    })?;
    let unflagged = coarse
        .bound
        .iter()
        .filter(|&&b| b <= threshold)
        .fold(0.0f64, |a, &b| a.max(b));
    let fitted = refined
        .iter()
        .fold(coarse.seen.max(unflagged), |a, &b| a.max(b));
    let profile_error = if exact { PROFILE_ERROR } else { 0.0 };
    let samples = coarse.lit as f64 * (ERROR_GRID + 1) as f64;
    let colours = flat.channels();
    let per = texels.per;
    Ok(FixedMap {
        format,
        planes: planes(coarse.values, format, colours),
        stats: FixedStats {
            format: format.to_string(),
            channels: colours * per,
            bytes_per_texel: 4 * colours * per,
            max_error: (fitted + profile_error).min(1.0),
            rms_error: (coarse.sum_sq / samples.max(1.0)).sqrt(),
            profile_error,
            near: texels.range.0,
            far: texels.range.1,
            refined_texels: flagged.len() as u64,
            seconds: start.elapsed().as_secs_f64(),
        },
    })
}

/// What a fixed-size map's texels are made from: the scene, the flat map (camera, settings,
/// slices), the depth range `[near, far]` their depth is normalised to, and the format with its
/// `per` channels.
struct Texels<'a> {
    scene: &'a Scene,
    flat: &'a Map,
    range: (f64, f64),
    format: DeepFormat,
    per: usize,
}

impl Texels<'_> {
    /// Texel `(i, j)`'s normalised profiles, one per colour channel (each within
    /// [`PROFILE_ERROR`] of the exact one, for an exact map).
    fn profiles(&self, i: u32, j: u32) -> Result<Vec<NormProfile>> {
        let prof = pixel_profile(self.scene, self.flat, (i, j), PROFILE_ERROR / PROFILE_SHARE)?;
        prof.taus
            .iter()
            .map(|tau| NormProfile::new(&prof.t, tau, prof.opaque_at, self.range))
            .collect()
    }

    /// The first pass (module docs): every texel encoded and its error bounded on the coarse
    /// grid, row by row on all threads; `progress` gets each row's texels.
    fn first_pass(&self, progress: &(impl Fn(u64) + Sync)) -> Result<Vec<Row>> {
        let camera = &self.flat.camera;
        let (w, h) = (camera.width(), camera.height());
        let colours = self.flat.channels();
        (0..h)
            .into_par_iter()
            .map(|j| {
                let mut row = Row {
                    values: vec![Vec::with_capacity(w as usize); colours * self.per],
                    coarse: Vec::with_capacity(w as usize),
                    seen: 0.0,
                    sum_sq: 0.0,
                    lit: 0,
                };
                for i in 0..w {
                    let mut bound = 0.0f64;
                    for (c, p) in self.profiles(i, j)?.iter().enumerate() {
                        let v = self.format.encode(p);
                        let e = texel_error(self.format, &v, p, f64::INFINITY);
                        bound = bound.max(e.bound);
                        row.seen = row.seen.max(e.seen);
                        if p.total() > 0.0 {
                            row.sum_sq += e.sum_sq;
                            row.lit += 1;
                        }
                        for (k, x) in v.into_iter().enumerate() {
                            row.values[c * self.per + k].push(x);
                        }
                    }
                    row.coarse.push(bound);
                }
                progress(u64::from(w));
                Ok(row)
            })
            .collect::<Result<Vec<Row>>>()
    }

    /// The second pass (module docs): the `flagged` texels (pixel indices) refined until their
    /// bound is below `threshold`, given every texel's encoded `values`; their bounds.
    /// `progress` gets the second pass's [`fixed_units`] share as they finish (all of it at
    /// once when none is flagged).
    fn refine(
        &self,
        values: &[Vec<f32>],
        flagged: &[usize],
        threshold: f64,
        progress: &(impl Fn(u64) + Sync),
    ) -> Result<Vec<f64>> {
        let camera = &self.flat.camera;
        let (w, per) = (camera.width(), self.per);
        // The second pass's units: flagged texel q completes floor((q + 1) U / F) in all.
        let units = fixed_units(camera.pixels()) - camera.pixels();
        if flagged.is_empty() {
            progress(units);
        }
        let share =
            |q: usize| (u128::from(units) * q as u128 / flagged.len().max(1) as u128) as u64;
        flagged
            .par_iter()
            .enumerate()
            .map(|(q, &p)| {
                progress(share(q + 1) - share(q));
                let (i, j) = ((p % w as usize) as u32, (p / w as usize) as u32);
                let mut bound = 0.0f64;
                for (c, prof) in self.profiles(i, j)?.iter().enumerate() {
                    let v: Vec<f32> = (0..per).map(|k| values[c * per + k][p]).collect();
                    bound = bound.max(texel_error(self.format, &v, prof, threshold).bound);
                }
                Ok(bound)
            })
            .collect::<Result<Vec<f64>>>()
    }
}

/// The first pass's rows joined: per colour and format channel the values of every pixel, per
/// pixel its coarse bound; the largest error seen at any evaluated depth (`G`, module docs),
/// the squared errors and the texels whose ray meets extinction.
struct Coarse {
    values: Vec<Vec<f32>>,
    bound: Vec<f64>,
    seen: f64,
    sum_sq: f64,
    lit: u64,
}

impl Coarse {
    /// `rows` (of `pixels` texels in all, `channels` values each) joined in row order.
    fn join(rows: Vec<Row>, pixels: usize, channels: usize) -> Self {
        let seen = rows.iter().map(|r| r.seen).fold(0.0, f64::max);
        let sum_sq: f64 = rows.iter().map(|r| r.sum_sq).sum();
        let lit: u64 = rows.iter().map(|r| r.lit).sum();
        let mut values: Vec<Vec<f32>> = vec![Vec::with_capacity(pixels); channels];
        let mut bound = Vec::with_capacity(pixels);
        for r in rows {
            for (d, s) in values.iter_mut().zip(r.values) {
                d.extend(s);
            }
            bound.extend(r.coarse);
        }
        Self {
            values,
            bound,
            seen,
            sum_sq,
            lit,
        }
    }
}

/// The map's channels, named `deep.<name>` (grey) or `deepR.<name>`, ... (colour), from each
/// colour and format channel's `values`.
fn planes(values: Vec<Vec<f32>>, format: DeepFormat, colours: usize) -> Vec<(String, Vec<f32>)> {
    let per = format.channels();
    let names = format.channel_names();
    values
        .into_iter()
        .enumerate()
        .map(|(n, v)| {
            (
                format!("{}.{}", layers(colours)[n / per], names[n % per]),
                v,
            )
        })
        .collect()
}

/// The header attributes of a fixed-size deep map (`bake --deep-format`): its format, the
/// bound on its error in T over every texel and depth (rounded up to a float), its RMS error,
/// the profile's share of the bound, and the depth range the texels' depth is normalised to.
pub(crate) fn fixed_attributes(s: &FixedStats) -> Vec<(String, AttributeValue)> {
    vec![
        (
            "umbra:deep_format".into(),
            AttributeValue::Text(Text::from(s.format.as_str())),
        ),
        (
            "umbra:deep_max_error".into(),
            AttributeValue::F32(crate::bake::encode::fixed::f32_up(s.max_error)),
        ),
        (
            "umbra:deep_rms_error".into(),
            AttributeValue::F32(s.rms_error as f32),
        ),
        (
            "umbra:deep_profile_error".into(),
            AttributeValue::F32(s.profile_error as f32),
        ),
        ("umbra:deep_near".into(), AttributeValue::F64(s.near)),
        ("umbra:deep_far".into(), AttributeValue::F64(s.far)),
    ]
}
