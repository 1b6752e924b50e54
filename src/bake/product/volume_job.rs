//! One transmittance volume from a file to a `.vdb` ([`VolumeJob`]): check the output, load
//! the density grid as the job traces it, compute every voxel's `T` (toward the light,
//! `transmittance_volume`, or toward a light with extent, `soft_volume`) and write it with its
//! `umbra:*` metadata.

use super::transmittance_volume::{output_voxels, VolumeStats};
use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};
use crate::light::Light;
use crate::volume::Volume;

/// One transmittance volume from a file to a `.vdb`: what `umbra bake ... -o NAME.vdb` runs.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeJob {
    /// The grid file and how it is read: its density grid, `mu_t = density_scale x value`,
    /// where the volume sits in the shot (the output grid's transform includes it).
    pub source: crate::input::Source,
    /// The light (a light with extent's centre).
    pub light: Light,
    /// The light with extent (`light-angle`, `light-radius`): each voxel holds the mean over
    /// it (`soft_volume`); `None` for the point light, as before, bit for bit.
    pub soft: Option<crate::light::SoftLight>,
    /// Estimator of every voxel's ray (regular tracking: exact).
    pub estimator: Estimator,
    /// Its options (samples, seed, interpolation).
    pub options: Options,
    /// Worker threads: 0 the current pool, `n` a pool of `n`.
    pub threads: usize,
    /// The `.vdb` written.
    pub output: std::path::PathBuf,
    /// Name of the written grid (`transmittance` by default, `--out-grid`).
    pub out_grid: String,
    /// Store 16-bit half floats.
    pub half: bool,
    /// Replace an existing output.
    pub overwrite: bool,
    /// Motion blur from a velocity grid of the input (`crate::motion`): T at each voxel is
    /// the shutter mean.
    pub motion: Option<crate::motion::MotionRequest>,
    /// A batch task's key (`umbra::batch::TaskKey` as text), written as the grid's
    /// `umbra:key` metadata; `None` for a bake outside a job.
    pub key: Option<String>,
}

/// What a finished transmittance volume produced.
#[derive(Debug, Clone)]
pub struct VolumeReport {
    /// Counts and cost.
    pub stats: VolumeStats,
    /// Things the user should be told (bad voxels in the density).
    pub warnings: Vec<crate::bake::Warning>,
}

/// The default name of the written grid.
pub const DEFAULT_OUT_GRID: &str = "transmittance";

impl VolumeJob {
    /// Check the output before any work: a writable `.vdb` path (no clobbering without
    /// `overwrite`) and a usable grid name.
    ///
    /// # Errors
    /// [`Error::Output`] naming the file; [`Error::InvalidArgument`] (`output`, `out-grid`).
    pub fn check_outputs(&self) -> Result<()> {
        crate::output::check_writable(&self.output, self.overwrite)?;
        crate::bake::product::pipeline::check_extension(
            &self.output,
            "vdb",
            "output",
            "a transmittance volume is written as OpenVDB",
        )?;
        if self.out_grid.is_empty() || self.out_grid.contains(['\0', '\u{1e}']) {
            return Err(Error::InvalidArgument {
                name: "out-grid".into(),
                reason: format!(
                    "{:?}: a grid name must be non-empty, without NUL or the record separator",
                    crate::text::escape(&self.out_grid)
                ),
            });
        }
        if self.out_grid == self.source.options().grid
            && crate::output::same_file(&self.output, self.source.path())
        {
            return Err(Error::InvalidArgument {
                name: "output".into(),
                reason: "the transmittance volume would replace the density it is made from".into(),
            });
        }
        Ok(())
    }

    /// Load the density grid as this job traces it (scale, `xform`).
    ///
    /// # Errors
    /// Load errors.
    pub fn load(&self) -> Result<Volume> {
        let (path, o) = (self.source.path(), self.source.options());
        if self.source.kind().is_scene_file() {
            return Err(Error::InvalidArgument {
                name: "output".into(),
                reason: format!(
                    "a transmittance volume (.vdb) is made from one density grid; {} is a scene \
                     file",
                    path.display()
                ),
            });
        }
        let mut v = Volume::load(path, &o.grid, o.density_scale)?;
        if let Some(x) = &self.source.xform()? {
            v = v.with_xform(x)?;
        }
        match &self.motion {
            Some(m) => crate::scene::blurred(v, m, path),
            None => Ok(v),
        }
    }

    /// Check, load, compute and write. `progress` is told the voxels to compute and receives
    /// finished voxel counts.
    ///
    /// # Errors
    /// Output, load, light, estimator and write errors; nothing is written on error.
    pub fn run(&self, progress: &dyn crate::progress::Progress) -> Result<VolumeReport> {
        self.run_steps(progress).map_err(|e| e.error)
    }

    /// [`VolumeJob::run`], each failure with the step it stopped at.
    pub(crate) fn run_steps(
        &self,
        progress: &dyn crate::progress::Progress,
    ) -> std::result::Result<VolumeReport, crate::bake::BakeError> {
        use crate::bake::{BakeError, Step};
        let check = |e| BakeError::at(Step::Check, e);
        self.check_outputs().map_err(check)?;
        self.options.validate().map_err(check)?;
        let vol = self
            .load()
            .map_err(|e| BakeError::loading(&self.source, e))?;
        self.run_on(&vol, progress)
            .map_err(|e| BakeError::at(Step::Bake, e))
    }

    /// [`VolumeJob::run`] on a volume already loaded (the Python module's `Volume`).
    ///
    /// # Errors
    /// As [`VolumeJob::run`].
    pub fn run_on(
        &self,
        vol: &Volume,
        progress: &dyn crate::progress::Progress,
    ) -> Result<VolumeReport> {
        self.check_outputs()?;
        progress.start(&crate::progress::Work {
            units: output_voxels(vol),
            what: "transmittance volume",
            unit: Some("voxels"),
        });
        let (leaves, stats) = self.leaves(vol, progress)?;
        let mut grid =
            crate::vdb::FloatGridOut::new(&self.out_grid, 1.0, vol.world_from_index(), leaves)?
                .with_half(self.half);
        let light = self.light.to_string();
        let meta = [
            (
                "umbra:quantity",
                if self.soft.is_some() {
                    "mean transmittance over the light's extent from each voxel centre"
                } else {
                    "transmittance exp(-tau) from each voxel centre toward the light"
                }
                .to_string(),
            ),
            ("umbra:light", light),
            ("umbra:estimator", self.estimator.name().to_string()),
            (
                "umbra:interp",
                format!("{:?}", self.options.interp).to_lowercase(),
            ),
            (
                "umbra:density_scale",
                format!("{}", self.source.options().density_scale),
            ),
            (
                "umbra:source_file",
                self.source.path().display().to_string(),
            ),
            ("umbra:grid", vol.name().to_string()),
            (
                "umbra:software",
                concat!("umbra ", env!("CARGO_PKG_VERSION")).to_string(),
            ),
        ];
        let key = self.key.iter().map(|k| ("umbra:key", k.clone()));
        for (k, v) in meta.into_iter().chain(self.extent_metadata()).chain(key) {
            grid = grid.with_metadata(k, &v);
        }
        crate::vdb::write_vdb(&self.output, &grid, self.overwrite)?;
        Ok(VolumeReport {
            stats,
            warnings: crate::bake::volume_warnings(&vol.sanitized())
                .into_iter()
                .chain(crate::bake::velocity_warnings(vol))
                .collect(),
        })
    }
}
