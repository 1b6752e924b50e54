//! # umbra
//!
//! How much light gets through this OpenVDB cloud? umbra loads `.vdb` sparse grids into a flat,
//! cache-friendly tree and answers transmittance questions about them.
//!
//! ```no_run
//! let grid = umbra::vdb::load_grid("data/cloud.vdb", "density")?;
//! let stats = grid.tree.stats();
//! println!("{} active voxels", stats.active_voxels);
//! # Ok::<(), umbra::Error>(())
//! ```
//!
//! Conventions: index space puts voxel `(i, j, k)` at the point `(i, j, k)`; `world_from_index`
//! is an affine map in f64 (column vectors); values are traced in `f32`.

pub mod bake;
pub mod batch;
pub mod compare;
pub mod error;
pub mod estimate;
pub mod info;
pub mod light;
pub mod math;
pub mod output;
pub mod ray;
pub mod regular;
pub mod rng;
pub mod traverse;
pub mod tree;
pub mod vdb;
pub mod volume;

pub use error::{Error, Result};
pub use glam;
pub use light::Light;
pub use ray::Ray;
pub use volume::{Interp, Volume};
