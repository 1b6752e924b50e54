//! Ray marching in object order: `riemann`, `jittered` and `mc` maps swept block by block.
//!
//! The ray path's marchers ([`crate::estimate::marching`]) cut every ray into the chords of the
//! `8^3` blocks of lookup space and lay `n = ceil(L / h)` equal pieces of length `dt` on each
//! chord; point `j` of a chord starting at `a` is at `a + (j + w_j) dt`, with `w_j = 1/2`
//! (`riemann`), a uniform `u_j` (`jittered`) or `n u_j - j` (`mc`: `n` uniform points on the
//! chord), the `u_j` drawn from the sample's stream forked by the chord's block
//! ([`crate::rng::Rng::fork`]). A chord's points therefore depend on its block, its pixel's
//! ray id and the sample alone, and the sweep reads them from the block's `9^3` corners in L1
//! ([`Kernel::march`], 8 chords per AVX2 register), adding `scale x sum_j f(x_j) dt` to the
//! pixel's optical depth.
//!
//! What the ray walk does not march, the sweep does not either: blocks whose halo is one value
//! are closed form, a tile's inner box (where every lookup reads the tile alone) is closed form
//! and only its halo cells are marched ([`tile_split`]), a leaf with an infinite value is
//! integrated exactly. A shell block (its chord inside a tile above lower nodes) is marched by
//! the ray path itself over its chord ([`crate::estimate::march_sample`]).
//!
//! **Samples and slices.** A random march keeps `samples x (1 + K)` optical depths per pixel
//! (`K` slices); `T` is the mean of `exp(-tau_i)` over samples and its standard error that of
//! the mean, as the ray path computes them. The ray path estimates slice `k` (`[0, t_k]`) as
//! its own ray with ray id `(64 + k) npix + p`, so a random march gives every chord before
//! `t_k` a lane of slice `k`'s stream; the midpoint march shares a whole chord's sum with
//! every slice past its end and adds a lane only for a chord a slice depth cuts.
//!
//! Every pixel and slice equals the ray path's estimate to within the kernel's f32 positions
//! (`marches_match_the_ray_path` in the sweep's tests).

use super::band::{BandKernel, BandRows, Crossing, Filled, Reads};
use super::pieces::{Part, Piece};
use super::rays::Layout;
use super::Sweep;
use crate::bake::camera::Camera;
use crate::bake::map::BakeSettings;
use crate::error::Result;
use crate::estimate::marching::{pieces, pieces_lanes, step_world};
use crate::estimate::{Algo, Bounds, Estimator, Options, Spread};
use crate::regular::kernel::{Kernel, Lanes, Simd, Steps, BLOCK, LANES};
use crate::regular::{leaf_integral, Counts};
use crate::rng::Rng;
use crate::tree::Accessor;
use crate::volume::Interp;
use glam::DVec3;

/// Where a march puts its points in their pieces.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Points {
    /// `riemann`: the midpoints.
    Midpoint,
    /// `jittered`: one uniform point per piece.
    Jittered,
    /// `mc`: `n` uniform points on the chord.
    Uniform,
}

/// A ray march the sweep renders: the estimator, its options and step, where its points lie.
#[derive(Debug, Clone, Copy)]
pub(crate) struct March {
    est: Estimator,
    opts: Options,
    step: f64,
    points: Points,
}

impl March {
    /// The estimator and its options.
    #[cfg(test)]
    pub(super) fn estimator(&self) -> (Estimator, Options) {
        (self.est, self.opts)
    }

    /// True for the random marches (`jittered`, `mc`).
    pub(crate) fn random(&self) -> bool {
        self.points != Points::Midpoint
    }

    /// Estimates per pixel: one for the midpoint march, `--spp` for a random one.
    pub(crate) fn samples(&self) -> usize {
        match self.points {
            Points::Midpoint => 1,
            _ => self.opts.samples.max(1) as usize,
        }
    }
}

/// The march the sweep renders for these settings: `riemann`, `jittered` or `mc` with
/// trilinear lookups and a fixed sample count. `None` for any other estimator.
pub(crate) fn marches(s: &BakeSettings) -> Option<March> {
    if !s.estimator.marches() || s.options.interp != Interp::Trilinear || s.target_error.is_some() {
        return None;
    }
    let points = match s.estimator.algo().0 {
        Algo::Riemann => Points::Midpoint,
        Algo::Jittered => Points::Jittered,
        _ => Points::Uniform,
    };
    Some(March {
        est: s.estimator,
        opts: s.options,
        step: s.estimator.param("step")?,
        points,
    })
}

/// One estimate a chord feeds: the value it adds to (offset in the pixel's sample block), where
/// its part of the chord ends, the ray id of its stream, and whether every slice past its end
/// shares it (the midpoint march's whole chords).
#[derive(Debug, Clone, Copy)]
pub(super) struct Job {
    pub(super) slot: usize,
    pub(super) end: f64,
    pub(super) ray_id: u64,
    shared: bool,
}

/// Up to [`LANES`] chords waiting for the kernel: their lanes, pieces, point offsets, and per
/// lane the band buffer index it adds to, whether slices share it, and its end. A midpoint
/// march keeps each lane's chord in f64 ([`Staged`]) until the batch is full, and then sets
/// the lanes and counts their pieces for the whole batch at once ([`Batch::set_staged`]).
struct Batch {
    lanes: Lanes,
    steps: Steps,
    offsets: Vec<[f32; LANES]>,
    at: [(usize, bool, f64); LANES],
    staged: Staged,
    used: usize,
}

/// The midpoint lanes before [`Batch::set_staged`], per lane: the block-centred entry point
/// and lookup-space direction (per axis), the chord's length and the step (world units).
struct Staged {
    e: [[f64; LANES]; 3],
    d: [[f64; LANES]; 3],
    len: [f64; LANES],
    h: [f64; LANES],
}

impl Staged {
    /// Lane `l`: the chord from `e` along `d` for `len`, at step `h`.
    #[inline]
    fn set(&mut self, l: usize, e: [f64; 3], d: DVec3, len: f64, h: f64) {
        for k in 0..3 {
            self.e[k][l] = e[k];
            self.d[k][l] = d[k];
        }
        self.len[l] = len;
        self.h[l] = h;
    }
}

impl Batch {
    fn new() -> Self {
        Self {
            lanes: Lanes::default(),
            steps: Steps::default(),
            offsets: Vec::new(),
            at: [(0, false, 0.0); LANES],
            // Unused lanes' steps stay finite (no division by zero in `pieces_lanes`).
            staged: Staged {
                e: [[0.0; LANES]; 3],
                d: [[0.0; LANES]; 3],
                len: [0.0; LANES],
                h: [1.0; LANES],
            },
            used: 0,
        }
    }

    /// The staged lanes `0..used` set and their pieces counted ([`pieces_lanes`]): what the
    /// midpoint march would set lane by lane, the same numbers, with the lanes' divisions and
    /// conversions (a long dependency chain per chord) done side by side.
    fn set_staged(&mut self, simd: Simd) {
        let c = &self.staged;
        for l in 0..self.used {
            let at = |v: &[[f64; LANES]; 3]| [v[0][l], v[1][l], v[2][l]];
            self.lanes.set(l, at(&c.e), at(&c.d), c.len[l]);
        }
        let steps = &mut self.steps;
        pieces_lanes(simd, (&c.len, &c.h), self.used, &mut steps.n, &mut steps.dt);
    }
}

impl Sweep<'_> {
    /// The estimates chord `[a, b]` of image pixel `p` feeds (see [`Job`]); `random`: every
    /// slice past the chord is an estimate of its own (random marches, null collisions).
    pub(super) fn jobs(&self, random: bool, (a, b): (f64, f64), p: u64, out: &mut Vec<Job>) {
        out.clear();
        let npix = u64::from(self.camera.width) * u64::from(self.camera.height);
        out.push(Job {
            slot: 0,
            end: b,
            ray_id: p,
            shared: !random,
        });
        for (k, &t) in self.depths.iter().enumerate() {
            let cut = t > a && t < b;
            if cut || (random && t >= b) {
                out.push(Job {
                    slot: 1 + k,
                    end: t.min(b),
                    ray_id: (64 + k as u64).wrapping_mul(npix).wrapping_add(p),
                    shared: false,
                });
            }
        }
    }

    /// Add `v` to `tau[at]`, and to every slice of that estimate past `end` when the slices
    /// share it.
    fn credit(&self, tau: &mut [f64], at: usize, (shared, end): (bool, f64), v: f64) {
        tau[at] += v;
        if shared {
            for (k, &t) in self.depths.iter().enumerate() {
                if t >= end {
                    tau[at + 1 + k] += v;
                }
            }
        }
    }

    /// One estimate of a block the kernel does not take, over `[a, end]` of pixel `px`'s ray
    /// (`q + d t` in lookup space), with the stream of `ray_id` and sample `i`: closed form for
    /// a constant block, exact for a leaf with an infinite value, the f64 march of the ray path
    /// for other leaves, the ray path itself for tiles and shell blocks.
    #[allow(clippy::too_many_arguments)]
    fn scalar(
        &self,
        m: &March,
        p: &Piece,
        (q, d): (DVec3, DVec3),
        (a, end, ray_id, i): (f64, f64, u64, u32),
        key: [i64; 3],
        (px, y0): (usize, u32),
        acc: &mut Accessor<'_>,
        n: &mut Counts,
    ) -> f64 {
        let tree = self.vol.tree();
        let scale = self.vol.density_scale();
        let (qa, da) = (q.to_array(), d.to_array());
        match p.part {
            Part::Const(mu) => mu * (end - a),
            Part::Leaf { leaf, .. }
                if !crate::math::scaled(scale, f64::from(tree.leaves[leaf as usize].halo.max))
                    .is_finite() =>
            {
                scale * leaf_integral(acc, leaf, qa, da, a, end, Interp::Trilinear, n)
            }
            Part::Leaf { .. } => {
                let h = step_world(d.length(), m.step);
                let (count, dt) = pieces(end - a, h);
                n.reads += count;
                let mut rng = Rng::new(m.opts.seed, ray_id, u64::from(i)).fork(key);
                let mut sum = 0.0;
                for j in 0..count {
                    let t = match m.points {
                        Points::Midpoint => a + (j as f64 + 0.5) * dt,
                        Points::Jittered => a + (j as f64 + rng.uniform()) * dt,
                        Points::Uniform => a + rng.uniform() * (count as f64 * dt),
                    };
                    let v = acc.trilinear([0, 1, 2].map(|k| qa[k] + da[k] * t));
                    sum += crate::math::scaled(scale, f64::from(v)) * dt;
                }
                sum
            }
            Part::Tile { .. } | Part::Shell { .. } => {
                let w = self.rays.width;
                let (x, y) = (px as u32 % w, y0 + px as u32 / w);
                let ray = self
                    .camera
                    .pixel_ray(x, y)
                    .and_then(|r| r.with_range(a, end));
                match ray {
                    Ok(ray) => {
                        let (tau, reads) = crate::estimate::march_sample(
                            self.vol, &ray, ray_id, &m.est, &m.opts, i,
                        );
                        n.reads += reads;
                        tau
                    }
                    // Reported as a NaN optical depth by `finish_band` / `finish_samples`.
                    Err(_) => f64::NAN,
                }
            }
        }
    }
}

/// A march's share of a band: a leaf or a tile on the lane kernel adds each of its chords'
/// marched optical depth `scale x sum_j f(x_j) dt` to every estimate the chord feeds
/// ([`Kernel::march`], `Kernel::width` lanes at a time, a lane per job and sample; a marched
/// tile's inner box in closed form); any other block goes through [`Sweep::scalar`] per chord.
pub(super) struct MarchBand<'s, 'a> {
    sw: &'s Sweep<'a>,
    m: &'s March,
    tau: &'s mut [f64],
    kernel: Kernel,
    width: usize,
    /// Values per pixel, per estimate (the full ray and its slices), estimates per pixel.
    stride: usize,
    per: usize,
    samples: usize,
    scale: f64,
    /// The band's first row.
    y0: u32,
    /// The step in world units for parallel rays (through a pinhole it is per pixel).
    h_parallel: Option<f64>,
    batch: Batch,
    jobs: Vec<Job>,
    /// The inner boxes of a marched tile's chords: pixel and `[ia, ib]`.
    consts: Vec<(usize, f64, f64)>,
    lookups: u64,
}

/// What a block the march takes on the lane kernel carries: its stream key (the block's
/// index `o / 8`), and whether it is a tile (whose inner box is closed form).
pub(super) struct MarchOn {
    key: [i64; 3],
    tile: bool,
}

impl<'s, 'a> MarchBand<'s, 'a> {
    /// March `m` into the buffer `tau` (zeros) of the band from row `y0`.
    pub(super) fn new(sw: &'s Sweep<'a>, m: &'s March, y0: u32, tau: &'s mut [f64]) -> Self {
        let kernel = Kernel::new();
        let h_parallel = match &sw.rays.layout {
            Layout::Parallel(par) => Some(step_world(par.d.length(), m.step)),
            Layout::Pinhole { .. } => None,
        };
        Self {
            sw,
            m,
            tau,
            kernel,
            width: kernel.width(),
            stride: sw.stride(),
            per: 1 + sw.depths.len(),
            samples: m.samples(),
            scale: sw.vol.density_scale(),
            y0,
            h_parallel,
            batch: Batch::new(),
            jobs: Vec::new(),
            consts: Vec::new(),
            lookups: 0,
        }
    }

    /// The ray id of the band's pixel `px` (the image's pixel index).
    fn pixel_id(&self, px: usize) -> u64 {
        u64::from(self.y0) * u64::from(self.sw.rays.width) + px as u64
    }

    /// The waiting lanes marched through `block`, each added to its estimate.
    fn flush(&mut self, block: &[f32; BLOCK]) {
        let batch = &mut self.batch;
        let midpoint = self.m.points == Points::Midpoint;
        if midpoint {
            batch.set_staged(self.kernel.simd());
        }
        let offsets = (!midpoint).then_some(&batch.offsets[..]);
        let sums = self
            .kernel
            .march(block, &batch.lanes, &batch.steps, offsets);
        for (l, &(at, shared, end)) in batch.at.iter().enumerate().take(batch.used) {
            self.lookups += u64::from(sums.cells[l]);
            self.sw
                .credit(self.tau, at, (shared, end), self.scale * sums.tau[l]);
        }
        // Lanes the next batch leaves unfilled must read as unused (`n = 0`; the march reads
        // no other field of an unused lane unmasked).
        batch.steps.n = [0; LANES];
        batch.used = 0;
    }

    /// The one estimate of a midpoint chord without slices (`Sweep::jobs`: slot 0, to `b`,
    /// shared; one sample) staged: pixel `px`'s chord `[a, b]` from the block-centred entry
    /// point `e` along `d`, at step `h`, through the block `at`.
    #[inline]
    fn stage(
        &mut self,
        px: usize,
        e: [f64; 3],
        d: DVec3,
        (a, b): (f64, f64),
        h: f64,
        at: &Filled<'_>,
    ) {
        let batch = &mut self.batch;
        let l = batch.used;
        batch.staged.set(l, e, d, b - a, h);
        batch.at[l] = (px * self.stride, true, b);
        batch.used += 1;
        if batch.used == self.width {
            self.flush(at.block);
        }
    }

    /// The lanes of part `[a, b]` of a chord (`c`, through the block `at` with stream key
    /// `key`; step `h`): one per job and sample, its pieces and, for a random march, its points'
    /// offsets from the sample's stream forked by the block.
    fn lanes(&mut self, key: [i64; 3], at: &Filled<'_>, c: Crossing, h: f64) {
        let Crossing { px, q, d, a, b } = c;
        let e = ((q - at.centre) + d * a).to_array();
        let m = self.m;
        if m.points == Points::Midpoint && self.sw.depths.is_empty() {
            self.stage(px, e, d, (a, b), h, at);
            return;
        }
        self.sw
            .jobs(m.random(), (a, b), self.pixel_id(px), &mut self.jobs);
        // Taken for the loop: a full batch flushes (`&mut self`) inside it.
        let jobs = std::mem::take(&mut self.jobs);
        for job in &jobs {
            let (count, dt) = pieces(job.end - a, h);
            for i in 0..self.samples {
                let batch = &mut self.batch;
                let l = batch.used;
                if m.points == Points::Midpoint {
                    batch.staged.set(l, e, d, job.end - a, h);
                } else {
                    batch.lanes.set(l, e, d.to_array(), job.end - a);
                    batch.steps.n[l] = count as u32;
                    batch.steps.dt[l] = dt as f32;
                    let rows = count as usize;
                    if batch.offsets.len() < rows {
                        batch.offsets.resize(rows, [0.0; LANES]);
                    }
                    let mut rng = Rng::new(m.opts.seed, job.ray_id, i as u64).fork(key);
                    for (j, row) in batch.offsets.iter_mut().take(rows).enumerate() {
                        let u = rng.uniform();
                        row[l] = match m.points {
                            Points::Uniform => (count as f64 * u - j as f64) as f32,
                            _ => u as f32,
                        };
                    }
                }
                batch.at[l] = (
                    px * self.stride + i * self.per + job.slot,
                    job.shared,
                    job.end,
                );
                batch.used += 1;
                if batch.used == self.width {
                    self.flush(at.block);
                }
            }
        }
        self.jobs = jobs;
    }
}

impl BandKernel for MarchBand<'_, '_> {
    type On = MarchOn;

    /// Leaves and tiles whose values the f32 kernel takes; shell blocks go by the ray path.
    fn enter(&mut self, p: &Piece) -> Option<MarchOn> {
        let tile = match p.part {
            Part::Leaf { fast: true, .. } => false,
            Part::Tile { fast: true, .. } => true,
            _ => return None,
        };
        self.consts.clear();
        Some(MarchOn {
            key: p.origin.map(|c| c >> 3),
            tile,
        })
    }

    /// Each estimate of each chord by [`Sweep::scalar`].
    fn off_kernel(
        &mut self,
        p: &Piece,
        rows: (u32, u32, u32),
        band: &BandRows,
        reads: &mut Reads<'_>,
    ) {
        let (sw, m, y0) = (self.sw, self.m, self.y0);
        let (stride, per, samples) = (self.stride, self.per, self.samples);
        let key = p.origin.map(|c| c >> 3);
        let Reads { acc, n } = reads;
        let jobs = &mut self.jobs;
        let tau = &mut *self.tau;
        sw.chords(p, rows, &band.dirs, |px, q, d, a, b| {
            let id = u64::from(y0) * u64::from(sw.rays.width) + px as u64;
            sw.jobs(m.random(), (a, b), id, jobs);
            for job in jobs.iter() {
                for i in 0..samples {
                    let part = (a, job.end, job.ray_id, i as u32);
                    let v = sw.scalar(m, p, (q, d), part, key, (px, y0), acc, n);
                    sw.credit(
                        tau,
                        px * stride + i * per + job.slot,
                        (job.shared, job.end),
                        v,
                    );
                }
            }
        });
    }

    /// A leaf's chords on parallel rays in a midpoint march without slices: the chords
    /// [`Sweep::chords`] gives, in its order, staged straight into the batch (the lanes
    /// [`BandKernel::chord`] would stage, without its calls per chord); any other piece or
    /// march through [`BandKernel::chord`].
    fn piece_chords(
        &mut self,
        sw: &Sweep<'_>,
        (p, rows): (&Piece, (u32, u32, u32)),
        band: &BandRows,
        on: &MarchOn,
        at: &Filled<'_>,
    ) {
        let (Layout::Parallel(par), Some(h), false, Points::Midpoint, true) = (
            &sw.rays.layout,
            self.h_parallel,
            on.tile,
            self.m.points,
            sw.depths.is_empty(),
        ) else {
            sw.chords(p, rows, &band.dirs, |px, q, d, a, b| {
                self.chord(on, at, Crossing { px, q, d, a, b });
            });
            return;
        };
        let ((ja, jb, y0), w, d) = (rows, sw.rays.width, par.d);
        let [i0, i1, ..] = p.rect;
        for j in ja..=jb {
            let row = sw.rays.row_clip(par, j, p.origin, 8);
            let Some([i0, i1]) = row.span([i0, i1]) else {
                continue;
            };
            for i in i0..=i1 {
                let Some((q, a, b)) = row.at(i) else {
                    continue;
                };
                let px = ((j - y0) * w + i) as usize;
                // As `MarchBand::lanes` stages it.
                self.stage(px, ((q - at.centre) + d * a).to_array(), d, (a, b), h, at);
            }
        }
    }

    /// The chord's lanes; a marched tile's chord is split around its inner box
    /// ([`tile_split`]), which is kept for [`BandKernel::leave`].
    #[inline]
    fn chord(&mut self, on: &MarchOn, at: &Filled<'_>, c: Crossing) {
        let Crossing { px, q, d, a, b } = c;
        let parts = if on.tile {
            let (parts, inner) = tile_split(q, d, at.origin, (a, b));
            self.consts.extend(inner.map(|(ia, ib)| (px, ia, ib)));
            parts
        } else {
            [Some((a, b)), None]
        };
        let h = self
            .h_parallel
            .unwrap_or_else(|| step_world(d.length(), self.m.step));
        for (a, b) in parts.into_iter().flatten() {
            self.lanes(on.key, at, Crossing { px, q, d, a, b }, h);
        }
    }

    /// The waiting lanes, then a marched tile's inner boxes: the tile's value in closed form,
    /// in every estimate.
    fn leave(&mut self, p: &Piece, _: &MarchOn, at: &Filled<'_>) {
        if self.batch.used > 0 {
            self.flush(at.block);
        }
        let Part::Tile { lower, slot, .. } = p.part else {
            return;
        };
        let (sw, tree) = (self.sw, self.sw.vol.tree());
        let v = tree.lowers[lower as usize].tile_value(slot as usize);
        let mu = if v == tree.background {
            sw.vol.mu_background()
        } else {
            crate::math::scaled(self.scale, f64::from(v))
        };
        for c in 0..self.consts.len() {
            let (px, ia, ib) = self.consts[c];
            sw.jobs(self.m.random(), (ia, ib), self.pixel_id(px), &mut self.jobs);
            for job in &self.jobs {
                for i in 0..self.samples {
                    let at = px * self.stride + i * self.per + job.slot;
                    sw.credit(self.tau, at, (job.shared, job.end), mu * (job.end - ia));
                }
            }
        }
    }

    fn finish(self) -> u64 {
        self.lookups
    }
}

/// How the ray walk splits a tile's chord `[a, b]` (`crate::traverse::hdda`'s `tile`): the
/// inner box `[o, o + 7]^3` where every trilinear lookup reads the tile alone is constant, the
/// rest (the halo cells on its + faces) is sampled. Returns the sampled parts (before and after
/// the inner box) and the inner part, or the whole chord sampled when the ray misses the box.
#[allow(clippy::type_complexity)]
pub(super) fn tile_split(
    q: DVec3,
    d: DVec3,
    o: [i64; 3],
    (a, b): (f64, f64),
) -> ([Option<(f64, f64)>; 2], Option<(f64, f64)>) {
    let lo = DVec3::from(o.map(|c| c as f64));
    match crate::ray::clip_box(q, d, lo, lo + DVec3::splat(7.0)) {
        Some((ia, ib)) if ia.max(a) < ib.min(b) => {
            let (ia, ib) = (ia.max(a), ib.min(b));
            let part = |x: f64, y: f64| (x < y).then_some((x, y));
            // The ray path merges sampled segments that touch within round-off into one span
            // (`marching::spans`): a ray grazing the inner box is marched whole.
            if a < ia && ib < b && ib <= ia + 1e-12 * ia.abs().max(1.0) {
                return ([Some((a, b)), None], Some((ia, ib)));
            }
            ([part(a, ia), part(ib, b)], Some((ia, ib)))
        }
        _ => ([Some((a, b)), None], None),
    }
}

/// A band of a random march or a null-collision map finished: per pixel, `T` the mean over its
/// `samples` estimates (each estimate `per` values: the full ray, then its slices; optical
/// depths `tau_i`, taken as `exp(-tau_i)`, or, for a null-collision map (`flight`: its
/// estimator and each pixel's bounds on `T`, or none when `err` is empty), the transmittance
/// estimates themselves) into `t_band`, the error bar of that mean into `err` (when it is not
/// empty; [`crate::estimate::error_bar`], as the ray path reports it), and the slices' means
/// (pixel-major) returned. A NaN value is the ray's error.
pub(super) fn finish_samples(
    camera: &Camera,
    y0: u32,
    tau: &[f64],
    (per, samples): (usize, usize),
    flight: Option<(&Estimator, &[Bounds])>,
    t_band: &mut [f32],
    err: &mut [f32],
) -> Result<Vec<f32>> {
    let direct = flight.is_some();
    let w = camera.width;
    let mut slices = Vec::with_capacity(t_band.len() * (per - 1));
    for (px, est) in tau.chunks(per * samples).enumerate() {
        if est.iter().any(|x| x.is_nan()) {
            let (i, j) = (px as u32 % w, y0 + px as u32 / w);
            let ray = camera.pixel_ray(i, j)?;
            let what = if direct {
                "transmittance estimate"
            } else {
                "optical depth"
            };
            return Err(crate::error::Error::nan_on_ray(what, &ray));
        }
        let mean_of = |slot: usize| {
            let t = move |i: usize| {
                let v = est[i * per + slot];
                if direct {
                    v
                } else {
                    (-v).exp()
                }
            };
            let mean = (0..samples).map(t).sum::<f64>() / samples as f64;
            (mean, t)
        };
        let (mean, t) = mean_of(0);
        t_band[px] = mean as f32;
        if !err.is_empty() {
            let mut spread = match flight {
                Some((est, bounds)) => Spread::of(est, bounds.get(px).copied().unwrap_or_default()),
                None => Spread::default(),
            };
            (0..samples).for_each(|i| spread.push(t(i)));
            err[px] = spread.std_err() as f32;
        }
        slices.extend((1..per).map(|k| mean_of(k).0 as f32));
    }
    Ok(slices)
}
