//! A transmittance volume toward a light with extent (issue 60; `--light-angle` with
//! `--light-dir`, `--light-radius` with `--light-pos`): each voxel holds `T_L` at its centre,
//! the mean transmittance over the light (docs/lights.md), as `query --at` answers it there.
//!
//! **The receiver.** Voxel `ijk` (an active voxel of the density grid, or a voxel of an active
//! tile) is answered at its centre, the index point `ijk` in world space, exactly where the
//! point light's transmittance volume traces its ray from.
//!
//! **The sampling.** Every voxel through the library's one path for many receivers
//! ([`SoftLight::answer_many`]): the `k`-th voxel in output order (8^3 leaves by origin,
//! voxels by offset; Python's `Volume.transmittance_volume` row `k`) with ray id `k` and the
//! estimator's seed, so its value is `query --at CENTRE --ray-id k --seed S` rounded to f32, bit
//! for bit, whatever the thread count. The shared walks of the point light's volume (lines of
//! voxel centres along a sun) do not apply: each voxel costs its light's directions
//! (the target error's count, or `light_samples`). A voxel whose whole cone provably misses
//! every box is 1 without sampling, one deep in umbra is its bound (`U / 2 +- U / 2`,
//! [`crate::light`]'s umbra proof); the rest are sampled (`sampled_fraction` reports it). The
//! file holds `T` only; the stats report the largest error bar (`std_err_max`), the metadata
//! the light's extent (`umbra:light_extent`, `umbra:light_samples`, `umbra:seed`).

use super::transmittance_volume::{
    output_blocks, summarise, transmittance_leaves, Sharing, VolumeStats,
};
use super::volume_job::VolumeJob;
use crate::error::Result;
use crate::estimate::{Estimator, Options};
use crate::light::SoftLight;
use crate::tree::bit;
use crate::vdb::LeafOut;
use crate::volume::Volume;

/// A voxel's `T`, error bar, lookups, and its directions and whether the cap cut them.
type VoxelAnswer = (f32, f64, u64, (usize, bool));

/// Voxels handed to [`SoftLight::answer_many`] together (progress is reported between them).
const VOXELS_PER_GROUP: usize = 1 << 14;

/// `T_L` toward `soft` at every output voxel of `vol` (module docs): the leaves to write and
/// what they cost. `progress` gets finished voxel counts.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] for a volume too large to write voxel by voxel,
/// regular tracking on a moving volume, the work budget ([`SoftLight::check_budget`]); the
/// first error of any voxel's answer.
pub fn soft_transmittance_leaves(
    vol: &Volume,
    soft: &SoftLight,
    est: &Estimator,
    opts: &Options,
    threads: usize,
    progress: &dyn crate::progress::Progress,
) -> Result<(Vec<LeafOut>, VolumeStats)> {
    super::transmittance_volume::check_estimator(vol, est, opts)?;
    let start = std::time::Instant::now();
    let (mut leaves, tile_leaves) = output_blocks(vol)?;
    // The scene the receivers are answered in: this volume alone (sigma 1), as a query reads
    // its file.
    let scene = crate::scene::Scene::from_volume(vol.clone());
    soft.check_budget(&scene, crate::bake::output_voxels(vol), est, opts)?;
    // Every voxel centre in output order, and where its value goes.
    let mut at = Vec::new();
    for (li, leaf) in leaves.iter().enumerate() {
        for n in (0..512usize).filter(|&n| bit(&leaf.active, n)) {
            at.push((li, n));
        }
    }
    let centre = |(li, n): (usize, usize)| {
        let o = leaves[li].origin;
        let ijk = [
            o[0] + (n >> 6) as i32,
            o[1] + ((n >> 3) & 7) as i32,
            o[2] + (n & 7) as i32,
        ];
        vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)))
            .to_array()
    };
    let receivers: Vec<[f64; 3]> = at.iter().map(|&p| centre(p)).collect();
    let run = || -> Result<Vec<VoxelAnswer>> {
        let mut out = Vec::with_capacity(receivers.len());
        for (g, group) in receivers.chunks(VOXELS_PER_GROUP).enumerate() {
            let first = (g * VOXELS_PER_GROUP) as u64;
            for a in soft.answer_many(&scene, group, first, est, opts) {
                let a = a?;
                let e = &a.estimate;
                out.push((
                    e.value[0] as f32,
                    e.std_err[0],
                    e.lookups,
                    (a.light_samples, a.light_capped),
                ));
            }
            progress.advance(group.len() as u64);
        }
        Ok(out)
    };
    let answers = crate::bake::trace::in_pool(threads, run)?;
    let (mut lookups, mut sampled, mut worst, mut traced) = (0u64, 0u64, 0.0f64, 0u64);
    for (&(li, n), &(t, err, l, (d, _))) in at.iter().zip(&answers) {
        leaves[li].values[n] = t;
        lookups += l;
        sampled += u64::from(d > 0);
        traced += d as u64;
        worst = worst.max(err);
    }
    let directions = crate::bake::LightDirections::of(answers.iter().map(|a| a.3));
    let voxels = at.len() as u64;
    let mut stats = VolumeStats {
        voxels: 0,
        leaves: leaves.len() as u64,
        tile_leaves,
        sharing: Sharing::Rays,
        line_step: None,
        rays: traced,
        lookups,
        t_min: f64::INFINITY,
        t_max: f64::NEG_INFINITY,
        t_mean: 0.0,
        seconds: 0.0,
        light_samples: Some(soft.samples),
        sampled_fraction: Some(if voxels == 0 {
            0.0
        } else {
            sampled as f64 / voxels as f64
        }),
        std_err_max: Some(worst),
        light_directions: Some(directions),
    };
    summarise(&leaves, &mut stats);
    stats.seconds = start.elapsed().as_secs_f64();
    Ok((leaves, stats))
}

impl VolumeJob {
    /// The voxels' values and stats, toward the light or the light with extent, without
    /// writing (what [`VolumeJob::run`] writes; the Python module's in-memory volume).
    ///
    /// # Errors
    /// As [`transmittance_leaves`] and [`soft_transmittance_leaves`].
    pub fn leaves(
        &self,
        vol: &Volume,
        progress: &dyn crate::progress::Progress,
    ) -> Result<(Vec<LeafOut>, VolumeStats)> {
        let (est, opts) = (&self.estimator, &self.options);
        match &self.soft {
            Some(s) => soft_transmittance_leaves(vol, s, est, opts, self.threads, progress),
            None => transmittance_leaves(vol, &self.light, est, opts, self.threads, progress),
        }
    }

    /// The metadata a transmittance volume toward a light with extent adds (none toward a
    /// point): the extent, the directions per voxel and the seed of their rotations.
    pub(crate) fn extent_metadata(&self) -> Vec<(&'static str, String)> {
        let Some(soft) = &self.soft else {
            return Vec::new();
        };
        vec![
            ("umbra:light_extent", format!("{:?}", soft.extent)),
            ("umbra:light_samples", soft.samples.to_string()),
            ("umbra:seed", self.options.seed.to_string()),
        ]
    }
}
