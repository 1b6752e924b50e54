//! Null-collision maps in object order: `ratio`, `residual-ratio` (both controls),
//! `track-length` and `decomposition` swept block by block.
//!
//! **Per block chord.** The ray path flies one stream per sample along the whole ray through
//! per-segment bounds ([`crate::estimate::null_collision`]). The sweep cuts every ray into the
//! chords of the `8^3` blocks of lookup space, as the exact sweep does, and estimates each
//! chord's transmittance on its own: with the block's bounds `[mu_lo, mu_hi]` (its halo's
//! values, scaled: every trilinear lookup inside the block interpolates those corners), a
//! control `mu_c` and a rate `r` (`0, mu_hi` for ratio and track-length; `mu_lo, mu_hi - mu_lo`
//! for the minorant control and decomposition; `(mu_lo + mu_hi) / 2, (mu_hi - mu_lo) / 2` for
//! the midpoint control), a chord of length `L` contributes `exp(-mu_c L)` in closed form and
//! a product over the tentative collisions `t_k` of a Poisson process of rate `r` on `[0, L]`:
//! `1 - (mu(t_k) - mu_c) / r` (ratio) or `0` with probability `(mu(t_k) - mu_c) / r` (delta
//! tracking). Each chord's factor is an unbiased estimate of that chord's transmittance, the
//! chords of one sample are independent, so their product is an unbiased estimate of the
//! ray's `T` (the expectation of a product of independent factors is the product of their
//! expectations).
//!
//! **All samples of a chord at once.** The `S` samples' tentative collisions in a chord are
//! `S` independent Poisson processes of rate `r`; their superposition is one Poisson process of
//! rate `S r` whose points each belong to a uniformly chosen sample (and conversely: labelling
//! the points of a rate-`S r` process independently and uniformly splits it into `S`
//! independent rate-`r` processes). So a chord draws one process for all its samples: steps
//! `E / (S r)`, `E = -ln(1 - u)`, each point given to sample `floor(S v)` (`v` a second uniform,
//! as a 64 x 64-bit product), whose product takes the point's factor. Since `E >= u`,
//! `u >= S r (L - t)` already says "past the end" without a logarithm: a chord without
//! collisions (most chords of a residual tracker) costs three mixes and a comparison whatever
//! `S` is. A sample already at 0 (a real collision of delta tracking, a zero ratio weight)
//! stays there and spends nothing. Lookups read the block's `9^3` corners in L1 ([`point`]),
//! clamped to the bounds (a trilinear value passes its corners only by round-off). Each
//! estimate's factors are multiplied in piece order and its closed-form part added once, when
//! the band is done: `T_i = exp(-sum mu_c L) x prod(factors)`.
//!
//! **Streams.** The chord of ray id `p` through block `k` draws from
//! [`Rng::of_chord`]`(chord_key(block_key(seed, k), p), part)` ([`crate::rng`]; `part` 0, or 1
//! for the part of a tile's chord after its inner box, so that the two parts are independent):
//! it depends on the block, the pixel's ray id (slice `k`'s own id `(64 + k) npix + p` for a
//! depth slice, as the ray path estimates slices) and the sample count, never on the order
//! blocks are visited or the thread count.
//!
//! **What the sweep does not fly.** Constant blocks and the inner box of a tile are closed
//! form (in every estimate), a leaf with an infinite value is integrated exactly (as the ray
//! path does), and everything else off the f32 kernel (tiles above lower nodes, shell blocks,
//! blocks whose expected collisions per chord exceed [`MAX_FLIGHTS`]) is estimated by the ray
//! path over the chord, sample `i` with `Rng::of_chord(c, i)` ([`crate::estimate::flight_sample`],
//! which refines high-contrast segments to per-cell bounds). A map whose samples would run
//! past the collision budget (`Options::max_collisions`, counted per estimate across its
//! flown chords; a chord handed to the ray path has the budget to itself) is declined and
//! traced by the ray path, which caps samples where they stand.

mod chord;

use super::band::{BandKernel, BandRows, Crossing, Filled, Reads};
use super::march::{tile_split, Job};
use super::pieces::{Part, Piece};
use super::Sweep;
use crate::bake::map::BakeSettings;
use crate::estimate::{Algo, Bounds, Control, Estimator, Options};
use crate::regular::kernel::max_chord;
use crate::regular::leaf_integral;
use crate::rng::{block_key, chord_key, Rng};
use crate::volume::Interp;
use chord::{Chord, Estimates};
use std::sync::atomic::Ordering;

/// Most expected tentative collisions along a block's longest chord (`r x max_chord`) for the
/// sweep to fly the block itself; above it the ray path refines the block's chords to
/// per-cell bounds.
const MAX_FLIGHTS: f64 = 32.0;

/// What a real collision does to a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Rule {
    /// Ratio tracking: the weight is multiplied by `1 - (mu - mu_c) / r`.
    Ratio,
    /// Delta tracking: a real collision (probability `(mu - mu_c) / r`) makes the sample 0.
    Delta,
}

/// A null-collision estimator the sweep renders: the estimator, its options, its rule and
/// control.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Flight {
    est: Estimator,
    opts: Options,
    rule: Rule,
    control: Option<Control>,
}

impl Flight {
    /// Estimates per pixel (`--spp`).
    pub(super) fn samples(&self) -> usize {
        self.opts.samples.max(1) as usize
    }

    /// Control extinction `mu_c` and tentative-collision rate `r` inside bounds `[lo, hi]`.
    fn rates(&self, lo: f64, hi: f64) -> (f64, f64) {
        match self.control {
            None => (0.0, hi),
            Some(Control::Minorant) => (lo, hi - lo),
            Some(Control::Midpoint) => (0.5 * (lo + hi), 0.5 * (hi - lo)),
        }
    }
}

/// The null-collision estimator the sweep renders for these settings (`ratio`,
/// `residual-ratio`, `residual-ratio-midpoint`, `track-length`, `decomposition` with trilinear
/// lookups, per-leaf majorants and a fixed sample count); `None` for any other.
pub(crate) fn flights(s: &BakeSettings) -> Option<Flight> {
    let o = &s.options;
    if o.interp != Interp::Trilinear
        || s.target_error.is_some()
        || o.global_majorant
        || o.granularity != crate::traverse::Granularity::Leaf
    {
        return None;
    }
    let (rule, control) = match s.estimator.algo().0 {
        Algo::Ratio => (Rule::Ratio, None),
        Algo::ResidualRatio(c) => (Rule::Ratio, Some(c)),
        Algo::TrackLength => (Rule::Delta, None),
        Algo::Decomposition => (Rule::Delta, Some(Control::Minorant)),
        _ => return None,
    };
    Some(Flight {
        est: s.estimator,
        opts: s.options,
        rule,
        control,
    })
}

/// A pixel's optical depths as the sweep meets its chords: the closed-form part and the
/// minorant and majorant depths of the flown part.
#[derive(Debug, Clone, Copy, Default)]
struct Depths {
    known: f64,
    lo: f64,
    hi: f64,
}

impl Depths {
    /// A chord whose optical depth `tau` is known exactly.
    fn add_exact(&mut self, tau: f64) {
        self.known += tau;
    }
    /// A flown chord whose optical depth is in `[lo, hi]`.
    fn add_bounded(&mut self, lo: f64, hi: f64) {
        self.lo += lo;
        self.hi += hi;
    }
    /// The pixel's bounds on `T`.
    fn bounds(&self) -> Bounds {
        Bounds::new(self.known, self.lo, self.hi)
    }
}

thread_local! {
    /// Per-thread band buffers of [`FlightBand`] (closed-form depths, collisions
    /// spent, factor products), kept so that a warm thread maps no fresh pages per band.
    static BUFFERS: std::cell::Cell<(Vec<f64>, Vec<u32>, Vec<f64>)> =
        const { std::cell::Cell::new((Vec::new(), Vec::new(), Vec::new())) };
}

/// A null-collision map's share of a band: a leaf or a tile on the lane kernel flies every
/// estimate of each of its chords (its part in a tile's inner box closed form), anything else
/// goes per chord through [`FlightBand::off_kernel`]; when the band is done each estimate is
/// `T_i = exp(-closed form) x prod(chord factors)` (see the module docs).
pub(super) struct FlightBand<'s, 'a> {
    sw: &'s Sweep<'a>,
    f: &'s Flight,
    /// The band's buffer: the estimates, once the band is done.
    tau: &'s mut [f64],
    /// Where each pixel's bounds on `T` go, when asked for.
    bounds: Option<&'s mut Vec<Bounds>>,
    /// Per pixel and slot, the closed-form optical depth its samples share.
    det: Vec<f64>,
    /// Per estimate, the tentative collisions it has spent.
    spent: Vec<u32>,
    /// Per estimate, the product of its chord factors.
    prod: Vec<f64>,
    /// Per pixel (full ray): the closed-form, minorant and majorant optical depths (empty
    /// without `bounds`).
    depth: Vec<Depths>,
    /// The budget per estimate, in the counters' range (a sample past 4e9 collisions is
    /// capped even when the budget is larger).
    budget: u32,
    /// The longest chord through a block ([`max_chord`]).
    longest: f64,
    stride: usize,
    per: usize,
    samples: usize,
    scale: f64,
    /// The band's first row.
    y0: u32,
    jobs: Vec<Job>,
    lookups: u64,
}

/// What a block the sweep flies carries: its bounds `[lo, hi]`, control `mu_c` and rate, its
/// stream key, and a tile's value `mu` (its inner box is closed form).
pub(super) struct FlightOn {
    lo: f64,
    hi: f64,
    mu_c: f64,
    rate: f64,
    kb: u64,
    tile_mu: Option<f64>,
}

impl<'s, 'a> FlightBand<'s, 'a> {
    /// Flight `f` into the buffer `tau` of the band from row `y0`, each pixel's bounds on `T`
    /// into `bounds` when given.
    pub(super) fn new(
        sw: &'s Sweep<'a>,
        f: &'s Flight,
        y0: u32,
        tau: &'s mut [f64],
        bounds: Option<&'s mut Vec<Bounds>>,
    ) -> Self {
        let (stride, per) = (sw.stride(), 1 + sw.depths.len());
        let npx = tau.len() / stride;
        let (mut det, mut spent, mut prod) = BUFFERS.take();
        det.clear();
        det.resize(npx * per, 0.0);
        let depth = vec![Depths::default(); if bounds.is_some() { npx } else { 0 }];
        spent.clear();
        spent.resize(tau.len(), 0);
        prod.clear();
        prod.resize(tau.len(), 1.0);
        Self {
            sw,
            f,
            budget: u32::try_from(f.opts.max_collisions).unwrap_or(u32::MAX),
            longest: max_chord(sw.vol),
            tau,
            bounds,
            det,
            spent,
            prod,
            depth,
            stride,
            per,
            samples: f.samples(),
            scale: sw.vol.density_scale(),
            y0,
            jobs: Vec::new(),
            lookups: 0,
        }
    }

    /// The ray id of the band's pixel `px` (the image's pixel index).
    fn pixel_id(&self, px: usize) -> u64 {
        u64::from(self.y0) * u64::from(self.sw.rays.width) + px as u64
    }

    /// Part `part` (0, or 1 after a tile's inner box) `[a, b]` of a chord `c` flown through
    /// the block `at`: its bounds into the pixel's depths, `mu_c x len` into each estimate's
    /// closed form, the chord's factors into each sample's product.
    fn fly(&mut self, on: &FlightOn, at: &Filled<'_>, c: Crossing, part: u64) {
        let Crossing { px, q, d, a, b } = c;
        let FlightOn {
            lo,
            hi,
            mu_c,
            rate,
            kb,
            ..
        } = *on;
        if let Some(dp) = self.depth.get_mut(px) {
            dp.add_bounded(lo * (b - a), hi * (b - a));
        }
        let e = ((q - at.centre) + d * a).to_array();
        self.sw
            .jobs(true, (a, b), self.pixel_id(px), &mut self.jobs);
        for job in &self.jobs {
            let len = job.end - a;
            if mu_c != 0.0 {
                self.det[px * self.per + job.slot] += mu_c * len;
            }
            if rate <= 0.0 || len <= 0.0 {
                continue;
            }
            let chord = Chord {
                rule: self.f.rule,
                block: at.block,
                e,
                d: d.to_array(),
                len,
                lo,
                hi,
                mu_c,
                rate,
                scale: self.scale,
            };
            let mut est = Estimates {
                prod: &mut self.prod,
                spent: &mut self.spent,
                base: px * self.stride + job.slot,
                per: self.per,
                samples: self.samples,
                budget: self.budget,
                evaluated: 0,
                capped: false,
            };
            let rng = Rng::of_chord(chord_key(kb, job.ray_id), part);
            chord.fly(rng, &mut est);
            self.lookups += est.evaluated;
            if est.capped {
                self.sw.capped.store(true, Ordering::Relaxed);
            }
        }
    }
}

impl BandKernel for FlightBand<'_, '_> {
    type On = FlightOn;

    /// Leaves and tiles whose values the f32 kernel takes and whose longest chord expects at
    /// most [`MAX_FLIGHTS`] tentative collisions.
    fn enter(&mut self, p: &Piece) -> Option<FlightOn> {
        let tree = self.sw.vol.tree();
        let halo = match p.part {
            Part::Leaf { leaf, fast: true } => tree.leaves[leaf as usize].halo,
            Part::Tile {
                lower,
                slot,
                fast: true,
            } => tree.lowers[lower as usize].tile_halo_of(slot as usize),
            _ => return None,
        };
        let (lo, hi) = (
            crate::math::scaled(self.scale, f64::from(halo.min)),
            crate::math::scaled(self.scale, f64::from(halo.max)),
        );
        let (mu_c, rate) = self.f.rates(lo, hi);
        // Not `>`: a NaN rate goes off the kernel too.
        let flies = rate * self.longest <= MAX_FLIGHTS;
        if !flies {
            return None;
        }
        // A tile's inner box reads the tile alone: closed form.
        let tile_mu = match p.part {
            Part::Tile { lower, slot, .. } => {
                let v = tree.lowers[lower as usize].tile_value(slot as usize);
                Some(if v == tree.background {
                    self.sw.vol.mu_background()
                } else {
                    crate::math::scaled(self.scale, f64::from(v))
                })
            }
            _ => None,
        };
        Some(FlightOn {
            lo,
            hi,
            mu_c,
            rate,
            kb: block_key(self.f.opts.seed, p.origin.map(|c| c >> 3)),
            tile_mu,
        })
    }

    /// The chords of a block the sweep does not fly itself (see the module docs): closed form
    /// or exact into the closed-form depths, else the ray path's sample into each estimate's
    /// product.
    fn off_kernel(
        &mut self,
        p: &Piece,
        rows: (u32, u32, u32),
        band: &BandRows,
        reads: &mut Reads<'_>,
    ) {
        let Self {
            sw,
            f,
            det,
            prod,
            depth,
            jobs,
            ..
        } = self;
        let (sw, f) = (*sw, *f);
        let (vol, tree, scale) = (sw.vol, sw.vol.tree(), self.scale);
        let (w, y0) = (sw.rays.width, self.y0);
        let (stride, per, samples) = (self.stride, self.per, self.samples);
        let kb = block_key(f.opts.seed, p.origin.map(|c| c >> 3));
        let infinite_leaf = match p.part {
            Part::Leaf { leaf, .. } => {
                let max = f64::from(tree.leaves[leaf as usize].halo.max);
                !crate::math::scaled(scale, max).is_finite()
            }
            _ => false,
        };
        let Reads { acc, n } = reads;
        sw.chords(p, rows, &band.dirs, |px, q, d, a, b| {
            let id = u64::from(y0) * u64::from(w) + px as u64;
            sw.jobs(true, (a, b), id, jobs);
            for job in jobs.iter() {
                let slot = px * per + job.slot;
                let dp = if job.slot == 0 {
                    depth.get_mut(px)
                } else {
                    None
                };
                match p.part {
                    Part::Const(mu) => {
                        det[slot] += mu * (job.end - a);
                        if let Some(dp) = dp {
                            dp.add_exact(mu * (job.end - a));
                        }
                    }
                    Part::Leaf { leaf, .. } if infinite_leaf => {
                        let (qa, da) = (q.to_array(), d.to_array());
                        let lin = Interp::Trilinear;
                        let v = scale * leaf_integral(acc, leaf, qa, da, a, job.end, lin, n);
                        det[slot] += v;
                        if let Some(dp) = dp {
                            dp.add_exact(v);
                        }
                    }
                    _ => {
                        let (x, y) = (px as u32 % w, y0 + px as u32 / w);
                        let ray = sw
                            .camera
                            .pixel_ray(x, y)
                            .and_then(|r| r.with_range(a, job.end));
                        let ck = chord_key(kb, job.ray_id);
                        if let (Some(dp), Ok(ray)) = (dp, &ray) {
                            let (known, lo, hi) = crate::estimate::flight_bounds(vol, ray, &f.opts);
                            dp.add_exact(known);
                            dp.add_bounded(lo, hi);
                        }
                        for i in 0..samples {
                            let at = px * stride + i * per + job.slot;
                            let Ok(ray) = &ray else {
                                // Reported as a NaN estimate by `finish_samples`.
                                prod[at] = f64::NAN;
                                continue;
                            };
                            if prod[at] == 0.0 {
                                continue; // already 0: nothing to fly
                            }
                            let mut rng = Rng::of_chord(ck, i as u64);
                            let (known, t, reads, capped) =
                                crate::estimate::flight_sample(vol, ray, &f.est, &f.opts, &mut rng);
                            n.reads += reads;
                            if capped {
                                sw.capped.store(true, Ordering::Relaxed);
                            }
                            prod[at] *= (-known).exp() * t;
                        }
                    }
                }
            }
        });
    }

    /// A chord of a flown block: a tile's chord is split around its inner box ([`tile_split`]:
    /// the inner part closed form in every estimate), each other part flown
    /// ([`FlightBand::fly`]) with a stream of its own (factors of one sample must be
    /// independent).
    #[inline]
    fn chord(&mut self, on: &FlightOn, at: &Filled<'_>, c: Crossing) {
        let Crossing { px, q, d, a, b } = c;
        let parts = match on.tile_mu {
            Some(mu) => {
                let (parts, inner) = tile_split(q, d, at.origin, (a, b));
                if let Some((ia, ib)) = inner {
                    self.sw
                        .jobs(true, (ia, ib), self.pixel_id(px), &mut self.jobs);
                    for job in &self.jobs {
                        self.det[px * self.per + job.slot] += mu * (job.end - ia);
                    }
                    if let Some(dp) = self.depth.get_mut(px) {
                        dp.add_exact(mu * (ib - ia));
                    }
                }
                parts
            }
            None => [Some((a, b)), None],
        };
        for (part, chord) in parts.into_iter().enumerate() {
            let Some((a, b)) = chord else { continue };
            self.fly(on, at, Crossing { px, q, d, a, b }, part as u64);
        }
    }

    fn leave(&mut self, _: &Piece, _: &FlightOn, _: &Filled<'_>) {}

    /// Each estimate: `exp(-closed form)` times its factors; the pixels' bounds on `T`.
    fn finish(self) -> u64 {
        let (per, stride, samples) = (self.per, self.stride, self.samples);
        for (px, slots) in self.det.chunks(per).enumerate() {
            for (slot, &v) in slots.iter().enumerate() {
                let known = (-v).exp();
                for i in 0..samples {
                    let at = px * stride + i * per + slot;
                    self.tau[at] = known * self.prod[at];
                }
            }
        }
        if let Some(out) = self.bounds {
            out.clear();
            out.extend(self.depth.iter().map(Depths::bounds));
        }
        BUFFERS.set((self.det, self.spent, self.prod));
        self.lookups
    }
}

#[cfg(test)]
mod tests;
