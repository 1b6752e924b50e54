//! Library errors as Python exceptions, and their wording for Python.

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

// ---------------------------------------------------------------------------------------------
// Errors

/// Which Python exception a library error becomes.
#[derive(Clone, Copy)]
pub(crate) enum Class {
    /// `umbra.FileError` (an `OSError`): the file or the file system.
    File,
    /// `umbra.InvalidArgument` (a `ValueError`): the caller's arguments.
    Argument,
    /// `umbra.Error`: anything else (a NaN answer).
    Other,
}

pub(crate) fn class_of(e: &umbra::Error) -> Class {
    use umbra::Error as E;
    match e {
        E::Io { .. }
        | E::NotVdb { .. }
        | E::Invalid { .. }
        | E::InvalidNanoVdb { .. }
        | E::Unsupported { .. }
        | E::LevelSet { .. }
        | E::Output { .. }
        | E::Exists { .. }
        | E::Scene { .. } => Class::File,
        E::InvalidArgument { .. } | E::Conflict { .. } | E::GridNotFound { .. } => Class::Argument,
        _ => Class::Other,
    }
}

static ERRORS: PyOnceLock<Py<PyModule>> = PyOnceLock::new();

/// A Python exception of `class` with `message` (the classes live in `umbra._errors`, so that
/// `FileError` can be both an `umbra.Error` and an `OSError`).
pub(crate) fn raise(class: Class, message: String) -> PyErr {
    Python::attach(|py| {
        let module =
            ERRORS.get_or_try_init(py, || py.import("umbra._errors").map(pyo3::Bound::unbind));
        let name = match class {
            Class::File => "FileError",
            Class::Argument => "InvalidArgument",
            Class::Other => "Error",
        };
        match module.and_then(|m| m.bind(py).getattr(name)) {
            Ok(ty) => match ty.cast_into::<PyType>() {
                Ok(ty) => PyErr::from_type(ty, message),
                Err(_) => pyo3::exceptions::PyRuntimeError::new_err(message),
            },
            Err(e) => e,
        }
    })
}

/// A library error as a Python exception, worded for Python: an option named as its keyword
/// (the library's `deep-error` is `deep_error`), an existing output with how to replace it.
pub(crate) fn py_err(e: umbra::Error) -> PyErr {
    let e = py_worded(e);
    raise(class_of(&e), python_words(&e.to_string()))
}

/// A library message with the options it names in words (a level set's option) as Python
/// spells them.
fn python_words(text: &str) -> String {
    text.replace(umbra::error::LEVELSET_OPTION, "levelset=\"solid\"")
}

/// A library error worded for Python: an option named as its keyword (the library's
/// `deep-error` is `deep_error`), an existing output with how to replace it.
pub(crate) fn py_worded(e: umbra::Error) -> umbra::Error {
    match e {
        umbra::Error::InvalidArgument { name, reason } => umbra::Error::InvalidArgument {
            name: name.trim_start_matches("--").replace('-', "_"),
            reason,
        },
        umbra::Error::Conflict { names, reason } => umbra::Error::Conflict {
            names: names.iter().map(|n| n.replace('-', "_")).collect(),
            reason,
        },
        umbra::Error::Exists { path } => umbra::Error::Output {
            path,
            reason: "already exists (pass force=True to replace it)".into(),
        },
        other => other,
    }
}

/// A library error as the command line words it (an option as its flag, `--step`): the
/// messages a query batch records per row, which the CLI's `query --rays` prints the same.
pub(crate) fn cli_worded(e: umbra::Error) -> umbra::Error {
    match e {
        umbra::Error::InvalidArgument { name, reason } => umbra::Error::InvalidArgument {
            name: format!("--{}", name.trim_start_matches("--").replace('_', "-")),
            reason,
        },
        other => other,
    }
}

/// A load error as `umbra query`/`bake` print it: `loading grid 'NAME': ...` (`loading the
/// scene: ...`), argument errors as they are.
pub(crate) fn load_err(e: umbra::Error, source: &umbra::input::Source) -> PyErr {
    let class = class_of(&e);
    match e {
        umbra::Error::InvalidArgument { .. } => py_err(e),
        other if source.kind().is_scene_file() => {
            raise(class, python_words(&format!("loading the scene: {other}")))
        }
        other => raise(
            class,
            python_words(&format!(
                "loading grid '{}': {other}",
                source.options().grid
            )),
        ),
    }
}

pub(crate) fn arg(name: &str, reason: impl Into<String>) -> PyErr {
    raise(
        Class::Argument,
        format!("invalid argument '{name}': {}", reason.into()),
    )
}

// ---------------------------------------------------------------------------------------------
// Module functions
