//! A region of a tree: a new tree holding only some of its lower nodes (with their leaves,
//! unloaded), so that a bake in parts copies and bounds only what a part reads instead of the
//! whole topology per part.
//!
//! The region tree keeps the root table's tiles and, of the upper nodes, those that hold a kept
//! lower node; in them every other lower node's slot becomes a tile of the background. Inside a
//! kept lower node it reads exactly as the tree (its leaves loaded or not, as
//! [`crate::vdb::LazyGrid`] leaves them); outside, it reads the background or an upper or root
//! tile. A caller reads only inside the kept nodes: the sweep in parts keeps every lower node
//! its pieces' trilinear corners (`[o, o + 128]` of a lower node, `[o, o + 8]` of a shell
//! block) can reach, and takes trees without extinction above lower nodes only.

use super::{Bounds, Internal, Leaf, Neighbour, RootEntry, RootSlot, Tree, UNLOADED};

/// Bytes a region holds per leaf of its kept lower nodes besides the values: the leaf, its
/// neighbour table and faces, and what computing its bounds holds for a moment (its bounds, and
/// a halo with its neighbours in a per-node vector that may have grown to twice its length).
pub(crate) const REGION_LEAF_BYTES: u64 = (std::mem::size_of::<Leaf>()
    + std::mem::size_of::<[Neighbour; 7]>()
    + std::mem::size_of::<[Bounds; 7]>()
    + std::mem::size_of::<Bounds>()
    + 2 * std::mem::size_of::<(u32, Bounds, [Neighbour; 7])>())
    as u64;

/// Bytes a region holds per kept lower node: its masks, slots, tile-slot halos and faces.
pub(crate) const REGION_LOWER_BYTES: u64 = (std::mem::size_of::<Internal>()
    + 2 * 512
    + 4096 * 4
    + 4096 * std::mem::size_of::<Bounds>()
    + std::mem::size_of::<[Bounds; 7]>()) as u64;

/// Bytes a region holds per upper node it copies (masks and slots; tile-halo exceptions are
/// few).
pub(crate) const REGION_UPPER_BYTES: u64 =
    (std::mem::size_of::<Internal>() + 2 * 4096 + 32768 * 4 + 1024) as u64;

/// Where a region's nodes come from: `(tree index, region index)` of its lower nodes and of
/// its leaves, each sorted by tree index.
#[derive(Debug, Clone, Default)]
pub(crate) struct RegionIndex {
    lowers: Vec<(u32, u32)>,
    leaves: Vec<(u32, u32)>,
}

impl RegionIndex {
    /// The region's index of the tree's lower node `l`, if kept.
    pub(crate) fn lower(&self, l: u32) -> Option<u32> {
        find(&self.lowers, l)
    }
    /// The region's index of the tree's leaf `l`, if its lower node is kept.
    pub(crate) fn leaf(&self, l: u32) -> Option<u32> {
        find(&self.leaves, l)
    }
}

fn find(pairs: &[(u32, u32)], key: u32) -> Option<u32> {
    pairs
        .binary_search_by_key(&key, |p| p.0)
        .ok()
        .map(|i| pairs[i].1)
}

impl Tree {
    /// The lower node holding the voxel `ijk` (any integers; `None` outside the `i32` range,
    /// in a tile or outside the root's entries).
    pub(crate) fn lower_at(&self, ijk: [i64; 3]) -> Option<u32> {
        let o = ijk.map(|c| c.div_euclid(128) * 128);
        match self.block_at(o, 2) {
            Neighbour::Lower(l) => Some(l),
            _ => None,
        }
    }

    /// This tree's topology cut down to the lower nodes `keep` (indices, any order, repeats
    /// allowed; out of range ones are ignored): every leaf of a kept node is present and
    /// unloaded, no bounds are computed. See the module docs for what the region reads
    /// outside them.
    pub(crate) fn region(&self, keep: &[u32]) -> (Tree, RegionIndex) {
        let mut kept: Vec<u32> = keep
            .iter()
            .copied()
            .filter(|&l| (l as usize) < self.lowers.len())
            .collect();
        kept.sort_unstable();
        kept.dedup();
        let bg = self.background.to_bits();
        // Sized exactly (a growing vector would hold up to twice its leaves for a moment).
        let leaves: usize = kept
            .iter()
            .map(|&l| {
                let n = &self.lowers[l as usize];
                n.child_mask
                    .iter()
                    .map(|w| w.count_ones() as usize)
                    .sum::<usize>()
            })
            .sum();
        let mut index = RegionIndex {
            lowers: Vec::with_capacity(kept.len()),
            leaves: Vec::with_capacity(leaves),
        };
        let mut out = Tree {
            background: self.background,
            bounds: Bounds::UNKNOWN,
            lowers: Vec::with_capacity(kept.len()),
            leaves: Vec::with_capacity(leaves),
            ..Tree::default()
        };
        for e in &self.root {
            let u = match e.slot {
                RootSlot::Tile { .. } => {
                    out.root.push(*e);
                    continue;
                }
                RootSlot::Child(u) => u as usize,
            };
            let upper = &self.uppers[u];
            let mut copy: Option<Internal> = None;
            for (w, &word) in upper.child_mask.iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    let s = w * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let l = upper.slots[s];
                    let node = copy.get_or_insert_with(|| Internal {
                        origin: upper.origin,
                        child_mask: upper.child_mask.clone(),
                        value_mask: upper.value_mask.clone(),
                        slots: upper.slots.clone(),
                        bounds: Bounds::UNKNOWN,
                        halo: Bounds::UNKNOWN,
                        tile_halo: Box::new([]),
                        halo_exceptions: Box::new([]),
                    });
                    if kept.binary_search(&l).is_err() {
                        node.child_mask[w] &= !(1u64 << (s & 63));
                        node.value_mask[w] &= !(1u64 << (s & 63));
                        node.slots[s] = bg;
                        continue;
                    }
                    node.slots[s] = out.lowers.len() as u32;
                    index.lowers.push((l, out.lowers.len() as u32));
                    out.lowers
                        .push(self.cut_lower(l, &mut out.leaves, &mut index.leaves));
                }
            }
            if let Some(node) = copy.filter(|n| n.child_mask.iter().any(|&w| w != 0)) {
                out.root.push(RootEntry {
                    origin: e.origin,
                    slot: RootSlot::Child(out.uppers.len() as u32),
                });
                out.uppers.push(node);
            }
        }
        index.lowers.sort_unstable();
        index.leaves.sort_unstable();
        (out, index)
    }

    /// A copy of lower node `l` whose children are appended to `leaves` (unloaded), their
    /// `(tree, region)` indices to `ids`.
    fn cut_lower(&self, l: u32, leaves: &mut Vec<Leaf>, ids: &mut Vec<(u32, u32)>) -> Internal {
        let n = &self.lowers[l as usize];
        let mut slots = n.slots.clone();
        for (w, &word) in n.child_mask.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let s = w * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let leaf = &self.leaves[n.slots[s] as usize];
                ids.push((n.slots[s], leaves.len() as u32));
                slots[s] = leaves.len() as u32;
                leaves.push(Leaf {
                    origin: leaf.origin,
                    value_mask: leaf.value_mask,
                    bounds: Bounds::UNKNOWN,
                    halo: Bounds::UNKNOWN,
                    data: UNLOADED,
                });
            }
        }
        Internal {
            origin: n.origin,
            child_mask: n.child_mask.clone(),
            value_mask: n.value_mask.clone(),
            slots,
            bounds: Bounds::UNKNOWN,
            halo: Bounds::UNKNOWN,
            tile_halo: Box::new([]),
            halo_exceptions: Box::new([]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    /// A tree with leaves in three lower nodes of two upper nodes, lower-node tiles and a
    /// non-zero background.
    fn tree() -> Tree {
        let mut b = TreeBuilder::new(0.25);
        let mut x = 99u64;
        let mut rnd = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for base in [[0, 0, 0], [128, 0, 0], [0, 130, 0], [4096, 0, 0]] {
            for _ in 0..400 {
                let p = [0, 1, 2].map(|a| base[a] + (rnd() % 140) as i32);
                b.set(p, (rnd() % 1000) as f32 / 100.0);
            }
        }
        b.tile([64, 64, 64], 3, 7.0).tile([4096 + 8, 8, 8], 3, 2.0);
        b.build()
    }

    #[test]
    fn a_region_reads_as_the_tree_inside_its_kept_lower_nodes() {
        let t = tree();
        assert!(t.lowers.len() >= 5, "{}", t.lowers.len());
        let keep = [1u32, 3, 1, 99];
        let (mut r, index) = t.region(&keep);
        assert_eq!(r.lowers.len(), 2);
        // Load every kept leaf with the tree's values.
        r.values = vec![[0.0; 512]; r.leaves.len()];
        for &(l, at) in &index.leaves {
            r.leaves[at as usize].data = at;
            r.values[at as usize] = *t.leaf_values(l);
        }
        r.compute_bounds();
        for &l in &[1u32, 3] {
            let n = &t.lowers[l as usize];
            let rl = index.lower(l).unwrap();
            assert_eq!(r.lowers[rl as usize].origin, n.origin);
            assert_eq!(r.lowers[rl as usize].bounds, n.bounds);
            for d in (0..128).step_by(3) {
                for e in (0..128).step_by(5) {
                    for f in (0..128).step_by(7) {
                        let p = [n.origin[0] + d, n.origin[1] + e, n.origin[2] + f];
                        assert_eq!(r.value(p).to_bits(), t.value(p).to_bits(), "{p:?}");
                        assert_eq!(r.is_active(p), t.is_active(p), "{p:?}");
                    }
                }
            }
            for s in 0..4096 {
                if n.has_child(s) {
                    let leaf = index.leaf(n.slots[s]).unwrap();
                    assert_eq!(r.lowers[rl as usize].slots[s], leaf);
                    assert_eq!(
                        r.leaves[leaf as usize].bounds,
                        t.leaves[n.slots[s] as usize].bounds
                    );
                }
            }
        }
        // Everything else reads the background (no extinction above lower nodes here).
        for l in [0u32, 2, 4] {
            if let Some(n) = t.lowers.get(l as usize) {
                assert_eq!(index.lower(l), None);
                assert_eq!(r.value(n.origin), t.background);
                assert_eq!(r.lower_at(n.origin.map(i64::from)), None);
            }
        }
        assert_eq!(
            r.lower_at(t.lowers[3].origin.map(|c| i64::from(c) + 127)),
            index.lower(3)
        );
    }

    #[test]
    fn a_region_of_every_lower_node_is_the_tree() {
        let t = tree();
        let all: Vec<u32> = (0..t.lowers.len() as u32).collect();
        let (r, index) = t.region(&all);
        assert_eq!(r.root, t.root);
        assert_eq!(
            (r.lowers.len(), r.leaves.len()),
            (t.lowers.len(), t.leaves.len())
        );
        for (l, b) in t.lowers.iter().enumerate() {
            let a = &r.lowers[index.lower(l as u32).unwrap() as usize];
            assert_eq!((a.origin, &a.child_mask), (b.origin, &b.child_mask));
            for s in 0..4096 {
                if b.has_child(s) {
                    assert_eq!(Some(a.slots[s]), index.leaf(b.slots[s]));
                } else {
                    assert_eq!(a.slots[s], b.slots[s]);
                }
            }
        }
        for (l, leaf) in t.leaves.iter().enumerate() {
            let at = index.leaf(l as u32).unwrap() as usize;
            assert_eq!(r.leaves[at].origin, leaf.origin);
        }
        let (empty, index) = t.region(&[]);
        assert!(empty.uppers.is_empty() && empty.leaves.is_empty());
        assert_eq!(index.leaf(0), None);
    }
}
