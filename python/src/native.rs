//! What the native module's files share, below all of them: the native `Volume`'s data
//! ([`NativeVolume`]; its Python methods are in `volume.rs`, its tracing in `trace.rs`, its
//! moving copies in `motion.rs`), the shapes of what its calls return, and the JSON of stats
//! and summaries. It imports only `errors`, so the module's files import each other without a
//! loop.

use crate::errors::*;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use umbra::bake::MapSummary;
use umbra::scene::Scene;

/// A loaded volume (a grid of a `.vdb` file, or a scene) with what it was loaded with.
#[pyclass(frozen, module = "umbra._umbra", name = "Volume")]
pub(crate) struct NativeVolume {
    pub(crate) scene: Scene,
    /// What was loaded: the path, its kind and how it was read (grid, density scale,
    /// interpolation, `xform`, a stage's selection); a moving copy is this source with the
    /// call's motion, loaded by [`umbra::input::Source::load`].
    pub(crate) source: umbra::input::Source,
    pub(crate) warnings: Vec<String>,
    /// Each fog volume's tree statistics, computed on first use (a pass over every leaf).
    pub(crate) stats: std::sync::OnceLock<Vec<umbra::internals::tree::TreeStats>>,
    /// The last moving copy a call's motion keywords asked for ([`NativeVolume::scene_for`]).
    pub(crate) moving: MovingCache,
}

/// `(T, std_err, tau, warnings)`, arrays of shape `(N, C)`.
pub(crate) type TraceOut<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Vec<String>,
);

/// A baked image: `(T, std_err or None, summary JSON, warnings)`, arrays of shape `(C, H, W)`
/// flattened channel-major.
pub(crate) type BakeOut<'py> = (
    Bound<'py, PyArray1<f32>>,
    Option<Bound<'py, PyArray1<f32>>>,
    String,
    Vec<String>,
);

/// A transmittance volume in memory: `(ijk, T, stats JSON, warnings)`, `ijk` of shape `(N, 3)`.
pub(crate) type VolumeOut<'py> = (
    Bound<'py, PyArray2<i32>>,
    Bound<'py, PyArray1<f32>>,
    String,
    Vec<String>,
);

/// A transmittance volume's stats as a JSON object: [`umbra::bake::VolumeStats`]'s fields
/// and `ns_per_voxel`.
pub(crate) fn stats_json(st: &umbra::bake::VolumeStats) -> PyResult<String> {
    let mut v = serde_json::to_value(st).map_err(|e| raise(Class::Other, e.to_string()))?;
    if let Some(o) = v.as_object_mut() {
        o.insert("ns_per_voxel".into(), serde_json::json!(st.ns_per_voxel()));
    }
    Ok(v.to_string())
}

/// `umbra bake --json`'s `deep` object.
pub(crate) fn deep_json(d: &umbra::bake::DeepStats) -> serde_json::Value {
    serde_json::json!({
        "max_error": d.max_error, "samples": d.samples,
        "mean_samples_per_pixel": d.mean_samples(), "max_samples_per_pixel": d.max_samples,
        "empty_pixels": d.empty_pixels, "profile_breakpoints": d.breakpoints,
        "coarse_cells": d.coarse_cells, "rms_error": d.rms_error, "seconds": d.seconds,
    })
}

/// A finished map's summary (the camera dict), as JSON text.
pub(crate) fn summary_json(report: &umbra::bake::BakeReport) -> PyResult<String> {
    let summary = MapSummary::new(&report.map, &report.provenance);
    serde_json::to_string(&summary).map_err(|e| raise(Class::Other, e.to_string()))
}

/// The cache of [`NativeVolume::scene_for`] (`motion.rs`): the last motion asked for (the
/// read options that name it) and its scene.
pub(crate) type MovingCache =
    std::sync::Mutex<Option<(umbra::input::SourceOptions, std::sync::Arc<Scene>)>>;
