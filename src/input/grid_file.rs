//! [`GridFile`]: a grid file opened by the reader its kind names, and what the layers above ask
//! of it: a grid decoded whole ([`GridFile::load`]), opened for partial reads
//! ([`GridFile::lazy`]), a vector grid as its three components ([`GridFile::load_vector`]), or
//! its transform and index box alone ([`GridFile::extent`]). The
//! model builds a [`crate::Volume`] from the [`Grid`] it gives; no module above this layer
//! opens a grid file itself.

use crate::error::Result;
use crate::vdb::{Archive, Grid, GridExtent, LazyGrid, VectorGrid};
use std::path::Path;

/// A grid file opened for reading: its header and list of grids read, no grid decoded.
#[derive(Debug)]
pub struct GridFile {
    reader: Reader,
}

/// The reader of each grid format.
#[derive(Debug)]
enum Reader {
    /// An OpenVDB archive.
    Vdb(Archive),
    /// A NanoVDB file ([`crate::nvdb`]): each grid one contiguous block, decoded whole.
    Nvdb(crate::nvdb::NvdbFile),
}

impl GridFile {
    /// Open `path` with the reader of its kind ([`super::source::InputKind::of`]; a path that is not a
    /// grid file of another format is read as `.vdb`, whose reader says why it is not one).
    ///
    /// # Errors
    /// As [`Archive::open`] (or the NanoVDB reader's open for `.nvdb`): [`crate::error::Error::Io`],
    /// [`crate::error::Error::NotVdb`],
    /// [`crate::error::Error::Unsupported`], [`crate::error::Error::Invalid`], naming the file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let reader = match super::source::InputKind::of(path) {
            super::source::InputKind::Nvdb => Reader::Nvdb(crate::nvdb::NvdbFile::open(path)?),
            _ => Reader::Vdb(Archive::open(path)?),
        };
        Ok(Self { reader })
    }

    /// The file it reads.
    #[must_use]
    pub fn path(&self) -> &Path {
        match &self.reader {
            Reader::Vdb(a) => &a.path,
            Reader::Nvdb(f) => &f.path,
        }
    }

    /// Check that the file holds grid `grid` (display, stored or unique base name).
    ///
    /// # Errors
    /// [`crate::error::Error::GridNotFound`] listing the grids it holds.
    pub fn check_grid(&self, grid: &str) -> Result<()> {
        match &self.reader {
            Reader::Vdb(a) => a.find_grid(grid).map(|_| ()),
            Reader::Nvdb(f) => f.find_grid(grid).map(|_| ()),
        }
    }

    /// Decode grid `grid` whole: identity, metadata, transform and tree.
    ///
    /// # Errors
    /// [`crate::error::Error::GridNotFound`], or a decoding error naming the file.
    pub fn load(&self, grid: &str) -> Result<Grid> {
        match &self.reader {
            Reader::Vdb(a) => a.load(a.find_grid(grid)?),
            Reader::Nvdb(f) => f.load(f.find_grid(grid)?),
        }
    }

    /// Decode the vector grid `grid` (`.vdb`: `vec3s`, `vec3d`, `vec3i`; `.nvdb`: `Vec3f`) as
    /// its three components, each a scalar tree of the grid's topology ([`VectorGrid`]).
    ///
    /// # Errors
    /// [`crate::error::Error::GridNotFound`]; [`crate::error::Error::Unsupported`] naming the file and the
    /// grid when it is not a vector grid; a decoding error naming the file.
    pub fn load_vector(&self, grid: &str) -> Result<VectorGrid> {
        match &self.reader {
            Reader::Vdb(a) => a.load_vector(a.find_grid(grid)?),
            Reader::Nvdb(f) => f.load_vector(f.find_grid(grid)?),
        }
    }

    /// Open grid `grid` for partial reads: its topology and where its leaves are, no value
    /// decoded ([`LazyGrid`]). `None` when the format has no partial reads: the caller loads
    /// the grid whole ([`GridFile::load`]).
    ///
    /// # Errors
    /// [`crate::error::Error::GridNotFound`], or a decoding error of the head, the topology or the
    /// buffer headers, naming the file.
    pub fn lazy(&self, grid: &str) -> Result<Option<LazyGrid>> {
        match &self.reader {
            Reader::Vdb(a) => a.open_lazy(a.find_grid(grid)?).map(Some),
            // One contiguous block per grid, with no index of its nodes outside it.
            Reader::Nvdb(f) => f.find_grid(grid).map(|_| None),
        }
    }

    /// Grid `grid`'s transform and index box, read without its voxel values (what framing
    /// needs).
    ///
    /// # Errors
    /// [`crate::error::Error::GridNotFound`], or a decoding error of the head or the topology, naming
    /// the file.
    pub fn extent(&self, grid: &str) -> Result<GridExtent> {
        match &self.reader {
            Reader::Vdb(a) => a.extent(a.find_grid(grid)?),
            Reader::Nvdb(f) => f.extent(f.find_grid(grid)?),
        }
    }
}

/// Load grid `grid` of the grid file `path` whole ([`GridFile::open`], [`GridFile::load`]).
///
/// # Errors
/// As [`GridFile::open`] and [`GridFile::load`].
pub fn load_grid(path: impl AsRef<Path>, grid: &str) -> Result<Grid> {
    GridFile::open(path)?.load(grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
    }

    #[test]
    fn a_grid_file_gives_what_the_vdb_reader_gives() {
        let path = cloud();
        let file = GridFile::open(&path).unwrap();
        assert_eq!(file.path(), path.as_path());
        file.check_grid("density").unwrap();
        let missing = file.check_grid("no such grid").unwrap_err();
        assert!(
            matches!(missing, crate::error::Error::GridNotFound { .. }),
            "{missing}"
        );
        let archive = Archive::open(&path).unwrap();
        let gd = archive.find_grid("density").unwrap();
        let eager = file.load("density").unwrap();
        let direct = archive.load(gd).unwrap();
        assert_eq!(eager.name, direct.name);
        assert_eq!(eager.tree.values, direct.tree.values);
        assert_eq!(
            eager.transform.world_from_index,
            direct.transform.world_from_index
        );
        let lazy = file.lazy("density").unwrap().unwrap();
        assert_eq!(lazy.head_bytes(), gd.block_pos - gd.grid_pos);
        assert_eq!(lazy.leaf_count(), direct.tree.leaves.len());
        let extent = file.extent("density").unwrap();
        assert_eq!(extent.name, "density");
        assert_eq!(extent.value_box, archive.extent(gd).unwrap().value_box);
        let loaded = load_grid(&path, "density").unwrap();
        assert_eq!(loaded.tree.values, direct.tree.values);
    }

    #[test]
    fn a_path_that_is_no_grid_file_says_so_as_the_vdb_reader_does() {
        let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml");
        let ours = GridFile::open(&scene).unwrap_err().to_string();
        let theirs = Archive::open(&scene).unwrap_err().to_string();
        assert_eq!(ours, theirs);
    }
}
