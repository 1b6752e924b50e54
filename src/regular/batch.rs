//! Exact optical depths of many rays at once: leaf blocks in object order on the SIMD kernel.
//!
//! A query batch (`umbra query --rays`, Python's `Volume.transmittance` on arrays) is made of
//! incoherent rays, so the map sweep's footprints do not apply, but its kernel does: each ray
//! is walked as [`super::optical_depth`] walks it (the hierarchical DDA at leaf granularity;
//! tiles and constant segments in closed form, leaves outside the kernel's range by the f64
//! code), except that the chord of every leaf the kernel takes ([`kernel_ok`] on the leaf's
//! halo) is set aside: `(leaf, entry e, direction d, length)`. The chords are then grouped by
//! leaf; each leaf's `9^3` trilinear corners are copied into L1 once and its chords integrated
//! 16 (AVX-512) or 8 at a time ([`Kernel::integrate`]: exact per dual cell, f32 cells summed in f64,
//! AVX-512 / AVX2 / portable, bit for bit the same). A ray's optical depth is the sum of its
//! walked parts plus its chords' integrals in the order the walk met them, so it depends on the
//! ray alone: not on the other rays of the batch, their order or the thread count.
//!
//! **Precision.** As the sweep's maps: the kernel's positions are f32 relative to the block
//! centre, so each chord's integral is within ~1e-6 relative of the f64 walk's (the tests
//! compare every ray with [`super::optical_depth`]).
//!
//! **Memory.** Rays go in chunks of [`CHUNK`] (about 40 bytes a chord, a chord per leaf a ray
//! crosses), chunks in parallel on rayon's threads.

use super::kernel::{blocks_around, fill, kernel_ok, max_chord, Kernel, Lanes, BLOCK};
use super::{leaf_integral, walk_tau, Counts, OpticalDepth};
use crate::error::Result;
use crate::math::non_empty;
use crate::ray::Ray;
use crate::traverse::{lookup_ray, Granularity, Segment};
use crate::tree::{Accessor, Block};
use crate::volume::{Interp, Volume};
use rayon::prelude::*;

/// Rays walked before their chords are integrated: enough that a leaf gathers many chords
/// (full kernel batches, one copy of its corners for all of them), few enough that the chords
/// stay in cache-sized tens of megabytes.
pub(crate) const CHUNK: usize = 16_384;

/// A leaf chord set aside for the kernel.
#[derive(Debug, Clone, Copy)]
struct Chord {
    /// Leaf index.
    leaf: u32,
    /// Ray index in the chunk.
    ray: u32,
    /// Block-centred entry point (lookup space minus `leaf origin + 4`).
    e: [f64; 3],
    /// World length inside the leaf's block.
    len: f64,
}

/// What the walk of one ray left: its walked optical depth, its chords `[first, end)` in the
/// chunk's list, and its counts.
#[derive(Debug, Clone, Copy, Default)]
struct Walked {
    tau: f64,
    first: usize,
    end: usize,
    segments: u64,
    counts: (u64, u64),
    /// Lookup-space direction (what the kernel's lanes take).
    d: [f64; 3],
}

/// Exact optical depth of every ray of `rays` through `vol` ([`super::optical_depth`] of each,
/// the trilinear leaves on the SIMD kernel): one result per ray, in order; a ray whose optical
/// depth is NaN gets its own error. Nearest lookups go ray by ray (the kernel is trilinear).
pub fn optical_depths(vol: &Volume, rays: &[Ray], interp: Interp) -> Vec<Result<OpticalDepth>> {
    if interp != Interp::Trilinear {
        return rays
            .par_iter()
            .map(|r| super::optical_depth(vol, r, interp))
            .collect();
    }
    let chunks: Vec<Vec<Result<OpticalDepth>>> = rays
        .par_chunks(CHUNK)
        .map(|chunk| chunk_depths(vol, chunk))
        .collect();
    chunks.into_iter().flatten().collect()
}

/// [`optical_depths`] of one chunk, on this thread.
fn chunk_depths(vol: &Volume, rays: &[Ray]) -> Vec<Result<OpticalDepth>> {
    let tree = vol.tree();
    let scale = vol.density_scale();
    let chord_max = max_chord(vol);
    let mut acc = Accessor::new(tree);
    let mut chords: Vec<Chord> = Vec::new();
    let mut walked = vec![Walked::default(); rays.len()];
    for (r, (ray, out)) in rays.iter().zip(&mut walked).enumerate() {
        let (q, d) = lookup_ray(vol, ray, Interp::Trilinear);
        let first = chords.len();
        let mut n = Counts::default();
        let leaf = |acc: &mut Accessor<'_>, s: Segment, leaf: u32, n: &mut Counts| {
            if s.is_constant() {
                return s.mu_min * s.length();
            }
            let l = &tree.leaves[leaf as usize];
            if !kernel_ok(l.halo.min, l.halo.max, chord_max) {
                let (a, b) = (s.t_min, s.t_max);
                return scale * leaf_integral(acc, leaf, q, d, a, b, Interp::Trilinear, n);
            }
            if non_empty(s.t_min, s.t_max) {
                let centre = l.origin.map(|c| f64::from(c) + 4.0);
                chords.push(Chord {
                    leaf,
                    ray: r as u32,
                    e: [0, 1, 2].map(|k| q[k] + d[k] * s.t_min - centre[k]),
                    len: s.length(),
                });
            }
            0.0
        };
        let (tau, w) = walk_tau(
            vol,
            ray,
            Interp::Trilinear,
            Granularity::Leaf,
            &mut acc,
            &mut n,
            leaf,
        );
        *out = Walked {
            tau,
            first,
            end: chords.len(),
            segments: w.segments,
            counts: (n.cells, n.reads),
            d,
        };
    }
    let (values, cells) = integrate_chords(vol, &walked, &chords, &mut acc);
    rays.iter()
        .zip(&walked)
        .map(|(ray, w)| {
            let mut tau = w.tau;
            let (mut n_cells, mut reads) = w.counts;
            for (v, c) in values[w.first..w.end].iter().zip(&cells[w.first..w.end]) {
                tau += scale * v;
                n_cells += u64::from(*c);
                reads += if *c > 0 { 4 + 4 * u64::from(*c) } else { 0 };
            }
            if tau.is_nan() {
                return Err(crate::error::Error::nan_on_ray("optical depth", ray));
            }
            Ok(OpticalDepth {
                tau,
                lookups: reads,
                segments: w.segments,
                cells: n_cells,
            })
        })
        .collect()
}

/// Each chord's unscaled integral and dual cells, in the chords' order: leaf by leaf, each
/// leaf's corners filled once and its chords run [`Kernel::width`] at a time.
fn integrate_chords<'t>(
    vol: &'t Volume,
    walked: &[Walked],
    chords: &[Chord],
    acc: &mut Accessor<'t>,
) -> (Vec<f64>, Vec<u32>) {
    let tree = vol.tree();
    // The chords grouped by leaf (a counting sort: linear in chords and leaves).
    let mut start = vec![0u32; tree.leaves.len() + 1];
    for c in chords {
        start[c.leaf as usize + 1] += 1;
    }
    for i in 1..start.len() {
        start[i] += start[i - 1];
    }
    let mut order = vec![0u32; chords.len()];
    for (i, c) in chords.iter().enumerate() {
        let at = &mut start[c.leaf as usize];
        order[*at as usize] = i as u32;
        *at += 1;
    }
    let kernel = Kernel::new();
    let mut block = [0f32; BLOCK];
    let (mut values, mut cells) = (vec![0.0f64; chords.len()], vec![0u32; chords.len()]);
    for group in order.chunk_by(|&a, &b| chords[a as usize].leaf == chords[b as usize].leaf) {
        let leaf = chords[group[0] as usize].leaf;
        let origin = tree.leaves[leaf as usize].origin.map(i64::from);
        let first = Block::Leaf(tree.leaf_values(leaf));
        let around = blocks_around(tree, acc, origin, first, tree.neighbours.get(leaf as usize));
        fill(&around, &mut block);
        let mut lanes = Lanes::default();
        for batch in group.chunks(kernel.width()) {
            // Lanes this batch leaves unfilled read as unused.
            lanes.len = [0.0; super::kernel::LANES];
            for (l, &i) in batch.iter().enumerate() {
                let c = &chords[i as usize];
                lanes.set(l, c.e, walked[c.ray as usize].d, c.len);
            }
            let sums = kernel.integrate(&block, &lanes);
            for (l, &i) in batch.iter().enumerate() {
                values[i as usize] = sums.tau[l];
                cells[i as usize] = sums.cells[l];
            }
        }
    }
    (values, cells)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    /// A test volume: a blob of leaves with smooth, varying values.
    fn blob() -> Volume {
        let mut b = TreeBuilder::new(0.0);
        for x in -20..20i32 {
            for y in -12..16i32 {
                for z in -16..10i32 {
                    let r2 = (x * x + y * y + z * z) as f32;
                    if r2 < 300.0 {
                        b.set([x, y, z], 1.0 + (x as f32 * 0.3).sin() + 0.01 * r2.sqrt());
                    }
                }
            }
        }
        // Voxels of 0.5 world units, sheared a little, moved off the origin.
        let xf = [
            [0.5, 0.05, 0.0, 1.0],
            [0.0, 0.5, 0.0, -2.0],
            [0.0, 0.0, 0.5, 0.25],
        ];
        Volume::from_tree("blob".into(), b.build(), xf, 0.7).expect("volume")
    }

    /// Every ray of a batch within 1e-6 relative (plus 1e-9) of the f64 walk, whatever the
    /// chunk it falls in; the same ray alone gives the same bits.
    #[test]
    fn batch_matches_the_ray_walk() {
        let vol = blob();
        let mut st = 3u64;
        let mut next = || {
            st = st
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (st >> 11) as f64 / (1u64 << 53) as f64 * 24.0 - 12.0
        };
        let mut rays = Vec::new();
        while rays.len() < 3000 {
            let (a, b) = ([next(), next(), next()], [next(), next(), next()]);
            if let Ok(r) = Ray::between(a, b) {
                rays.push(r);
            }
        }
        // Lattice-aligned rays too: along axes through voxel planes.
        rays.push(Ray::between([-30.0, 0.0, 0.0], [30.0, 0.0, 0.0]).expect("ray"));
        rays.push(Ray::between([0.5, -30.0, 2.0], [0.5, 30.0, 2.0]).expect("ray"));
        let got = optical_depths(&vol, &rays, Interp::Trilinear);
        let mut kernel_rays = 0;
        for (ray, g) in rays.iter().zip(&got) {
            let g = g.as_ref().expect("finite");
            let want = super::super::optical_depth(&vol, ray, Interp::Trilinear).expect("finite");
            // The sweep's bound: f32 positions move a cell's integral by `|grad f| 2^-23 h`,
            // so `1e-6 tau + 1e-7 M`, `M` the majorant optical depth.
            let mut maj = 0.0;
            crate::traverse::walk(&vol, ray, Interp::Trilinear, Granularity::Leaf, |s| {
                maj += s.mu_maj.abs() * s.length();
                std::ops::ControlFlow::Continue(())
            });
            assert!(
                (g.tau - want.tau).abs() <= 1e-6 * want.tau + 1e-7 * maj,
                "{} vs {} (majorant {maj})",
                g.tau,
                want.tau
            );
            assert_eq!(g.segments, want.segments);
            kernel_rays += usize::from(g.tau > 0.0);
            let alone = optical_depths(&vol, std::slice::from_ref(ray), Interp::Trilinear);
            assert_eq!(
                alone[0].as_ref().expect("finite").tau.to_bits(),
                g.tau.to_bits()
            );
        }
        assert!(kernel_rays > 1000, "{kernel_rays} rays met the blob");
    }
}
