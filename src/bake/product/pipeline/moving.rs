//! A blurred map in parts (`--max-memory` with a velocity): the shell of the density set moving
//! as a whole load would set it, from two numbers per leaf.
//!
//! The blurred bounds ([`crate::motion::BlurBounds`]) need the largest and smallest value of
//! every density leaf, never the values together: a streaming pass decodes the leaves a few
//! lower nodes at a time ([`crate::vdb::LazyGrid::load_region`]), keeps each leaf's
//! `(max, min)` after the bad-voxel policy (what a whole load's bounds hold) and drops the
//! values. The velocity is loaded whole (its three component trees). The shell then carries
//! the motion (bounds bit for bit the whole load's), the camera is framed from its blurred
//! box, and each run of rows on the ray path decodes the density leaves within the reach of
//! the blocks its rays cross (`crate::demand`) and shares the shell's motion.

use super::BakeJob;
use crate::error::Result;
use crate::vdb::LazyGrid;
use crate::volume::Volume;

/// The shell of a moving grid, set moving, and what its motion holds.
pub(super) struct MovingShell {
    /// The shell volume carrying the whole grid's motion.
    pub(super) shell: Volume,
    /// Bytes held while the parts are baked: the velocity's trees and the blurred bounds.
    pub(super) held: u64,
    /// Bytes held for a moment while the bounds are built (their per-block scratch).
    pub(super) building: u64,
}

impl BakeJob {
    /// The motion of this job's source on `shell` (the lazily opened grid's topology as a
    /// volume), its leaf ranges read `chunk_bytes` of decoded values at a time; `None` when
    /// the source does not move.
    ///
    /// # Errors
    /// As [`crate::motion::MotionRequest::field`] and [`Volume::with_summarised_motion`];
    /// decoding errors of the leaves.
    pub(super) fn moving_shell(
        &self,
        lazy: &LazyGrid,
        shell: Volume,
        chunk_bytes: impl FnOnce(u64) -> u64,
    ) -> Result<std::result::Result<MovingShell, Volume>> {
        let Some(m) = crate::motion::MotionRequest::of(self.source.options())? else {
            return Ok(Err(shell));
        };
        let field = m.field(self.source.path())?;
        let field_bytes = field.memory_bytes();
        let chunk = (chunk_bytes(field_bytes) / LEAF_VALUES).max(1);
        let ranges = self.leaf_ranges(lazy, shell.tree(), chunk)?;
        let shell = shell.with_summarised_motion(m.spec, field, &ranges)?;
        let blocks = shell.motion().map_or(0, |m| m.bounds().blocks() as u64);
        Ok(Ok(MovingShell {
            shell,
            held: field_bytes + blocks * 8,
            building: blocks * 16,
        }))
    }

    /// The `(max, min)` of every leaf of `topology` (this grid's, as the shell holds it) as a
    /// whole load bounds it (after the bad-voxel policy), decoding about `chunk` leaves at a
    /// time: whole lower nodes each time, as regions of the tree.
    fn leaf_ranges(
        &self,
        lazy: &LazyGrid,
        topology: &crate::tree::Tree,
        chunk: u64,
    ) -> Result<Vec<(f32, f32)>> {
        let leaves = topology.leaves();
        // Leaves by lower node (every leaf sits in one).
        let mut by_lower: Vec<Vec<u32>> = vec![Vec::new(); topology.lowers().len()];
        for (i, l) in leaves.iter().enumerate() {
            if let Some(n) = topology.lower_at(l.origin.map(i64::from)) {
                by_lower[n as usize].push(i as u32);
            }
        }
        let mut ranges: Vec<Option<(f32, f32)>> = vec![None; leaves.len()];
        let mut start = 0;
        while start < by_lower.len() {
            let (mut end, mut n) = (start, 0u64);
            while end < by_lower.len() && (end == start || n + by_lower[end].len() as u64 <= chunk)
            {
                n += by_lower[end].len() as u64;
                end += 1;
            }
            let lowers: Vec<u32> = (start as u32..end as u32).collect();
            let ids: Vec<u32> = by_lower[start..end].concat();
            start = end;
            if ids.is_empty() {
                continue;
            }
            let (grid, index) = lazy.load_region(topology, &lowers, &ids)?;
            let part = self.volume_of(grid)?;
            for &l in &ids {
                if let Some(r) = index.leaf(l) {
                    let b = part.tree().leaves()[r as usize].bounds;
                    ranges[l as usize] = Some((b.max, b.min));
                }
            }
        }
        if let Some(l) = ranges.iter().position(Option::is_none) {
            return Err(crate::error::Error::Invalid {
                path: self.source.path().to_path_buf(),
                reason: format!(
                    "leaf {l} at {:?} lies in no lower node of the topology",
                    leaves[l].origin
                ),
            });
        }
        Ok(ranges.into_iter().flatten().collect())
    }
}

/// A decoded leaf's values, bytes.
const LEAF_VALUES: u64 = std::mem::size_of::<[f32; 512]>() as u64;
