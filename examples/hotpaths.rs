//! A driver for profilers (callgrind, perf): runs one hot path many times with no harness
//! noise. `cargo run --release --example hotpaths -- MODE [FILE] [REPS]`, MODE one of
//! `nearest`, `trilinear`, `vdbrs` (vdb-rs bare parse) (exact regular tracking of 2000 random rays crossing the grid's box,
//! REPS times) or `load` (full load of FILE's `density` grid, REPS times).
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use rand::{Rng, SeedableRng};
use std::hint::black_box;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mode = args.get(1).map_or("trilinear", String::as_str);
    let file = args
        .get(2)
        .cloned()
        .unwrap_or_else(|| "../shared/corpus/gen/cloud_fbm.vdb".into());
    let reps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    if mode == "vdbrs" {
        let t = std::time::Instant::now();
        for _ in 0..reps {
            let f = std::io::BufReader::new(std::fs::File::open(&file).unwrap());
            let mut r = vdb_rs::VdbReader::new(f).unwrap();
            black_box(r.read_grid::<f32>("density").unwrap());
        }
        eprintln!(
            "vdb-rs: {:.3} ms/parse",
            t.elapsed().as_secs_f64() * 1e3 / reps as f64
        );
        return;
    }
    if mode == "load" {
        let t = std::time::Instant::now();
        for _ in 0..reps {
            black_box(umbra::vdb::load_grid(&file, "density").unwrap());
        }
        eprintln!(
            "load: {:.3} ms/load",
            t.elapsed().as_secs_f64() * 1e3 / reps as f64
        );
        return;
    }
    let interp = if mode == "nearest" {
        Interp::Nearest
    } else {
        Interp::Trilinear
    };
    let vol = Volume::load(&file, "density", 5.0).unwrap();
    let info = umbra::info::FileInfo::from_archive(&umbra::vdb::open(&file).unwrap());
    let [lo, hi] = info.grids[0].world_bbox.unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let rays: Vec<Ray> = (0..2000)
        .map(|_| {
            let mut p = || [0, 1, 2].map(|a| rng.gen_range(lo[a]..hi[a]));
            let (a, b) = (p(), p());
            let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let o = [0, 1, 2].map(|k| a[k] - 2.0 * d[k]);
            let e = [0, 1, 2].map(|k| a[k] + 3.0 * d[k]);
            Ray::between(o, e).unwrap()
        })
        .collect();
    let t = std::time::Instant::now();
    let (mut tau, mut cells, mut segs) = (0.0, 0u64, 0u64);
    for _ in 0..reps {
        for r in &rays {
            let od = optical_depth(&vol, r, interp).unwrap();
            tau += od.tau;
            cells += od.cells;
            segs += od.segments;
        }
    }
    let s = t.elapsed().as_secs_f64();
    let n = (reps * rays.len()) as f64;
    eprintln!(
        "{mode}: {:.0} rays/s, {:.1} cells/ray, {:.1} segments/ray, {:.1} ns/cell, sum tau {tau:.9e}",
        n / s,
        cells as f64 / n,
        segs as f64 / n,
        s * 1e9 / cells as f64
    );
}
