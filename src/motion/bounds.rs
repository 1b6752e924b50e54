//! [`BlurBounds`]: a majorant of the blurred density per `8^3` block of the density's index
//! space, valid at every shutter time (module docs of `crate::motion`).
//!
//! For a block `C` (voxels `[8c, 8c + 8)`), every point `x` of `C` reads the density at
//! `x - k v(x)` with `|k| <= K = max |S t / F|` over the shutter, so within
//! `r_C = K |v|_max(C)` world units, which is `r_C |row_i(M^-1)|` voxels along index axis `i`.
//! The lookup there (nearest or trilinear, with its half-voxel shift) reads voxels at most two
//! more away, so `maj(C) = max` of the density's block maxima over the blocks meeting
//! `[8c - r_i - 2, 8c + 8 + r_i + 2]` on each axis majorises `rho_t` on `C` at every `t`, with
//! `|v|_max(C)` [`crate::motion::VelocityField::speed_bound`] over `C`'s world box. The blocks
//! are kept dense over the density's blocks grown by the largest reach; outside them the
//! blurred density is the background.

use super::{MotionSpec, VelocityField};
use crate::error::{Error, Result};
use crate::tree::{RootSlot, Tree};
use glam::{DAffine3, DVec3};
use rayon::prelude::*;

/// The most blocks the dense majorant array may hold (64 MiB of `f32`).
pub const MAX_BLOCKS: u64 = 1 << 24;

/// Blurred majorants per `8^3` block over a dense box of blocks; the background outside.
#[derive(Debug, Clone)]
pub struct BlurBounds {
    /// Smallest block coordinate per axis (block `b` holds voxels `[8b, 8b + 8)`).
    lo: [i64; 3],
    /// Blocks per axis.
    dims: [usize; 3],
    /// Raw density majorant per block (z fastest), before the density scale.
    maj: Vec<f32>,
    /// Raw density minorant per block (z fastest): the smallest value any lookup in the
    /// block can read at any shutter time.
    min: Vec<f32>,
    /// The largest and smallest of `maj` and `min` over every block and the background (one
    /// majorant for the whole grid: `--global-majorant`).
    global: (f32, f32),
    /// The density outside the box (its background).
    outside: f32,
    /// The index box of the voxels of every block whose majorant is not the background.
    value_box: Option<[[i64; 3]; 2]>,
    /// How far the shutter moves density at the largest speed: world units and voxels (the
    /// largest over the index axes).
    reach: (f64, f64),
    /// The density's own extent in voxels (the largest over the axes of its blocks' box).
    extent: f64,
}

fn refused(reason: String) -> Error {
    Error::InvalidArgument {
        name: "velocity".into(),
        reason,
    }
}

/// The refusal of a reach whose bounds would pass [`MAX_BLOCKS`] (or no finite reach at
/// all): the distance in world units and voxels, and the flags that set it.
fn too_far(field: &VelocityField, spec: &MotionSpec, world: f64, voxels: &[f64; 3]) -> Error {
    let voxels = voxels.iter().fold(0.0f64, |m, r| m.max(*r - 2.0));
    let num = if world.is_finite() && voxels.is_finite() {
        format!(
            "up to {} world units ({} voxels)",
            crate::math::sig3(world),
            crate::math::sig3(voxels)
        )
    } else {
        "no finite distance".to_string()
    };
    Error::InvalidArgument {
        name: "shutter".into(),
        reason: format!(
            "the velocity grid '{}' (largest speed {}) moves density {num} over the \
             shutter {},{} frames at {} fps with velocity scale {}: the blurred bounds would need \
             more than {MAX_BLOCKS} blocks of 8^3 voxels; shorten the shutter, lower the velocity \
             scale or raise the frame rate",
            crate::text::escape(field.name()),
            crate::math::sig3(field.speed_max()),
            crate::math::short(spec.open()),
            crate::math::short(spec.close()),
            crate::math::short(spec.fps()),
            crate::math::short(spec.scale())
        ),
    }
}

/// Per block of a dense box (`at` its index there, `count` blocks): the largest and smallest
/// value of `sources` ([`source_blocks`]) in it; a block no leaf or tile covers holds the
/// background `outside`.
pub(super) fn dense_sources(
    sources: &[([i64; 3], f32, f32)],
    outside: f32,
    at: impl Fn([i64; 3]) -> usize,
    count: usize,
) -> Vec<(f32, f32)> {
    let mut src = vec![(outside, f32::INFINITY); count];
    for (b, hi, lo_v) in sources {
        let i = at(*b);
        src[i] = (src[i].0.max(*hi), src[i].1.min(*lo_v));
    }
    for v in &mut src {
        if v.1 == f32::INFINITY {
            v.1 = outside;
        }
    }
    src
}

/// Every block of `tree` with data: `(block, max value, min value)` for each leaf (its bounds:
/// every value a lookup in it can return, inactive ones included, `leaf_range(i)` as
/// `(max, min)` for leaf `i`) and each tile whose value is not the background (a 4096^3 root
/// tile is refused: too large to bound by blocks).
pub(super) fn source_blocks(
    tree: &Tree,
    leaf_range: &dyn Fn(usize) -> (f32, f32),
) -> Result<Vec<([i64; 3], f32, f32)>> {
    let bg = tree.background;
    let mut out = Vec::with_capacity(tree.leaves.len());
    for e in &tree.root {
        if let RootSlot::Tile { value, .. } = e.slot {
            if value != bg {
                return Err(refused(
                    "the density holds a root tile (4096^3 voxels of one value); motion blur \
                     bounds density by 8^3 blocks"
                        .into(),
                ));
            }
        }
    }
    for (nodes, dim, child) in [(&tree.uppers, 32usize, 128i64), (&tree.lowers, 16, 8)] {
        for n in nodes {
            for s in 0..n.slots.len() {
                if n.has_child(s) || n.tile_value(s) == bg {
                    continue;
                }
                let l = [s / (dim * dim), (s / dim) % dim, s % dim];
                let o = [0, 1, 2].map(|a| i64::from(n.origin[a]) + l[a] as i64 * child);
                let per = child / 8;
                for x in 0..per {
                    for y in 0..per {
                        for z in 0..per {
                            let b = [o[0] / 8 + x, o[1] / 8 + y, o[2] / 8 + z];
                            out.push((b, n.tile_value(s), n.tile_value(s)));
                        }
                    }
                }
            }
        }
    }
    for (i, l) in tree.leaves.iter().enumerate() {
        let (max, min) = leaf_range(i);
        out.push((l.origin.map(|c| i64::from(c) >> 3), max, min));
    }
    Ok(out)
}

impl BlurBounds {
    /// The bounds of `density` (map `index_from_world`) blurred by `field` over `spec`'s
    /// shutter.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `velocity`) for a partial density tree, a root tile,
    /// or a reach whose dense box would pass [`MAX_BLOCKS`].
    pub fn build(
        density: &Tree,
        index_from_world: DAffine3,
        field: &VelocityField,
        spec: &MotionSpec,
    ) -> Result<Self> {
        if !density.is_complete() {
            return Err(refused("motion blur needs the density loaded whole".into()));
        }
        let leaf = |i: usize| (density.leaves[i].bounds.max, density.leaves[i].bounds.min);
        Self::build_with(density, &leaf, index_from_world, field, spec)
    }

    /// [`BlurBounds::build`] from the density's topology `shell` (its tiles and leaf origins;
    /// its leaf values need not be loaded) and `leaf_range[i]`, the `(max, min)` of leaf `i`'s
    /// values as a whole load bounds them: the same bounds, bit for bit, for a density decoded a
    /// part at a time (a bake in parts keeps only these two numbers per leaf).
    ///
    /// # Errors
    /// As [`BlurBounds::build`], and [`Error::InvalidArgument`] (name `velocity`) when
    /// `leaf_range` does not hold one entry per leaf of `shell`.
    pub(crate) fn from_summary(
        shell: &Tree,
        leaf_range: &[(f32, f32)],
        index_from_world: DAffine3,
        field: &VelocityField,
        spec: &MotionSpec,
    ) -> Result<Self> {
        if leaf_range.len() != shell.leaves.len() {
            return Err(refused(format!(
                "{} leaf ranges for a density of {} leaves",
                leaf_range.len(),
                shell.leaves.len()
            )));
        }
        Self::build_with(shell, &|i| leaf_range[i], index_from_world, field, spec)
    }

    /// [`BlurBounds::build`] with leaf `i`'s `(max, min)` from `leaf_range`.
    fn build_with(
        density: &Tree,
        leaf_range: &dyn Fn(usize) -> (f32, f32),
        index_from_world: DAffine3,
        field: &VelocityField,
        spec: &MotionSpec,
    ) -> Result<Self> {
        let outside = density.background;
        let sources = source_blocks(density, leaf_range)?;
        let Some(first) = sources.first() else {
            return Ok(Self {
                lo: [0; 3],
                dims: [0; 3],
                maj: Vec::new(),
                min: Vec::new(),
                global: (outside, outside),
                outside,
                value_box: None,
                reach: (0.0, 0.0),
                extent: 0.0,
            });
        };
        let (mut slo, mut shi) = (first.0, first.0);
        for (b, _, _) in &sources {
            for a in 0..3 {
                slo[a] = slo[a].min(b[a]);
                shi[a] = shi[a].max(b[a]);
            }
        }
        // Voxels per world unit along each index axis: |row_i(M^-1)|.
        let m = index_from_world.matrix3.transpose();
        let per_world = [m.x_axis.length(), m.y_axis.length(), m.z_axis.length()];
        let reach = spec.reach_per_velocity();
        let radius = |speed: f64| lookup_radius(per_world, reach, speed);
        let rg = radius(field.speed_max());
        // Sized in f64 first: a reach from extreme numbers (a velocity of 1e30, a shutter of
        // 1e20 frames, 1e-300 fps) is refused by name before any integer is formed.
        let grow_f = rg.map(|r| (r / 8.0).ceil() + 1.0);
        let dims_f = [0, 1, 2].map(|a| (shi[a] - slo[a] + 1) as f64 + 2.0 * grow_f[a]);
        let count_f = dims_f.iter().product::<f64>();
        if !(count_f.is_finite() && count_f <= MAX_BLOCKS as f64) {
            return Err(too_far(field, spec, reach * field.speed_max(), &rg));
        }
        let grow = grow_f.map(|g| g as i64);
        let moved = (
            reach * field.speed_max(),
            rg.iter().fold(0.0f64, |m, r| m.max(r - 2.0)),
        );
        let extent = (0..3).fold(0.0f64, |m, a| m.max(((shi[a] - slo[a] + 1) * 8) as f64));
        let lo = [0, 1, 2].map(|a| slo[a] - grow[a]);
        let dims = [0, 1, 2].map(|a| (shi[a] + grow[a] - lo[a] + 1) as u64);
        let count = dims.iter().product::<u64>();
        let dims = dims.map(|d| d as usize);
        let at = |b: [i64; 3]| {
            let i = [0, 1, 2].map(|a| (b[a] - lo[a]) as usize);
            (i[0] * dims[1] + i[1]) * dims[2] + i[2]
        };
        let src = dense_sources(&sources, outside, at, count as usize);
        let world_from_index = index_from_world.inverse();
        let slab = dims[1] * dims[2];
        let mut both = vec![(outside, outside); count as usize];
        both.par_chunks_mut(slab.max(1))
            .enumerate()
            .for_each(|(x, out)| {
                for y in 0..dims[1] {
                    for z in 0..dims[2] {
                        let c = [lo[0] + x as i64, lo[1] + y as i64, lo[2] + z as i64];
                        let r = block_radius(&world_from_index, per_world, reach, field, c);
                        out[y * dims[2] + z] = extremes_within(&src, outside, (lo, dims), c, r);
                    }
                }
            });
        let (maj, min): (Vec<f32>, Vec<f32>) = both.into_iter().unzip();
        let global = (
            maj.iter().fold(outside, |m, v| m.max(*v)),
            min.iter().fold(outside, |m, v| m.min(*v)),
        );
        let value_box = value_box_of(&maj, outside, lo, dims);
        Ok(Self {
            lo,
            dims,
            maj,
            min,
            global,
            outside,
            value_box,
            reach: moved,
            extent,
        })
    }

    /// The part `[a, b]` of `[t0, t1]` where the index-space ray `q + t d` is inside the dense
    /// box of blocks `[8 lo, 8 (lo + dims))` (slab test; half-open on the axes the ray runs
    /// along, as the blocks are), `None` when it misses it or the box is empty: where a walk
    /// through the bounds starts and ends.
    #[must_use]
    pub fn clip(&self, q: [f64; 3], d: [f64; 3], (t0, t1): (f64, f64)) -> Option<(f64, f64)> {
        if self.dims.contains(&0) {
            return None;
        }
        let (mut a, mut b) = (t0, t1);
        for k in 0..3 {
            let lo = (self.lo[k] * 8) as f64;
            let hi = ((self.lo[k] + self.dims[k] as i64) * 8) as f64;
            if d[k] == 0.0 {
                if q[k] < lo || q[k] >= hi {
                    return None;
                }
                continue;
            }
            let (ta, tb) = ((lo - q[k]) / d[k], (hi - q[k]) / d[k]);
            a = a.max(ta.min(tb));
            b = b.min(ta.max(tb));
        }
        (b > a).then_some((a, b))
    }

    /// The index box of the voxels of every block the blurred density may differ from the
    /// background in (inclusive), `None` when there is none.
    #[must_use]
    pub fn value_box(&self) -> Option<[[i64; 3]; 2]> {
        self.value_box
    }

    /// How far the shutter moves density at the field's largest speed, `(world units,
    /// voxels)`, and the density's own extent in voxels (its blocks' box): a move past the
    /// extent blurs the cache beyond its own size (usually a wrong velocity scale or unit).
    #[must_use]
    pub fn reach(&self) -> ((f64, f64), f64) {
        (self.reach, self.extent)
    }

    /// Blocks held (the dense box).
    #[must_use]
    pub fn blocks(&self) -> usize {
        self.maj.len()
    }

    /// The raw minorant and majorant of block `b`, `(min, max)`: every lookup in the block at
    /// every shutter time reads a value between them (the background outside the box).
    #[must_use]
    pub fn block_range(&self, b: [i64; 3]) -> (f32, f32) {
        self.index(b)
            .map_or((self.outside, self.outside), |i| (self.min[i], self.maj[i]))
    }

    /// The raw `(min, max)` over every block and the background: one bound for the whole
    /// grid (`--global-majorant`).
    #[must_use]
    pub fn global_range(&self) -> (f32, f32) {
        (self.global.1, self.global.0)
    }

    /// Where block `b` sits in the dense arrays, `None` outside the box.
    fn index(&self, b: [i64; 3]) -> Option<usize> {
        let mut i = 0usize;
        for ((&c, &lo), &dim) in b.iter().zip(&self.lo).zip(&self.dims) {
            let k = c - lo;
            if k < 0 || k >= dim as i64 {
                return None;
            }
            i = i * dim + k as usize;
        }
        Some(i)
    }

    /// The dense box: its smallest block coordinate per axis and its blocks per axis (block
    /// `b` holds voxels `[8b, 8b + 8)`); outside it, [`BlurBounds::block`] is the background.
    #[must_use]
    pub fn dense_box(&self) -> ([i64; 3], [usize; 3]) {
        (self.lo, self.dims)
    }
}

/// The largest maximum and the smallest minimum of `src` (`(max, min)` per block, dense over
/// `lo`, `dims`, z fastest) over the blocks that meet the voxels `[8c - r, 8c + 8 + r]` on
/// each axis, and `outside` (the background beyond the box); the minimum is clamped at 0.
fn extremes_within(
    src: &[(f32, f32)],
    outside: f32,
    (lo, dims): ([i64; 3], [usize; 3]),
    c: [i64; 3],
    r: [f64; 3],
) -> (f32, f32) {
    let range = |a: usize| {
        let v0 = ((c[a] * 8) as f64 - r[a]).floor() as i64;
        let v1 = ((c[a] * 8 + 8) as f64 + r[a]).floor() as i64;
        (v0, v1)
    };
    extremes_over(src, outside, (lo, dims, 3), [range(0), range(1), range(2)])
}

/// The largest maximum and the smallest minimum of `src` (`(max, min)` per cell of
/// `2^shift` voxels a side, dense over cells `lo`, `dims`, z fastest) over the cells that meet
/// the voxels `[v0, v1]` (inclusive) on each axis, and `outside` when they leave the box (the
/// background beyond it); the minimum is clamped at 0.
pub(super) fn extremes_over(
    src: &[(f32, f32)],
    outside: f32,
    (lo, dims, shift): ([i64; 3], [usize; 3], u32),
    voxels: [(i64, i64); 3],
) -> (f32, f32) {
    let [rx, ry, rz] = voxels.map(|(v0, v1)| (v0 >> shift, v1 >> shift));
    let inside = |(a, b): (i64, i64), k: usize| (a.max(lo[k]), b.min(lo[k] + dims[k] as i64 - 1));
    // The reach leaves the dense box: the background is read there.
    let leaves_box = [rx, ry, rz]
        .iter()
        .enumerate()
        .any(|(k, &(a, b))| a < lo[k] || b > lo[k] + dims[k] as i64 - 1);
    let (rx, ry, rz) = (inside(rx, 0), inside(ry, 1), inside(rz, 2));
    let (mut hi, mut mn) = (outside, if leaves_box { outside } else { f32::INFINITY });
    for bx in rx.0..=rx.1 {
        for by in ry.0..=ry.1 {
            let row = ((bx - lo[0]) as usize * dims[1] + (by - lo[1]) as usize) * dims[2];
            for bz in rz.0..=rz.1 {
                let (m, n) = src[row + (bz - lo[2]) as usize];
                hi = hi.max(m);
                mn = mn.min(n);
            }
        }
    }
    (hi, mn.min(hi).max(0.0))
}

/// The index box of the voxels of every block of `maj` (dense over `lo`, `dims`, z fastest)
/// whose majorant is not `outside`.
fn value_box_of(
    maj: &[f32],
    outside: f32,
    lo: [i64; 3],
    dims: [usize; 3],
) -> Option<[[i64; 3]; 2]> {
    let mut value_box: Option<[[i64; 3]; 2]> = None;
    for (i, &m) in maj.iter().enumerate() {
        if m == outside {
            continue;
        }
        let b = [
            i / (dims[1] * dims[2]),
            (i / dims[2]) % dims[1],
            i % dims[2],
        ];
        let v = [0, 1, 2].map(|a| (lo[a] + b[a] as i64) * 8);
        let bb = value_box.get_or_insert([v, v.map(|c| c + 7)]);
        for a in 0..3 {
            bb[0][a] = bb[0][a].min(v[a]);
            bb[1][a] = bb[1][a].max(v[a] + 7);
        }
    }
    value_box
}

/// How many voxels along each index axis the lookups of a point read around it when the
/// shutter moves it `reach x speed` world units (`per_world`: voxels per world unit per axis),
/// the trilinear stencil and the lookup's half-voxel shift included.
fn lookup_radius(per_world: [f64; 3], reach: f64, speed: f64) -> [f64; 3] {
    per_world.map(|p| reach * speed * p + 2.0)
}

/// The radius in voxels per index axis around block `c` that every lookup of a point of the
/// block reads within at every shutter time (`reach`: world displacement per unit of velocity;
/// the speed bounded over the block's world box, one voxel beyond it).
fn block_radius(
    world_from_index: &DAffine3,
    per_world: [f64; 3],
    reach: f64,
    field: &VelocityField,
    c: [i64; 3],
) -> [f64; 3] {
    if reach == 0.0 {
        return lookup_radius(per_world, reach, 0.0);
    }
    let (wlo, whi) = world_box(world_from_index, c);
    lookup_radius(per_world, reach, field.speed_bound(wlo, whi))
}

/// The voxel box (inclusive) every lookup of a point of block `c` (or within one voxel of it)
/// reads at every shutter time of `spec` under `field`, for a density with map
/// `index_from_world`: the block grown by [`BlurBounds`]' radius and one voxel more. A bake in
/// parts loads the density leaves meeting this box for every block its rays cross.
pub(crate) fn block_reads(
    index_from_world: &DAffine3,
    field: &VelocityField,
    spec: &MotionSpec,
    c: [i64; 3],
) -> [[i64; 3]; 2] {
    let m = index_from_world.matrix3.transpose();
    let per_world = [m.x_axis.length(), m.y_axis.length(), m.z_axis.length()];
    let world_from_index = index_from_world.inverse();
    let r = block_radius(
        &world_from_index,
        per_world,
        spec.reach_per_velocity(),
        field,
        c,
    );
    let lo = [0, 1, 2].map(|a| ((c[a] * 8) as f64 - r[a] - 1.0).floor() as i64);
    let hi = [0, 1, 2].map(|a| ((c[a] * 8 + 8) as f64 + r[a] + 1.0).ceil() as i64);
    [lo, hi]
}

/// The world box of block `c`'s voxels `[8c - 1, 8c + 9]` (one voxel beyond, for the lookup
/// shift).
fn world_box(world_from_index: &DAffine3, c: [i64; 3]) -> (DVec3, DVec3) {
    let lo = DVec3::from_array(c.map(|v| (v * 8) as f64 - 1.0));
    crate::math::mapped_box(world_from_index, lo, lo + 10.0)
}
