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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
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
    /// True if the walk met a node whose values a partial load did not read
    /// ([`crate::tree::Bounds::UNKNOWN`]); it stopped there, and its segments are incomplete.
    pub unloaded: bool,
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
    /// [`SPARSE_ROOT_FACTOR`], or another value in tests to force either root walk.
    sparse_factor: usize,
    /// Touch mode ([`touched_blocks`]): every block the walk visits at the requested
    /// granularity, as (origin, edge), instead of segments.
    touch: Option<&'v mut dyn FnMut([i64; 3], i64)>,
    unloaded: bool,
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

/// [`walk`], also telling the visitor which node of the requested granularity produced a
/// segment: a leaf (index into `Tree::leaves`) at [`Granularity::Leaf`], a lower node (into
/// `Tree::lowers`) at [`Granularity::Lower`], an upper node (into `Tree::uppers`) at
/// [`Granularity::Upper`]; `None` for tiles and empty root cells. Regular tracking reads a
/// leaf's voxels directly instead of descending the tree for every voxel; the object-order map
/// renderer (`bake/trace/sweep`) integrates lower nodes itself and walks rays only for the rest.
pub(crate) fn walk_nodes(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    gran: Granularity,
    visit: impl FnMut(Segment, Option<u32>) -> ControlFlow<()>,
) -> Walk {
    let length = ray.t_max() - ray.t_min();
    let mut w = Walker::new(vol, ray, interp, gran, visit, None);
    let stopped = w.run(ray).is_break();
    Walk {
        length,
        covered: w.covered,
        segments: w.segments,
        stopped: stopped && !w.unloaded,
        unloaded: w.unloaded,
    }
}

/// Every block a [`walk`] of `ray` visits at granularity `gran`, as `(origin, edge)` in index
/// voxels: leaves and tiles (edge 8, 128 or 4096), empty root cells next to data, or whole
/// lower/upper nodes at the coarser granularities. The walk's path depends only on the
/// topology (root table, child masks, the value box), never on values, so this works on a tree
/// whose leaves are not loaded; every value a walk or a lookup along the ray reads, and every
/// bound it uses, lies in the closed box `[origin, origin + edge]` of a visited block (the
/// block's own voxels plus the one-voxel halo trilinear lookups and halo bounds read). That is
/// what a partial load reads ([`crate::vdb::LazyGrid`]).
pub(crate) fn touched_blocks(
    vol: &Volume,
    ray: &Ray,
    interp: Interp,
    gran: Granularity,
    mut touch: impl FnMut([i64; 3], i64),
) {
    let skip = |_: Segment, _: Option<u32>| ControlFlow::Continue(());
    let mut w = Walker::new(vol, ray, interp, gran, skip, Some(&mut touch));
    let _ = w.run(ray);
}

impl<'v, F: FnMut(Segment, Option<u32>) -> ControlFlow<()>> Walker<'v, F> {
    /// A walker of `ray` through `vol`, emitting segments to `visit`, or in touch mode
    /// reporting blocks to `touch`.
    fn new(
        vol: &'v Volume,
        ray: &Ray,
        interp: Interp,
        gran: Granularity,
        visit: F,
        touch: Option<&'v mut dyn FnMut([i64; 3], i64)>,
    ) -> Self {
        let (q, d) = lookup_ray(vol, ray, interp);
        Self {
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
            sparse_factor: SPARSE_ROOT_FACTOR,
            touch,
            unloaded: false,
        }
    }

    fn run(&mut self, ray: &Ray) -> ControlFlow<()> {
        let Some([lo, hi]) = self.vol.value_box() else {
            return ControlFlow::Continue(());
        };
        if self.vol.tree().shell && self.touch.is_none() {
            self.unloaded = true;
            return ControlFlow::Break(());
        }
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
        let vol = self.vol;
        let sparse_factor = self.sparse_factor;
        let mut root_cell = |c: [i64; 3], ta: f64, tb: f64| {
            let wide = c.map(|v| v * 4096);
            let Some(origin) = to_i32(wide) else {
                // Below the i32 range: background, but trilinear lookups there read the
                // range's first voxels.
                return self.tile(self.bg, None, wide, 4096, 3, ta, tb);
            };
            match self.vol.tree().root_find(origin) {
                None => self.tile(self.bg, None, wide, 4096, 3, ta, tb),
                Some(r) => match self.vol.tree().root[r].slot {
                    RootSlot::Tile { value, .. } => self.tile(value, None, wide, 4096, 3, ta, tb),
                    RootSlot::Child(u) => self.upper(u, ta, tb),
                },
            }
        };
        // Root cells the ray crosses, against the root entries there are: a ray through a
        // sparse grid (two leaves at opposite corners of the index range) crosses millions
        // of empty root cells, so it walks only the spans near entries instead.
        let crossed: f64 = d.iter().map(|c| c.abs()).sum::<f64>() * (t1 - t0) / 4096.0;
        let entries = vol.tree().root.len();
        if crossed <= sparse_factor.saturating_mul(entries + 1) as f64 {
            return dda(q, d, (t0, t1), &cells, root_cell);
        }
        let mut spans = ROOT_SPANS.with(std::cell::Cell::take);
        root_spans(vol, q, d, grow_lo, (t0, t1), &mut spans);
        let mut flow = ControlFlow::Continue(());
        for &(a, b) in &spans {
            flow = dda(q, d, (a, b), &cells, &mut root_cell);
            if flow.is_break() {
                break;
            }
        }
        ROOT_SPANS.with(|c| c.set(spans));
        flow
    }

    fn upper(&mut self, u: u32, t0: f64, t1: f64) -> ControlFlow<()> {
        let tree = &self.vol.tree();
        let node = &tree.uppers[u as usize];
        if self.gran == Granularity::Upper {
            return self.node_segment(self.pick(node.bounds, node.halo), 3, Some(u), t0, t1);
        }
        self.internal(node, 4096, 128, t0, t1, |w, child, ta, tb| {
            w.lower(child, ta, tb)
        })
    }

    fn lower(&mut self, l: u32, t0: f64, t1: f64) -> ControlFlow<()> {
        let node = &self.vol.tree().lowers[l as usize];
        if self.gran == Granularity::Lower {
            return self.node_segment(self.pick(node.bounds, node.halo), 2, Some(l), t0, t1);
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
                let origin = c.map(|v| v * child_dim);
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
        if let Some(touch) = self.touch.as_mut() {
            let tree = self.vol.tree();
            let i = leaf.unwrap_or(0) as usize;
            let (origin, dim) = match level {
                1 => (tree.leaves[i].origin, 8),
                2 => (tree.lowers[i].origin, 128),
                _ => (tree.uppers[i].origin, 4096),
            };
            touch(origin.map(i64::from), dim);
            return ControlFlow::Continue(());
        }
        if b.is_unknown() {
            self.unloaded = true;
            return ControlFlow::Break(());
        }
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
        origin: [i64; 3],
        dim: i64,
        level: u8,
        t0: f64,
        t1: f64,
    ) -> ControlFlow<()> {
        if let Some(touch) = self.touch.as_mut() {
            touch(origin, dim);
            return ControlFlow::Continue(());
        }
        if self.interp == Interp::Nearest {
            if v == self.bg {
                return ControlFlow::Continue(());
            }
            let v = f64::from(v);
            return self.segment(v, v, level, t0, t1);
        }
        let h = halo.unwrap_or_else(|| self.vol.tree().halo_bounds(origin, dim));
        if h.is_unknown() {
            self.unloaded = true;
            return ControlFlow::Break(());
        }
        if h.min == h.max {
            if h.min == self.bg {
                return ControlFlow::Continue(());
            }
            let c = f64::from(h.min);
            return self.segment(c, c, level, t0, t1);
        }
        // Split off the inner box where every trilinear lookup reads only this tile.
        let inner_lo = origin.map(|c| c as f64);
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

/// A ray that crosses more than this many root cells per root entry walks only the spans near
/// entries ([`root_spans`]); below it the plain root DDA is cheaper than sorting spans.
const SPARSE_ROOT_FACTOR: usize = 4;

thread_local! {
    /// Reused span list of the sparse root walk (taken, filled, put back: no allocation per ray
    /// once warm, and a nested walk on the same thread just gets a fresh list).
    static ROOT_SPANS: std::cell::Cell<Vec<(f64, f64)>> = const { std::cell::Cell::new(Vec::new()) };
}

/// The parts of `[t0, t1]` where a lookup can read anything but the background: for each root
/// entry at origin `o`, the lookup-space box `[o - 4096 g, o + 4096]` (`g = 1` for trilinear,
/// whose lookups in a root cell read the first voxel of the next cell on each axis), sorted and
/// merged. Between the spans every root cell is empty with an empty halo, so skipping them
/// changes no segment: cost `O(E log E)` for `E` root entries instead of one step per crossed
/// cell (`2^20` per axis for a grid spanning the `i32` index range).
fn root_spans(
    vol: &Volume,
    q: [f64; 3],
    d: [f64; 3],
    grow_lo: i64,
    (t0, t1): (f64, f64),
    spans: &mut Vec<(f64, f64)>,
) {
    spans.clear();
    for e in &vol.tree().root {
        let o = e.origin.map(f64::from);
        let lo = o.map(|c| c - (4096 * grow_lo) as f64);
        let hi = o.map(|c| c + 4096.0);
        if let Some((a, b)) = clip_box(q, d, lo, hi) {
            let (a, b) = (a.max(t0), b.min(t1));
            if a < b {
                spans.push((a, b));
            }
        }
    }
    spans.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut merged = 0;
    for i in 0..spans.len() {
        if merged > 0 && spans[i].0 <= spans[merged - 1].1 {
            spans[merged - 1].1 = spans[merged - 1].1.max(spans[i].1);
        } else {
            spans[merged] = spans[i];
            merged += 1;
        }
    }
    spans.truncate(merged);
}

fn to_i32(c: [i64; 3]) -> Option<[i32; 3]> {
    Some([
        i32::try_from(c[0]).ok()?,
        i32::try_from(c[1]).ok()?,
        i32::try_from(c[2]).ok()?,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    /// Segments of one walk with the root walk forced sparse (`factor` 0) or dense.
    fn segments(vol: &Volume, ray: &Ray, interp: Interp, factor: usize) -> Vec<Segment> {
        let mut out = Vec::new();
        let visit = |s: Segment, _| {
            out.push(s);
            ControlFlow::Continue(())
        };
        let mut w = Walker::new(vol, ray, interp, Granularity::Leaf, visit, None);
        w.sparse_factor = factor;
        let _ = w.run(ray);
        out
    }

    /// `(integral of mu_maj, integral of mu_min, covered length)` over the segments.
    fn integrals(s: &[Segment]) -> [f64; 3] {
        s.iter().fold([0.0; 3], |a, s| {
            let l = s.t_max - s.t_min;
            [a[0] + l * s.mu_maj, a[1] + l * s.mu_min, a[2] + l]
        })
    }

    #[test]
    fn sparse_root_walk_emits_what_the_dense_walk_emits() {
        let mut b = TreeBuilder::new(0.0);
        for (i, o) in [
            [0, 0, 0],
            [3 * 4096 + 5, 50, 8],
            [-8192, -4096, 100],
            [4095, 4095, 4095],
            [-1, 4096, -4097],
        ]
        .into_iter()
        .enumerate()
        {
            for k in 0..40 {
                b.set(
                    [o[0] + k % 7, o[1] + k % 5, o[2] + k % 3],
                    0.5 + i as f32 + k as f32,
                );
            }
        }
        b.tile([2 * 4096, -3 * 4096, 0], 12, 0.25);
        let m = [
            [0.01, 0.0, 0.0, 0.0],
            [0.0, 0.01, 0.0, 0.0],
            [0.0, 0.0, 0.01, 0.0],
        ];
        let vol = Volume::from_tree("t".into(), b.build(), m, 1.0).expect("volume");
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut compared = 0;
        for _ in 0..300 {
            let o = [0; 3].map(|_| (next() - 0.5) * 400.0);
            let target = [0; 3].map(|_| (next() - 0.5) * 200.0);
            let dir = glam::DVec3::from(target) - glam::DVec3::from(o);
            let Ok(ray) = Ray::new(o, dir.to_array(), 0.0, 1e3) else {
                continue;
            };
            for interp in [Interp::Nearest, Interp::Trilinear] {
                let dense = integrals(&segments(&vol, &ray, interp, usize::MAX));
                let sparse = integrals(&segments(&vol, &ray, interp, 0));
                for (x, y) in dense.iter().zip(&sparse) {
                    assert!(
                        (x - y).abs() <= 1e-9 * (1.0 + x.abs()),
                        "{dense:?} vs {sparse:?}"
                    );
                }
                compared += usize::from(dense[2] > 0.0);
            }
        }
        assert!(compared > 50, "only {compared} rays crossed data");
    }

    #[test]
    fn far_apart_leaves_are_walked_through_their_spans_only() {
        let mut b = TreeBuilder::new(0.0);
        let lo = i32::MIN;
        let hi = i32::MAX - 7;
        for k in 0..8 {
            b.set([lo + k, lo + k, lo + k], 1.0);
            b.set([hi + k, hi + k, hi + k], 1.0);
        }
        let m = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let vol = Volume::from_tree("t".into(), b.build(), m, 1.0).expect("volume");
        let from = glam::DVec3::splat(f64::from(lo) - 3.0);
        let to = glam::DVec3::splat(f64::from(hi) + 11.0);
        let ray = Ray::new(
            from.to_array(),
            (to - from).to_array(),
            0.0,
            (to - from).length(),
        )
        .expect("ray");
        let mut cells = 0u64;
        let (q, d) = lookup_ray(&vol, &ray, Interp::Trilinear);
        let clip = clip_box(q, d, [f64::from(lo) - 1.0; 3], [f64::from(hi) + 8.0; 3]);
        let (t0, t1) = clip.expect("ray crosses the box");
        let mut spans = Vec::new();
        root_spans(&vol, q, d, 1, (t0, t1), &mut spans);
        for &(a, b) in &spans {
            let cells_box = Cells {
                size: 4096.0,
                lo: [-(1 << 19) - 1; 3],
                hi: [1 << 19; 3],
            };
            let _ = dda(q, d, (a, b), &cells_box, |_, _, _| {
                cells += 1;
                ControlFlow::Continue(())
            });
        }
        assert_eq!(spans.len(), 2, "{spans:?}");
        assert!(cells <= 16, "{cells} root cells walked");
        // Each diagonal leaf holds 8 voxels of 1 along the ray: tau = 8 sqrt(3) per corner
        // (trilinear reaches half a voxel beyond, nearest exactly the voxels).
        let tau = crate::regular::optical_depth(&vol, &ray, Interp::Nearest)
            .expect("tau")
            .tau;
        assert!((tau - 16.0 * 3f64.sqrt()).abs() < 1e-6, "{tau}");
    }
}
