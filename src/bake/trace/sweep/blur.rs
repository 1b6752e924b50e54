//! Motion-blurred `riemann` maps in object order.
//!
//! On a moving volume (`crate::motion`) the ray path's `riemann` takes `K` stratified shutter
//! times per pixel, `t_k = o + (k + u_k) / K (c - o)` from the pixel's stream, cuts each ray at
//! the `8^3` blocks of lookup space, lays `n = ceil(L / h)` equal pieces on each block chord,
//! reads the velocity `v(x_j)` once at each midpoint and the density once per time,
//!
//! ```text
//! tau_k += mu(x_j - S t_k v(x_j) / F) dt,    T = 1/K sum_k exp(-tau_k),
//! ```
//!
//! over the blocks whose blurred majorant ([`crate::motion::BlurBounds`]) is not zero. Every
//! term belongs to one block chord, so the sweep visits those blocks instead, each once per band
//! of rows, and adds every chord's terms to its pixel's `K` optical depths. What makes it fast
//! is where the reads land: all the midpoints of one block, at every shutter time, read density
//! within the block moved by the velocities it holds, and velocity within the block itself. So
//! before its chords the sweep copies both neighbourhoods into dense windows
//! ([`crate::tree::Window`], [`crate::motion::VelocityLookup::cover`]) and reads them without
//! a descent; a window too large (a fast block, a long shutter) is not made and the reads go
//! through the accessors. The reads give the ray path's bits either way.
//!
//! Each pixel's `K` values go into the ray path's spread (`estimate::blur::marcher_spread`,
//! bounds from the chords' blurred minorants and majorants), so `T` and its error bar are the
//! ray path's up to the order of the sums: the same midpoints, read the same way, added per
//! pixel in block order rather than ray order (`blurred_riemann_maps_match_the_ray_path`).
//!
//! The sweep declines (the ray path traces the map) slices, `--target-error`, nearest lookups,
//! `--global-majorant`, a non-zero background, a block whose majorant is infinite, and bands
//! whose pixels' times would pass [`MAX_BAND_VALUES`].

use super::pieces::bins_of;
use super::rays::Rays;
use crate::bake::camera::Camera;
use crate::bake::map::{BakeSettings, BakeStats, Map, SweepDeclined};
use crate::error::Result;
use crate::estimate::blur::{marcher_spread, marcher_std_err, strata_times};
use crate::estimate::marching::{pieces, step_world};
use crate::estimate::{Algo, Bounds};
use crate::math::scaled;
use crate::motion::{Motion, VelocityLookup};
use crate::regular::kernel::Simd;
use crate::tree::{Accessor, Window};
use crate::volume::{Interp, Volume};
use glam::{DAffine3, DVec3};
use rayon::prelude::*;

/// The most voxels a window holds (128 KiB of `f32`): a block moved further than this covers
/// is read through the accessors.
const MAX_WINDOW: usize = 1 << 15;

/// The most per-pixel time values a band holds (`K` displacements and `K` optical depths per
/// pixel, 64 MiB of `f64` each).
const MAX_BAND_VALUES: u64 = 1 << 23;

/// A window is made when it holds at most this many voxels per read it serves; fewer reads (a
/// block few pixels see) go through the accessors.
const VOXELS_PER_READ: usize = 8;

/// One block of the blurred sweep: its index origin, the pixels it may cover, and its blurred
/// minorant and majorant (scaled).
struct Block {
    origin: [i64; 3],
    rect: [u32; 4],
    mu: (f64, f64),
}

/// A planned blurred sweep.
struct BlurSweep<'a> {
    vol: &'a Volume,
    motion: &'a Motion,
    camera: &'a Camera,
    rays: Rays,
    blocks: Vec<Block>,
    bins: Vec<Vec<u32>>,
    rows: u32,
    step: f64,
    seed: u64,
}

/// What [`BlurSweep::plan`] makes of a map.
enum Plan<'a> {
    /// The sweep takes it.
    Sweep(Box<BlurSweep<'a>>),
    /// Not a blurred `riemann` map, or none of its rays meets the blurred bounds: the ray path
    /// is the only path (or a trivial one), nothing to say.
    NotMine,
    /// A blurred `riemann` map the sweep declines: the ray path traces it, and says why.
    Declined(SweepDeclined),
}

/// What [`render`] did with a map.
pub(crate) enum Swept {
    /// The map, swept.
    Map(Box<Map>),
    /// Not the sweep's; `Some`: a blurred `riemann` map it declined, and why.
    Rays(Option<SweepDeclined>),
}

/// Render `camera`'s blurred `riemann` map of the moving `vol` in object order, or say why
/// not (module docs): the caller traces rays.
pub(crate) fn render(
    vol: &Volume,
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    rows: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Swept> {
    let start = std::time::Instant::now();
    let sweep = match BlurSweep::plan(vol, camera, s, depths, rows)? {
        Plan::Sweep(sweep) => sweep,
        Plan::NotMine => return Ok(Swept::Rays(None)),
        Plan::Declined(why) => return Ok(Swept::Rays(Some(why))),
    };
    let w = camera.width as usize;
    let mut t_image = vec![0.0f32; camera.pixels() as usize];
    let mut err_image = vec![0.0f32; camera.pixels() as usize];
    let stats = t_image
        .par_chunks_mut(rows as usize * w)
        .zip(err_image.par_chunks_mut(rows as usize * w))
        .enumerate()
        .map(|(b, (t, e))| {
            let st = sweep.band(b, t, e)?;
            progress.advance(t.len() as u64);
            Ok(st)
        })
        .collect::<Result<Vec<BakeStats>>>()?;
    let mut total = BakeStats {
        rays: camera.pixels(),
        sweep: true,
        ..BakeStats::default()
    };
    for st in &stats {
        total.absorb(st);
    }
    total.seconds = start.elapsed().as_secs_f64();
    Ok(Swept::Map(Box::new(Map {
        camera: *camera,
        settings: s.clone(),
        t: t_image,
        std_err: s.std_err.then_some(err_image),
        depths: Vec::new(),
        slices: Vec::new(),
        color: None,
        stats: total,
    })))
}

impl<'a> BlurSweep<'a> {
    /// The sweep of `camera`'s map, or why not (module docs).
    fn plan(
        vol: &'a Volume,
        camera: &'a Camera,
        s: &BakeSettings,
        depths: &[f64],
        rows: u32,
    ) -> Result<Plan<'a>> {
        let Some(motion) = vol.moving() else {
            return Ok(Plan::NotMine);
        };
        let (Algo::Riemann, step) = s.estimator.algo() else {
            return Ok(Plan::NotMine);
        };
        let declined = if !depths.is_empty() {
            Some(SweepDeclined::Slices)
        } else if s.target_error.is_some() {
            Some(SweepDeclined::TargetError)
        } else if s.options.interp != Interp::Trilinear {
            Some(SweepDeclined::Nearest)
        } else if s.options.global_majorant {
            Some(SweepDeclined::GlobalMajorant)
        } else if vol.mu_background() != 0.0 {
            Some(SweepDeclined::Background(vol.mu_background()))
        } else {
            None
        };
        if let Some(why) = declined {
            return Ok(Plan::Declined(why));
        }
        // A band keeps `K` displacements and optical depths per pixel: a band over
        // `MAX_BAND_VALUES` of them (thousands of times on a wide map) goes by rays.
        let band_values = u64::from(rows) * u64::from(camera.width);
        let values = band_values.saturating_mul(u64::from(motion.spec().time_samples()));
        if values > MAX_BAND_VALUES {
            return Ok(Plan::Declined(SweepDeclined::WideBand {
                values,
                max: MAX_BAND_VALUES,
            }));
        }
        let bounds = motion.bounds();
        let (lo, dims) = bounds.dense_box();
        // The ray path clips its rays to the bounds' dense box (`bound_segments`).
        let clip = (
            lo.map(|c| (c * 8) as f64),
            [0, 1, 2].map(|a| ((lo[a] + dims[a] as i64) * 8) as f64),
        );
        let Some(rays) = Rays::clipped_to(vol, camera, clip)? else {
            return Ok(Plan::NotMine);
        };
        let scale = vol.density_scale();
        let mut blocks = Vec::new();
        for x in 0..dims[0] as i64 {
            for y in 0..dims[1] as i64 {
                for z in 0..dims[2] as i64 {
                    let c = [lo[0] + x, lo[1] + y, lo[2] + z];
                    let (mn, mx) = bounds.block_range(c);
                    let mu = (scaled(scale, f64::from(mn)), scaled(scale, f64::from(mx)));
                    if !mu.1.is_finite() {
                        // Opaque somewhere at some time: the ray path's fine march.
                        return Ok(Plan::Declined(SweepDeclined::Opaque));
                    }
                    if mu.1 <= 0.0 {
                        continue;
                    }
                    let origin = c.map(|v| v * 8);
                    if let Some(rect) = rays.footprint(origin, 8) {
                        blocks.push(Block { origin, rect, mu });
                    }
                }
            }
        }
        let bins = bins_of(blocks.iter().map(|b| b.rect), rows, camera.height);
        Ok(Plan::Sweep(Box::new(Self {
            vol,
            motion,
            camera,
            rays,
            blocks,
            bins,
            rows,
            step,
            seed: s.options.seed,
        })))
    }

    /// Band `b`: each pixel's `T` into `t` and its error bar into `err`; the band's statistics.
    fn band(&self, b: usize, t: &mut [f32], err: &mut [f32]) -> Result<BakeStats> {
        let w = self.camera.width;
        let y0 = b as u32 * self.rows;
        let y1 = y0 + (t.len() / w as usize) as u32 - 1;
        let k = self.motion.spec().time_samples() as usize;
        let mut px = Pixels::new(self, y0, y1, k)?;
        let dirs = self.rays.pixel_dirs(self.vol, self.camera, y0, y1)?;
        let mut reads = Reads::new(self.vol, self.motion);
        for &id in &self.bins[b] {
            let block = &self.blocks[id as usize];
            let [_, _, j0, j1] = block.rect;
            let rows = (j0.max(y0), j1.min(y1), y0);
            reads.mids.clear();
            self.rays
                .chords((block.origin, block.rect), rows, &dirs, |n, _, _, a, b| {
                    let len = b - a;
                    px.touched[n] = true;
                    px.depth[n].0 += block.mu.0 * len;
                    px.depth[n].1 += block.mu.1 * len;
                    let (count, dt) = pieces(len, px.h[n]);
                    let (o, d) = px.ray[n];
                    for i in 0..count {
                        let tm = a + (i as f64 + 0.5) * dt;
                        reads.mids.push((n as u32, o + d * tm, dt));
                    }
                });
            reads.block(self, block.origin, &mut px);
        }
        Ok(px.finish(t, err, reads.lookups))
    }
}

/// What a band knows per pixel: its world ray, step, displacements, optical depths and bounds.
struct Pixels {
    /// World origin and unit direction.
    ray: Vec<(DVec3, DVec3)>,
    /// The march's step in world units along the ray.
    h: Vec<f64>,
    /// `K` displacements per velocity `S t_k / F` a pixel, then its `K` optical depths.
    ks: Vec<f64>,
    tau: Vec<f64>,
    /// `(sum mu_min len, sum mu_maj len)` over its chords.
    depth: Vec<(f64, f64)>,
    /// Whether any block chord crossed it.
    touched: Vec<bool>,
    k: usize,
}

impl Pixels {
    fn new(sw: &BlurSweep<'_>, y0: u32, y1: u32, k: usize) -> Result<Self> {
        let w = sw.camera.width;
        let n = ((y1 - y0 + 1) * w) as usize;
        let mut px = Self {
            ray: Vec::with_capacity(n),
            h: Vec::with_capacity(n),
            ks: Vec::with_capacity(n * k),
            tau: vec![0.0; n * k],
            depth: vec![(0.0, 0.0); n],
            touched: vec![false; n],
            k,
        };
        let (mut times, mut ks) = (Vec::new(), Vec::new());
        let step = sw.step;
        for j in y0..=y1 {
            for i in 0..w {
                let ray = sw.camera.pixel_ray(i, j)?;
                let id = u64::from(j) * u64::from(w) + u64::from(i);
                strata_times(sw.motion.spec(), (sw.seed, id), &mut times, &mut ks);
                px.ks.extend_from_slice(&ks);
                let vpw = sw.vol.to_index_dir(ray.direction()).length();
                px.h.push(step_world(vpw, step));
                px.ray.push((ray.origin(), ray.direction()));
            }
        }
        Ok(px)
    }

    /// Each pixel's `T` (the mean of its `K` values) and error bar, as the ray path finishes
    /// them; the band's statistics.
    fn finish(self, t: &mut [f32], err: &mut [f32], lookups: u64) -> BakeStats {
        let mut st = BakeStats {
            samples: t.len() as u64,
            lookups,
            ..BakeStats::default()
        };
        for n in 0..t.len() {
            let (value, e) = if self.touched[n] {
                let (lo, hi) = self.depth[n];
                let mut spread = marcher_spread(Bounds::new(0.0, lo, hi));
                for tau in &self.tau[n * self.k..(n + 1) * self.k] {
                    spread.push((-tau).exp());
                }
                (spread.mean, marcher_std_err(&spread))
            } else {
                // No block with density on the ray: `T = 1` exactly.
                (1.0, 0.0)
            };
            t[n] = value as f32;
            err[n] = e as f32;
            st.max_std_err = crate::bake::map::worse_std_err(st.max_std_err, e);
        }
        st
    }
}

/// A band's readers and the block at hand's midpoints: `(pixel, world point, piece length)`,
/// then the velocity at each.
struct Reads<'v> {
    density: Accessor<'v>,
    window: Window,
    velocity: VelocityLookup<'v>,
    index_from_world: DAffine3,
    world_from_index: DAffine3,
    scale: f64,
    mids: Vec<(u32, DVec3, f64)>,
    vels: Vec<DVec3>,
    lookups: u64,
    simd: Simd,
}

impl<'v> Reads<'v> {
    fn new(vol: &'v Volume, m: &'v Motion) -> Self {
        let index_from_world = vol.index_from_world();
        Self {
            density: Accessor::new(vol.tree()),
            window: Window::default(),
            velocity: m.field().lookup(),
            index_from_world,
            world_from_index: index_from_world.inverse(),
            scale: vol.density_scale(),
            mids: Vec::new(),
            vels: Vec::new(),
            lookups: 0,
            simd: Simd::active(),
        }
    }

    /// The midpoints gathered for the block at index `origin`: the velocity at each, then the
    /// density at each shutter time added to its pixel's optical depths.
    fn block(&mut self, sw: &BlurSweep<'_>, origin: [i64; 3], px: &mut Pixels) {
        if self.mids.is_empty() {
            return;
        }
        let reads = self.mids.len() * px.k;
        // Velocity: the block's world box (its 8 corners).
        let o = DVec3::from_array(origin.map(|c| c as f64));
        let (lo, hi) = crate::math::mapped_box(&self.world_from_index, o, o + 8.0);
        let budget = (self.mids.len() * VOXELS_PER_READ).min(MAX_WINDOW);
        self.velocity.cover(lo, hi, budget);
        self.vels.clear();
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if self.simd != Simd::Portable {
            let (mut p8, mut v8) = ([DVec3::ZERO; 8], [DVec3::ZERO; 8]);
            for chunk in self.mids.chunks_exact(8) {
                for (p, m) in p8.iter_mut().zip(chunk) {
                    *p = m.1;
                }
                #[allow(unsafe_code)]
                // SAFETY: `Simd::active` chose AVX-512 or AVX2 only on a CPU that runs it.
                unsafe {
                    if self.simd == Simd::Avx512 {
                        self.velocity.at8_avx512(&p8, &mut v8);
                    } else {
                        self.velocity.at8_avx2(&p8, &mut v8);
                    }
                }
                self.vels.extend_from_slice(&v8);
                done += 8;
            }
        }
        for &(_, p, _) in &self.mids[done..] {
            self.vels.push(self.velocity.at(p));
        }
        // Density: every point any time reads, `p - k v` for `k` at the shutter's ends.
        let spec = sw.motion.spec();
        let ends = [
            spec.displacement_per_velocity(spec.open()),
            spec.displacement_per_velocity(spec.close()),
        ];
        let (mut a, mut b) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (&(_, p, _), &v) in self.mids.iter().zip(&self.vels) {
            for k in ends {
                let u = self.index_from_world.transform_point3(p - k * v);
                a = a.min(u);
                b = b.max(u);
            }
        }
        let lo_v = [a.x, a.y, a.z].map(crate::math::floor_i64);
        let hi_v = [b.x, b.y, b.z].map(|c| crate::math::floor_i64(c) + 1);
        let dims = [0, 1, 2].map(|k| hi_v[k].saturating_sub(lo_v[k]).saturating_add(1));
        let voxels = dims
            .iter()
            .try_fold(1i64, |n, &d| n.checked_mul(d))
            .unwrap_or(i64::MAX);
        let fits = a.is_finite()
            && b.is_finite()
            && voxels > 0
            && (voxels as u64) <= (reads * VOXELS_PER_READ).min(MAX_WINDOW) as u64;
        if fits {
            let dims = dims.map(|d| d as usize);
            self.window.fill(&mut self.density, lo_v, dims);
        } else {
            self.window.clear();
        }
        let moved = Moved {
            window: &self.window,
            index_from_world: &self.index_from_world,
            scale: self.scale,
        };
        let work = (&self.mids[..], &self.vels[..]);
        add_all(self.simd, &moved, work, px, &mut self.density);
        self.lookups += reads as u64;
    }
}

/// Shutter times read together, one lane each.
const LANES: usize = 8;

/// What the reads of a block's midpoints share: the density's window and placement.
struct Moved<'w> {
    window: &'w Window,
    index_from_world: &'w DAffine3,
    scale: f64,
}

impl Moved<'_> {
    /// The density at `p - k v` for one `k`: [`BlurredMedium`]'s read (the window's copy, or
    /// the accessor outside it).
    ///
    /// [`BlurredMedium`]: crate::estimate::blur::BlurredMedium
    #[inline(always)]
    fn one(&self, p: DVec3, v: DVec3, k: f64, acc: &mut Accessor<'_>) -> f64 {
        let q = self.index_from_world.transform_point3(p - k * v).to_array();
        let x = match self.window.trilinear(q) {
            Some(x) => x,
            None => acc.trilinear(q),
        };
        scaled(self.scale, f64::from(x))
    }

    /// The density at `p - k_l v` for [`LANES`] times at once, with [`Moved::one`]'s bits:
    /// the same world point and index transform, lane by lane (`glam`'s order:
    /// `((m_x y_x + m_y y_y) + m_z y_z) + t`), the window's AVX-512 lanes
    /// ([`Window::trilinear8_avx512`]) or AVX2 half-lanes ([`Window::trilinear8_avx2`],
    /// `WIDE` false), then any lane outside it read on its own. Inlined into `add_avx512` and
    /// `add_avx2` only.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn lanes<const WIDE: bool>(
        &self,
        p: DVec3,
        v: DVec3,
        ks: &[f64; LANES],
        acc: &mut Accessor<'_>,
        out: &mut [f64; LANES],
    ) {
        let m = self.index_from_world;
        let (a, b, c, t) = (
            m.matrix3.x_axis,
            m.matrix3.y_axis,
            m.matrix3.z_axis,
            m.translation,
        );
        let mut q = [[0.0f64; LANES]; 3];
        for l in 0..LANES {
            let y = [p.x - ks[l] * v.x, p.y - ks[l] * v.y, p.z - ks[l] * v.z];
            q[0][l] = a.x * y[0] + b.x * y[1] + c.x * y[2] + t.x;
            q[1][l] = a.y * y[0] + b.y * y[1] + c.y * y[2] + t.y;
            q[2][l] = a.z * y[0] + b.z * y[1] + c.z * y[2] + t.z;
        }
        let mut x = [0f32; LANES];
        #[allow(unsafe_code)]
        // SAFETY: called only from `add_avx512` (`WIDE`), on a CPU that runs AVX-512F, or
        // from `add_avx2`, on one that runs AVX2.
        let mut outside = unsafe {
            if WIDE {
                self.window.trilinear8_avx512([&q[0], &q[1], &q[2]], &mut x)
            } else {
                self.window.trilinear8_avx2([&q[0], &q[1], &q[2]], &mut x)
            }
        };
        for (o, &x) in out.iter_mut().zip(&x) {
            *o = scaled(self.scale, f64::from(x));
        }
        while outside != 0 {
            let l = outside.trailing_zeros() as usize;
            out[l] = self.one(p, v, ks[l], acc);
            outside &= outside - 1;
        }
    }
}

/// Every midpoint's density reads at its pixel's shutter times, added to its optical depths:
/// `tau_k += mu(p - k v) dt`, [`LANES`] times at once with `LANES_ON` (AVX-512 lanes with
/// `WIDE`, AVX2 half-lanes without), one by one otherwise; the same bits either way.
#[inline(always)]
fn add_reads<const LANES_ON: bool, const WIDE: bool>(
    moved: &Moved<'_>,
    (mids, vels): (&[(u32, DVec3, f64)], &[DVec3]),
    px: &mut Pixels,
    acc: &mut Accessor<'_>,
) {
    let k = px.k;
    #[cfg(target_arch = "x86_64")]
    let mut mu = [0.0f64; LANES];
    for (&(n, p, dt), &v) in mids.iter().zip(vels) {
        let n = n as usize;
        let (ks, tau) = (&px.ks[n * k..(n + 1) * k], &mut px.tau[n * k..(n + 1) * k]);
        #[allow(unused_mut)]
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if LANES_ON {
            for (kc, tc) in ks.chunks_exact(LANES).zip(tau.chunks_exact_mut(LANES)) {
                let kc: &[f64; LANES] = kc.try_into().unwrap_or(&[0.0; LANES]);
                moved.lanes::<WIDE>(p, v, kc, acc, &mut mu);
                for (t, m) in tc.iter_mut().zip(&mu) {
                    *t += m * dt;
                }
                done += LANES;
            }
        }
        for (t, &kk) in tau[done..].iter_mut().zip(&ks[done..]) {
            *t += moved.one(p, v, kk, acc) * dt;
        }
    }
}

/// [`add_reads`] at the level `simd` this CPU runs: AVX-512 lanes, AVX2 half-lanes, or one
/// read at a time (portable).
#[allow(unsafe_code)]
fn add_all(
    simd: Simd,
    moved: &Moved<'_>,
    work: (&[(u32, DVec3, f64)], &[DVec3]),
    px: &mut Pixels,
    acc: &mut Accessor<'_>,
) {
    match simd {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `Simd::active` chose the level only if this CPU runs it.
        Simd::Avx512 => unsafe { add_avx512(moved, work, px, acc) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Simd::Avx2 => unsafe { add_avx2(moved, work, px, acc) },
        _ => add_reads::<false, false>(moved, work, px, acc),
    }
}

/// [`add_reads`] in half-lanes compiled for AVX2 (4 `f64` lanes a register; no FMA, so every
/// blend rounds as the scalar read's).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn add_avx2(
    moved: &Moved<'_>,
    work: (&[(u32, DVec3, f64)], &[DVec3]),
    px: &mut Pixels,
    acc: &mut Accessor<'_>,
) {
    add_reads::<true, false>(moved, work, px, acc);
}

/// [`add_reads`] in lanes compiled for AVX-512F (8 `f64` lanes a register).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(unsafe_code)]
unsafe fn add_avx512(
    moved: &Moved<'_>,
    work: (&[(u32, DVec3, f64)], &[DVec3]),
    px: &mut Pixels,
    acc: &mut Accessor<'_>,
) {
    add_reads::<true, true>(moved, work, px, acc);
}
