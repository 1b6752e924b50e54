//! The products a bake makes and their pipelines: a map from file to written EXR
//! (`pipeline`: [`crate::bake::BakeJob`]), the deep map of a scene (`deep_map`) and its
//! fixed-size encodings (`fixed_map`), and the
//! transmittance volume (`transmittance_volume`: [`crate::bake::VolumeJob`]). A product frames
//! (`bake/camera`), traces (`bake/trace`) and encodes (`bake/encode`); nothing below imports
//! it.

pub(crate) mod deep_map;
pub(crate) mod fixed_map;
pub(crate) mod pipeline;
pub(crate) mod soft_deep;
pub(crate) mod soft_volume;
mod transmittance_layers;
pub(crate) mod transmittance_volume;
pub(crate) mod volume_job;
