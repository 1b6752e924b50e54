//! umbra's flat sparse tree, in the NanoVDB mould: three contiguous arrays of nodes (upper 32^3
//! children of 128^3 voxels each, lower 16^3 children of 8^3 voxels, leaves of 8^3 voxels), a
//! sorted root table, `u32` child indices instead of pointers, and bit masks. An internal node's
//! slot holds either a child index or a tile value (as `f32` bits); the child mask says which.
//!
//! Index space: voxel `(i, j, k)` is centred at index coordinate `(i, j, k)`. A node at level L
//! covers voxels `[origin, origin + dim)` with dim = 8, 128, 4096 for leaf, lower, upper.

mod accessor;
mod bounds;
mod build;
mod region;
mod stats;
mod window;

pub use accessor::Accessor;
pub(crate) use accessor::Block;
pub use bounds::Bounds;
pub use build::TreeBuilder;
pub(crate) use region::{RegionIndex, REGION_LEAF_BYTES, REGION_LOWER_BYTES, REGION_UPPER_BYTES};
pub use stats::TreeStats;
pub use window::Window;

/// log2 of a leaf's edge in voxels.
pub const LEAF_LOG2: u32 = 3;
/// log2 of a lower internal node's edge in voxels (16 leaves).
pub const LOWER_LOG2: u32 = 7;
/// log2 of an upper internal node's edge in voxels (32 lower nodes).
pub const UPPER_LOG2: u32 = 12;

/// Edge length in voxels of a node at `level` (0 = voxel, 1 = leaf, 2 = lower, 3 = upper).
#[must_use]
pub const fn level_dim(level: u32) -> i64 {
    match level {
        0 => 1,
        1 => 1 << LEAF_LOG2,
        2 => 1 << LOWER_LOG2,
        _ => 1 << UPPER_LOG2,
    }
}

/// Test bit `i` of a mask.
#[inline]
#[must_use]
pub fn bit(mask: &[u64], i: usize) -> bool {
    mask[i >> 6] >> (i & 63) & 1 != 0
}

/// Offset of voxel `ijk` inside its leaf: `(x & 7) << 6 | (y & 7) << 3 | (z & 7)`.
#[inline]
#[must_use]
pub fn leaf_offset(ijk: [i32; 3]) -> usize {
    (((ijk[0] & 7) << 6) | ((ijk[1] & 7) << 3) | (ijk[2] & 7)) as usize
}

/// Slot of `ijk` inside its lower node (16^3 slots of 8^3 voxels).
#[inline]
#[must_use]
pub fn lower_offset(ijk: [i32; 3]) -> usize {
    ((((ijk[0] & 127) >> 3) << 8) | (((ijk[1] & 127) >> 3) << 4) | ((ijk[2] & 127) >> 3)) as usize
}

/// Slot of `ijk` inside its upper node (32^3 slots of 128^3 voxels).
#[inline]
#[must_use]
pub fn upper_offset(ijk: [i32; 3]) -> usize {
    ((((ijk[0] & 4095) >> 7) << 10) | (((ijk[1] & 4095) >> 7) << 5) | ((ijk[2] & 4095) >> 7))
        as usize
}

/// Origin of the node of edge `2^log2` containing `ijk`.
#[inline]
#[must_use]
pub fn node_origin(ijk: [i32; 3], log2: u32) -> [i32; 3] {
    let m = !((1i32 << log2) - 1);
    [ijk[0] & m, ijk[1] & m, ijk[2] & m]
}

/// A leaf: its active mask, bounds, and where its 8^3 voxel values are
/// ([`Tree::leaf_values`]).
#[derive(Debug, Clone)]
pub struct Leaf {
    /// Index coordinate of voxel (0,0,0) of the leaf.
    pub origin: [i32; 3],
    /// Active-voxel mask, bit `leaf_offset(ijk)`.
    pub value_mask: [u64; 8],
    /// min/max of every value a nearest lookup can return inside the leaf
    /// ([`Bounds::UNKNOWN`] while its values are not loaded).
    pub bounds: Bounds,
    /// min/max of what trilinear lookups in the leaf's dual-grid region read (voxels
    /// `[o, o + 8]`: the leaf plus a one-voxel halo on its + faces).
    pub halo: Bounds,
    /// Index of the leaf's 512 values in `Tree::values`, or [`UNLOADED`].
    pub(crate) data: u32,
}

/// `Leaf::data` of a leaf whose values were not read (a partial load, see
/// [`crate::vdb::LazyGrid`]).
pub(crate) const UNLOADED: u32 = u32::MAX;

/// What reading an unloaded leaf returns: NaN, which every answer refuses
/// ([`crate::error::Error::NotANumber`]) instead of returning a wrong number. Partial loads read every
/// leaf a job's rays touch, so no correct caller sees these.
pub(crate) static UNLOADED_VALUES: [f32; 512] = [f32::NAN; 512];

/// An internal node with `N` slots (`N` = 4096 for lower, 32768 for upper).
#[derive(Debug, Clone)]
pub struct Internal {
    /// Index coordinate of the node's first voxel.
    pub origin: [i32; 3],
    /// Slots holding a child (bit set) rather than a tile value.
    pub child_mask: Box<[u64]>,
    /// Active tiles (only meaningful where the child bit is clear).
    pub value_mask: Box<[u64]>,
    /// Child index into the next level's array, or tile value as `f32::to_bits`.
    pub slots: Box<[u32]>,
    /// min/max of every value a nearest lookup can return inside the node.
    pub bounds: Bounds,
    /// min/max of what trilinear lookups in the node's dual-grid region read (voxels
    /// `[o, o + dim]`).
    pub halo: Bounds,
    /// Per slot: the halo bound of a tile slot (EMPTY for child slots). Lower nodes only;
    /// upper nodes leave it empty and keep `halo_exceptions` (see [`Internal::tile_halo_of`]).
    pub tile_halo: Box<[Bounds]>,
    /// Upper nodes: `(slot, halo)` of the tile slots whose halo is not just their own value,
    /// sorted by slot (a dense table would be 256 KiB per upper node).
    pub halo_exceptions: Box<[(u32, Bounds)]>,
}

impl Internal {
    /// A node as a decoder or builder lays it out (origin, masks, slots), its bounds and halos
    /// not yet computed (`EMPTY`, filled by the tree's bounds pass).
    #[must_use]
    pub fn unbounded(
        origin: [i32; 3],
        child_mask: Box<[u64]>,
        value_mask: Box<[u64]>,
        slots: Box<[u32]>,
    ) -> Self {
        Self {
            origin,
            child_mask,
            value_mask,
            slots,
            bounds: Bounds::EMPTY,
            halo: Bounds::EMPTY,
            tile_halo: Box::new([]),
            halo_exceptions: Box::new([]),
        }
    }

    /// True if slot `n` holds a child.
    #[inline]
    #[must_use]
    pub fn has_child(&self, n: usize) -> bool {
        bit(&self.child_mask, n)
    }
    /// The tile value of slot `n` (meaningless if it holds a child).
    #[inline]
    #[must_use]
    pub fn tile_value(&self, n: usize) -> f32 {
        f32::from_bits(self.slots[n])
    }

    /// The halo bound of tile slot `n`: what trilinear lookups in its dual-grid region read.
    #[inline]
    #[must_use]
    pub fn tile_halo_of(&self, n: usize) -> Bounds {
        if let Some(&b) = self.tile_halo.get(n) {
            return b;
        }
        match self
            .halo_exceptions
            .binary_search_by_key(&(n as u32), |e| e.0)
        {
            Ok(i) => self.halo_exceptions[i].1,
            Err(_) => Bounds::point(self.tile_value(n)),
        }
    }
}

/// What covers an 8^3 (or 128^3, 4096^3) block next to another: a node or a single value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Neighbour {
    /// Every voxel has this value (a tile at any level, or the background).
    Const(f32),
    /// A leaf (index into [`Tree::leaves`]).
    Leaf(u32),
    /// A lower node (index into [`Tree::lowers`]).
    Lower(u32),
    /// An upper node (index into [`Tree::uppers`]).
    Upper(u32),
}

/// Bounds of the 7 low faces of every node (see `bounds.rs`), what halos are made of.
#[derive(Debug, Clone, Default)]
pub(crate) struct Faces {
    pub(crate) leaves: Vec<bounds::FaceBounds>,
    pub(crate) lowers: Vec<bounds::FaceBounds>,
    pub(crate) uppers: Vec<bounds::FaceBounds>,
}

/// One entry of the root table: a 4096^3 tile or an upper node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RootSlot {
    /// A constant root-level tile.
    Tile {
        /// Tile value.
        value: f32,
        /// Whether the tile is active.
        active: bool,
    },
    /// Index into [`Tree::uppers`].
    Child(u32),
}

/// A root table entry, keyed by its origin (a multiple of 4096 on every axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RootEntry {
    /// Origin of the 4096^3 region.
    pub origin: [i32; 3],
    /// Its content.
    pub slot: RootSlot,
}

/// The flat tree of one grid, values decoded to `f32`.
///
/// Invariant: `bounds`, every node's `bounds`/`halo`, the tile halos and the neighbour tables
/// describe exactly the values the tree holds (what the majorant-driven estimators rely on).
/// The fields are crate-private so that nothing outside the decoder, [`TreeBuilder`] and the
/// bad-voxel policy can change values without recomputing the bounds; read them through the
/// accessors.
#[derive(Debug, Clone, Default)]
pub struct Tree {
    /// Value everywhere outside the root's entries.
    pub(crate) background: f32,
    /// Root table sorted by origin (x, then y, then z), as OpenVDB orders it.
    pub(crate) root: Vec<RootEntry>,
    /// Upper internal nodes (32^3 slots, 4096^3 voxels).
    pub(crate) uppers: Vec<Internal>,
    /// Lower internal nodes (16^3 slots, 128^3 voxels).
    pub(crate) lowers: Vec<Internal>,
    /// Leaves (8^3 voxels).
    pub(crate) leaves: Vec<Leaf>,
    /// The loaded leaves' values, all 512 (inactive ones too), x-major: `values[leaf.data]`.
    pub(crate) values: Vec<[f32; 512]>,
    /// min/max of every value a nearest lookup anywhere can return, background included.
    pub(crate) bounds: Bounds,
    /// Per leaf: its 7 + neighbour blocks, `[k - 1]` for the block at `origin + 8 * (k >> 2,
    /// k >> 1 & 1, k & 1)` (what a trilinear lookup on the leaf's + faces reads).
    pub(crate) neighbours: Vec<[Neighbour; 7]>,
    pub(crate) faces: Faces,
    /// Topology only: no leaf loaded and no bounds computed ([`crate::vdb::LazyGrid::shell`]).
    /// Every walk over it stops at once as unloaded; only topology walks read it.
    pub(crate) shell: bool,
}

impl Tree {
    /// Value everywhere outside the root's entries.
    #[must_use]
    pub fn background(&self) -> f32 {
        self.background
    }
    /// Root table sorted by origin (x, then y, then z), as OpenVDB orders it.
    #[must_use]
    pub fn root(&self) -> &[RootEntry] {
        &self.root
    }
    /// Upper internal nodes (32^3 slots, 4096^3 voxels).
    #[must_use]
    pub fn uppers(&self) -> &[Internal] {
        &self.uppers
    }
    /// Lower internal nodes (16^3 slots, 128^3 voxels).
    #[must_use]
    pub fn lowers(&self) -> &[Internal] {
        &self.lowers
    }
    /// Leaves (8^3 voxels).
    #[must_use]
    pub fn leaves(&self) -> &[Leaf] {
        &self.leaves
    }
    /// min/max of every value a nearest lookup anywhere can return, background included
    /// ([`Bounds::UNKNOWN`] in a partial tree).
    #[must_use]
    pub fn bounds(&self) -> Bounds {
        self.bounds
    }
    /// The 512 values of leaf `leaf` (x-major, inactive ones too, index [`leaf_offset`]). A
    /// leaf a partial load did not read gives NaNs.
    ///
    /// # Panics
    /// If `leaf` is not an index into [`Tree::leaves`].
    #[inline]
    #[must_use]
    pub fn leaf_values(&self, leaf: u32) -> &[f32; 512] {
        self.values_of(&self.leaves[leaf as usize])
    }
    /// The values of `leaf`, a leaf of this tree.
    #[inline]
    pub(crate) fn values_of(&self, leaf: &Leaf) -> &[f32; 512] {
        self.values
            .get(leaf.data as usize)
            .unwrap_or(&UNLOADED_VALUES)
    }
    /// Number of leaves whose values are loaded (all of them but after a partial load).
    #[must_use]
    pub fn loaded_leaf_count(&self) -> usize {
        self.values.len()
    }
    /// Whether every leaf's values are loaded (false for a partial load).
    #[must_use]
    pub fn is_complete(&self) -> bool {
        self.values.len() == self.leaves.len()
    }
    /// Per leaf: its 7 + neighbour blocks (see the field docs in the source).
    #[must_use]
    pub fn neighbours(&self) -> &[[Neighbour; 7]] {
        &self.neighbours
    }
}

/// What a descent to `ijk` found: the value and the node that holds it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Found {
    /// Outside every root entry: the background.
    Background,
    /// A root-level tile (root entry index).
    RootTile(usize),
    /// A tile in an upper node.
    UpperTile {
        /// Index into [`Tree::uppers`].
        node: u32,
        /// Slot within the node.
        slot: usize,
    },
    /// A tile in a lower node.
    LowerTile {
        /// Index into [`Tree::lowers`].
        node: u32,
        /// Slot within the node.
        slot: usize,
    },
    /// A voxel of a leaf.
    Voxel {
        /// Index into [`Tree::leaves`].
        node: u32,
        /// Voxel offset within the leaf.
        offset: usize,
    },
}

impl Tree {
    /// Index of the root entry whose region contains `ijk`.
    #[must_use]
    pub fn root_find(&self, ijk: [i32; 3]) -> Option<usize> {
        let key = node_origin(ijk, UPPER_LOG2);
        self.root.binary_search_by(|e| e.origin.cmp(&key)).ok()
    }

    /// Descend from the root to the deepest node holding `ijk`.
    #[must_use]
    pub fn find(&self, ijk: [i32; 3]) -> Found {
        let Some(r) = self.root_find(ijk) else {
            return Found::Background;
        };
        let upper = match self.root[r].slot {
            RootSlot::Tile { .. } => return Found::RootTile(r),
            RootSlot::Child(u) => u,
        };
        self.find_in_upper(upper, ijk)
    }

    /// Descend from upper node `upper`.
    #[must_use]
    pub fn find_in_upper(&self, upper: u32, ijk: [i32; 3]) -> Found {
        let node = &self.uppers[upper as usize];
        let slot = upper_offset(ijk);
        if !node.has_child(slot) {
            return Found::UpperTile { node: upper, slot };
        }
        self.find_in_lower(node.slots[slot], ijk)
    }

    /// Descend from lower node `lower`.
    #[must_use]
    pub fn find_in_lower(&self, lower: u32, ijk: [i32; 3]) -> Found {
        let node = &self.lowers[lower as usize];
        let slot = lower_offset(ijk);
        if !node.has_child(slot) {
            return Found::LowerTile { node: lower, slot };
        }
        Found::Voxel {
            node: node.slots[slot],
            offset: leaf_offset(ijk),
        }
    }

    /// The value a [`Found`] refers to.
    #[must_use]
    pub fn value_of(&self, f: Found) -> f32 {
        match f {
            Found::Background => self.background,
            Found::RootTile(r) => match self.root[r].slot {
                RootSlot::Tile { value, .. } => value,
                RootSlot::Child(_) => self.background,
            },
            Found::UpperTile { node, slot } => self.uppers[node as usize].tile_value(slot),
            Found::LowerTile { node, slot } => self.lowers[node as usize].tile_value(slot),
            Found::Voxel { node, offset } => self.leaf_values(node)[offset],
        }
    }

    /// Every value held outside the leaves, changed in place by `f`: the background, each root
    /// tile and each internal tile (what a value policy such as the bad-voxel one visits before
    /// the leaves). Bounds are not recomputed: the caller does so if any changed.
    pub(crate) fn tile_values_mut(&mut self, mut f: impl FnMut(&mut f32)) {
        f(&mut self.background);
        for e in &mut self.root {
            if let RootSlot::Tile { value, .. } = &mut e.slot {
                f(value);
            }
        }
        for n in self.uppers.iter_mut().chain(self.lowers.iter_mut()) {
            for i in 0..n.slots.len() {
                if !n.has_child(i) {
                    let mut v = f32::from_bits(n.slots[i]);
                    f(&mut v);
                    n.slots[i] = v.to_bits();
                }
            }
        }
    }

    /// The value at voxel `ijk` (active or not), as OpenVDB's `tree.getValue(ijk)`.
    #[must_use]
    pub fn value(&self, ijk: [i32; 3]) -> f32 {
        self.value_of(self.find(ijk))
    }

    /// Whether voxel `ijk` is active.
    #[must_use]
    pub fn is_active(&self, ijk: [i32; 3]) -> bool {
        match self.find(ijk) {
            Found::Background => false,
            Found::RootTile(r) => matches!(self.root[r].slot, RootSlot::Tile { active: true, .. }),
            Found::UpperTile { node, slot } => bit(&self.uppers[node as usize].value_mask, slot),
            Found::LowerTile { node, slot } => bit(&self.lowers[node as usize].value_mask, slot),
            Found::Voxel { node, offset } => bit(&self.leaves[node as usize].value_mask, offset),
        }
    }

    /// Bytes of memory the tree holds.
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        let internal = |v: &Vec<Internal>| {
            v.iter()
                .map(|n| {
                    std::mem::size_of::<Internal>()
                        + 8 * (n.child_mask.len() + n.value_mask.len())
                        + 4 * n.slots.len()
                        + std::mem::size_of::<Bounds>() * n.tile_halo.len()
                        + std::mem::size_of::<(u32, Bounds)>() * n.halo_exceptions.len()
                })
                .sum::<usize>()
        };
        (std::mem::size_of::<Self>()
            + self.root.capacity() * std::mem::size_of::<RootEntry>()
            + internal(&self.uppers)
            + internal(&self.lowers)
            + self.leaves.capacity() * std::mem::size_of::<Leaf>()
            + self.values.capacity() * std::mem::size_of::<[f32; 512]>()
            + self.neighbours.capacity() * std::mem::size_of::<[Neighbour; 7]>()
            + (self.faces.leaves.capacity()
                + self.faces.lowers.capacity()
                + self.faces.uppers.capacity())
                * std::mem::size_of::<bounds::FaceBounds>()) as u64
    }
}

/// The index box of every leaf (origins `leaves`) and every tile of `tree` whose value differs
/// from the background.
pub(crate) fn value_box_of(
    tree: &Tree,
    leaves: impl Iterator<Item = [i32; 3]>,
) -> Option<[[i64; 3]; 2]> {
    let mut b: Option<[[i64; 3]; 2]> = None;
    let mut add = |o: [i32; 3], dim: i64| {
        let lo = o.map(i64::from);
        let hi = lo.map(|c| c + dim - 1);
        let bb = b.get_or_insert([lo, hi]);
        for a in 0..3 {
            bb[0][a] = bb[0][a].min(lo[a]);
            bb[1][a] = bb[1][a].max(hi[a]);
        }
    };
    let bg = tree.background;
    for e in &tree.root {
        if let RootSlot::Tile { value, .. } = e.slot {
            if value != bg {
                add(e.origin, 4096);
            }
        }
    }
    for (nodes, dim, child) in [(&tree.uppers, 32usize, 128i64), (&tree.lowers, 16, 8)] {
        for n in nodes {
            for s in 0..n.slots.len() {
                if !n.has_child(s) && n.tile_value(s) != bg {
                    let l = [s / (dim * dim), (s / dim) % dim, s % dim];
                    add(
                        [0, 1, 2].map(|a| n.origin[a] + (l[a] as i64 * child) as i32),
                        child,
                    );
                }
            }
        }
    }
    for origin in leaves {
        add(origin, 8);
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_round_trip_every_voxel_of_a_leaf_and_negative_coords() {
        let mut seen = [false; 512];
        for x in -8..0 {
            for y in 0..8 {
                for z in 8..16 {
                    let n = leaf_offset([x, y, z]);
                    assert!(!seen[n]);
                    seen[n] = true;
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(node_origin([-1, 4095, 4096], UPPER_LOG2), [-4096, 0, 4096]);
        assert_eq!(lower_offset([127, 0, 8]), (15 << 8) | 1);
        assert_eq!(upper_offset([-1, 0, 0]), 31 << 10);
    }
}
