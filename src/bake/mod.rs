//! Baking: what a light sees through a volume, as a map (flat, tiled, deep OpenEXR, with a PNG
//! preview) or as a transmittance volume (`.vdb`). The rooms follow the stages of a bake, and a
//! room imports only its own stage and those below it (`tests/layering.rs` holds this):
//!
//! | stage | room | what it does |
//! |---|---|---|
//! | vocabulary | `map` | what a map is and how it is asked for: [`BakeSettings`], [`Depths`], [`Map`], channel names |
//! | vocabulary | `camera` | [`View`] -> [`Camera`]: framing, OpenEXR matrices, cameras reused from earlier maps, how far a volume reaches outside a fixed camera |
//! | stages | `trace` | making a [`Map`] in memory: the parallel tile renderer (one estimate per pixel), the exact sweep in object order (`trace/sweep`, AVX2 lanes), scenes channel by channel |
//! | stages | `encode` | writing bytes: EXR scanline / tiled / mip-mapped ([`write_exr`]), deep EXR ([`DeepImage`]), fixed-size deep formats ([`DeepFormat`]), PNG, the map as data ([`MapSummary`]), the greedy deep-sample fit |
//! | products | `product` | [`BakeJob`] (file to written map), [`bake_deep`] (deep maps), [`bake_fixed`] (deep maps at a fixed size per texel), [`VolumeJob`] (transmittance volumes) |
//!
//! A bake is asked for through [`crate::request`], which plans one of these products.
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
//! perspective with the light outside the volume) are traced in object order by the sweep:
//! each 8^3 block of the tree adds its exact integral to every pixel it covers (see
//! ARCHITECTURE.md); everything else, and any map with [`BakeSettings::order`] =
//! [`Order::Rays`], traces one ray per pixel.

mod camera;
mod encode;
mod map;
mod product;
mod trace;

pub(crate) use camera::CameraParts;
pub use camera::{
    camera_from_json, check_res, is_omni, read_camera, world_box_corners, Camera, CameraSpec, Omni,
    Outside, Projection, Resolution, View, DEFAULT_LONG_SIDE, DEFAULT_OMNI_SIDE, MAX_PIXELS,
    MAX_SIDE,
};
pub use encode::deep_exr::{
    encode_deep_exr, write_deep_exr, DeepAttributes, DeepImage, RESERVED_ATTRIBUTES,
};
pub use encode::deep_fit::{
    check_deep_error, fit_profile, fit_spans, fitted_transmittance, DeepSample, DEFAULT_DEEP_ERROR,
};
pub use encode::exr::{write_exr, write_exr_as, write_map, write_png, Provenance};
pub use encode::fixed::{texel_error, DeepFormat, NormProfile, TexelError, TAU_CAP};
pub use encode::layout::{mip_levels, mip_sizes, ExrLayout, MAX_TILE};
pub use encode::summary::{MapSummary, SummaryCamera, SummaryLight};
pub use map::{
    channel_names, check_threads, slice_channel, BakeSettings, BakeStats, Channel, Depths,
    LightDirections, Map, Order, Receiver, SoftMap, SweepDeclined, MAX_BATCHES, MAX_SLICES,
    MAX_THREADS,
};
pub use product::deep_map::{bake_deep, deep_attributes, DeepMap, DeepStats, STOCHASTIC_DEPTHS};
pub use product::fixed_map::{bake_fixed, FixedMap, FixedStats, PROFILE_ERROR};
pub use product::pipeline::{
    map_warnings, motion_warnings, solid_warnings, velocity_warnings, volume_warnings, BakeError,
    BakeJob, BakeReport, BoundedPlan, Product, Step, Warning, IMPLIED_BUDGET,
};
pub use product::soft_deep::{
    soft_deep_attributes, soft_deep_depths, soft_deep_image, SOFT_DEEP_DEPTHS,
};
pub use product::soft_volume::soft_transmittance_leaves;
pub use product::transmittance_volume::{
    output_voxels, transmittance_leaves, Sharing, VolumeStats, MAX_VOLUME_LEAVES,
};
pub use product::volume_job::{VolumeJob, VolumeReport, DEFAULT_OUT_GRID};
pub use trace::{bake, bake_scene};
