//! Tracing a map: the parallel tile renderer (one estimate per pixel, plus adaptive batches and
//! depth slices) in this file, the exact sweep in object order (`sweep`) and the per-channel
//! bake of scenes (`scene`). Tracing makes a [`Map`] in memory; it reads no file and writes
//! none (encoding is `bake/encode`, orchestration `bake/product`).

pub(crate) mod scene;
mod soft;
pub(crate) mod sweep;

use crate::bake::camera::{Camera, MAX_PIXELS};
use crate::bake::map::{
    bad, split_channels, worse_std_err, BakeSettings, BakeStats, Channel, Map, Order, MAX_BATCHES,
};
use crate::error::Result;
use crate::estimate::{estimate, Estimate, Estimator, Options};
use crate::ray::Ray;
use crate::scene::{Scene, SceneEstimate};
use crate::volume::Volume;
use rayon::prelude::*;

/// Tile side in pixels: bands of up to `TILE` rows are the unit of parallel work, and each
/// band is traced `TILE` columns at a time (the unit of progress).
const TILE: u32 = 16;
/// What a map traces: one volume (every single-grid path) or a scene.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Source<'a> {
    Volume(&'a Volume),
    Scene(&'a Scene),
}

impl Source<'_> {
    fn estimate(
        &self,
        ray: &Ray,
        id: u64,
        est: &Estimator,
        opts: &Options,
    ) -> Result<SceneEstimate> {
        match self {
            Self::Volume(v) => {
                // A far camera's rays (a perspective map from a light 1e16 away) walk from
                // next to the volume, as a scene's do.
                let (ray, _) = Scene::localise(ray, Scene::volume_box(v));
                Ok(SceneEstimate::grey(&estimate(v, &ray, id, est, opts)?))
            }
            Self::Scene(s) => crate::scene::estimate(s, ray, id, est, opts),
        }
    }

    fn channels(&self) -> usize {
        match self {
            Self::Volume(_) => 1,
            Self::Scene(s) => s.channels(),
        }
    }
}

/// One pixel's results.
#[derive(Debug, Clone, Copy, Default)]
struct Px {
    t: [f64; 3],
    std_err: [f64; 3],
    samples: u64,
    lookups: u64,
    capped: u64,
    violations: u64,
    unconverged: bool,
}

impl Px {
    /// This pixel's share of the map statistics.
    fn stats(&self) -> BakeStats {
        BakeStats {
            samples: self.samples,
            lookups: self.lookups,
            capped: self.capped,
            majorant_violations: self.violations,
            max_std_err: self.std_err.iter().copied().fold(0.0, worse_std_err),
            unconverged: u64::from(self.unconverged),
            ..BakeStats::default()
        }
    }
}

impl BakeStats {
    /// Add the counts of `o` (pixels, bands) to these; `rays` and `seconds` are the caller's.
    pub(crate) fn absorb(&mut self, o: &BakeStats) {
        self.samples += o.samples;
        self.lookups += o.lookups;
        self.capped += o.capped;
        self.majorant_violations += o.majorant_violations;
        self.max_std_err = worse_std_err(self.max_std_err, o.max_std_err);
        self.unconverged += o.unconverged;
        self.declined = self.declined.or(o.declined);
    }
}

/// Merge two batches' means and squared-deviation sums (Chan et al.; the second batch's from
/// its sample standard error, without the error bar's floor).
fn merge(a: (f64, f64, u64), e: &Estimate) -> (f64, f64, u64) {
    let (mean, m2, n) = a;
    let nb = u64::from(e.samples);
    let se = e.spread.sample_std_err();
    let m2b = se * se * nb as f64 * nb.saturating_sub(1) as f64;
    let tot = n + nb;
    let delta = e.value - mean;
    (
        mean + delta * nb as f64 / tot as f64,
        m2 + m2b + delta * delta * (n as f64) * (nb as f64) / tot as f64,
        tot,
    )
}

/// One pixel: its estimate (adaptive batches included) and its slices
/// (`slices_out[k * channels + c]`).
fn pixel(
    src: Source<'_>,
    s: &BakeSettings,
    depths: &[f64],
    ray: &Ray,
    p: u64,
    npix: u64,
    slices_out: &mut [f32],
) -> Result<Px> {
    let nc = src.channels();
    let e = src.estimate(ray, p, &s.estimator, &s.options)?;
    let mut px = Px {
        t: e.value,
        std_err: e.std_err,
        samples: u64::from(e.samples),
        lookups: e.lookups,
        capped: e.capped,
        violations: e.majorant_violations,
        unconverged: false,
    };
    if let Some(target) = s.target_error {
        let mut acc = [(0.0, 0.0, 0); 3];
        let mut spread = e.spread;
        for (c, a) in acc.iter_mut().enumerate() {
            *a = merge(*a, &e.channel(c));
        }
        px.unconverged = e.samples > 1;
        let max = u64::from(s.max_spp);
        let mut b = 1u64;
        // Stop on sqrt(s^2 + (sqrt(3) / n)^2) <= E (the largest s of the channels): the second
        // term is the rule-of-three bound on what n samples that all missed a rare event can
        // hide (estimates in [0, 1]), so n samples that happen to agree (s = 0) do not stop a
        // pixel early.
        let err = |raw: &[f64; 3], n: u64| {
            raw[..nc]
                .iter()
                .fold(0.0f64, |m, s| m.max(s.hypot(3f64.sqrt() / n as f64)))
        };
        let mut raw = e.spread.map(|s| s.sample_std_err());
        while err(&raw, acc[0].2) > target
            && acc[0].2 < max
            && b < u64::from(MAX_BATCHES)
            && e.samples > 1
        {
            let batch = acc[0].2.min(max - acc[0].2);
            let opts = Options {
                samples: u32::try_from(batch).unwrap_or(u32::MAX),
                ..s.options
            };
            let eb = src.estimate(ray, b * npix + p, &s.estimator, &opts)?;
            for (c, a) in acc.iter_mut().enumerate() {
                *a = merge(*a, &eb.channel(c));
                px.t[c] = a.0;
                raw[c] = (a.1 / (a.2 - 1) as f64 / a.2 as f64).sqrt();
                spread[c].widen(&eb.spread[c]);
            }
            px.lookups += eb.lookups;
            px.capped += eb.capped;
            px.violations += eb.majorant_violations;
            px.samples = acc[0].2;
            b += 1;
        }
        px.unconverged &= err(&raw, acc[0].2) > target;
        // The reported error bar: the merged samples through the one error-bar function
        // (the first batch alone is the estimate's own).
        if b > 1 {
            for (c, sp) in spread.iter_mut().enumerate().take(nc) {
                (sp.n, sp.mean, sp.m2) = (acc[c].2, acc[c].0, acc[c].1);
                px.std_err[c] = sp.std_err();
            }
        }
    }
    if depths.is_empty() {
        return Ok(px);
    }
    if s.estimator == Estimator::REGULAR {
        // Exact optical depth is additive: trace [t_{k-1}, t_k] once each.
        let (mut tau, mut t0) = ([0.0f64; 3], 0.0);
        for (k, &d) in depths.iter().enumerate() {
            let seg = ray.with_range(t0, d)?;
            let e = src.estimate(&seg, p, &s.estimator, &s.options)?;
            for c in 0..nc {
                tau[c] += e.tau.map_or_else(|| -e.value[c].ln(), |t| t[c]);
                slices_out[k * nc + c] = (-tau[c]).exp() as f32;
            }
            px.lookups += e.lookups;
            t0 = d;
        }
    } else {
        let opts = Options {
            samples: u32::try_from(px.samples).unwrap_or(u32::MAX),
            ..s.options
        };
        for (k, &d) in depths.iter().enumerate() {
            let seg = ray.with_range(0.0, d)?;
            let e = src.estimate(&seg, (64 + k as u64) * npix + p, &s.estimator, &opts)?;
            px.lookups += e.lookups;
            px.capped += e.capped;
            px.violations += e.majorant_violations;
            for c in 0..nc {
                slices_out[k * nc + c] = e.value[c] as f32;
            }
        }
    }
    Ok(px)
}

/// Bake a map of `vol` seen by `camera`. `progress` hears (from worker threads,
/// [`crate::progress::Progress::advance`]) the number of pixels each finished tile held; a
/// closure `|n| ...` will do.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] for bad settings (samples, target error, depths, threads, an
/// oversized image); estimator errors of any pixel.
pub fn bake(
    vol: &Volume,
    camera: &Camera,
    settings: &BakeSettings,
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    if settings.soft.is_some() {
        return Err(bad(
            "light-angle",
            "a map toward a light with extent is baked from a scene (bake_scene): its rays are \
             made against every volume's box"
                .into(),
        ));
    }
    bake_source(Source::Volume(vol), camera, settings, progress)
}

/// Bake a map of a scene (several volumes, colour, solids; see [`crate::scene`]): channels
/// `R`, `G`, `B` for an RGB scene. A scene of one grey volume bakes exactly as [`bake`].
///
/// # Errors
/// As [`bake`].
pub fn bake_scene(
    scene: &Scene,
    camera: &Camera,
    settings: &BakeSettings,
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    if let Some(soft) = &settings.soft {
        return soft::bake_soft(scene, camera, settings, soft, progress);
    }
    match scene.single() {
        Some(vol) => bake(vol, camera, settings, progress),
        None => bake_source(Source::Scene(scene), camera, settings, progress),
    }
}

fn bake_source(
    src: Source<'_>,
    camera: &Camera,
    settings: &BakeSettings,
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    crate::bake::check_res(camera.width, camera.height)?;
    settings.validate()?;
    let depths = settings.depths.resolve(camera)?;
    let channels = (1 + depths.len() as u64 + u64::from(settings.std_err)) * src.channels() as u64;
    if camera.pixels() * channels > MAX_PIXELS {
        return Err(bad(
            "res",
            format!(
                "{}x{} with {channels} channels is more than {MAX_PIXELS} samples",
                camera.width, camera.height
            ),
        ));
    }
    let vols: Vec<&Volume> = match src {
        Source::Volume(v) => vec![v],
        Source::Scene(s) => s.fogs().iter().map(crate::scene::Fog::volume).collect(),
    };
    check_work(&vols, camera, settings)?;
    let run = || render(src, camera, settings, &depths, progress);
    in_pool(settings.threads, run)
}

/// `run` on a pool of `threads` workers (0: the current pool).
pub(crate) fn in_pool<T: Send>(
    threads: usize,
    run: impl FnOnce() -> Result<T> + Send,
) -> Result<T> {
    if threads == 0 {
        return run();
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| bad("threads", e.to_string()))?
        .install(run)
}

/// The work budget of a map of `vols` ([`crate::estimate::budget::check_job`]): every pixel
/// may take up to max-spp samples when adaptive.
fn check_work(vols: &[&Volume], camera: &Camera, settings: &BakeSettings) -> Result<()> {
    let (samples, name) = match settings.target_error {
        Some(_) => (settings.max_spp.max(settings.options.samples), "max-spp"),
        None => (settings.options.samples, "spp"),
    };
    for vol in vols {
        crate::estimate::budget::check_job(
            vol,
            &settings.estimator,
            camera.pixels(),
            u64::from(samples),
            name,
        )?;
    }
    Ok(())
}

/// [`bake`] of a lazily opened grid in bounded memory, by the sweep in parts of at most about
/// `part_bytes` each, each a region of the tree ([`crate::bake::trace::sweep::render_streamed`]):
/// the same map, bit for bit. `volume_of` makes a volume of each decoded part (density scale,
/// transform). `None` when this map cannot be swept in parts (not an exact trilinear map,
/// extinction outside lower nodes).
///
/// # Errors
/// As [`bake`], and decoding errors of the leaves.
pub(crate) fn bake_streamed(
    lazy: &crate::vdb::LazyGrid,
    shell: &Volume,
    volume_of: &(dyn Fn(crate::vdb::Grid) -> Result<Volume> + Sync),
    camera: &Camera,
    settings: &BakeSettings,
    part_bytes: u64,
    progress: &dyn crate::progress::Progress,
) -> Result<Option<(Map, crate::bake::trace::sweep::Streamed)>> {
    crate::bake::check_res(camera.width, camera.height)?;
    settings.validate()?;
    let marched = crate::bake::trace::sweep::marches(settings).is_some();
    if settings.order != Order::Auto || !(crate::bake::trace::sweep::applies(settings) || marched) {
        return Ok(None);
    }
    let depths = settings.depths.resolve(camera)?;
    let run = || {
        let rows = band_rows(camera.height, rayon::current_num_threads());
        crate::bake::trace::sweep::render_streamed(
            lazy, shell, volume_of, camera, settings, &depths, rows, part_bytes, progress,
        )
    };
    in_pool(settings.threads, run)
}

/// [`bake`] of a lazily opened grid in bounded memory, on the ray path: image rows in runs
/// whose pixel rays touch at most about `group_leaves` leaves ([`crate::demand`]), each run
/// decoded by `load` (a volume holding those leaves), rendered and dropped. Every pixel is the
/// whole-grid ray path's, bit for bit (its ray reads only leaves its run loaded). A single row
/// touching more leaves than that is one run of its own.
///
/// # Errors
/// As [`bake`], and decoding errors of the leaves.
pub(crate) fn bake_rows_streamed(
    shell: &Volume,
    load: &(dyn Fn(&[u32]) -> Result<Volume> + Sync),
    camera: &Camera,
    settings: &BakeSettings,
    group_leaves: usize,
    progress: &dyn crate::progress::Progress,
) -> Result<(Map, u64)> {
    crate::bake::check_res(camera.width, camera.height)?;
    settings.validate()?;
    let depths = settings.depths.resolve(camera)?;
    check_work(&[shell], camera, settings)?;
    let run = || -> Result<(Map, u64)> {
        let start = std::time::Instant::now();
        let (w, h) = (camera.width, camera.height);
        let rows = band_rows(h, rayon::current_num_threads());
        let (interp, gran) = (settings.options.interp, settings.options.granularity);
        let mut t_image = Vec::with_capacity(camera.pixels() as usize);
        let mut bands = Vec::new();
        let mut parts = 0;
        let mut r0 = 0;
        let mut held: Vec<u32> = Vec::new();
        let mut flush = |r0: u32, r1: u32, ids: &[u32]| -> Result<()> {
            let vol = load(ids)?;
            let (t, b) = render_rows(
                Source::Volume(&vol),
                camera,
                settings,
                &depths,
                (r0, r1),
                rows,
                progress,
            )?;
            t_image.extend(t);
            bands.extend(b);
            parts += 1;
            Ok(())
        };
        for j in 0..h {
            let rays: Vec<Ray> = (0..w)
                .map(|i| camera.pixel_ray(i, j))
                .collect::<Result<_>>()?;
            let row = crate::demand::leaves_touched(shell, &rays, interp, gran);
            let mut union: Vec<u32> = held.iter().chain(&row).copied().collect();
            union.sort_unstable();
            union.dedup();
            if j > r0 && union.len() > group_leaves {
                flush(r0, j, &held)?;
                r0 = j;
                held = row;
            } else {
                held = union;
            }
        }
        flush(r0, h, &held)?;
        let nc = 1;
        let mut map = assemble_rays(camera, settings, &depths, nc, t_image, bands, start);
        // A blurred `riemann` map in parts goes by rays, where a whole load would be swept.
        if settings.order == Order::Auto
            && shell.moving().is_some()
            && matches!(
                settings.estimator.algo(),
                (crate::estimate::Algo::Riemann, _)
            )
        {
            map.stats.declined = Some(crate::bake::SweepDeclined::Parts);
        }
        Ok((map, parts))
    };
    in_pool(settings.threads, run)
}

/// The optional channels of one finished band of rows (the main `T` is written in place) and
/// its share of the statistics; per-pixel records are not kept.
struct Band {
    /// `std_err[n nc + c]`: channel `c` of the band's pixel `n`.
    std_err: Vec<f32>,
    /// Green and blue `T` of an RGB map, `gb[2 n + c - 1]`.
    gb: Vec<f32>,
    /// `slices[(n k + s) nc + c]`: slice `s`, channel `c` of the band's pixel `n`.
    slices: Vec<f32>,
    stats: BakeStats,
}

/// Rows per band: one tile high, fewer when the image has too few rows to give every worker
/// about four bands.
pub(crate) fn band_rows(height: u32, workers: usize) -> u32 {
    let per = u32::try_from(workers.max(1) * 4).unwrap_or(u32::MAX);
    TILE.min((height / per).max(1))
}

fn render(
    src: Source<'_>,
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    progress: &dyn crate::progress::Progress,
) -> Result<Map> {
    let start = std::time::Instant::now();
    let h = camera.height;
    let nc = src.channels();
    let rows = band_rows(h, rayon::current_num_threads());
    let mut declined = None;
    if s.order == Order::Auto {
        let exact = crate::bake::trace::sweep::applies(s);
        match src {
            // A moving volume: blurred `riemann` maps are swept (`sweep::blur`), every other
            // map is traced ray by ray; a blurred `riemann` map the sweep declines says why.
            Source::Volume(vol) if vol.moving().is_some() => {
                match crate::bake::trace::sweep::render_blurred(
                    vol, camera, s, depths, rows, progress,
                )? {
                    crate::bake::trace::sweep::Swept::Map(map) => return Ok(*map),
                    crate::bake::trace::sweep::Swept::Rays(why) => declined = why,
                }
            }
            Source::Volume(vol)
                if exact
                    || crate::bake::trace::sweep::marches(s).is_some()
                    || crate::bake::trace::sweep::flights(s).is_some() =>
            {
                if let Some(map) =
                    crate::bake::trace::sweep::render(vol, camera, s, depths, rows, progress)?
                {
                    return Ok(map);
                }
            }
            Source::Scene(scene) if exact => {
                return crate::bake::trace::scene::exact(scene, camera, s, depths, rows, progress);
            }
            _ => {}
        }
    }
    let (t_image, bands) = render_rows(src, camera, s, depths, (0, h), rows, progress)?;
    let mut map = assemble_rays(camera, s, depths, nc, t_image, bands, start);
    map.stats.declined = declined;
    Ok(map)
}

/// The ray path over image rows `r0..r1` (in bands of `rows` rows, in parallel): their `T`
/// and their bands. Pixel `(i, j)` is ray id `j W + i` of the whole image, whatever the range.
fn render_rows(
    src: Source<'_>,
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    (r0, r1): (u32, u32),
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<(Vec<f32>, Vec<Band>)> {
    let w = camera.width;
    let npix = camera.pixels();
    let k = depths.len();
    let nc = src.channels();
    let len = (r1 - r0) as usize * w as usize;
    // Bands of whole rows are contiguous in the row-major image, so every worker writes `T`
    // straight into its own part of the output; inside a band, pixels go tile by tile
    // (`TILE` columns at a time) so that neighbouring rays reuse the same cached nodes.
    let mut t_image = vec![0.0f32; len];
    let bands: Vec<Band> = t_image
        .par_chunks_mut(rows as usize * w as usize)
        .enumerate()
        .map(|(b, t_band)| {
            let y0 = r0 + b as u32 * rows;
            let bh = (t_band.len() / w as usize) as u32;
            let n_band = t_band.len();
            let mut band = Band {
                std_err: vec![0.0; if s.std_err { n_band * nc } else { 0 }],
                gb: vec![0.0; n_band * (nc - 1)],
                slices: vec![0.0; n_band * k * nc],
                stats: BakeStats::default(),
            };
            let mut x0 = 0;
            while x0 < w {
                let tw = TILE.min(w - x0);
                for j in y0..y0 + bh {
                    for i in x0..x0 + tw {
                        let n = (j - y0) as usize * w as usize + i as usize;
                        let ray = camera.pixel_ray(i, j)?;
                        let p = u64::from(j) * u64::from(w) + u64::from(i);
                        let out = &mut band.slices[n * k * nc..(n + 1) * k * nc];
                        let px = pixel(src, s, depths, &ray, p, npix, out)?;
                        t_band[n] = px.t[0] as f32;
                        for c in 1..nc {
                            band.gb[n * 2 + c - 1] = px.t[c] as f32;
                        }
                        if s.std_err {
                            for c in 0..nc {
                                band.std_err[n * nc + c] = px.std_err[c] as f32;
                            }
                        }
                        band.stats.absorb(&px.stats());
                    }
                }
                progress.advance(u64::from(tw * bh));
                x0 += tw;
            }
            Ok(band)
        })
        .collect::<Result<_>>()?;
    Ok((t_image, bands))
}

/// The map of the ray path from its `T` image and bands (in image order).
fn assemble_rays(
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    nc: usize,
    t_image: Vec<f32>,
    bands: Vec<Band>,
    start: std::time::Instant,
) -> Map {
    let (npix, k) = (camera.pixels(), depths.len());
    let len = npix as usize;
    let mut chans: Vec<Channel> = (0..nc)
        .map(|_| Channel {
            t: Vec::with_capacity(if nc > 1 { len } else { 0 }),
            std_err: s.std_err.then(|| Vec::with_capacity(len)),
            slices: vec![Vec::with_capacity(len); k],
        })
        .collect();
    let mut stats = BakeStats {
        rays: npix,
        ..BakeStats::default()
    };
    // Bands are in image order, so their optional channels concatenate into whole images.
    for band in bands {
        for (c, ch) in chans.iter_mut().enumerate() {
            if c > 0 {
                ch.t.extend(band.gb.iter().skip(c - 1).step_by(2));
            }
            if let Some(e) = ch.std_err.as_mut() {
                e.extend(band.std_err.iter().skip(c).step_by(nc));
            }
            for (sl, slice) in ch.slices.iter_mut().enumerate() {
                slice.extend(band.slices.iter().skip(sl * nc + c).step_by(k.max(1) * nc));
            }
        }
        stats.absorb(&band.stats);
    }
    stats.seconds = start.elapsed().as_secs_f64();
    let (red, color) = split_channels(chans);
    Map {
        camera: *camera,
        settings: s.clone(),
        t: t_image,
        std_err: red.std_err,
        depths: depths.to_vec(),
        slices: red.slices,
        color,
        stats,
    }
}
