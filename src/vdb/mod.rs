//! Reading `.vdb` files. umbra parses the archive (header, grid descriptors, metadata) and
//! decodes each grid's transform and tree itself, straight into its flat [`Tree`]; it reads only
//! the bytes of the grid asked for. The README's "How loading works" says why vdb-rs is used only
//! as an independent cross-check in the tests; `ARCHITECTURE.md` places this module in the layers.

mod archive;
pub(crate) mod blosc;
mod bytes;
mod decode;
mod lazy;
mod metadata;
mod transform;
mod values;
pub mod write;

pub use archive::{display_name, Archive, Compression, GridDescriptor, NAME_SEPARATOR};
pub(crate) use decode::positioned_read;
pub use lazy::LazyGrid;
pub use metadata::{MetaMap, MetaValue};
pub use transform::{FrustumParams, Transform};
pub(crate) use values::Pick;
pub use values::{PrecisionLoss, ValueKind};
pub use write::{encode_vdb, write_vdb, FloatGridOut, GridClassOut, LeafOut, VdbCompression};

use crate::error::{DecodeError, Error, Result};
use crate::text;
use crate::tree::Tree;
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
    /// The tree, values converted to `f32` (vector grids: the vector length; see
    /// [`VectorGrid`] for the components).
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

/// A vector grid decoded as its three components, each a scalar tree of the same topology.
#[derive(Debug, Clone)]
pub struct VectorGrid {
    /// Display name (`vel`, `vel[1]`, `[0]`), as [`Grid::name`].
    pub name: String,
    /// Value type: [`ValueKind::Vec3s`], [`ValueKind::Vec3d`] or [`ValueKind::Vec3i`].
    pub value_type: ValueKind,
    /// `class` metadata (`staggered` for MAC grids), if any.
    pub class: Option<String>,
    /// Index-to-world transform.
    pub transform: Transform,
    /// Grid metadata, in file order.
    pub metadata: MetaMap,
    /// The x, y and z components, each a tree of the grid's topology holding that component of
    /// every stored value (background, tiles, inactive and active voxels), bounds computed.
    pub components: [Tree; 3],
}

impl VectorGrid {
    /// The grid of three component grids of one vector grid (decoded with picks 0, 1, 2).
    pub(crate) fn from_components(grids: [Grid; 3]) -> Self {
        let [x, y, z] = grids;
        Self {
            name: x.name,
            value_type: x.value_type,
            class: x.class,
            transform: x.transform,
            metadata: x.metadata,
            components: [x.tree, y.tree, z.tree],
        }
    }
}

/// What a grid's class and metadata say of its vectors: one reading for a decoded vector grid
/// ([`VectorGrid`], what motion blur samples) and for a grid `info` describes ([`Grid`]).
pub trait VectorFacts {
    /// The grid class (`staggered` for a MAC grid).
    fn grid_class(&self) -> Option<&str>;
    /// The grid's metadata.
    fn grid_metadata(&self) -> &MetaMap;

    /// Whether the grid's class is `staggered` (OpenVDB's `GRID_STAGGERED`: a MAC grid, each
    /// component sampled at the centre of its voxel's lower face on that axis).
    fn is_staggered(&self) -> bool {
        self.grid_class() == Some("staggered")
    }

    /// Whether the bool metadata `is_local_space` (OpenVDB's `META_IS_LOCAL_SPACE`) is true:
    /// the vectors are in index space, not world space.
    fn is_local_space(&self) -> bool {
        self.local_space() == Some(true)
    }

    /// The bool metadata `is_local_space` as the file has it (`None`: not in the file).
    fn local_space(&self) -> Option<bool> {
        metadata::meta_bool(self.grid_metadata(), "is_local_space")
    }

    /// The string metadata `vector_type` (OpenVDB's `META_VECTOR_TYPE`: `invariant`,
    /// `covariant`, `covariant normalize`, `contravariant relative`, `contravariant
    /// absolute`), if any.
    fn vector_type(&self) -> Option<&str> {
        metadata::meta_string(self.grid_metadata(), "vector_type")
    }
}

impl VectorFacts for Grid {
    fn grid_class(&self) -> Option<&str> {
        self.class.as_deref()
    }
    fn grid_metadata(&self) -> &MetaMap {
        &self.metadata
    }
}

impl VectorFacts for VectorGrid {
    fn grid_class(&self) -> Option<&str> {
        self.class.as_deref()
    }
    fn grid_metadata(&self) -> &MetaMap {
        &self.metadata
    }
}

/// The error for a grid asked for as a vector grid that is not one: `type_name` is its value
/// type as its format names it.
pub(crate) fn not_a_vector(path: &Path, grid: &str, type_name: &str) -> Error {
    Error::Unsupported {
        path: path.to_path_buf(),
        what: format!(
            "grid '{}' is a {} grid; a velocity must be a vec3 grid (vec3s, vec3d, vec3i)",
            text::escape(grid),
            text::escape(type_name)
        ),
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

/// A grid's transform and index box, read without its voxel values ([`Archive::extent`]).
#[derive(Debug, Clone)]
pub struct GridExtent {
    /// Display name (`density`, `density[1]`, `[0]`).
    pub name: String,
    /// Index-to-world transform.
    pub transform: Transform,
    /// Inclusive index box of every leaf and every non-background tile; `None` when the grid
    /// holds only its background.
    pub value_box: Option<[[i64; 3]; 2]>,
}

/// What a grid's header says before its tree: readable for every grid type, including those
/// umbra does not decode (point data, other tree configurations) ([`Archive::header`]).
#[derive(Debug, Clone)]
pub struct GridHeader {
    /// `class` metadata (`fog volume`, `level set`, ...), if any.
    pub class: Option<String>,
    /// Index-to-world transform.
    pub transform: Transform,
    /// Grid metadata, in file order.
    pub metadata: MetaMap,
    /// Compression flags the grid was stored with.
    pub compression: Compression,
}

impl GridHeader {
    /// OpenVDB's `file_mem_bytes` metadata, if stored.
    #[must_use]
    pub fn file_mem_bytes(&self) -> Option<i64> {
        metadata::meta_int(&self.metadata, "file_mem_bytes")
    }
}

/// First window for a grid's head (metadata, transform, topology): most topologies fit.
const HEAD_WINDOW: u64 = 1 << 16;

/// A grid's head: what precedes its leaf buffers.
struct Head {
    compression: Compression,
    metadata: MetaMap,
    /// The raw `file_delayed_load` table, if the writer stored one.
    delayed_load: Option<Vec<u8>>,
    transform: Transform,
    topology: Option<decode::Topology>,
}

impl Archive {
    /// Decode the grid described by `gd` (which must come from this archive). Reads only the
    /// bytes between the grid's offsets (and its instance parent's, for instanced grids), and
    /// of those only what the decoder consumes: the head through a growing window, the leaf
    /// buffers streamed.
    ///
    /// # Errors
    /// [`Error::Io`], [`Error::Invalid`] or [`Error::Unsupported`], naming the file; an
    /// instanced grid whose parent is missing, is itself, is an instance or has another tree
    /// type is [`Error::Invalid`].
    pub fn load(&self, gd: &GridDescriptor) -> Result<Grid> {
        self.open_lazy(gd)?.load_all()
    }

    /// Decode the vector grid described by `gd` (from this archive) as its three components:
    /// the grid is decoded once per component, each pass as [`Archive::load`] (instances,
    /// halves, compression and inactive values alike), keeping that component of every value.
    ///
    /// # Errors
    /// As [`Archive::load`]; [`Error::Unsupported`] naming the file and the grid when it is not
    /// a `vec3s`, `vec3d` or `vec3i` grid.
    pub fn load_vector(&self, gd: &GridDescriptor) -> Result<VectorGrid> {
        let kind = ValueKind::from_tree_type(&gd.tree_type).map_err(|e| e.at(&self.path))?;
        if !kind.is_vector() {
            return Err(not_a_vector(&self.path, &gd.display_name, kind.name()));
        }
        let x = self.open_lazy_as(gd, Pick::Component(0))?.load_all()?;
        let y = self.open_lazy_as(gd, Pick::Component(1))?.load_all()?;
        let z = self.open_lazy_as(gd, Pick::Component(2))?.load_all()?;
        Ok(VectorGrid::from_components([x, y, z]))
    }

    /// The header of grid `gd` (from this archive): compression, metadata and transform, read
    /// without its tree, so any grid type has one.
    ///
    /// # Errors
    /// [`Error::Io`] or [`Error::Invalid`] naming the file for a header that cannot be read.
    pub fn header(&self, gd: &GridDescriptor) -> Result<GridHeader> {
        // The value type only matters for the topology, which is not read.
        let (head, _) = self.head(gd, ValueKind::Float, None)?;
        Ok(GridHeader {
            class: metadata::meta_string(&head.metadata, "class").map(str::to_string),
            transform: head.transform,
            metadata: head.metadata,
            compression: head.compression,
        })
    }

    /// Parse a grid's head (compression, metadata, transform, and with `topology` its tree
    /// without leaf values, vector values as the pick says) through a growing window; returns
    /// the open file for the buffers.
    fn head(
        &self,
        gd: &GridDescriptor,
        kind: ValueKind,
        topology: Option<Pick>,
    ) -> Result<(Head, std::fs::File)> {
        let path = &self.path;
        let mut file = std::fs::File::open(path).map_err(|err| Error::Io {
            path: path.clone(),
            err,
        })?;
        let region = format!("grid '{}'", text::escape(&gd.display_name));
        let (head, _) = archive::parse_window(
            &mut file,
            (gd.grid_pos, gd.block_pos),
            HEAD_WINDOW,
            &region,
            path,
            |r| {
                let compression = Compression::from_flags(r.u32("compression flags")?);
                let (metadata, delayed_load) = metadata::read_grid_meta_map(r)?;
                let transform = transform::read_transform(r)?;
                let topology = if let Some(pick) = topology {
                    let t = decode::read_topology(
                        r,
                        kind,
                        pick,
                        gd.saved_as_half,
                        compression,
                        gd.block_pos,
                    )?;
                    Some(t)
                } else {
                    None
                };
                Ok(Head {
                    compression,
                    metadata,
                    delayed_load,
                    transform,
                    topology,
                })
            },
        )?;
        Ok((head, file))
    }

    /// What framing needs of the grid `gd` (from this archive), read without its leaf values:
    /// its transform and the index box [`crate::Volume::value_box`] would give (every leaf and
    /// every tile whose value differs from the background; an instance takes its parent's
    /// tree).
    ///
    /// # Errors
    /// As [`Archive::load`].
    pub fn extent(&self, gd: &GridDescriptor) -> Result<GridExtent> {
        let kind = ValueKind::from_tree_type(&gd.tree_type).map_err(|e| e.at(&self.path))?;
        let parent = if gd.instance_parent.is_empty() {
            None
        } else {
            Some(self.instance_parent(gd)?)
        };
        let pick = parent.is_none().then_some(Pick::Length);
        let (head, _) = self.head(gd, kind, pick)?;
        let value_box = match (head.topology, parent) {
            (Some(t), _) => t.value_box(),
            (None, Some(p)) => self.extent(p)?.value_box,
            (None, None) => {
                let why = "grid has neither a tree nor an instance parent";
                return Err(DecodeError::invalid(why).at(&self.path));
            }
        };
        Ok(GridExtent {
            name: gd.display_name.clone(),
            transform: head.transform,
            value_box,
        })
    }

    /// The grid whose tree an instanced grid shares (OpenVDB grid instancing). OpenVDB writes
    /// the first grid that holds a tree in full and later grids sharing it as instances naming
    /// it, so the parent must be another grid of this file, not itself an instance (no
    /// chains, no cycles), with the same tree type (a float grid cannot share a vec3s tree;
    /// OpenVDB refuses such a file too).
    fn instance_parent(&self, gd: &GridDescriptor) -> Result<&GridDescriptor> {
        let bad = |reason: String| DecodeError::invalid(reason).at(&self.path);
        let name = text::escape(&gd.display_name);
        if gd.instance_parent == gd.stored_name {
            return Err(bad(format!(
                "grid '{name}' is an instance of itself: the file has no tree for it"
            )));
        }
        let parent_name = display_name(&gd.instance_parent);
        let parent_name = text::escape(&parent_name);
        let parent = self
            .grids
            .iter()
            .find(|g| g.stored_name == gd.instance_parent)
            .ok_or_else(|| {
                bad(format!(
                    "grid '{name}' is an instance of '{parent_name}', which is not in the file"
                ))
            })?;
        if !parent.instance_parent.is_empty() {
            return Err(bad(format!(
                "grid '{name}' is an instance of '{parent_name}', which is itself an instance \
                 (of '{}'); OpenVDB instances always name the grid that holds the tree",
                text::escape(&display_name(&parent.instance_parent))
            )));
        }
        if parent.tree_type != gd.tree_type || parent.saved_as_half != gd.saved_as_half {
            let t = |g: &GridDescriptor| {
                format!(
                    "{}{}",
                    text::escape(&g.tree_type),
                    if g.saved_as_half { " (half)" } else { "" }
                )
            };
            return Err(bad(format!(
                "grid '{name}' of type {} is an instance of '{parent_name}' of type {}: an \
                 instance must share its parent's tree type",
                t(gd),
                t(parent)
            )));
        }
        Ok(parent)
    }
}
