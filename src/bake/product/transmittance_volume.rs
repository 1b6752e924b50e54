//! Transmittance volumes: `T` from the light stored per voxel in a VDB float grid beside the
//! density (what Houdini's and Blender's `shadow` fields hold), written by umbra's own VDB
//! writer ([`crate::vdb::write_vdb`]).
//!
//! **What a voxel holds.** Voxel `ijk` (an active voxel of the density grid, or a voxel of an
//! active tile) holds `T = exp(-tau)` along [`crate::Light::ray_from`] from its centre, the
//! index point `ijk` in world space: toward a directional light until the ray leaves the
//! volume box, toward a point light up to the light. The output grid has exactly the density
//! grid's active voxels (active tiles written as dense leaves), background 1, the volume's
//! transform (with `--xform`). Inactive voxels inside written leaves hold 1.
//!
//! **Shared work, exactly.** With regular tracking and a directional light whose direction in
//! index space is parallel to a lattice vector `w` (integer components up to
//! [`MAX_LINE_STEP`]: an axis, a diagonal, or any direction typed with one or two decimals,
//! such as `0.3,-1,0.2`, parallel to `(3, -10, 2)`), the voxel centres `c`, `c + w`, `c + 2w`,
//! ... lie on one ray toward the light: `tau(c) = tau(c + w) + int_c^{c+w} mu`. So each line's
//! voxel nearest the light traces one exact ray and every other voxel adds the exact integral
//! over the steps to it: along an axis `h (v_k + v_{k+1}) / 2` per step (`h` the world length
//! of one index step; the trilinear field is linear between two centres there, and the nearest
//! field is `v_k` for half the step and `v_{k+1}` for the other half), along other lattice
//! vectors regular tracking's cell walk over the index segment `[c, c + w]`. A gap of more than
//! a few steps starts a fresh ray (which skips empty space). Any other light (point lights,
//! suns off the lattice) traces one exact ray per voxel, the rays of 32 leaves at a time in a
//! query batch (`regular::optical_depths`: each leaf's chords together on the SIMD kernel, the
//! f64 walk's answer to the kernel's f32 positions; nearest lookups ray by ray); stochastic estimators
//! estimate every voxel's ray on its own (ray id: the voxel's index in the output, leaf by
//! leaf, 512 per leaf).
//!
//! The lattice test allows each component `1e-12 n` off an integer (`n` the scale tried): over
//! a line of `m` steps the line drifts from the rays by at most about `1e-12 m` voxels, far
//! below f32. Exact values along parallel lines that hold one voxel centre each cannot share
//! work, so suns off the lattice pay a ray per voxel; an interpolating light-aligned grid would
//! be faster but not exact.

use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use crate::light::Light;
use crate::tree::{bit, Accessor};
use crate::vdb::LeafOut;
use crate::volume::{Interp, Volume};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Longest run of voxel steps a line walks between two output voxels; a longer gap starts a
/// fresh ray (which skips empty space by the HDDA).
const MAX_STEPS: i64 = 64;

/// Most 8^3 leaves a transmittance volume may hold (2 KiB of values each: 4 GiB).
pub const MAX_VOLUME_LEAVES: usize = 1 << 21;

/// How the voxels' transmittances were computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Sharing {
    /// One exact ray per line of voxel centres along the light (a sun along a lattice
    /// direction of the index grid).
    Lines,
    /// One sweep per layer of voxel centres toward a sun (`transmittance_layers`).
    Layers,
    /// One ray (or estimate) per voxel.
    Rays,
}

/// What a transmittance volume holds and cost.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct VolumeStats {
    /// Voxels written (the density's active voxels, active tiles included).
    pub voxels: u64,
    /// Leaves written.
    pub leaves: u64,
    /// Leaves made from active tiles.
    pub tile_leaves: u64,
    /// How the work was shared.
    pub sharing: Sharing,
    /// With [`Sharing::Lines`]: the index step from a voxel centre to the next one toward the
    /// light on its line.
    pub line_step: Option<[i64; 3]>,
    /// Rays traced from scratch (one per line, or one per voxel).
    pub rays: u64,
    /// Density values read.
    pub lookups: u64,
    /// Smallest, largest and mean `T` over the voxels (`T_min` as data, the key every
    /// front end's report uses).
    #[serde(rename = "T_min")]
    pub t_min: f64,
    /// Largest `T` (`T_max` as data).
    #[serde(rename = "T_max")]
    pub t_max: f64,
    /// Mean `T` (`T_mean` as data).
    #[serde(rename = "T_mean")]
    pub t_mean: f64,
    /// Wall time of the computation, seconds.
    pub seconds: f64,
    /// Toward a light with extent: the directions traced per sampled voxel; absent toward a
    /// point.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_samples: Option<u32>,
    /// Toward a light with extent: the fraction of voxels sampled (the others' whole cone
    /// provably misses every box: `T = 1` without sampling); absent toward a point.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sampled_fraction: Option<f64>,
    /// Toward a light with extent: the largest error bar of a voxel's `T` (the file holds `T`
    /// only); absent toward a point.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub std_err_max: Option<f64>,
    /// Toward a light with extent: the directions its sampled voxels traced (mean, 99th
    /// percentile, most) and the voxels whose target error asked for more than
    /// `light-max-samples`; absent toward a point.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_directions: Option<crate::bake::LightDirections>,
}

impl VolumeStats {
    /// Wall time per voxel, nanoseconds.
    #[must_use]
    pub fn ns_per_voxel(&self) -> f64 {
        self.seconds * 1e9 / self.voxels.max(1) as f64
    }
}

/// How many voxels a transmittance volume of `vol` holds: the active voxels of its leaves and
/// of its active lower and upper tiles (what [`transmittance_leaves`] writes; an active root
/// tile counts its 4096^3 voxels, which the write then refuses). From the masks alone.
#[must_use]
pub fn output_voxels(vol: &Volume) -> u64 {
    let tree = vol.tree();
    let leaves: u64 = tree
        .leaves()
        .iter()
        .map(|l| {
            l.value_mask
                .iter()
                .map(|w| u64::from(w.count_ones()))
                .sum::<u64>()
        })
        .sum();
    let tiles = |nodes: &[crate::tree::Internal], voxels: u64| -> u64 {
        nodes
            .iter()
            .map(|n| {
                n.value_mask
                    .iter()
                    .zip(n.child_mask.iter())
                    .map(|(v, c)| u64::from((v & !c).count_ones()))
                    .sum::<u64>()
                    * voxels
            })
            .sum()
    };
    let root = tree
        .root()
        .iter()
        .filter(|e| matches!(e.slot, crate::tree::RootSlot::Tile { active: true, .. }))
        .count() as u64;
    leaves + tiles(tree.lowers(), 512) + tiles(tree.uppers(), 128 * 128 * 128) + root * (1 << 36)
}

/// The 8^3 blocks of the output and how many of them are made from active tiles.
pub(super) fn output_blocks(vol: &Volume) -> Result<(Vec<LeafOut>, u64)> {
    let leaves = blocks(vol)?;
    let leaf_count = vol
        .tree()
        .leaves()
        .iter()
        .filter(|l| l.value_mask.iter().any(|&w| w != 0))
        .count();
    let tile_leaves = (leaves.len() - leaf_count) as u64;
    debug_assert_eq!(
        output_voxels(vol),
        leaves
            .iter()
            .map(|l| l
                .active
                .iter()
                .map(|w| u64::from(w.count_ones()))
                .sum::<u64>())
            .sum::<u64>()
    );
    Ok((leaves, tile_leaves))
}

/// The smallest, largest and mean `T` over the active voxels of `leaves`, and their count
/// (1 and 1 for none).
pub(super) fn summarise(leaves: &[LeafOut], stats: &mut VolumeStats) {
    let mut sum = 0.0f64;
    for l in leaves {
        for (n, &v) in l.values.iter().enumerate() {
            if bit(&l.active, n) {
                let v = f64::from(v);
                stats.voxels += 1;
                stats.t_min = stats.t_min.min(v);
                stats.t_max = stats.t_max.max(v);
                sum += v;
            }
        }
    }
    stats.t_mean = sum / stats.voxels.max(1) as f64;
    if stats.voxels == 0 {
        (stats.t_min, stats.t_max) = (1.0, 1.0);
    }
}

/// The 8^3 blocks of the output: a leaf's active voxels or an active tile's.
fn blocks(vol: &Volume) -> Result<Vec<LeafOut>> {
    let tree = vol.tree();
    let too_big = |n: usize| Error::InvalidArgument {
        name: "output".into(),
        reason: format!(
            "the transmittance volume would hold more than {MAX_VOLUME_LEAVES} leaves of 8^3 \
             voxels ({n} so far): active tiles are written voxel by voxel"
        ),
    };
    let empty = |origin: [i32; 3], active: [u64; 8]| LeafOut {
        origin,
        values: Box::new([1.0; 512]),
        active,
    };
    let mut out: Vec<LeafOut> = Vec::new();
    for l in tree.leaves() {
        if l.value_mask.iter().any(|&w| w != 0) {
            out.push(empty(l.origin, l.value_mask));
        }
    }
    for lower in tree.lowers() {
        for n in 0..4096usize {
            if !lower.has_child(n) && bit(&lower.value_mask, n) {
                let o = [(n >> 8) as i32, ((n >> 4) & 15) as i32, (n & 15) as i32];
                let origin = [0, 1, 2].map(|a| lower.origin[a] + o[a] * 8);
                out.push(empty(origin, [u64::MAX; 8]));
            }
        }
    }
    for upper in tree.uppers() {
        for n in 0..32768usize {
            if !upper.has_child(n) && bit(&upper.value_mask, n) {
                let o = [(n >> 10) as i32, ((n >> 5) & 31) as i32, (n & 31) as i32];
                let base = [0, 1, 2].map(|a| upper.origin[a] + o[a] * 128);
                if out.len() + 4096 > MAX_VOLUME_LEAVES {
                    return Err(too_big(out.len() + 4096));
                }
                for k in 0..4096i32 {
                    let b = [k >> 8, (k >> 4) & 15, k & 15];
                    out.push(empty([0, 1, 2].map(|a| base[a] + b[a] * 8), [u64::MAX; 8]));
                }
            }
        }
    }
    if tree
        .root()
        .iter()
        .any(|e| matches!(e.slot, crate::tree::RootSlot::Tile { active: true, .. }))
    {
        return Err(Error::InvalidArgument {
            name: "output".into(),
            reason: "the grid has an active 4096^3 root tile; a transmittance volume of it \
                     would be 6.9e10 voxels"
                .into(),
        });
    }
    if out.len() > MAX_VOLUME_LEAVES {
        return Err(too_big(out.len()));
    }
    out.sort_by_key(|l| l.origin);
    Ok(out)
}

/// Largest component of a lattice step [`light_step`] looks for.
pub const MAX_LINE_STEP: i64 = 16;

/// For a directional light whose index-space direction is parallel (to `1e-12` of its length,
/// per component) to a lattice vector `w` with components of at most [`MAX_LINE_STEP`]: the
/// shortest such `w` pointing toward the light. Voxel centres `c` and `c + w` lie on one ray
/// toward the light. `None` for point lights and other directions.
#[must_use]
pub fn light_step(vol: &Volume, light: &Light) -> Option<[i64; 3]> {
    let Light::Directional { dir } = *light else {
        return None;
    };
    let d = (-vol.to_index_dir(glam::DVec3::from_array(dir))).to_array();
    let a = (0..3).max_by(|&x, &y| d[x].abs().total_cmp(&d[y].abs()))?;
    if !(d[a].abs() > 0.0 && d[a].is_finite()) {
        return None;
    }
    let unit = d.map(|c| c / d[a].abs());
    (1..=MAX_LINE_STEP).find_map(|n| {
        let v = unit.map(|c| c * n as f64);
        let w = v.map(|c| c.round());
        let close = (0..3).all(|k| (v[k] - w[k]).abs() <= 1e-12 * n as f64);
        close.then(|| w.map(|c| c as i64))
    })
}

/// The estimator's options checked, and regular tracking refused on a moving volume (its exact
/// paths read the still grid): what every transmittance volume checks first.
///
/// # Errors
/// The options' errors; [`Error::InvalidArgument`] naming `estimator`.
pub(crate) fn check_estimator(vol: &Volume, est: &Estimator, opts: &Options) -> Result<()> {
    opts.validate()?;
    if vol.motion().is_some() && *est == Estimator::REGULAR {
        return Err(crate::error::Error::InvalidArgument {
            name: "estimator".into(),
            reason: crate::estimate::blur::REGULAR_REFUSED.into(),
        });
    }
    Ok(())
}

/// Transmittance toward `light` at every output voxel of `vol` (module docs): the leaves to
/// write and what they cost. `progress` gets finished voxel counts.
///
/// # Errors
/// [`Error::InvalidArgument`] for a volume too large to write voxel by voxel, a bad light;
/// estimator errors of any voxel's ray.
pub fn transmittance_leaves(
    vol: &Volume,
    light: &Light,
    est: &Estimator,
    opts: &Options,
    threads: usize,
    progress: &dyn crate::progress::Progress,
) -> Result<(Vec<LeafOut>, VolumeStats)> {
    // The exact paths below read the still grid.
    check_estimator(vol, est, opts)?;
    let start = std::time::Instant::now();
    let (mut leaves, tile_leaves) = output_blocks(vol)?;
    let step = light_step(vol, light).filter(|_| *est == Estimator::REGULAR);
    // Check the light once (a zero direction is refused here, not per voxel).
    light.ray_from(vol, vol.to_world(glam::DVec3::ZERO).to_array())?;
    let mut layered = false;
    let run = || -> Result<(u64, u64)> {
        match step {
            Some(w) => {
                match (0..3).find(|&a| w[a] != 0 && w.iter().filter(|&&c| c != 0).count() == 1) {
                    Some(a) => by_lines(
                        vol,
                        light,
                        opts,
                        &mut leaves,
                        a,
                        w[a].signum() as i32,
                        progress,
                    ),
                    None => by_lattice(vol, light, opts, &mut leaves, w, progress),
                }
            }
            None if *est == Estimator::REGULAR && opts.interp == Interp::Trilinear => {
                match super::transmittance_layers::by_layers(vol, light, &mut leaves, progress)? {
                    Some(done) => {
                        layered = true;
                        Ok(done)
                    }
                    None => by_ray_batches(vol, light, &mut leaves, progress),
                }
            }
            None => by_rays(vol, light, est, opts, &mut leaves, progress),
        }
    };
    let (rays, lookups) = crate::bake::trace::in_pool(threads, run)?;
    let mut stats = VolumeStats {
        voxels: 0,
        leaves: leaves.len() as u64,
        tile_leaves,
        sharing: if step.is_some() {
            Sharing::Lines
        } else if layered {
            Sharing::Layers
        } else {
            Sharing::Rays
        },
        line_step: step,
        rays,
        lookups,
        t_min: f64::INFINITY,
        t_max: f64::NEG_INFINITY,
        t_mean: 0.0,
        seconds: 0.0,
        light_samples: None,
        sampled_fraction: None,
        light_directions: None,
        std_err_max: None,
    };
    summarise(&leaves, &mut stats);
    stats.seconds = start.elapsed().as_secs_f64();
    Ok((leaves, stats))
}

/// Leaves whose voxels' rays [`by_ray_batches`] hands over together: at most 16,384 rays, one
/// chunk of [`crate::regular::optical_depths`].
const LEAVES_PER_BATCH: usize = 32;

/// Exact trilinear T of every voxel by its own ray, the rays of [`LEAVES_PER_BATCH`] leaves at
/// a time through [`crate::regular::optical_depths`] (every leaf's chords together on the SIMD
/// kernel; the f64 walk's answer to the kernel's f32 positions, as exact maps), groups of
/// leaves in parallel. Each voxel's T depends on its ray alone.
fn by_ray_batches(
    vol: &Volume,
    light: &Light,
    leaves: &mut [LeafOut],
    progress: &dyn crate::progress::Progress,
) -> Result<(u64, u64)> {
    leaves
        .par_chunks_mut(LEAVES_PER_BATCH)
        .map(|group| {
            let (mut rays, mut at) = (Vec::new(), Vec::new());
            for (g, leaf) in group.iter().enumerate() {
                for n in (0..512usize).filter(|&n| bit(&leaf.active, n)) {
                    rays.push(voxel_ray(vol, light, leaf, n)?);
                    at.push((g, n));
                }
            }
            let mut lookups = 0u64;
            let depths = crate::regular::optical_depths(vol, &rays, Interp::Trilinear);
            for ((g, n), od) in at.into_iter().zip(depths) {
                let od = od?;
                lookups += od.lookups;
                group[g].values[n] = od.transmittance() as f32;
            }
            progress.advance(rays.len() as u64);
            Ok((rays.len() as u64, lookups))
        })
        .try_reduce(|| (0, 0), |a, b| Ok((a.0 + b.0, a.1 + b.1)))
}

/// The ray from voxel `n` of `leaf` (its centre in world space) toward the light.
fn voxel_ray(vol: &Volume, light: &Light, leaf: &LeafOut, n: usize) -> Result<crate::Ray> {
    let ijk = [
        leaf.origin[0] + (n >> 6) as i32,
        leaf.origin[1] + ((n >> 3) & 7) as i32,
        leaf.origin[2] + (n & 7) as i32,
    ];
    let p = vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)));
    light.ray_from(vol, p.to_array())
}

/// One ray (or estimate) per voxel, leaves in parallel.
fn by_rays(
    vol: &Volume,
    light: &Light,
    est: &Estimator,
    opts: &Options,
    leaves: &mut [LeafOut],
    progress: &dyn crate::progress::Progress,
) -> Result<(u64, u64)> {
    let exact = *est == Estimator::REGULAR;
    leaves
        .par_iter_mut()
        .enumerate()
        .map(|(li, leaf)| {
            let (mut rays, mut lookups, mut done) = (0u64, 0u64, 0u64);
            for n in 0..512usize {
                if !bit(&leaf.active, n) {
                    continue;
                }
                let ray = voxel_ray(vol, light, leaf, n)?;
                let t = if exact {
                    let od = crate::regular::optical_depth(vol, &ray, opts.interp)?;
                    lookups += od.lookups;
                    od.transmittance()
                } else {
                    let id = li as u64 * 512 + n as u64;
                    let e = crate::estimate::estimate(vol, &ray, id, est, opts)?;
                    lookups += e.lookups;
                    e.value
                };
                leaf.values[n] = t as f32;
                rays += 1;
                done += 1;
            }
            progress.advance(done);
            Ok((rays, lookups))
        })
        .try_reduce(|| (0, 0), |a, b| Ok((a.0 + b.0, a.1 + b.1)))
}

/// The exact shared walk along lines of voxel centres (module docs): leaves grouped into
/// columns along `axis`, each column's 64 lines walked from the light.
#[allow(clippy::too_many_arguments)]
fn by_lines(
    vol: &Volume,
    light: &Light,
    opts: &Options,
    leaves: &mut [LeafOut],
    axis: usize,
    toward: i32,
    progress: &dyn crate::progress::Progress,
) -> Result<(u64, u64)> {
    let (u, v) = match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    // Columns: leaves sharing the two other origin coordinates, nearest the light first.
    let mut columns: BTreeMap<(i32, i32), Vec<&mut LeafOut>> = BTreeMap::new();
    for l in leaves.iter_mut() {
        columns
            .entry((l.origin[u], l.origin[v]))
            .or_default()
            .push(l);
    }
    let mut columns: Vec<Vec<&mut LeafOut>> = columns.into_values().collect();
    for c in &mut columns {
        c.sort_by_key(|l| -toward * l.origin[axis]);
    }
    let mut unit = glam::DVec3::ZERO;
    unit[axis] = 1.0;
    let h = vol.world_from_index().matrix3.mul_vec3(unit).length();
    let scale = vol.density_scale();
    columns
        .par_iter_mut()
        .map(|column| {
            let mut acc = Accessor::new(vol.tree());
            let (mut rays, mut lookups, mut done) = (0u64, 0u64, 0u64);
            for a in 0..8i32 {
                for b in 0..8i32 {
                    // The line's last voxel written and its optical depth.
                    let mut last: Option<(i64, f64)> = None;
                    for leaf in column.iter_mut() {
                        for s in 0..8i32 {
                            // Walk away from the light: from the near face of the leaf.
                            let k = if toward > 0 { 7 - s } else { s };
                            let mut ijk = [0i32; 3];
                            ijk[axis] = leaf.origin[axis] + k;
                            ijk[u] = leaf.origin[u] + a;
                            ijk[v] = leaf.origin[v] + b;
                            let n = crate::tree::leaf_offset(ijk);
                            if !bit(&leaf.active, n) {
                                continue;
                            }
                            let here = i64::from(ijk[axis]);
                            // A long gap (another cloud further along the line) is cheaper
                            // to cross by a fresh ray, which skips empty space.
                            let last_near =
                                last.filter(|(from, _)| (from - here).abs() <= MAX_STEPS);
                            let tau = match last_near {
                                None => {
                                    let p =
                                        vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)));
                                    let ray = light.ray_from(vol, p.to_array())?;
                                    let od = crate::regular::optical_depth(vol, &ray, opts.interp)?;
                                    rays += 1;
                                    lookups += od.lookups;
                                    od.tau
                                }
                                Some((from, tau)) => {
                                    // Steps from `from` (nearer the light) back to `here`.
                                    let mut sum = 0.0f64;
                                    let mut c =
                                        [i64::from(ijk[0]), i64::from(ijk[1]), i64::from(ijk[2])];
                                    c[axis] = from;
                                    let mut prev = f64::from(acc.value_at(c));
                                    let step = -i64::from(toward);
                                    let mut pos = from;
                                    while pos != here {
                                        pos += step;
                                        c[axis] = pos;
                                        let val = f64::from(acc.value_at(c));
                                        sum += 0.5 * (prev + val);
                                        prev = val;
                                    }
                                    lookups += (from - here).unsigned_abs() + 1;
                                    tau + crate::math::scaled(scale, sum) * h
                                }
                            };
                            leaf.values[n] = (-tau).exp() as f32;
                            last = Some((here, tau));
                            done += 1;
                        }
                    }
                }
            }
            progress.advance(done);
            Ok((rays, lookups))
        })
        .try_reduce(|| (0, 0), |a, b| Ok((a.0 + b.0, a.1 + b.1)))
}

/// The exact shared walk along lattice lines `c + m w` (`w` toward the light, not along an
/// axis): each line's voxel nearest the light traces a ray, the others add the exact integral
/// over each step `[c, c + w]` (regular tracking's cell walk on that index segment).
fn by_lattice(
    vol: &Volume,
    light: &Light,
    opts: &Options,
    leaves: &mut [LeafOut],
    w: [i64; 3],
    progress: &dyn crate::progress::Progress,
) -> Result<(u64, u64)> {
    let a = (0..3).max_by_key(|&x| w[x].abs()).unwrap_or(0);
    // Every output voxel: its line (the point with `0 <= key_a < |w_a|` on it), its position
    // `m` on the line (larger is nearer the light), and where it goes.
    let mut voxels: Vec<([i64; 3], i64, u32, u16)> = Vec::new();
    for (li, l) in leaves.iter().enumerate() {
        for n in 0..512usize {
            if bit(&l.active, n) {
                let c = [
                    i64::from(l.origin[0]) + (n >> 6) as i64,
                    i64::from(l.origin[1]) + ((n >> 3) & 7) as i64,
                    i64::from(l.origin[2]) + (n & 7) as i64,
                ];
                let m = c[a].div_euclid(w[a]);
                let key = [0, 1, 2].map(|k| c[k] - m * w[k]);
                voxels.push((key, m, li as u32, n as u16));
            }
        }
    }
    voxels.sort_unstable_by(|x, y| x.0.cmp(&y.0).then(y.1.cmp(&x.1)));
    let mut lines: Vec<std::ops::Range<usize>> = Vec::new();
    let mut start = 0;
    for i in 1..=voxels.len() {
        if i == voxels.len() || voxels[i].0 != voxels[start].0 {
            lines.push(start..i);
            start = i;
        }
    }
    let wv = glam::DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64);
    let step_len = vol.world_from_index().matrix3.mul_vec3(wv).length();
    let scale = vol.density_scale();
    let shift = opts.interp.shift();
    let dir = wv.to_array();
    let results = lines
        .par_iter()
        .map(|range| {
            let mut acc = Accessor::new(vol.tree());
            let mut out = Vec::with_capacity(range.len());
            let (mut rays, mut lookups) = (0u64, 0u64);
            let mut last: Option<(i64, f64)> = None;
            for &(key, m, li, n) in &voxels[range.clone()] {
                let c = [0, 1, 2].map(|k| key[k] + m * w[k]);
                let tau = match last.filter(|(from, _)| from - m <= MAX_STEPS / 8) {
                    Some((from, tau)) => {
                        let mut sum = 0.0f64;
                        let mut cells = 0u64;
                        for s in m..from {
                            let q = [0, 1, 2].map(|k| (key[k] + s * w[k]) as f64 + shift);
                            sum += crate::regular::integrate_cells(
                                &mut acc,
                                q,
                                dir,
                                0.0,
                                1.0,
                                opts.interp,
                                &mut cells,
                            );
                        }
                        lookups += cells;
                        tau + crate::math::scaled(scale, sum) * step_len
                    }
                    None => {
                        let p =
                            vol.to_world(glam::DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64));
                        let ray = light.ray_from(vol, p.to_array())?;
                        let od = crate::regular::optical_depth(vol, &ray, opts.interp)?;
                        rays += 1;
                        lookups += od.lookups;
                        od.tau
                    }
                };
                out.push((li, n, (-tau).exp() as f32));
                last = Some((m, tau));
            }
            progress.advance(range.len() as u64);
            Ok((out, rays, lookups))
        })
        .collect::<Result<Vec<_>>>()?;
    let (mut rays, mut lookups) = (0, 0);
    for (out, r, l) in results {
        rays += r;
        lookups += l;
        for (li, n, v) in out {
            leaves[li as usize].values[usize::from(n)] = v;
        }
    }
    Ok((rays, lookups))
}
