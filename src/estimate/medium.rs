//! The extinction along one ray, as the estimators query it: `mu(t)` at world distance `t`,
//! with the lookup count that is the estimators' deterministic cost measure.

use crate::math::scaled;
use crate::ray::Ray;
use crate::regular::integrate_cells;
use crate::traverse::{dda, lookup_ray, Cells, Segment};
use crate::tree::Accessor;
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

/// What the estimators ask of the medium along one ray: the extinction at a world distance,
/// its exact integral, and the lookup scale. [`RayMedium`] is one grid; a scene's medium
/// ([`crate::scene`]) sums several, per colour channel.
pub trait Extinction {
    /// Extinction `mu_t(t)` at world distance `t` along the ray (one lookup per grid).
    fn mu(&mut self, t: f64) -> f64;
    /// Exact optical depth `integral of mu_t over [t0, t1]`.
    fn exact(&mut self, t0: f64, t1: f64) -> f64;
    /// Index-space length of one world unit along the ray (the finest grid's, for a scene):
    /// converts marching steps given in voxels to world units.
    fn voxels_per_world_unit(&self) -> f64;
    /// The ray in lookup space, `(q, d)` with the point `q + d t` at world distance `t`, when
    /// ray marching cuts its spans into the chords of the `8^3` blocks of that space
    /// (`block_chords`: the blocks a map's object-order sweep visits, so a march takes the
    /// same points ray by ray or block by block). `None` (a scene's several grids): spans are
    /// marched whole.
    fn lattice(&self) -> Option<([f64; 3], [f64; 3])> {
        None
    }
}

impl Extinction for RayMedium<'_> {
    #[inline]
    fn mu(&mut self, t: f64) -> f64 {
        RayMedium::mu(self, t)
    }
    fn exact(&mut self, t0: f64, t1: f64) -> f64 {
        RayMedium::exact(self, t0, t1)
    }
    fn voxels_per_world_unit(&self) -> f64 {
        RayMedium::voxels_per_world_unit(self)
    }
    fn lattice(&self) -> Option<([f64; 3], [f64; 3])> {
        Some((self.q, self.d))
    }
}

/// Side of the blocks marching restarts its pieces in (lookup-space cells).
pub(crate) const BLOCK_SIDE: f64 = 8.0;

/// The chords of `[t0, t1]` in the `8^3` blocks of lookup space along the line `q + d t`:
/// `f(a, b)` for each, in order, cut where the line crosses a plane `x_k = 8 m`. The cut `t`
/// of a plane is `(8 m - q_k) / d_k`, whichever block is asked: neighbouring chords share it.
pub(crate) fn block_chords(
    q: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    f: &mut dyn FnMut(f64, f64),
) {
    if t1.partial_cmp(&t0) != Some(std::cmp::Ordering::Greater) {
        return;
    }
    // Per axis: the next plane's index (in units of the block side), its step and its `t`.
    let mut plane = [0.0f64; 3];
    let mut step = [0.0f64; 3];
    let mut next = [f64::INFINITY; 3];
    for k in 0..3 {
        if d[k] == 0.0 || !d[k].is_finite() {
            continue;
        }
        let x = (q[k] + d[k] * t0) / BLOCK_SIDE;
        (plane[k], step[k]) = if d[k] > 0.0 {
            (x.floor() + 1.0, 1.0)
        } else {
            (x.ceil() - 1.0, -1.0)
        };
        next[k] = (plane[k] * BLOCK_SIDE - q[k]) / d[k];
    }
    let mut a = t0;
    loop {
        let k = if next[0] <= next[1] && next[0] <= next[2] {
            0
        } else if next[1] <= next[2] {
            1
        } else {
            2
        };
        let cut = next[k];
        if cut.partial_cmp(&t1) != Some(std::cmp::Ordering::Less) {
            f(a, t1);
            return;
        }
        if cut > a {
            f(a, cut);
            a = cut;
        }
        plane[k] += step[k];
        next[k] = (plane[k] * BLOCK_SIDE - q[k]) / d[k];
    }
}

/// Extinction along a ray with a cached accessor and a lookup counter.
#[derive(Debug, Clone)]
pub struct RayMedium<'v> {
    acc: Accessor<'v>,
    /// Lookup-space origin (index space plus the interpolation's shift).
    q: [f64; 3],
    /// Index-space direction per world unit.
    d: [f64; 3],
    interp: Interp,
    scale: f64,
    lookups: u64,
}

impl<'v> RayMedium<'v> {
    /// The medium of `vol` along `ray`.
    #[must_use]
    pub fn new(vol: &'v Volume, ray: &Ray, interp: Interp) -> Self {
        let (q, d) = lookup_ray(vol, ray, interp);
        Self {
            acc: Accessor::new(vol.tree()),
            q,
            d,
            interp,
            scale: vol.density_scale(),
            lookups: 0,
        }
    }

    /// Extinction `mu_t = scale * value` at world distance `t` (one lookup).
    #[inline]
    pub fn mu(&mut self, t: f64) -> f64 {
        self.lookups += 1;
        let p = [0, 1, 2].map(|a| self.q[a] + self.d[a] * t);
        let v = match self.interp {
            // In lookup space the nearest voxel is floor(q).
            Interp::Nearest => self.acc.value_at(p.map(crate::math::floor_i64)),
            Interp::Trilinear => self.acc.trilinear(p),
        };
        scaled(self.scale, f64::from(v))
    }

    /// Exact optical depth over `[t0, t1]` by regular tracking (counts one lookup per cell).
    pub fn exact(&mut self, t0: f64, t1: f64) -> f64 {
        let mut cells = 0;
        let v = integrate_cells(
            &mut self.acc,
            self.q,
            self.d,
            t0,
            t1,
            self.interp,
            &mut cells,
        );
        self.lookups += cells;
        scaled(self.scale, v)
    }

    /// Split `s` into one segment per lookup cell it crosses, each with the exact bounds of
    /// that cell: the voxel value (nearest; constant) or the min/max of its 8 corners
    /// (trilinear). Used where a node's bounds are too loose to sample efficiently.
    pub fn refine(&mut self, s: &Segment, out: &mut Vec<Segment>) {
        let p0 = [0, 1, 2].map(|a| self.q[a] + self.d[a] * s.t_min);
        let p1 = [0, 1, 2].map(|a| self.q[a] + self.d[a] * s.t_max);
        let lo = [0, 1, 2].map(|a| p0[a].min(p1[a]).floor() as i64);
        let hi = [0, 1, 2].map(|a| p0[a].max(p1[a]).floor() as i64);
        let grid = Cells { size: 1.0, lo, hi };
        let (q, d, interp, scale) = (self.q, self.d, self.interp, self.scale);
        let acc = &mut self.acc;
        let mut reads = 0;
        let _ = dda(q, d, (s.t_min, s.t_max), &grid, |c, ta, tb| {
            let (mut mn, mut mx) = (f32::INFINITY, f32::NEG_INFINITY);
            let corners = if interp == Interp::Nearest { 1 } else { 8 };
            for n in 0..corners {
                let o = [(n >> 2) & 1, (n >> 1) & 1, n & 1].map(i64::from);
                let v = acc.value_at([c[0] + o[0], c[1] + o[1], c[2] + o[2]]);
                mn = mn.min(v);
                mx = mx.max(v);
            }
            reads += 1;
            let k = |v: f32| scaled(scale, f64::from(v));
            out.push(Segment {
                t_min: ta,
                t_max: tb,
                mu_min: k(mn),
                mu_maj: k(mx),
                level: 0,
            });
            ControlFlow::Continue(())
        });
        self.lookups += reads;
    }

    /// Index-space length of one world unit along the ray (to convert voxel steps).
    #[must_use]
    pub fn voxels_per_world_unit(&self) -> f64 {
        self.d.iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    /// Density evaluations so far.
    #[must_use]
    pub fn lookups(&self) -> u64 {
        self.lookups
    }
}
