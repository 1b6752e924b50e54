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

pub mod bake;
pub mod batch;
pub mod compare;
pub mod demand;
pub mod error;
pub mod estimate;
pub mod info;
pub mod input;
pub mod light;
pub mod math;
mod memory;
pub mod output;
pub mod points;
pub mod progress;
pub mod ray;
pub mod regular;
pub mod request;
pub mod rng;
pub mod scene;
pub mod solid;
pub mod text;
pub mod traverse;
pub mod tree;
pub mod usd;
pub mod vdb;
pub mod volume;
pub mod xform;

pub use error::{Error, Result};
pub use glam;
pub use light::Light;
pub use ray::Ray;
pub use volume::{Interp, Volume};
