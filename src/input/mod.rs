//! Inputs: what kind of input a path is, decided here and nowhere else, and the one interface
//! through which the model gets a grid's tree and transform from a file ([`GridFile`]).
//!
//! A path is a grid file (`.vdb`, or NanoVDB's `.nvdb`: its grids are read directly, `grid`
//! names one), a scene file
//! (`.toml`: `[[volume]]` tables naming grid files, [`crate::scene::file`]) or a USD stage
//! (`.usd`, `.usda`, `.usdc`, and the package `.usdz`: its `Volume` prims name grid files,
//! [`crate::usd`]). Every other module asks [`Source`], made once from a path ([`Source::new`] asks [`InputKind::of`]; `tests/layering.rs`
//! fails on an extension test elsewhere); nothing above this layer opens a grid file but through
//! [`GridFile`] (`umbra info`'s report on a `.vdb` archive itself aside), so a new grid format
//! is a reader and a few lines here (ARCHITECTURE.md, "Where to add things": an input kind).

mod grid_file;
mod options;
mod source;

pub use grid_file::{load_grid, GridFile};
pub use options::{parse_pair, parse_vec3, parse_xform, Interp, LevelSet, SourceOptions};
pub use source::{is_package, InputKind, Source};
// What every reader gives: a decoded grid (identity, metadata, transform, tree), a vector grid
// as its three components, a grid opened for partial reads, a grid's extent, its
// index-to-world transform.
pub use crate::vdb::{Grid, GridExtent, LazyGrid, Transform, VectorFacts, VectorGrid};

use std::path::Path;

/// Whether `path` names a text USD layer (`.usda`, any case): what a `usd_out` layer must be.
/// (An output, not an input; asked here so that the extensions USD files go by are read in
/// one place.)
#[must_use]
pub fn is_usda_layer(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("usda"))
}
