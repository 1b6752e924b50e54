//! Motion blur on the native `Volume`: the motion keywords of a call pick the scene it traces,
//! the loaded one or a moving copy of it (kept for the next call with the same motion).

use crate::errors::*;
use crate::native::NativeVolume;
use pyo3::prelude::*;
use std::sync::Arc;
use umbra::internals::motion::MotionRequest;
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
    /// The scene a call traces: the loaded one, or, with `motion` (the call's options'
    /// motion, [`umbra::request::EstimatorOptions::motion`]), the loaded grid blurred by that
    /// velocity grid of its file, kept for the next call with the same motion.
    pub(crate) fn scene_for(
        &self,
        py: Python<'_>,
        motion: Option<MotionRequest>,
    ) -> PyResult<SceneRef<'_>> {
        let Some(request) = motion else {
            return Ok(SceneRef::Still(&self.scene));
        };
        let mut cache = self
            .moving
            .lock()
            .map_err(|_| raise(Class::Other, "a motion blur call panicked".into()))?;
        if let Some((r, s)) = cache.as_ref() {
            if *r == request {
                return Ok(SceneRef::Moving(s.clone()));
            }
        }
        if !umbra::input::InputKind::of(&self.path).is_grid_file() {
            return Err(arg(
                "velocity",
                "motion blur reads the velocity grid of a grid file (.vdb, .nvdb)",
            ));
        }
        let vol = self.single("velocity")?.clone();
        let scene = py
            .detach(|| -> umbra::Result<Scene> {
                let field = request.field(&self.path)?;
                Scene::new(
                    vec![umbra::scene::Fog::new(
                        vol.with_motion(request.spec, field)?,
                        [1.0; 3],
                    )?],
                    Vec::new(),
                    false,
                )
            })
            .map_err(py_err)?;
        let scene = Arc::new(scene);
        *cache = Some((request, scene.clone()));
        Ok(SceneRef::Moving(scene))
    }
}
