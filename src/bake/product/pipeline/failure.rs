//! Where a bake failed ([`Step`]) and why ([`BakeError`]): the library error with the step it
//! stopped at and what it was doing, which each front end words its own way.

use crate::error::Error;

/// The step of a bake a failure stopped it at ([`BakeError`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Checking the request: its options, its outputs (writable, not clobbered) and its
    /// settings. Nothing but a reused camera's file was read.
    Check,
    /// Reading the input: the grid (or a scene, a stage's volumes, the topology of a bake in
    /// parts) and framing the camera on it.
    Load,
    /// Tracing, encoding and committing the outputs.
    Bake,
}

/// A bake that failed: the library's error, the [`Step`] it stopped at, and for a load, the
/// context a user reads it in (`loading grid 'density'`, `loading the scene`). Displayed as
/// `context: error`, the line `umbra bake` prints and the Python module raises.
#[derive(Debug)]
pub struct BakeError {
    /// Where the bake stopped.
    pub step: Step,
    /// What was being loaded, for a load error that is not about an argument or an output.
    pub context: Option<String>,
    /// The error.
    pub error: Error,
}

impl BakeError {
    /// `error` at `step`, without context.
    #[must_use]
    pub fn at(step: Step, error: Error) -> Self {
        Self {
            step,
            context: None,
            error,
        }
    }

    /// A load error of `source` (its grid): in the context of loading it, unless it is about
    /// an argument or an output, which speak for themselves.
    #[must_use]
    pub fn loading(source: &crate::input::Source, error: Error) -> Self {
        let context = match error {
            Error::Output { .. } | Error::Exists { .. } | Error::InvalidArgument { .. } => None,
            _ if source.kind().is_scene_file() => Some("loading the scene".to_string()),
            _ => Some(format!("loading grid '{}'", source.options().grid)),
        };
        Self {
            step: Step::Load,
            context,
            error,
        }
    }

    /// The failure with its library error worded by a front end (`f`: an option as its user
    /// types it, an existing output with how to replace it); step and context unchanged.
    #[must_use]
    pub fn worded(self, f: impl FnOnce(Error) -> Error) -> Self {
        Self {
            error: f(self.error),
            ..self
        }
    }
}

impl std::fmt::Display for BakeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.context {
            Some(c) => write!(f, "{c}: {}", self.error),
            None => write!(f, "{}", self.error),
        }
    }
}

impl std::error::Error for BakeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.error)
    }
}
