//! [`IntervalBounds`]: the blurred bounds of [`BlurBounds`] per interval of the shutter, for
//! the estimators that draw one time per sample (issue 61).
//!
//! The shutter `[o, c]` is cut into `J` equal intervals. In interval `j` a point `x` of the
//! `8^3` block `C` reads the density at `x - k v(x)` with `k = S t / F` in `[k_j0, k_j1]`
//! (`k` is linear in `t`) and `v(x)` in `V(C)`, the box of the world velocity's component
//! ranges over `C` ([`VelocityField::velocity_range`]). So the point read lies in `C`'s world
//! box plus the box of `{-k v : k in [k_j0, k_j1], v in V(C)}` (bilinear in `k` and each
//! component: its extremes are at the corners), carried to index space by the box of its
//! eight corners. A nearest lookup there reads voxel `floor(u + 1/2)`, a trilinear one
//! `floor(u)` and `floor(u) + 1`: the voxels `[floor(u_lo), floor(u_hi) + 1]` hold every value
//! read. The layer's `(min, max)` of `C` is then the extremes of the density's blocks meeting
//! them, intersected with the whole shutter's (both hold, so both at once do). The window is
//! `1/J` of the shutter's wide and sits where the density is at that time, not on the union
//! of every position over the shutter.

use super::bounds::{dense_sources, extremes_over, source_blocks};
use super::{BlurBounds, MotionSpec, VelocityField};
use crate::error::Result;
use crate::tree::Tree;
use glam::{DAffine3, DVec3};
use rayon::prelude::*;

/// The most intervals a shutter is cut into.
pub const MAX_INTERVALS: usize = 16;

/// The most `(min, max)` pairs the layers may hold together (64 MiB): `J` is lowered to fit.
pub const MAX_LAYER_ENTRIES: usize = 1 << 23;

/// How far, in voxels, density may move within one interval when the count is derived from
/// the reach: each interval then moves it about one voxel.
const VOXELS_PER_INTERVAL: f64 = 1.0;

/// Rounding allowance in voxels: a window ending within it of a voxel boundary does not take
/// the voxel beyond, which a lookup there reads with a trilinear weight of at most this.
const SLACK: f64 = 1e-7;

/// The most cells the fine source extremes may hold (32 MiB).
const FINE_MAX: usize = 1 << 22;

/// The blurred `(min, max)` per `8^3` block for each of `J` equal intervals of the shutter,
/// over the dense box of the whole shutter's [`BlurBounds`] (the background outside it).
#[derive(Debug, Clone)]
pub struct IntervalBounds {
    /// Intervals `J` (1: none kept, the whole shutter's bounds serve).
    count: usize,
    /// Smallest block coordinate per axis (the whole shutter's box).
    lo: [i64; 3],
    /// Blocks per axis.
    dims: [usize; 3],
    /// `[min, max]` of block `b`'s interval `j` at `b J + j`, `b` z fastest, raw density.
    range: Vec<[f32; 2]>,
    /// The density outside the box (its background).
    outside: f32,
}

impl IntervalBounds {
    /// No intervals: the whole shutter's bounds serve every time.
    #[must_use]
    pub fn none(whole: &BlurBounds) -> Self {
        let (lo, dims) = whole.dense_box();
        Self {
            count: 1,
            lo,
            dims,
            range: Vec::new(),
            // Beyond the box the whole shutter's bounds are the background.
            outside: whole.block_range([i64::MIN; 3]).1,
        }
    }

    /// The intervals to cut `spec`'s shutter into for `whole` and `field`: enough that each
    /// moves density about one voxel at the field's largest speed, at most
    /// [`MAX_INTERVALS`], and no more than keep `J` layers of the dense box within
    /// [`MAX_LAYER_ENTRIES`].
    #[must_use]
    pub fn default_count(
        whole: &BlurBounds,
        index_from_world: DAffine3,
        field: &VelocityField,
        spec: &MotionSpec,
    ) -> usize {
        let m = index_from_world.matrix3.transpose();
        let per_world = m
            .x_axis
            .length()
            .max(m.y_axis.length())
            .max(m.z_axis.length());
        let span = (spec.scale() * (spec.close() - spec.open()) / spec.fps()).abs();
        let voxels = span * field.speed_max() * per_world / VOXELS_PER_INTERVAL;
        let wanted = if voxels.is_finite() {
            voxels.ceil().clamp(1.0, MAX_INTERVALS as f64) as usize
        } else {
            MAX_INTERVALS
        };
        let room = MAX_LAYER_ENTRIES / whole.blocks().max(1);
        wanted.min(room).max(1)
    }

    /// The bounds of `density` (map `index_from_world`) moved by `field` over `count` equal
    /// intervals of `spec`'s shutter, within `whole`'s box (the bounds of the whole shutter,
    /// built from the same three).
    ///
    /// # Errors
    /// As [`BlurBounds::build`] (a root tile).
    pub fn build(
        density: &Tree,
        index_from_world: DAffine3,
        field: &VelocityField,
        spec: &MotionSpec,
        (whole, count): (&BlurBounds, usize),
    ) -> Result<Self> {
        let (lo, dims) = whole.dense_box();
        let blocks = whole.blocks();
        if count <= 1 || blocks == 0 || !density.is_complete() {
            return Ok(Self::none(whole));
        }
        let outside = density.background;
        let fine = Fine::build(density, (lo, dims))?;
        // `k` at each interval's ends: `k` is linear in `t`, so `[k_j0, k_j1]` sorted.
        let ks: Vec<(f64, f64)> = (0..count)
            .map(|j| {
                let k = |f: f64| spec.displacement_per_velocity(spec.time_at(f));
                let (a, b) = (k(j as f64 / count as f64), k((j + 1) as f64 / count as f64));
                (a.min(b), a.max(b))
            })
            .collect();
        let world_from_index = index_from_world.inverse();
        let slab = dims[1] * dims[2];
        let mut range = vec![[outside; 2]; blocks * count];
        range
            .par_chunks_mut((slab * count).max(1))
            .enumerate()
            .for_each(|(x, out)| {
                for y in 0..dims[1] {
                    for z in 0..dims[2] {
                        let c = [lo[0] + x as i64, lo[1] + y as i64, lo[2] + z as i64];
                        let corner =
                            |d: i64, s: f64| DVec3::from_array(c.map(|v| (v * 8 + d) as f64 + s));
                        let (wlo, whi) = crate::math::mapped_box(
                            &world_from_index,
                            corner(0, -SLACK),
                            corner(8, SLACK),
                        );
                        let (wmin, wmax) = whole.block_range(c);
                        let cell = &mut out[(y * dims[2] + z) * count..][..count];
                        if wmin == wmax {
                            // One value at every time (no density reaches the block, mostly):
                            // every interval's bounds are that value too.
                            cell.fill([wmin, wmax]);
                            continue;
                        }
                        let v = field.velocity_range(wlo, whi);
                        for (r, &k) in cell.iter_mut().zip(&ks) {
                            let (dlo, dhi) = displacement_box(k, v);
                            let (ulo, uhi) =
                                crate::math::mapped_box(&index_from_world, wlo + dlo, whi + dhi);
                            let voxels = [0, 1, 2].map(|a| {
                                let v0 = (ulo[a] + SLACK).floor();
                                let v1 = (uhi[a] - SLACK).ceil();
                                (v0 as i64, v1 as i64)
                            });
                            let (hi, mn) = fine.extremes(outside, voxels);
                            let hi = hi.min(wmax);
                            *r = [mn.max(wmin).min(hi), hi];
                        }
                    }
                }
            });
        Ok(Self {
            count,
            lo,
            dims,
            range,
            outside,
        })
    }

    /// Intervals the shutter is cut into (1: none kept).
    #[must_use]
    pub fn count(&self) -> usize {
        self.count
    }

    /// The interval of the shutter time at fraction `u` in `[0, 1)` of the shutter
    /// ([`MotionSpec::time_at`]).
    #[must_use]
    pub fn interval_of(&self, u: f64) -> usize {
        ((u * self.count as f64) as usize).min(self.count - 1)
    }

    /// The raw minorant and majorant of block `b` over interval `j`, `(min, max)`: every
    /// lookup in the block at every time of that interval reads a value between them (the
    /// background outside the box). `None` when no intervals are kept (`count() == 1`) or `j`
    /// is past them.
    #[must_use]
    pub fn block_range(&self, j: usize, b: [i64; 3]) -> Option<(f32, f32)> {
        if self.range.is_empty() || j >= self.count {
            return None;
        }
        let mut i = 0usize;
        for ((&c, &lo), &dim) in b.iter().zip(&self.lo).zip(&self.dims) {
            let k = c - lo;
            if k < 0 || k >= dim as i64 {
                return Some((self.outside, self.outside));
            }
            i = i * dim + k as usize;
        }
        let [mn, mx] = self.range[i * self.count + j];
        Some((mn, mx))
    }
}

/// The box of `{-k v : k in [k0, k1], v in [vlo, vhi]}` per world axis: `-k v_i` is bilinear,
/// so its extremes are at the corners.
fn displacement_box((k0, k1): (f64, f64), (vlo, vhi): (DVec3, DVec3)) -> (DVec3, DVec3) {
    let c = [-k0 * vlo, -k0 * vhi, -k1 * vlo, -k1 * vhi];
    let lo = c.iter().fold(DVec3::splat(f64::INFINITY), |m, v| m.min(*v));
    let hi = c
        .iter()
        .fold(DVec3::splat(f64::NEG_INFINITY), |m, v| m.max(*v));
    (lo, hi)
}

/// The density's extremes per cell of `2^shift` voxels (2, 4 or 8 a side: the finest whose
/// dense box stays within [`FINE_MAX`] cells), over the whole shutter's box of blocks: from
/// each leaf's voxels (inactive ones too), each tile's value, the background elsewhere.
struct Fine {
    shift: u32,
    lo: [i64; 3],
    dims: [usize; 3],
    ext: Vec<(f32, f32)>,
}

impl Fine {
    fn build(density: &Tree, (lo, dims): ([i64; 3], [usize; 3])) -> Result<Self> {
        let blocks = dims.iter().product::<usize>();
        let shift = (1..=3u32)
            .find(|s| blocks.saturating_mul(1 << (3 * (3 - s))) <= FINE_MAX)
            .unwrap_or(3);
        let per = 1usize << (3 - shift);
        let (flo, fdims) = (lo.map(|v| v * per as i64), dims.map(|d| d * per));
        let at = |b: [i64; 3]| {
            let i = [0, 1, 2].map(|a| (b[a] - lo[a]) as usize);
            (i[0] * dims[1] + i[1]) * dims[2] + i[2]
        };
        let leaf = |i: usize| (density.leaves[i].bounds.max, density.leaves[i].bounds.min);
        let src = dense_sources(
            &source_blocks(density, &leaf)?,
            density.background,
            at,
            blocks,
        );
        let fat = |f: [usize; 3]| (f[0] * fdims[1] + f[1]) * fdims[2] + f[2];
        let mut ext = vec![(density.background, density.background); fdims.iter().product()];
        for x in 0..fdims[0] {
            for y in 0..fdims[1] {
                for z in 0..fdims[2] {
                    ext[fat([x, y, z])] =
                        src[at([0, 1, 2].map(|a| lo[a] + ([x, y, z][a] / per) as i64))];
                }
            }
        }
        if shift < 3 {
            let side = 1usize << shift;
            for l in &density.leaves {
                let Some(vals) = density.values.get(l.data as usize) else {
                    continue;
                };
                let f0 = [0, 1, 2].map(|a| ((i64::from(l.origin[a]) >> shift) - flo[a]) as usize);
                for (i, &v) in vals.iter().enumerate() {
                    let d = [i >> 6, (i >> 3) & 7, i & 7];
                    let f = [0, 1, 2].map(|a| f0[a] + d[a] / side);
                    let e = &mut ext[fat(f)];
                    // The block's own extremes were set above: reset on the cell's first voxel.
                    if d.iter().all(|c| c % side == 0) {
                        *e = (v, v);
                    } else {
                        *e = (e.0.max(v), e.1.min(v));
                    }
                }
            }
        }
        Ok(Self {
            shift,
            lo: flo,
            dims: fdims,
            ext,
        })
    }

    /// The extremes over the voxels `[v0, v1]` on each axis (`outside` beyond the box).
    fn extremes(&self, outside: f32, voxels: [(i64, i64); 3]) -> (f32, f32) {
        extremes_over(&self.ext, outside, (self.lo, self.dims, self.shift), voxels)
    }
}
