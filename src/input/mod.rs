//! Inputs: what kind of input a path is, decided here and nowhere else, and the one interface
//! through which the model gets a grid's tree and transform from a file ([`GridFile`]).
//!
//! A path is a grid file (`.vdb`, or NanoVDB's `.nvdb`: its grids are read directly, `grid`
//! names one), a scene file
//! (`.toml`: `[[volume]]` tables naming grid files, [`crate::scene::file`]) or a USD stage
//! (`.usd`, `.usda`, `.usdc`, and the package `.usdz`: its `Volume` prims name grid files,
//! [`crate::usd`]). Every other module asks [`InputKind::of`] (`tests/layering.rs` fails on an
//! extension test elsewhere); nothing above this layer opens a grid file but through
//! [`GridFile`] (`umbra info`'s report on a `.vdb` archive itself aside), so a new grid format
//! is a reader and a few lines here (ARCHITECTURE.md, "Where to add things": an input kind).

mod source;

pub use source::{load_grid, GridFile};
// What every reader gives: a decoded grid (identity, metadata, transform, tree), a vector grid
// as its three components, a grid opened for partial reads, a grid's extent, its
// index-to-world transform.
pub use crate::vdb::{Grid, GridExtent, LazyGrid, Transform, VectorFacts, VectorGrid};

use std::path::Path;

/// What kind of input a path is, from its extension (any case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum InputKind {
    /// An OpenVDB grid file (`.vdb`), and any path no other kind claims: it is read as one,
    /// and the reader's error says why it is not.
    Vdb,
    /// A NanoVDB grid file (`.nvdb`): each grid one contiguous block, read whole.
    Nvdb,
    /// A scene file (`.toml`): `[[volume]]` tables naming grid files.
    Scene,
    /// A USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`); `package` for a `.usdz` package (a zip
    /// archive whose root layer and assets are its members).
    Stage {
        /// Whether the stage is a `.usdz` package.
        package: bool,
    },
}

impl InputKind {
    /// The kind of input `path` names, from its extension (any case).
    #[must_use]
    pub fn of(path: &Path) -> Self {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let is = |x: &str| ext.eq_ignore_ascii_case(x);
        if is("toml") {
            Self::Scene
        } else if is("nvdb") {
            Self::Nvdb
        } else if is("usdz") {
            Self::Stage { package: true }
        } else if is("usd") || is("usda") || is("usdc") {
            Self::Stage { package: false }
        } else {
            Self::Vdb
        }
    }

    /// Whether the input is a grid file, read through [`GridFile`] (its grid named by `grid`),
    /// rather than a file naming grid files (a scene file or a stage).
    #[must_use]
    pub fn is_grid_file(self) -> bool {
        matches!(self, Self::Vdb | Self::Nvdb)
    }

    /// Whether a grid of the input can be read in part (only the leaves a job touches): `.vdb`
    /// grids can; a NanoVDB grid is one block, read whole ([`GridFile::lazy`] is `None`).
    #[must_use]
    pub fn has_partial_reads(self) -> bool {
        self == Self::Vdb
    }

    /// The format's short name, as reports give it (`umbra info`'s `format`): `vdb`, `nvdb`,
    /// `scene`, `usd`.
    #[must_use]
    pub fn format(self) -> &'static str {
        match self {
            Self::Vdb => "vdb",
            Self::Nvdb => "nvdb",
            Self::Scene => "scene",
            Self::Stage { .. } => "usd",
        }
    }

    /// Whether the input is a scene file (`.toml`).
    #[must_use]
    pub fn is_scene_file(self) -> bool {
        self == Self::Scene
    }

    /// Whether the input is a USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`).
    #[must_use]
    pub fn is_stage(self) -> bool {
        matches!(self, Self::Stage { .. })
    }

    /// Whether the input is a USD package (`.usdz`).
    #[must_use]
    pub fn is_package(self) -> bool {
        self == Self::Stage { package: true }
    }
}

/// Whether `path` names a text USD layer (`.usda`, any case): what a `usd_out` layer must be.
/// (An output, not an input; asked here so that the extensions USD files go by are read in
/// one place.)
#[must_use]
pub fn is_usda_layer(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("usda"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinds_by_extension_in_any_case() {
        let of = |p: &str| InputKind::of(Path::new(p));
        assert_eq!(of("a/cloud.vdb"), InputKind::Vdb);
        assert_eq!(of("a/cloud.VDB"), InputKind::Vdb);
        assert_eq!(of("cloud"), InputKind::Vdb);
        assert_eq!(of("cloud.bin"), InputKind::Vdb);
        assert_eq!(of("scene.TOML"), InputKind::Scene);
        assert_eq!(of("a/smoke.nvdb"), InputKind::Nvdb);
        assert_eq!(of("smoke.0001.NVDB"), InputKind::Nvdb);
        assert!(of("a.NvDb").is_grid_file() && !of("a.nvdb").is_scene_file());
        assert!(!of("a.nvdb").is_stage());
        assert_eq!(
            (of("a.nvdb").format(), of("a.vdb").format()),
            ("nvdb", "vdb")
        );
        assert_eq!(of("a/b.USDZ"), InputKind::Stage { package: true });
        for s in ["s.usd", "s.usda", "s.USDC", "s.UsdA"] {
            assert_eq!(of(s), InputKind::Stage { package: false }, "{s}");
        }
        assert!(of("a.usdz").is_stage() && of("a.usdz").is_package());
        assert!(of("a.usd").is_stage() && !of("a.usd").is_package());
        assert!(of("a.vdb").is_grid_file() && !of("a.vdb").is_stage());
        assert!(of("a.toml").is_scene_file() && !of("a.toml").is_grid_file());
        assert!(!of("a.usda").is_grid_file() && !of("a.usda").is_scene_file());
        // A name that is all extension has none.
        assert_eq!(of(".toml"), InputKind::Vdb);
        assert!(is_usda_layer(Path::new("o/shadows.USDA")));
        assert!(!is_usda_layer(Path::new("o/shadows.usdc")));
        assert!(!is_usda_layer(Path::new("usda")));
    }
}
