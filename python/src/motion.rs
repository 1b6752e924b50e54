//! Motion blur on the native `Volume`: the motion keywords of a call pick the scene it traces,
//! the loaded one or a moving copy of it (kept for the next call with the same motion).

use crate::errors::*;
use crate::volume::NativeVolume;
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

/// The motion keywords of a call's options (JSON text, already checked by the options'
/// own parse; other keys ignored).
#[derive(Default)]
struct MotionKeys {
    velocity: Option<String>,
    shutter: Option<[f64; 2]>,
    fps: Option<f64>,
    velocity_scale: Option<f64>,
    time_samples: Option<u32>,
}

impl MotionKeys {
    fn of(options: &str) -> Self {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(options) else {
            return Self::default();
        };
        let num = |k: &str| v.get(k).and_then(serde_json::Value::as_f64);
        Self {
            velocity: v
                .get("velocity")
                .and_then(|s| s.as_str())
                .map(str::to_string),
            shutter: v.get("shutter").and_then(|s| s.as_array()).and_then(|a| {
                match (
                    a.first().and_then(|x| x.as_f64()),
                    a.get(1).and_then(|x| x.as_f64()),
                ) {
                    (Some(o), Some(c)) if a.len() == 2 => Some([o, c]),
                    _ => None,
                }
            }),
            fps: num("fps"),
            velocity_scale: num("velocity_scale"),
            time_samples: v
                .get("time_samples")
                .and_then(serde_json::Value::as_u64)
                .map(|n| u32::try_from(n).unwrap_or(u32::MAX)),
        }
    }
}

impl NativeVolume {
    /// The scene a call with `options` (the Python keywords, JSON text) traces: the loaded
    /// one, or, when `velocity` is given, the loaded grid blurred by that velocity grid of its
    /// file (`umbra::request::motion_request`; kept for the next call with the same motion).
    pub(crate) fn scene_for(&self, py: Python<'_>, options: &str) -> PyResult<SceneRef<'_>> {
        let keys = MotionKeys::of(options);
        let Some(velocity) = keys.velocity else {
            let given = [
                ("shutter", keys.shutter.is_some()),
                ("fps", keys.fps.is_some()),
                ("velocity_scale", keys.velocity_scale.is_some()),
                ("time_samples", keys.time_samples.is_some()),
            ];
            if let Some((k, _)) = given.iter().find(|(_, g)| *g) {
                return Err(arg(
                    k,
                    "applies to motion blur: give the velocity grid (velocity)",
                ));
            }
            return Ok(SceneRef::Still(&self.scene));
        };
        let request = umbra::request::motion_request(
            &velocity,
            keys.shutter,
            keys.fps,
            keys.velocity_scale,
            keys.time_samples,
        )
        .map_err(py_err)?;
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

/// The cache of [`NativeVolume::scene_for`]: the last motion asked for and its scene.
pub(crate) type MovingCache = std::sync::Mutex<Option<(MotionRequest, Arc<Scene>)>>;
