//! Partial loads: open a grid by reading its topology and finding where each leaf's buffer
//! starts, then decode only the leaves a job touches, by positioned reads, on all cores.
//!
//! OpenVDB writes a grid as its topology (root table, internal nodes with their tiles, leaf
//! value masks) followed by the leaf buffers in the same depth-first order. A buffer's length
//! is not stored anywhere in the topology, so [`Archive::open_lazy`] walks the buffers once,
//! reading each header (value mask, metadata byte, inactive values, selection mask, the size
//! prefix of the value run) and stepping over the values: no decompression. After that,
//! leaf `i`'s bytes are `offsets[i]..offsets[i + 1]`, and any set of leaves decodes
//! independently ([`LazyGrid::load`]).

use super::decode::{self, Stream};
use super::values::Pick;
use super::{Archive, GridDescriptor, ValueKind};
use crate::error::{DecodeError, Result};
use crate::vdb::Grid;
use std::path::PathBuf;

/// A grid opened for partial reads: its identity, transform and topology, and where every
/// leaf's buffer is in the file (which stays open).
#[derive(Debug)]
pub struct LazyGrid {
    path: PathBuf,
    file: std::fs::File,
    /// The grid with every leaf present but unloaded (bounds [`crate::tree::Bounds::UNKNOWN`]).
    shell: Grid,
    stream: Stream,
    offsets: Vec<u64>,
    /// What converting the topology's doubles (background, tiles) to `f32` cost.
    topology_precision: crate::vdb::PrecisionLoss,
    /// Bytes of the grid's head (metadata, transform, topology) in the file.
    head_bytes: u64,
}

impl Archive {
    /// Open the grid `gd` (from this archive) for partial reads: read its head and topology
    /// and locate every leaf buffer, decoding no values. An instanced grid shares its
    /// parent's tree and buffers.
    ///
    /// # Errors
    /// As [`Archive::load`], for the head, the topology and the buffer headers; corrupt
    /// values are found only by the load that decodes them.
    pub fn open_lazy(&self, gd: &GridDescriptor) -> Result<LazyGrid> {
        self.open_lazy_as(gd, Pick::Length)
    }

    /// [`Archive::open_lazy`] with vector values (background, tiles, inactive and voxel
    /// values) decoded as `pick` says.
    pub(crate) fn open_lazy_as(&self, gd: &GridDescriptor, pick: Pick) -> Result<LazyGrid> {
        let path = &self.path;
        let kind = ValueKind::from_tree_type(&gd.tree_type).map_err(|e| e.at(path))?;
        let parent = if gd.instance_parent.is_empty() {
            None
        } else {
            Some(self.instance_parent(gd)?)
        };
        let (head, mut file) = self.head(gd, kind, parent.is_none().then_some(pick))?;
        let class = super::metadata::meta_string(&head.metadata, "class").map(str::to_string);
        let identity = |tree| Grid {
            name: gd.display_name.clone(),
            stored_name: gd.stored_name.clone(),
            value_type: kind,
            class: class.clone(),
            transform: head.transform.clone(),
            metadata: head.metadata.clone(),
            compression: head.compression,
            saved_as_half: gd.saved_as_half,
            tree,
            precision_loss: None,
        };
        match (head.topology, parent) {
            (Some(topology), _) => {
                let (mut tree, stream) = topology.into_parts();
                let table = head.delayed_load.as_deref().and_then(|t| {
                    decode::offsets_from_table(t, &tree, &stream, gd.block_pos, gd.end_pos)
                });
                let offsets = match table {
                    Some(o) => o,
                    None => {
                        let mut buffers =
                            decode::BufferWindow::new(&mut file, path, gd.block_pos, gd.end_pos);
                        decode::locate_buffers(&tree, &stream, &mut buffers)?
                    }
                };
                tree.shell = true;
                tree.bounds = crate::tree::Bounds::UNKNOWN;
                Ok(LazyGrid {
                    path: path.clone(),
                    file,
                    topology_precision: stream.precision.get(),
                    stream: Stream::of(&stream),
                    offsets,
                    shell: identity(tree),
                    head_bytes: gd.block_pos.saturating_sub(gd.grid_pos),
                })
            }
            (None, Some(parent)) => {
                let mut p = self.open_lazy_as(parent, pick)?;
                let tree = std::mem::take(&mut p.shell.tree);
                p.shell = identity(tree);
                p.head_bytes = gd.block_pos.saturating_sub(gd.grid_pos);
                Ok(p)
            }
            (None, None) => {
                let why = "grid has neither a tree nor an instance parent";
                Err(DecodeError::invalid(why).at(path))
            }
        }
    }
}

impl LazyGrid {
    /// The grid without values: identity, metadata, transform and the full topology, every
    /// leaf unloaded (its values read as NaN, its bounds are not computed, and every walk over
    /// it stops as unloaded, so nothing traced through it returns a number). What a job plans
    /// its rays with before it loads.
    #[must_use]
    pub fn shell(&self) -> &Grid {
        &self.shell
    }

    /// The file it reads.
    #[must_use]
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Bytes of the grid's head in the file: its metadata, transform and topology, what
    /// opening it read before the leaf buffers (for an instance, its own head).
    #[must_use]
    pub fn head_bytes(&self) -> u64 {
        self.head_bytes
    }

    /// Number of leaves in the grid.
    #[must_use]
    pub fn leaf_count(&self) -> usize {
        self.shell.tree.leaves.len()
    }

    /// Where leaf `leaf`'s buffer (value mask, flags, compressed values) is in the file, as a
    /// byte range; `None` past the leaf count.
    #[must_use]
    pub fn buffer_range(&self, leaf: u32) -> Option<std::ops::Range<u64>> {
        let l = leaf as usize;
        Some(*self.offsets.get(l)?..*self.offsets.get(l + 1)?)
    }

    /// Bytes of leaf buffers in the file (compressed).
    #[must_use]
    pub fn buffer_bytes(&self) -> u64 {
        match (self.offsets.first(), self.offsets.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0,
        }
    }

    /// The statistics of the whole grid ([`crate::tree::Tree::stats`] of an eager load, equal
    /// to the bit) and the double-to-float cost, streamed: chunks of leaves are decoded on all
    /// cores, summarised and dropped, so memory holds the topology and a few chunks, never the
    /// decoded grid. What `umbra info` reports.
    ///
    /// # Errors
    /// As [`LazyGrid::load`].
    pub fn stats(&self) -> Result<(crate::tree::TreeStats, Option<crate::vdb::PrecisionLoss>)> {
        let tree = &self.shell.tree;
        let precision = std::sync::Mutex::new(None::<crate::vdb::PrecisionLoss>);
        let stats = tree.stats_by(|range, f| -> Result<()> {
            let ids: Vec<u32> = (range.start as u32..range.end as u32).collect();
            let mut values = vec![[0f32; 512]; ids.len()];
            let p = decode::decode_leaves(
                &self.file,
                &self.path,
                self.stream,
                tree,
                &self.offsets,
                &ids,
                &mut values,
            )?;
            if let Some(p) = p {
                let mut all = precision
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                all.get_or_insert_with(Default::default).merge(p);
            }
            for (&l, v) in ids.iter().zip(&values) {
                f(&tree.leaves[l as usize], v);
            }
            Ok(())
        })?;
        let p = precision
            .into_inner()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        Ok((stats, self.with_topology_precision(p)))
    }

    /// Bytes the decoded grid's tree takes ([`crate::tree::Tree::memory_bytes`] after a full
    /// load), from the topology: the shell's nodes, plus per leaf its values, neighbour table
    /// and faces, plus the lower nodes' tile-slot halos and every node's faces. Upper nodes'
    /// halo exceptions (a few tile slots next to data) are not counted.
    #[must_use]
    pub fn loaded_memory_bytes(&self) -> u64 {
        let t = &self.shell.tree;
        let faces = std::mem::size_of::<[crate::tree::Bounds; 7]>();
        let per_leaf = std::mem::size_of::<[f32; 512]>()
            + std::mem::size_of::<[crate::tree::Neighbour; 7]>()
            + faces;
        let lower = 4096 * std::mem::size_of::<crate::tree::Bounds>() + faces;
        t.memory_bytes()
            + (t.leaves.len() * per_leaf + t.lowers.len() * lower + t.uppers.len() * faces) as u64
    }

    /// The grid with the values of `leaves` (indices into the topology's leaves, any order,
    /// repeats allowed) decoded and every other leaf unloaded. Bounds are recomputed: those of
    /// loaded leaves, and of everything whose halo reads only loaded leaves, are exact; the
    /// rest are unknown. Rays whose walks stay on loaded leaves give exactly what an eager
    /// load gives (`Volume::load_for` picks the leaves).
    ///
    /// # Errors
    /// [`crate::error::Error::Io`] if the file cannot be read, [`crate::error::Error::Invalid`] naming the
    /// file, the leaf and the byte offset of its buffer when its data is corrupt;
    /// [`crate::error::Error::InvalidArgument`] for an index past the leaf count.
    pub fn load(&self, leaves: &[u32]) -> Result<Grid> {
        let ids = self.check_leaves(leaves)?;
        self.decode(&ids, self.shell.tree.clone())
    }

    /// Move the shell out (the lazy grid keeps its identity but no topology: only
    /// [`LazyGrid::load_from`] loads after this). For callers that keep the topology in a
    /// volume of their own instead of twice.
    pub(crate) fn take_shell(&mut self) -> Grid {
        let tree = std::mem::take(&mut self.shell.tree);
        let mut g = self.shell.clone_without_tree();
        g.tree = tree;
        g
    }

    /// [`LazyGrid::load`] onto a copy of `topology`, this grid's topology as a shell volume
    /// holds it (after [`LazyGrid::take_shell`]).
    pub(crate) fn load_from(&self, topology: &crate::tree::Tree, leaves: &[u32]) -> Result<Grid> {
        let ids = self.check_leaves(leaves)?;
        self.check_topology(topology)?;
        self.decode(&ids, topology.clone())
    }

    /// The region of `topology` (this grid's, as [`LazyGrid::load_from`]) made of the lower
    /// nodes `lowers` ([`crate::tree::Tree::region`]), with the values of `leaves` (topology
    /// indices, each in a kept lower node) decoded and its bounds computed over the region
    /// alone: what a part of a bake in parts holds, in place of a copy of the whole topology.
    ///
    /// # Errors
    /// As [`LazyGrid::load`]; [`crate::error::Error::InvalidArgument`] for a leaf outside the kept
    /// lower nodes.
    pub(crate) fn load_region(
        &self,
        topology: &crate::tree::Tree,
        lowers: &[u32],
        leaves: &[u32],
    ) -> Result<(Grid, crate::tree::RegionIndex)> {
        let ids = self.check_leaves(leaves)?;
        self.check_topology(topology)?;
        let (tree, index) = topology.region(lowers);
        let mut at = Vec::with_capacity(ids.len());
        for &l in &ids {
            at.push(
                index
                    .leaf(l)
                    .ok_or_else(|| crate::error::Error::InvalidArgument {
                        name: "leaves".into(),
                        reason: format!("leaf {l} is outside the region's lower nodes"),
                    })?,
            );
        }
        let (values, precision) = self.read_values(topology, &ids)?;
        Ok((self.grid_of(tree, &at, values, precision), index))
    }

    /// An error unless `topology` has this grid's leaf count.
    fn check_topology(&self, topology: &crate::tree::Tree) -> Result<()> {
        if topology.leaves.len() + 1 != self.offsets.len() {
            return Err(crate::error::Error::InvalidArgument {
                name: "topology".into(),
                reason: "not this grid's topology".into(),
            });
        }
        Ok(())
    }

    /// [`LazyGrid::load`], giving up the lazy grid (its topology becomes the grid's tree
    /// instead of being copied).
    ///
    /// # Errors
    /// As [`LazyGrid::load`].
    pub fn into_partial(mut self, leaves: &[u32]) -> Result<Grid> {
        let ids = self.check_leaves(leaves)?;
        let tree = std::mem::take(&mut self.shell.tree);
        self.decode(&ids, tree)
    }

    /// `leaves` sorted, without repeats, each checked against the leaf count.
    fn check_leaves(&self, leaves: &[u32]) -> Result<Vec<u32>> {
        // From the offsets: the count stays known after `take_shell`.
        let n = self.offsets.len().saturating_sub(1);
        let mut ids = leaves.to_vec();
        ids.sort_unstable();
        ids.dedup();
        if let Some(&l) = ids.last().filter(|&&l| l as usize >= n) {
            return Err(crate::error::Error::InvalidArgument {
                name: "leaves".into(),
                reason: format!("leaf {l} of a grid with {n} leaves"),
            });
        }
        Ok(ids)
    }

    /// The whole grid, every leaf decoded (on all of rayon's threads for large grids): what
    /// [`Archive::load`] returns.
    ///
    /// # Errors
    /// As [`LazyGrid::load`].
    pub fn load_all(mut self) -> Result<Grid> {
        let ids: Vec<u32> = (0..self.leaf_count() as u32).collect();
        let tree = std::mem::take(&mut self.shell.tree);
        self.decode(&ids, tree)
    }

    fn decode(&self, ids: &[u32], tree: crate::tree::Tree) -> Result<Grid> {
        let (values, precision) = self.read_values(&tree, ids)?;
        Ok(self.grid_of(tree, ids, values, precision))
    }

    /// The values of the topology's leaves `ids` (sorted), decoded, with their double-to-float
    /// cost.
    fn read_values(
        &self,
        topology: &crate::tree::Tree,
        ids: &[u32],
    ) -> Result<(Vec<[f32; 512]>, Option<crate::vdb::PrecisionLoss>)> {
        let mut values = vec![[0f32; 512]; ids.len()];
        let precision = decode::decode_leaves(
            &self.file,
            &self.path,
            self.stream,
            topology,
            &self.offsets,
            ids,
            &mut values,
        )?;
        Ok((values, precision))
    }

    /// The grid of `tree` holding `values[k]` at its leaf `at[k]`, bounds computed.
    fn grid_of(
        &self,
        mut tree: crate::tree::Tree,
        at: &[u32],
        values: Vec<[f32; 512]>,
        precision: Option<crate::vdb::PrecisionLoss>,
    ) -> Grid {
        for (k, &l) in at.iter().enumerate() {
            tree.leaves[l as usize].data = k as u32;
        }
        tree.values = values;
        tree.shell = false;
        tree.compute_bounds();
        let mut grid = self.shell.clone_without_tree();
        grid.tree = tree;
        grid.precision_loss = self.with_topology_precision(precision);
        grid
    }

    /// The leaves' double-to-float cost and the topology's together (double grids only).
    fn with_topology_precision(
        &self,
        leaves: Option<crate::vdb::PrecisionLoss>,
    ) -> Option<crate::vdb::PrecisionLoss> {
        if self.stream.kind != ValueKind::Double || self.stream.half {
            return None;
        }
        let mut p = self.topology_precision;
        if let Some(l) = leaves {
            p.merge(l);
        }
        Some(p)
    }
}

impl Grid {
    /// Everything but the tree (and the precision report, which belongs to a decode).
    fn clone_without_tree(&self) -> Self {
        Self {
            name: self.name.clone(),
            stored_name: self.stored_name.clone(),
            value_type: self.value_type,
            class: self.class.clone(),
            transform: self.transform.clone(),
            metadata: self.metadata.clone(),
            compression: self.compression,
            saved_as_half: self.saved_as_half,
            tree: crate::tree::Tree::default(),
            precision_loss: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `.vdb` of `data/` and the shared corpus (where present).
    fn files() -> Vec<PathBuf> {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
        let mut out = Vec::new();
        for dir in [
            root.join("data"),
            root.join("../shared/corpus/gen"),
            root.join("../shared/corpus/real"),
        ] {
            let Ok(entries) = std::fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.flatten() {
                if e.path().extension().is_some_and(|x| x == "vdb") {
                    out.push(e.path());
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn the_delayed_load_table_gives_the_offsets_the_scan_finds() {
        let mut with_table = 0;
        for path in files() {
            let Ok(archive) = Archive::open(&path) else {
                continue;
            };
            for gd in &archive.grids {
                let Ok(kind) = ValueKind::from_tree_type(&gd.tree_type) else {
                    continue;
                };
                if !gd.instance_parent.is_empty() {
                    continue;
                }
                let (head, mut file) = archive.head(gd, kind, Some(Pick::Length)).unwrap();
                let (tree, stream) = head.topology.unwrap().into_parts();
                let mut buffers =
                    decode::BufferWindow::new(&mut file, &path, gd.block_pos, gd.end_pos);
                let scanned = decode::locate_buffers(&tree, &stream, &mut buffers).unwrap();
                assert_eq!(scanned.last(), Some(&gd.end_pos), "{}", path.display());
                let Some(table) = head.delayed_load else {
                    continue;
                };
                let from_table =
                    decode::offsets_from_table(&table, &tree, &stream, gd.block_pos, gd.end_pos);
                if kind != ValueKind::Bool && (stream.compression.blosc || stream.compression.zip) {
                    assert_eq!(
                        from_table.as_ref(),
                        Some(&scanned),
                        "{} grid {}",
                        path.display(),
                        gd.display_name
                    );
                    with_table += 1;
                } else {
                    assert!(from_table.is_none());
                }
            }
        }
        assert!(with_table >= 10, "only {with_table} grids with a table");
    }

    #[test]
    fn a_table_that_does_not_add_up_is_not_used() {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
        let archive = Archive::open(&path).unwrap();
        let gd = archive.find_grid("density").unwrap();
        let kind = ValueKind::from_tree_type(&gd.tree_type).unwrap();
        let (head, _) = archive.head(gd, kind, Some(Pick::Length)).unwrap();
        let (tree, stream) = head.topology.unwrap().into_parts();
        let table = head.delayed_load.unwrap();
        let (a, b) = (gd.block_pos, gd.end_pos);
        assert!(decode::offsets_from_table(&table, &tree, &stream, a, b).is_some());
        assert!(decode::offsets_from_table(&table, &tree, &stream, a, b + 1).is_none());
        assert!(
            decode::offsets_from_table(&table[..table.len() - 1], &tree, &stream, a, b).is_none()
        );
        let mut other = table.clone();
        other[0] ^= 1; // another leaf count
        assert!(decode::offsets_from_table(&other, &tree, &stream, a, b).is_none());
        assert!(decode::offsets_from_table(&[], &tree, &stream, a, b).is_none());
    }
}
