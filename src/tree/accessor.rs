//! A cached read accessor: remembers the last leaf, lower and upper node it visited and starts
//! each lookup from the deepest cached node containing the voxel, as NanoVDB's ReadAccessor does.
//! Coherent lookups (along a ray) almost always hit the leaf cache. It takes `&mut self`, so each
//! thread owns its own.

use super::{leaf_offset, node_origin, Found, RootSlot, Tree, LEAF_LOG2, LOWER_LOG2, UPPER_LOG2};

const NONE: u32 = u32::MAX;

/// Per-thread cached accessor over a [`Tree`]. Sampling follows OpenVDB: nearest is
/// `PointSampler` (voxel `round(p)`), trilinear is `BoxSampler` (the 8 voxels around `p`).
#[derive(Debug, Clone)]
pub struct Accessor<'t> {
    tree: &'t Tree,
    leaf_key: [i32; 3],
    leaf: u32,
    /// The cached leaf's values.
    leaf_values: &'t [f32; 512],
    lower_key: [i32; 3],
    lower: u32,
    upper_key: [i32; 3],
    upper: u32,
    lookups: u64,
}

impl<'t> Accessor<'t> {
    /// A fresh accessor with an empty cache.
    #[must_use]
    pub fn new(tree: &'t Tree) -> Self {
        Self {
            tree,
            leaf_key: [0; 3],
            leaf: NONE,
            leaf_values: &super::UNLOADED_VALUES,
            lower_key: [0; 3],
            lower: NONE,
            upper_key: [0; 3],
            upper: NONE,
            lookups: 0,
        }
    }

    /// The tree it reads.
    #[must_use]
    pub fn tree(&self) -> &'t Tree {
        self.tree
    }

    /// Number of voxel value reads so far (the deterministic cost measure).
    #[must_use]
    pub fn lookups(&self) -> u64 {
        self.lookups
    }

    /// The value at voxel `ijk`, active or not (OpenVDB `getValue`).
    #[inline]
    pub fn value(&mut self, ijk: [i32; 3]) -> f32 {
        self.lookups += 1;
        if self.leaf != NONE && node_origin(ijk, LEAF_LOG2) == self.leaf_key {
            return self.leaf_values[leaf_offset(ijk)];
        }
        let found = self.locate(ijk);
        self.tree.value_of(found)
    }

    /// The value at voxel `ijk` of the unbounded index space: voxels outside the `i32` range a
    /// VDB tree can hold are background (a trilinear lookup at the edge of the range reads one
    /// voxel beyond it; wrapping or clamping the coordinate would read a voxel at the far end
    /// of the range, or the edge voxel twice).
    #[inline]
    pub fn value_at(&mut self, ijk: [i64; 3]) -> f32 {
        match to_voxel(ijk) {
            Some(v) => self.value(v),
            None => {
                self.lookups += 1;
                self.tree.background
            }
        }
    }

    /// [`Accessor::block`] for a voxel of the unbounded index space (background outside the
    /// `i32` range).
    #[inline]
    pub(crate) fn block_at(&mut self, ijk: [i64; 3]) -> Block<'t> {
        match to_voxel(ijk) {
            Some(v) => self.block(v),
            None => Block::Const(self.tree.background),
        }
    }

    /// The 8^3 block holding voxel `ijk`: a leaf's values, or the one value of the tile or
    /// background covering it. Not counted as a lookup (the caller counts its reads).
    #[inline]
    pub(crate) fn block(&mut self, ijk: [i32; 3]) -> Block<'t> {
        if self.leaf != NONE && node_origin(ijk, LEAF_LOG2) == self.leaf_key {
            return Block::Leaf(self.leaf_values);
        }
        match self.locate(ijk) {
            Found::Voxel { node, .. } => Block::Leaf(self.tree.leaf_values(node)),
            f => Block::Const(self.tree.value_of(f)),
        }
    }

    /// Descend to `ijk` from the deepest cached node that holds it, updating the caches.
    #[inline]
    fn locate(&mut self, ijk: [i32; 3]) -> Found {
        let found = if self.lower != NONE && node_origin(ijk, LOWER_LOG2) == self.lower_key {
            self.tree.find_in_lower(self.lower, ijk)
        } else if self.upper != NONE && node_origin(ijk, UPPER_LOG2) == self.upper_key {
            self.descend_upper(self.upper, ijk)
        } else {
            match self.tree.root_find(ijk) {
                None => Found::Background,
                Some(r) => match self.tree.root[r].slot {
                    RootSlot::Tile { .. } => Found::RootTile(r),
                    RootSlot::Child(u) => {
                        self.upper = u;
                        self.upper_key = node_origin(ijk, UPPER_LOG2);
                        self.descend_upper(u, ijk)
                    }
                },
            }
        };
        if let Found::Voxel { node, .. } = found {
            self.leaf = node;
            self.leaf_values = self.tree.leaf_values(node);
            self.leaf_key = node_origin(ijk, LEAF_LOG2);
        }
        found
    }

    fn descend_upper(&mut self, upper: u32, ijk: [i32; 3]) -> Found {
        let f = self.tree.find_in_upper(upper, ijk);
        if !matches!(f, Found::UpperTile { .. }) {
            let node = &self.tree.uppers[upper as usize];
            self.lower = node.slots[super::upper_offset(ijk)];
            self.lower_key = node_origin(ijk, LOWER_LOG2);
        }
        f
    }

    /// Nearest-neighbour sample at index-space point `p`: the voxel `round(p)`, ties away from
    /// zero, as OpenVDB's `PointSampler` (`::round`).
    #[inline]
    pub fn nearest(&mut self, p: [f64; 3]) -> f32 {
        self.value_at(p.map(|c| crate::math::floor_i64(c.round())))
    }

    /// Trilinear sample at index-space point `p` (OpenVDB `BoxSampler`): interpolates the 8
    /// voxels `floor(p) + {0,1}^3`, z first, then y, then x, as OpenVDB does.
    #[inline]
    pub fn trilinear(&mut self, p: [f64; 3]) -> f32 {
        let w = p.map(crate::math::floor_i64);
        let u = [0, 1, 2].map(|a| p[a] - w[a] as f64);
        let mut v = [[[0f32; 2]; 2]; 2];
        let inner = to_voxel(w).filter(|i| i.iter().all(|&c| c & 7 != 7));
        if let Some(i) = inner {
            // All 8 voxels in one 8^3 block: one cached descent, then direct reads.
            self.lookups += 8;
            let b = self.block(i);
            let o = leaf_offset(i);
            for (dx, vx) in v.iter_mut().enumerate() {
                for (dy, vy) in vx.iter_mut().enumerate() {
                    for (dz, vz) in vy.iter_mut().enumerate() {
                        *vz = b.get(o + (dx << 6) + (dy << 3) + dz);
                    }
                }
            }
        } else {
            for (dx, vx) in v.iter_mut().enumerate() {
                for (dy, vy) in vx.iter_mut().enumerate() {
                    for (dz, vz) in vy.iter_mut().enumerate() {
                        *vz = self.value_at([w[0] + dx as i64, w[1] + dy as i64, w[2] + dz as i64]);
                    }
                }
            }
        }
        interpolate(&v, u)
    }
}

/// OpenVDB's `BoxSampler` blend of the 8 voxels `v[dx][dy][dz]` around a point at fractions
/// `u` of its cell: z first, then y, then x, each `a + (b - a) w` in f64 rounded to f32, with
/// `a` kept where `a == b` or `w == 0` (so infinite values give `inf`, not `inf * 0 = NaN`, at
/// zero weight) and `b` where `w == 1`. Every trilinear read of a tree's values goes through
/// it ([`Accessor::trilinear`], [`super::Window::trilinear`]), so they agree bit for bit.
#[inline(always)]
pub(crate) fn interpolate(v: &[[[f32; 2]; 2]; 2], u: [f64; 3]) -> f32 {
    let lerp = |a: f32, b: f32, w: f64| {
        if a == b || w == 0.0 {
            a
        } else if w == 1.0 {
            b
        } else {
            (f64::from(a) + (f64::from(b) - f64::from(a)) * w) as f32
        }
    };
    let y0 = lerp(
        lerp(v[0][0][0], v[0][0][1], u[2]),
        lerp(v[0][1][0], v[0][1][1], u[2]),
        u[1],
    );
    let y1 = lerp(
        lerp(v[1][0][0], v[1][0][1], u[2]),
        lerp(v[1][1][0], v[1][1][1], u[2]),
        u[1],
    );
    lerp(y0, y1, u[0])
}

/// The values of one 8^3 block of voxels: a leaf's, or a single value (tile or background).
#[derive(Debug, Clone, Copy)]
pub(crate) enum Block<'t> {
    /// A leaf's 512 values, indexed by [`leaf_offset`].
    Leaf(&'t [f32; 512]),
    /// Every voxel of the block has this value.
    Const(f32),
}

impl Block<'_> {
    /// The value at leaf offset `n` (`n < 512`).
    #[inline]
    pub(crate) fn get(self, n: usize) -> f32 {
        match self {
            Self::Leaf(v) => v[n],
            Self::Const(c) => c,
        }
    }
}

/// `ijk` as a voxel coordinate of a VDB tree, if it is inside the `i32` range.
#[inline]
fn to_voxel(ijk: [i64; 3]) -> Option<[i32; 3]> {
    Some([
        i32::try_from(ijk[0]).ok()?,
        i32::try_from(ijk[1]).ok()?,
        i32::try_from(ijk[2]).ok()?,
    ])
}
