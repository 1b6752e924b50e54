//! One band of the sweep: the loop every estimator runs over a band's pieces
//! ([`Sweep::run_band`]), and the exact integral's share of it ([`ExactBand`]).
//!
//! A band (image rows `y0..=y1`) visits its pieces in tree order. A piece goes on the lane
//! kernel (its block's `9^3` corners copied into L1 once, [`fill`], then every chord of every
//! pixel its footprint covers, [`Sweep::chords`]) or off it (closed form, the f64 code of
//! [`crate::regular`], or the ray path per chord). What a piece and its chords add is the
//! estimator's, a [`BandKernel`]: [`ExactBand`] (`tau += int mu_t dt` per chord),
//! `march::MarchBand` (`tau += sum_j mu(x_j) dt` per sample) and
//! `flight::FlightBand` (a product of unbiased chord factors per sample). The loop is
//! generic over the kernel, so each band is monomorphised and dispatched once. Every pixel
//! takes its pieces' contributions in piece order, so a map is the same bits whatever the bands
//! or threads.

use super::pieces::{neighbourhood, Part, Piece};
use super::rays::PixelDir;
use super::Sweep;
use crate::error::Result;
use crate::regular::kernel::{fill, Kernel, Lanes, BLOCK, LANES};
use crate::regular::{cells_integral, leaf_integral, optical_depth_above_lowers, Counts};
use crate::tree::Accessor;
use crate::volume::Interp;
use glam::DVec3;

/// A band's rows `y0..=y1` and, through a pinhole, each pixel's lookup-space direction (as the
/// ray path computes it; empty for parallel rays).
pub(super) struct BandRows {
    pub(super) y0: u32,
    pub(super) y1: u32,
    pub(super) dirs: Vec<PixelDir>,
}

impl BandRows {
    /// The rows of piece `p` in this band, as [`Sweep::chords`] takes them: `(ja, jb, y0)`, the
    /// band's rows its footprint `[j0, j1]` covers and the band's first row.
    fn of(&self, p: &Piece) -> (u32, u32, u32) {
        let [_, _, j0, j1] = p.rect;
        (j0.max(self.y0), j1.min(self.y1), self.y0)
    }
}

/// What a band reads off the lane kernel: the tree through a cached accessor, and the lookups
/// that costs, counted as the ray path counts them.
pub(super) struct Reads<'t> {
    pub(super) acc: Accessor<'t>,
    pub(super) n: Counts,
}

/// A block on the lane kernel: its `9^3` corner values ([`fill`]), its lookup-space origin `o`
/// and its centre `o + 4`, which lane entry points are relative to.
pub(super) struct Filled<'b> {
    pub(super) block: &'b [f32; BLOCK],
    pub(super) origin: [i64; 3],
    pub(super) centre: DVec3,
}

/// One pixel's ray through a block: the pixel's index in the band, the ray `q + t d` in lookup
/// space, and its chord `[a, b]` inside the block (and the walk's clip box).
#[derive(Debug, Clone, Copy)]
pub(super) struct Crossing {
    pub(super) px: usize,
    pub(super) q: DVec3,
    pub(super) d: DVec3,
    pub(super) a: f64,
    pub(super) b: f64,
}

/// What one estimator adds to a band's buffer, piece by piece ([`Sweep::run_band`] calls these
/// in this order): `start`, then per piece in tree order either `off_kernel`, or `chord` for
/// every chord of the piece (pixels row by row) and `leave`; then `finish`.
pub(super) trait BandKernel {
    /// What a piece on the lane kernel carries to its chords (its bounds and rates, stream key).
    type On;

    /// Before the pieces: what the band's rays get outside lower nodes (the exact map's rest
    /// walk); nothing by default.
    fn start(&mut self, _band: &BandRows, _reads: &mut Reads<'_>) -> Result<()> {
        Ok(())
    }

    /// Whether piece `p` goes on the lane kernel: its data when it does, `None` when
    /// [`BandKernel::off_kernel`] takes it.
    fn enter(&mut self, p: &Piece) -> Option<Self::On>;

    /// Every chord of piece `p` in `rows` (as [`Sweep::chords`] takes them) when the lane kernel
    /// does not take the piece.
    fn off_kernel(
        &mut self,
        p: &Piece,
        rows: (u32, u32, u32),
        band: &BandRows,
        reads: &mut Reads<'_>,
    );

    /// One chord of a piece on the lane kernel, its block's corners in `at`.
    fn chord(&mut self, on: &Self::On, at: &Filled<'_>, c: Crossing);

    /// Every chord of piece `p` on the lane kernel in `rows` (as [`Sweep::chords`] takes
    /// them): [`BandKernel::chord`] for each chord [`Sweep::chords`] gives, pixels row by row.
    /// A kernel may walk them itself, in the same order, where it has a shorter loop.
    fn piece_chords(
        &mut self,
        sw: &Sweep<'_>,
        (p, rows): (&Piece, (u32, u32, u32)),
        band: &BandRows,
        on: &Self::On,
        at: &Filled<'_>,
    ) {
        sw.chords(p, rows, &band.dirs, |px, q, d, a, b| {
            self.chord(on, at, Crossing { px, q, d, a, b });
        });
    }

    /// After the chords of piece `p`: the lanes still waiting, and closed-form parts.
    fn leave(&mut self, p: &Piece, on: &Self::On, at: &Filled<'_>);

    /// After the pieces: the band's buffer finished; the lookups the kernel spent.
    fn finish(self) -> u64;
}

impl Sweep<'_> {
    /// The loop every band runs over its pieces `ids` (in tree order) with estimator `k` (see
    /// [`BandKernel`]); the lookups spent.
    pub(super) fn run_band<K: BandKernel>(
        &self,
        ids: &[u32],
        band: &BandRows,
        mut k: K,
    ) -> Result<u64> {
        let tree = self.vol.tree();
        let mut reads = Reads {
            acc: Accessor::new(tree),
            n: Counts::default(),
        };
        k.start(band, &mut reads)?;
        let mut block = [0f32; BLOCK];
        for &id in ids {
            let p = &self.pieces[id as usize];
            let rows = band.of(p);
            let Some(on) = k.enter(p) else {
                k.off_kernel(p, rows, band, &mut reads);
                continue;
            };
            fill(&neighbourhood(tree, &mut reads.acc, p), &mut block);
            let at = Filled {
                block: &block,
                origin: p.origin,
                centre: DVec3::from(p.origin.map(|c| (c + 4) as f64)),
            };
            k.piece_chords(self, (p, rows), band, &on, &at);
            k.leave(p, &on, &at);
        }
        Ok(k.finish() + reads.n.reads)
    }

    /// Each pixel's lookup-space direction through a pinhole, rows `y0..=y1`
    /// ([`super::rays::Rays::pixel_dirs`]).
    pub(super) fn pixel_dirs(&self, y0: u32, y1: u32) -> Result<Vec<PixelDir>> {
        self.rays.pixel_dirs(self.vol, self.camera, y0, y1)
    }

    /// Add a piece's contribution to pixel `n`'s full optical depth and to every slice whose
    /// depth is past the chord's end `b`; the slices the chord straddles (`a < t_k < b`) are
    /// `partial(t_k)`, the contribution of `[a, t_k]`.
    fn add(
        &self,
        buf: &mut [f64],
        n: usize,
        (a, b): (f64, f64),
        full: f64,
        mut partial: impl FnMut(f64) -> f64,
    ) {
        let s = self.stride();
        buf[n * s] += full;
        for (k, &t) in self.depths.iter().enumerate() {
            if t >= b {
                buf[n * s + 1 + k] += full;
            } else if t > a {
                buf[n * s + 1 + k] += partial(t);
            }
        }
    }

    /// Every ray of rows `ja..=jb` (band rows from `y0`) that crosses piece `p`
    /// ([`super::rays::Rays::chords`]).
    pub(super) fn chords(
        &self,
        p: &Piece,
        rows: (u32, u32, u32),
        dirs: &[PixelDir],
        f: impl FnMut(usize, DVec3, DVec3, f64, f64),
    ) {
        self.rays.chords((p.origin, p.rect), rows, dirs, f);
    }
}

/// The exact integral's share of a band: a block on the lane kernel adds `scale x int f dt`
/// over each chord ([`Kernel::integrate`], `Kernel::width` lanes at a time, packed across
/// rows); a chord a slice depth `t_k` cuts adds one more lane for `[a, t_k]`. Constant blocks
/// add `mu x chord`, blocks off the kernel the f64 integral ([`leaf_integral`],
/// [`cells_integral`]); rays that need it start from their optical depth outside lower nodes.
pub(super) struct ExactBand<'s, 'a> {
    sw: &'s Sweep<'a>,
    tau: &'s mut [f64],
    kernel: Kernel,
    width: usize,
    stride: usize,
    scale: f64,
    lanes: Lanes,
    /// Per lane: the pixel, 0 (the whole chord) or 1 + k (slice k's part), and the chord's end.
    at: [(usize, usize, f64); LANES],
    used: usize,
    lookups: u64,
}

impl<'s, 'a> ExactBand<'s, 'a> {
    /// The exact integral into the band buffer `tau` (zeros).
    pub(super) fn new(sw: &'s Sweep<'a>, tau: &'s mut [f64]) -> Self {
        let kernel = Kernel::new();
        Self {
            sw,
            tau,
            kernel,
            width: kernel.width(),
            stride: sw.stride(),
            scale: sw.vol.density_scale(),
            lanes: Lanes::default(),
            at: [(0, 0, 0.0); LANES],
            used: 0,
            lookups: 0,
        }
    }

    /// The waiting lanes integrated over `block` and added to their pixels: a whole chord to
    /// the full depth and every slice past its end, a slice's part to that slice.
    fn flush(&mut self, block: &[f32; BLOCK]) {
        let sums = self.kernel.integrate(block, &self.lanes);
        let (stride, depths) = (self.stride, &self.sw.depths);
        for (l, &(px, slot, end)) in self.at.iter().enumerate().take(self.used) {
            if sums.cells[l] == 0 {
                continue;
            }
            let v = self.scale * sums.tau[l];
            self.lookups += 4 + 4 * u64::from(sums.cells[l]);
            if slot > 0 {
                self.tau[px * stride + slot] += v;
                continue;
            }
            self.tau[px * stride] += v;
            for (k, &t) in depths.iter().enumerate() {
                if t >= end {
                    self.tau[px * stride + 1 + k] += v;
                }
            }
        }
        // Lanes the next batch leaves unfilled must read as unused (`len = 0`); their other
        // fields are never read unmasked.
        self.lanes.len = [0.0; LANES];
        self.used = 0;
    }
}

impl BandKernel for ExactBand<'_, '_> {
    type On = ();

    /// Rays that meet extinction outside lower nodes start from its optical depth (and each
    /// slice's), walked at lower-node granularity.
    fn start(&mut self, band: &BandRows, reads: &mut Reads<'_>) -> Result<()> {
        let sw = self.sw;
        if !sw.rest_needed {
            return Ok(());
        }
        let (vol, camera, w, stride) = (sw.vol, sw.camera, sw.rays.width, self.stride);
        let Reads { acc, n } = reads;
        for j in band.y0..=band.y1 {
            for i in 0..w {
                let ray = camera.pixel_ray(i, j)?;
                let at = ((j - band.y0) * w + i) as usize * stride;
                self.tau[at] = optical_depth_above_lowers(vol, &ray, acc, n);
                for (k, &t) in sw.depths.iter().enumerate() {
                    self.tau[at + 1 + k] =
                        optical_depth_above_lowers(vol, &ray.with_range(0.0, t)?, acc, n);
                }
            }
        }
        Ok(())
    }

    /// Blocks whose values the f32 kernel takes ([`crate::regular::kernel::kernel_ok`]).
    fn enter(&mut self, p: &Piece) -> Option<()> {
        let fast = matches!(
            p.part,
            Part::Leaf { fast: true, .. }
                | Part::Tile { fast: true, .. }
                | Part::Shell { fast: true }
        );
        // A block's lanes start from nothing.
        fast.then(|| self.lanes = Lanes::default())
    }

    /// Closed form, or the f64 ray code: pixel by pixel.
    fn off_kernel(
        &mut self,
        p: &Piece,
        rows: (u32, u32, u32),
        band: &BandRows,
        reads: &mut Reads<'_>,
    ) {
        let (sw, scale) = (self.sw, self.scale);
        let Reads { acc, n } = reads;
        sw.chords(p, rows, &band.dirs, |px, q, d, a, b| {
            let (q, d, lin) = (q.to_array(), d.to_array(), Interp::Trilinear);
            let mut part = |t1: f64| match p.part {
                Part::Const(mu) => mu * (t1 - a),
                Part::Leaf { leaf, .. } => scale * leaf_integral(acc, leaf, q, d, a, t1, lin, n),
                _ => scale * cells_integral(acc, q, d, a, t1, lin, n),
            };
            let full = part(b);
            sw.add(self.tau, px, (a, b), full, part);
        });
    }

    /// The chord's lane, and a lane for each slice depth inside it.
    #[inline]
    fn chord(&mut self, _: &(), at: &Filled<'_>, c: Crossing) {
        let sw = self.sw;
        let e = ((c.q - at.centre) + c.d * c.a).to_array();
        let cuts = sw
            .depths
            .iter()
            .enumerate()
            .filter(|(_, &t)| t > c.a && t < c.b);
        for (slot, end) in std::iter::once((0, c.b)).chain(cuts.map(|(k, &t)| (1 + k, t))) {
            self.lanes.set(self.used, e, c.d.to_array(), end - c.a);
            self.at[self.used] = (c.px, slot, c.b);
            self.used += 1;
            if self.used == self.width {
                self.flush(at.block);
            }
        }
    }

    fn leave(&mut self, _: &Piece, _: &(), at: &Filled<'_>) {
        if self.used > 0 {
            self.flush(at.block);
        }
    }

    fn finish(self) -> u64 {
        self.lookups
    }
}
