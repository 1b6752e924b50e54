//! The one bake pipeline, shared by `umbra bake`, batch tasks and library callers: check the
//! outputs, load the grid, frame the camera, bake, write the map and its preview together, and
//! report what a user should be warned about.

use super::{bake, write_map, BakeSettings, Camera, Map, Provenance, View};
use crate::error::Result;
use crate::output::check_target;
use crate::volume::{Sanitized, Volume};
use std::path::PathBuf;

/// One bake from a file to an EXR map (and optionally a PNG preview).
#[derive(Debug, Clone, PartialEq)]
pub struct BakeJob {
    /// The `.vdb` file.
    pub input: PathBuf,
    /// Grid to trace.
    pub grid: String,
    /// `mu_t = density_scale x value`.
    pub density_scale: f64,
    /// Camera request.
    pub view: View,
    /// Sampling settings.
    pub settings: BakeSettings,
    /// The OpenEXR map.
    pub output: PathBuf,
    /// An 8-bit PNG preview of `T`.
    pub preview: Option<PathBuf>,
    /// Replace existing outputs.
    pub overwrite: bool,
}

/// Something a finished bake wants its user to know.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Warning {
    /// NaN or negative voxels were traced as 0 (the bad-voxel policy).
    BadVoxels {
        /// NaN values.
        nan: u64,
        /// Negative values.
        negative: u64,
    },
    /// Samples stopped at the collision cap: those pixels are biased.
    Capped {
        /// Samples stopped.
        samples: u64,
    },
    /// Lookups outside their segment's bounds: the tree's majorants are wrong.
    MajorantViolations {
        /// Lookups outside the bounds.
        lookups: u64,
    },
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::BadVoxels { nan, negative } => {
                write!(f, "{nan} NaN and {negative} negative values treated as 0")
            }
            Self::Capped { samples } => {
                write!(f, "{samples} samples hit the collision cap (biased)")
            }
            Self::MajorantViolations { lookups } => write!(
                f,
                "{lookups} lookups exceeded their majorant (the estimate is biased; please report)"
            ),
        }
    }
}

/// Warnings about a volume's bad voxels.
#[must_use]
pub fn volume_warnings(s: &Sanitized) -> Vec<Warning> {
    if s.nan + s.negative > 0 {
        vec![Warning::BadVoxels {
            nan: s.nan,
            negative: s.negative,
        }]
    } else {
        Vec::new()
    }
}

/// What a finished bake produced.
#[derive(Debug, Clone)]
pub struct BakeReport {
    /// The map as written.
    pub map: Map,
    /// Where it came from (as in the EXR header).
    pub provenance: Provenance,
    /// Things the user should be told, in order.
    pub warnings: Vec<Warning>,
}

impl BakeJob {
    /// Check every output before any work: writable directory, no clobbering without
    /// `overwrite`, the map and the preview distinct.
    ///
    /// # Errors
    /// [`crate::Error::Output`] naming the file.
    pub fn check_outputs(&self) -> Result<()> {
        check_target(&self.output, self.overwrite)?;
        if let Some(p) = &self.preview {
            check_target(p, self.overwrite)?;
            if *p == self.output {
                return Err(crate::Error::Output {
                    path: p.clone(),
                    reason: "the preview and the map are the same file".into(),
                });
            }
        }
        Ok(())
    }

    /// Run the bake: check the outputs, load, frame, bake (`progress` receives finished pixel
    /// counts from worker threads), write the map and the preview together.
    ///
    /// # Errors
    /// Output, load, framing, settings and write errors; nothing is written on error.
    pub fn run(&self, progress: &(dyn Fn(u64) + Sync)) -> Result<BakeReport> {
        self.check_outputs()?;
        self.settings.validate()?;
        let vol = Volume::load(&self.input, &self.grid, self.density_scale)?;
        let camera = Camera::frame(&self.view, &vol.box_corners()?)?;
        self.run_on(vol, camera, progress)
    }

    /// [`BakeJob::run`] on a volume already loaded and a camera already framed (`input`,
    /// `grid` and `density_scale` are then only recorded in the header). The volume is dropped
    /// before writing, so peak memory is the tree plus the image.
    ///
    /// # Errors
    /// As [`BakeJob::run`].
    pub fn run_on(
        &self,
        vol: Volume,
        camera: Camera,
        progress: &(dyn Fn(u64) + Sync),
    ) -> Result<BakeReport> {
        self.check_outputs()?;
        let map = bake(&vol, &camera, &self.settings, progress)?;
        let mut warnings = volume_warnings(&vol.sanitized());
        let provenance = Provenance {
            source_file: self.input.display().to_string(),
            grid: vol.name().to_string(),
            density_scale: self.density_scale,
            light_dir: self.view.light_dir,
            light_pos: self.view.light_pos,
        };
        drop(vol);
        write_map(
            &self.output,
            self.preview.as_deref(),
            &map,
            &provenance,
            self.overwrite,
        )?;
        if map.stats.capped > 0 {
            warnings.push(Warning::Capped {
                samples: map.stats.capped,
            });
        }
        if map.stats.majorant_violations > 0 {
            warnings.push(Warning::MajorantViolations {
                lookups: map.stats.majorant_violations,
            });
        }
        Ok(BakeReport {
            map,
            provenance,
            warnings,
        })
    }
}
