//! The hierarchical DDA. A ray is mapped to index space, shifted into *lookup space* (where the
//! cell a lookup reads is `floor(q)`: `q = p + 0.5` for nearest, `q = p` for trilinear), clipped
//! to the box outside which the density is the background, then walked at the root (4096^3
//! cells), through upper nodes (128^3 cells) and lower nodes (8^3 cells), down to the requested
//! granularity. Tiles and empty regions are never visited at a finer level than their own.
//!
//! Trilinear lookups in a tile's cells read one voxel beyond its + faces, so a tile whose halo is
//! not constant is split: the inner box `[o, o + dim - 1)` where every lookup returns the tile
//! value (a constant segment), and the boundary pieces before and after it, bounded by the tile's
//! halo. The same holds for background tiles and empty root cells next to data, which is why a
//! trilinear walk reaches one voxel beyond the active data where vdb_render stops.

use super::{dda, Cells, Segment};
use crate::math::{floor_i64, non_empty, scaled};
use crate::ray::{clip_box, Ray};
use crate::tree::{Bounds, Internal, RootSlot};
use crate::volume::{Interp, Volume};
use std::ops::ControlFlow;

/// Finest node level at which segments are emitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Granularity {
    /// One segment per leaf (8^3) or tile: tightest majorants, most segments.
    Leaf,
    /// One segment per lower node (128^3) or tile.
    Lower,
    /// One segment per upper node (4096^3) or tile: loosest majorants, fewest segments.
    Upper,
}

/// The result of a walk: the ray range considered and how much of it the segments covered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Walk {
    /// Total ray length considered, `t_max - t_min` (may be infinite).
    pub length: f64,
    /// Sum of the emitted segments' lengths; the rest of `length` has the background density.
    pub covered: f64,
    /// Number of segments emitted.
    pub segments: u64,
    /// True if the visitor stopped the walk early.
    pub stopped: bool,
}

struct Walker<'v, F> {
    vol: &'v Volume,
    interp: Interp,
    gran: Granularity,
    q: [f64; 3],
    d: [f64; 3],
    scale: f64,
    bg: f32,
    visit: F,
    covered: f64,
    segments: u64,
}

/// Walk `ray` through `vol`, calling `visit` for every segment where the density can differ
/// from the background, in ray order. Segments never overlap; gaps between them have the
/// background density (`Volume::mu_background`).
pub fn walk(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    gran: Granularity,
    mut visit: impl FnMut(Segment) -> ControlFlow<()>,
) -> Walk {
    walk_nodes(vol, ray, interp, gran, |s, _| visit(s))
}

/// [`walk`], also telling the visitor which leaf (index into `Tree::leaves`) produced a segment
/// (`None` for tiles, empty root cells and coarser nodes), so that regular tracking can read the
/// leaf's voxels directly instead of descending the tree for every voxel.
pub(crate) fn walk_nodes(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    gran: Granularity,
    visit: impl FnMut(Segment, Option<u32>) -> ControlFlow<()>,
) -> Walk {
    let length = ray.t_max() - ray.t_min();
    let (q, d) = lookup_ray(vol, ray, interp);
    let mut w = Walker {
        vol,
        interp,
        gran,
        q,
        d,
        scale: vol.density_scale(),
        bg: vol.tree().background,
        visit,
        covered: 0.0,
        segments: 0,
    };
    let stopped = w.run(ray).is_break();
    Walk {
        length,
        covered: w.covered,
        segments: w.segments,
        stopped,
    }
}

impl<F: FnMut(Segment, Option<u32>) -> ControlFlow<()>> Walker<'_, F> {
    fn run(&mut self, ray: &Ray) -> ControlFlow<()> {
        let Some([lo, hi]) = self.vol.value_box() else {
            return ControlFlow::Continue(());
        };
        // Lookup cells whose reads can touch the value box.
        let grow_lo = match self.interp {
            Interp::Nearest => 0,
            Interp::Trilinear => 1,
        };
        let clip_lo = lo.map(|c| (c - grow_lo) as f64);
        let clip_hi = hi.map(|c| (c + 1) as f64);
        let Some((a, b)) = clip_box(self.q, self.d, clip_lo, clip_hi) else {
            return ControlFlow::Continue(());
        };
        let (t0, t1) = (a.max(ray.t_min()), b.min(ray.t_max()));
        if !non_empty(t0, t1) {
            return ControlFlow::Continue(());
        }
        let cell = |c: f64| floor_i64(c / 4096.0);
        let rlo = clip_lo.map(cell);
        let rhi = clip_hi.map(|c| cell(c - 0.5));
        let (q, d) = (self.q, self.d);
        let cells = Cells {
            size: 4096.0,
            lo: rlo,
            hi: rhi,
        };
        dda(q, d, (t0, t1), &cells, |c, ta, tb| {
            let Some(origin) = to_i32(c.map(|v| v * 4096)) else {
                return ControlFlow::Continue(());
            };
            match self.vol.tree().root_find(origin) {
                None => self.tile(self.bg, None, origin, 4096, 3, ta, tb),
                Some(r) => match self.vol.tree().root[r].slot {
                    RootSlot::Tile { value, .. } => self.tile(value, None, origin, 4096, 3, ta, tb),
                    RootSlot::Child(u) => self.upper(u, ta, tb),
                },
            }
        })
    }

    fn upper(&mut self, u: u32, t0: f64, t1: f64) -> ControlFlow<()> {
        let tree = &self.vol.tree();
        let node = &tree.uppers[u as usize];
        if self.gran == Granularity::Upper {
            return self.node_segment(self.pick(node.bounds, node.halo), 3, None, t0, t1);
        }
        self.internal(node, 4096, 128, t0, t1, |w, child, ta, tb| {
            w.lower(child, ta, tb)
        })
    }

    fn lower(&mut self, l: u32, t0: f64, t1: f64) -> ControlFlow<()> {
        let node = &self.vol.tree().lowers[l as usize];
        if self.gran == Granularity::Lower {
            return self.node_segment(self.pick(node.bounds, node.halo), 2, None, t0, t1);
        }
        self.internal(node, 128, 8, t0, t1, |w, l, ta, tb| {
            let leaf = &w.vol.tree().leaves[l as usize];
            w.node_segment(w.pick(leaf.bounds, leaf.halo), 1, Some(l), ta, tb)
        })
    }

    fn internal(
        &mut self,
        node: &Internal,
        dim: i64,
        child_dim: i64,
        t0: f64,
        t1: f64,
        mut child: impl FnMut(&mut Self, u32, f64, f64) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        let o = node.origin.map(i64::from);
        let lo = o.map(|c| c.div_euclid(child_dim));
        let hi = lo.map(|c| c + dim / child_dim - 1);
        let side = (dim / child_dim) as usize;
        let level = if child_dim == 8 { 1 } else { 2 };
        let (q, d) = (self.q, self.d);
        let cells = Cells {
            size: child_dim as f64,
            lo,
            hi,
        };
        dda(q, d, (t0, t1), &cells, |c, ta, tb| {
            let l = [0, 1, 2].map(|a| (c[a] - lo[a]) as usize);
            let slot = (l[0] * side + l[1]) * side + l[2];
            if node.has_child(slot) {
                child(self, node.slots[slot], ta, tb)
            } else {
                let origin = c.map(|v| (v * child_dim) as i32);
                let halo = Some(node.tile_halo_of(slot));
                self.tile(
                    node.tile_value(slot),
                    halo,
                    origin,
                    child_dim,
                    level,
                    ta,
                    tb,
                )
            }
        })
    }

    fn pick(&self, nearest: Bounds, trilinear: Bounds) -> Bounds {
        match self.interp {
            Interp::Nearest => nearest,
            Interp::Trilinear => trilinear,
        }
    }

    fn node_segment(
        &mut self,
        b: Bounds,
        level: u8,
        leaf: Option<u32>,
        t0: f64,
        t1: f64,
    ) -> ControlFlow<()> {
        if b.min == self.bg && b.max == self.bg {
            return ControlFlow::Continue(());
        }
        self.emit(f64::from(b.min), f64::from(b.max), level, leaf, t0, t1)
    }

    /// A constant region of value `v` (tile, background tile or empty root cell).
    #[allow(clippy::too_many_arguments)]
    fn tile(
        &mut self,
        v: f32,
        halo: Option<Bounds>,
        origin: [i32; 3],
        dim: i64,
        level: u8,
        t0: f64,
        t1: f64,
    ) -> ControlFlow<()> {
        if self.interp == Interp::Nearest {
            if v == self.bg {
                return ControlFlow::Continue(());
            }
            let v = f64::from(v);
            return self.segment(v, v, level, t0, t1);
        }
        let h = halo.unwrap_or_else(|| self.vol.tree().halo_bounds(origin, dim));
        if h.min == h.max {
            if h.min == self.bg {
                return ControlFlow::Continue(());
            }
            let c = f64::from(h.min);
            return self.segment(c, c, level, t0, t1);
        }
        // Split off the inner box where every trilinear lookup reads only this tile.
        let inner_lo = origin.map(f64::from);
        let inner_hi = inner_lo.map(|c| c + (dim - 1) as f64);
        let (hmin, hmax) = (f64::from(h.min), f64::from(h.max));
        match clip_box(self.q, self.d, inner_lo, inner_hi) {
            Some((a, b)) if a.max(t0) < b.min(t1) => {
                let (a, b) = (a.max(t0), b.min(t1));
                self.segment(hmin, hmax, level, t0, a)?;
                if v != self.bg {
                    let c = f64::from(v);
                    self.segment(c, c, level, a, b)?;
                }
                self.segment(hmin, hmax, level, b, t1)
            }
            _ => self.segment(hmin, hmax, level, t0, t1),
        }
    }

    fn segment(&mut self, min: f64, max: f64, level: u8, t0: f64, t1: f64) -> ControlFlow<()> {
        self.emit(min, max, level, None, t0, t1)
    }

    fn emit(
        &mut self,
        min: f64,
        max: f64,
        level: u8,
        leaf: Option<u32>,
        t0: f64,
        t1: f64,
    ) -> ControlFlow<()> {
        if !non_empty(t0, t1) {
            return ControlFlow::Continue(());
        }
        self.covered += t1 - t0;
        self.segments += 1;
        (self.visit)(
            Segment {
                t_min: t0,
                t_max: t1,
                mu_min: scaled(self.scale, min),
                mu_maj: scaled(self.scale, max),
                level,
            },
            leaf,
        )
    }
}

/// The ray in lookup space, where the cell a lookup reads is `floor(q)`. For nearest lookups
/// on an axis the ray does not move along, the coordinate is snapped to the centre of the cell
/// OpenVDB's `::round` (ties away from zero) picks, so a ray lying exactly on a tie plane reads
/// the same voxels as `PointSampler`.
#[must_use]
pub fn lookup_ray(vol: &Volume, ray: &Ray, interp: Interp) -> ([f64; 3], [f64; 3]) {
    let p = vol.to_index(ray.origin()).to_array();
    let d = vol.to_index_dir(ray.direction()).to_array();
    let q = [0, 1, 2].map(|a| match interp {
        Interp::Nearest if d[a] == 0.0 => p[a].round() + 0.5,
        _ => p[a] + interp.shift(),
    });
    (q, d)
}

fn to_i32(c: [i64; 3]) -> Option<[i32; 3]> {
    Some([
        i32::try_from(c[0]).ok()?,
        i32::try_from(c[1]).ok()?,
        i32::try_from(c[2]).ok()?,
    ])
}
