//! Shared cameras: one camera per light for a whole sequence, framed on the union of its volume
//! boxes before any task runs (`framing = "shared"`), and cached beside the log so the many
//! processes of a farm job read every frame's topology once between them.

use super::parse::err;
use super::{BatchError, Framing, Job, Task};
use crate::bake::Camera;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The shared cameras of a job as its cache file stores them.
#[derive(Serialize, Deserialize)]
struct CameraCache {
    fingerprint: String,
    cameras: Vec<CachedCamera>,
}

/// One shared camera: its sequence, light and fields.
#[derive(Serialize, Deserialize)]
struct CachedCamera {
    sequence: usize,
    light: String,
    camera: crate::bake::CameraParts,
}

impl Job {
    /// With `framing = "shared"` (and no fixed camera): frame one camera per sequence (one
    /// `[[inputs]]` entry) and light on the union of the sequence's volume boxes, so all maps
    /// of a light across the sequence line up. The boxes come from
    /// each file's header and topology (no voxel values; [`crate::Volume::read_box_corners`]);
    /// the camera frames all their corners together (a single input: exactly its own box). Inputs whose grid holds only its
    /// background add nothing, nor do inputs that cannot be decoded (their tasks then fail
    /// alone, as without sharing). Runs before any task, so a missing input or grid fails the
    /// whole job up front.
    ///
    /// # Errors
    /// [`BatchError::Task`] naming the input that cannot be read; [`BatchError::Invalid`]
    /// naming a light that cannot frame the union (for example a light inside it).
    pub fn share_cameras(&self) -> Result<(), BatchError> {
        if self.framing != Framing::Shared || self.camera.is_some() || self.volume {
            return Ok(());
        }
        let mut shared = std::collections::BTreeMap::new();
        let sequences = self.tasks.last().map_or(0, |t| t.sequence + 1);
        for sequence in 0..sequences {
            // Tasks that bake nothing (a light without shadows) frame nothing.
            let tasks: Vec<&Task> = self
                .tasks
                .iter()
                .filter(|t| t.sequence == sequence && self.shadowless(t).is_none())
                .collect();
            let mut lights: Vec<&str> = tasks.iter().map(|t| t.light.as_str()).collect();
            lights.sort_unstable();
            lights.dedup();
            // Each stage light frames the volumes its shadow link includes; the others share
            // one union of every volume.
            let mut unions = std::collections::BTreeMap::new();
            for light in lights {
                let mine: Vec<&Task> = tasks.iter().copied().filter(|t| t.light == light).collect();
                let key = mine.first().and_then(|t| t.usd_light.clone());
                if !unions.contains_key(&key) {
                    unions.insert(key.clone(), self.sequence_corners(&mine)?);
                }
                let union = unions.get(&key).map_or(&[][..], Vec::as_slice);
                if union.is_empty() {
                    continue; // nothing to frame anywhere: each task reports it
                }
                let t = mine[0];
                let view = self.bake_job(t, 0)?.view;
                self.steady_light(t, &mine)?;
                let camera = Camera::frame(&view, union).map_err(|e| {
                    err(
                        &self.path,
                        &format!("lights '{}'", t.light),
                        format!("cannot frame the shared camera of inputs[{sequence}]: {e}"),
                    )
                })?;
                shared.insert((sequence, t.light.clone()), camera);
            }
        }
        // A second call finds the same cameras (same files), so a set map stays.
        let _ = self.shared.set(shared);
        Ok(())
    }

    /// The corners of the volume boxes of every input of `tasks` (one sequence, one light),
    /// read as the first task reads its input (toward its light).
    fn sequence_corners(&self, tasks: &[&Task]) -> Result<Vec<glam::DVec3>, BatchError> {
        let Some(first) = tasks.first() else {
            return Ok(Vec::new());
        };
        // A USD stage is one input read at every frame of the sequence.
        let mut inputs: Vec<(&Path, Option<f64>)> = tasks
            .iter()
            .map(|t| (t.input.as_path(), t.time()))
            .collect();
        inputs.dedup();
        let mut union = Vec::new();
        for (input, time) in inputs {
            // Every task of a sequence reads its files as its [[inputs]] entry says.
            let mut source = first.source.at(input);
            source.options_mut().frame = time;
            match source.box_corners() {
                Ok(c) => union.extend(c),
                // A missing file or grid, or a malformed scene, fails the job before any
                // task runs.
                Err(
                    e @ (crate::error::Error::Io { .. }
                    | crate::error::Error::GridNotFound { .. }
                    | crate::error::Error::Scene { .. }),
                ) => return Err(e.into()),
                // A corrupt or unsupported frame adds nothing here and fails alone.
                Err(_) => {}
            }
        }
        Ok(union)
    }

    /// A shared camera is one projection: a stage light that moves or turns over the sequence
    /// cannot have one (each frame's map would be wrong), so it is refused by name.
    fn steady_light(&self, t: &Task, tasks: &[&Task]) -> Result<(), BatchError> {
        if t.usd_light.is_none() {
            return Ok(());
        }
        let first = self.bake_job(t, 0)?.view;
        for o in tasks
            .iter()
            .filter(|o| o.light == t.light && o.time() != t.time())
        {
            let v = self.bake_job(o, 0)?.view;
            if (v.light_dir, v.light_pos) != (first.light_dir, first.light_pos) {
                return Err(err(
                    &self.path,
                    &format!("lights '{}'", t.light),
                    format!(
                        "the stage light moves between frames {} and {}: a shared camera \
                         cannot follow it; set framing = \"per-frame\" in [bake]",
                        t.time().map_or_else(|| "start".into(), |f| f.to_string()),
                        o.time().map_or_else(|| "start".into(), |f| f.to_string())
                    ),
                ));
            }
        }
        Ok(())
    }

    /// [`Job::share_cameras`] through a cache file, so that the many processes of a farm job
    /// (`--task`, `--shard`) read every frame's topology once between them rather than once
    /// each. The cache (JSON: a fingerprint of everything framing depends on, and each
    /// camera's fields) is used when its fingerprint matches and it is not older than the job
    /// file or any input; otherwise the cameras are computed and the cache rewritten
    /// atomically. A cache that cannot be read or written is only a lost shortcut: the cameras
    /// are then computed as without it. Returns whether the cache was used.
    ///
    /// # Errors
    /// As [`Job::share_cameras`].
    pub fn share_cameras_cached(&self, cache: &Path) -> Result<bool, BatchError> {
        if self.framing != Framing::Shared
            || self.camera.is_some()
            || self.volume
            || self.shared.get().is_some()
        {
            return Ok(false);
        }
        let fingerprint = self.framing_fingerprint();
        if let Some(cameras) = self.read_camera_cache(cache, &fingerprint) {
            let _ = self.shared.set(cameras);
            return Ok(true);
        }
        self.share_cameras()?;
        if let Some(cameras) = self.shared.get() {
            let stored = CameraCache {
                fingerprint,
                cameras: cameras
                    .iter()
                    .map(|((sequence, light), c)| CachedCamera {
                        sequence: *sequence,
                        light: light.clone(),
                        camera: c.parts(),
                    })
                    .collect(),
            };
            if let Ok(text) = serde_json::to_string_pretty(&stored) {
                // Best effort: a farm node that cannot write beside the log still runs. The
                // job is valid by now (the cameras are framed), so its log directory may be
                // made here.
                if let Some(d) = cache.parent().filter(|d| !d.as_os_str().is_empty()) {
                    let _ = std::fs::create_dir_all(d);
                }
                let _ = crate::output::write_atomic(cache, true, |w| {
                    std::io::Write::write_all(w, text.as_bytes()).map_err(|e| e.to_string())
                });
            }
        }
        Ok(false)
    }

    /// Everything the shared cameras depend on, as text.
    fn framing_fingerprint(&self) -> String {
        let tasks: Vec<_> = self
            .tasks
            .iter()
            .map(|t| {
                (
                    t.sequence,
                    &t.input,
                    &t.light,
                    t.dir,
                    t.pos,
                    &t.usd_light,
                    t.frame,
                    (&t.grid, &t.xform, t.levelset),
                )
            })
            .collect();
        let o = &self.options;
        serde_json::json!({
            "version": 1,
            "grid": self.grid,
            "res": o.res,
            "fov_deg": o.fov,
            "ortho": o.ortho,
            "up": o.up,
            "frame_box": o.frame_box,
            "xform": o.source.xform,
            "tasks": tasks,
        })
        .to_string()
    }

    /// The cached cameras, when the cache is valid (see [`Job::share_cameras_cached`]).
    fn read_camera_cache(
        &self,
        cache: &Path,
        fingerprint: &str,
    ) -> Option<std::collections::BTreeMap<(usize, String), Camera>> {
        let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
        let at = modified(cache)?;
        // The job file, and every file each task reads (a stage's or a scene's assets too).
        if modified(&self.path)? > at {
            return None;
        }
        for t in &self.tasks {
            for p in self.sources(t)? {
                if modified(&p)? > at {
                    return None;
                }
            }
        }
        let stored: CameraCache = serde_json::from_slice(&std::fs::read(cache).ok()?).ok()?;
        if stored.fingerprint != fingerprint {
            return None;
        }
        stored
            .cameras
            .iter()
            .map(|c| {
                Some((
                    (c.sequence, c.light.clone()),
                    Camera::restore(&c.camera).ok()?,
                ))
            })
            .collect()
    }
}
