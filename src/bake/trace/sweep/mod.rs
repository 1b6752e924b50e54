//! The sweep: exact maps in object order.
//!
//! Exact optical depth is additive along a ray: `tau(pixel) = sum over blocks B of
//! int_{ray ∩ B} mu_t dt`. So instead of walking every ray down the tree, the sweep visits the
//! tree's 8^3 blocks (leaves and tiles of lower nodes) once each (per band of rows) and adds
//! each block's exact contribution to every pixel its footprint covers. The rays of an
//! orthographic map are parallel; those of a perspective map share the pinhole, so the rays
//! that cross one block are still neighbours in the image and stay coherent through it:
//!
//! - **Blocks.** Every lower node the hierarchical DDA would enter (its trilinear halo is not
//!   just the background) contributes its 4096 child blocks, in lookup space `[o, o + 8]^3`.
//!   A block whose halo is one value `c` adds `mu(c) x chord` in closed form (the background's
//!   `mu` for background blocks, so a non-zero background is counted once); any other block
//!   adds the exact integral of its trilinear field, computed by the lane kernel
//!   ([`kernel`]: the block's 9^3 corner values copied once into L1, 8 rays of a footprint row
//!   at a time, f32 AVX2 cells summed in f64) or, for blocks whose values are infinite, huge or
//!   subnormal, by the f64 per-ray code of [`crate::regular`].
//! - **Everything above lower nodes** (tiles of upper nodes and root cells with a value or a
//!   halo other than the background, and the background itself when its `mu` is not zero) is
//!   what a ray walk at lower-node granularity emits outside lower nodes; it is traced per
//!   pixel, and skipped when the tree has none of it.
//! - **Footprints.** A block's pixels are found by projecting its 8 corners (of the block
//!   clipped to the walk's clip box) onto the image, grown by a pixel: along the rays for an
//!   orthographic map (`[q_x q_y d]^-1 (p - q_0)`, where pixel `(i, j)`'s ray is
//!   `q_0 + i q_x + j q_y + t d`), through the pinhole for a perspective one (`v = [D s_x
//!   s_y]^-1 (p - P)` gives pixel `(v_1 / v_0, v_2 / v_0)`, where pixel `(i, j)`'s ray runs
//!   from `P` through `D + i s_x + j s_y`). Each row narrows that to a column span (linear in
//!   the column for parallel rays; for a pinhole, where the row's plane cuts the box's edges),
//!   and each pixel's ray is then clipped to the box exactly, so the footprint decides nothing.
//!   A pinhole inside or beside the clip box (a light in the smoke) is swept too: a block
//!   reaching to or behind the pinhole's plane projects without bound where it crosses that
//!   plane, so its footprint runs to the image's edge on those sides (`straddling_rect`);
//!   only the few blocks around the light's plane are that wide. Cube maps go face by face
//!   (`render_cube`), six pinholes at the light.
//! - **Slices.** Slice `k` (depth `t_k`) is the optical depth of `[0, t_k]`: a block's chord
//!   `[a, b]` counts whole when `b <= t_k`, and a chord that straddles `t_k` adds one more lane
//!   integrating `[a, t_k]`.
//! - **Order and threads.** Blocks are binned into bands of image rows; bands run in parallel,
//!   each over its blocks in tree order. A pixel's sum is the rest walk first, then its blocks
//!   in tree order: the same whatever the thread count.
//!
//! The result equals the ray path's ([`crate::regular::optical_depth`] per pixel) to within the
//! kernel's f32 cell arithmetic (see [`kernel`]); `tests/library/bake.rs` holds it to `1e-6` relative on
//! corpus files. Lookups are counted as the ray path counts them: 8 corner reads for the first
//! dual cell of a block, 4 for each further one.

mod band;
mod blur;
mod flight;
mod march;
mod pieces;
mod rays;
mod streamed;

use band::{BandRows, ExactBand};
pub(crate) use blur::{render as render_blurred, Swept};
pub(crate) use flight::flights;
use flight::{Flight, FlightBand};
pub(crate) use march::marches;
use march::{finish_samples, March, MarchBand};
use pieces::{bins, needs_rest, pieces, Piece};
use rays::Rays;
pub(crate) use streamed::{part_bytes, render_streamed, streams, Streamed};

use crate::bake::camera::Camera;
use crate::bake::map::{worse_std_err, BakeSettings, BakeStats, Map};
use crate::error::Result;
use crate::estimate::{Bounds, Estimator};
use crate::volume::{Interp, Volume};
use rayon::prelude::*;

/// True when the sweep renders maps with these settings: exact regular tracking with trilinear
/// lookups (depth slices included), orthographic or perspective ([`render`] still declines a
/// map whose pinhole is inside the clip box or whose frame is degenerate).
pub(crate) fn applies(s: &BakeSettings) -> bool {
    s.estimator == Estimator::REGULAR && s.options.interp == Interp::Trilinear
}

/// A planned sweep: the map's rays, its pieces binned by band, and whether the rays also need
/// the walk above lower nodes.
struct Sweep<'a> {
    vol: &'a Volume,
    camera: &'a Camera,
    rays: Rays,
    pieces: Vec<Piece>,
    bins: Vec<Vec<u32>>,
    rest_needed: bool,
    rows: u32,
    /// Slice depths `t_k` (world distance along each ray), increasing.
    depths: Vec<f64>,
    /// A ray march ([`March`]) instead of the exact integral.
    march: Option<March>,
    /// A null-collision estimator ([`Flight`]) instead of the exact integral.
    flight: Option<Flight>,
    /// Set when an estimate ran out of its collision budget: the map is then traced instead.
    capped: std::sync::atomic::AtomicBool,
}

impl<'a> Sweep<'a> {
    /// Plan the sweep of `camera`'s map in bands of `rows` rows; `None` when the sweep cannot
    /// take its rays ([`Rays::new`]).
    fn new(vol: &'a Volume, camera: &'a Camera, rows: u32, depths: &[f64]) -> Result<Option<Self>> {
        let Some(rays) = Rays::new(vol, camera)? else {
            return Ok(None);
        };
        let rest_needed = needs_rest(vol);
        let pieces = pieces(vol, &rays, !rest_needed);
        Ok(Some(Self::from_pieces(
            vol,
            camera,
            rays,
            pieces,
            rest_needed,
            rows,
            depths,
        )))
    }

    /// A sweep of the given pieces (in their order).
    fn from_pieces(
        vol: &'a Volume,
        camera: &'a Camera,
        rays: Rays,
        pieces: Vec<Piece>,
        rest_needed: bool,
        rows: u32,
        depths: &[f64],
    ) -> Self {
        let bins = bins(&pieces, rows, camera.height);
        Self {
            vol,
            camera,
            rays,
            pieces,
            bins,
            rest_needed,
            rows,
            depths: depths.to_vec(),
            march: None,
            flight: None,
            capped: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// This sweep as the march `m` or the null-collision estimator `f` (both `None`: exact),
    /// or `None` when it cannot be swept: extinction outside lower nodes, which the sweep
    /// integrates exactly per pixel, where the ray path samples it.
    fn marching(mut self, m: Option<March>, f: Option<Flight>) -> Option<Self> {
        if (m.is_some() || f.is_some()) && self.rest_needed {
            return None;
        }
        // `marches` and `flights` take disjoint estimators: at most one is set.
        self.march = m;
        self.flight = f;
        Some(self)
    }

    /// Add every band's pieces to `tau` (the whole image, [`Sweep::stride`] values a pixel);
    /// the lookups spent.
    fn add_all(&self, tau: &mut [f64]) -> Result<u64> {
        let band = self.rows as usize * self.rays.width as usize * self.stride();
        Ok(tau
            .par_chunks_mut(band)
            .enumerate()
            .map(|(b, band)| {
                let mut lookups = 0;
                self.band(b, band, &mut lookups)?;
                Ok(lookups)
            })
            .collect::<Result<Vec<u64>>>()?
            .iter()
            .sum())
    }

    /// Values per pixel in a band's buffer: per sample (one but for a random march), the full
    /// optical depth, then one per slice.
    fn stride(&self) -> usize {
        self.samples() * (1 + self.depths.len())
    }

    /// Samples per pixel: a random march's or a null-collision estimator's, else one.
    fn samples(&self) -> usize {
        self.march
            .map(|m| m.samples())
            .or(self.flight.map(|f| f.samples()))
            .unwrap_or(1)
    }

    /// The image rows `y0..=y1` of band `b`, whose buffer holds `len` values.
    fn band_span(&self, b: usize, len: usize) -> (u32, u32) {
        let y0 = b as u32 * self.rows;
        (
            y0,
            y0 + (len / self.stride() / self.rays.width as usize) as u32 - 1,
        )
    }
}

/// Render `camera`'s map of `vol` in object order; `None` when the sweep cannot take its rays
/// (a degenerate frame in index space, or a pinhole inside the clip box): the caller traces
/// rays instead.
pub(crate) fn render(
    vol: &Volume,
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Option<Map>> {
    if let Some(faces) = camera.cube_faces() {
        // A random march's or a null-collision map's streams follow the ray path's pixel ids
        // of the whole cube image, which a face's sweep does not know: such maps go by rays.
        if marches(s).is_some_and(|m| m.random()) || flights(s).is_some() {
            return Ok(None);
        }
        return render_cube(vol, camera, &faces, s, depths, progress);
    }
    let start = std::time::Instant::now();
    let Some(sweep) = Sweep::new(vol, camera, rows, depths)? else {
        return Ok(None);
    };
    let Some(sweep) = sweep.marching(marches(s), flights(s)) else {
        return Ok(None);
    };
    let (w, stride, samples) = (camera.width, sweep.stride(), sweep.samples());
    let sampled = samples > 1 || sweep.flight.is_some();
    let mut t_image = vec![0.0f32; camera.pixels() as usize];
    let done: Vec<(Band, Vec<f32>)> = t_image
        .par_chunks_mut(rows as usize * w as usize)
        .enumerate()
        .map(|(b, t_band)| {
            let mut tau = vec![0.0f64; t_band.len() * stride];
            let mut lookups = 0;
            // A null-collision map's error bar takes each pixel's bounds on T.
            let mut bounds = Vec::new();
            sweep.band_bounded(b, &mut tau, &mut lookups, s.std_err.then_some(&mut bounds))?;
            let est = sweep.flight.as_ref().map(|_| (&s.estimator, &bounds[..]));
            let y0 = b as u32 * rows;
            let (slices, err) =
                finish_rows(camera, y0, &tau, (stride, samples), est, s.std_err, t_band)?;
            progress.advance(t_band.len() as u64);
            Ok(((lookups, slices), err))
        })
        .collect::<Result<_>>()?;
    if sweep.capped.load(std::sync::atomic::Ordering::Relaxed) {
        // An estimate ran out of its collision budget: the ray path caps it where it stands.
        return Ok(None);
    }
    let map = view_map(
        camera,
        s,
        depths,
        t_image,
        done,
        sampled.then_some(samples),
        start,
    );
    Ok(Some(map))
}

/// A cube map swept face by face ([`Camera::cube_faces`]: six pinholes at the light whose
/// images, stacked, are the cube's), or `None` when a face cannot be swept.
fn render_cube(
    vol: &Volume,
    camera: &Camera,
    faces: &[Camera; 6],
    s: &BakeSettings,
    depths: &[f64],
    progress: &dyn crate::progress::Progress,
) -> Result<Option<Map>> {
    let rows = super::band_rows(faces[0].height, rayon::current_num_threads());
    let mut maps = Vec::with_capacity(6);
    for face in faces {
        let Some(m) = render(vol, face, s, depths, rows, progress)? else {
            return Ok(None);
        };
        maps.push(m);
    }
    Ok(stack_faces(camera, maps))
}

/// The cube map `camera` from the maps of its faces, in order: their images stacked, their
/// statistics summed.
fn stack_faces(camera: &Camera, maps: Vec<Map>) -> Option<Map> {
    let mut cube: Option<Map> = None;
    for m in maps {
        match &mut cube {
            None => cube = Some(m),
            Some(c) => {
                c.t.extend_from_slice(&m.t);
                if let (Some(a), Some(b)) = (&mut c.std_err, &m.std_err) {
                    a.extend_from_slice(b);
                }
                for (a, b) in c.slices.iter_mut().zip(&m.slices) {
                    a.extend_from_slice(b);
                }
                c.stats.absorb(&m.stats);
                c.stats.rays += m.stats.rays;
                c.stats.seconds += m.stats.seconds;
            }
        }
    }
    cube.map(|mut c| {
        c.camera = *camera;
        c
    })
}

/// A finished band of rows from `y0`: `T = exp(-tau)` of each pixel into `t_band`, and its
/// slices (`slices[n k + c]`, as the ray renderer keeps them); a NaN optical depth is an
/// error naming the pixel's ray.
fn finish_band(
    camera: &Camera,
    y0: u32,
    tau: &[f64],
    stride: usize,
    t_band: &mut [f32],
) -> Result<Vec<f32>> {
    let w = camera.width;
    let mut slices = Vec::with_capacity(t_band.len() * (stride - 1));
    for (n, px) in tau.chunks(stride).enumerate() {
        if px.iter().any(|x| x.is_nan()) {
            let (i, j) = (n as u32 % w, y0 + n as u32 / w);
            let ray = camera.pixel_ray(i, j)?;
            return Err(crate::error::Error::nan_on_ray("optical depth", &ray));
        }
        t_band[n] = (-px[0]).exp() as f32;
        slices.extend(px[1..].iter().map(|x| (-x).exp() as f32));
    }
    Ok(slices)
}

/// A finished band: its lookups and its slices (as [`assemble`] takes them).
type Band = (u64, Vec<f32>);

/// A band of rows from `y0` finished from its buffer `tau` (`stride` values a pixel, in
/// `samples` estimates): `T` into `t_band`; its slices (pixel-major) and, with `std_err`, each
/// pixel's error bar returned. A random march's or a null-collision map's `T` (`flight`: that
/// map's estimator and its pixels' bounds on `T`) is the mean over samples
/// ([`finish_samples`]), any other map's `exp(-tau)` ([`finish_band`]).
fn finish_rows(
    camera: &Camera,
    y0: u32,
    tau: &[f64],
    (stride, samples): (usize, usize),
    flight: Option<(&Estimator, &[Bounds])>,
    std_err: bool,
    t_band: &mut [f32],
) -> Result<(Vec<f32>, Vec<f32>)> {
    let mut err = vec![0.0f32; if std_err { t_band.len() } else { 0 }];
    let slices = if samples > 1 || flight.is_some() {
        finish_samples(
            camera,
            y0,
            tau,
            (stride / samples, samples),
            flight,
            t_band,
            &mut err,
        )?
    } else {
        finish_band(camera, y0, tau, stride, t_band)?
    };
    Ok((slices, err))
}

/// A view's map from its `T` image and its finished bands (each `(lookups, slices)` and its
/// error bars, [`finish_rows`]); a map of `sampled` estimates a pixel (a random march, a
/// null-collision map) counts them, and keeps the error bars with `--std-err`.
fn view_map(
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    t_image: Vec<f32>,
    done: Vec<(Band, Vec<f32>)>,
    sampled: Option<usize>,
    start: std::time::Instant,
) -> Map {
    let (bands, errs): (Vec<Band>, Vec<Vec<f32>>) = done.into_iter().unzip();
    let mut map = assemble(camera, s, depths, t_image, &bands, start);
    if let Some(samples) = sampled {
        map.stats.samples = camera.pixels() * samples as u64;
        map.std_err = s.std_err.then(|| errs.concat());
        if let Some(e) = &map.std_err {
            map.stats.max_std_err = e.iter().fold(0.0, |m, &v| worse_std_err(m, f64::from(v)));
        }
    }
    map
}

/// The map from its `T` image and its bands' `(lookups, slices)`.
fn assemble(
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    t_image: Vec<f32>,
    bands: &[Band],
    start: std::time::Instant,
) -> Map {
    let (k, npix) = (depths.len(), camera.pixels());
    let mut slices = vec![Vec::with_capacity(npix as usize); k];
    for (_, band) in bands {
        for (c, slice) in slices.iter_mut().enumerate() {
            slice.extend(band.iter().skip(c).step_by(k.max(1)));
        }
    }
    let lookups = bands.iter().map(|(l, _)| l).sum();
    let len = npix as usize;
    Map {
        camera: *camera,
        settings: s.clone(),
        t: t_image,
        std_err: s.std_err.then(|| vec![0.0; len]),
        depths: depths.to_vec(),
        slices,
        color: None,
        stats: BakeStats {
            rays: npix,
            samples: npix,
            lookups,
            seconds: start.elapsed().as_secs_f64(),
            sweep: true,
            ..BakeStats::default()
        },
    }
}

/// The exact optical depth of every pixel of `camera`'s map of `vol`, in object order:
/// `tau[n (1 + K) + s]` is pixel `n`'s full depth (`s = 0`) and slice `s - 1`'s; with the
/// lookups spent. `None` when the sweep cannot take the rays (as [`render`]). `progress`
/// receives finished pixel counts. What a scene's exact map adds per volume.
pub(crate) fn tau_image(
    vol: &Volume,
    camera: &Camera,
    depths: &[f64],
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Option<(Vec<f64>, u64)>> {
    if let Some(faces) = camera.cube_faces() {
        let rows = super::band_rows(faces[0].height, rayon::current_num_threads());
        let (mut tau, mut lookups) = (Vec::new(), 0);
        for face in &faces {
            let Some((t, l)) = tau_image(vol, face, depths, rows, progress)? else {
                return Ok(None);
            };
            tau.extend_from_slice(&t);
            lookups += l;
        }
        return Ok(Some((tau, lookups)));
    }
    let Some(sweep) = Sweep::new(vol, camera, rows, depths)? else {
        return Ok(None);
    };
    let (w, stride) = (camera.width as usize, sweep.stride());
    let mut tau = vec![0.0f64; camera.pixels() as usize * stride];
    let lookups = tau
        .par_chunks_mut(rows as usize * w * stride)
        .enumerate()
        .map(|(b, band)| {
            let mut lookups = 0;
            sweep.band(b, band, &mut lookups)?;
            progress.advance((band.len() / stride) as u64);
            Ok(lookups)
        })
        .collect::<Result<Vec<u64>>>()?
        .iter()
        .sum();
    Ok(Some((tau, lookups)))
}

/// A lattice of parallel rays in lookup space: ray `(i, j)` (`i < width`, `j < height`) is
/// `q0 + i qx + j qy + t d` for `t` in `[0, t_max]` (world units along it: `d` is the
/// lookup-space image of a unit world direction). A transmittance volume's layer of voxel
/// centres, each ray ending at its voxel, is one.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lattice {
    pub(crate) q0: [f64; 3],
    pub(crate) qx: [f64; 3],
    pub(crate) qy: [f64; 3],
    pub(crate) d: [f64; 3],
    pub(crate) t_max: f64,
    pub(crate) width: u32,
    pub(crate) height: u32,
}

/// The exact optical depth of every ray of `lattice` through `vol` in object order (the map
/// sweep's blocks, lane kernel and piece order, on rays that need not be perpendicular to
/// their rows): `tau[j width + i]`, and the lookups spent. `None` when the sweep cannot take
/// them: extinction outside lower nodes (which the map sweep walks pixel by pixel from a
/// camera), a singular lattice, or more rays than one image holds.
pub(crate) fn tau_lattice(
    vol: &Volume,
    lattice: &Lattice,
    rows: u32,
) -> Result<Option<(Vec<f64>, u64)>> {
    if needs_rest(vol) {
        return Ok(None);
    }
    // The sweep's image: `lattice`'s size. Its rays are the lattice's; the camera is read
    // only for pinhole directions and the rest walk, neither of which a lattice has.
    let spec = crate::bake::camera::CameraSpec {
        kind: crate::bake::camera::Projection::Ortho,
        width: lattice.width,
        height: lattice.height,
        origin: [0.0; 3],
        step_x: [1.0, 0.0, 0.0],
        step_y: [0.0, -1.0, 0.0],
        direction: [0.0, 0.0, -1.0],
        t_max: lattice.t_max,
    };
    let Ok(grid) = Camera::from_spec(&spec) else {
        return Ok(None);
    };
    let Some(rays) = Rays::lattice(vol, lattice) else {
        return Ok(None);
    };
    let pieces = pieces(vol, &rays, true);
    let sweep = Sweep::from_pieces(vol, &grid, rays, pieces, false, rows, &[]);
    let mut tau = vec![0.0f64; grid.pixels() as usize];
    let lookups = sweep.add_all(&mut tau)?;
    Ok(Some((tau, lookups)))
}

/// The band dispatch: each band picks its estimator's kernel once ([`band::BandKernel`]) and
/// runs the one loop ([`Sweep::run_band`]) with it.
impl Sweep<'_> {
    /// Band `b` (rows `[b rows, b rows + rows)`): every pixel's optical depth (or, for a
    /// null-collision map, transmittance estimate) into `tau`, [`Sweep::stride`] values a pixel
    /// (per sample: the full ray, then each slice `[0, t_k]`).
    pub(super) fn band(&self, b: usize, tau: &mut [f64], lookups: &mut u64) -> Result<()> {
        self.band_bounded(b, tau, lookups, None)
    }

    /// Band `b` as [`Sweep::band`]; a null-collision map also puts each pixel's bounds on `T`
    /// (its full ray) into `bounds` when given: what the error bar's floor needs
    /// ([`crate::estimate::error_bar`]).
    pub(super) fn band_bounded(
        &self,
        b: usize,
        tau: &mut [f64],
        lookups: &mut u64,
        bounds: Option<&mut Vec<Bounds>>,
    ) -> Result<()> {
        let (y0, y1) = self.band_span(b, tau.len());
        let band = BandRows {
            y0,
            y1,
            dirs: self.pixel_dirs(y0, y1)?,
        };
        let ids = &self.bins[b];
        // `marching` sets at most one of them.
        *lookups += match (&self.march, &self.flight) {
            (Some(m), _) => self.run_band(ids, &band, MarchBand::new(self, m, y0, tau))?,
            (None, Some(f)) => {
                self.run_band(ids, &band, FlightBand::new(self, f, y0, tau, bounds))?
            }
            (None, None) => self.run_band(ids, &band, ExactBand::new(self, tau))?,
        };
        Ok(())
    }
}

#[cfg(test)]
mod tests;
