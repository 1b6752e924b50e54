//! Value bounds per node: the min and max of every value a lookup inside the node can return.
//!
//! Regions: for nearest lookups a node of edge `dim` at origin `o` owns the points whose voxel
//! `floor(p + 0.5)` lies in `[o, o + dim)`; it reads only its own voxels and tiles (`bounds`).
//! For trilinear lookups it owns the points with `floor(p)` in `[o, o + dim)` (the cells between
//! voxel centres, the dual grid), and a lookup there reads voxels `floor(p) + {0, 1}`: the node's
//! voxels plus a one-voxel halo on its + faces, `[o, o + dim]` (`halo`), inactive values and
//! background included. Internal nodes also keep the halo bound of every tile slot. These are the
//! majorants and minorants the traversal hands to the estimators.

use super::{Internal, Leaf, RootSlot, Tree};
use rayon::prelude::*;

/// A closed interval `[min, max]` of values; empty when `min > max`. NaN values are ignored
/// (they never raise a majorant; see the NaN policy in the README).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    /// Smallest value (minorant).
    pub min: f32,
    /// Largest value (majorant).
    pub max: f32,
}

impl Default for Bounds {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Bounds {
    /// The empty interval.
    pub const EMPTY: Self = Self {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
    };

    /// The interval holding exactly `v`.
    #[must_use]
    pub fn point(v: f32) -> Self {
        let mut b = Self::EMPTY;
        b.include(v);
        b
    }

    /// Grow to include `v` (NaN is ignored).
    #[inline]
    pub fn include(&mut self, v: f32) {
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    /// Grow to include another interval.
    #[inline]
    pub fn union(&mut self, o: Self) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }

    /// True if no value was included.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.min > self.max
    }
}

/// An inclusive box of voxels in i64 (so `origin - 1` never overflows).
#[derive(Debug, Clone, Copy)]
struct VoxelBox {
    lo: [i64; 3],
    hi: [i64; 3],
}

impl VoxelBox {
    /// The voxels a node's own values occupy: `[o, o + dim - 1]`.
    fn own(origin: [i32; 3], dim: i64) -> Self {
        let o = origin.map(i64::from);
        Self {
            lo: o,
            hi: o.map(|v| v + dim - 1),
        }
    }
    /// The voxels trilinear lookups in the node's dual-grid region read: `[o, o + dim]`.
    fn trilinear(origin: [i32; 3], dim: i64) -> Self {
        let o = origin.map(i64::from);
        Self {
            lo: o,
            hi: o.map(|v| v + dim),
        }
    }
    /// Range of child slots (each `child_dim` wide) of a node at `origin` that the box touches,
    /// or None if it touches none.
    fn slot_range(&self, origin: [i32; 3], dim: i64, child_dim: i64) -> Option<[(i64, i64); 3]> {
        let mut r = [(0, 0); 3];
        for a in 0..3 {
            let o = i64::from(origin[a]);
            let lo = self.lo[a].max(o);
            let hi = self.hi[a].min(o + dim - 1);
            if lo > hi {
                return None;
            }
            r[a] = ((lo - o) / child_dim, (hi - o) / child_dim);
        }
        Some(r)
    }
    fn contains_node(&self, origin: [i32; 3], dim: i64) -> bool {
        (0..3).all(|a| {
            let o = i64::from(origin[a]);
            self.lo[a] <= o && o + dim - 1 <= self.hi[a]
        })
    }
}

impl Tree {
    /// Compute every node's nearest bounds, then every node's halo bounds. Called once at load.
    pub(crate) fn compute_bounds(&mut self) {
        for leaf in &mut self.leaves {
            leaf.bounds = leaf.values.iter().fold(Bounds::EMPTY, |mut b, &v| {
                b.include(v);
                b
            });
        }
        let leaf_bounds: Vec<Bounds> = self.leaves.iter().map(|l| l.bounds).collect();
        internal_bounds(&mut self.lowers, &leaf_bounds);
        let lower_bounds: Vec<Bounds> = self.lowers.iter().map(|n| n.bounds).collect();
        internal_bounds(&mut self.uppers, &lower_bounds);
        let mut all = Bounds::point(self.background);
        for e in &self.root {
            match e.slot {
                RootSlot::Tile { value, .. } => all.include(value),
                RootSlot::Child(u) => all.union(self.uppers[u as usize].bounds),
            }
        }
        self.bounds = all;

        // Halos read neighbours' nearest bounds, so they come second.
        let halos: Vec<Bounds> = self
            .leaves
            .par_iter()
            .map(|l| self.box_bounds(VoxelBox::trilinear(l.origin, 8)))
            .collect();
        self.leaves
            .iter_mut()
            .zip(halos)
            .for_each(|(l, h)| l.halo = h);
        let halos: Vec<_> = self
            .lowers
            .par_iter()
            .map(|n| self.internal_halos(n, 128, 8))
            .collect();
        for (n, (h, t)) in self.lowers.iter_mut().zip(halos) {
            n.halo = h;
            n.tile_halo = t;
        }
        let halos: Vec<_> = self
            .uppers
            .par_iter()
            .map(|n| self.internal_halos(n, 4096, 128))
            .collect();
        for (n, (h, t)) in self.uppers.iter_mut().zip(halos) {
            n.halo = h;
            n.tile_halo = t;
        }
    }

    /// A node's halo bound and the halo bound of each of its tile slots (children get EMPTY).
    fn internal_halos(&self, n: &Internal, dim: i64, child_dim: i64) -> (Bounds, Box<[Bounds]>) {
        let side = dim / child_dim;
        let tiles = (0..n.slots.len())
            .into_par_iter()
            .with_min_len(512)
            .map(|s| {
                if n.has_child(s) {
                    return Bounds::EMPTY;
                }
                let s = s as i64;
                let local = [s / (side * side), (s / side) % side, s % side];
                let o = [0, 1, 2].map(|a| n.origin[a] + (local[a] * child_dim) as i32);
                let bx = VoxelBox::trilinear(o, child_dim);
                // Slots off the node's + faces read only this node: skip the root search.
                if local.iter().all(|&l| l + 1 < side) {
                    if dim == 4096 {
                        self.upper_box(n, bx)
                    } else {
                        self.lower_box(n, bx)
                    }
                } else {
                    self.box_bounds(bx)
                }
            })
            .collect::<Vec<_>>()
            .into_boxed_slice();
        (self.box_bounds(VoxelBox::trilinear(n.origin, dim)), tiles)
    }

    /// Bounds of the values a trilinear lookup can read in the dual-grid region of the `dim`^3
    /// block at `origin` (a tile, node, voxel, or empty root cell): voxels `[o, o + dim]`.
    #[must_use]
    pub fn halo_bounds(&self, origin: [i32; 3], dim: i64) -> Bounds {
        self.box_bounds(VoxelBox::trilinear(origin, dim))
    }

    /// Bounds of the values of the `dim`^3 block at `origin`, without halo.
    #[must_use]
    pub fn region_bounds(&self, origin: [i32; 3], dim: i64) -> Bounds {
        self.box_bounds(VoxelBox::own(origin, dim))
    }

    /// min/max over every voxel value in the box, background included where the box leaves
    /// the root's entries.
    fn box_bounds(&self, bx: VoxelBox) -> Bounds {
        let mut b = Bounds::EMPTY;
        let cells: i64 = (0..3)
            .map(|a| bx.hi[a].div_euclid(4096) - bx.lo[a].div_euclid(4096) + 1)
            .product();
        let mut hit = 0i64;
        for e in &self.root {
            if bx.slot_range(e.origin, 4096, 4096).is_none() {
                continue;
            }
            hit += 1;
            match e.slot {
                RootSlot::Tile { value, .. } => b.include(value),
                RootSlot::Child(u) => b.union(self.upper_box(&self.uppers[u as usize], bx)),
            }
        }
        if hit < cells {
            b.include(self.background);
        }
        b
    }

    fn upper_box(&self, node: &Internal, bx: VoxelBox) -> Bounds {
        self.internal_box(node, 4096, 128, bx, &|c, bx| {
            self.lower_box(&self.lowers[c as usize], bx)
        })
    }

    fn lower_box(&self, node: &Internal, bx: VoxelBox) -> Bounds {
        self.internal_box(node, 128, 8, bx, &|l, bx| {
            leaf_box(&self.leaves[l as usize], bx)
        })
    }

    fn internal_box(
        &self,
        node: &Internal,
        dim: i64,
        child_dim: i64,
        bx: VoxelBox,
        child: &dyn Fn(u32, VoxelBox) -> Bounds,
    ) -> Bounds {
        if bx.contains_node(node.origin, dim) {
            return node.bounds;
        }
        let Some(r) = bx.slot_range(node.origin, dim, child_dim) else {
            return Bounds::EMPTY;
        };
        let side = dim / child_dim;
        let mut b = Bounds::EMPTY;
        for x in r[0].0..=r[0].1 {
            for y in r[1].0..=r[1].1 {
                for z in r[2].0..=r[2].1 {
                    let n = ((x * side + y) * side + z) as usize;
                    if node.has_child(n) {
                        b.union(child(node.slots[n], bx));
                    } else {
                        b.include(node.tile_value(n));
                    }
                }
            }
        }
        b
    }
}

fn leaf_box(leaf: &Leaf, bx: VoxelBox) -> Bounds {
    if bx.contains_node(leaf.origin, 8) {
        return leaf.bounds;
    }
    let Some(r) = bx.slot_range(leaf.origin, 8, 1) else {
        return Bounds::EMPTY;
    };
    let mut b = Bounds::EMPTY;
    for x in r[0].0..=r[0].1 {
        for y in r[1].0..=r[1].1 {
            for z in r[2].0..=r[2].1 {
                b.include(leaf.values[((x << 6) | (y << 3) | z) as usize]);
            }
        }
    }
    b
}

fn internal_bounds(nodes: &mut [Internal], child_bounds: &[Bounds]) {
    for node in nodes {
        let mut b = Bounds::EMPTY;
        for (n, &s) in node.slots.iter().enumerate() {
            if node.has_child(n) {
                b.union(child_bounds[s as usize]);
            } else {
                b.include(f32::from_bits(s));
            }
        }
        node.bounds = b;
    }
}
