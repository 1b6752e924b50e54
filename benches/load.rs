//! Load time of the largest corpus files: vdb-rs 0.6.0 `read_grid` (bare parse into its HashMap
//! tree) against umbra's full load (parse + flat tree + per-node bounds and halos).
//! Run: `cargo bench --ignore-rust-version --bench load`. Needs `../shared/corpus`.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use std::path::PathBuf;

const FILES: &[(&str, &str)] = &[
    ("gen/cloud_fbm.vdb", "density"),
    ("real/openvdb_smoke1_houdini_v222.vdb", "density"),
    ("gen/tiles_mixed.vdb", "density"),
    ("gen/sphere_levelset.vdb", "ls_sphere"),
];

fn bench_load(c: &mut Criterion) {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let mut group = c.benchmark_group("load");
    group.sample_size(20);
    for &(file, grid) in FILES {
        let path = dir.join(file);
        if !path.exists() {
            eprintln!("skipping {}: not found", path.display());
            continue;
        }
        let short = file.rsplit('/').next().unwrap_or(file);
        group.bench_function(format!("vdb-rs/{short}"), |b| {
            b.iter(|| {
                let f = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
                let mut r = vdb_rs::VdbReader::new(f).unwrap();
                r.read_grid::<f32>(grid).unwrap()
            });
        });
        group.bench_function(format!("umbra/{short}"), |b| {
            b.iter(|| umbra::internals::vdb::load_grid(&path, grid).unwrap());
        });
    }
    group.finish();
}

criterion_group!(benches, bench_load);
criterion_main!(benches);
