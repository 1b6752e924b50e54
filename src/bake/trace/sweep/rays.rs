//! The map's rays in lookup space: orthographic rows (`Parallel`, [`RowClip`]) or rays through a
//! pinhole ([`PixelDir`]), the walk's clip box, and the footprint of a box on the image.

use crate::bake::camera::{Camera, Projection};
use crate::error::Result;
use crate::math::box_corners;
use crate::traverse::lookup_ray;
use crate::volume::{Interp, Volume};
use glam::{DMat3, DVec3};

/// Orthographic rays in lookup space: pixel `(i, j)`'s is `q0 + i qx + j qy + t d`;
/// `inv = [qx qy d]^-1` maps offsets from `q0` to `(i, j, t)`.
#[derive(Clone, Copy)]
pub(super) struct Parallel {
    q0: DVec3,
    qx: DVec3,
    qy: DVec3,
    pub(super) d: DVec3,
    /// `1 / d` per axis (unused where `d` is zero).
    inv_d: DVec3,
    inv: DMat3,
}

/// How pixel `(i, j)`'s ray runs in lookup space.
#[derive(Clone, Copy)]
pub(super) enum Layout {
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
pub(super) struct Rays {
    pub(super) layout: Layout,
    pub(super) t_min: f64,
    pub(super) t_max: f64,
    /// The lookup-space box the ray walk clips rays to (the value box, grown by the reach of
    /// trilinear lookups): outside it every ray has the background, which the rest walk adds.
    clip_lo: [f64; 3],
    clip_hi: [f64; 3],
    pub(super) width: u32,
    pub(super) height: u32,
}

impl Rays {
    /// The rays of `camera`, or `None` when the sweep cannot take them: a degenerate frame in
    /// index space, or a pinhole that is not strictly behind the whole clip box (then some
    /// block's footprint is unbounded and the rays are traced instead).
    pub(super) fn new(vol: &Volume, camera: &Camera) -> Result<Option<Self>> {
        // As `hdda::Walker::run`: lookup cells whose trilinear reads touch the value box.
        let clip = match vol.value_box() {
            Some([lo, hi]) => (lo.map(|c| (c - 1) as f64), hi.map(|c| (c + 1) as f64)),
            None => ([0.0; 3], [0.0; 3]),
        };
        Self::clipped_to(vol, camera, clip)
    }

    /// The rays of `lattice` (lookup space), or `None` when `[qx qy d]` is singular.
    pub(super) fn lattice(vol: &Volume, lattice: &super::Lattice) -> Option<Self> {
        let (clip_lo, clip_hi) = match vol.value_box() {
            Some([lo, hi]) => (lo.map(|c| (c - 1) as f64), hi.map(|c| (c + 1) as f64)),
            None => ([0.0; 3], [0.0; 3]),
        };
        let v = DVec3::from_array;
        let (q0, qx, qy, d) = (v(lattice.q0), v(lattice.qx), v(lattice.qy), v(lattice.d));
        let m = DMat3::from_cols(qx, qy, d);
        let det = m.determinant();
        if !(det.is_finite() && det != 0.0 && q0.is_finite() && lattice.t_max.is_finite()) {
            return None;
        }
        Some(Self {
            layout: Layout::Parallel(Parallel {
                q0,
                qx,
                qy,
                d,
                inv_d: d.recip(),
                inv: m.inverse(),
            }),
            t_min: 0.0,
            t_max: lattice.t_max,
            clip_lo,
            clip_hi,
            width: lattice.width,
            height: lattice.height,
        })
    }

    /// [`Rays::new`] with the walk's clip box `clip` (lookup space) given.
    pub(super) fn clipped_to(
        vol: &Volume,
        camera: &Camera,
        (clip_lo, clip_hi): ([f64; 3], [f64; 3]),
    ) -> Result<Option<Self>> {
        if crate::bake::camera::is_omni(camera.kind) {
            // Not one projection: a cube map is swept face by face (`render_cube`).
            return Ok(None);
        }
        let r0 = camera.pixel_ray(0, 0)?;
        // A pinhole farther than `scene::FAR` box sizes (a light 1e16 away): its footprints
        // cannot be resolved in f64, so the map is traced, each ray moved next to the volume.
        if let Some((lo, hi)) = crate::scene::Scene::volume_box(vol) {
            let size = (hi - lo).max_element();
            if (r0.origin() - (lo + hi) / 2.0).length() > crate::scene::FAR * size {
                return Ok(None);
            }
        }
        let (q0, d) = lookup_ray(vol, &r0, Interp::Trilinear);
        let (q0, d) = (DVec3::from(q0), DVec3::from(d));
        let qx = vol.to_index_dir(DVec3::from(camera.step_x));
        let qy = vol.to_index_dir(DVec3::from(camera.step_y));
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

    /// Every ray of rows `ja..=jb` (band rows from `y0`) that crosses the `8^3` block at
    /// `origin` whose footprint is `rect` ([`Rays::footprint`]): `f(n, q, d, a, b)` with its
    /// pixel's index in the band, its lookup-space origin and direction, and its chord
    /// `[a, b]` inside the block (and the walk's clip box).
    pub(super) fn chords(
        &self,
        (origin, rect): ([i64; 3], [u32; 4]),
        (ja, jb, y0): (u32, u32, u32),
        dirs: &[PixelDir],
        mut f: impl FnMut(usize, DVec3, DVec3, f64, f64),
    ) {
        let rays = self;
        let (w, [i0, i1, ..]) = (rays.width, rect);
        match &rays.layout {
            Layout::Parallel(par) => {
                for j in ja..=jb {
                    let row = rays.row_clip(par, j, origin, 8);
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
                let Some(bx) = rays.clipped(origin, 8) else {
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

    /// Each pixel's lookup-space direction through a pinhole, rows `y0..=y1` of `camera`'s
    /// map of `vol`, as the ray path computes it (empty for parallel rays).
    pub(super) fn pixel_dirs(
        &self,
        vol: &Volume,
        camera: &Camera,
        y0: u32,
        y1: u32,
    ) -> Result<Vec<PixelDir>> {
        let w = self.width;
        let mut dirs = Vec::new();
        if matches!(self.layout, Layout::Pinhole { .. }) {
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

    /// The box of side `dim` at `o` clipped to the walk's clip box, or `None` when they do not
    /// overlap.
    pub(super) fn clipped(&self, o: [i64; 3], dim: i64) -> Option<([f64; 3], [f64; 3])> {
        let lo = [0, 1, 2].map(|k| (o[k] as f64).max(self.clip_lo[k]));
        let hi = [0, 1, 2].map(|k| ((o[k] + dim) as f64).min(self.clip_hi[k]));
        (0..3).all(|k| lo[k] <= hi[k]).then_some((lo, hi))
    }

    /// The pixels `[i0, i1] x [j0, j1]` whose rays can cross the lookup-space box of side
    /// `dim` at `o` (within the clip box), or `None`: its corners projected onto the image
    /// (along the rays, or through the pinhole), grown by a pixel.
    pub(super) fn footprint(&self, o: [i64; 3], dim: i64) -> Option<[u32; 4]> {
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
    pub(super) fn row_clip(&self, par: &Parallel, j: u32, o: [i64; 3], dim: i64) -> RowClip {
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
pub(super) fn pinhole_span(corners: &[DVec3; 8], j: u32, [i0, i1]: [u32; 2]) -> Option<[u32; 2]> {
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
pub(super) struct PixelDir {
    pub(super) d: DVec3,
    pub(super) inv_d: DVec3,
}

impl PixelDir {
    /// `[t0, t1]` of the ray `p + t d` inside `[lo, hi]` and `[t_min, t_max]` (the slab test of
    /// [`crate::ray::clip_box`] with the divisions done once per pixel), or `None`.
    #[inline]
    pub(super) fn clip(
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
pub(super) struct RowClip {
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
    pub(super) fn span(&self, [i0, i1]: [u32; 2]) -> Option<[u32; 2]> {
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
        // The slabs the rays cross (a fixed array: this runs for every row of every block).
        let (mut slabs, mut crossed) = ([0usize; 3], 0);
        for k in (0..3).filter(|&k| !self.flat[k]) {
            slabs[crossed] = k;
            crossed += 1;
        }
        let slabs = &slabs[..crossed];
        for k in 0..3 {
            if self.flat[k] {
                // lo <= q + i qx <= hi.
                need(self.lo[k] - self.q[k], -self.qx[k]);
                need(self.q[k] - self.hi[k], self.qx[k]);
                continue;
            }
            need(self.near[k] - self.t_max, self.beta[k]);
            need(self.t_min - self.far[k], -self.beta[k]);
            for &m in slabs {
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
    pub(super) fn at(&self, i: u32) -> Option<(DVec3, f64, f64)> {
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
