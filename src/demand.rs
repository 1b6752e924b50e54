//! What a job touches: the leaves whose values a set of rays can read, so that a hero-size
//! cache is decoded only where the job looks ([`crate::vdb::LazyGrid::load`]).
//!
//! A walk's path through the tree depends on the topology alone (root table, child masks,
//! value box), never on values. `traverse::touched_blocks` replays it and reports every block it
//! visits at the job's granularity. Every value the job can read along the ray, and every bound
//! it uses, lies in the closed box `[o, o + dim]` of a visited block `(o, dim)`:
//! - a leaf segment's lookups and its exact integral read the leaf and, for trilinear cells,
//!   the one-voxel layer on its + faces; its bounds (`bounds`, `halo`) are made of exactly those;
//! - a tile's halo is its value and the + neighbours' faces, again inside `[o, o + dim]`;
//! - coarser granularities use a lower or upper node's bounds, made of all its leaves.
//!
//! So loading the leaves that meet those boxes makes every bound and value such a walk reads
//! equal to an eager load's, and every answer on those rays is bit-identical (tested).
//!
//! A moving volume ([`Volume::moving`]) is walked by its blurred bounds instead: `8^3` blocks
//! of the bounds' dense box along the ray (the walk of `estimate::blur`), every lookup of a
//! point of block `c` at any shutter time reading density within the block's reach
//! ([`crate::motion::Motion::block_reads`]: the reach its majorant was made with, the lookup
//! stencil and a voxel more). The leaves meeting those boxes are what its rays can read; the
//! bounds themselves are the motion's, built once for the whole grid.

use crate::motion::Motion;
use crate::ray::Ray;
use crate::traverse::{dda, touched_blocks, Cells, Granularity};
use crate::volume::{Interp, Volume};
use rayon::prelude::*;
use std::collections::HashSet;
use std::ops::ControlFlow;

/// The leaves of `vol`'s tree (indices into [`crate::tree::Tree::leaves`], increasing) whose
/// values a walk of any of `rays` at `gran` under `interp` reads, or whose values make up a
/// bound it reads. Reads topology only (`vol` may be a shell, see
/// [`crate::vdb::LazyGrid::shell`]). Parallel over rays; the answer does not depend on the
/// thread count.
#[must_use]
pub fn leaves_touched(vol: &Volume, rays: &[Ray], interp: Interp, gran: Granularity) -> Vec<u32> {
    if let Some(m) = vol.moving() {
        return leaves_touched_blurred(vol, m, rays);
    }
    let tree = vol.tree();
    let words = tree.leaves().len().div_ceil(64);
    let mark = |mut set: Vec<u64>, ray: &Ray| {
        touched_blocks(vol, ray, interp, gran, |o, dim| {
            let hi = o.map(|c| c + dim);
            tree.leaves_in_box(o, hi, &mut |l| set[l as usize >> 6] |= 1 << (l & 63));
        });
        set
    };
    marked(rays, words, mark)
}

/// [`leaves_touched`] of a moving volume: the blocks of the blurred bounds each ray crosses,
/// then the leaves within each distinct block's reach (module docs).
fn leaves_touched_blurred(vol: &Volume, m: &Motion, rays: &[Ray]) -> Vec<u32> {
    let (lo, dims) = m.bounds().dense_box();
    if dims.contains(&0) {
        return Vec::new();
    }
    let cells = Cells {
        size: 8.0,
        lo,
        hi: [0, 1, 2].map(|k| lo[k] + dims[k] as i64 - 1),
    };
    let visit = |mut blocks: HashSet<[i64; 3]>, ray: &Ray| {
        let q = vol.to_index(ray.origin()).to_array();
        let d = vol.to_index_dir(ray.direction()).to_array();
        // The walk starts where the ray enters the box of blocks (as the estimator's does).
        let Some(range) = m.bounds().clip(q, d, (ray.t_min(), ray.t_max())) else {
            return blocks;
        };
        let _ = dda(q, d, range, &cells, |c, _, _| {
            blocks.insert(c);
            ControlFlow::Continue(())
        });
        blocks
    };
    let blocks = rays
        .par_iter()
        .fold(HashSet::new, visit)
        .reduce(HashSet::new, |mut a, b| {
            a.extend(b);
            a
        });
    let mut blocks: Vec<[i64; 3]> = blocks.into_iter().collect();
    blocks.sort_unstable();
    let tree = vol.tree();
    let words = tree.leaves().len().div_ceil(64);
    let ifw = vol.index_from_world();
    let mark = |mut set: Vec<u64>, c: &[i64; 3]| {
        let [lo, hi] = m.block_reads(&ifw, *c);
        tree.leaves_in_box(lo, hi, &mut |l| set[l as usize >> 6] |= 1 << (l & 63));
        set
    };
    marked(&blocks, words, mark)
}

/// The leaf indices `mark` sets (in a bit set of `words` words) over `items`, increasing; in
/// parallel, the same answer for any thread count.
fn marked<T: Sync>(
    items: &[T],
    words: usize,
    mark: impl Fn(Vec<u64>, &T) -> Vec<u64> + Sync + Send,
) -> Vec<u32> {
    let set = items.par_iter().fold(|| vec![0u64; words], mark).reduce(
        || vec![0u64; words],
        |mut a, b| {
            a.iter_mut().zip(b).for_each(|(x, y)| *x |= y);
            a
        },
    );
    let mut out = Vec::new();
    for (w, &word) in set.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            out.push((w * 64 + bits.trailing_zeros() as usize) as u32);
            bits &= bits - 1;
        }
    }
    out
}
