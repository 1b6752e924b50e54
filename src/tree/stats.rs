//! Whole-tree statistics as OpenVDB reports them: active voxel count (tiles count as the voxels
//! they cover), active bounding box, value range and sum of active values, NaN/Inf counts.

use super::{bit, Bounds, Internal, Leaf, RootSlot, Tree};
use rayon::prelude::*;
use serde::Serialize;

/// Leaves per statistics chunk (a fixed size, so sums do not depend on the thread count).
pub(crate) const LEAF_CHUNK: usize = 4096;

/// Statistics over the active values of a tree.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TreeStats {
    /// Active voxels, tiles counted as the voxels they cover (OpenVDB `activeVoxelCount`).
    pub active_voxels: u64,
    /// Active voxels stored in leaves.
    pub active_leaf_voxels: u64,
    /// Number of leaves.
    pub leaf_count: u64,
    /// Active root-level tiles (4096^3 voxels each).
    pub root_tiles: u64,
    /// Active tiles in upper nodes (128^3 voxels each).
    pub upper_tiles: u64,
    /// Active tiles in lower nodes (8^3 voxels each).
    pub lower_tiles: u64,
    /// Inclusive index bounding box of the active voxels, `None` if there are none.
    pub index_bbox: Option<[[i32; 3]; 2]>,
    /// Smallest and largest active value (NaN excluded, ±Inf included).
    pub value_range: Option<(f32, f32)>,
    /// Sum of finite active values in f64, tiles weighted by voxel count.
    pub value_sum: f64,
    /// Active NaN voxels (tiles weighted).
    pub nan_count: u64,
    /// Active ±Inf voxels (tiles weighted).
    pub inf_count: u64,
}

#[derive(Debug, Default)]
struct Acc {
    s: TreeStats,
    range: Bounds,
}

impl Acc {
    fn add(&mut self, v: f32, n: u64) {
        if v.is_nan() {
            self.s.nan_count += n;
            return;
        }
        self.range.include(v);
        if v.is_infinite() {
            self.s.inf_count += n;
        } else {
            self.s.value_sum += f64::from(v) * n as f64;
        }
    }
    fn bbox(&mut self, lo: [i32; 3], hi: [i32; 3]) {
        let b = self.s.index_bbox.get_or_insert([lo, hi]);
        for a in 0..3 {
            b[0][a] = b[0][a].min(lo[a]);
            b[1][a] = b[1][a].max(hi[a]);
        }
    }
    fn tile(&mut self, origin: [i32; 3], log2: u32, v: f32) {
        let n = 1u64 << (3 * log2);
        self.s.active_voxels += n;
        self.add(v, n);
        let d = (1i32 << log2) - 1;
        self.bbox(origin, origin.map(|c| c.saturating_add(d)));
    }
    fn leaf(&mut self, leaf: &Leaf, values: &[f32; 512]) {
        let mut lo = [i32::MAX; 3];
        let mut hi = [i32::MIN; 3];
        for (w, &word) in leaf.value_mask.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let n = w * 64 + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                self.add(values[n], 1);
                let l = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
                for a in 0..3 {
                    lo[a] = lo[a].min(leaf.origin[a] + l[a]);
                    hi[a] = hi[a].max(leaf.origin[a] + l[a]);
                }
                self.s.active_leaf_voxels += 1;
            }
        }
        if lo[0] <= hi[0] {
            self.bbox(lo, hi);
        }
    }
    /// Fold in the leaf statistics of another part of the tree.
    fn merge(&mut self, o: Self) {
        self.s.nan_count += o.s.nan_count;
        self.s.inf_count += o.s.inf_count;
        self.s.value_sum += o.s.value_sum;
        self.s.active_leaf_voxels += o.s.active_leaf_voxels;
        self.range.union(o.range);
        if let Some([lo, hi]) = o.s.index_bbox {
            self.bbox(lo, hi);
        }
    }
    fn internal(&mut self, node: &Internal, side_log2: u32, child_log2: u32) -> u64 {
        let mut tiles = 0;
        for n in 0..node.slots.len() {
            if !node.has_child(n) && bit(&node.value_mask, n) {
                tiles += 1;
                let s = side_log2;
                let local = [n >> (2 * s), (n >> s) & ((1 << s) - 1), n & ((1 << s) - 1)];
                let o = [0, 1, 2].map(|a| node.origin[a] + ((local[a] as i32) << child_log2));
                self.tile(o, child_log2, node.tile_value(n));
            }
        }
        tiles
    }
}

impl Tree {
    /// Compute [`TreeStats`] in one pass over the nodes.
    #[must_use]
    pub fn stats(&self) -> TreeStats {
        let loaded = |range: std::ops::Range<usize>, f: &mut dyn FnMut(&Leaf, &[f32; 512])| {
            for leaf in &self.leaves[range] {
                f(leaf, self.values_of(leaf));
            }
            Ok::<(), std::convert::Infallible>(())
        };
        match self.stats_by(loaded) {
            Ok(s) => s,
            Err(never) => match never {},
        }
    }

    /// [`Tree::stats`] with the leaf values handed out by `chunk`, which calls its callback
    /// with every leaf of a range of leaf indices and that leaf's values (chunks of
    /// `LEAF_CHUNK` leaves, in parallel): a lazily opened grid streams them from the file
    /// without holding the decoded grid.
    ///
    /// # Errors
    /// What `chunk` returns.
    pub(crate) fn stats_by<E: Send>(
        &self,
        chunk: impl Fn(std::ops::Range<usize>, &mut dyn FnMut(&Leaf, &[f32; 512])) -> Result<(), E>
            + Sync,
    ) -> Result<TreeStats, E> {
        let mut acc = Acc {
            range: Bounds::EMPTY,
            ..Acc::default()
        };
        for e in &self.root {
            if let RootSlot::Tile {
                value,
                active: true,
            } = e.slot
            {
                acc.s.root_tiles += 1;
                acc.tile(e.origin, 12, value);
            }
        }
        for u in &self.uppers {
            acc.s.upper_tiles += acc.internal(u, 5, 7);
        }
        for l in &self.lowers {
            acc.s.lower_tiles += acc.internal(l, 4, 3);
        }
        acc.s.leaf_count = self.leaves.len() as u64;
        // Leaves in fixed chunks, in parallel; the chunks' sums are added in order, so the
        // result does not depend on the thread count (nor on where the values come from).
        let parts: Vec<Result<Acc, E>> = (0..self.leaves.len().div_ceil(LEAF_CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut acc = Acc {
                    range: Bounds::EMPTY,
                    ..Acc::default()
                };
                let range = c * LEAF_CHUNK..((c + 1) * LEAF_CHUNK).min(self.leaves.len());
                chunk(range, &mut |leaf, values| acc.leaf(leaf, values))?;
                Ok(acc)
            })
            .collect();
        for p in parts {
            acc.merge(p?);
        }
        acc.s.active_voxels += acc.s.active_leaf_voxels;
        acc.s.value_range = (!acc.range.is_empty()).then_some((acc.range.min, acc.range.max));
        Ok(acc.s)
    }
}
