//! `umbra._umbra`: the native half of umbra's Python module, a thin layer over the umbra
//! library. The pure-Python package `umbra` (`python/umbra/__init__.py`) checks and converts
//! arguments (NumPy arrays to C-contiguous `float64`), and this module does the work with the
//! GIL released, on rayon's threads.
//!
//! Errors become `umbra.Error` (`umbra.FileError`, also an `OSError`, for what a file or the
//! file system did; `umbra.InvalidArgument`, also a `ValueError`, for what the caller asked),
//! with the messages the CLI prints after `umbra: error: `.

use pyo3::prelude::*;

mod errors;
mod functions;
mod motion;
mod native;
mod trace;
mod volume;

use functions::*;
use native::NativeVolume;

/// umbra's native module: see the `umbra` package.
#[pymodule]
fn _umbra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(info_json, m)?)?;
    m.add_function(wrap_pyfunction!(estimators_json, m)?)?;
    m.add_function(wrap_pyfunction!(estimator_options_json, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(run_job, m)?)?;
    m.add_function(wrap_pyfunction!(job_status, m)?)?;
    m.add_function(wrap_pyfunction!(emit_job, m)?)?;
    m.add_function(wrap_pyfunction!(bake_file, m)?)?;
    m.add_function(wrap_pyfunction!(usd_lights_json, m)?)?;
    m.add_function(wrap_pyfunction!(usd_points_json, m)?)?;
    m.add_class::<NativeVolume>()?;
    Ok(())
}
