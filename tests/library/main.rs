//! The library's tests, one module per subject: answers against independent references (the
//! OpenVDB oracle, vdb-rs, closed forms), the estimators within their standard errors, the
//! readers and writers, cameras, products and the public API as a caller uses it. One test
//! binary (`cargo test --profile quick --ignore-rust-version --test library [FILTER]`); the
//! modules are the former `tests/*.rs` files, unchanged.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../bake_support/mod.rs"]
mod bake_support;
#[path = "../common/mod.rs"]
mod common;
#[path = "../common/vdb_writer.rs"]
mod vdb_writer;

mod bake;
mod bake_files;
mod blur_error_bars;
mod blur_intervals;
mod blur_options;
mod blur_sweep;
mod camera_control;
mod camera_reuse;
mod data_samples;
mod deep_exr;
mod deep_formats;
mod estimators;
mod exr_layout;
mod lazy;
mod library_api;
mod lights_adaptive;
mod lights_extent;
mod lights_extent_points;
mod lights_maps;
mod lights_umbra;
mod map_summary;
mod motion;
mod motion_parts;
mod near_lattice;
mod nvdb;
mod nvdb32;
mod omni;
mod oracle_corpus;
mod query_request;
mod readme;
mod regular_tracking;
mod scene;
mod solid;
mod source_options;
mod spent_weights;
mod transmittance_layers;
mod tree_bounds;
mod usd_corrupt;
mod vdb_write;
mod vdbrs_crosscheck;
mod vector;
mod xform;
