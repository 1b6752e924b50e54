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

use super::march::tile_split;
use super::{fill, neighbourhood, Part, Sweep};
use crate::bake::map::BakeSettings;
use crate::error::Result;
use crate::estimate::{Algo, Bounds, Control, Estimator, Options};
use crate::regular::kernel::{max_chord, point, BLOCK};
use crate::regular::{leaf_integral, Counts};
use crate::rng::{block_key, chord_key, Rng};
use crate::tree::Accessor;
use crate::volume::Interp;
use glam::DVec3;
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

/// One chord's flight: the block, the chord (block-centred entry `e`, lookup direction `d`,
/// world length `len`) and the block's bounds, control and rate.
struct Chord<'b> {
    rule: Rule,
    block: &'b [f32; BLOCK],
    e: [f64; 3],
    d: [f64; 3],
    len: f64,
    lo: f64,
    hi: f64,
    mu_c: f64,
    rate: f64,
    scale: f64,
}

/// Where a chord's samples keep their state: the product of their chord factors and the
/// collisions they spent, sample `i` at `base + i per`; the budget of collisions per estimate,
/// and what the chord's flight did: the collisions it evaluated, whether a sample was capped.
struct Estimates<'a> {
    prod: &'a mut [f64],
    spent: &'a mut [u32],
    base: usize,
    per: usize,
    samples: usize,
    budget: u32,
    evaluated: u64,
    capped: bool,
}

/// Largest expected point count of a chord (`samples x r x L`) drawn by inverting the Poisson
/// distribution; above it the points are drawn as exponential gaps.
const POISSON_INVERSION: f64 = 30.0;

impl Chord<'_> {
    /// Fly every sample through the chord with the stream `rng` (see the module docs): the
    /// tentative collisions of all samples as one Poisson process of rate `samples x r`, each
    /// point given to a uniform sample. A sample already at 0 stays there; one whose
    /// collisions reach the budget stops.
    fn fly(&self, mut rng: Rng, est: &mut Estimates<'_>) {
        let samples = est.samples as f64;
        let lambda = self.rate * self.len * samples;
        let u = rng.uniform();
        // No point when `u <= exp(-lambda)`; `1 - lambda <= exp(-lambda)` decides most chords
        // without an exponential.
        if u <= 1.0 - lambda {
            return;
        }
        if lambda <= POISSON_INVERSION {
            // The count by inversion, then that many uniform points (their order does not
            // matter: a product of factors, or any real collision, is the same in any order).
            let (mut k, mut p) = (0u32, (-lambda).exp());
            let mut cdf = p;
            while u > cdf && k < 1000 {
                k += 1;
                p *= lambda / f64::from(k);
                cdf += p;
            }
            for _ in 0..k {
                // One draw gives both: the sample `floor(S x)` and `t = L frac(S x)`.
                let m = u128::from(rng.next_u64()) * est.samples as u128;
                let frac = (m as u64) as f64 * (1.0 / 18_446_744_073_709_551_616.0);
                let i = (m >> 64) as usize;
                self.collide(frac * self.len, i, &mut rng, est);
            }
            return;
        }
        // Many points: exponential gaps `E / (S r)`, `E = -ln(1 - u) >= u` (past the end when
        // `u` is).
        let total = self.rate * samples;
        let inv_total = 1.0 / total;
        let mut t = 0.0f64;
        loop {
            let u = rng.uniform();
            if u >= total * (self.len - t) {
                break;
            }
            t -= (1.0 - u).ln() * inv_total;
            if t >= self.len {
                break;
            }
            let i = ((u128::from(rng.next_u64()) * est.samples as u128) >> 64) as usize;
            self.collide(t, i, &mut rng, est);
        }
    }

    /// A tentative collision of sample `i` at `t`: its factor into the sample's product
    /// (nothing for a sample already at 0; none past the budget, which marks it capped).
    #[inline]
    fn collide(&self, t: f64, i: usize, rng: &mut Rng, est: &mut Estimates<'_>) {
        let at = est.base + i * est.per;
        if est.prod[at] == 0.0 {
            return;
        }
        if est.spent[at] >= est.budget {
            est.capped = true;
            return;
        }
        est.spent[at] += 1;
        est.evaluated += 1;
        let p = [0, 1, 2].map(|a| self.e[a] + self.d[a] * t);
        // `scale > 0` here (a zero scale has rate 0 and no collisions).
        let v = self.scale * point(self.block, p);
        let mu = if v > self.hi {
            self.hi
        } else if v < self.lo {
            self.lo
        } else {
            v
        } - self.mu_c;
        match self.rule {
            Rule::Ratio => est.prod[at] *= 1.0 - mu / self.rate,
            Rule::Delta => {
                if rng.uniform() * self.rate < mu {
                    est.prod[at] = 0.0;
                }
            }
        }
    }
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
    /// Per-thread band buffers of [`Sweep::band_flight`] (closed-form depths, collisions
    /// spent, factor products), kept so that a warm thread maps no fresh pages per band.
    static BUFFERS: std::cell::Cell<(Vec<f64>, Vec<u32>, Vec<f64>)> =
        const { std::cell::Cell::new((Vec::new(), Vec::new(), Vec::new())) };
}

impl Sweep<'_> {
    /// Band `b` of a null-collision map: every pixel's (sample's, slice's) transmittance
    /// estimate into `tau` (estimates, not optical depths: [`super::finish_samples`] is told),
    /// and, when `bounds` is given, each pixel's bounds on `T` (its full ray; what the error
    /// bar's floor needs, [`crate::estimate::error_bar`]).
    pub(super) fn band_flight(
        &self,
        f: &Flight,
        b: usize,
        tau: &mut [f64],
        lookups: &mut u64,
        bounds: Option<&mut Vec<Bounds>>,
    ) -> Result<()> {
        let (vol, rays) = (self.vol, &self.rays);
        let ids = &self.bins[b];
        let (y0, y1) = self.band_span(b, tau.len());
        let tree = vol.tree();
        let (w, stride) = (rays.width, self.stride());
        let per = 1 + self.depths.len();
        let npx = tau.len() / stride;
        let scale = vol.density_scale();
        let mut acc = Accessor::new(tree);
        let mut n = Counts::default();
        let dirs = self.pixel_dirs(y0, y1)?;
        let pixel_id = |px: usize| u64::from(y0) * u64::from(w) + px as u64;
        let samples = f.samples();
        // Per pixel and slot, the closed-form optical depth its samples share; per estimate,
        // the tentative collisions it has spent and the product of its chord factors.
        let (mut det, mut spent, mut prod) = BUFFERS.take();
        det.clear();
        det.resize(npx * per, 0.0);
        // Per pixel (full ray): the closed-form, minorant and majorant optical depths.
        let mut depth = vec![Depths::default(); if bounds.is_some() { npx } else { 0 }];
        spent.clear();
        spent.resize(tau.len(), 0);
        prod.clear();
        prod.resize(tau.len(), 1.0);
        // The budget per estimate, in the counters' range (a sample past 4e9 collisions is
        // capped even when the budget is larger).
        let budget = u32::try_from(f.opts.max_collisions).unwrap_or(u32::MAX);
        let longest = max_chord(vol);
        let mut block = [0f32; BLOCK];
        let mut jobs = Vec::new();
        for &id in ids {
            let p = &self.pieces[id as usize];
            let [_, _, j0, j1] = p.rect;
            let rows = (j0.max(y0), j1.min(y1), y0);
            let key = p.origin.map(|c| c >> 3);
            let kb = block_key(f.opts.seed, key);
            let halo = match p.part {
                Part::Leaf { leaf, fast: true } => Some(tree.leaves[leaf as usize].halo),
                Part::Tile {
                    lower,
                    slot,
                    fast: true,
                } => Some(tree.lowers[lower as usize].tile_halo_of(slot as usize)),
                _ => None,
            };
            let bounds = halo.map(|h| {
                let (lo, hi) = (
                    crate::math::scaled(scale, f64::from(h.min)),
                    crate::math::scaled(scale, f64::from(h.max)),
                );
                let (mu_c, rate) = f.rates(lo, hi);
                (lo, hi, mu_c, rate)
            });
            let Some((lo, hi, mu_c, rate)) = bounds.filter(|b| b.3 * longest <= MAX_FLIGHTS) else {
                self.off_kernel(
                    f,
                    p,
                    (rows, &dirs),
                    kb,
                    (&mut prod, &mut det, &mut depth),
                    &mut acc,
                    &mut n,
                );
                continue;
            };
            fill(&neighbourhood(tree, &mut acc, p), &mut block);
            let centre = DVec3::from(p.origin.map(|c| (c + 4) as f64));
            // A tile's inner box reads the tile alone: closed form.
            let tile_mu = match p.part {
                Part::Tile { lower, slot, .. } => {
                    let v = tree.lowers[lower as usize].tile_value(slot as usize);
                    Some(if v == tree.background {
                        vol.mu_background()
                    } else {
                        crate::math::scaled(scale, f64::from(v))
                    })
                }
                _ => None,
            };
            self.chords(p, rows, &dirs, |px, q, d, a, b| {
                let parts = match tile_mu {
                    Some(mu) => {
                        let (parts, inner) = tile_split(q, d, p.origin, (a, b));
                        if let Some((ia, ib)) = inner {
                            self.jobs(true, (ia, ib), pixel_id(px), &mut jobs);
                            for job in &jobs {
                                det[px * per + job.slot] += mu * (job.end - ia);
                            }
                            if let Some(dp) = depth.get_mut(px) {
                                dp.add_exact(mu * (ib - ia));
                            }
                        }
                        parts
                    }
                    None => [Some((a, b)), None],
                };
                // The two parts of a tile's chord (either side of its inner box) get streams
                // of their own: factors of one sample must be independent.
                for (part, chord) in parts.into_iter().enumerate() {
                    let Some((a, b)) = chord else { continue };
                    if let Some(dp) = depth.get_mut(px) {
                        dp.add_bounded(lo * (b - a), hi * (b - a));
                    }
                    let e = ((q - centre) + d * a).to_array();
                    self.jobs(true, (a, b), pixel_id(px), &mut jobs);
                    for job in &jobs {
                        let len = job.end - a;
                        if mu_c != 0.0 {
                            det[px * per + job.slot] += mu_c * len;
                        }
                        if rate <= 0.0 || len <= 0.0 {
                            continue;
                        }
                        let chord = Chord {
                            rule: f.rule,
                            block: &block,
                            e,
                            d: d.to_array(),
                            len,
                            lo,
                            hi,
                            mu_c,
                            rate,
                            scale,
                        };
                        let mut est = Estimates {
                            prod: &mut prod,
                            spent: &mut spent,
                            base: px * stride + job.slot,
                            per,
                            samples,
                            budget,
                            evaluated: 0,
                            capped: false,
                        };
                        let rng = Rng::of_chord(chord_key(kb, job.ray_id), part as u64);
                        chord.fly(rng, &mut est);
                        *lookups += est.evaluated;
                        if est.capped {
                            self.capped.store(true, Ordering::Relaxed);
                        }
                    }
                }
            });
        }
        // Each estimate: `exp(-closed form)` times its factors.
        for (px, slots) in det.chunks(per).enumerate() {
            for (slot, &v) in slots.iter().enumerate() {
                let known = (-v).exp();
                for i in 0..samples {
                    let at = px * stride + i * per + slot;
                    tau[at] = known * prod[at];
                }
            }
        }
        *lookups += n.reads;
        BUFFERS.set((det, spent, prod));
        if let Some(out) = bounds {
            out.clear();
            out.extend(depth.iter().map(Depths::bounds));
        }
        Ok(())
    }

    /// The chords of a block the sweep does not fly itself (see the module docs): closed form
    /// or exact into `det`, else the ray path's sample into each estimate's product `prod`.
    #[allow(clippy::too_many_arguments)]
    fn off_kernel(
        &self,
        f: &Flight,
        p: &super::Piece,
        (rows, dirs): ((u32, u32, u32), &[super::PixelDir]),
        kb: u64,
        (prod, det, depth): (&mut [f64], &mut [f64], &mut [Depths]),
        acc: &mut Accessor<'_>,
        n: &mut Counts,
    ) {
        let (vol, tree, scale) = (self.vol, self.vol.tree(), self.vol.density_scale());
        let (w, y0) = (self.rays.width, rows.2);
        let (stride, per, samples) = (self.stride(), 1 + self.depths.len(), f.samples());
        let infinite_leaf = match p.part {
            Part::Leaf { leaf, .. } => {
                let max = f64::from(tree.leaves[leaf as usize].halo.max);
                !crate::math::scaled(scale, max).is_finite()
            }
            _ => false,
        };
        let mut jobs = Vec::new();
        self.chords(p, rows, dirs, |px, q, d, a, b| {
            let id = u64::from(y0) * u64::from(w) + px as u64;
            self.jobs(true, (a, b), id, &mut jobs);
            for job in &jobs {
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
                        let ray = self
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
                                self.capped.store(true, Ordering::Relaxed);
                            }
                            prod[at] *= (-known).exp() * t;
                        }
                    }
                }
            }
        });
    }
}

#[cfg(test)]
mod tests;
