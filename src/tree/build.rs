//! Building a [`Tree`] in memory: analytic test media, procedural samples, and any caller that
//! has values but no file. Voxels set here are active; everything else is the background.

use super::{
    leaf_offset, lower_offset, node_origin, upper_offset, Bounds, Internal, Leaf, RootEntry,
    RootSlot, Tree, LEAF_LOG2, LOWER_LOG2, UPPER_LOG2,
};
use std::collections::BTreeMap;

/// A leaf under construction: active mask and values.
type LeafData = Box<([u64; 8], [f32; 512])>;

/// Accumulates voxels and tiles, then builds the flat tree.
#[derive(Debug, Clone, Default)]
pub struct TreeBuilder {
    background: f32,
    leaves: BTreeMap<[i32; 3], LeafData>,
    /// (origin, log2 edge) -> value; log2 3 = 8^3 tile, 7 = 128^3 tile, 12 = root tile.
    tiles: Vec<([i32; 3], u32, f32)>,
}

impl TreeBuilder {
    /// An empty tree with the given background.
    #[must_use]
    pub fn new(background: f32) -> Self {
        Self {
            background,
            ..Self::default()
        }
    }

    /// Set voxel `ijk` to `value` (active).
    pub fn set(&mut self, ijk: [i32; 3], value: f32) -> &mut Self {
        let bg = self.background;
        let leaf = self
            .leaves
            .entry(node_origin(ijk, LEAF_LOG2))
            .or_insert_with(|| Box::new(([0; 8], [bg; 512])));
        let n = leaf_offset(ijk);
        leaf.0[n >> 6] |= 1 << (n & 63);
        leaf.1[n] = value;
        self
    }

    /// An active constant tile of edge `2^log2` (3, 7 or 12) containing `ijk`. A voxel set
    /// inside a tile replaces the whole tile by a node (the tile's other voxels become
    /// background), and tiles must not overlap each other.
    pub fn tile(&mut self, ijk: [i32; 3], log2: u32, value: f32) -> &mut Self {
        self.tiles.push((node_origin(ijk, log2), log2, value));
        self
    }

    /// Build the flat tree with bounds and halos.
    #[must_use]
    pub fn build(&self) -> Tree {
        let bg = self.background;
        let mut tree = Tree {
            background: bg,
            ..Tree::default()
        };
        let mut root: BTreeMap<[i32; 3], RootSlot> = BTreeMap::new();
        let mut uppers: BTreeMap<[i32; 3], Internal> = BTreeMap::new();
        let mut lowers: BTreeMap<[i32; 3], Internal> = BTreeMap::new();
        let blank = |origin, n: usize| {
            Internal::unbounded(
                origin,
                vec![0; n / 64].into_boxed_slice(),
                vec![0; n / 64].into_boxed_slice(),
                vec![bg.to_bits(); n].into_boxed_slice(),
            )
        };
        let set_bit = |m: &mut [u64], n: usize| m[n >> 6] |= 1 << (n & 63);
        for &(o, log2, v) in &self.tiles {
            match log2 {
                12 => {
                    root.insert(
                        o,
                        RootSlot::Tile {
                            value: v,
                            active: true,
                        },
                    );
                }
                7 => {
                    let up = uppers
                        .entry(node_origin(o, UPPER_LOG2))
                        .or_insert_with(|| blank(node_origin(o, UPPER_LOG2), 32768));
                    let s = upper_offset(o);
                    up.slots[s] = v.to_bits();
                    set_bit(&mut up.value_mask, s);
                }
                _ => {
                    let lo = lowers
                        .entry(node_origin(o, LOWER_LOG2))
                        .or_insert_with(|| blank(node_origin(o, LOWER_LOG2), 4096));
                    let s = lower_offset(o);
                    lo.slots[s] = v.to_bits();
                    set_bit(&mut lo.value_mask, s);
                }
            }
        }
        for (&o, leaf) in &self.leaves {
            let lo = lowers
                .entry(node_origin(o, LOWER_LOG2))
                .or_insert_with(|| blank(node_origin(o, LOWER_LOG2), 4096));
            let s = lower_offset(o);
            lo.slots[s] = tree.leaves.len() as u32;
            set_bit(&mut lo.child_mask, s);
            tree.leaves.push(Leaf {
                origin: o,
                value_mask: leaf.0,
                bounds: Bounds::EMPTY,
                halo: Bounds::EMPTY,
                data: tree.values.len() as u32,
            });
            tree.values.push(leaf.1);
        }
        for (o, mut lo) in lowers {
            let uo = node_origin(o, UPPER_LOG2);
            let up = uppers.entry(uo).or_insert_with(|| blank(uo, 32768));
            let s = upper_offset(o);
            lo.origin = o;
            up.slots[s] = tree.lowers.len() as u32;
            set_bit(&mut up.child_mask, s);
            tree.lowers.push(lo);
        }
        for (o, up) in uppers {
            root.insert(o, RootSlot::Child(tree.uppers.len() as u32));
            tree.uppers.push(up);
        }
        tree.root = root
            .into_iter()
            .map(|(origin, slot)| RootEntry { origin, slot })
            .collect();
        tree.compute_bounds();
        tree
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_tree_reads_back_voxels_tiles_and_background() {
        let mut b = TreeBuilder::new(0.25);
        b.set([1, 2, 3], 5.0).set([-9, 0, 200], 7.0);
        b.tile([128, 0, 0], 7, 2.0).tile([16, 16, 16], 3, 3.0);
        b.tile([-8192, 0, 0], 12, 9.0);
        let t = b.build();
        assert_eq!(t.value([1, 2, 3]), 5.0);
        assert_eq!(t.value([1, 2, 4]), 0.25);
        assert_eq!(t.value([-9, 0, 200]), 7.0);
        assert_eq!(t.value([200, 100, 5]), 2.0);
        assert_eq!(t.value([23, 23, 23]), 3.0);
        assert_eq!(t.value([-4097, 5, 5]), 9.0);
        assert_eq!(t.value([5000, 0, 0]), 0.25);
        let s = t.stats();
        assert_eq!(s.active_voxels, 2 + 128 * 128 * 128 + 512 + 4096u64.pow(3));
        assert_eq!(
            t.bounds,
            Bounds {
                min: 0.25,
                max: 9.0
            }
        );
    }
}
