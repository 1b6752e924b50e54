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

use crate::ray::Ray;
use crate::traverse::{touched_blocks, Granularity};
use crate::volume::{Interp, Volume};
use rayon::prelude::*;

/// The leaves of `vol`'s tree (indices into [`crate::tree::Tree::leaves`], increasing) whose
/// values a walk of any of `rays` at `gran` under `interp` reads, or whose values make up a
/// bound it reads. Reads topology only (`vol` may be a shell, see
/// [`crate::vdb::LazyGrid::shell`]). Parallel over rays; the answer does not depend on the
/// thread count.
#[must_use]
pub fn leaves_touched(vol: &Volume, rays: &[Ray], interp: Interp, gran: Granularity) -> Vec<u32> {
    let tree = vol.tree();
    let words = tree.leaves().len().div_ceil(64);
    let mark = |mut set: Vec<u64>, ray: &Ray| {
        touched_blocks(vol, ray, interp, gran, |o, dim| {
            let hi = o.map(|c| c + dim);
            tree.leaves_in_box(o, hi, &mut |l| set[l as usize >> 6] |= 1 << (l & 63));
        });
        set
    };
    let set = rays.par_iter().fold(|| vec![0u64; words], mark).reduce(
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
