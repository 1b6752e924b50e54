//! The `umbra` binary end to end, one module per subject: the CLI's contract (exit codes,
//! one-line errors, atomic outputs), bake/query/batch runs, hostile and mutated files, the stress
//! catalogue, the corpus manifest and products read back by real tools. One test binary
//! (`cargo test --profile quick --ignore-rust-version --test cli [FILTER]`); the modules are the
//! former `tests/*.rs` files, unchanged.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../bake_support/mod.rs"]
mod bake_support;
#[path = "../common/mod.rs"]
mod common;
#[path = "../common/vdb_writer.rs"]
mod vdb_writer;

mod batch;
mod batch_key;
mod cli_bake;
mod cli_contract;
mod cli_query;
mod commands_doc;
mod corpus_manifest;
mod deep_map;
mod friction;
mod hostile;
mod info_map;
mod lights_extent;
mod lights_extent_points;
mod lights_maps;
mod motion;
mod mutation;
mod nvdb;
mod quiet_inputs;
mod stress;
mod transmittance_volume;
mod vdb_blender;
