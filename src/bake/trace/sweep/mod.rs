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
//! kernel's f32 cell arithmetic (see [`kernel`]); `tests/bake.rs` holds it to `1e-6` relative on
//! corpus files. Lookups are counted as the ray path counts them: 8 corner reads for the first
//! dual cell of a block, 4 for each further one.

mod flight;
mod march;
mod streamed;

pub(crate) use flight::flights;
use flight::Flight;
pub(crate) use march::marches;
use march::{finish_samples, March};
pub(crate) use streamed::{part_bytes, render_streamed, streams, Streamed};

use crate::bake::camera::{Camera, Projection};
use crate::bake::map::{BakeSettings, BakeStats, Map};
use crate::error::Result;
use crate::estimate::Estimator;
use crate::math::box_corners;
use crate::regular::kernel::{
    blocks_around, fill, kernel_ok, max_chord, Kernel, Lanes, BLOCK, LANES,
};
use crate::regular::{cells_integral, leaf_integral, optical_depth_above_lowers, Counts};
use crate::traverse::lookup_ray;
use crate::tree::{Accessor, Block, RootSlot, Tree};
use crate::volume::{Interp, Volume};
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// True when the sweep renders maps with these settings: exact regular tracking with trilinear
/// lookups (depth slices included), orthographic or perspective ([`render`] still declines a
/// map whose pinhole is inside the clip box or whose frame is degenerate).
pub(crate) fn applies(s: &BakeSettings) -> bool {
    s.estimator == Estimator::REGULAR && s.options.interp == Interp::Trilinear
}

/// Orthographic rays in lookup space: pixel `(i, j)`'s is `q0 + i qx + j qy + t d`;
/// `inv = [qx qy d]^-1` maps offsets from `q0` to `(i, j, t)`.
#[derive(Clone, Copy)]
struct Parallel {
    q0: DVec3,
    qx: DVec3,
    qy: DVec3,
    d: DVec3,
    /// `1 / d` per axis (unused where `d` is zero).
    inv_d: DVec3,
    inv: DMat3,
}

/// How pixel `(i, j)`'s ray runs in lookup space.
#[derive(Clone, Copy)]
enum Layout {
    /// Orthographic.
    Parallel(Parallel),
    /// Perspective: `p + t d(i, j)`, `d(i, j)` the lookup-space image of the unit world
    /// direction through pixel `(i, j)`. `inv = [D sx sy]^-1` (the lookup-space images of the
    /// camera's `direction`, `step_x`, `step_y`) maps `c - p` to `(v0, v0 i, v0 j)`: point `c`
    /// lies on the ray of (fractional) pixel `(v1 / v0, v2 / v0)`, in front of the pinhole when
    /// `v0 > 0`.
    Pinhole { p: DVec3, inv: DMat3 },
}

/// The map's rays in lookup space, `t` in `[t_min, t_max]` (world units along each ray).
#[derive(Clone, Copy)]
struct Rays {
    layout: Layout,
    t_min: f64,
    t_max: f64,
    /// The lookup-space box the ray walk clips rays to (the value box, grown by the reach of
    /// trilinear lookups): outside it every ray has the background, which the rest walk adds.
    clip_lo: [f64; 3],
    clip_hi: [f64; 3],
    width: u32,
    height: u32,
}

impl Rays {
    /// The rays of `camera`, or `None` when the sweep cannot take them: a degenerate frame in
    /// index space, or a pinhole that is not strictly behind the whole clip box (then some
    /// block's footprint is unbounded and the rays are traced instead).
    fn new(vol: &Volume, camera: &Camera) -> Result<Option<Self>> {
        if crate::bake::camera::is_omni(camera.kind) {
            // Not one projection: a cube map is swept face by face (`render_cube`).
            return Ok(None);
        }
        let r0 = camera.pixel_ray(0, 0)?;
        let (q0, d) = lookup_ray(vol, &r0, Interp::Trilinear);
        let (q0, d) = (DVec3::from(q0), DVec3::from(d));
        let qx = vol.to_index_dir(DVec3::from(camera.step_x));
        let qy = vol.to_index_dir(DVec3::from(camera.step_y));
        // As `hdda::Walker::run`: lookup cells whose trilinear reads touch the value box.
        let (clip_lo, clip_hi) = match vol.value_box() {
            Some([lo, hi]) => (lo.map(|c| (c - 1) as f64), hi.map(|c| (c + 1) as f64)),
            None => ([0.0; 3], [0.0; 3]),
        };
        let m = match camera.kind {
            Projection::Ortho => DMat3::from_cols(qx, qy, d),
            _ => DMat3::from_cols(vol.to_index_dir(DVec3::from(camera.direction)), qx, qy),
        };
        let det = m.determinant();
        if !(det.is_finite() && det != 0.0) {
            return Ok(None);
        }
        let inv = m.inverse();
        let layout = match camera.kind {
            Projection::Ortho => Layout::Parallel(Parallel {
                q0,
                qx,
                qy,
                d,
                inv_d: d.recip(),
                inv,
            }),
            // A pinhole inside or beside the clip box too: the blocks that reach behind its
            // plane get the footprint of `pinhole_rect`.
            _ => Layout::Pinhole { p: q0, inv },
        };
        Ok(Some(Self {
            layout,
            t_min: r0.t_min(),
            t_max: r0.t_max(),
            clip_lo,
            clip_hi,
            width: camera.width,
            height: camera.height,
        }))
    }

    /// The box of side `dim` at `o` clipped to the walk's clip box, or `None` when they do not
    /// overlap.
    fn clipped(&self, o: [i64; 3], dim: i64) -> Option<([f64; 3], [f64; 3])> {
        let lo = [0, 1, 2].map(|k| (o[k] as f64).max(self.clip_lo[k]));
        let hi = [0, 1, 2].map(|k| ((o[k] + dim) as f64).min(self.clip_hi[k]));
        (0..3).all(|k| lo[k] <= hi[k]).then_some((lo, hi))
    }

    /// The pixels `[i0, i1] x [j0, j1]` whose rays can cross the lookup-space box of side
    /// `dim` at `o` (within the clip box), or `None`: its corners projected onto the image
    /// (along the rays, or through the pinhole), grown by a pixel.
    fn footprint(&self, o: [i64; 3], dim: i64) -> Option<[u32; 4]> {
        let (blo, bhi) = self.clipped(o, dim)?;
        if let &Layout::Pinhole { p, inv } = &self.layout {
            let corners = box_corners([blo, bhi]).map(|c| inv * (c - p));
            if corners.iter().any(|v| v.x <= 0.0) {
                return self.straddling_rect(&corners);
            }
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for c in box_corners([blo, bhi]) {
            // (column, row, t) of the corner; `t` only for parallel rays.
            let v = match &self.layout {
                Layout::Parallel(par) => par.inv * (c - par.q0),
                &Layout::Pinhole { p, inv } => {
                    // `v0 > 0`: a box reaching behind the pinhole's plane went to
                    // `straddling_rect`.
                    let v = inv * (c - p);
                    DVec3::new(v.y / v.x, v.z / v.x, 0.0)
                }
            };
            lo = lo.min(v);
            hi = hi.max(v);
        }
        let behind =
            matches!(self.layout, Layout::Parallel(_)) && (hi.z < self.t_min || lo.z > self.t_max);
        if behind || !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        let (i0, i1) = pixel_range(lo.x, hi.x, self.width)?;
        let (j0, j1) = pixel_range(lo.y, hi.y, self.height)?;
        Some([i0, i1, j0, j1])
    }

    /// The footprint of a box that reaches to or behind the pinhole's plane (`v0 <= 0` at some
    /// corner `v = [D sx sy]^-1 (c - p)`), or `None` when it lies wholly there (rays run
    /// `v = t (1, i, j)`, `t >= 0`, so they never enter `v0 < 0`). The part in front projects
    /// to the corners with `v0 > 0` and, where the box crosses the plane `v0 = 0` at a point
    /// `w`, without bound in the directions of `(w1, w2)`: the rect runs to the image's edge
    /// on the side of each sign (both sides for 0).
    fn straddling_rect(&self, corners: &[DVec3; 8]) -> Option<[u32; 4]> {
        if corners.iter().all(|v| v.x <= 0.0) {
            return None;
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let mut open = |w: DVec3| {
            for (k, c) in [w.y, w.z].into_iter().enumerate() {
                if c >= 0.0 {
                    hi[k] = f64::INFINITY;
                }
                if c <= 0.0 {
                    lo[k] = f64::NEG_INFINITY;
                }
            }
        };
        for k in 0..8 {
            let v = corners[k];
            if v.x == 0.0 {
                open(v);
            }
            for bit in [1, 2, 4] {
                let m = k | bit;
                let u = corners[m];
                if m != k && (v.x > 0.0) != (u.x > 0.0) && v.x != 0.0 && u.x != 0.0 {
                    open(v + (u - v) * (v.x / (v.x - u.x)));
                }
            }
        }
        for v in corners.iter().filter(|v| v.x > 0.0) {
            for (k, c) in [v.y / v.x, v.z / v.x].into_iter().enumerate() {
                lo[k] = lo[k].min(c);
                hi[k] = hi[k].max(c);
            }
        }
        let (i0, i1) = pixel_range(lo[0], hi[0], self.width)?;
        let (j0, j1) = pixel_range(lo[1], hi[1], self.height)?;
        Some([i0, i1, j0, j1])
    }

    /// Row `j`'s parallel rays against the lookup box of side `dim` at `o`, as linear functions
    /// of the column (see [`RowClip`]).
    fn row_clip(&self, par: &Parallel, j: u32, o: [i64; 3], dim: i64) -> RowClip {
        let Parallel {
            q0,
            qx,
            qy,
            d,
            inv_d,
            ..
        } = *par;
        let q = q0 + qy * f64::from(j);
        let mut r = RowClip {
            q,
            qx,
            near: [f64::NEG_INFINITY; 3],
            far: [f64::INFINITY; 3],
            beta: [0.0; 3],
            lo: [0.0; 3],
            hi: [0.0; 3],
            flat: [false; 3],
            t_min: self.t_min,
            t_max: self.t_max,
        };
        for k in 0..3 {
            let lo = (o[k] as f64).max(self.clip_lo[k]);
            let hi = ((o[k] + dim) as f64).min(self.clip_hi[k]);
            (r.lo[k], r.hi[k]) = (lo, hi);
            if d[k] == 0.0 {
                r.flat[k] = true;
                continue;
            }
            let (u, v) = ((lo - q[k]) * inv_d[k], (hi - q[k]) * inv_d[k]);
            (r.near[k], r.far[k]) = if d[k] > 0.0 { (u, v) } else { (v, u) };
            r.beta[k] = -qx[k] * inv_d[k];
        }
        r
    }
}

/// The columns of `[i0, i1]` whose rays in row `j` can cross a box in front of a pinhole,
/// given its corners as `v = [D sx sy]^-1 (c - p)` (see [`Layout::Pinhole`]; every `v0 > 0`,
/// the caller takes the whole span of a box reaching behind the pinhole's plane):
/// row `j`'s rays fill the plane `g(v) = v2 - j v0 = 0`, which cuts the box in a convex polygon
/// whose vertices lie on the box's edges; their columns `v1 / v0` bound the span, grown by a
/// column ([`PixelDir::clip`] decides), or `None` when the plane misses the box.
fn pinhole_span(corners: &[DVec3; 8], j: u32, [i0, i1]: [u32; 2]) -> Option<[u32; 2]> {
    let y = f64::from(j);
    let g = corners.map(|v| v.z - y * v.x);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut take = |v: DVec3| {
        let i = v.y / v.x;
        lo = lo.min(i);
        hi = hi.max(i);
    };
    for k in 0..8 {
        if g[k] == 0.0 {
            take(corners[k]);
        }
        // The edges from corner k along each axis (k without that bit to k with it).
        for bit in [1, 2, 4] {
            let m = k | bit;
            if m != k && g[k] * g[m] < 0.0 {
                let w = g[k] / (g[k] - g[m]);
                take(corners[k] + (corners[m] - corners[k]) * w);
            }
        }
    }
    let (lo, hi) = (
        (lo - 1.0).floor().max(f64::from(i0)),
        (hi + 1.0).ceil().min(f64::from(i1)),
    );
    (lo <= hi).then_some([lo as u32, hi as u32])
}

/// The pixels `[a - 1, b + 1]` (rounded out) of a side of `n`, clipped to it; `None` when
/// they miss it. Infinite bounds run to the edge.
fn pixel_range(a: f64, b: f64, n: u32) -> Option<(u32, u32)> {
    let (a, b) = ((a - 1.0).floor(), (b + 1.0).ceil());
    (b >= 0.0 && a <= f64::from(n) - 1.0)
        .then(|| (a.max(0.0) as u32, b.min(f64::from(n) - 1.0) as u32))
}

/// One perspective pixel's ray in lookup space: its direction and `1 / d` per axis.
#[derive(Debug, Clone, Copy)]
struct PixelDir {
    d: DVec3,
    inv_d: DVec3,
}

impl PixelDir {
    /// `[t0, t1]` of the ray `p + t d` inside `[lo, hi]` and `[t_min, t_max]` (the slab test of
    /// [`crate::ray::clip_box`] with the divisions done once per pixel), or `None`.
    #[inline]
    fn clip(
        &self,
        p: DVec3,
        (lo, hi): ([f64; 3], [f64; 3]),
        t_min: f64,
        t_max: f64,
    ) -> Option<(f64, f64)> {
        let (mut a, mut b) = (t_min, t_max);
        for k in 0..3 {
            if self.d[k] == 0.0 {
                // Half-open, as `RowClip::at`: a face two blocks share belongs to the upper.
                if p[k] < lo[k] || p[k] >= hi[k] {
                    return None;
                }
                continue;
            }
            let (u, v) = (
                (lo[k] - p[k]) * self.inv_d[k],
                (hi[k] - p[k]) * self.inv_d[k],
            );
            a = a.max(u.min(v));
            b = b.min(u.max(v));
        }
        (a < b).then_some((a, b))
    }
}

/// One row of rays against one box: slab `k`'s entry and exit are `near[k] + beta[k] i` and
/// `far[k] + beta[k] i` for column `i` (a slab the rays run parallel to, `flat[k]`, has
/// `near = -inf`, `far = inf`, and its bounds `lo..hi` checked on the ray's coordinate).
/// The slab test of [`crate::ray::clip_box`] (intersected with `[t_min, t_max]` and the
/// walk's clip box) with the divisions hoisted out of the row.
struct RowClip {
    q: DVec3,
    qx: DVec3,
    near: [f64; 3],
    far: [f64; 3],
    beta: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    /// Per axis: the rays run parallel to this slab.
    flat: [bool; 3],
    t_min: f64,
    t_max: f64,
}

impl RowClip {
    /// The columns of `[i0, i1]` whose rays can cross the box (a superset, grown by a column:
    /// [`RowClip::at`] decides), or `None`. A ray crosses the box when every slab's entry comes
    /// before every slab's exit and before `t_max`, every exit after `t_min`, and it lies
    /// between the bounds of the slabs it runs parallel to; each of these is linear in `i`, so
    /// each bounds `i` on one side.
    fn span(&self, [i0, i1]: [u32; 2]) -> Option<[u32; 2]> {
        let (mut lo, mut hi) = (f64::from(i0), f64::from(i1));
        // `alpha + beta i < 0` (strict or not: the margin below covers the difference).
        let mut need = |alpha: f64, beta: f64| {
            if beta > 0.0 {
                hi = hi.min(-alpha / beta);
            } else if beta < 0.0 {
                lo = lo.max(-alpha / beta);
            } else if alpha > 0.0 {
                hi = f64::NEG_INFINITY;
            }
        };
        let slabs: Vec<usize> = (0..3).filter(|&k| !self.flat[k]).collect();
        for k in 0..3 {
            if self.flat[k] {
                // lo <= q + i qx <= hi.
                need(self.lo[k] - self.q[k], -self.qx[k]);
                need(self.q[k] - self.hi[k], self.qx[k]);
                continue;
            }
            need(self.near[k] - self.t_max, self.beta[k]);
            need(self.t_min - self.far[k], -self.beta[k]);
            for &m in &slabs {
                need(self.near[k] - self.far[m], self.beta[k] - self.beta[m]);
            }
        }
        let (lo, hi) = (
            (lo - 1.0).floor().max(f64::from(i0)),
            (hi + 1.0).ceil().min(f64::from(i1)),
        );
        (lo <= hi).then_some([lo as u32, hi as u32])
    }

    /// Column `i`'s ray: its lookup-space origin and `[t0, t1]` inside the box, or `None`.
    #[inline]
    fn at(&self, i: u32) -> Option<(DVec3, f64, f64)> {
        let x = f64::from(i);
        let q = self.q + self.qx * x;
        // Half-open on the slabs the rays run along: a ray exactly on the face two blocks
        // share belongs to the upper one (the cell `floor(q)` the ray walk reads), not to both.
        if (0..3).any(|k| self.flat[k] && !(self.lo[k]..self.hi[k]).contains(&q[k])) {
            return None;
        }
        let (mut a, mut b) = (self.t_min, self.t_max);
        for k in 0..3 {
            let (n, f) = (
                self.near[k] + self.beta[k] * x,
                self.far[k] + self.beta[k] * x,
            );
            if n > a {
                a = n;
            }
            if f < b {
                b = f;
            }
        }
        (a < b).then_some((q, a, b))
    }
}

/// What a block adds to the rays crossing it.
#[derive(Debug, Clone, Copy)]
enum Part {
    /// `mu x chord`.
    Const(f64),
    /// The exact integral of a leaf's field (`fast`: on the f32 kernel).
    Leaf { leaf: u32, fast: bool },
    /// The exact integral of a lower node's tile slot with a varying halo.
    Tile { lower: u32, slot: u32, fast: bool },
    /// The exact integral of an 8^3 block outside every lower node (in a tile of an upper node
    /// or an empty root cell) whose corners on its + faces read a lower node's values.
    Shell { fast: bool },
}

/// One block of the sweep.
#[derive(Debug, Clone, Copy)]
struct Piece {
    part: Part,
    /// Lookup-space origin of its `[o, o + 8]^3` box.
    origin: [i64; 3],
    /// Pixels `[i0, i1] x [j0, j1]` it may cover.
    rect: [u32; 4],
}

/// Every block of every lower node the ray walk would enter, in tree order; then, with
/// `shells`, the blocks outside lower nodes whose trilinear corners read them (sorted by
/// origin).
fn pieces(vol: &Volume, rays: &Rays, shells: bool) -> Vec<Piece> {
    let tree = vol.tree();
    let entered = entered_lowers(tree, 0..tree.lowers.len());
    let mut out = Vec::new();
    let mut outside = std::collections::BTreeSet::new();
    for l in 0..tree.lowers.len() {
        if lower_pieces(vol, rays, l, &mut out) && shells {
            shell_blocks(&entered, tree.lowers[l].origin.map(i64::from), &mut outside);
        }
    }
    if shells {
        shell_pieces(vol, rays, &outside, &mut out);
    }
    out
}

/// The origins of the lower nodes among `lowers` a ray walk would enter (halo not just the
/// background).
fn entered_lowers(
    tree: &Tree,
    lowers: impl Iterator<Item = usize>,
) -> std::collections::HashSet<[i32; 3]> {
    lowers
        .map(|l| &tree.lowers[l])
        .filter(|n| entered(tree, n))
        .map(|n| n.origin)
        .collect()
}

/// Whether a ray walk would enter lower node `n` of `tree` (its halo is not just the
/// background).
fn entered(tree: &Tree, n: &crate::tree::Internal) -> bool {
    !(n.halo.min == tree.background && n.halo.max == tree.background)
}

/// The pieces of lower node `l` (every child block whose halo is not a zero extinction, and
/// whose footprint meets the image) appended to `out`, in slot order; false when the walk
/// would not enter the node or the map does not see it.
fn lower_pieces(vol: &Volume, rays: &Rays, l: usize, out: &mut Vec<Piece>) -> bool {
    let tree = vol.tree();
    let node = &tree.lowers[l];
    let bg = tree.background;
    if !entered(tree, node) {
        return false;
    }
    if rays.footprint(node.origin.map(i64::from), 128).is_none() {
        return false;
    }
    let scale = vol.density_scale();
    let mu_bg = vol.mu_background();
    let chord = max_chord(vol);
    let base = node.origin.map(i64::from);
    for slot in 0..4096usize {
        let local = [slot >> 8, (slot >> 4) & 15, slot & 15];
        let origin = [0, 1, 2].map(|a| base[a] + 8 * local[a] as i64);
        let child = node.has_child(slot).then(|| node.slots[slot]);
        let h = match child {
            Some(leaf) => tree.leaves[leaf as usize].halo,
            None => node.tile_halo_of(slot),
        };
        let part = if h.min == h.max {
            let mu = if h.min == bg {
                mu_bg
            } else {
                crate::math::scaled(scale, f64::from(h.min))
            };
            if mu == 0.0 {
                continue;
            }
            Part::Const(mu)
        } else {
            let fast = kernel_ok(h.min, h.max, chord);
            match child {
                Some(leaf) => Part::Leaf { leaf, fast },
                None => Part::Tile {
                    lower: l as u32,
                    slot: slot as u32,
                    fast,
                },
            }
        };
        if let Some(rect) = rays.footprint(origin, 8) {
            out.push(Piece { part, origin, rect });
        }
    }
    true
}

/// The shell blocks `outside` (see [`shell_blocks`]) that hold something other than the
/// background and meet the image, appended to `out` in their (sorted) order.
fn shell_pieces(
    vol: &Volume,
    rays: &Rays,
    outside: &std::collections::BTreeSet<[i64; 3]>,
    out: &mut Vec<Piece>,
) {
    let tree = vol.tree();
    let bg = tree.background;
    let chord = max_chord(vol);
    let mut acc = Accessor::new(tree);
    let mut block = [0f32; BLOCK];
    for &origin in outside {
        let probe = Piece {
            part: Part::Shell { fast: false },
            origin,
            rect: [0; 4],
        };
        fill(&neighbourhood(tree, &mut acc, &probe), &mut block);
        let (lo, hi) = block
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        if lo == hi && lo == bg {
            continue;
        }
        if let Some(rect) = rays.footprint(origin, 8) {
            let part = Part::Shell {
                fast: kernel_ok(lo, hi, chord),
            };
            out.push(Piece { part, origin, rect });
        }
    }
}

/// The 8^3 blocks before lower node `base` (on its - sides: faces, edges, corner) that lie in
/// no entered lower node: their dual cells on the + faces read `base`'s first voxels.
fn shell_blocks(
    entered: &std::collections::HashSet<[i32; 3]>,
    base: [i64; 3],
    out: &mut std::collections::BTreeSet<[i64; 3]>,
) {
    for bits in 1..8i64 {
        let step = [bits >> 2, (bits >> 1) & 1, bits & 1];
        let lower = [0, 1, 2].map(|a| base[a] - 128 * step[a]);
        let inside = lower.map(i32::try_from).iter().all(Result::is_ok)
            && entered.contains(&lower.map(|c| c as i32));
        if inside {
            continue;
        }
        // The blocks of that neighbour touching `base`: the last block on each stepped axis,
        // every block on the others.
        let span = |a: usize| if step[a] == 1 { 15..16 } else { 0..16 };
        for x in span(0) {
            for y in span(1) {
                for z in span(2) {
                    out.insert([lower[0] + 8 * x, lower[1] + 8 * y, lower[2] + 8 * z]);
                }
            }
        }
    }
}

/// True when a ray can meet a non-zero extinction outside lower nodes other than in the shell
/// blocks ([`shell_blocks`]): a non-zero background, or a root or upper-node tile other than
/// the background. Then the rays are walked for everything outside lower nodes (shells
/// included) instead.
fn needs_rest(vol: &Volume) -> bool {
    let tree = vol.tree();
    let bg = tree.background;
    if vol.mu_background() != 0.0 {
        return true;
    }
    let root_tile = tree
        .root
        .iter()
        .any(|e| matches!(e.slot, RootSlot::Tile { value, .. } if value != bg));
    let upper = tree
        .uppers
        .iter()
        .any(|n| (0..n.slots.len()).any(|s| !n.has_child(s) && n.tile_value(s) != bg));
    root_tile || upper
}

/// The 8 blocks whose values a block's trilinear corners read: itself (`k = 0`) and its + face,
/// edge and corner neighbours (`k` = bits x, y, z).
fn neighbourhood<'t>(tree: &'t Tree, acc: &mut Accessor<'t>, p: &Piece) -> [Block<'t>; 8] {
    let (first, nb) = match p.part {
        Part::Leaf { leaf, .. } => (
            Block::Leaf(tree.leaf_values(leaf)),
            tree.neighbours.get(leaf as usize),
        ),
        Part::Tile { lower, slot, .. } => (
            Block::Const(tree.lowers[lower as usize].tile_value(slot as usize)),
            None,
        ),
        Part::Const(_) | Part::Shell { .. } => (acc.block_at(p.origin), None),
    };
    blocks_around(tree, acc, p.origin, first, nb)
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

    /// Each pixel's lookup-space direction through a pinhole, rows `y0..=y1`, as the ray path
    /// computes it (empty for parallel rays).
    fn pixel_dirs(&self, y0: u32, y1: u32) -> Result<Vec<PixelDir>> {
        let (vol, camera, w) = (self.vol, self.camera, self.rays.width);
        let mut dirs = Vec::new();
        if matches!(self.rays.layout, Layout::Pinhole { .. }) {
            dirs.reserve(((y1 - y0 + 1) * w) as usize);
            for j in y0..=y1 {
                for i in 0..w {
                    let (_, d) = lookup_ray(vol, &camera.pixel_ray(i, j)?, Interp::Trilinear);
                    let d = DVec3::from(d);
                    dirs.push(PixelDir {
                        d,
                        inv_d: d.recip(),
                    });
                }
            }
        }
        Ok(dirs)
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

    /// Every ray of rows `ja..=jb` (band rows from `y0`) that crosses piece `p`:
    /// `f(n, q, d, a, b)` with its pixel's index in the band, its lookup-space origin and
    /// direction, and its chord `[a, b]` inside the block (and the walk's clip box).
    fn chords(
        &self,
        p: &Piece,
        (ja, jb, y0): (u32, u32, u32),
        dirs: &[PixelDir],
        mut f: impl FnMut(usize, DVec3, DVec3, f64, f64),
    ) {
        let rays = &self.rays;
        let (w, [i0, i1, ..]) = (rays.width, p.rect);
        match &rays.layout {
            Layout::Parallel(par) => {
                for j in ja..=jb {
                    let row = rays.row_clip(par, j, p.origin, 8);
                    let Some([i0, i1]) = row.span([i0, i1]) else {
                        continue;
                    };
                    for i in i0..=i1 {
                        if let Some((q, a, b)) = row.at(i) {
                            f(((j - y0) * w + i) as usize, q, par.d, a, b);
                        }
                    }
                }
            }
            &Layout::Pinhole { p: q, inv } => {
                let Some(bx) = rays.clipped(p.origin, 8) else {
                    return;
                };
                let corners = box_corners([bx.0, bx.1]).map(|c| inv * (c - q));
                // A box reaching behind the pinhole's plane: its footprint's columns
                // (`Rays::straddling_rect`); each ray is clipped to the box all the same.
                let straddles = corners.iter().any(|v| v.x <= 0.0);
                for j in ja..=jb {
                    let span = if straddles {
                        Some([i0, i1])
                    } else {
                        pinhole_span(&corners, j, [i0, i1])
                    };
                    let Some([i0, i1]) = span else {
                        continue;
                    };
                    for i in i0..=i1 {
                        let n = ((j - y0) * w + i) as usize;
                        let pd = &dirs[n];
                        if let Some((a, b)) = pd.clip(q, bx, rays.t_min, rays.t_max) {
                            f(n, q, pd.d, a, b);
                        }
                    }
                }
            }
        }
    }

    /// Band `b` (rows `[b rows, b rows + rows)`): every pixel's optical depth into `tau`,
    /// [`Sweep::stride`] values a pixel (the full ray, then each slice `[0, t_k]`).
    fn band(&self, b: usize, tau: &mut [f64], lookups: &mut u64) -> Result<()> {
        if let Some(m) = &self.march {
            return self.band_march(m, b, tau, lookups);
        }
        if let Some(f) = &self.flight {
            return self.band_flight(f, b, tau, lookups, None);
        }
        let (vol, camera, rays) = (self.vol, self.camera, &self.rays);
        let (pieces, ids) = (&self.pieces, &self.bins[b]);
        let (y0, y1) = self.band_span(b, tau.len());
        let tree = vol.tree();
        let w = rays.width;
        let stride = self.stride();
        let scale = vol.density_scale();
        let mut acc = Accessor::new(tree);
        let mut n = Counts::default();
        // Perspective: each pixel's lookup-space direction, as the ray path computes it.
        let dirs = self.pixel_dirs(y0, y1)?;
        if self.rest_needed {
            for j in y0..=y1 {
                for i in 0..w {
                    let ray = camera.pixel_ray(i, j)?;
                    let at = ((j - y0) * w + i) as usize * stride;
                    tau[at] = optical_depth_above_lowers(vol, &ray, &mut acc, &mut n);
                    for (k, &t) in self.depths.iter().enumerate() {
                        tau[at + 1 + k] = optical_depth_above_lowers(
                            vol,
                            &ray.with_range(0.0, t)?,
                            &mut acc,
                            &mut n,
                        );
                    }
                }
            }
        }
        let kernel = Kernel::new();
        let width = kernel.width();
        let mut block = [0f32; BLOCK];
        for &id in ids {
            let p = &pieces[id as usize];
            let [_, _, j0, j1] = p.rect;
            let rows = (j0.max(y0), j1.min(y1), y0);
            match p.part {
                Part::Leaf { fast: true, .. }
                | Part::Tile { fast: true, .. }
                | Part::Shell { fast: true } => {
                    fill(&neighbourhood(tree, &mut acc, p), &mut block);
                    let centre = DVec3::from(p.origin.map(|c| (c + 4) as f64));
                    // The rays that cross the block, `width` at a time (lanes packed across rows); a
                    // slice depth inside a chord adds a lane for the chord up to it.
                    let mut lanes = Lanes::default();
                    // Per lane: the pixel, 0 (the whole chord) or 1 + k (slice k's part), and
                    // the chord's end.
                    let mut at = [(0usize, 0usize, 0.0f64); LANES];
                    let mut used = 0;
                    let mut flush =
                        |lanes: &mut Lanes, at: &[(usize, usize, f64); LANES], used: &mut usize| {
                            let sums = kernel.integrate(&block, lanes);
                            for (l, &(px, slot, end)) in at.iter().enumerate().take(*used) {
                                if sums.cells[l] == 0 {
                                    continue;
                                }
                                let v = scale * sums.tau[l];
                                *lookups += 4 + 4 * u64::from(sums.cells[l]);
                                if slot > 0 {
                                    tau[px * stride + slot] += v;
                                    continue;
                                }
                                tau[px * stride] += v;
                                for (k, &t) in self.depths.iter().enumerate() {
                                    if t >= end {
                                        tau[px * stride + 1 + k] += v;
                                    }
                                }
                            }
                            // Lanes the next batch leaves unfilled must read as unused
                            // (`len = 0`); their other fields are never read unmasked.
                            lanes.len = [0.0; LANES];
                            *used = 0;
                        };
                    self.chords(p, rows, &dirs, |px, q, d, a, b| {
                        let e = ((q - centre) + d * a).to_array();
                        let cuts = self
                            .depths
                            .iter()
                            .enumerate()
                            .filter(|(_, &t)| t > a && t < b);
                        for (slot, end) in
                            std::iter::once((0, b)).chain(cuts.map(|(k, &t)| (1 + k, t)))
                        {
                            lanes.set(used, e, d.to_array(), end - a);
                            at[used] = (px, slot, b);
                            used += 1;
                            if used == width {
                                flush(&mut lanes, &at, &mut used);
                            }
                        }
                    });
                    if used > 0 {
                        flush(&mut lanes, &at, &mut used);
                    }
                }
                // Closed form, or the f64 ray code: pixel by pixel.
                Part::Const(_)
                | Part::Leaf { fast: false, .. }
                | Part::Tile { fast: false, .. }
                | Part::Shell { fast: false } => {
                    self.chords(p, rows, &dirs, |px, q, d, a, b| {
                        let (q, d, lin) = (q.to_array(), d.to_array(), Interp::Trilinear);
                        let mut part = |t1: f64| match p.part {
                            Part::Const(mu) => mu * (t1 - a),
                            Part::Leaf { leaf, .. } => {
                                scale * leaf_integral(&mut acc, leaf, q, d, a, t1, lin, &mut n)
                            }
                            _ => scale * cells_integral(&mut acc, q, d, a, t1, lin, &mut n),
                        };
                        let full = part(b);
                        self.add(tau, px, (a, b), full, part);
                    });
                }
            }
        }
        *lookups += n.reads;
        Ok(())
    }
}

/// The pieces of each band of `rows` rows, in piece order.
fn bins(pieces: &[Piece], rows: u32, height: u32) -> Vec<Vec<u32>> {
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); height.div_ceil(rows) as usize];
    for (id, p) in pieces.iter().enumerate() {
        for b in (p.rect[2] / rows)..=(p.rect[3] / rows) {
            bins[b as usize].push(id as u32);
        }
    }
    bins
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
    let mut t_image = vec![0.0f32; camera.pixels() as usize];
    let done: Vec<(u64, Vec<f32>, Vec<f32>)> = t_image
        .par_chunks_mut(rows as usize * w as usize)
        .enumerate()
        .map(|(b, t_band)| {
            let mut tau = vec![0.0f64; t_band.len() * stride];
            let mut lookups = 0;
            // A null-collision map's error bar takes each pixel's bounds on T.
            let mut bounds = Vec::new();
            match &sweep.flight {
                Some(f) if s.std_err => {
                    sweep.band_flight(f, b, &mut tau, &mut lookups, Some(&mut bounds))?;
                }
                _ => sweep.band(b, &mut tau, &mut lookups)?,
            }
            let y0 = b as u32 * rows;
            let mut err = vec![0.0f32; if s.std_err { t_band.len() } else { 0 }];
            let slices = if samples > 1 || sweep.flight.is_some() {
                let est = sweep.flight.as_ref().map(|_| (&s.estimator, &bounds[..]));
                finish_samples(
                    camera,
                    y0,
                    &tau,
                    (stride / samples, samples),
                    est,
                    t_band,
                    &mut err,
                )?
            } else {
                finish_band(camera, y0, &tau, stride, t_band)?
            };
            progress.advance(t_band.len() as u64);
            Ok((lookups, slices, err))
        })
        .collect::<Result<_>>()?;
    if sweep.capped.load(std::sync::atomic::Ordering::Relaxed) {
        // An estimate ran out of its collision budget: the ray path caps it where it stands.
        return Ok(None);
    }
    let mut bands = Vec::with_capacity(done.len());
    let mut errs = Vec::with_capacity(done.len());
    for (lookups, slices, err) in done {
        bands.push((lookups, slices));
        errs.push(err);
    }
    let mut map = assemble(camera, s, depths, t_image, &bands, start);
    if samples > 1 || sweep.flight.is_some() {
        map.stats.samples = camera.pixels() * samples as u64;
        map.std_err = s.std_err.then(|| errs.concat());
        if let Some(e) = &map.std_err {
            map.stats.max_std_err = e.iter().fold(0.0, |m, &v| m.max(f64::from(v)));
        }
    }
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
            return Err(crate::Error::nan_on_ray("optical depth", &ray));
        }
        t_band[n] = (-px[0]).exp() as f32;
        slices.extend(px[1..].iter().map(|x| (-x).exp() as f32));
    }
    Ok(slices)
}

/// The map from its `T` image and its bands' `(lookups, slices)`.
fn assemble(
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    t_image: Vec<f32>,
    bands: &[(u64, Vec<f32>)],
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

#[cfg(test)]
mod tests;
