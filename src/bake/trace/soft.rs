//! Maps toward a light with extent (issue 60): each texel stores `T_L`, the mean
//! transmittance over the light at a receiver point on the texel's own ray (the hard map's
//! projector ray from the light's centre, [`Camera::pixel_ray`]), with the replicates' error
//! bar; each depth slice stores `T_L` at a receiver at its depth on the same ray.
//!
//! **The receiver** ([`Receiver`]): by default where the ray leaves the last volume or solid
//! box it crosses (a ray that meets no box: its end, `t_max`), or at `receiver-depth` along it.
//!
//! **The answer at a receiver** is exactly `umbra query --at X --ray-id P` toward the same
//! light ([`crate::light::SoftLight::answer_each`]): texel `p = j W + i` uses ray id `p`, slice `k`
//! ray id `(64 + k) W H + p`, as a hard map's pixels do, so a texel depends on the seed alone,
//! never on the thread count.
//!
//! **Receivers answered without sampling.** A receiver whose every direction provably meets no
//! density ([`Occupancy`]: the light's whole cone from it, [`crate::light::SoftLight::reach`],
//! misses every block that holds density, or the light's own box test found nothing) stores
//! `T = 1` with `std_err = 0`; under a target error one whose cone only grazes density stores
//! `T = 1` with its bound as the error bar ([`Occupancy::optical_bound`]). Neither is counted
//! in [`BakeStats::light_sampled`]; the second is counted in [`BakeStats::light_bounded`].
//!
//! **The count.** Each receiver's directions are [`crate::light::SoftLight::answer_each`]'s: a
//! fixed `light-samples`, or as many as `target-error` asks (default 5e-3), counted in
//! [`BakeStats::light_directions`].

use super::in_pool;
use crate::bake::camera::{Camera, MAX_PIXELS};
use crate::bake::map::LightDirections;
use crate::bake::map::{
    bad, split_channels, BakeSettings, BakeStats, Channel, Map, Receiver as Place, SoftMap,
};
use crate::error::Result;
use crate::light::{Occupancy, Receiver};
use crate::ray::Ray;
use crate::scene::{Scene, SceneEstimate};
use rayon::prelude::*;

/// Receivers answered per batch of rays, one batch per worker at a time: enough rays for the
/// SIMD batches (256 directions x 32 receivers = 8192 rays), few enough to hold.
const BLOCK: usize = 32;
/// Receivers per block under a target error: a pilot of 64 directions x 128 receivers = 8192
/// rays per batch.
const ADAPTIVE_BLOCK: usize = 128;

/// The soft map of `scene` seen by `camera` toward `soft` (module docs).
///
/// # Errors
/// Settings, resolution and work-budget errors (naming `light-samples` when the directions are
/// too much work); the first estimate that fails.
pub(crate) fn bake_soft(
    scene: &Scene,
    camera: &Camera,
    settings: &BakeSettings,
    soft: &SoftMap,
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    crate::bake::check_res(camera.width, camera.height)?;
    settings.validate()?;
    // A `target-error` is the light's (the plan put it there); with a fixed count it is
    // refused there, and here for a map made without a plan.
    let light = soft
        .light
        .with_target(settings.target_error, "target-error")?;
    let soft = &SoftMap {
        light,
        receiver: soft.receiver,
    };
    let depths = settings.depths.resolve(camera)?;
    let per_texel = 1 + depths.len();
    let channels = scene.channels();
    let planes = (per_texel as u64 + u64::from(settings.std_err)) * channels as u64;
    if camera.pixels() * planes > MAX_PIXELS {
        return Err(bad(
            "res",
            format!(
                "{}x{} with {planes} channels is more than {MAX_PIXELS} samples",
                camera.width, camera.height
            ),
        ));
    }
    let rays = camera.pixels() * per_texel as u64 * u64::from(soft.light.samples);
    for f in scene.fogs() {
        crate::estimate::budget::check_job(
            f.volume(),
            &settings.estimator,
            rays,
            u64::from(settings.options.samples),
            "light-samples",
        )?;
    }
    in_pool(settings.threads, || {
        render(scene, camera, settings, soft, &depths, progress)
    })
}

/// Where receiver `k` of a texel (0: the texel's own, `1 + s`: slice `s`) is on `ray`.
fn receiver_t(scene: &Scene, ray: &Ray, receiver: Place, depths: &[f64], k: usize) -> f64 {
    match (k, receiver) {
        (0, Place::Depth(d)) => d,
        (0, Place::BoxExit) => box_exit(scene, ray),
        (k, _) => depths[k - 1],
    }
}

/// Where `ray` leaves the last box (fog volumes: their index boxes; solids: the world box of
/// their corners) it crosses; its end when it meets none.
fn box_exit(scene: &Scene, ray: &Ray) -> f64 {
    scene
        .box_exit(ray.origin(), ray.direction())
        .unwrap_or(ray.t_max())
}

/// One receiver's answer, its directions and whether the target asked for more than the cap.
struct Answer {
    estimate: SceneEstimate,
    directions: usize,
    capped: bool,
}

/// Every receiver of the map, `BLOCK` at a time on every worker; then the images.
fn render(
    scene: &Scene,
    camera: &Camera,
    settings: &BakeSettings,
    soft: &SoftMap,
    depths: &[f64],
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    let start = std::time::Instant::now();
    let n = camera.pixels() as usize;
    let per_texel = 1 + depths.len();
    let occupancy = Occupancy::of(scene);
    let (est, opts) = (&settings.estimator, &settings.options);
    let w = camera.width as usize;
    // Receiver `r` of the map is texel `r % n`'s receiver `r / n` (slices after the map),
    // answered `block` at a time on every worker (each stage's rays of a block in one batch).
    let total = n * per_texel;
    let block = if soft.light.target.is_some() {
        ADAPTIVE_BLOCK
    } else {
        BLOCK
    };
    let done = std::sync::atomic::AtomicUsize::new(0);
    let make = |r: usize| -> Result<Option<Receiver>> {
        let (p, k) = (r % n, r / n);
        let ray = camera.pixel_ray((p % w) as u32, (p / w) as u32)?;
        let at = ray
            .at(receiver_t(scene, &ray, soft.receiver, depths, k))
            .to_array();
        let ray_id = if k == 0 { p } else { (63 + k) * n + p } as u64;
        Ok(Some(Receiver { at, ray_id }))
    };
    let blocks: Vec<Vec<Answer>> = (0..total.div_ceil(block))
        .into_par_iter()
        .map(|b| {
            let (r0, r1) = (b * block, ((b + 1) * block).min(total));
            let made: Vec<Option<Receiver>> = (r0..r1).map(make).collect::<Result<_>>()?;
            let answers = answer_block(scene, (&soft.light, &occupancy), &made, (est, opts))?;
            // Progress in whole texels' worth of receivers.
            let before = done.fetch_add(r1 - r0, std::sync::atomic::Ordering::Relaxed);
            progress.advance(((before + r1 - r0) / per_texel - before / per_texel) as u64);
            Ok(answers)
        })
        .collect::<Result<_>>()?;
    let answers: Vec<Answer> = blocks.into_iter().flatten().collect();
    Ok(assemble(
        camera,
        settings,
        depths,
        &answers,
        scene.channels(),
        start,
    ))
}

/// The answers of one block of receivers (`None`: provably unoccluded), each stage's rays in
/// one batch ([`crate::light::SoftLight::answer_each`]).
fn answer_block(
    scene: &Scene,
    (light, occupancy): (&crate::light::SoftLight, &Occupancy),
    made: &[Option<Receiver>],
    (est, opts): (&crate::estimate::Estimator, &crate::estimate::Options),
) -> Result<Vec<Answer>> {
    light
        .answer_each(scene, occupancy, made, est, opts)
        .into_iter()
        .map(|a| {
            Ok(match a {
                Some(a) => {
                    let a = a?;
                    Answer {
                        estimate: a.estimate,
                        directions: a.light_samples,
                        capped: a.light_capped,
                    }
                }
                None => Answer {
                    estimate: unsampled(scene.channels()),
                    directions: 0,
                    capped: false,
                },
            })
        })
        .collect()
}

fn unsampled(channels: usize) -> SceneEstimate {
    let mut e = SceneEstimate::exact(channels, [0.0; 3], 0, 0);
    e.tau = None;
    e.value = [1.0; 3];
    e
}

/// The map from every receiver's answer (`answers[k n + p]`: texel `p`'s receiver `k`).
fn assemble(
    camera: &Camera,
    settings: &BakeSettings,
    depths: &[f64],
    answers: &[Answer],
    channels: usize,
    start: std::time::Instant,
) -> Map {
    let n = camera.pixels() as usize;
    let image = |k: usize, c: usize, err: bool| -> Vec<f32> {
        answers[k * n..(k + 1) * n]
            .iter()
            .map(|a| {
                let e = &a.estimate;
                (if err { e.std_err[c] } else { e.value[c] }) as f32
            })
            .collect()
    };
    let chans: Vec<Channel> = (0..channels)
        .map(|c| Channel {
            t: image(0, c, false),
            std_err: settings.std_err.then(|| image(0, c, true)),
            slices: (1..=depths.len()).map(|k| image(k, c, false)).collect(),
        })
        .collect();
    let (red, color) = split_channels(chans);
    let mut stats = BakeStats {
        rays: n as u64,
        ..BakeStats::default()
    };
    for a in answers {
        let e = &a.estimate;
        stats.lookups += e.lookups;
        stats.capped += e.capped;
        stats.majorant_violations += e.majorant_violations;
        stats.max_std_err = e.std_err[..channels]
            .iter()
            .copied()
            .fold(stats.max_std_err, crate::bake::map::worse_std_err);
    }
    stats.samples = answers[..n]
        .iter()
        .map(|a| u64::from(a.estimate.samples.max(1)))
        .sum();
    stats.light_sampled = Some([
        answers.iter().filter(|a| a.directions > 0).count() as u64,
        answers.len() as u64,
    ]);
    stats.light_bounded = Some(
        answers
            .iter()
            .filter(|a| a.directions == 0 && a.estimate.std_err[0] > 0.0)
            .count() as u64,
    );
    stats.light_directions = Some(LightDirections::of(
        answers.iter().map(|a| (a.directions, a.capped)),
    ));
    stats.seconds = start.elapsed().as_secs_f64();
    Map {
        camera: *camera,
        settings: settings.clone(),
        t: red.t,
        std_err: red.std_err,
        depths: depths.to_vec(),
        slices: red.slices,
        color,
        stats,
    }
}
