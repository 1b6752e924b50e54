//! Value bounds per node: the min and max of every value a lookup inside the node can return.
//!
//! Regions: for nearest lookups a node of edge `dim` at origin `o` owns the points whose voxel
//! `floor(p + 0.5)` lies in `[o, o + dim)`; it reads only its own voxels and tiles (`bounds`).
//! For trilinear lookups it owns the points with `floor(p)` in `[o, o + dim)` (the cells between
//! voxel centres, the dual grid), and a lookup there reads voxels `floor(p) + {0, 1}`: the node's
//! voxels plus a one-voxel halo on its + faces, `[o, o + dim]` (`halo`), inactive values and
//! background included. Internal nodes also keep the halo bound of every tile slot. These are the
//! majorants and minorants the traversal hands to the estimators.

use super::{
    level_dim, lower_offset, upper_offset, Faces, Internal, Leaf, Neighbour, RootSlot, Tree,
};
use rayon::prelude::*;

/// Bounds of the 7 low faces of a block, `[k - 1]` for face `k` (see [`Tree::face`]).
pub(crate) type FaceBounds = [Bounds; 7];

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
        // Comparisons are false for NaN, so NaN never enters (and `min`/`max` are never NaN).
        self.min = if v < self.min { v } else { self.min };
        self.max = if v > self.max { v } else { self.max };
    }

    /// Grow to include another interval.
    #[inline]
    pub fn union(&mut self, o: Self) {
        self.min = if o.min < self.min { o.min } else { self.min };
        self.max = if o.max > self.max { o.max } else { self.max };
    }

    /// The whole real line: the bounds of a leaf whose values a partial load did not read, and
    /// of everything that depends on it. Sanitised values are never negative, so `min = -inf`
    /// tells unknown data apart from real data; a walk over a partial tree checks it.
    pub const UNKNOWN: Self = Self {
        min: f32::NEG_INFINITY,
        max: f32::INFINITY,
    };

    /// True for [`Bounds::UNKNOWN`] (and anything unioned with it).
    #[inline]
    #[must_use]
    pub fn is_unknown(&self) -> bool {
        self.min == f32::NEG_INFINITY && self.max == f32::INFINITY
    }

    /// True if no value was included.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.min > self.max
    }
}

/// An upper node's halo and its tile-slot halo exceptions.
type UpperHalos = (Bounds, Box<[(u32, Bounds)]>);

/// What [`Tree::lower_halos`] finds for one lower node.
struct LowerHalos {
    halo: Bounds,
    tile_halo: Box<[Bounds]>,
    /// `(leaf, halo, + neighbours)` of each child leaf.
    leaves: Vec<(u32, Bounds, [Neighbour; 7])>,
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
    fn trilinear(origin: [i64; 3], dim: i64) -> Self {
        Self {
            lo: origin,
            hi: origin.map(|v| v + dim),
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
    /// Compute every node's nearest bounds and low-face bounds, the leaves' neighbour table,
    /// then every node's and tile slot's halo bounds. Called once at load (and again if the
    /// values change).
    ///
    /// Cost: one pass over the leaf values (bounds and the 7 low faces of each leaf), one over
    /// the internal nodes' slots, then 7 neighbour-block lookups per leaf and per lower-node
    /// tile slot (mostly inside the same node: index arithmetic). Upper nodes keep only the
    /// tile-slot halos that differ from their own value, found from the child slots and the
    /// node's + faces.
    pub(crate) fn compute_bounds(&mut self) {
        // 1. Nearest bounds and low faces, bottom-up (leaves and nodes in parallel).
        let values = &self.values;
        let leaf_faces: Vec<FaceBounds> = self
            .leaves
            .par_iter_mut()
            .map(|leaf| {
                let (b, f) = match values.get(leaf.data as usize) {
                    Some(v) => leaf_stats(v),
                    None => (Bounds::UNKNOWN, [Bounds::UNKNOWN; 7]),
                };
                leaf.bounds = b;
                f
            })
            .collect();
        let child_bounds: Vec<Bounds> = self.leaves.iter().map(|l| l.bounds).collect();
        let lower_faces = internal_stats(&mut self.lowers, 4, &child_bounds, &leaf_faces);
        let child_bounds: Vec<Bounds> = self.lowers.iter().map(|n| n.bounds).collect();
        let upper_faces = internal_stats(&mut self.uppers, 5, &child_bounds, &lower_faces);
        let mut all = Bounds::point(self.background);
        for e in &self.root {
            match e.slot {
                RootSlot::Tile { value, .. } => all.include(value),
                RootSlot::Child(u) => all.union(self.uppers[u as usize].bounds),
            }
        }
        self.bounds = all;
        self.faces = Faces {
            leaves: leaf_faces,
            lowers: lower_faces,
            uppers: upper_faces,
        };

        // 2. Neighbours and halos: they read the neighbours' faces, so they come second. Each
        // lower node (its tile slots and its leaves) is independent: in parallel.
        let lower_halos: Vec<LowerHalos> = self
            .lowers
            .par_iter()
            .map(|n| self.lower_halos(n))
            .collect();
        let upper_halos: Vec<UpperHalos> = self
            .uppers
            .par_iter()
            .map(|n| {
                let around = self.around(n.origin, 3);
                (
                    self.halo_from(n.bounds, &around),
                    self.upper_exceptions(n, &around),
                )
            })
            .collect();
        let mut nbrs = Vec::with_capacity(self.leaves.len());
        nbrs.resize(self.leaves.len(), [Neighbour::Const(self.background); 7]);
        for (n, h) in self.lowers.iter_mut().zip(lower_halos) {
            n.halo = h.halo;
            n.tile_halo = h.tile_halo;
            n.halo_exceptions = Box::new([]);
            for (l, halo, nb) in h.leaves {
                self.leaves[l as usize].halo = halo;
                nbrs[l as usize] = nb;
            }
        }
        for (n, (h, e)) in self.uppers.iter_mut().zip(upper_halos) {
            n.halo = h;
            n.tile_halo = Box::new([]);
            n.halo_exceptions = e;
        }
        self.neighbours = nbrs;
    }

    /// A lower node's halo, its tile slots' halos, and its leaves' halos and neighbours.
    fn lower_halos(&self, n: &Internal) -> LowerHalos {
        let around = self.around(n.origin, 2);
        let mut tile_halo = vec![Bounds::EMPTY; n.slots.len()];
        let mut leaves = Vec::new();
        for (slot, th) in tile_halo.iter_mut().enumerate() {
            let l = [slot >> 8, (slot >> 4) & 15, slot & 15];
            if !n.has_child(slot) && l.iter().all(|&c| c < 15) {
                // Inside the node, a tile whose 7 + neighbours are tiles of the same value
                // (bit for bit) has a constant halo.
                let v = n.slots[slot];
                let plain = [1, 16, 17, 256, 257, 272, 273]
                    .iter()
                    .all(|&d| !n.has_child(slot + d) && n.slots[slot + d] == v);
                if plain {
                    *th = Bounds::point(f32::from_bits(v));
                    continue;
                }
            }
            let nb: [Neighbour; 7] =
                std::array::from_fn(|k| self.slot_neighbour(n, 4, slot, k + 1, &around));
            if n.has_child(slot) {
                let l = n.slots[slot];
                leaves.push((l, self.halo_from(self.leaves[l as usize].bounds, &nb), nb));
            } else {
                *th = self.halo_from(Bounds::point(n.tile_value(slot)), &nb);
            }
        }
        LowerHalos {
            halo: self.halo_from(n.bounds, &around),
            tile_halo: tile_halo.into_boxed_slice(),
            leaves,
        }
    }

    /// The tile slots of upper node `n` whose halo is not `point(tile value)`: among those
    /// with a + neighbour (the 7 slots at `+{0,1}^3`) that is a child, a tile of another value,
    /// or outside the node (`around`: the node's own 7 + neighbours).
    fn upper_exceptions(&self, n: &Internal, around: &[Neighbour; 7]) -> Box<[(u32, Bounds)]> {
        const SIDE: usize = 32;
        let idx = |l: [usize; 3]| (l[0] * SIDE + l[1]) * SIDE + l[2];
        let mut cand = vec![0u64; n.slots.len() / 64];
        let mark = |c: &mut [u64], s: usize| c[s >> 6] |= 1 << (s & 63);
        // Are all tiles one value? (Usually: the background.)
        let first_tile = (0..n.slots.len()).find(|&s| !n.has_child(s));
        let uniform = first_tile.is_none_or(|f| {
            let v = n.slots[f];
            n.child_mask.iter().enumerate().all(|(w, &cw)| {
                let s = &n.slots[w * 64..w * 64 + 64];
                if cw == 0 {
                    s.iter().fold(true, |ok, &x| ok & (x == v))
                } else {
                    (0..64).all(|b| cw >> b & 1 != 0 || s[b] == v)
                }
            })
        });
        if uniform {
            // The slots on the + faces, then the - neighbours of every child slot.
            for i in 0..SIDE {
                for j in 0..SIDE {
                    mark(&mut cand, idx([SIDE - 1, i, j]));
                    mark(&mut cand, idx([i, SIDE - 1, j]));
                    mark(&mut cand, idx([i, j, SIDE - 1]));
                }
            }
            for (w, &word) in n.child_mask.iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    let s = w * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let l = [s / (SIDE * SIDE), (s / SIDE) % SIDE, s % SIDE];
                    for k in 1..8usize {
                        let b = [k >> 2, (k >> 1) & 1, k & 1];
                        if (0..3).all(|a| l[a] >= b[a]) {
                            mark(&mut cand, idx([0, 1, 2].map(|a| l[a] - b[a])));
                        }
                    }
                }
            }
        } else {
            cand.fill(u64::MAX);
        }
        let mut out = Vec::new();
        for (w, &word) in cand.iter().enumerate() {
            let mut bits = word & !n.child_mask[w];
            while bits != 0 {
                let s = w * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let own = Bounds::point(n.tile_value(s));
                let nb: [Neighbour; 7] =
                    std::array::from_fn(|k| self.slot_neighbour(n, 5, s, k + 1, around));
                let h = self.halo_from(own, &nb);
                if h != own {
                    out.push((s as u32, h));
                }
            }
        }
        out.into_boxed_slice()
    }

    /// The 7 + neighbour blocks of the `level` block at `origin`.
    fn around(&self, origin: [i32; 3], level: u32) -> [Neighbour; 7] {
        let dim = level_dim(level);
        let o = origin.map(i64::from);
        std::array::from_fn(|k| {
            let k = k + 1;
            let b = [k >> 2, (k >> 1) & 1, k & 1];
            self.block_at([0, 1, 2].map(|a| o[a] + dim * b[a] as i64), level)
        })
    }

    /// Neighbour block `k` (bits x, y, z) of slot `slot` of internal node `node` (`2^side_log2`
    /// slots per side; `around` are the node's own + neighbours): a slot of the node itself or
    /// of the neighbouring node, by index arithmetic.
    #[inline]
    fn slot_neighbour(
        &self,
        node: &Internal,
        side_log2: u32,
        slot: usize,
        k: usize,
        around: &[Neighbour; 7],
    ) -> Neighbour {
        let side = 1usize << side_log2;
        let l = [
            slot >> (2 * side_log2),
            (slot >> side_log2) & (side - 1),
            slot & (side - 1),
        ];
        let m = [l[0] + (k >> 2), l[1] + ((k >> 1) & 1), l[2] + (k & 1)];
        let out = (usize::from(m[0] >= side) << 2)
            | (usize::from(m[1] >= side) << 1)
            | usize::from(m[2] >= side);
        let m = m.map(|c| c & (side - 1));
        let s = (((m[0] << side_log2) | m[1]) << side_log2) | m[2];
        let other;
        let n = if out == 0 {
            node
        } else {
            other = match around[out - 1] {
                Neighbour::Lower(i) => &self.lowers[i as usize],
                Neighbour::Upper(i) => &self.uppers[i as usize],
                c => return c,
            };
            other
        };
        if !n.has_child(s) {
            Neighbour::Const(n.tile_value(s))
        } else if side_log2 == 4 {
            Neighbour::Leaf(n.slots[s])
        } else {
            Neighbour::Lower(n.slots[s])
        }
    }

    /// What covers the block of edge `level_dim(level)` (`level` 1, 2 or 3) at `origin` (a
    /// multiple of that edge): a node of that level, or one value (a tile at that level or
    /// above, or the background; also beyond the `i32` range).
    pub(crate) fn block_at(&self, origin: [i64; 3], level: u32) -> Neighbour {
        let bg = Neighbour::Const(self.background);
        let (Ok(x), Ok(y), Ok(z)) = (
            i32::try_from(origin[0]),
            i32::try_from(origin[1]),
            i32::try_from(origin[2]),
        ) else {
            return bg;
        };
        let o = [x, y, z];
        let Some(r) = self.root_find(o) else {
            return bg;
        };
        let u = match self.root[r].slot {
            RootSlot::Tile { value, .. } => return Neighbour::Const(value),
            RootSlot::Child(u) => u,
        };
        if level >= 3 {
            return Neighbour::Upper(u);
        }
        let n = &self.uppers[u as usize];
        let s = upper_offset(o);
        if !n.has_child(s) {
            return Neighbour::Const(n.tile_value(s));
        }
        if level == 2 {
            return Neighbour::Lower(n.slots[s]);
        }
        let m = &self.lowers[n.slots[s] as usize];
        let s = lower_offset(o);
        if m.has_child(s) {
            Neighbour::Leaf(m.slots[s])
        } else {
            Neighbour::Const(m.tile_value(s))
        }
    }

    /// Low face `k` (1..8) of a neighbour block: the values of its voxels whose local
    /// coordinate is 0 on every axis whose bit is set in `k` (x = 4, y = 2, z = 1).
    fn face(&self, n: Neighbour, k: usize) -> Bounds {
        match n {
            Neighbour::Const(v) => Bounds::point(v),
            Neighbour::Leaf(i) => self.faces.leaves[i as usize][k - 1],
            Neighbour::Lower(i) => self.faces.lowers[i as usize][k - 1],
            Neighbour::Upper(i) => self.faces.uppers[i as usize][k - 1],
        }
    }

    /// A block's halo from its own bounds and its 7 + neighbours (`nb[k - 1]` = block `k`).
    fn halo_from(&self, own: Bounds, nb: &[Neighbour; 7]) -> Bounds {
        let mut b = own;
        for (k, &n) in nb.iter().enumerate() {
            b.union(self.face(n, k + 1));
        }
        b
    }

    /// The halo of the block of `level` at `origin` whose own values have bounds `own`.
    fn halo_at(&self, origin: [i32; 3], level: u32, own: Bounds) -> Bounds {
        self.halo_from(own, &self.around(origin, level))
    }

    /// Bounds of the values a trilinear lookup can read in the dual-grid region of the `dim`^3
    /// block at `origin` (a tile, node, voxel, or empty root cell): voxels `[o, o + dim]`. The
    /// origin is in the unbounded index space: a root cell just below the `i32` range (which
    /// trilinear lookups reach) holds the background and reads the range's first voxels on its
    /// + faces.
    #[must_use]
    pub fn halo_bounds(&self, origin: [i64; 3], dim: i64) -> Bounds {
        let whole = VoxelBox::trilinear(origin, dim);
        let level = match dim {
            8 => 1,
            128 => 2,
            4096 => 3,
            _ => return self.box_bounds(whole),
        };
        let aligned = origin.iter().all(|&c| c % dim == 0);
        let in_range = [0, 1, 2].map(|a| i32::try_from(origin[a]).ok());
        let ([Some(x), Some(y), Some(z)], true, true) = (
            in_range,
            aligned,
            self.faces.leaves.len() == self.leaves.len(),
        ) else {
            return self.box_bounds(whole);
        };
        let own = match self.block_at(origin, level) {
            Neighbour::Const(v) => Bounds::point(v),
            Neighbour::Leaf(i) => self.leaves[i as usize].bounds,
            Neighbour::Lower(i) => self.lowers[i as usize].bounds,
            Neighbour::Upper(i) => self.uppers[i as usize].bounds,
        };
        self.halo_at([x, y, z], level, own)
    }

    /// Call `f` with every leaf holding a voxel of the inclusive index box `[lo, hi]` (each
    /// once, in tree order per upper node). Reads topology only.
    pub(crate) fn leaves_in_box(&self, lo: [i64; 3], hi: [i64; 3], f: &mut dyn FnMut(u32)) {
        let bx = VoxelBox { lo, hi };
        let each = |node: &Internal, dim: i64, child_dim: i64, f: &mut dyn FnMut(u32)| {
            let Some(r) = bx.slot_range(node.origin, dim, child_dim) else {
                return;
            };
            let side = dim / child_dim;
            for x in r[0].0..=r[0].1 {
                for y in r[1].0..=r[1].1 {
                    for z in r[2].0..=r[2].1 {
                        let n = ((x * side + y) * side + z) as usize;
                        if node.has_child(n) {
                            f(node.slots[n]);
                        }
                    }
                }
            }
        };
        for e in &self.root {
            if let RootSlot::Child(u) = e.slot {
                each(&self.uppers[u as usize], 4096, 128, &mut |l| {
                    each(&self.lowers[l as usize], 128, 8, f);
                });
            }
        }
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
            leaf_box(&self.leaves[l as usize], self.leaf_values(l), bx)
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

fn leaf_box(leaf: &Leaf, values: &[f32; 512], bx: VoxelBox) -> Bounds {
    if bx.contains_node(leaf.origin, 8) {
        return leaf.bounds;
    }
    if leaf.data == super::UNLOADED {
        return Bounds::UNKNOWN;
    }
    let Some(r) = bx.slot_range(leaf.origin, 8, 1) else {
        return Bounds::EMPTY;
    };
    let mut b = Bounds::EMPTY;
    for x in r[0].0..=r[0].1 {
        for y in r[1].0..=r[1].1 {
            for z in r[2].0..=r[2].1 {
                b.include(values[((x << 6) | (y << 3) | z) as usize]);
            }
        }
    }
    b
}

/// Bounds of `f(x)` over a run of values (a multiple of 8 long), in 8 independent lanes of
/// `if x < min { min = x }` (NaN never wins), which the compiler turns into packed min/max.
#[inline]
fn lanes_bounds<T: Copy>(v: &[T], f: impl Fn(T) -> f32) -> Bounds {
    let (mut lo, mut hi) = ([f32::INFINITY; 8], [f32::NEG_INFINITY; 8]);
    for c in v.chunks_exact(8) {
        let c: [f32; 8] = std::array::from_fn(|i| f(c[i]));
        let nlo: [f32; 8] = std::array::from_fn(|i| if c[i] < lo[i] { c[i] } else { lo[i] });
        let nhi: [f32; 8] = std::array::from_fn(|i| if hi[i] < c[i] { c[i] } else { hi[i] });
        (lo, hi) = (nlo, nhi);
    }
    let mut b = Bounds::EMPTY;
    for i in 0..8 {
        b.union(Bounds {
            min: lo[i],
            max: hi[i],
        });
    }
    b
}

/// A leaf's bounds and the bounds of its 7 low faces (`[k - 1]`, see [`Tree::face`]).
fn leaf_stats(v: &[f32; 512]) -> (Bounds, FaceBounds) {
    // 8 independent lanes of `if x < min { min = x }` (NaN never wins), which vectorises.
    let b = lanes_bounds(v, |x| x);
    let mut f = [Bounds::EMPTY; 7];
    f[3] = lanes_bounds(&v[..64], |x| x); // k = 4: x = 0
    for x in 0..8 {
        for z in 0..8 {
            f[1].include(v[(x << 6) | z]); // k = 2: y = 0
        }
        for y in 0..8 {
            f[0].include(v[(x << 6) | (y << 3)]); // k = 1: z = 0
        }
        f[2].include(v[x << 6]); // k = 3: y = z = 0
        f[5].include(v[x]); // k = 6: x = y = 0
        f[4].include(v[x << 3]); // k = 5: x = z = 0
    }
    f[6] = Bounds::point(v[0]); // k = 7: the corner voxel
    (b, f)
}

/// Origin (i64) of slot `slot` of a node at `origin` with `2^side_log2` slots per side of
/// `2^child_log2` voxels.
#[cfg(test)]
fn slot_origin(origin: [i32; 3], slot: usize, side_log2: u32, child_log2: u32) -> [i64; 3] {
    let side = (1usize << side_log2) - 1;
    let l = [
        slot >> (2 * side_log2),
        (slot >> side_log2) & side,
        slot & side,
    ];
    [0, 1, 2].map(|a| i64::from(origin[a]) + ((l[a] as i64) << child_log2))
}

/// Every node's bounds (from its children's bounds and its tile values) and its 7 low faces
/// (from its children's faces and the tile values on them).
fn internal_stats(
    nodes: &mut [Internal],
    side_log2: u32,
    child_bounds: &[Bounds],
    child_faces: &[FaceBounds],
) -> Vec<FaceBounds> {
    let side = 1usize << side_log2;
    let mut out = Vec::with_capacity(nodes.len());
    for node in nodes {
        let mut b = Bounds::EMPTY;
        for (w, &cw) in node.child_mask.iter().enumerate() {
            let slots = &node.slots[w * 64..w * 64 + 64];
            if cw == 0 {
                b.union(lanes_bounds(slots, f32::from_bits));
                continue;
            }
            for (i, &x) in slots.iter().enumerate() {
                if cw >> i & 1 != 0 {
                    b.union(child_bounds[x as usize]);
                } else {
                    b.include(f32::from_bits(x));
                }
            }
        }
        node.bounds = b;
        let face_of = |n: usize, k: usize| {
            if node.has_child(n) {
                child_faces[node.slots[n] as usize][k - 1]
            } else {
                Bounds::point(node.tile_value(n))
            }
        };
        let mut f = [Bounds::EMPTY; 7];
        for k in 1..8usize {
            let b = [k >> 2, (k >> 1) & 1, k & 1];
            // Slots whose local coordinate is 0 on the axes of `k`.
            let r = b.map(|bit| if bit == 1 { 1 } else { side });
            for x in 0..r[0] {
                for y in 0..r[1] {
                    for z in 0..r[2] {
                        f[k - 1].union(face_of((((x << side_log2) | y) << side_log2) | z, k));
                    }
                }
            }
        }
        out.push(f);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    /// Every halo the fast face-based pass stores (leaves, lower tile slots, upper tile slots,
    /// nodes) equals the box scan over `[o, o + dim]`, on a tree with leaves, tiles at every
    /// level, negative coordinates, neighbouring upper nodes and a non-zero background.
    #[test]
    fn fast_halos_equal_box_scans() {
        let mut b = TreeBuilder::new(0.5);
        let mut x = 12345u64;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..3000 {
            let p = [0, 1, 2].map(|_| (rnd() % 300) as i32 - 150);
            b.set(p, (rnd() % 1000) as f32 / 100.0);
        }
        b.tile([-4096 - 128, 0, 0], 7, 3.0)
            .tile([-128, 128, 0], 7, 4.0)
            .tile([160, 160, 160], 3, 5.0)
            .tile([152, 160, 160], 3, 0.25)
            .tile([4096, 0, 0], 12, 6.0);
        let t = b.build();
        for l in &t.leaves {
            assert_eq!(
                l.halo,
                t.box_bounds(VoxelBox::trilinear(l.origin.map(i64::from), 8))
            );
        }
        for (nodes, side_log2, child_log2) in [(&t.lowers, 4u32, 3u32), (&t.uppers, 5, 7)] {
            for n in nodes {
                let dim = 1i64 << (side_log2 + child_log2);
                assert_eq!(
                    n.halo,
                    t.box_bounds(VoxelBox::trilinear(n.origin.map(i64::from), dim))
                );
                for s in 0..n.slots.len() {
                    if n.has_child(s) {
                        continue;
                    }
                    let o = slot_origin(n.origin, s, side_log2, child_log2).map(|c| c as i32);
                    let want = t.box_bounds(VoxelBox::trilinear(o.map(i64::from), 1 << child_log2));
                    assert_eq!(n.tile_halo_of(s), want, "slot {s} at {o:?}");
                }
            }
        }
        for e in &t.root {
            let want = t.box_bounds(VoxelBox::trilinear(e.origin.map(i64::from), 4096));
            assert_eq!(t.halo_bounds(e.origin.map(i64::from), 4096), want);
        }
        for o in [[-4096, -4096, -4096], [8192, 0, 0], [0, 4096, 0]] {
            assert_eq!(
                t.halo_bounds(o.map(i64::from), 4096),
                t.box_bounds(VoxelBox::trilinear(o.map(i64::from), 4096))
            );
        }
    }
}
