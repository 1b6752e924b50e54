//! Deep shadow maps (Lokovic and Veach 2000): per pixel, the whole transmittance function
//! along the pixel's ray as OpenEXR volumetric deep samples (see `bake/encode/deep_fit.rs` for how
//! a sample describes `T(z)`, `bake/encode/deep_exr.rs` for the file).
//!
//! **Channels.** A grey map has `A`, `Z`, `ZBack`; a colour map (`--sigma-t`, RGB scenes) has
//! `AR`, `AG`, `AB` (each colour's alpha, `1 - exp(-(tau_c(ZBack) - tau_c(Z)))`: OpenEXR's
//! standard names for per-channel opacity; `R`, `G`, `B` are premultiplied colours to every
//! deep reader, which would composite them with `A`) and `A` (the alpha of the mean optical
//! depth `(tau_R + tau_G + tau_B) / 3`), all fitted together.
//! `Z`/`ZBack` are world distances `t` along the pixel's ray ([`crate::bake::Camera::pixel_ray`]),
//! samples sorted and non-overlapping; an opaque voxel or a solid adds one point sample
//! (`Z = ZBack`, alpha 1) where the ray meets it. Pixels whose ray meets no extinction have no
//! samples.
//!
//! **Error.** With regular tracking the function is the exact one: the optical-depth profile
//! of [`crate::regular::optical_depth_profile`] (piecewise linear within `E / 4` in T of the
//! exact `tau(t)`) fitted by [`crate::bake::fit_spans`] within `E / 2`, so the samples' `T(z)`
//! is within `3E / 4` of the exact prefix transmittance at every depth `z`; the last `E / 4`
//! is the room left for the file's f32 depths and alphas. Stochastic estimators give the
//! deep function of their estimate: `T` estimated at [`STOCHASTIC_DEPTHS`] depths evenly
//! spaced across the volume's depth range (the map's slices: ray ids `(64 + k) W H + p`;
//! `T = 1` up to the start of that range, where no ray has met the volume box yet),
//! made non-increasing (a running minimum, clamped to `[0, 1]`), linear in optical depth
//! between them, fitted within `E / 2`.

use crate::bake::encode::deep_exr::{DeepAttributes, DeepImage};
use crate::bake::encode::deep_fit::{check_deep_error, fit_spans, linear_at, samples_tau};
use crate::bake::encode::exr::{m44f, umbra_attributes};
use crate::bake::trace::in_pool;
use crate::bake::{Map, Provenance, MAX_SLICES};
use crate::error::{Error, Result};
use crate::estimate::Estimator;
use crate::ray::Ray;
use crate::regular::{optical_depth_profile, optical_depth_profile_tau};
use crate::scene::Scene;
use exr::meta::attribute::{AttributeValue, Text};
use rayon::prelude::*;

/// Depths at which a stochastic estimator's deep function is estimated.
pub const STOCHASTIC_DEPTHS: usize = MAX_SLICES;
/// Share of the error bound the piecewise-linear profile may use.
pub(crate) const PROFILE_SHARE: f64 = 0.25;
/// Share of the error bound the fit may use.
const FIT_SHARE: f64 = 0.5;

/// What a deep map holds and cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct DeepStats {
    /// The bound `E` on `|T_deep(z) - T(z)|`.
    pub max_error: f64,
    /// Pixels.
    pub pixels: u64,
    /// Pixels without samples (their rays meet no extinction).
    pub empty_pixels: u64,
    /// Deep samples of all pixels.
    pub samples: u64,
    /// The most samples of one pixel.
    pub max_samples: u32,
    /// Breakpoints of the profiles the samples were fitted to (what `--depths` would need
    /// per pixel to describe the same function piecewise linearly).
    pub breakpoints: u64,
    /// Trilinear cells whose profile was cut into the most pieces allowed, where the bound
    /// does not hold (0 in every case we know of).
    pub coarse_cells: u64,
    /// RMS of `T_deep - T_profile` at 65 uniform depths of the map's depth range, over every
    /// pixel (and colour channel) whose ray meets extinction: what `compare --deep` sets
    /// against the fixed-size formats' `rms_error`.
    pub rms_error: f64,
    /// Wall time of the deep pass, seconds.
    pub seconds: f64,
}

impl DeepStats {
    /// Mean samples per pixel.
    #[must_use]
    pub fn mean_samples(&self) -> f64 {
        self.samples as f64 / self.pixels.max(1) as f64
    }
}

/// A baked deep map.
#[derive(Debug)]
pub struct DeepMap {
    /// The samples, ready for [`crate::bake::write_deep_exr`].
    pub image: DeepImage,
    /// Counts and cost.
    pub stats: DeepStats,
}

/// One pixel's profile: depths, per-channel optical depths (`taus[c][k]`), where it turns
/// opaque.
pub(crate) struct PixelProfile {
    pub(crate) t: Vec<f64>,
    pub(crate) taus: Vec<Vec<f64>>,
    pub(crate) opaque_at: Option<f64>,
    coarse: u64,
}

/// Pixel `(i, j)`'s profile: exact (regular tracking, within `max_error / 4` in T) or the
/// stochastic map's slices.
pub(crate) fn pixel_profile(
    scene: &Scene,
    flat: &Map,
    (i, j): (u32, u32),
    max_error: f64,
) -> Result<PixelProfile> {
    if flat.settings.estimator == Estimator::REGULAR {
        exact_profile(scene, &flat.camera.pixel_ray(i, j)?, flat, max_error)
    } else {
        let p = u64::from(j) * u64::from(flat.camera.width()) + u64::from(i);
        Ok(estimated_profile(flat, p as usize))
    }
}

/// The deep map of `scene` seen by `flat`'s camera with `flat`'s settings. `flat` is the
/// map the same job baked; a stochastic estimator's map must hold [`STOCHASTIC_DEPTHS`]
/// slices (its deep function comes from them), an exact map's slices are not used.
/// `progress` gets finished pixel counts.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `deep-error`) for a bound outside `(0, 1)`, (name `deep`)
/// for a stochastic map without its slices; tracing errors of a pixel.
pub fn bake_deep(
    scene: &Scene,
    flat: &Map,
    max_error: f64,
    progress: &dyn crate::progress::Progress,
) -> Result<DeepMap> {
    check_deep_error(max_error)?;
    let start = std::time::Instant::now();
    let camera = &flat.camera;
    let settings = &flat.settings;
    let exact = settings.estimator == Estimator::REGULAR;
    if !exact && flat.slices.len() != STOCHASTIC_DEPTHS {
        return Err(Error::InvalidArgument {
            name: "deep".into(),
            reason: format!(
                "a {} deep map is fitted to {STOCHASTIC_DEPTHS} depth slices; the map has {}",
                settings.estimator.name(),
                flat.slices.len()
            ),
        });
    }
    check_depth_resolution(scene, camera)?;
    let colour = scene.channels() == 3;
    let (w, h) = (camera.width(), camera.height());
    let range = (camera.t_near().max(0.0), camera.t_max());
    let run = || {
        (0..h)
            .into_par_iter()
            .map(|j| {
                let mut row = Row::new(colour);
                for i in 0..w {
                    let prof = pixel_profile(scene, flat, (i, j), max_error)?;
                    row.push(&prof, max_error * FIT_SHARE, range)?;
                }
                progress.advance(u64::from(w));
                Ok(row)
            })
            .collect::<Result<Vec<Row>>>()
    };
    let rows = in_pool(settings.threads, run)?;
    let mut stats = DeepStats {
        max_error,
        pixels: camera.pixels(),
        ..DeepStats::default()
    };
    let names = channel_names(colour);
    let mut counts = Vec::with_capacity(camera.pixels() as usize);
    let mut data: Vec<Vec<f32>> = vec![Vec::new(); names.len()];
    let (mut sum_sq, mut lit) = (0.0, 0u64);
    for r in rows {
        sum_sq += r.sum_sq;
        lit += r.lit;
        stats.breakpoints += r.breakpoints;
        stats.coarse_cells += r.coarse;
        counts.extend_from_slice(&r.counts);
        for (d, c) in data.iter_mut().zip(r.data) {
            d.extend(c);
        }
    }
    stats.rms_error = (sum_sq / (lit as f64 * RMS_DEPTHS as f64).max(1.0)).sqrt();
    stats.samples = counts.iter().map(|&c| u64::from(c)).sum();
    stats.max_samples = counts.iter().copied().max().unwrap_or(0);
    stats.empty_pixels = counts.iter().filter(|&&c| c == 0).count() as u64;
    let image = DeepImage::new(w, h, names, counts, data)?;
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(DeepMap { image, stats })
}

/// Channel names in the order [`Row`] fills them.
/// A deep map's depths are distances from the camera stored in f32: refused (naming `deep`)
/// when, where the centre ray leaves the scene's world box (longest side `L`), one f32 step of
/// depth (at most `t 2^-23` at depth `t`) is more than `L / 4096` (a light more than about 2048 box sizes away), so the depths
/// could not tell the volume's layers apart; a flat map, or a sun, is what such a light takes.
fn check_depth_resolution(scene: &Scene, camera: &crate::bake::camera::Camera) -> Result<()> {
    let Some((lo, hi)) = scene.world_box() else {
        return Ok(());
    };
    let size = (hi - lo).max_element();
    let centre = camera.pixel_ray(camera.width() / 2, camera.height() / 2)?;
    let Some((_, t1)) = crate::ray::clip_box(centre.origin(), centre.direction(), lo, hi) else {
        return Ok(());
    };
    // One f32 step at depth `t1` is at most `t1 2^-23`.
    let step = t1.abs() * f64::from(f32::EPSILON);
    if step > size / 4096.0 {
        return Err(Error::InvalidArgument {
            name: "deep".into(),
            reason: format!(
                "a deep map stores depths from the light in 32-bit floats: {} away from a \
                 volume {} across, one step of depth is {}, too coarse to tell its layers \
                 apart; bake a flat map, or use a sun (light-dir) for a light this far",
                crate::math::short(t1),
                crate::math::short(size),
                crate::math::short(step)
            ),
        });
    }
    Ok(())
}

fn channel_names(colour: bool) -> Vec<String> {
    let names: &[&str] = if colour {
        &["A", "AR", "AG", "AB", "Z", "ZBack"]
    } else {
        &["A", "Z", "ZBack"]
    };
    names.iter().map(|s| (*s).to_string()).collect()
}

/// One row's samples.
struct Row {
    colour: bool,
    counts: Vec<u32>,
    /// Per channel as [`channel_names`].
    data: Vec<Vec<f32>>,
    breakpoints: u64,
    coarse: u64,
    sum_sq: f64,
    lit: u64,
}

/// Uniform depths of the RMS error ([`DeepStats::rms_error`]).
const RMS_DEPTHS: usize = 65;

/// `tau` at `z` of deep samples `spans` (breakpoint pairs of `t`, `tau`).
fn fitted_tau(spans: &[(usize, usize)], t: &[f64], tau: &[f64], z: f64) -> f64 {
    samples_tau(spans.iter().map(|&(i, j)| (t[i], t[j], tau[i], tau[j])), z)
}

impl Row {
    fn new(colour: bool) -> Self {
        Self {
            colour,
            counts: Vec::new(),
            data: vec![Vec::new(); channel_names(colour).len()],
            breakpoints: 0,
            coarse: 0,
            sum_sq: 0.0,
            lit: 0,
        }
    }

    /// Fit `prof` and append its samples as the row's next pixel.
    fn push(&mut self, prof: &PixelProfile, fit_error: f64, (near, far): (f64, f64)) -> Result<()> {
        self.breakpoints += prof.t.len() as u64;
        self.coarse += prof.coarse;
        // The fitted channels: grey tau, or R, G, B and their mean (for A).
        let mean: Vec<f64>;
        let mut fitted: Vec<&[f64]> = prof.taus.iter().map(Vec::as_slice).collect();
        if self.colour {
            mean = (0..prof.t.len())
                .map(|k| prof.taus.iter().map(|c| c[k]).sum::<f64>() / 3.0)
                .collect();
            fitted.push(&mean);
        }
        let spans = fit_spans(&prof.t, &fitted, fit_error)?;
        // The RMS error at uniform depths, per colour channel (T = 0 past an opaque depth in
        // both the profile and the samples).
        for tau in &prof.taus {
            if tau.last().is_none_or(|&v| v <= 0.0) && prof.opaque_at.is_none() {
                continue;
            }
            self.lit += 1;
            for k in 0..RMS_DEPTHS {
                let z = near + (far - near) * k as f64 / (RMS_DEPTHS - 1) as f64;
                if prof.opaque_at.is_some_and(|o| z >= o) {
                    continue;
                }
                let e = (-linear_at(&prof.t, tau, z)).exp()
                    - (-fitted_tau(&spans, &prof.t, tau, z)).exp();
                self.sum_sq += e * e;
            }
        }
        let alpha = |tau: &[f64], i: usize, j: usize| -(-(tau[j] - tau[i])).exp_m1() as f32;
        let z = self.data.len() - 2;
        for &(i, j) in &spans {
            if self.colour {
                self.data[0].push(alpha(fitted[3], i, j));
                for (d, tau) in self.data[1..4].iter_mut().zip(&fitted[..3]) {
                    d.push(alpha(tau, i, j));
                }
            } else {
                self.data[0].push(alpha(fitted[0], i, j));
            }
            self.data[z].push(prof.t[i] as f32);
            self.data[z + 1].push(prof.t[j] as f32);
        }
        let mut n = spans.len();
        if let Some(o) = prof.opaque_at {
            for d in &mut self.data[..z] {
                d.push(1.0);
            }
            self.data[z].push(o as f32);
            self.data[z + 1].push(o as f32);
            n += 1;
        }
        self.counts.push(u32::try_from(n).unwrap_or(u32::MAX));
        Ok(())
    }
}

/// The exact profile of a pixel's ray through `scene`: one grey volume directly (bound in
/// T), several volumes or a colour map as `tau_c = sum_k sigma_k,c tau_k` on the union of
/// their breakpoints (each volume's bound in optical depth, shared so the sum stays within the
/// profile's share of `max_error`), cut at the first solid.
fn exact_profile(scene: &Scene, ray: &Ray, flat: &Map, max_error: f64) -> Result<PixelProfile> {
    let interp = flat.settings.options.interp;
    let e = max_error * PROFILE_SHARE;
    let hit = scene
        .solids()
        .iter()
        .filter_map(|s| s.first_hit(ray))
        .min_by(f64::total_cmp);
    if let (Some(vol), None) = (scene.single(), hit) {
        let p = optical_depth_profile(vol, ray, interp, e)?;
        return Ok(PixelProfile {
            t: p.t().to_vec(),
            taus: vec![p.tau().to_vec()],
            opaque_at: p.opaque_at(),
            coarse: p.coarse_cells(),
        });
    }
    let fogs = scene.fogs();
    let channels = scene.channels();
    let sigma_max = fogs
        .iter()
        .flat_map(|f| f.sigma()[..channels].to_vec())
        .fold(0.0f64, f64::max);
    let per_fog = e / (fogs.len().max(1) as f64 * sigma_max.max(f64::MIN_POSITIVE));
    let mut profiles = Vec::with_capacity(fogs.len());
    for f in fogs {
        if f.sigma()[..channels].iter().all(|&s| s == 0.0) {
            continue;
        }
        profiles.push((
            f.sigma(),
            optical_depth_profile_tau(f.volume(), ray, interp, per_fog)?,
        ));
    }
    let mut opaque_at = hit;
    for (_, p) in &profiles {
        if let Some(o) = p.opaque_at() {
            opaque_at = Some(opaque_at.map_or(o, |h| h.min(o)));
        }
    }
    let mut t: Vec<f64> = profiles.iter().flat_map(|(_, p)| p.t().to_vec()).collect();
    t.push(ray.t_min());
    if let Some(o) = opaque_at {
        t.retain(|&x| x <= o);
        t.push(o);
    }
    t.sort_by(f64::total_cmp);
    t.dedup();
    let taus = (0..channels)
        .map(|c| {
            t.iter()
                .map(|&x| {
                    profiles
                        .iter()
                        .map(|(s, p)| crate::math::scaled(s[c], p.at(x)))
                        .sum::<f64>()
                })
                .collect::<Vec<f64>>()
        })
        .collect::<Vec<_>>();
    // At the opaque depth itself the profiles read infinity; the samples end just before it.
    let mut taus = taus;
    if let Some(o) = opaque_at {
        if t.last() == Some(&o) {
            let before = t.len().checked_sub(2);
            for tau in &mut taus {
                if let (Some(b), Some(last)) = (before.map(|b| tau[b]), tau.last_mut()) {
                    if !last.is_finite() {
                        *last = b;
                    }
                }
            }
            if t.len() == 1 {
                for tau in &mut taus {
                    tau[0] = 0.0;
                }
            }
        }
    }
    Ok(PixelProfile {
        t,
        taus,
        opaque_at,
        coarse: profiles.iter().map(|(_, p)| p.coarse_cells()).sum(),
    })
}

/// A stochastic pixel's profile from its slices (module docs).
fn estimated_profile(flat: &Map, p: usize) -> PixelProfile {
    let channels = flat.channels();
    // No ray meets the volume box before t_near: T = 1 up to there.
    let start = flat.camera.t_near().max(0.0);
    let mut t = vec![if flat.depths.first().is_some_and(|&d| start < d) {
        start
    } else {
        0.0
    }];
    t.extend_from_slice(&flat.depths);
    let mut opaque_at = None;
    let mut taus = Vec::with_capacity(channels);
    let mut keep = t.len();
    for c in 0..channels {
        let slices = flat.channel(c).2;
        let mut tau = vec![0.0f64];
        let mut running = 1.0f64;
        for (k, s) in slices.iter().enumerate() {
            running = running.min(f64::from(s[p]).clamp(0.0, 1.0));
            if running <= 0.0 {
                // T = 0 from this depth on: opaque there.
                keep = keep.min(k + 1);
                opaque_at = Some(opaque_at.map_or(flat.depths[k], |o: f64| o.min(flat.depths[k])));
                break;
            }
            tau.push(-running.ln());
        }
        taus.push(tau);
    }
    t.truncate(keep);
    for tau in &mut taus {
        tau.truncate(keep);
    }
    PixelProfile {
        t,
        taus,
        opaque_at,
        coarse: 0,
    }
}

/// The deep file's header beyond the structure: the flat map's `umbra:*` attributes, the
/// OpenEXR camera matrices, and the deep fit's own.
#[must_use]
pub fn deep_attributes(flat: &Map, prov: &Provenance, stats: &DeepStats) -> DeepAttributes {
    let c = &flat.camera;
    let mut extra = match crate::bake::encode::exr::envmap(c.kind) {
        Some(e) => vec![("envmap".to_string(), AttributeValue::EnvironmentMap(e))],
        None => vec![
            (
                "worldToCamera".to_string(),
                AttributeValue::Matrix4x4(m44f(c.world_to_camera())),
            ),
            (
                "worldToNDC".to_string(),
                AttributeValue::Matrix4x4(m44f(c.world_to_ndc())),
            ),
        ],
    };
    extra.extend([
        (
            "software".to_string(),
            AttributeValue::Text(Text::from(concat!("umbra ", env!("CARGO_PKG_VERSION")))),
        ),
        (
            "comments".to_string(),
            AttributeValue::Text(Text::from(
                "deep transmittance: volumetric samples, Z and ZBack the world distance along \
                 each pixel's ray; see the umbra:* attributes",
            )),
        ),
        (
            "umbra:deep_error".to_string(),
            AttributeValue::F64(stats.max_error),
        ),
    ]);
    extra.extend(
        umbra_attributes(flat, prov)
            .into_iter()
            .filter(|(k, _)| !k.starts_with("umbra:depth.")),
    );
    DeepAttributes {
        part_name: "transmittance".into(),
        extra,
    }
}
