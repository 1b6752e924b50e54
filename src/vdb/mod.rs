//! Reading `.vdb` files. umbra parses the archive (header, grid descriptors, metadata) and
//! decodes each grid's transform and tree itself, straight into its flat [`Tree`]; it reads only
//! the bytes of the grid asked for. The README's "How loading works" says why vdb-rs is used only
//! as an independent cross-check in the tests; `ARCHITECTURE.md` places this module in the layers.

mod archive;
mod blosc;
mod bytes;
mod decode;
mod metadata;
mod transform;
mod values;

pub use archive::{display_name, Archive, Compression, GridDescriptor, NAME_SEPARATOR};
pub use metadata::{MetaMap, MetaValue};
pub use transform::{FrustumParams, Transform};
pub use values::{PrecisionLoss, ValueKind};

use crate::error::{DecodeError, Error, Result};
use crate::tree::Tree;
use bytes::ByteReader;
use std::path::Path;

/// One decoded grid: its identity, transform, metadata and tree.
#[derive(Debug, Clone)]
pub struct Grid {
    /// Display name (`density`, `density[1]`, `[0]`).
    pub name: String,
    /// Name as stored in the file.
    pub stored_name: String,
    /// Value type.
    pub value_type: ValueKind,
    /// `class` metadata (`fog volume`, `level set`, ...), if any.
    pub class: Option<String>,
    /// Index-to-world transform.
    pub transform: Transform,
    /// Grid metadata, in file order.
    pub metadata: MetaMap,
    /// Compression flags the grid was stored with.
    pub compression: Compression,
    /// Whether values were stored as 16-bit halves.
    pub saved_as_half: bool,
    /// The tree, values converted to `f32` (vector grids: the vector length).
    pub tree: Tree,
    /// For double grids: what the conversion to `f32` cost (None for other types).
    pub precision_loss: Option<PrecisionLoss>,
}

impl Grid {
    /// OpenVDB's `file_mem_bytes` metadata (the in-memory size OpenVDB reports), if stored.
    #[must_use]
    pub fn file_mem_bytes(&self) -> Option<i64> {
        metadata::meta_int(&self.metadata, "file_mem_bytes")
    }
}

/// Read the header and grid list of `path`.
///
/// # Errors
/// See [`Archive::open`].
pub fn open(path: impl AsRef<Path>) -> Result<Archive> {
    Archive::open(path.as_ref())
}

/// Load the grid called `name` (display, stored or unique base name) from `path`.
///
/// # Errors
/// Any [`Error`] from opening, [`Error::GridNotFound`], or a decoding error naming the file.
pub fn load_grid(path: impl AsRef<Path>, name: &str) -> Result<Grid> {
    let archive = open(path)?;
    let gd = archive.find_grid(name)?.clone();
    archive.load(&gd)
}

impl Archive {
    /// Decode the grid described by `gd` (which must come from this archive). Reads only the
    /// bytes between the grid's offsets (and its instance parent's, for instanced grids).
    ///
    /// # Errors
    /// [`Error::Io`], [`Error::Invalid`] or [`Error::Unsupported`], naming the file.
    pub fn load(&self, gd: &GridDescriptor) -> Result<Grid> {
        let path = &self.path;
        let kind = ValueKind::from_tree_type(&gd.tree_type).map_err(|e| e.at(path))?;
        let bytes = self.grid_head(gd)?;
        let mut r = ByteReader::new(&bytes, gd.grid_pos);
        let compression =
            Compression::from_flags(r.u32("compression flags").map_err(|e| e.at(path))?);
        let metadata = metadata::read_meta_map(&mut r).map_err(|e| e.at(path))?;
        let transform = transform::read_transform(&mut r).map_err(|e| e.at(path))?;
        let (tree, precision_loss) = if gd.instance_parent.is_empty() {
            let mut file = std::fs::File::open(path).map_err(|err| Error::Io {
                path: path.clone(),
                err,
            })?;
            let mut buffers = decode::BufferWindow::new(&mut file, path, gd.block_pos, gd.end_pos);
            decode::decode_tree(
                &mut r,
                kind,
                gd.saved_as_half,
                compression,
                gd.block_pos,
                &mut buffers,
            )?
        } else {
            let parent = self.instance_parent(gd)?;
            (parent.tree, parent.precision_loss)
        };
        let class = metadata::meta_string(&metadata, "class").map(str::to_string);
        Ok(Grid {
            name: gd.display_name.clone(),
            stored_name: gd.stored_name.clone(),
            value_type: kind,
            class,
            transform,
            metadata,
            compression,
            saved_as_half: gd.saved_as_half,
            tree,
            precision_loss,
        })
    }

    /// The grid's bytes before its leaf buffers: metadata, transform and topology
    /// (`[grid_pos, block_pos)`; the buffers are streamed by the decoder).
    fn grid_head(&self, gd: &GridDescriptor) -> Result<Vec<u8>> {
        let mut file = std::fs::File::open(&self.path).map_err(|err| Error::Io {
            path: self.path.clone(),
            err,
        })?;
        let len = gd.block_pos - gd.grid_pos;
        let bytes = archive::read_window(&mut file, gd.grid_pos, len, &self.path)?;
        if bytes.len() as u64 != len {
            return Err(DecodeError::invalid(format!(
                "grid '{}' topology ends at offset {} but the file has only {} bytes",
                gd.display_name,
                gd.block_pos,
                gd.grid_pos + bytes.len() as u64
            ))
            .at(&self.path));
        }
        Ok(bytes)
    }

    /// An instanced grid shares its parent's tree (OpenVDB grid instancing).
    fn instance_parent(&self, gd: &GridDescriptor) -> Result<Grid> {
        let parent = self
            .grids
            .iter()
            .find(|g| g.stored_name == gd.instance_parent && g.instance_parent.is_empty())
            .ok_or_else(|| {
                DecodeError::invalid(format!(
                    "grid '{}' is an instance of '{}', which is not in the file",
                    gd.display_name,
                    display_name(&gd.instance_parent)
                ))
                .at(&self.path)
            })?;
        self.load(parent)
    }
}
