//! [`Source`]: what a job reads, made once from a path, and [`InputKind`], what kind of input
//! a path is: the one place an input's kind is decided ([`InputKind::of`], asked by
//! [`Source::new`] and by [`super::GridFile::open`] alone).

use super::options::SourceOptions;
use std::path::{Path, PathBuf};

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

/// Whether `path` names a USD package (`.usdz`): how the USD reader tells a layer or an
/// asset read through a package (a path inside the input layer, not a job's input).
#[must_use]
pub fn is_package(path: &Path) -> bool {
    InputKind::of(path).is_package()
}

/// What a job reads: its input's path, the kind of that input (decided when the source is
/// made, [`InputKind::of`]) and how it is read ([`SourceOptions`]: the grid or stage
/// selection, what the values mean, the placement, the motion). Every product takes one; the
/// layers above ask it ([`Source::kind`]) instead of the path. Loaded by `Source::load` and
/// its siblings (`crate::scene::file`, which builds scenes from it).
#[derive(Debug, Clone, PartialEq)]
pub struct Source {
    path: PathBuf,
    kind: InputKind,
    options: SourceOptions,
}

impl Source {
    /// The source at `path`, read with `options`; its kind from the path's extension.
    #[must_use]
    pub fn new(path: impl Into<PathBuf>, options: SourceOptions) -> Self {
        let path = path.into();
        let kind = InputKind::of(&path);
        Self {
            path,
            kind,
            options,
        }
    }

    /// The input's path.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What kind of input it is.
    #[must_use]
    pub fn kind(&self) -> InputKind {
        self.kind
    }

    /// How it is read.
    #[must_use]
    pub fn options(&self) -> &SourceOptions {
        &self.options
    }

    /// How it is read, to change.
    pub fn options_mut(&mut self) -> &mut SourceOptions {
        &mut self.options
    }

    /// The same read options at another path (a grid file a stage names, a frame of a
    /// sequence), its kind decided anew.
    #[must_use]
    pub fn at(&self, path: impl Into<PathBuf>) -> Self {
        Self::new(path, self.options.clone())
    }

    /// Check what only some kinds of input read: the stage options (`frame`, `volume`,
    /// `field`, `light`) are refused for an input that is not a USD stage; a stage's `frame`
    /// must be finite and its `field` not empty.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming the option.
    pub fn check(&self) -> crate::error::Result<()> {
        let o = &self.options;
        let bad = |name: &str, reason: String| crate::error::Error::InvalidArgument {
            name: name.into(),
            reason,
        };
        if !self.kind.is_stage() {
            let given = [
                ("frame", o.frame.is_some()),
                ("volume", o.volume.is_some()),
                ("field", o.field.is_some()),
                ("light", o.light.is_some()),
            ];
            return match given.iter().find(|(_, g)| *g) {
                Some((k, _)) => Err(bad(k, self.not_a_stage())),
                None => Ok(()),
            };
        }
        if let Some(f) = o.frame {
            if !f.is_finite() {
                return Err(bad("frame", format!("{f} is not a finite time code")));
            }
        }
        if o.field.as_deref() == Some("") {
            return Err(bad("field", "must not be empty".into()));
        }
        Ok(())
    }

    /// Why a stage option does not apply to this input.
    #[must_use]
    pub fn not_a_stage(&self) -> String {
        format!(
            "applies to USD stages (.usd, .usda, .usdc, .usdz); {} is not one",
            self.path.display()
        )
    }

    /// The placement transform, checked.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming `xform`.
    pub fn xform(&self) -> crate::error::Result<Option<crate::xform::Xform>> {
        self.options
            .xform
            .as_deref()
            .map(crate::xform::Xform::from_row_major)
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::is_usda_layer;

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
