//! [`VelocityField`]: a vec3 grid's three components as scalar trees, read at world points
//! the way OpenVDB's samplers read them: `BoxSampler` (trilinear at the index point `u`) for a
//! cell-centred grid, `StaggeredBoxSampler` for a staggered (MAC) grid, whose component `k` is
//! stored on the face `u - e_k / 2` of voxel `u` and so is read trilinearly at `u + e_k / 2`.
//! Vectors are in world units per second, or in the grid's index space when its metadata says
//! `is_local_space` (then `v_world = L v_index`, `L` the linear part of its world-from-index
//! map, as OpenVDB transforms contravariant vectors).

use crate::error::{Error, Result};
use crate::tree::{Accessor, Tree, Window};
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
    /// Per `8^3` block of the grid's index space holding a leaf: the smallest and largest
    /// `v_k` per component over its voxels.
    leaf_range: HashMap<[i32; 3], [[f32; 2]; 3]>,
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
        let mut leaf_range = HashMap::with_capacity(leaves);
        for i in 0..leaves {
            let r = [0, 1, 2].map(|k| {
                let b = components[k].leaves[i].bounds;
                [b.min, b.max]
            });
            for k in 0..3 {
                most[k] = most[k].max(r[k][0].abs().max(r[k][1].abs()));
            }
            leaf_range.insert(components[0].leaves[i].origin, r);
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
            leaf_range,
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

    /// Bytes the field holds: its three component trees and its per-leaf component ranges.
    #[must_use]
    pub fn memory_bytes(&self) -> u64 {
        let trees: u64 = self.components.iter().map(Tree::memory_bytes).sum();
        let per_leaf = std::mem::size_of::<([i32; 3], [[f32; 2]; 3])>() as u64 + 8;
        trees + self.leaf_range.capacity() as u64 * per_leaf
    }

    /// A reader of the field with its own cached accessors.
    #[must_use]
    pub fn lookup(&self) -> VelocityLookup<'_> {
        VelocityLookup {
            f: self,
            acc: [0, 1, 2].map(|k| Accessor::new(&self.components[k])),
            win: Default::default(),
        }
    }

    /// A bound on the speed the field gives anywhere in the world box `[lo, hi]`: the
    /// components' magnitudes over every voxel the interpolation reads there (the box in the
    /// grid's index space, grown by the trilinear stencil and the staggered half voxel).
    #[must_use]
    pub fn speed_bound(&self, lo: DVec3, hi: DVec3) -> f64 {
        let Some(r) = self.component_ranges(lo, hi) else {
            return self.speed_max;
        };
        let m = r.map(|[a, b]| a.abs().max(b.abs()));
        speed_of(&self.to_world, m).min(self.speed_max)
    }

    /// Bounds on each world component of the velocity anywhere in the world box `[lo, hi]`,
    /// `(smallest, largest)`: the stored components' ranges over every voxel the interpolation
    /// reads there ([`VelocityField::speed_bound`]'s), turned to world vectors by interval
    /// arithmetic; `[-speed_max, speed_max]` per axis for a box too large to scan.
    #[must_use]
    pub fn velocity_range(&self, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
        let Some(r) = self.component_ranges(lo, hi) else {
            return (DVec3::splat(-self.speed_max), DVec3::splat(self.speed_max));
        };
        let (mut a, mut b) = (DVec3::ZERO, DVec3::ZERO);
        for (k, [c0, c1]) in r.iter().enumerate() {
            let col = self.to_world.col(k);
            let (p, q) = (col * f64::from(*c0), col * f64::from(*c1));
            a += p.min(q);
            b += p.max(q);
        }
        let s = DVec3::splat(self.speed_max);
        (a.max(-s), b.min(s))
    }

    /// The smallest and largest stored value of each component over every voxel the
    /// interpolation reads in the world box `[lo, hi]` (trilinear stencil, staggered half
    /// voxel), from per-leaf ranges and tile values; `None` past 4096 blocks.
    fn component_ranges(&self, lo: DVec3, hi: DVec3) -> Option<[[f32; 2]; 3]> {
        let (a, b) = crate::math::mapped_box(&self.index_from_world, lo, hi);
        let block = |v: f64, grow: f64| (((v + grow).floor() as i64) >> 3) as i32;
        let lo_b = [a.x, a.y, a.z].map(|v| block(v, -1.0));
        let hi_b = [b.x, b.y, b.z].map(|v| block(v, 2.0));
        let count: i64 = (0..3)
            .map(|k| i64::from(hi_b[k]) - i64::from(lo_b[k]) + 1)
            .product();
        if count > 4096 {
            return None;
        }
        let mut m = [[f32::INFINITY, f32::NEG_INFINITY]; 3];
        for x in lo_b[0]..=hi_b[0] {
            for y in lo_b[1]..=hi_b[1] {
                for z in lo_b[2]..=hi_b[2] {
                    let o = [x << 3, y << 3, z << 3];
                    let v = match self.leaf_range.get(&o) {
                        Some(v) => *v,
                        None => [0, 1, 2].map(|k| {
                            let t = self.components[k].value(o);
                            [t, t]
                        }),
                    };
                    for k in 0..3 {
                        m[k] = [m[k][0].min(v[k][0]), m[k][1].max(v[k][1])];
                    }
                }
            }
        }
        Some(m)
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
    /// Each component's values around the points about to be read ([`VelocityLookup::cover`]);
    /// empty until then.
    win: [Window; 3],
}

impl VelocityLookup<'_> {
    /// The velocity at world point `p` (world units per second): component `k` is the
    /// trilinear sample of its tree at `u + e_k / 2` (staggered) or `u` (cell-centred), `u`
    /// the grid's index point of `p`, read from its window when [`VelocityLookup::cover`]
    /// copied one around `p` (the same bits) and through the cached accessor otherwise.
    #[inline]
    pub fn at(&mut self, p: DVec3) -> DVec3 {
        let u = self.f.index_from_world.transform_point3(p).to_array();
        let half = if self.f.staggered { 0.5 } else { 0.0 };
        let c = DVec3::new(
            self.component(0, [u[0] + half, u[1], u[2]]),
            self.component(1, [u[0], u[1] + half, u[2]]),
            self.component(2, [u[0], u[1], u[2] + half]),
        );
        self.f.to_world * c
    }

    /// [`VelocityLookup::at`] at 8 world points at once, each component's window read in
    /// AVX-512 lanes ([`Window::trilinear8_avx512`]) and any point outside it read on its own:
    /// the same bits as 8 calls.
    ///
    /// # Safety
    /// The CPU must run AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(unsafe_code)]
    pub unsafe fn at8_avx512(&mut self, p: &[DVec3; 8], out: &mut [DVec3; 8]) {
        // SAFETY: the caller's CPU runs AVX-512F.
        unsafe { self.at8::<true>(p, out) }
    }

    /// [`VelocityLookup::at8_avx512`] for AVX2 CPUs ([`Window::trilinear8_avx2`]): the same
    /// bits as 8 calls of [`VelocityLookup::at`].
    ///
    /// # Safety
    /// The CPU must run AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    pub unsafe fn at8_avx2(&mut self, p: &[DVec3; 8], out: &mut [DVec3; 8]) {
        // SAFETY: the caller's CPU runs AVX2.
        unsafe { self.at8::<false>(p, out) }
    }

    /// The 8 points of [`VelocityLookup::at8_avx512`] (`WIDE`) or
    /// [`VelocityLookup::at8_avx2`]; inlined into each.
    ///
    /// # Safety
    /// The CPU must run AVX-512F (`WIDE`) or AVX2.
    #[cfg(target_arch = "x86_64")]
    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn at8<const WIDE: bool>(&mut self, p: &[DVec3; 8], out: &mut [DVec3; 8]) {
        let half = if self.f.staggered { 0.5 } else { 0.0 };
        let mut u = [[0.0f64; 8]; 3];
        for l in 0..8 {
            let w = self.f.index_from_world.transform_point3(p[l]);
            (u[0][l], u[1][l], u[2][l]) = (w.x, w.y, w.z);
        }
        let mut c = [[0.0f64; 8]; 3];
        for k in 0..3 {
            let mut q = u;
            for v in &mut q[k] {
                *v += half;
            }
            let mut x = [0f32; 8];
            // SAFETY: the caller's CPU runs the level (this function's contract).
            let mut outside = unsafe {
                if WIDE {
                    self.win[k].trilinear8_avx512([&q[0], &q[1], &q[2]], &mut x)
                } else {
                    self.win[k].trilinear8_avx2([&q[0], &q[1], &q[2]], &mut x)
                }
            };
            for l in 0..8 {
                c[k][l] = f64::from(x[l]);
            }
            while outside != 0 {
                let l = outside.trailing_zeros() as usize;
                c[k][l] = f64::from(self.acc[k].trilinear([q[0][l], q[1][l], q[2][l]]));
                outside &= outside - 1;
            }
        }
        for l in 0..8 {
            out[l] = self.f.to_world * DVec3::new(c[0][l], c[1][l], c[2][l]);
        }
    }

    /// Component `k` at its index point `q`: from its window, or through its accessor.
    #[inline(always)]
    fn component(&mut self, k: usize, q: [f64; 3]) -> f64 {
        let v = match self.win[k].trilinear(q) {
            Some(v) => v,
            None => self.acc[k].trilinear(q),
        };
        f64::from(v)
    }

    /// Copy each component's voxels around the world box `[lo, hi]` into its window, so that
    /// the reads at points in it that follow need no descent: the box's index-space bounds
    /// grown by the trilinear stencil and the staggered half voxel. Windows over more than
    /// `max_voxels` voxels are not made (the reads then go through the accessors); false then.
    pub fn cover(&mut self, lo: DVec3, hi: DVec3, max_voxels: usize) -> bool {
        let (a, b) = crate::math::mapped_box(&self.f.index_from_world, lo, hi);
        let half = if self.f.staggered { 0.5 } else { 0.0 };
        let lo_v = [a.x, a.y, a.z].map(crate::math::floor_i64);
        let hi_v = [b.x, b.y, b.z].map(|v| crate::math::floor_i64(v + half) + 1);
        let dims = [0, 1, 2].map(|k| hi_v[k].saturating_sub(lo_v[k]).saturating_add(1));
        let fits = a.is_finite()
            && b.is_finite()
            && dims
                .iter()
                .try_fold(1i64, |n, &d| n.checked_mul(d))
                .is_some_and(|n| n > 0 && n as u64 <= max_voxels as u64);
        if !fits {
            for w in &mut self.win {
                w.clear();
            }
            return false;
        }
        let dims = dims.map(|d| d as usize);
        for k in 0..3 {
            self.win[k].fill(&mut self.acc[k], lo_v, dims);
        }
        true
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
    fn covered_reads_and_eight_at_once_give_the_accessors_bits() {
        for staggered in [false, true] {
            // A field that varies along every axis, over several leaves.
            let comps = [0, 1, 2].map(|k| {
                let mut b = TreeBuilder::new(0.5);
                for x in -3..19 {
                    for y in -2..17 {
                        for z in 0..21 {
                            let v = ((x * 7 + y * 13 + z * (3 + k)) % 17) as f32 * 0.3 - 2.0;
                            b.set([x, y, z], v);
                        }
                    }
                }
                b.build()
            });
            let m = [
                [0.7, 0.1, 0.0, 0.3],
                [0.0, 0.6, -0.2, 1.1],
                [0.05, 0.0, 0.8, -0.4],
            ];
            let f = VelocityField::new("v".into(), comps, m, staggered, false).unwrap();
            let (mut plain, mut covered) = (f.lookup(), f.lookup());
            let (lo, hi) = (DVec3::new(1.0, 0.5, 2.0), DVec3::new(6.0, 5.5, 9.0));
            assert!(covered.cover(lo, hi, 1 << 15));
            let mut s = 0x9E3779B97F4A7C15u64;
            let mut next = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            // Points inside the covered box and beyond it.
            let pts: Vec<DVec3> = (0..800)
                .map(|_| lo + (hi - lo) * DVec3::new(next(), next(), next()) * 1.4 - 0.2)
                .collect();
            let want: Vec<DVec3> = pts.iter().map(|&p| plain.at(p)).collect();
            for (p, w) in pts.iter().zip(&want) {
                assert_eq!(
                    covered.at(*p).to_array().map(f64::to_bits),
                    w.to_array().map(f64::to_bits)
                );
            }
            #[cfg(target_arch = "x86_64")]
            for wide in [true, false] {
                let runs = if wide {
                    std::arch::is_x86_feature_detected!("avx512f")
                } else {
                    std::arch::is_x86_feature_detected!("avx2")
                };
                if !runs {
                    continue;
                }
                for (c, w) in pts.chunks_exact(8).zip(want.chunks_exact(8)) {
                    let p: [DVec3; 8] = c.try_into().unwrap();
                    let mut out = [DVec3::ZERO; 8];
                    #[allow(unsafe_code)]
                    // SAFETY: the CPU runs the level (checked above).
                    unsafe {
                        if wide {
                            covered.at8_avx512(&p, &mut out);
                        } else {
                            covered.at8_avx2(&p, &mut out);
                        }
                    }
                    for l in 0..8 {
                        assert_eq!(
                            out[l].to_array().map(f64::to_bits),
                            w[l].to_array().map(f64::to_bits)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_speed_bound_and_component_ranges_hold_every_lookup_in_their_box() {
        let f = field([1.0, -2.0, 0.5], true);
        let (lo, hi) = (DVec3::new(2.0, 3.0, 1.0), DVec3::new(6.0, 7.0, 5.0));
        let bound = f.speed_bound(lo, hi);
        let (vlo, vhi) = f.velocity_range(lo, hi);
        // x reads 2..8 (16 voxels of data: a leaf and its neighbour): far tighter than
        // [-speed_max, speed_max].
        assert!(vhi.x - vlo.x < f.speed_max(), "{vlo} {vhi}");
        let mut l = f.lookup();
        for n in 0..1000 {
            let t = DVec3::new(
                (n % 10) as f64 / 9.0,
                ((n / 10) % 10) as f64 / 9.0,
                (n / 100) as f64 / 9.0,
            );
            let p = lo + (hi - lo) * t;
            let v = l.at(p);
            assert!(v.length() <= bound + 1e-9);
            assert!(
                vlo.cmple(v).all() && v.cmple(vhi).all(),
                "{v} not in {vlo}..{vhi}"
            );
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
