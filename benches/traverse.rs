//! HDDA traversal and exact regular tracking on the largest corpus cloud
//! (`gen/cloud_fbm.vdb`): rays/s for nearest and trilinear regular tracking, segments/s of the
//! bare HDDA at each granularity. Counts (segments per ray, cells per ray) are printed once so
//! that voxels crossed per second = cells/ray x rays/s. Run: `cargo bench --ignore-rust-version --bench traverse`.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use std::hint::black_box;
use std::ops::ControlFlow;
use std::path::PathBuf;
use umbra::internals::traverse::{walk, Granularity};
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

const RAYS: usize = 2000;

fn rays(vol: &Volume, world_lo: [f64; 3], world_hi: [f64; 3]) -> Vec<Ray> {
    let _ = vol;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    (0..RAYS)
        .map(|_| {
            let mut p = || [0, 1, 2].map(|a| rng.gen_range(world_lo[a]..world_hi[a]));
            let (a, b) = (p(), p());
            // Extend to cross the whole box.
            let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let o = [0, 1, 2].map(|k| a[k] - 2.0 * d[k]);
            let e = [0, 1, 2].map(|k| a[k] + 3.0 * d[k]);
            Ray::between(o, e).unwrap()
        })
        .collect()
}

fn bench_traverse(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    if !path.exists() {
        eprintln!("skipping: {} not found", path.display());
        return;
    }
    let vol = Volume::load(&path, "density", 5.0).unwrap();
    let info = umbra::info::FileInfo::from_archive(&umbra::internals::vdb::open(&path).unwrap());
    let [lo, hi] = info.grids[0].world_bbox.unwrap();
    let rays = rays(&vol, lo, hi);

    for interp in [Interp::Nearest, Interp::Trilinear] {
        let (mut cells, mut lookups, mut segs) = (0u64, 0u64, 0u64);
        for r in &rays {
            let od = optical_depth(&vol, r, interp).unwrap();
            cells += od.cells;
            lookups += od.lookups;
            segs += od.segments;
        }
        let n = rays.len() as f64;
        eprintln!(
            "regular {interp:?}: {:.1} cells/ray, {:.1} lookups/ray, {:.1} leaf-level segments/ray",
            cells as f64 / n,
            lookups as f64 / n,
            segs as f64 / n
        );
    }
    for gran in [Granularity::Leaf, Granularity::Lower, Granularity::Upper] {
        let mut segs = 0u64;
        for r in &rays {
            segs += walk(&vol, r, Interp::Trilinear, gran, |_| {
                ControlFlow::Continue(())
            })
            .segments;
        }
        eprintln!(
            "HDDA {gran:?} (trilinear): {:.1} segments/ray",
            segs as f64 / rays.len() as f64
        );
    }

    let mut g = c.benchmark_group("regular_tracking");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(20);
    for interp in [Interp::Nearest, Interp::Trilinear] {
        g.bench_function(format!("{interp:?}"), |b| {
            b.iter(|| {
                let mut s = 0.0;
                for r in &rays {
                    s += optical_depth(&vol, r, interp).unwrap().tau;
                }
                black_box(s)
            });
        });
    }
    g.finish();
    let mut g = c.benchmark_group("hdda");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(20);
    for gran in [Granularity::Leaf, Granularity::Lower, Granularity::Upper] {
        g.bench_function(format!("{gran:?}"), |b| {
            b.iter(|| {
                let mut n = 0u64;
                for r in &rays {
                    n += walk(&vol, r, Interp::Trilinear, gran, |_| {
                        ControlFlow::Continue(())
                    })
                    .segments;
                }
                black_box(n)
            });
        });
    }
    g.finish();
}

criterion_group!(benches, bench_traverse);
criterion_main!(benches);
