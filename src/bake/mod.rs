//! Baking transmittance maps: a [`Camera`] framed on the volume box, one ray per pixel traced in
//! parallel tiles, written to OpenEXR ([`write_exr`]) atomically, with a PNG preview.
//!
//! **Volume box.** What a map frames: [`crate::Volume::box_corners`], the world image of the
//! index box holding every non-background value grown by one voxel (the reach of a trilinear
//! lookup). Outside it the extinction is the background's.
//!
//! **Pixels.** Pixel `(i, j)` (row `j`, row 0 at the top) traces [`Camera::pixel_ray`] over
//! `[0, t_max]`. Its main estimate `T` uses the random streams of ray id `p = j W + i` (the same as
//! `umbra query --ray-id p`); adaptive batch `b >= 1` uses ray id `b N + p` and depth slice `k`
//! ray id `(64 + k) N + p`, with `N = W H`. So a pixel's value depends only on the seed and the
//! settings, never on the thread count or the tile order.
//!
//! **Order.** Exact maps (regular tracking, trilinear, slices included; orthographic, and
//! perspective with the light outside the volume) are traced in object order by the sweep: each 8^3 block of the tree adds its exact integral to every pixel
//! it covers (`sweep`, see ARCHITECTURE.md); everything else, and any map with
//! [`BakeSettings::order`] = [`Order::Rays`], traces one ray per pixel.

mod camera;
mod camera_file;
mod deep;
mod deep_fit;
mod deep_map;
pub(crate) use camera::CameraParts;
mod layout;
mod map;
mod matrix;
mod output;
mod pipeline;
mod reach;
mod render;
mod scene_map;
mod shadow_volume;
mod summary;
mod sweep;

pub use camera::{
    check_res, world_box_corners, Camera, CameraSpec, Projection, Resolution, View,
    DEFAULT_LONG_SIDE, MAX_PIXELS, MAX_SIDE,
};
pub use camera_file::{camera_from_json, read_camera};
pub use deep::{encode_deep_exr, write_deep_exr, DeepAttributes, DeepImage, RESERVED_ATTRIBUTES};
pub use deep_fit::{fit_profile, fit_spans, fitted_transmittance, DeepSample};
pub use deep_map::{
    bake_deep, check_deep_error, deep_attributes, DeepMap, DeepStats, DEFAULT_DEEP_ERROR,
    STOCHASTIC_DEPTHS,
};
pub use layout::{mip_levels, mip_sizes, ExrLayout, MAX_TILE};
pub use map::{
    channel_names, check_threads, slice_channel, BakeSettings, BakeStats, Channel, Depths, Map,
    Order, MAX_BATCHES, MAX_SLICES, MAX_THREADS,
};
pub use output::{write_exr, write_exr_as, write_map, write_png, Provenance};
pub use pipeline::{map_warnings, volume_warnings, BakeJob, BakeReport, Product, Warning};
pub use reach::Outside;
pub use render::{bake, bake_scene};
pub use shadow_volume::{
    output_voxels, transmittance_leaves, Sharing, VolumeJob, VolumeReport, VolumeStats,
    DEFAULT_OUT_GRID, MAX_VOLUME_LEAVES,
};
pub use summary::{MapSummary, SummaryCamera};
