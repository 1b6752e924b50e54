//! Loading a [`Source`]: the one loader of scenes, stages and grid files (`Source::load` and
//! its siblings, in the scene layer because they build scenes), and the checked form of a
//! source's read options (`SceneOptions::of`).

use super::file::{load, load_for_rays, read_box_corners, sources, SceneOptions};
use super::Scene;
use crate::error::Result;
use crate::input::Source;
use glam::DVec3;
use std::path::PathBuf;

impl SceneOptions {
    /// The read options of `source`, checked: its placement and its motion
    /// ([`crate::motion::MotionRequest::of`]).
    fn of(source: &Source) -> Result<Self> {
        let o = source.options();
        Ok(Self {
            kind: source.kind(),
            grid: o.grid.clone(),
            density_scale: o.density_scale,
            sigma_t: o.sigma_t,
            xform: source.xform()?,
            levelset_solid: o.levelset == Some(crate::input::LevelSet::Solid),
            stage: crate::usd::Selection::of(source.options()),
            motion: crate::motion::MotionRequest::of(o)?,
        })
    }
}

impl Source {
    /// Load the scene this source reads: a scene file (`.toml`), a USD stage (its volumes at
    /// the selection's time code, [`crate::usd`]) or one grid of a grid file, with the read
    /// options applied (scale, colour, placement, level sets, motion).
    ///
    /// # Errors
    /// As [`load`], and [`Error::InvalidArgument`] naming `xform` or a motion option.
    pub fn load(&self) -> Result<Scene> {
        load(self.path(), &SceneOptions::of(self)?)
    }

    /// [`Source::load`] for a job whose rays are known before it traces ([`load_for_rays`]).
    ///
    /// # Errors
    /// As [`load_for_rays`].
    pub fn load_for_rays(
        &self,
        gran: crate::traverse::Granularity,
        lazy_from: u64,
        rays: impl FnOnce(&Scene) -> Vec<crate::ray::Ray>,
    ) -> Result<(Scene, Vec<crate::ray::Ray>)> {
        let interp = self.options().interp;
        load_for_rays(
            self.path(),
            &SceneOptions::of(self)?,
            interp,
            gran,
            lazy_from,
            rays,
        )
    }

    /// The files a load reads ([`sources`]).
    ///
    /// # Errors
    /// As [`sources`].
    pub fn files(&self) -> Result<Vec<PathBuf>> {
        sources(self.path(), &SceneOptions::of(self)?)
    }

    /// The world corners of every grid box the source reads ([`read_box_corners`]).
    ///
    /// # Errors
    /// As [`read_box_corners`].
    pub fn box_corners(&self) -> Result<Vec<DVec3>> {
        read_box_corners(self.path(), &SceneOptions::of(self)?)
    }
}
