//! Motion blur on the native `Volume`: the motion keywords of a call pick the scene it traces,
//! the loaded one or a moving copy of it (kept for the next call with the same motion).

use crate::errors::*;
use crate::native::NativeVolume;
use pyo3::prelude::*;
use std::sync::Arc;
use umbra::scene::Scene;

/// The scene a call traces: the loaded one, or a moving copy of it.
pub(crate) enum SceneRef<'a> {
    Still(&'a Scene),
    Moving(Arc<Scene>),
}

impl std::ops::Deref for SceneRef<'_> {
    type Target = Scene;
    fn deref(&self) -> &Scene {
        match self {
            Self::Still(s) => s,
            Self::Moving(s) => s,
        }
    }
}

impl NativeVolume {
    /// The scene a call traces: the loaded one, or, when the call's read options `read` ask
    /// for motion (their motion keys, checked by the caller:
    /// [`umbra::request::EstimatorOptions::motion`]), the loaded source with that motion,
    /// loaded by [`umbra::input::Source::load`] and kept for the next call with the same
    /// motion.
    pub(crate) fn scene_for(
        &self,
        py: Python<'_>,
        read: umbra::input::SourceOptions,
    ) -> PyResult<SceneRef<'_>> {
        if read.velocity.is_none() {
            return Ok(SceneRef::Still(&self.scene));
        }
        // The loaded source with the call's motion keys: the one key set that names it.
        let mut options = self.source.options().clone();
        options.velocity = read.velocity;
        options.shutter = read.shutter;
        options.fps = read.fps;
        options.velocity_scale = read.velocity_scale;
        options.time_samples = read.time_samples;
        let mut cache = self
            .moving
            .lock()
            .map_err(|_| raise(Class::Other, "a motion blur call panicked".into()))?;
        if let Some((r, s)) = cache.as_ref() {
            if *r == options {
                return Ok(SceneRef::Moving(s.clone()));
            }
        }
        if !self.source.kind().is_grid_file() {
            return Err(arg(
                "velocity",
                "motion blur reads the velocity grid of a grid file (.vdb, .nvdb)",
            ));
        }
        self.single("velocity")?;
        let mut moving = self.source.clone();
        moving.options_mut().clone_from(&options);
        let scene = py.detach(|| moving.load()).map_err(py_err)?;
        let scene = Arc::new(scene);
        *cache = Some((options, scene.clone()));
        Ok(SceneRef::Moving(scene))
    }
}
