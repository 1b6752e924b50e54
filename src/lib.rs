//! # umbra
//!
//! How much light gets through this OpenVDB cloud? umbra loads `.vdb` sparse grids into a flat,
//! cache-friendly tree and answers transmittance questions about them: exactly (regular
//! tracking, `T = exp(-integral of mu_t dt)` with `mu_t = density_scale x value`, nearest or
//! trilinear) and with every estimator of the family, with error bars.
//!
//! The main entry points, in the order a caller meets them: load a grid ([`Volume::load`]),
//! make rays ([`Ray`], [`Light::ray_from`]), pick an estimator from the registry
//! ([`estimate::Estimator::from_name`]) and [`estimate::estimate`]; or bake a whole map
//! ([`bake::Camera::frame`], [`bake::bake`], [`bake::write_map`]; [`bake::BakeJob`] does all of
//! it from a file).
//!
//! ```
//! use umbra::bake::{bake, BakeSettings, Camera, Projection, Resolution, View};
//! use umbra::estimate::{estimate, Estimator, Options};
//! use umbra::{Light, Ray, Volume};
//!
//! let path = concat!(env!("CARGO_MANIFEST_DIR"), "/data/cloud.vdb");
//! let vol = Volume::load(path, "density", 1.0)?;
//!
//! // Exact transmittance along a segment, and toward a directional light.
//! let ray = Ray::between([-2.0, 0.0, 0.0], [2.0, 0.5, 0.0])?;
//! let exact = estimate(&vol, &ray, 0, &Estimator::REGULAR, &Options::default())?;
//! let tau = exact.tau.expect("regular tracking reports tau");
//! assert!((exact.value - (-tau).exp()).abs() < 1e-15);
//! let sun = Light::Directional { dir: [-1.0, -1.0, 0.0] };
//! let to_sun = sun.ray_from(&vol, [0.0, 1.5, 0.0])?;
//!
//! // The same with ratio tracking, 256 samples: within a few standard errors of exact.
//! let ratio = Estimator::from_name("ratio")?;
//! let opts = Options { samples: 256, seed: 7, ..Options::default() };
//! let e = estimate(&vol, &to_sun, 0, &ratio, &opts)?;
//! let t = estimate(&vol, &to_sun, 0, &Estimator::REGULAR, &opts)?.value;
//! assert!((e.value - t).abs() < 5.0 * e.std_err + 1e-3);
//!
//! // A 32x32 orthographic shadow map seen from the light.
//! let view = View {
//!     projection: Projection::Ortho,
//!     light_dir: Some([-1.0, -1.0, 0.0]),
//!     light_pos: None,
//!     fov_deg: None,
//!     res: Some(Resolution::Exact(32, 32)),
//!     ..View::default()
//! };
//! let camera = Camera::frame(&view, &vol.box_corners()?)?;
//! let map = bake(&vol, &camera, &BakeSettings::new(Estimator::REGULAR, Options::default()), &|_| {})?;
//! assert_eq!(map.t.len(), 32 * 32);
//! assert!(map.t.iter().all(|&t| (0.0..=1.0).contains(&t)));
//! # Ok::<(), umbra::Error>(())
//! ```
//!
//! Conventions: index space puts voxel `(i, j, k)` at the point `(i, j, k)`; `world_from_index`
//! is an affine map in f64 (column vectors, glam's `DAffine3`); values are traced in `f32`, sums
//! in `f64`. `ARCHITECTURE.md` maps the modules, their invariants and where to add things.

// The public API: what a library user needs (volumes, inputs, scenes and USD stages,
// estimators and exact optical depth, requests, bakes, batch jobs, comparisons, reports,
// progress, errors). `tests/layering.rs` holds it to at most 14 public modules.
pub mod bake;
pub mod batch;
pub mod compare;
pub mod error;
pub mod estimate;
pub mod info;
pub mod input;
pub mod progress;
pub mod regular;
pub mod request;
pub mod scene;
pub mod usd;
pub mod volume;

// The stages beneath them: crate-private, reached from outside only through `internals`.
mod demand;
mod light;
mod math;
mod memory;
mod motion;
mod nvdb;
mod output;
mod points;
mod ray;
mod rng;
mod solid;
mod text;
mod traverse;
mod tree;
mod vdb;
mod xform;

/// The crate's internal stages, for umbra's own CLI, Python module, tests and benches (sibling
/// crates that need what a library user does not): not a stable API, hidden from the docs.
/// Each module here is the crate-private module of the same name.
#[doc(hidden)]
pub mod internals {
    /// Which leaves a set of rays touches (`crate::demand`).
    pub mod demand {
        pub use crate::demand::*;
    }
    /// Lights (`crate::light`).
    pub mod light {
        pub use crate::light::*;
    }
    /// Small geometry helpers (`crate::math`).
    pub mod math {
        pub use crate::math::*;
    }
    /// Motion blur: velocity fields and blurred bounds (`crate::motion`).
    pub mod motion {
        pub use crate::motion::*;
    }
    /// The NanoVDB `.nvdb` reader (`crate::nvdb`).
    pub mod nvdb {
        pub use crate::nvdb::*;
    }
    /// Atomic, checked writes (`crate::output`).
    pub mod output {
        pub use crate::output::*;
    }
    /// Transmittance at positions (`crate::points`).
    pub mod points {
        pub use crate::points::*;
    }
    /// Rays and their clipping (`crate::ray`).
    pub mod ray {
        pub use crate::ray::*;
    }
    /// The counter-based random stream (`crate::rng`).
    pub mod rng {
        pub use crate::rng::*;
    }
    /// Solid occluders (`crate::solid`).
    pub mod solid {
        pub use crate::solid::*;
    }
    /// Text escaping and wording helpers (`crate::text`).
    pub mod text {
        pub use crate::text::*;
    }
    /// The hierarchical DDA (`crate::traverse`).
    pub mod traverse {
        pub use crate::traverse::*;
    }
    /// The flat sparse tree (`crate::tree`).
    pub mod tree {
        pub use crate::tree::*;
    }
    /// The `.vdb` reader and writer (`crate::vdb`).
    pub mod vdb {
        pub use crate::vdb::*;
    }
    /// Affine transforms of scene entries (`crate::xform`).
    pub mod xform {
        pub use crate::xform::*;
    }
}

pub use error::{Error, Result};
pub use glam;
pub use light::Light;
pub use ray::Ray;
pub use volume::{Interp, Volume};
