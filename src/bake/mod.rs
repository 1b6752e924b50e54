//! Baking transmittance maps: a [`Camera`] framed on the volume box, one ray per pixel traced in
//! parallel tiles, written to OpenEXR ([`write_exr`]) atomically, with a PNG preview.
//!
//! **Volume box.** What a map frames and where "until the ray leaves the volume" ends: the
//! world image (a parallelepiped for a general affine map) of the index box holding every
//! non-background value ([`Volume::value_box`]) grown by one voxel, the reach of a trilinear
//! lookup. Outside it the extinction is the background's.
//!
//! **Pixels.** Pixel `(i, j)` (row `j`, row 0 at the top) traces [`Camera::pixel_ray`] over
//! `[0, t_max]`. Its main estimate `T` uses the random streams of ray id `p = j W + i` (the same as
//! `umbra query --ray-id p`); adaptive batch `b >= 1` uses ray id `b N + p` and depth slice `k`
//! ray id `(64 + k) N + p`, with `N = W H`. So a pixel's value depends only on the seed and the
//! settings, never on the thread count or the tile order.

mod camera;
mod matrix;
mod output;
mod pipeline;
mod render;

pub use camera::{check_res, Camera, Projection, View, DEFAULT_LONG_SIDE, MAX_PIXELS, MAX_SIDE};
pub use output::{slice_channel, write_exr, write_map, write_png, Provenance};
pub use pipeline::{volume_warnings, BakeJob, BakeReport, Warning};
pub use render::{bake, BakeSettings, BakeStats, Depths, Map, MAX_BATCHES, MAX_SLICES};

use crate::error::{Error, Result};
use crate::volume::Volume;

/// Index-space volume box `[lo, hi]`: `value_box` grown by one voxel; `None` when the density is
/// the background everywhere.
#[must_use]
pub fn volume_box_index(vol: &Volume) -> Option<([f64; 3], [f64; 3])> {
    vol.value_box()
        .map(|[lo, hi]| (lo.map(|v| (v - 1) as f64), hi.map(|v| (v + 1) as f64)))
}

/// The 8 world corners of the volume box, corner `n` taking `hi` on axis `a` when bit `2 - a` of
/// `n` is set.
///
/// # Errors
/// [`Error::InvalidArgument`] (name `grid`) when the grid holds nothing but its background:
/// there is nothing to frame.
pub fn volume_corners(vol: &Volume) -> Result<[[f64; 3]; 8]> {
    let (lo, hi) = volume_box_index(vol).ok_or_else(|| Error::InvalidArgument {
        name: "grid".into(),
        reason: format!(
            "grid '{}' holds no value other than its background: nothing to frame",
            vol.name()
        ),
    })?;
    Ok(std::array::from_fn(|n| {
        let p = [0, 1, 2].map(|a| if n >> (2 - a) & 1 == 1 { hi[a] } else { lo[a] });
        vol.to_world(p)
    }))
}
