//! Exact maps of scenes: optical depth is additive across volumes, so each fog volume's exact
//! `tau` image is made the way a single grid's is (the sweep in object order when it applies,
//! otherwise one regular-tracking ray per pixel) and added per channel,
//! `tau_c = sum_k sigma_{k,c} tau_k`; then one exponential per channel and pixel. Solids cut
//! each pixel's ray at its first hit: `T = 0` for the map and for every slice at or past it.

use crate::bake::camera::Camera;
use crate::bake::map::{BakeSettings, BakeStats, Channel, Map, Order};
use crate::error::{Error, Result};
use crate::math::scaled;
use crate::scene::Scene;
use crate::volume::{Interp, Volume};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Progress over several passes of the whole image, reported as whole-image pixels.
struct Passes<'a> {
    inner: &'a dyn crate::progress::Progress,
    passes: u64,
    done: AtomicU64,
}

impl Passes<'_> {
    fn add(&self, n: u64) {
        let before = self.done.fetch_add(n, Ordering::Relaxed);
        let step = before / self.passes.max(1);
        let after = (before + n) / self.passes.max(1);
        if after > step {
            self.inner.advance(after - step);
        }
    }
}

/// One volume's exact optical depth per pixel by regular tracking along each pixel's ray
/// (`tau[n (1 + K) + s]` as [`crate::bake::trace::sweep::tau_image`]), and the lookups it cost.
fn ray_tau(
    vol: &Volume,
    camera: &Camera,
    depths: &[f64],
    interp: Interp,
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<(Vec<f64>, u64)> {
    let (w, stride) = (camera.width as usize, 1 + depths.len());
    let mut tau = vec![0.0f64; camera.pixels() as usize * stride];
    let lookups = tau
        .par_chunks_mut(rows as usize * w * stride)
        .enumerate()
        .map(|(b, band)| {
            let y0 = b as u32 * rows;
            let mut lookups = 0;
            for (n, px) in band.chunks_mut(stride).enumerate() {
                let (i, j) = ((n % w) as u32, y0 + (n / w) as u32);
                let ray = camera.pixel_ray(i, j)?;
                let od = crate::regular::optical_depth(vol, &ray, interp)?;
                px[0] = od.tau;
                lookups += od.lookups;
                let (mut acc, mut t0) = (0.0, 0.0);
                for (k, &d) in depths.iter().enumerate() {
                    let od = crate::regular::optical_depth(vol, &ray.with_range(t0, d)?, interp)?;
                    acc += od.tau;
                    lookups += od.lookups;
                    px[1 + k] = acc;
                    t0 = d;
                }
            }
            progress.advance((band.len() / stride) as u64);
            Ok(lookups)
        })
        .collect::<Result<Vec<u64>>>()?
        .iter()
        .sum();
    Ok((tau, lookups))
}

/// The first solid hit along every pixel's ray (`inf` where none).
fn hits(
    scene: &Scene,
    camera: &Camera,
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Vec<f64>> {
    let w = camera.width as usize;
    let mut out = vec![f64::INFINITY; camera.pixels() as usize];
    out.par_chunks_mut(rows as usize * w)
        .enumerate()
        .try_for_each(|(b, band)| {
            let y0 = b as u32 * rows;
            for (n, h) in band.iter_mut().enumerate() {
                let ray = camera.pixel_ray((n % w) as u32, y0 + (n / w) as u32)?;
                for s in scene.solids() {
                    if let Some(t) = s.first_hit(&ray) {
                        *h = h.min(t);
                    }
                }
            }
            progress.advance(band.len() as u64);
            Ok::<(), Error>(())
        })?;
    Ok(out)
}

/// The exact map of `scene` (see the module docs).
///
/// # Errors
/// Ray, estimator and NaN errors of any pixel.
pub(crate) fn exact(
    scene: &Scene,
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    let start = std::time::Instant::now();
    let npix = camera.pixels() as usize;
    let (stride, nc) = (1 + depths.len(), scene.channels());
    let passes = Passes {
        inner: progress,
        passes: (scene.fogs().len() + usize::from(!scene.solids().is_empty())) as u64,
        done: AtomicU64::new(0),
    };
    let report = |n: u64| passes.add(n);
    let interp = s.options.interp;
    let mut tau = vec![vec![0.0f64; npix * stride]; nc];
    let (mut lookups, mut swept) = (0, true);
    for fog in scene.fogs() {
        let vol = fog.volume();
        let sweep = if s.order == Order::Auto && interp == Interp::Trilinear {
            crate::bake::trace::sweep::tau_image(vol, camera, depths, rows, &report)?
        } else {
            None
        };
        let (t, l) = match sweep {
            Some(r) => r,
            None => {
                swept = false;
                ray_tau(vol, camera, depths, interp, rows, &report)?
            }
        };
        lookups += l;
        for (c, acc) in tau.iter_mut().enumerate() {
            let sigma = fog.sigma()[c];
            acc.iter_mut()
                .zip(&t)
                .for_each(|(a, x)| *a += scaled(sigma, *x));
        }
    }
    let hit = if scene.solids().is_empty() {
        Vec::new()
    } else {
        hits(scene, camera, rows, &report)?
    };
    if let Some(n) = tau.iter().flat_map(|t| t.iter()).position(|x| x.is_nan()) {
        let n = (n % (npix * stride)) / stride;
        let ray = camera.pixel_ray(
            (n % camera.width as usize) as u32,
            (n / camera.width as usize) as u32,
        )?;
        return Err(crate::error::Error::nan_on_ray("optical depth", &ray));
    }
    let chans = tau.iter().map(|t| {
        let value = |n: usize, k: usize| -> f32 {
            // Slice k (0 = the whole ray, t_max) ends at this depth.
            let end = if k == 0 { f64::INFINITY } else { depths[k - 1] };
            match hit.get(n) {
                Some(&h) if h.is_finite() && h <= end => 0.0,
                _ => (-t[n * stride + k]).exp() as f32,
            }
        };
        Channel {
            t: (0..npix).map(|n| value(n, 0)).collect(),
            std_err: s.std_err.then(|| vec![0.0; npix]),
            slices: (1..stride)
                .map(|k| (0..npix).map(|n| value(n, k)).collect())
                .collect(),
        }
    });
    let (red, color) = crate::bake::map::split_channels(chans.collect());
    Ok(Map {
        camera: *camera,
        settings: s.clone(),
        t: red.t,
        std_err: red.std_err,
        depths: depths.to_vec(),
        slices: red.slices,
        color,
        stats: BakeStats {
            rays: npix as u64,
            samples: npix as u64,
            lookups,
            seconds: start.elapsed().as_secs_f64(),
            sweep: swept && !scene.fogs().is_empty(),
            ..BakeStats::default()
        },
    })
}
