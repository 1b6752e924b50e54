//! Reading NanoVDB `.nvdb` files (formats 32.0 to 32.8, as OpenVDB 10 to 12's `nanovdb_convert`,
//! Warp's `Volume.save_to_nvdb` and fVDB write them; a newer version is refused by name):
//! the segments and their grid metadata ([`file`]), each grid's buffer decompressed whole (codecs
//! NONE, ZIP, BLOSC), its checksum verified ([`checksum`]) and its tree decoded into umbra's
//! flat [`crate::tree::Tree`] ([`tree`]), the buffer's structures laid out as [`layout`] says.
//! Value types `float`, `double`, `Vec3f` (kept as its length, or as its three components by
//! [`NvdbFile::load_vector`]) and the quantised `Fp4`, `Fp8`,
//! `Fp16`, `FpN`; every other type is described from its headers and refused on load.
//!
//! A grid is one contiguous block of the file with no index of its nodes outside it, so a grid
//! is always read whole (no partial loads); the file's metadata must agree with what the grid
//! buffer holds (name, type, class, sizes, node, tile and voxel counts, bbox) or the load fails
//! naming what disagrees.

mod bytes;
mod checksum;
mod file;
mod layout;
mod tree;

pub use checksum::Checksum;
pub use file::{Codec, GridMeta, Version};
pub use layout::{class_name, is_decoded, quantisation, type_name};

use crate::error::{DecodeError, Error, Result};
use crate::text;
use crate::vdb::{Compression, Grid, GridExtent, Pick, PrecisionLoss, Transform, VectorGrid};
use bytes::Bytes;
use std::path::{Path, PathBuf};

/// A `.nvdb` file opened: its grids' metadata read, no grid decoded.
#[derive(Debug)]
pub struct NvdbFile {
    /// The file.
    pub path: PathBuf,
    /// Its length in bytes.
    pub file_len: u64,
    /// Every grid's metadata, in file order.
    pub grids: Vec<GridMeta>,
    /// Display names: the stored name, `name[k]` for the k-th of a repeated name, `[k]` for
    /// the k-th unnamed grid.
    pub names: Vec<String>,
}

/// A grid decoded, with what its file says about it.
#[derive(Debug)]
pub struct Decoded {
    /// The grid.
    pub grid: Grid,
    /// What checking its checksum found.
    pub checksum: Checksum,
    /// The grid buffer's own version (the file header may say another).
    pub version: Version,
}

impl NvdbFile {
    /// Open `path` and read every segment's header and grid metadata.
    ///
    /// # Errors
    /// [`Error::Io`]; [`Error::NotVdb`] (shown as "not a NanoVDB file") for an empty or short
    /// file or one without NanoVDB's magic number; [`Error::InvalidNanoVdb`] for corrupt
    /// metadata; [`Error::Unsupported`] for another format version.
    pub fn open(path: &Path) -> Result<Self> {
        let io = |err| Error::Io {
            path: path.to_path_buf(),
            err,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let meta = file.metadata().map_err(io)?;
        if meta.is_dir() {
            return Err(not_nvdb(path, "a directory"));
        }
        let len = meta.len();
        let read = |at: u64, n: u64| read_at(&file, len, at, n);
        let grids = match file::parse_segments(len, &read) {
            Ok(g) => g,
            Err(None) if len == 0 => return Err(not_nvdb(path, "empty file")),
            Err(None) => return Err(not_nvdb(path, "bad magic number")),
            Err(Some(e)) => return Err(e.at_nvdb(path)),
        };
        let names = display_names(&grids);
        Ok(Self {
            path: path.to_path_buf(),
            file_len: len,
            grids,
            names,
        })
    }

    /// The index of grid `name` (display name, or a stored name held by one grid only).
    ///
    /// # Errors
    /// [`Error::GridNotFound`] listing the display names.
    pub fn find_grid(&self, name: &str) -> Result<usize> {
        if let Some(i) = self.names.iter().position(|n| n == name) {
            return Ok(i);
        }
        let mut stored = self
            .grids
            .iter()
            .enumerate()
            .filter(|(_, g)| g.name == name);
        match (stored.next(), stored.next()) {
            (Some((i, _)), None) => Ok(i),
            _ => Err(Error::GridNotFound {
                path: self.path.clone(),
                name: name.to_string(),
                available: self.names.clone(),
            }),
        }
    }

    /// Decode grid `i` whole; a checksum mismatch is an error.
    ///
    /// # Errors
    /// As [`NvdbFile::decode`], and [`Error::InvalidNanoVdb`] for a checksum mismatch.
    pub fn load(&self, i: usize) -> Result<Grid> {
        let d = self.decode(i)?;
        if let Checksum::Mismatch(why) = &d.checksum {
            return Err(self.invalid(i, &format!("checksum mismatch: {why}")));
        }
        Ok(d.grid)
    }

    /// Decode the Vec3f grid `i` as its three components (the grid buffer read, checked and
    /// its checksum verified once, the tree decoded once per component).
    ///
    /// # Errors
    /// As [`NvdbFile::load`]; [`Error::Unsupported`] naming the file and the grid when it is
    /// not a vector grid.
    pub fn load_vector(&self, i: usize) -> Result<VectorGrid> {
        let meta = self
            .grids
            .get(i)
            .ok_or_else(|| self.invalid(i, "no such grid index"))?;
        // Vec3f (6) is decoded; Vec3d (7) is a vector type the decoder refuses by name.
        if !matches!(meta.grid_type, 6 | 7) {
            return Err(crate::vdb::not_a_vector(
                &self.path,
                &self.names[i],
                type_name(meta.grid_type),
            ));
        }
        let picks = [0, 1, 2].map(Pick::Component);
        let (grids, checksum, _) = self.decode_picks(i, &picks)?;
        if let Checksum::Mismatch(why) = &checksum {
            return Err(self.invalid(i, &format!("checksum mismatch: {why}")));
        }
        match <[Grid; 3]>::try_from(grids) {
            Ok(xyz) => Ok(VectorGrid::from_components(xyz)),
            Err(_) => Err(self.invalid(i, "not three components")),
        }
    }

    /// Grid `i`'s transform and the index box [`crate::Volume::value_box`] gives, from the
    /// grid decoded (a grid is one block: its nodes are read with it).
    ///
    /// # Errors
    /// As [`NvdbFile::load`].
    pub fn extent(&self, i: usize) -> Result<GridExtent> {
        let g = self.load(i)?;
        let value_box = crate::tree::value_box_of(&g.tree, g.tree.leaves.iter().map(|l| l.origin));
        Ok(GridExtent {
            name: g.name,
            transform: g.transform,
            value_box,
        })
    }

    /// Decode grid `i` whole and check its checksum (reported, not enforced).
    ///
    /// # Errors
    /// [`Error::Io`]; [`Error::Unsupported`] for a grid type umbra does not decode;
    /// [`Error::InvalidNanoVdb`] naming the file, the grid and what is corrupt or disagrees.
    pub fn decode(&self, i: usize) -> Result<Decoded> {
        let (mut grids, checksum, version) = self.decode_picks(i, &[Pick::Length])?;
        let grid = grids
            .pop()
            .ok_or_else(|| self.invalid(i, "no tree decoded"))?;
        Ok(Decoded {
            grid,
            checksum,
            version,
        })
    }

    /// Decode grid `i` once per pick (vector values as it says): the buffer is read, checked
    /// and its checksum computed once; with the grid's checksum and version.
    fn decode_picks(&self, i: usize, picks: &[Pick]) -> Result<(Vec<Grid>, Checksum, Version)> {
        let meta = self
            .grids
            .get(i)
            .ok_or_else(|| self.invalid(i, "no such grid index"))?;
        let Some(layout) = layout::Layout::of(meta.grid_type) else {
            return Err(Error::Unsupported {
                path: self.path.clone(),
                what: format!(
                    "grid '{}': NanoVDB grid type {} (umbra decodes float, double, Vec3f, Fp4, \
                     Fp8, Fp16 and FpN grids)",
                    text::escape(&self.names[i]),
                    type_name(meta.grid_type)
                ),
            });
        };
        let blob = self.read_blob(meta)?;
        let buf = file::grid_buffer(meta, blob).map_err(|e| self.decode_err(i, e))?;
        let b = Bytes::new(&buf);
        let at = |e: DecodeError| self.decode_err(i, e);
        let head = layout::GridHead::parse(&b).map_err(at)?;
        let grid_what = format!("grid '{}'", text::escape(&self.names[i]));
        file::check_version(head.version, &grid_what).map_err(at)?;
        agree(meta, &head, b.len()).map_err(at)?;
        let nodes = tree::locate(&b, &head, &layout).map_err(at)?;
        let root_bbox = [
            b.vec3i(nodes.root).map_err(at)?,
            b.vec3i(nodes.root + 12).map_err(at)?,
        ];
        if meta.counted && root_bbox != meta.index_bbox {
            return Err(self.invalid(
                i,
                &format!(
                    "the file's index bbox {:?} disagrees with the root's {root_bbox:?}",
                    meta.index_bbox
                ),
            ));
        }
        let checksum = checksum::check(&b, &head, &layout, &nodes).map_err(at)?;
        let transform = self.transform(i, &head)?;
        let mut grids = Vec::with_capacity(picks.len());
        for &pick in picks {
            let d = tree::decode(&b, &head, &layout, &nodes, pick).map_err(at)?;
            let tiles = head.tile_count.map(u64::from);
            // Warp (whose file metadata is not counted) writes its node counts where the tree
            // header's tile counts belong: only the voxel count is its own to check.
            if d.voxels != head.voxel_count || (meta.counted && d.tiles != tiles) {
                return Err(self.invalid(
                    i,
                    &format!(
                        "the tree header counts {} active voxels and {tiles:?} active tiles \
                         (lower, upper, root), the tree holds {} and {:?}",
                        head.voxel_count, d.voxels, d.tiles
                    ),
                ));
            }
            let kind = layout.kind;
            grids.push(self.grid(i, kind, transform.clone(), d.tree, d.precision));
        }
        Ok((grids, checksum, head.version))
    }

    /// The grid's affine map, which must be finite and invertible.
    fn transform(&self, i: usize, head: &layout::GridHead) -> Result<Transform> {
        let m = head.world_from_index();
        let det = glam::DMat3::from_cols_array(&head.mat).determinant();
        if m.iter().flatten().any(|v| !v.is_finite()) || det == 0.0 || !det.is_finite() {
            return Err(self.invalid(
                i,
                &format!("the map {:?} is not an invertible affine", head.mat),
            ));
        }
        Ok(Transform::affine("AffineMap", m))
    }

    fn grid(
        &self,
        i: usize,
        kind: crate::vdb::ValueKind,
        transform: Transform,
        tree: crate::tree::Tree,
        precision_loss: Option<PrecisionLoss>,
    ) -> Grid {
        let meta = &self.grids[i];
        let class = class_name(meta.grid_class).to_string();
        Grid {
            name: self.names[i].clone(),
            stored_name: meta.name.clone(),
            value_type: kind,
            class: Some(class.clone()),
            transform,
            metadata: vec![("class".into(), crate::vdb::MetaValue::String(class))],
            compression: Compression {
                zip: meta.codec == Codec::Zip,
                active_mask: false,
                blosc: meta.codec == Codec::Blosc,
            },
            saved_as_half: false,
            tree,
            precision_loss,
        }
    }

    /// The bytes of grid `meta`'s blob (its size was checked against the file on open), read
    /// in pieces on every core (the copy out of the page cache and the first touch of the
    /// buffer's pages shared among the workers).
    fn read_blob(&self, meta: &GridMeta) -> Result<Vec<u8>> {
        let file = std::fs::File::open(&self.path).map_err(|err| Error::Io {
            path: self.path.clone(),
            err,
        })?;
        read_pieces(&file, self.file_len, meta.offset, meta.blob_bytes)
            .map_err(|e| e.at_nvdb(&self.path))
    }

    fn invalid(&self, i: usize, why: &str) -> Error {
        let name = self.names.get(i).map_or("?", String::as_str);
        DecodeError::invalid(format!("grid '{}': {why}", text::escape(name))).at_nvdb(&self.path)
    }

    fn decode_err(&self, i: usize, e: DecodeError) -> Error {
        match e {
            DecodeError::Unsupported(m) => Error::Unsupported {
                path: self.path.clone(),
                what: m,
            },
            DecodeError::Invalid(m) | DecodeError::Truncated { msg: m, .. } => self.invalid(i, &m),
        }
    }
}

/// The file's metadata and the grid's own headers must agree (on the counts only where the
/// writer filled them in: see [`GridMeta::counted`]).
fn agree(meta: &GridMeta, h: &layout::GridHead, len: u64) -> crate::error::DecodeResult<()> {
    let name_ok = h.flags & layout::LONG_NAME != 0 || h.name == meta.name.as_bytes();
    let checks: [(&str, bool, String); 8] = [
        (
            "grid size",
            h.grid_size == meta.grid_size && len == meta.grid_size,
            format!(
                "{} (file) / {} (grid) / {len} (decoded)",
                meta.grid_size, h.grid_size
            ),
        ),
        (
            "grid type",
            h.grid_type == meta.grid_type,
            format!("{} / {}", type_name(meta.grid_type), type_name(h.grid_type)),
        ),
        (
            "grid class",
            h.grid_class == meta.grid_class,
            format!("{} / {}", meta.grid_class, h.grid_class),
        ),
        (
            "name",
            name_ok,
            format!(
                "'{}' / '{}'",
                text::escape(&meta.name),
                text::escape(&String::from_utf8_lossy(&h.name))
            ),
        ),
        (
            "node counts",
            !meta.counted || h.node_count[..] == meta.node_count[..3] && meta.node_count[3] == 1,
            format!("{:?} / {:?}", meta.node_count, h.node_count),
        ),
        (
            "tile counts",
            !meta.counted || h.tile_count == meta.tile_count,
            format!("{:?} / {:?}", meta.tile_count, h.tile_count),
        ),
        (
            "voxel count",
            !meta.counted || h.voxel_count == meta.voxel_count,
            format!("{} / {}", meta.voxel_count, h.voxel_count),
        ),
        (
            "grid index",
            h.grid_index < h.grid_count,
            format!("index {} of {}", h.grid_index, h.grid_count),
        ),
    ];
    for (what, ok, detail) in checks {
        if !ok {
            return Err(DecodeError::invalid(format!(
                "the file's metadata and the grid disagree on the {what}: {detail}"
            )));
        }
    }
    Ok(())
}

fn not_nvdb(path: &Path, reason: &str) -> Error {
    Error::NotVdb {
        path: path.to_path_buf(),
        format: "NanoVDB",
        reason: reason.to_string(),
    }
}

/// Read `n` bytes at `at` of a file of `len` bytes, after checking they are all in it.
fn read_at(file: &std::fs::File, len: u64, at: u64, n: u64) -> crate::error::DecodeResult<Vec<u8>> {
    check_range(len, at, n)?;
    let n = usize::try_from(n)
        .map_err(|_| DecodeError::unsupported("a block beyond the address space"))?;
    let mut buf = vec![0u8; n];
    crate::vdb::positioned_read(file, &mut buf, at)
        .map_err(|e| DecodeError::invalid(format!("reading {n} bytes at byte {at}: {e}")))?;
    Ok(buf)
}

/// Bytes per piece of [`read_pieces`].
const READ_PIECE: usize = 4 << 20;

/// As [`read_at`], the bytes read in pieces of [`READ_PIECE`] on every core (positioned reads
/// of one file, each piece into its own part of the buffer).
fn read_pieces(
    file: &std::fs::File,
    len: u64,
    at: u64,
    n: u64,
) -> crate::error::DecodeResult<Vec<u8>> {
    use rayon::prelude::*;
    if n <= READ_PIECE as u64 {
        return read_at(file, len, at, n);
    }
    check_range(len, at, n)?;
    let size = usize::try_from(n)
        .map_err(|_| DecodeError::unsupported("a block beyond the address space"))?;
    let mut buf = vec![0u8; size];
    buf.par_chunks_mut(READ_PIECE)
        .enumerate()
        .try_for_each(|(k, piece)| {
            let from = at + (k * READ_PIECE) as u64;
            crate::vdb::positioned_read(file, piece, from).map_err(|e| {
                DecodeError::invalid(format!("reading {} bytes at byte {from}: {e}", piece.len()))
            })
        })?;
    Ok(buf)
}

/// `n` bytes at `at` must be within a file of `len` bytes.
fn check_range(len: u64, at: u64, n: u64) -> crate::error::DecodeResult<()> {
    if at.checked_add(n).is_none_or(|e| e > len) {
        return Err(DecodeError::Truncated {
            msg: format!("{n} bytes at byte {at} run past the end of the file ({len} bytes)"),
            need: at.saturating_add(n),
        });
    }
    Ok(())
}

/// Display names: the stored name when unique, `name[k]` for the k-th of a repeated name, `[k]`
/// for the k-th unnamed grid.
fn display_names(grids: &[GridMeta]) -> Vec<String> {
    let mut counts: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    for g in grids {
        *counts.entry(g.name.as_str()).or_default() += 1;
    }
    let mut seen: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
    grids
        .iter()
        .map(|g| {
            let count = counts.get(g.name.as_str()).copied().unwrap_or(0);
            let k = seen.entry(g.name.as_str()).or_default();
            let name = if g.name.is_empty() || count > 1 {
                format!("{}[{k}]", g.name)
            } else {
                g.name.clone()
            };
            *k += 1;
            name
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A blob read in pieces on every core is the bytes one read gives, for a size that is no
    /// multiple of the piece, at an odd offset; a range past the end is refused before any read.
    #[test]
    fn a_blob_read_in_pieces_is_the_blob_read_at_once() {
        let mut f = tempfile::tempfile().unwrap();
        let bytes: Vec<u8> = (0..(2 * READ_PIECE + 12_345) as u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        std::io::Write::write_all(&mut f, &bytes).unwrap();
        let len = bytes.len() as u64;
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let n = len - 20;
            let got = pool.install(|| read_pieces(&f, len, 7, n)).unwrap();
            assert!(got == read_at(&f, len, 7, n).unwrap(), "{threads} threads");
            assert!(got[..] == bytes[7..len as usize - 13], "{threads} threads");
        }
        assert!(matches!(
            read_pieces(&f, len, 8, len),
            Err(DecodeError::Truncated { .. })
        ));
    }
}
