//! [`VelocityField`]: a vec3 grid's three components as scalar trees, read at world points
//! the way OpenVDB's samplers read them: `BoxSampler` (trilinear at the index point `u`) for a
//! cell-centred grid, `StaggeredBoxSampler` for a staggered (MAC) grid, whose component `k` is
//! stored on the face `u - e_k / 2` of voxel `u` and so is read trilinearly at `u + e_k / 2`.
//! Vectors are in world units per second, or in the grid's index space when its metadata says
//! `is_local_space` (then `v_world = L v_index`, `L` the linear part of its world-from-index
//! map, as OpenVDB transforms contravariant vectors).

use crate::error::{Error, Result};
use crate::tree::{Accessor, Tree};
use glam::{DAffine3, DMat3, DVec3};
use std::collections::HashMap;

/// A velocity grid ready to be read at world points; valid by construction
/// ([`VelocityField::new`]): finite invertible map, non-finite components set to 0 and counted.
#[derive(Debug, Clone)]
pub struct VelocityField {
    name: String,
    components: [Tree; 3],
    world_from_index: DAffine3,
    index_from_world: DAffine3,
    /// Index-space (or world-space) vector to world vector.
    to_world: DMat3,
    local_space: bool,
    staggered: bool,
    /// Components that were NaN or infinite, set to 0.
    non_finite: u64,
    /// Per `8^3` block of the grid's index space holding a leaf: the largest `|v_k|` per
    /// component over its voxels.
    leaf_max: HashMap<[i32; 3], [f32; 3]>,
    /// The largest `|v|` anywhere (every voxel, tile and the background), in world units.
    speed_max: f64,
}

fn set_finite(v: &mut f32, bad: &mut u64) {
    if !v.is_finite() {
        *v = 0.0;
        *bad += 1;
    }
}

/// Set the non-finite values of `tree` (background, tiles, leaves) to 0, counting them (the
/// bounds recomputed when any changed); with the largest `|value|` outside the leaves.
fn sanitise(tree: &mut Tree) -> (u64, f32) {
    let (mut bad, mut tiles) = (0, 0f32);
    tree.tile_values_mut(|v| {
        set_finite(v, &mut bad);
        tiles = tiles.max(v.abs());
    });
    for leaf in &mut tree.values {
        for v in leaf.iter_mut() {
            set_finite(v, &mut bad);
        }
    }
    if bad > 0 && !tree.shell {
        tree.compute_bounds();
    }
    (bad, tiles)
}

impl VelocityField {
    /// The field of grid `name` with components `components` (x, y, z: scalar trees of one
    /// topology), index-to-world map `world_from_index` (3x4 rows, column vectors), stored on
    /// faces when `staggered`, in index space when `local_space`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `velocity`) for components of different topologies, a
    /// partial tree, or a map that is not finite and invertible.
    pub fn new(
        name: String,
        components: [Tree; 3],
        world_from_index: [[f64; 4]; 3],
        staggered: bool,
        local_space: bool,
    ) -> Result<Self> {
        let bad = |reason: String| Error::InvalidArgument {
            name: "velocity".into(),
            reason: format!("grid '{}': {reason}", crate::text::escape(&name)),
        };
        let mut components = components;
        if components.iter().any(|t| !t.is_complete()) {
            return Err(bad("a velocity grid must be loaded whole".into()));
        }
        let leaves = components[0].leaves.len();
        if components.iter().any(|t| t.leaves.len() != leaves)
            || (0..leaves).any(|i| {
                let o = components[0].leaves[i].origin;
                components.iter().any(|t| t.leaves[i].origin != o)
            })
        {
            return Err(bad("its components do not share one topology".into()));
        }
        let m = world_from_index;
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err(bad(format!("non-finite map {m:?}")));
        }
        let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        let world_from_index = DAffine3 {
            matrix3: DMat3::from_cols(col(0), col(1), col(2)),
            translation: col(3),
        };
        let det = world_from_index.matrix3.determinant();
        let index_from_world = world_from_index.inverse();
        let invertible = det.is_finite() && det != 0.0;
        if !invertible
            || !index_from_world
                .matrix3
                .to_cols_array()
                .iter()
                .all(|v| v.is_finite())
        {
            return Err(bad("its map cannot be inverted".into()));
        }
        // Non-finite components zeroed; each component's largest magnitude anywhere.
        let (mut non_finite, mut most) = (0, [0f32; 3]);
        for (k, t) in components.iter_mut().enumerate() {
            let (bad, tiles) = sanitise(t);
            non_finite += bad;
            most[k] = tiles;
        }
        let mut leaf_max = HashMap::with_capacity(leaves);
        for i in 0..leaves {
            let m = [0, 1, 2].map(|k| {
                let b = components[k].leaves[i].bounds;
                b.min.abs().max(b.max.abs())
            });
            for k in 0..3 {
                most[k] = most[k].max(m[k]);
            }
            leaf_max.insert(components[0].leaves[i].origin, m);
        }
        let to_world = if local_space {
            world_from_index.matrix3
        } else {
            DMat3::IDENTITY
        };
        let speed_max = speed_of(&to_world, most);
        let f = Self {
            name,
            components,
            world_from_index,
            index_from_world,
            to_world,
            local_space,
            staggered,
            non_finite,
            leaf_max,
            speed_max,
        };
        Ok(f)
    }

    /// The same field in the frame `x` places its volume in: the map becomes `X M`, and
    /// world-space vectors turn with `X`'s linear part (index-space ones follow the map).
    #[must_use]
    pub fn placed(mut self, x: &crate::xform::Xform) -> Self {
        let a = x.affine();
        self.world_from_index = a * self.world_from_index;
        self.index_from_world = self.world_from_index.inverse();
        self.to_world = if self.local_space {
            self.world_from_index.matrix3
        } else {
            a.matrix3 * self.to_world
        };
        self.speed_max *= norm_bound(&a.matrix3);
        self
    }

    /// The grid's name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Whether the components are stored on faces (`class = staggered`).
    #[must_use]
    pub fn is_staggered(&self) -> bool {
        self.staggered
    }
    /// Components that were NaN or infinite (set to 0), over every voxel, tile and background.
    #[must_use]
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }
    /// The largest speed anywhere in the field (world units per second; a bound).
    #[must_use]
    pub fn speed_max(&self) -> f64 {
        self.speed_max
    }

    /// A reader of the field with its own cached accessors.
    #[must_use]
    pub fn lookup(&self) -> VelocityLookup<'_> {
        VelocityLookup {
            f: self,
            acc: [0, 1, 2].map(|k| Accessor::new(&self.components[k])),
        }
    }

    /// A bound on the speed the field gives anywhere in the world box `[lo, hi]`: the
    /// components' magnitudes over every voxel the interpolation reads there (the box in the
    /// grid's index space, grown by the trilinear stencil and the staggered half voxel).
    #[must_use]
    pub fn speed_bound(&self, lo: DVec3, hi: DVec3) -> f64 {
        let (mut a, mut b) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for n in 0..8 {
            let c = DVec3::new(
                if n & 1 == 0 { lo.x } else { hi.x },
                if n & 2 == 0 { lo.y } else { hi.y },
                if n & 4 == 0 { lo.z } else { hi.z },
            );
            let u = self.index_from_world.transform_point3(c);
            a = a.min(u);
            b = b.max(u);
        }
        let block = |v: f64, grow: f64| (((v + grow).floor() as i64) >> 3) as i32;
        let lo_b = [a.x, a.y, a.z].map(|v| block(v, -1.0));
        let hi_b = [b.x, b.y, b.z].map(|v| block(v, 2.0));
        let count: i64 = (0..3)
            .map(|k| i64::from(hi_b[k]) - i64::from(lo_b[k]) + 1)
            .product();
        if count > 4096 {
            return self.speed_max;
        }
        let mut m = [0f32; 3];
        for x in lo_b[0]..=hi_b[0] {
            for y in lo_b[1]..=hi_b[1] {
                for z in lo_b[2]..=hi_b[2] {
                    let o = [x << 3, y << 3, z << 3];
                    let v = match self.leaf_max.get(&o) {
                        Some(v) => *v,
                        None => [0, 1, 2].map(|k| self.components[k].value(o).abs()),
                    };
                    for k in 0..3 {
                        m[k] = m[k].max(v[k]);
                    }
                }
            }
        }
        speed_of(&self.to_world, m).min(self.speed_max)
    }
}

/// A bound on `|v|` in world units from bounds `m` on each component's magnitude, the
/// vectors turned to world by `to_world`: `|L m|_2 <= |L|_2 |m|_2` ([`norm_bound`]).
fn speed_of(to_world: &DMat3, m: [f32; 3]) -> f64 {
    let m = DVec3::new(m[0].into(), m[1].into(), m[2].into());
    norm_bound(to_world) * m.length()
}

/// A bound on the spectral norm: `|A|_2 <= sqrt(|A|_1 |A|_inf)` (largest column and row sums
/// of magnitudes); exact for the identity and for scalings.
fn norm_bound(m: &DMat3) -> f64 {
    let a = m.to_cols_array_2d();
    let col = (0..3).map(|c| a[c].iter().map(|v| v.abs()).sum::<f64>());
    let row = (0..3).map(|r| (0..3).map(|c| a[c][r].abs()).sum::<f64>());
    (col.fold(0.0, f64::max) * row.fold(0.0, f64::max)).sqrt()
}

/// A [`VelocityField`] read at world points through cached accessors (one per thread or ray).
#[derive(Debug, Clone)]
pub struct VelocityLookup<'f> {
    f: &'f VelocityField,
    acc: [Accessor<'f>; 3],
}

impl VelocityLookup<'_> {
    /// The velocity at world point `p` (world units per second).
    #[inline]
    pub fn at(&mut self, p: DVec3) -> DVec3 {
        let u = self.f.index_from_world.transform_point3(p).to_array();
        let half = if self.f.staggered { 0.5 } else { 0.0 };
        let c = [0, 1, 2].map(|k| {
            let mut q = u;
            q[k] += half;
            f64::from(self.acc[k].trilinear(q))
        });
        self.f.to_world * DVec3::from_array(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    fn identity() -> [[f64; 4]; 3] {
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ]
    }

    fn field(v: [f32; 3], staggered: bool) -> VelocityField {
        let comps = [0, 1, 2].map(|k| {
            let mut b = TreeBuilder::new(0.0);
            for x in 0..16 {
                for y in 0..16 {
                    for z in 0..16 {
                        b.set([x, y, z], v[k] * x as f32);
                    }
                }
            }
            b.build()
        });
        VelocityField::new("v".into(), comps, identity(), staggered, false).unwrap()
    }

    #[test]
    fn cell_centred_reads_trilinear_and_staggered_reads_half_a_voxel_on() {
        let f = field([1.0, 2.0, 0.0], false);
        let v = f.lookup().at(DVec3::new(3.25, 4.0, 4.0));
        assert!((v - DVec3::new(3.25, 6.5, 0.0)).length() < 1e-6, "{v}");
        let s = field([1.0, 2.0, 0.0], true);
        // Component x at u + (0.5, 0, 0), component y at u + (0, 0.5, 0): y's x stays 3.25.
        let v = s.lookup().at(DVec3::new(3.25, 4.0, 4.0));
        assert!((v - DVec3::new(3.75, 6.5, 0.0)).length() < 1e-6, "{v}");
    }

    #[test]
    fn the_speed_bound_holds_every_lookup_in_its_box() {
        let f = field([1.0, -2.0, 0.5], true);
        let (lo, hi) = (DVec3::new(2.0, 3.0, 1.0), DVec3::new(6.0, 7.0, 5.0));
        let bound = f.speed_bound(lo, hi);
        let mut l = f.lookup();
        for n in 0..1000 {
            let t = DVec3::new(
                (n % 10) as f64 / 9.0,
                ((n / 10) % 10) as f64 / 9.0,
                (n / 100) as f64 / 9.0,
            );
            let p = lo + (hi - lo) * t;
            assert!(l.at(p).length() <= bound + 1e-9);
        }
        assert!(bound <= f.speed_max());
    }

    #[test]
    fn non_finite_components_are_zeroed_and_counted() {
        let mut b = TreeBuilder::new(0.0);
        b.set([1, 1, 1], f32::NAN).set([2, 1, 1], f32::INFINITY);
        let t = b.build();
        let f = VelocityField::new(
            "v".into(),
            [t.clone(), t.clone(), t],
            identity(),
            false,
            false,
        )
        .unwrap();
        assert_eq!(f.non_finite(), 6);
        assert_eq!(f.lookup().at(DVec3::new(1.0, 1.0, 1.0)), DVec3::ZERO);
    }
}
