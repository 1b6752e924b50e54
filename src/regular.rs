//! Exact regular tracking: the optical depth `tau = integral of mu_t(p(t)) dt` along a ray, in
//! closed form, and `T = exp(-tau)`. This is umbra's reference answer.
//!
//! - Constant segments (tiles, constant halos) contribute `mu * length`, no lookups.
//! - Nearest (piecewise-constant voxels): inside a segment, a unit DDA in lookup space sums
//!   `mu(voxel) * dt` over the voxels crossed.
//! - Trilinear: inside one dual cell the trilinear field along the ray is a cubic polynomial in
//!   `t` (a product of three linear factors), which two-point Gauss-Legendre quadrature
//!   integrates exactly: `int_a^b f = h (f(m - h/sqrt3) + f(m + h/sqrt3))`, `m = (a+b)/2`,
//!   `h = (b-a)/2`.
//! - The parts of the ray outside every segment have the background density: `mu_bg * gap`.
//!
//! **Speed.** A leaf's segment reads the leaf's values directly (and, for trilinear, the 8^3
//! blocks of up to 7 + neighbours, resolved once per segment), never descending the tree per
//! voxel. The trilinear walk keeps the 8 corner values of the current dual cell and, stepping to
//! the next cell along axis `a`, reads only the 4 corners of the new far face (the other 4 are
//! the old cell's). `lookups` counts the voxel values actually read.

use crate::error::Result;
use crate::math::{floor_i64, non_empty};
use crate::ray::Ray;
use crate::traverse::{lookup_ray, walk_nodes, Dda, Granularity, Segment};
use crate::tree::{Accessor, Block, Neighbour};
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

mod batch;
pub(crate) mod kernel;
mod profile;
pub use batch::optical_depths;
pub use kernel::Simd;
pub use profile::{optical_depth_profile, optical_depth_profile_tau, Profile, MAX_PIECES};

/// Exact optical depth along a ray and what it cost.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OpticalDepth {
    /// Optical depth (may be `inf` through opaque voxels or an infinite ray in a non-zero
    /// background).
    pub tau: f64,
    /// Density lookups (voxel reads).
    pub lookups: u64,
    /// HDDA segments visited.
    pub segments: u64,
    /// Voxels (nearest) or dual cells (trilinear) integrated.
    pub cells: u64,
}

impl OpticalDepth {
    /// Transmittance `exp(-tau)`.
    #[must_use]
    pub fn transmittance(&self) -> f64 {
        (-self.tau).exp()
    }
}

const GAUSS: f64 = 0.577_350_269_189_625_8; // 1 / sqrt(3)

/// Exact optical depth of `ray` through `vol`.
///
/// # Errors
/// None at present; the `Result` leaves room for per-query validation.
pub fn optical_depth(vol: &Volume, ray: &Ray, interp: Interp) -> Result<OpticalDepth> {
    let mut acc = Accessor::new(vol.tree());
    let mut n = Counts::default();
    let (q, d) = lookup_ray(vol, ray, interp);
    let scale = vol.density_scale();
    let leaf = |acc: &mut Accessor<'_>, s: Segment, leaf: u32, n: &mut Counts| {
        if s.is_constant() {
            s.mu_min * s.length()
        } else {
            scale * leaf_integral(acc, leaf, q, d, s.t_min, s.t_max, interp, n)
        }
    };
    let (tau, w) = walk_tau(vol, ray, interp, Granularity::Leaf, &mut acc, &mut n, leaf);
    if tau.is_nan() {
        return Err(crate::error::Error::nan_on_ray("optical depth", ray));
    }
    Ok(OpticalDepth {
        tau,
        lookups: n.reads,
        segments: w.segments,
        cells: n.cells,
    })
}

/// The optical depth of `ray` outside lower nodes: what a walk at lower-node granularity emits
/// for tiles of upper nodes, root cells and the background, lower nodes left out (the sweep
/// integrates those itself).
pub(crate) fn optical_depth_above_lowers(
    vol: &Volume,
    ray: &Ray,
    acc: &mut Accessor<'_>,
    n: &mut Counts,
) -> f64 {
    walk_tau(
        vol,
        ray,
        Interp::Trilinear,
        Granularity::Lower,
        acc,
        n,
        |_, _, _, _| 0.0,
    )
    .0
}

/// The optical depth of a walk at granularity `gran`: a node's segment by `node` (its optical
/// depth), the other segments in closed form where constant and cell by cell otherwise, the
/// gaps at the background's extinction.
#[allow(clippy::too_many_arguments)]
fn walk_tau<'t>(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    gran: Granularity,
    acc: &mut Accessor<'t>,
    n: &mut Counts,
    mut node: impl FnMut(&mut Accessor<'t>, Segment, u32, &mut Counts) -> f64,
) -> (f64, crate::traverse::Walk) {
    let (q, d) = lookup_ray(vol, ray, interp);
    let scale = vol.density_scale();
    let mut tau = 0.0f64;
    let w = walk_nodes(vol, ray, interp, gran, |s: Segment, id| {
        tau += match id {
            Some(id) => node(acc, s, id, n),
            None if s.is_constant() => s.mu_min * s.length(),
            None => scale * cells_integral(acc, q, d, s.t_min, s.t_max, interp, n),
        };
        ControlFlow::Continue(())
    });
    let gap = w.length - w.covered;
    let mu_bg = vol.mu_background();
    if mu_bg != 0.0 && gap > 0.0 {
        tau += mu_bg * gap;
    }
    if w.unloaded {
        // A partial load that missed this ray's leaves (a bug): refused as NaN, never a number.
        tau = f64::NAN;
    }
    (tau, w)
}

/// Cells integrated and voxel values read.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct Counts {
    pub(crate) cells: u64,
    pub(crate) reads: u64,
}

/// Integral of the (unscaled) density over `[t0, t1]`, cell by cell.
pub(crate) fn integrate_cells(
    acc: &mut Accessor<'_>,
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    interp: Interp,
    cells: &mut u64,
) -> f64 {
    let mut n = Counts::default();
    let v = cells_integral(acc, q, d, t0, t1, interp, &mut n);
    *cells += n.cells;
    v
}

/// The lookup cells the part `[t0, t1]` of the line can touch: `floor` of its end points.
#[inline]
pub(crate) fn cell_range(q: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> ([i64; 3], [i64; 3]) {
    let p0 = [0, 1, 2].map(|a| q[a] + d[a] * t0);
    let p1 = [0, 1, 2].map(|a| q[a] + d[a] * t1);
    let lo = [0, 1, 2].map(|a| floor_i64(p0[a].min(p1[a])));
    let hi = [0, 1, 2].map(|a| floor_i64(p0[a].max(p1[a])));
    (lo, hi)
}

/// Any segment, every voxel through the cached accessor.
pub(crate) fn cells_integral(
    acc: &mut Accessor<'_>,
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    interp: Interp,
    n: &mut Counts,
) -> f64 {
    if !non_empty(t0, t1) {
        return 0.0;
    }
    let (lo, hi) = cell_range(q, d, t0, t1);
    let w = Dda::new(q, d, t0, lo, hi);
    let mut src = AccSource { acc, cell: [0; 3] };
    match interp {
        Interp::Nearest => nearest_cells(&mut src, w, q, d, t1, lo, hi, n),
        Interp::Trilinear => trilinear_cells(&mut src, w, q, d, t1, lo, hi, n),
    }
}

/// A leaf's segment: the cells are the leaf's (lookup cells `[o, o + 7]`), read straight from
/// its values; trilinear corners on the + faces come from the neighbouring blocks.
#[allow(clippy::too_many_arguments)]
pub(crate) fn leaf_integral(
    acc: &mut Accessor<'_>,
    leaf: u32,
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    interp: Interp,
    n: &mut Counts,
) -> f64 {
    if !non_empty(t0, t1) {
        return 0.0;
    }
    let tree = acc.tree();
    let l = &tree.leaves[leaf as usize];
    let o = l.origin.map(i64::from);
    let (lo, hi) = (o, o.map(|c| c + 7));
    let w = Dda::new(q, d, t0, lo, hi);
    let mut src = LeafSource {
        values: tree.values_of(l),
        blocks: [Block::Const(f32::NAN); 8],
        base: 0,
        interior: true,
    };
    match interp {
        Interp::Nearest => nearest_cells(&mut src, w, q, d, t1, lo, hi, n),
        Interp::Trilinear => {
            // Block `k` (bits x, y, z) is the 8^3 block at `o + 8 * bits`; only those the
            // corners can reach are resolved: on axis `a` the cells reach the + face only if
            // the ray moves up `a` or starts on that face.
            src.blocks[0] = Block::Leaf(tree.values_of(l));
            let reach = [0, 1, 2].map(|a| usize::from(d[a] > 0.0 || w.cell[a] == hi[a]));
            let nb = tree.neighbours.get(leaf as usize);
            for k in 1..8usize {
                let bits = [k >> 2, (k >> 1) & 1, k & 1];
                if (0..3).all(|a| bits[a] <= reach[a]) {
                    src.blocks[k] = match nb.map(|n| n[k - 1]) {
                        Some(Neighbour::Leaf(i)) => Block::Leaf(tree.leaf_values(i)),
                        Some(Neighbour::Const(c)) => Block::Const(c),
                        _ => acc.block_at([0, 1, 2].map(|a| o[a] + 8 * bits[a] as i64)),
                    };
                }
            }
            trilinear_cells(&mut src, w, q, d, t1, lo, hi, n)
        }
    }
}

/// Where the cell walkers read voxel values: `at(cell)` positions the source on a lookup cell,
/// `get(k)` reads corner `k` (`x << 2 | y << 1 | z` offsets) of that cell; nearest reads only
/// corner 0, the cell's own voxel.
trait CornerSource {
    fn at(&mut self, cell: [i64; 3]);
    fn get(&mut self, k: usize) -> f32;
}

/// Reads through the cached accessor (any cell anywhere).
struct AccSource<'a, 't> {
    acc: &'a mut Accessor<'t>,
    cell: [i64; 3],
}

impl CornerSource for AccSource<'_, '_> {
    #[inline]
    fn at(&mut self, cell: [i64; 3]) {
        self.cell = cell;
    }
    #[inline]
    fn get(&mut self, k: usize) -> f32 {
        let c = self.cell;
        self.acc.value_at([
            c[0] + (k >> 2) as i64,
            c[1] + ((k >> 1) & 1) as i64,
            c[2] + (k & 1) as i64,
        ])
    }
}

/// Offsets of the 8 corners of a cell inside a leaf's value array.
const CORNER_OFFSET: [usize; 8] = [0, 1, 8, 9, 64, 65, 72, 73];

/// Reads a leaf's cells (`[o, o + 7]`): corners inside the leaf straight from its values, the
/// others (on the + faces) from the neighbouring blocks.
struct LeafSource<'t> {
    values: &'t [f32; 512],
    blocks: [Block<'t>; 8],
    /// Leaf offset of the current cell.
    base: usize,
    /// Every corner of the current cell is in the leaf.
    interior: bool,
}

impl CornerSource for LeafSource<'_> {
    #[inline]
    fn at(&mut self, cell: [i64; 3]) {
        // Leaf-local coordinates are the low 3 bits (the leaf origin is a multiple of 8).
        let u = cell.map(|c| (c & 7) as usize);
        self.base = (u[0] << 6) | (u[1] << 3) | u[2];
        // A local coordinate is 7 (the + face) iff its 3 bits are all set.
        self.interior = self.base & (self.base >> 1) & (self.base >> 2) & 0o111 == 0;
    }
    #[inline]
    fn get(&mut self, k: usize) -> f32 {
        if self.interior || k == 0 {
            return self.values[(self.base + CORNER_OFFSET[k]) & 511];
        }
        let u = [
            (self.base >> 6) + (k >> 2),
            ((self.base >> 3) & 7) + ((k >> 1) & 1),
            (self.base & 7) + (k & 1),
        ];
        let b = ((u[0] >> 3) << 2) | ((u[1] >> 3) << 1) | (u[2] >> 3);
        self.blocks[b].get(((u[0] & 7) << 6) | ((u[1] & 7) << 3) | (u[2] & 7))
    }
}

/// Nearest: `sum value(cell) * dt` over the cells of `[t0, t1]` within `[lo, hi]`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn nearest_cells(
    src: &mut impl CornerSource,
    w: Dda,
    q: [f64; 3],
    d: [f64; 3],
    t1: f64,
    lo: [i64; 3],
    hi: [i64; 3],
    n: &mut Counts,
) -> f64 {
    let mut sum = 0.0f64;
    nearest_walk(src, w, q, d, t1, lo, hi, n, |v, ta, tb| {
        sum += v * (tb - ta);
    });
    sum
}

/// The voxels of `[t0, t1]` within `[lo, hi]` in ray order: `visit(value, ta, tb)` for each
/// voxel's piece `[ta, tb]` of the line.
#[allow(clippy::too_many_arguments)]
#[inline]
fn nearest_walk(
    src: &mut impl CornerSource,
    mut w: Dda,
    q: [f64; 3],
    d: [f64; 3],
    t1: f64,
    lo: [i64; 3],
    hi: [i64; 3],
    n: &mut Counts,
    mut visit: impl FnMut(f64, f64, f64),
) {
    let mut t = w.t0;
    loop {
        let axis = w.axis();
        let t_exit = w.t_next[axis].min(t1);
        if t_exit > t {
            n.cells += 1;
            n.reads += 1;
            src.at(w.cell);
            visit(f64::from(src.get(0)), t, t_exit);
            t = t_exit;
        }
        if t_exit >= t1 {
            return;
        }
        w.advance(axis, q, d, lo, hi);
    }
}

/// Trilinear: the exact integral over the dual cells of `[t0, t1]` within `[lo, hi]`, reusing
/// the 4 corners two consecutive cells share.
#[allow(clippy::too_many_arguments)]
#[inline]
fn trilinear_cells(
    src: &mut impl CornerSource,
    w: Dda,
    q: [f64; 3],
    d: [f64; 3],
    t1: f64,
    lo: [i64; 3],
    hi: [i64; 3],
    n: &mut Counts,
) -> f64 {
    let du = [0, 1, 2].map(|a| d[a] * GAUSS);
    let mut sum = 0.0f64;
    trilinear_walk(src, w, q, d, t1, lo, hi, n, |v, cell, ta, tb| {
        sum += cubic_cell_integral(v, cell, q, d, du, ta, tb);
    });
    sum
}

/// The dual cells of `[t0, t1]` within `[lo, hi]` in ray order: `visit(corners, cell, ta, tb)`
/// for each cell's piece `[ta, tb]` of the line, reusing the 4 corners two consecutive cells
/// share.
#[allow(clippy::too_many_arguments)]
#[inline]
fn trilinear_walk(
    src: &mut impl CornerSource,
    mut w: Dda,
    q: [f64; 3],
    d: [f64; 3],
    t1: f64,
    lo: [i64; 3],
    hi: [i64; 3],
    n: &mut Counts,
    mut visit: impl FnMut(&[f64; 8], [i64; 3], f64, f64),
) {
    let mut v = [0f64; 8];
    src.at(w.cell);
    for (k, x) in v.iter_mut().enumerate() {
        *x = f64::from(src.get(k));
    }
    n.reads += 8;
    let mut t = w.t0;
    loop {
        let axis = w.axis();
        let t_exit = w.t_next[axis].min(t1);
        if t_exit > t {
            n.cells += 1;
            visit(&v, w.cell, t, t_exit);
            t = t_exit;
        }
        if t_exit >= t1 {
            return;
        }
        if !w.advance(axis, q, d, lo, hi) {
            // Held at the range's edge: the same cell, the same corners.
            continue;
        }
        // The old far face on `axis` is the new near face (or the other way round).
        // Constant indices in each arm, so the 8 corners can stay in registers.
        src.at(w.cell);
        let mut get = |k: usize| f64::from(src.get(k));
        v = match (axis, w.step[axis] > 0) {
            (0, true) => [v[4], v[5], v[6], v[7], get(4), get(5), get(6), get(7)],
            (0, false) => [get(0), get(1), get(2), get(3), v[0], v[1], v[2], v[3]],
            (1, true) => [v[2], v[3], get(2), get(3), v[6], v[7], get(6), get(7)],
            (1, false) => [get(0), get(1), v[0], v[1], get(4), get(5), v[4], v[5]],
            (_, true) => [v[1], get(1), v[3], get(3), v[5], get(5), v[7], get(7)],
            (_, false) => [get(0), v[0], get(2), v[2], get(4), v[4], get(6), v[6]],
        };
        n.reads += 4;
    }
}

/// Exact integral of the trilinear field of dual cell `c` (corner values `v`, index
/// `x << 2 | y << 1 | z`) along `q + t d`, `t` in `[ta, tb]`, by 2-point Gauss-Legendre
/// (`du = d / sqrt 3`). Both Gauss points are evaluated side by side (two-lane arithmetic).
#[inline]
fn cubic_cell_integral(
    v: &[f64; 8],
    c: [i64; 3],
    q: [f64; 3],
    d: [f64; 3],
    du: [f64; 3],
    ta: f64,
    tb: f64,
) -> f64 {
    let m = 0.5 * (ta + tb);
    let h = 0.5 * (tb - ta);
    let u = [0, 1, 2].map(|a| {
        let um = q[a] + d[a] * m - c[a] as f64;
        [um - du[a] * h, um + du[a] * h]
    });
    let lerp = |a: [f64; 2], b: [f64; 2], w: [f64; 2]| {
        [a[0] + (b[0] - a[0]) * w[0], a[1] + (b[1] - a[1]) * w[1]]
    };
    // Along z the two corner values are the same for both points: one difference each.
    let zl = |a: f64, b: f64| {
        let dd = b - a;
        [a + dd * u[2][0], a + dd * u[2][1]]
    };
    let z0 = zl(v[0], v[1]);
    let z1 = zl(v[2], v[3]);
    let z2 = zl(v[4], v[5]);
    let z3 = zl(v[6], v[7]);
    let f = lerp(lerp(z0, z1, u[1]), lerp(z2, z3, u[1]), u[0]);
    let r = h * (f[0] + f[1]);
    if !r.is_finite() && v.iter().any(|x| x.is_infinite()) {
        // An opaque (+Inf) corner makes the field infinite wherever its weight is positive,
        // i.e. along any piece of positive length inside the cell: inf, not inf * 0 = NaN.
        f64::INFINITY
    } else {
        r
    }
}
