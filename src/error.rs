//! Typed library errors, classified by whose fault they are (exrs style): the file is not a VDB,
//! the file is corrupt, the file is valid but uses a feature umbra does not support, the caller
//! asked for something that does not exist, or the operating system failed.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// How a [`Error::LevelSet`] names the option that traces a level set as a solid, in the
/// library's spelling: the front ends replace it with theirs.
pub const LEVELSET_OPTION: &str = "the option levelset set to solid";

/// Every error the umbra library can return. Each variant names the file it concerns so a
/// one-line message is enough for a user to act on.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system could not read or write the path.
    #[error("{}: {err}", path.display())]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Underlying error (not a `#[source]`: the message already includes it).
        err: std::io::Error,
    },
    /// The path exists but is not a file of the grid format it is read as (bad magic number,
    /// too short, a directory): an OpenVDB file, or for a `.nvdb` path a NanoVDB file.
    #[error("{}: not a {format} file ({reason})", path.display())]
    NotVdb {
        /// File concerned.
        path: PathBuf,
        /// The format it is not: `VDB` or `NanoVDB`.
        format: &'static str,
        /// What made it not a file of that format.
        reason: String,
    },
    /// The file is a VDB file but its content is corrupt or truncated.
    #[error("{}: corrupt VDB file: {reason}", path.display())]
    Invalid {
        /// File concerned.
        path: PathBuf,
        /// What is wrong, with the byte offset where it was found.
        reason: String,
    },
    /// The file is a NanoVDB (`.nvdb`) file but its content is corrupt or truncated, or its
    /// metadata disagrees with its grids (a checksum mismatch included).
    #[error("{}: corrupt NanoVDB file: {reason}", path.display())]
    InvalidNanoVdb {
        /// File concerned.
        path: PathBuf,
        /// What is wrong, with the byte offset or the grid where it was found.
        reason: String,
    },
    /// The file is valid but uses a feature umbra does not implement.
    #[error("{}: unsupported: {what}", path.display())]
    Unsupported {
        /// File concerned.
        path: PathBuf,
        /// The unsupported feature, by its OpenVDB name.
        what: String,
    },
    /// A level-set grid asked to be traced as fog: what its values mean forbids it. Each front
    /// end words [`LEVELSET_OPTION`] in its own spelling (`--levelset solid`, `levelset =
    /// "solid"`, `levelset="solid"`).
    #[error(
        "{}: unsupported: grid '{}' is a level set (signed distance to a surface, not a \
         density): tracing it as fog would give meaningless transmittance; trace it as an \
         opaque solid ({LEVELSET_OPTION}; kind = \"solid\" in a scene file), or convert it to \
         a fog volume (OpenVDB sdfToFogVolume, Houdini VDB Convert)",
        path.display(),
        crate::text::escape(grid)
    )]
    LevelSet {
        /// File concerned.
        path: PathBuf,
        /// The level-set grid.
        grid: String,
    },
    /// The requested grid is not in the file.
    #[error("{}: no grid named '{}' (available: {})", path.display(), crate::text::escape(name), if available.is_empty() { "none".to_string() } else { available.iter().map(|a| crate::text::escape(a)).collect::<Vec<_>>().join(", ") })]
    GridNotFound {
        /// File concerned.
        path: PathBuf,
        /// Name asked for.
        name: String,
        /// Display names of the grids the file holds, in file order.
        available: Vec<String>,
    },
    /// An output file could not be written (exists and may not be overwritten, its directory is
    /// missing, the encoder failed). Nothing is left behind at `path` when this is returned.
    #[error("{}: cannot write: {reason}", path.display())]
    Output {
        /// File that was to be written.
        path: PathBuf,
        /// Why it was not written.
        reason: String,
    },
    /// A computation produced NaN where a number was due (a transmittance, an optical depth).
    /// Reported instead of returned, so no NaN or null ever reaches a map or a pipeline with
    /// success; it means an input outside what umbra resolves, or a bug.
    #[error("the {what} is not a number (NaN){context}")]
    NotANumber {
        /// What came out as NaN (`transmittance estimate`, `optical depth`).
        what: String,
        /// Where: the ray, or empty.
        context: String,
    },
    /// A scene file (`.toml`) is malformed: bad TOML, an unknown key, an entry that makes no
    /// sense. The reason names the line or the `[[volume]]` entry.
    #[error("{}: {reason}", path.display())]
    Scene {
        /// The scene file.
        path: PathBuf,
        /// What is wrong, where.
        reason: String,
    },
    /// A USD stage cannot be read as a shot: it cannot be opened, or a prim it names is not
    /// what umbra reads (no volume, a field that is not an `OpenVDBAsset`, a missing asset, an
    /// unknown light). The reason names the time code and the prim.
    #[error("{}: {reason}", path.display())]
    Stage {
        /// The stage file.
        path: PathBuf,
        /// What is wrong, at which time, on which prim.
        reason: String,
    },
    /// An output file exists and the caller did not allow replacing it. Nothing was written.
    /// Each front end adds how its user allows replacing it (`--force`, `force=True`).
    #[error("{}: cannot write: already exists", path.display())]
    Exists {
        /// The existing file.
        path: PathBuf,
    },
    /// A caller-supplied argument is out of its domain. `name` is the library's name of the
    /// option in kebab case (`deep-error`); each front end respells it as its user types it
    /// (`--deep-error` on the command line, `deep_error` in Python and job files).
    #[error("invalid argument '{name}': {reason}")]
    InvalidArgument {
        /// Argument name.
        name: String,
        /// Why it is invalid.
        reason: String,
    },
    /// Caller-supplied options that do not go together, or one given without another it
    /// needs. `names` are the options in the library's spelling (kebab case) and `reason`
    /// names them as `{0}`, `{1}`, ... (its display fills them in), so that each front end
    /// respells every name as its user types it, as for [`Error::InvalidArgument`].
    #[error("{}", fill_names(reason, names))]
    Conflict {
        /// The options the reason names, in the library's spelling.
        names: Vec<String>,
        /// Why they conflict, with `{i}` where `names[i]` goes.
        reason: String,
    },
}

/// `template` with `{i}` replaced by `names[i]` (the last first, so `{1}` never eats `{10}`).
fn fill_names(template: &str, names: &[String]) -> String {
    let mut s = template.to_string();
    for (i, n) in names.iter().enumerate().rev() {
        s = s.replace(&format!("{{{i}}}"), n);
    }
    s
}

/// A decoding error without a path: the byte reader and decoders produce these, and
/// [`DecodeError::at`] attaches the file name at the module boundary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum DecodeError {
    /// The data ran out before a field was complete. `need` is the absolute file offset one
    /// past the last byte the field needs, so a reader over a window of the file knows how far
    /// to grow it, or that no file of this length can hold the field.
    Truncated {
        /// What ran out, where.
        msg: String,
        /// Absolute end offset the field needs (saturating).
        need: u64,
    },
    /// The data is corrupt.
    Invalid(String),
    /// The data uses an unsupported feature.
    Unsupported(String),
}

impl DecodeError {
    pub(crate) fn invalid(msg: impl Into<String>) -> Self {
        Self::Invalid(msg.into())
    }
    pub(crate) fn unsupported(msg: impl Into<String>) -> Self {
        Self::Unsupported(msg.into())
    }
    /// Attach the path of a NanoVDB file: corrupt data is [`Error::InvalidNanoVdb`].
    pub(crate) fn at_nvdb(self, path: &std::path::Path) -> Error {
        match self {
            Self::Invalid(reason) | Self::Truncated { msg: reason, .. } => Error::InvalidNanoVdb {
                path: path.to_path_buf(),
                reason,
            },
            other => other.at(path),
        }
    }
    /// Attach the file path, turning this into a public [`Error`].
    pub(crate) fn at(self, path: &std::path::Path) -> Error {
        match self {
            Self::Invalid(reason) | Self::Truncated { msg: reason, .. } => Error::Invalid {
                path: path.to_path_buf(),
                reason,
            },
            Self::Unsupported(what) => Error::Unsupported {
                path: path.to_path_buf(),
                what,
            },
        }
    }
}

/// Result alias for path-less decoding.
pub(crate) type DecodeResult<T> = std::result::Result<T, DecodeError>;
